"""The run store: one SQLite file per run holding every raw reading as it was taken.

Each reading is committed (WAL journal, synchronous=FULL) before the engine commands the
next motion, so a run killed at any point keeps every reading already taken. A run on the
virtual clock (a simulation: no machine waits for the disk) commits each reading to the
operating system instead (:meth:`RunStore.sync_each_commit`): a killed process still keeps every
reading, only an OS crash or a power loss may lose the last ones. The store also
keeps the procedure and scenario text, the seed and the software version, so a run directory
says how it was made.

The file appears whole: :meth:`RunStore.create` builds schema and metadata in a temporary file
and links it into place, so a run killed in its first milliseconds leaves no store without its
procedure. A planned reading may take several attempts (a skipped reading is retaken on resume);
each attempt's readings share an ``attempt`` number, and a planned reading is done once one
attempt stored it without a skip.

A store is never deleted or overwritten unless it is proven empty (:func:`check_store`): one
that SQLite cannot read whole is damaged, left as it is, and its readings are salvaged page by
page (rtcal.store.salvage, `rtcal export`). A write the disk refuses (full, I/O error) is a
:class:`StoreWriteError` — an OSError, so the command exits 1 with the resume hint — and the
run's last status is written into space reserved for it when the run started.
"""

from __future__ import annotations

import csv
import errno
import json
import os
import sqlite3
from contextlib import closing, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Collection, Iterable, Iterator, Mapping, Protocol
from urllib.parse import quote

from drivers.addresses import redact_tokens
from rtcal.store.hint import resume_hint

# what every stored (instrument, quantity) is: its field of the instrument's description
# (drivers/interfaces.py), why it was read (purpose) and its unit; and which attempt each start of the run
# (0, +1 per resume) began with. docs/store.md says what every column means
DESCRIPTIONS_SCHEMA = """
CREATE TABLE IF NOT EXISTS descriptions (
    instrument TEXT NOT NULL,
    kind TEXT NOT NULL,
    quantity TEXT NOT NULL,
    field TEXT NOT NULL,
    purpose TEXT NOT NULL,
    unit TEXT NOT NULL,
    dtype TEXT NOT NULL,
    what TEXT NOT NULL,
    PRIMARY KEY (instrument, quantity)
);
CREATE TABLE IF NOT EXISTS starts (
    generation INTEGER PRIMARY KEY,
    first_attempt INTEGER NOT NULL,
    t_s REAL NOT NULL
)"""

SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS readings (
    id INTEGER PRIMARY KEY,
    t_s REAL NOT NULL,
    instrument TEXT NOT NULL,
    quantity TEXT NOT NULL,
    value REAL NOT NULL,
    unit TEXT NOT NULL,
    point INTEGER,
    station INTEGER,
    sample INTEGER,
    segment INTEGER,
    commanded_angle_deg REAL,
    commanded_x_mm REAL,
    commanded_y_mm REAL,
    commanded_z_mm REAL,
    seating INTEGER,
    run INTEGER,
    direction INTEGER,
    plan_index INTEGER,
    attempt INTEGER,
    context TEXT
);
CREATE INDEX IF NOT EXISTS readings_by_plan ON readings(plan_index, attempt);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY,
    t_s REAL NOT NULL,
    kind TEXT NOT NULL,
    instrument TEXT,
    message TEXT NOT NULL
);
""" + DESCRIPTIONS_SCHEMA

READING_COLUMNS = (
    "t_s", "instrument", "quantity", "value", "unit", "point", "station", "sample", "segment",
    "commanded_angle_deg", "commanded_x_mm", "commanded_y_mm", "commanded_z_mm", "seating", "run", "direction",
    "plan_index", "attempt",
)
# the type of each reading column, in the table's order (what salvage decodes a damaged page's record by)
READING_COLUMN_TYPES = {"t_s": "REAL", "instrument": "TEXT", "quantity": "TEXT", "value": "REAL", "unit": "TEXT",
                        "point": "INTEGER", "station": "INTEGER", "sample": "INTEGER", "segment": "INTEGER",
                        "commanded_angle_deg": "REAL", "commanded_x_mm": "REAL", "commanded_y_mm": "REAL",
                        "commanded_z_mm": "REAL", "seating": "INTEGER", "run": "INTEGER", "direction": "INTEGER",
                        "plan_index": "INTEGER", "attempt": "INTEGER"}
NOT_NULL = ("t_s", "instrument", "quantity", "value", "unit")
CONTEXT = "context"
"""The readings table's last column: a JSON object of what the method's plan declared beyond the columns above
(its context columns, e.g. ``{"ball_height_mm": 42.0}``), NULL when it declared none (every reading before it).
The store's meta ``context_columns`` says what each name is (docs/store.md)."""
CONTEXT_COLUMNS_KEY = "context_columns"
SKIPPED = "skipped"  # the quantity of a marker row: this attempt skipped the instrument's reading
REJECTED = "rejected"  # the quantity of a marker row: this attempt's readings contradict the commands; none is used
MARKERS = (SKIPPED, REJECTED)
LAST_READING_ID = "last_reading_id"  # meta key: the id of the last reading stored
EVENT_COLUMNS = ("t_s", "kind", "instrument", "message")


