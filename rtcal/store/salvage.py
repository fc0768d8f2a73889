"""Readings and events read straight from the pages of a run.sqlite that SQLite refuses.

SQLite refuses a damaged file whole ("database disk image is malformed": cut short, a page
overwritten); the rows on its other pages are still there. Every table leaf page of the file —
overlaid by the committed frames of its write-ahead log, freelist pages left out — is decoded
by the published file format (https://www.sqlite.org/fileformat2.html, sections 1.3, 1.6, 2.1,
4) and a record is taken as a reading or an event by its shape: the store's columns and their
types. Nothing is written. How many readings could not be read: the store keeps the id of its
last reading in ``meta`` (ids run 1, 2, …; rows are never deleted), so every id up to it that
was not found is counted; without that row, up to the highest id found.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

from rtcal.store.runstore import LAST_READING_ID, NOT_NULL, READING_COLUMN_TYPES, READING_COLUMNS

MAGIC = b"SQLite format 3\x00"
WAL_MAGIC = (0x377F0682, 0x377F0683)
TABLE_LEAF, TABLE_INTERIOR = 0x0D, 0x05
NUMERIC = (int, float)
# per reading column after the id, by the store's declared column types: the Python types a stored value
# may have (None: NULL allowed)
_PYTHON_TYPES: dict[str, tuple[type, ...]] = {"REAL": NUMERIC, "INTEGER": (int,), "TEXT": (str,)}
_READING_TYPES = [_PYTHON_TYPES[READING_COLUMN_TYPES[c]] + (() if c in NOT_NULL else (type(None),)) for c in READING_COLUMNS]
# REAL affinity: SQLite stores a whole value as an integer on disk
_REAL_COLUMNS = {k for k, c in enumerate(READING_COLUMNS) if READING_COLUMN_TYPES[c] == "REAL"}


@dataclass
class Salvage:
    """What could be read: readings and events by id, with their columns as the store has them."""

    readings: dict[int, tuple] = field(default_factory=dict)  # READING_COLUMNS, then the context (JSON or None)
    events: dict[int, tuple] = field(default_factory=dict)
    last_reading_id: int | None = None
    highest_key: int = 0  # the highest id the readings tree's interior pages name (ids up to it were stored)
    pages: int = 0  # pages the file has
    pages_expected: int = 0  # pages its header says it has (0: unknown)

    @property
    def unreadable_readings(self) -> int:
        """Readings known to have been stored that could not be read."""
        known = self.last_reading_id if self.last_reading_id is not None else max(self.highest_key, *self.readings, 0)
        return max(known - sum(1 for i in self.readings if i <= known), 0)

    def summary(self) -> str:
        """One sentence: read, not read, and how sure the count is."""
        text = f"{len(self.readings)} readings and {len(self.events)} events could be read; " \
               f"{self.unreadable_readings} readings cannot"
        if self.last_reading_id is None:
            text += " (counted up to the highest id found: the store's count of its readings was not readable, so more may be lost)"
        if self.pages_expected > self.pages:
            text += f"; the file has {self.pages} of the {self.pages_expected} pages its header names (cut short)"
        return text


def salvage_store(path: Path) -> Salvage:
    """Every reading and event on a readable page of ``path`` (and of ``path``-wal)."""
    path = Path(path)
    with path.open("rb") as fh:
        header = fh.read(100)
        page_size, reserved, expected = _header(header)
        wal_pages, wal_page_size = _wal_pages(Path(f"{path}-wal"))
        if expected == 0 and header[:16] != MAGIC and wal_page_size:
            page_size = wal_page_size  # the file's first page is lost: the log still knows the page size
        if wal_page_size != page_size:
            wal_pages = {}
        size = fh.seek(0, 2)
        out = Salvage(pages=size // page_size, pages_expected=expected)
        usable = page_size - reserved
        count = max(size // page_size, max(wal_pages, default=0))

        def page(number: int) -> bytes:
            if number in wal_pages:
                return wal_pages[number]
            if not 1 <= number <= size // page_size:
                return b""
            fh.seek((number - 1) * page_size)
            return fh.read(page_size)

        free = _freelist(page(1), page, count)
        out.highest_key = _highest_key(page, usable, count)
        for number in range(1, count + 1):
            if number in free:
                continue
            data = page(number)
            start = 100 if number == 1 else 0
            if len(data) < start + 8 or data[start] != TABLE_LEAF:
                continue
            for rowid, values in _leaf_records(data, start, usable, page, count):
                _classify(rowid, values, out)
    return out


def _header(header: bytes) -> tuple[int, int, int]:
    """Page size, reserved bytes per page and the page count the file's header names (0 if unknown)."""
    if len(header) < 100 or header[:16] != MAGIC:
        return 4096, 0, 0  # SQLite's default page size; the write-ahead log may say otherwise
    size = int.from_bytes(header[16:18], "big")
    size = 65536 if size == 1 else size
    if size < 512 or size & (size - 1):
        size = 4096
    valid = header[24:28] == header[92:96]  # the page count is valid when it was written with the change counter
    return size, header[20], int.from_bytes(header[28:32], "big") if valid else 0