class StoreUnusable(Exception):
    """A run directory's store that cannot be resumed (a link, a directory, no procedure in it)."""


class StoreDamaged(StoreUnusable):
    """A store SQLite cannot read whole: left as it is; `rtcal export` salvages its readings."""


class StoreWriteError(OSError):
    """The disk refused a write to the store (full, quota, I/O error): a failure, not bad input."""


# SQLite's primary result codes for a file that the disk, not the program, let down
_DISK_CODES = {8: errno.EROFS, 10: errno.EIO, 11: errno.EIO, 13: errno.ENOSPC, 14: errno.EIO, 26: errno.EIO}


def _as_disk_failure(exc: sqlite3.Error, path: Path) -> StoreWriteError | None:
    """A StoreWriteError for SQLITE_FULL, IOERR, CORRUPT, READONLY, CANTOPEN, NOTADB; None otherwise."""
    code = getattr(exc, "sqlite_errorcode", None)
    if code is None or (code & 0xFF) not in _DISK_CODES:
        return None
    return StoreWriteError(_DISK_CODES[code & 0xFF], f"cannot write the run store: {exc}", str(path))


@dataclass(frozen=True)
class StoreCheck:
    """What a run.sqlite holds, found without changing a byte of it.

    ``kind``: "run" (whole, with its procedure), "empty" (whole, and no procedure, reading or
    event in it: safe to replace), "orphan" (whole, readings or events but no procedure),
    "damaged" (SQLite cannot read it whole, or not at all) or "foreign" (a link, a directory, a
    device: not opened). ``detail`` says what was found.
    """

    kind: str
    detail: str = ""

    def advice(self, run_dir: Path) -> str:
        """What the user can do about a store that is neither a run nor empty."""
        if self.kind == "damaged":
            return (f"`rtcal export {run_dir}` salvages every reading that can still be read (and counts those that "
                    "cannot)")
        if self.kind == "orphan":
            return f"`rtcal export {run_dir}` writes its readings and events as CSV"
        return "move it away"


def check_store(path: Path) -> StoreCheck:
    """Read ``path`` with SQLite, read-only, to the last page (``PRAGMA quick_check``)."""
    path = Path(path)
    if os.path.islink(path) or not path.is_file():
        return StoreCheck("foreign", "is not a regular file (a link, a directory or a device); rtcal does not follow it")
    # without a write-ahead log there is no writer and nothing uncommitted: read the file as it is
    # (`immutable`: SQLite creates no -wal or -shm beside it); with one, read-only through the log
    mode = "mode=ro" if os.path.lexists(f"{path}-wal") else "immutable=1"
    try:
        with closing(sqlite3.connect(f"file:{quote(str(path.absolute()))}?{mode}", uri=True, timeout=10.0)) as db:
            verdict = db.execute("PRAGMA quick_check(1)").fetchone()[0]
            if verdict != "ok":
                return StoreCheck("damaged", f"is damaged ({verdict})")
            tables = {row[0] for row in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            rows = sum(db.execute(f"SELECT COUNT(*) FROM {t}").fetchone()[0] for t in ("readings", "events") if t in tables)
            method = db.execute("SELECT value FROM meta WHERE key = 'method'").fetchone() if "meta" in tables else None
    except sqlite3.DatabaseError as exc:  # not a database, malformed, cut short, unreadable
        return StoreCheck("damaged", f"is damaged: SQLite cannot read it whole ({exc})")
    if method is not None:
        return StoreCheck("run", f"holds a run ({method[0]})")
    if rows:
        return StoreCheck("orphan", f"holds readings or events ({rows} rows) but no procedure")
    return StoreCheck("empty", "holds no procedure, no reading and no event")


@dataclass(frozen=True)
class Reading:
    """One raw value with its time, instrument and the commanded state it was taken in."""

    t_s: float
    instrument: str
    quantity: str
    value: float
    unit: str
    point: int | None = None
    station: int | None = None
    sample: int | None = None
    segment: int | None = None
    commanded_angle_deg: float | None = None
    commanded_x_mm: float | None = None
    commanded_y_mm: float | None = None
    commanded_z_mm: float | None = None
    seating: int | None = None
    run: int | None = None
    direction: int | None = None
    plan_index: int | None = None  # the planned reading this belongs to (see each method's plan)
    attempt: int | None = None  # readings of one attempt at a planned reading share it (None: stores before attempts)
    context: Mapping[str, Any] | None = field(default=None, compare=False, hash=False)
    """The method's declared context columns' values (None: it declared none), as the store's ``context`` column."""


FIXED_CONTEXT = frozenset(READING_COLUMNS[5:]) | {CONTEXT}
"""The keys of a plan entry's context that are the readings table's own columns; every other key is one of the
method's declared context columns and goes into ``context`` (:func:`row_context`)."""


def row_context(context: Mapping[str, Any], declared: Collection[str] = ()) -> dict[str, Any]:
    """A plan's context as the keyword arguments of :class:`Reading`: the store's own columns as they are, the
    method's ``declared`` context columns gathered under ``context`` (sorted, so a store's rows never differ by
    the order a plan wrote them in). A key that is neither is a ValueError naming it: a plan's mistake."""
    extra = {k: v for k, v in context.items() if k not in FIXED_CONTEXT}
    undeclared = sorted(k for k in extra if k not in declared)
    if undeclared:
        raise ValueError(f"the plan's context names {', '.join(map(repr, undeclared))}, which is neither a column of the "
                         f"store ({', '.join(sorted(FIXED_CONTEXT - {CONTEXT}))}) nor one of the method's declared "
                         f"context_columns ({', '.join(sorted(declared)) or 'none'})")
    fixed = {k: v for k, v in context.items() if k in FIXED_CONTEXT}
    if extra:
        fixed[CONTEXT] = {**(fixed.get(CONTEXT) or {}), **{k: extra[k] for k in sorted(extra)}}
    return fixed


def _context_json(context: Mapping[str, Any] | None) -> str | None:
    return None if not context else json.dumps(dict(context), sort_keys=True, allow_nan=False)


def _context_of(text: str | None) -> dict[str, Any] | None:
    return None if text is None else json.loads(text)


DESCRIPTION_COLUMNS = ("instrument", "kind", "quantity", "field", "purpose", "unit", "dtype", "what")


@dataclass(frozen=True)
class StoredDescription:
    """One row of the store's ``descriptions`` table: what an instrument's stored quantity is."""

    instrument: str
    kind: str
    quantity: str
    field: str
    purpose: str
    unit: str
    dtype: str
    what: str


def descriptions_of(instrument: str, kind: str, fields: Iterable[Any]) -> list[StoredDescription]:
    """Every quantity an instrument's described fields (drivers.interfaces.FieldDescription) may be stored
    under, one per purpose."""
    from drivers.interfaces import PURPOSES

    return [StoredDescription(instrument, kind, f.quantity(p), f.name, p, f.unit, f.dtype, f.what)
            for f in fields for p in PURPOSES]


def stored_descriptions(db: sqlite3.Connection) -> dict[tuple[str, str], StoredDescription]:
    """(instrument, quantity) → what it is, as a store's ``descriptions`` table says (empty before it)."""
    if db.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'descriptions'").fetchone() is None:
        return {}
    rows = db.execute(f"SELECT {', '.join(DESCRIPTION_COLUMNS)} FROM descriptions")
    return {(d.instrument, d.quantity): d for d in (StoredDescription(*row) for row in rows)}


def described_in(db: sqlite3.Connection) -> dict[tuple[str, str], StoredDescription]:
    """What every (instrument, quantity) of a store is: its descriptions, over — for an instrument a store
    written before them does not describe — the kind tables (drivers/interfaces.py) of the instruments
    a procedure names (the same names and units: the plans have always stored them so)."""
    from drivers.factory import KIND_OF
    from drivers.kinds import describe_kind

    found = {(d.instrument, d.quantity): d for name, kind in KIND_OF.items()
             for d in descriptions_of(name, kind, describe_kind(kind).values())}
    return {**found, **stored_descriptions(db)}


def stored_quantity(described: dict[tuple[str, str], StoredDescription], instrument: str, field: str, purpose: str = "") -> str:
    """The quantity ``instrument``'s ``field`` read for ``purpose`` is stored under."""
    for d in described.values():
        if d.instrument == instrument and d.field == field and d.purpose == purpose:
            return d.quantity
    raise KeyError(f"{instrument}.{field} ({purpose or 'reading'}) is not described in the store")


class RunReadings(Protocol):
    """A run's store as a method's analysis reads it (read-only): its readings, which of them count, what
    each stored quantity is, its metadata. :class:`RunStore` is one; rtcal.api names it for plugins."""

    def readings(self, instrument: str | None = None, quantity: str | None = None) -> Iterator[Reading]:
        """Every row as stored (markers, rejected and superseded attempts included), in store order."""
        ...

    def counted(self, instrument: str | None = None, field: str | None = None, purpose: str = "",
                whole_only: bool = False) -> list[Reading]:
        """The readings that count (:func:`counted_attempts`), in store order; ``field`` (with its ``purpose``)
        names the described field of ``instrument`` they were stored for."""
        ...

    def quantity_of(self, instrument: str, field: str, purpose: str = "") -> str:
        """The quantity ``instrument``'s ``field`` read for ``purpose`` is stored under."""
        ...

    def described(self) -> dict[tuple[str, str], StoredDescription]: ...

    def done_plan_indices(self) -> set[int]: ...

    def meta(self) -> dict[str, str]: ...


def counted_attempts(attempts: Iterable[tuple[int | None, int | None, bool, bool]]) -> dict[int | None, tuple[int | None, bool]]:
    """The one rule of which readings count, from every stored attempt's (plan index, attempt, skipped
    something, rejected): per planned reading, one attempt — the last stored whole (nothing skipped, not
    rejected), else the last not rejected (what it took before a skip: an instrument that read still counts);
    a rejected attempt's readings (they contradicted the commands) never count. Returns plan index → (its
    counted attempt, whether that attempt is whole). A planned reading retaken after a partial attempt
    counts once, never averaged with it."""
    whole: dict[int | None, int | None] = {}
    partial: dict[int | None, int | None] = {}

    def later(a: int | None, b: int | None) -> bool:
        return (-1 if a is None else a) > (-1 if b is None else b)

    for plan_index, attempt, skipped, rejected in attempts:
        if rejected:
            continue
        chosen = partial if skipped else whole
        if plan_index not in chosen or later(attempt, chosen[plan_index]):
            chosen[plan_index] = attempt
    counted = {k: (a, False) for k, a in partial.items()}
    counted.update({k: (a, True) for k, a in whole.items()})
    return counted


class RunStore:
    """A run's database file. Use :meth:`create` for a new run and :meth:`open` to read one."""

    FILENAME = "run.sqlite"

    PARTIAL_PREFIX = ".run.sqlite.partial-"  # a store being created; never resumed, removed by the next `run --out`
    RESERVE_NAME = ".run.sqlite.reserve"  # disk space held back for the run's last status (see reserve_space)
    RESERVE_BYTES = 256 * 1024  # the status transaction needs a few pages of the write-ahead log

    def __init__(self, connection: sqlite3.Connection, path: Path):
        self._db = connection
        self.path = path
        self._extra_meta: Callable[[], dict[str, str]] | None = None
        self._more_meta: list[Callable[[], dict[str, str]]] = []
        self._reserve: Path | None = None
        row = self._db.execute("SELECT MAX(attempt) FROM readings").fetchone()
        self._next_attempt = 0 if row[0] is None else int(row[0]) + 1
        # a store opened read-only from before context columns has none: its readings declared none
        self._context = f", {CONTEXT}" if any(r[1] == CONTEXT for r in self._db.execute("PRAGMA table_info(readings)")) \
            else ", NULL"

    @classmethod
    def create(cls, run_dir: Path, meta: dict[str, str]) -> "RunStore":
        """A new store with its schema and metadata, appearing at ``run.sqlite`` only when whole."""
        path = run_dir / cls.FILENAME
        if os.path.lexists(path):
            raise FileExistsError(f"{path} already holds a run; {resume_hint(run_dir)}, or choose another --out")
        partial = run_dir / f"{cls.PARTIAL_PREFIX}{os.getpid()}"
        try:
            os.unlink(partial)
        except FileNotFoundError:
            pass
        try:
            with closing(sqlite3.connect(partial, isolation_level=None)) as db:
                db.execute("BEGIN IMMEDIATE")
                for statement in SCHEMA.split(";"):
                    if statement.strip():
                        db.execute(statement)
                db.executemany("INSERT INTO meta(key, value) VALUES (?, ?)", [(k, redact_tokens(str(v))) for k, v in meta.items()])
                db.execute("COMMIT")
        except sqlite3.Error as exc:
            os.unlink(partial)
            raise _as_disk_failure(exc, path) or exc from None
        try:
            os.link(partial, path)  # unlike rename, never replaces an existing store
        except FileExistsError:
            raise FileExistsError(f"{path} already holds a run; choose another --out directory") from None
        finally:
            os.unlink(partial)
        _fsync_dir(run_dir)
        return cls(cls._connect(path), path)

    @classmethod
    def open(cls, run_dir: Path) -> "RunStore":
        """An existing run's store; FileNotFoundError if there is none, StoreDamaged if SQLite cannot
        read it whole, StoreUnusable if it holds no procedure. The file is checked read-only first."""
        path = run_dir / cls.FILENAME
        if not os.path.lexists(path):
            raise FileNotFoundError(f"no run store at {path}")
        found = check_store(path)
        if found.kind == "damaged":
            raise StoreDamaged(f"{path} {found.detail}; it is left as it is: {found.advice(run_dir)}")
        if found.kind == "empty":
            raise StoreUnusable(f"{path} {found.detail}: start the run again with `rtcal run … --out {run_dir}` "
                                "(which replaces it)")
        if found.kind != "run":
            raise StoreUnusable(f"{path} {found.detail}: not a run to go on with; {found.advice(run_dir)}")
        db = cls._connect(path)
        try:
            columns = {row[1] for row in db.execute("PRAGMA table_info(readings)")}
            if "attempt" not in columns:  # a store from before attempts: each planned reading was attempted once
                db.execute("ALTER TABLE readings ADD COLUMN attempt INTEGER")
                db.execute("CREATE INDEX IF NOT EXISTS readings_by_plan ON readings(plan_index, attempt)")
            if CONTEXT not in columns:  # a store from before context columns: its readings declared none (NULL)
                db.execute(f"ALTER TABLE readings ADD COLUMN {CONTEXT} TEXT")
            tables = {row[0] for row in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            if "descriptions" not in tables:  # a store from before descriptions: a resume describes its instruments
                for statement in DESCRIPTIONS_SCHEMA.split(";"):
                    db.execute(statement)
        except sqlite3.Error as exc:
            db.close()
            raise _as_disk_failure(exc, path) or StoreDamaged(f"{path}: {exc}") from None
        return cls(db, path)

    @staticmethod
    def _connect(path: Path) -> sqlite3.Connection:
        db = sqlite3.connect(path, isolation_level=None, timeout=10.0)
        try:
            db.execute("PRAGMA journal_mode=WAL")  # writes the file's header: a full disk can refuse it
            db.execute("PRAGMA synchronous=FULL")
        except sqlite3.Error as exc:
            db.close()
            raise _as_disk_failure(exc, path) or StoreDamaged(f"{path}: {exc}") from None
        return db

    def sync_each_commit(self, to_disk: bool) -> None:
        """Where a commit has gone when it returns: to the disk (synchronous=FULL, the default: a power loss keeps
        every reading), or, for a run on the virtual clock, to the operating system (synchronous=NORMAL: in WAL
        mode a killed process keeps every committed reading; an OS crash or a power loss may lose the last
        ones, which `rtcal resume` takes again). A sync costs milliseconds: nothing beside a reading in real
        time, minutes of a simulated run of 36 000 readings (issue 43)."""
        try:
            self._db.execute(f"PRAGMA synchronous={'FULL' if to_disk else 'NORMAL'}")
        except sqlite3.Error as exc:
            raise _as_disk_failure(exc, self.path) or exc from None

    def reserve_space(self) -> None:
        """Hold back disk space beside the store (a run or resume calls this before measuring), so
        that a disk that fills up mid-run still takes the run's last status (:meth:`set_final_meta`)."""
        reserve = self.path.parent / self.RESERVE_NAME
        fd = os.open(reserve, os.O_WRONLY | os.O_CREAT | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0), 0o600)
        try:
            os.posix_fallocate(fd, 0, self.RESERVE_BYTES)
        except OSError as exc:
            os.unlink(reserve)
            raise OSError(exc.errno, f"cannot set {self.RESERVE_BYTES // 1024} KiB aside for the run's status: "
                                     f"{exc.strerror}", str(reserve)) from None
        finally:
            os.close(fd)
        self._reserve = reserve

    def _give_up_reserve(self) -> None:
        if self._reserve is not None:
            try:
                os.unlink(self._reserve)
            except FileNotFoundError:
                pass
            self._reserve = None

    def set_final_meta(self, meta: dict[str, str]) -> bool:
        """The run's last status (stopped, failed): on a full disk the reserve is given up for it.
        False if even then the disk refused it (the caller says so; the readings are unaffected)."""
        for _ in range(2):
            try:
                self.set_meta(meta)
                return True
            except StoreWriteError:
                if self._reserve is None:
                    return False
                self._give_up_reserve()
        return False

    def keep_meta(self, provider: Callable[[], dict[str, str]] | None) -> None:
        """Write ``provider()``'s metadata in every later transaction, so that state outside the
        store (e.g. a simulated bench's fault-request counters) is as durable as the readings."""
        self._extra_meta = provider

    def keep_meta_also(self, provider: Callable[[], dict[str, str]]) -> None:
        """Another provider for :meth:`keep_meta`'s purpose (e.g. where the engine is: the live view's `current`)."""
        self._more_meta.append(provider)

    def new_attempt(self) -> int:
        """The number of a new attempt at a planned reading (one writer: the run directory is locked)."""
        self._next_attempt += 1
        return self._next_attempt - 1

    def set_meta(self, meta: dict[str, str]) -> None:
        with self._transaction():
            self._upsert_meta(meta)

    def _upsert_meta(self, meta: dict[str, str]) -> None:
        # no token of any kind is stored (an address's token=… is redacted): a copied run commands nothing
        self._db.executemany("INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)",
                             [(k, redact_tokens(str(v))) for k, v in meta.items()])

    def meta(self) -> dict[str, str]:
        return dict(self._db.execute("SELECT key, value FROM meta"))

    def add_readings(self, readings: Iterable[Reading]) -> None:
        """Append readings in one durable transaction (call before the next motion)."""
        rows = [(*(getattr(r, c) for c in READING_COLUMNS), _context_json(r.context)) for r in readings]
        placeholders = ", ".join("?" for _ in range(len(READING_COLUMNS) + 1))
        with self._transaction():
            self._db.executemany(f"INSERT INTO readings({', '.join(READING_COLUMNS)}, {CONTEXT}) VALUES ({placeholders})",
                                 rows)
            # how many readings there are, where a damaged store's salvage can still find it (ids run 1, 2, …)
            self._db.execute(f"INSERT OR REPLACE INTO meta(key, value) VALUES ('{LAST_READING_ID}', "
                             "(SELECT MAX(id) FROM readings))")
            self._keep()

    def add_descriptions(self, rows: Iterable[StoredDescription]) -> None:
        """What each (instrument, quantity) a run stores is; a resume's descriptions replace the earlier ones."""
        with self._transaction():
            self._db.executemany("INSERT OR REPLACE INTO descriptions(instrument, kind, quantity, field, purpose, unit, "
                                 "dtype, what) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                                 [tuple(getattr(d, c) for c in DESCRIPTION_COLUMNS) for d in rows])

    def add_start(self, generation: int, t_s: float) -> None:
        """A start of the run (0, +1 per resume) begins with the next attempt (the first start so numbered is kept)."""
        with self._transaction():
            self._db.execute("INSERT OR IGNORE INTO starts(generation, first_attempt, t_s) VALUES (?, ?, ?)",
                             (generation, self._next_attempt, t_s))

    def start_of(self, attempt: int | None) -> int | None:
        """The start (0, +1 per resume) an attempt was taken in; None where the store does not say (a store
        from before starts were recorded, a reading outside any attempt)."""
        if attempt is None or not self._has_table("starts"):
            return None
        row = self._db.execute("SELECT MAX(generation) FROM starts WHERE first_attempt <= ?", (attempt,)).fetchone()
        return None if row[0] is None else int(row[0])

    def _has_table(self, name: str) -> bool:
        return self._db.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = ?", (name,)).fetchone() is not None

    def descriptions(self) -> dict[tuple[str, str], StoredDescription]:
        """(instrument, quantity) → what it is; empty for a store from before descriptions."""
        return stored_descriptions(self._db)

    def described(self) -> dict[tuple[str, str], StoredDescription]:
        """What every (instrument, quantity) is (:func:`described_in`)."""
        return described_in(self._db)

    def add_event(self, t_s: float, kind: str, message: str, instrument: str | None = None) -> None:
        with self._transaction():
            self._db.execute("INSERT INTO events(t_s, kind, instrument, message) VALUES (?, ?, ?, ?)",
                             (t_s, kind, instrument, redact_tokens(message)))
            self._keep()

    def _keep(self) -> None:
        if self._extra_meta is not None:
            self._upsert_meta(self._extra_meta())
        for provider in self._more_meta:
            self._upsert_meta(provider())

    def readings(self, instrument: str | None = None, quantity: str | None = None) -> Iterator[Reading]:
        sql = f"SELECT {', '.join(READING_COLUMNS)}{self._context} FROM readings"
        clauses, args = [], []
        if instrument is not None:
            clauses.append("instrument = ?")
            args.append(instrument)
        if quantity is not None:
            clauses.append("quantity = ?")
            args.append(quantity)
        if clauses:
            sql += " WHERE " + " AND ".join(clauses)
        for row in self._db.execute(sql + " ORDER BY id", args):
            yield Reading(*row[:-1], context=_context_of(row[-1]))  # type: ignore[misc]  # the columns, then context

    def counted(self, instrument: str | None = None, field: str | None = None, purpose: str = "",
                whole_only: bool = False) -> list[Reading]:
        """The readings that count (:func:`counted_attempts`: per planned reading the last attempt stored whole,
        else the last not rejected), markers left out, in store order; ``whole_only``: only those of an attempt
        stored whole. ``field`` (with its ``purpose``) names the described field of ``instrument``."""
        quantity = None if field is None or instrument is None else self.quantity_of(instrument, field, purpose)
        chosen = counted_attempts((k, a, bool(s), bool(r)) for k, a, s, r in self._db.execute(
            "SELECT plan_index, attempt, MAX(quantity = ?), MAX(quantity = ?) FROM readings GROUP BY plan_index, attempt",
            (SKIPPED, REJECTED)))
        return [r for r in self.readings(instrument, quantity) if r.quantity not in MARKERS
                and (c := chosen.get(r.plan_index)) is not None and c[0] == r.attempt and (c[1] or not whole_only)]

    def quantity_of(self, instrument: str, field: str, purpose: str = "") -> str:
        """The quantity ``instrument``'s ``field`` read for ``purpose`` is stored under (KeyError: not described)."""
        return stored_quantity(self.described(), instrument, field, purpose)

    def done_plan_indices(self) -> set[int]:
        """Planned readings stored by an attempt that skipped nothing and was not rejected (each
        attempt is committed whole)."""
        return {row[0] for row in self._db.execute(
            "SELECT DISTINCT plan_index FROM readings r WHERE plan_index IS NOT NULL AND quantity NOT IN (?, ?) AND NOT EXISTS "
            "(SELECT 1 FROM readings s WHERE s.plan_index = r.plan_index AND s.attempt IS r.attempt AND s.quantity IN (?, ?))",
            MARKERS + MARKERS)}

    def readings_stored_twice(self) -> int:
        """Readings beyond the first with the same planned reading, attempt, instrument, quantity and
        sample: none in a store rtcal wrote (an attempt is stored whole, once), so a sign of editing."""
        return int(self._db.execute(
            "SELECT COALESCE(SUM(n - 1), 0) FROM (SELECT COUNT(*) AS n FROM readings WHERE plan_index IS NOT NULL "
            "GROUP BY plan_index, attempt, instrument, quantity, sample HAVING n > 1)").fetchone()[0])

    def skipped_plan_indices(self) -> set[int]:
        """Planned readings whose every attempt so far skipped something or was rejected (resume retakes them)."""
        skipped = {row[0] for row in self._db.execute("SELECT DISTINCT plan_index FROM readings WHERE quantity IN (?, ?)", MARKERS)}
        return skipped - self.done_plan_indices()

    def rejected_attempts(self) -> set[tuple[int | None, int | None]]:
        """(plan index, attempt) of every attempt whose readings contradicted the commands: kept, never used."""
        return {(row[0], row[1]) for row in self._db.execute(
            "SELECT DISTINCT plan_index, attempt FROM readings WHERE quantity = ?", (REJECTED,))}

    def last_time_s(self) -> float:
        """Time of the last reading or event (0 for an empty run): where a resumed clock goes on."""
        row = self._db.execute("SELECT MAX(t) FROM (SELECT MAX(t_s) AS t FROM readings UNION ALL SELECT MAX(t_s) FROM events)").fetchone()
        return float(row[0] or 0.0)

    def max_segment(self) -> int:
        """The highest tracking segment stored so far, −1 if none."""
        row = self._db.execute("SELECT MAX(segment) FROM readings").fetchone()
        return -1 if row[0] is None else int(row[0])

    def events(self) -> list[dict]:
        cur = self._db.execute("SELECT t_s, kind, instrument, message FROM events ORDER BY id")
        return [dict(zip(("t_s", "kind", "instrument", "message"), row)) for row in cur]

    def instrument_readings(self) -> int:
        """Raw instrument values stored (what `rtcal export` writes, skip markers apart)."""
        return int(self._db.execute("SELECT COUNT(*) FROM readings WHERE quantity <> ?", (SKIPPED,)).fetchone()[0])

    def export_csv(self, directory: Path) -> tuple[int, int]:
        """readings.csv (every column), events.csv and descriptions.csv (what each stored quantity is:
        docs/store.md), streamed row by row; returns the readings' and events' row counts."""
        readings = self._db.execute(f"SELECT id, {', '.join(READING_COLUMNS)}{self._context} FROM readings ORDER BY id")
        events = self._db.execute(f"SELECT id, {', '.join(EVENT_COLUMNS)} FROM events ORDER BY id")
        counts = write_csv(directory / "readings.csv", ("id",) + READING_COLUMNS + (CONTEXT,), readings), \
            write_csv(directory / "events.csv", ("id",) + EVENT_COLUMNS, events)
        stored = {(i, q) for i, q in self._db.execute("SELECT DISTINCT instrument, quantity FROM readings")}
        described = [d for key, d in sorted(self.described().items()) if key in stored]
        write_csv(directory / "descriptions.csv", DESCRIPTION_COLUMNS,
                  (tuple(getattr(d, c) for c in DESCRIPTION_COLUMNS) for d in described))
        return counts

    def close(self) -> None:
        self._db.close()
        self._give_up_reserve()

    @contextmanager
    def _transaction(self) -> Iterator[None]:
        """One durable transaction; rolled back on any failure, a disk's refusal raised as StoreWriteError."""
        try:
            self._db.execute("BEGIN IMMEDIATE")
            yield
            self._db.execute("COMMIT")
        except BaseException as exc:
            if self._db.in_transaction:  # SQLite may have rolled back itself (SQLITE_FULL, IOERR)
                try:
                    self._db.execute("ROLLBACK")
                except sqlite3.Error:
                    pass
            failure = _as_disk_failure(exc, self.path) if isinstance(exc, sqlite3.Error) else None
            if failure is not None:
                raise failure from None
            raise


def write_csv(path: Path, columns: tuple[str, ...], rows: Iterable[tuple]) -> int:
    """``rows`` (None as an empty cell) under a header, through rtcal.outputs; returns the row count."""
    from rtcal.outputs import output_file

    n = 0
    with output_file(path) as tmp, tmp.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for row in rows:
            w.writerow("" if v is None else v for v in row)
            n += 1
    return n


def _fsync_dir(directory: Path) -> None:
    """Make a new directory entry durable (a power loss must not lose the store's name)."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