def _wal_pages(path: Path) -> tuple[dict[int, bytes], int]:
    """Pages of the write-ahead log's committed frames (the last commit's view) and its page size."""
    try:
        data = path.read_bytes()
    except OSError:
        return {}, 0
    if len(data) < 32 or int.from_bytes(data[:4], "big") not in WAL_MAGIC:
        return {}, 0
    size = int.from_bytes(data[8:12], "big")
    if size < 512 or size > 65536 or size & (size - 1):
        return {}, 0
    salt = data[16:24]
    pages: dict[int, bytes] = {}
    pending: dict[int, bytes] = {}
    at = 32
    while at + 24 + size <= len(data):
        frame = data[at:at + 24]
        if frame[8:16] != salt:
            break
        pending[int.from_bytes(frame[:4], "big")] = data[at + 24:at + 24 + size]
        if int.from_bytes(frame[4:8], "big"):  # a commit frame: everything before it is committed
            pages.update(pending)
            pending = {}
        at += 24 + size
    return pages, size


def _freelist(first: bytes, page, count: int) -> set[int]:
    """Pages on the freelist (they may hold stale rows), as far as its trunk pages can be read."""
    if len(first) < 100 or first[:16] != MAGIC:
        return set()
    free: set[int] = set()
    trunk = int.from_bytes(first[32:36], "big")
    while 1 <= trunk <= count and trunk not in free:
        free.add(trunk)
        data = page(trunk)
        if len(data) < 8:
            break
        n = min(int.from_bytes(data[4:8], "big"), (len(data) - 8) // 4)
        free.update(int.from_bytes(data[8 + 4 * k:12 + 4 * k], "big") for k in range(n))
        trunk = int.from_bytes(data[:4], "big")
    return free


def _highest_key(page, usable: int, count: int) -> int:
    """The highest key on the readings table's interior pages, walked from its root page (named
    in the schema on page 1): every id up to it was stored, found or not. 0 if unknown."""
    root = 0
    first = page(1)
    if len(first) > 108 and first[100] == TABLE_LEAF:
        for _, values in _leaf_records(first, 100, usable, page, count):
            if len(values) == 5 and values[:2] == ["table", "readings"] and isinstance(values[3], int):
                root = values[3]
    highest, todo, seen = 0, [root] if root else [], set()
    while todo:
        number = todo.pop()
        data = page(number)
        if number in seen or len(data) < 12 or data[0] != TABLE_INTERIOR:
            continue
        seen.add(number)
        todo.append(int.from_bytes(data[8:12], "big"))  # the right-most child
        for k in range(min(int.from_bytes(data[3:5], "big"), (len(data) - 12) // 2)):
            try:
                at = int.from_bytes(data[12 + 2 * k:14 + 2 * k], "big")
                todo.append(int.from_bytes(data[at:at + 4], "big"))
                highest = max(highest, _varint(data, at + 4)[0])
            except IndexError:
                continue
    return highest


def _varint(data: bytes, at: int) -> tuple[int, int]:
    value = 0
    for k in range(9):
        byte = data[at + k]
        if k == 8:
            return (value << 8) | byte, at + 9
        value = (value << 7) | (byte & 0x7F)
        if byte < 0x80:
            return value, at + k + 1
    raise ValueError("varint")  # not reached


def _leaf_records(data: bytes, start: int, usable: int, page, count: int):
    """(rowid, values) of every cell of a table leaf page that decodes; a cell that does not is skipped."""
    cells = int.from_bytes(data[start + 3:start + 5], "big")
    for k in range(min(cells, (len(data) - start - 8) // 2)):
        try:
            at = int.from_bytes(data[start + 8 + 2 * k:start + 10 + 2 * k], "big")
            size, at = _varint(data, at)
            rowid, at = _varint(data, at)
            yield rowid, _record(_payload(data, at, size, usable, page, count))
        except (IndexError, ValueError, struct.error, UnicodeDecodeError):
            continue


def _payload(data: bytes, at: int, size: int, usable: int, page, count: int) -> bytes:
    """A cell's payload, following its overflow pages (sections 1.6 and 2.1 of the format)."""
    most = usable - 35
    if size <= most:
        return data[at:at + size]
    least = (usable - 12) * 32 // 255 - 23
    local = least + (size - least) % (usable - 4)
    local = local if local <= most else least
    parts = [data[at:at + local]]
    got, nxt, seen = local, int.from_bytes(data[at + local:at + local + 4], "big"), set()
    while got < size:
        if not 1 <= nxt <= count or nxt in seen:
            raise ValueError("overflow chain broken")
        seen.add(nxt)
        over = page(nxt)
        chunk = over[4:min(usable, 4 + size - got)]
        if not chunk:
            raise ValueError("overflow page missing")
        parts.append(chunk)
        got += len(chunk)
        nxt = int.from_bytes(over[:4], "big")
    return b"".join(parts)


def _record(payload: bytes) -> list[int | float | str | bytes | None]:
    """The values of a record (section 2.1): serial types in a header, then the values."""
    header_size, at = _varint(payload, 0)
    if header_size > len(payload):
        raise ValueError("record header beyond the payload")
    types = []
    while at < header_size:
        t, at = _varint(payload, at)
        types.append(t)
    values: list[int | float | str | bytes | None] = []
    at = header_size
    for t in types:
        if t == 0:
            values.append(None)
        elif t in (1, 2, 3, 4, 5, 6):
            n = (1, 2, 3, 4, 6, 8)[t - 1]
            if at + n > len(payload):
                raise ValueError("value beyond the payload")
            values.append(int.from_bytes(payload[at:at + n], "big", signed=True))
            at += n
        elif t == 7:
            values.append(struct.unpack(">d", payload[at:at + 8])[0])
            at += 8
        elif t in (8, 9):
            values.append(t - 8)
        elif t >= 12:
            n = (t - 12) // 2
            if at + n > len(payload):
                raise ValueError("value beyond the payload")
            raw = payload[at:at + n]
            values.append(raw.decode("utf-8") if t % 2 else raw)
            at += n
        else:
            raise ValueError("reserved serial type")
    return values


def _classify(rowid: int, values: list, out: Salvage) -> None:
    """A reading (id, then READING_COLUMNS and its context; a store from before attempts has two columns fewer,
    one from before context columns one), an event (id, t_s, kind, instrument, message), or the meta row with
    the last reading's id."""
    if len(READING_COLUMNS) <= len(values) <= len(READING_COLUMNS) + 2 and values[0] is None:
        row = values[1:] + [None] * (len(READING_COLUMNS) + 2 - len(values))
        if all(isinstance(v, types) for v, types in zip(row, _READING_TYPES + [(str, type(None))])):
            out.readings.setdefault(rowid, tuple(float(v) if k in _REAL_COLUMNS and v is not None else v
                                                 for k, v in enumerate(row)))
    elif len(values) == 5 and values[0] is None and isinstance(values[1], NUMERIC) and isinstance(values[2], str) \
            and isinstance(values[3], (str, type(None))) and isinstance(values[4], str):
        out.events.setdefault(rowid, (float(values[1]), *values[2:]))
    elif len(values) == 2 and values[0] == LAST_READING_ID and isinstance(values[1], str) and values[1].isdigit():
        out.last_reading_id = int(values[1])
