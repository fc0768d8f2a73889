"""The run store: one SQLite file per run holding every raw reading as it was taken.

Each reading is committed (WAL journal, synchronous=FULL) before the sequencer commands the
next motion, so a run killed at any point keeps every reading already taken. The store also
keeps the procedure and scenario text, the seed and the software version, so a run directory
says how it was made.

The file appears whole: :meth:`RunStore.create` builds schema and metadata in a temporary file
and links it into place, so a run killed in its first milliseconds leaves no store without its
procedure. A planned reading may take several attempts (a skipped reading is retaken on resume);
each attempt's readings share an ``attempt`` number, and a planned reading is done once one
attempt stored it without a skip.
"""

from __future__ import annotations

import os
import sqlite3
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Iterator

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
    attempt INTEGER
);
CREATE INDEX IF NOT EXISTS readings_by_plan ON readings(plan_index, attempt);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY,
    t_s REAL NOT NULL,
    kind TEXT NOT NULL,
    instrument TEXT,
    message TEXT NOT NULL
);
"""

READING_COLUMNS = (
    "t_s", "instrument", "quantity", "value", "unit", "point", "station", "sample", "segment",
    "commanded_angle_deg", "commanded_x_mm", "commanded_y_mm", "commanded_z_mm", "seating", "run", "direction",
    "plan_index", "attempt",
)
SKIPPED = "skipped"  # the quantity of a marker row: this attempt skipped the instrument's reading
REJECTED = "rejected"  # the quantity of a marker row: this attempt's readings contradict the commands; none is used
MARKERS = (SKIPPED, REJECTED)


class StoreUnusable(Exception):
    """A run directory's store that cannot be resumed (unfinished at creation, not a store)."""


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
    plan_index: int | None = None  # the planned reading this belongs to (see the sequencers)
    attempt: int | None = None  # readings of one attempt at a planned reading share it (None: stores before attempts)


class RunStore:
    """A run's database file. Use :meth:`create` for a new run and :meth:`open` to read one."""

    FILENAME = "run.sqlite"

    PARTIAL_PREFIX = ".run.sqlite.partial-"  # a store being created; never resumed, removed by the next `run --out`

    def __init__(self, connection: sqlite3.Connection, path: Path):
        self._db = connection
        self.path = path
        self._extra_meta: Callable[[], dict[str, str]] | None = None
        row = self._db.execute("SELECT MAX(attempt) FROM readings").fetchone()
        self._next_attempt = 0 if row[0] is None else int(row[0]) + 1

    @classmethod
    def create(cls, run_dir: Path, meta: dict[str, str]) -> "RunStore":
        """A new store with its schema and metadata, appearing at ``run.sqlite`` only when whole."""
        path = run_dir / cls.FILENAME
        if os.path.lexists(path):
            raise FileExistsError(f"{path} already holds a run; `rtcal resume {run_dir}` goes on, or choose another --out")
        partial = run_dir / f"{cls.PARTIAL_PREFIX}{os.getpid()}"
        try:
            os.unlink(partial)
        except FileNotFoundError:
            pass
        db = sqlite3.connect(partial, isolation_level=None)
        try:
            db.execute("BEGIN IMMEDIATE")
            for statement in SCHEMA.split(";"):
                if statement.strip():
                    db.execute(statement)
            db.executemany("INSERT INTO meta(key, value) VALUES (?, ?)", [(k, str(v)) for k, v in meta.items()])
            db.execute("COMMIT")
        finally:
            db.close()
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
        """An existing run's store; FileNotFoundError if there is none, StoreUnusable if it cannot be resumed."""
        path = run_dir / cls.FILENAME
        if not os.path.lexists(path):
            raise FileNotFoundError(f"no run store at {path}")
        if os.path.islink(path) or not path.is_file():
            raise StoreUnusable(f"{path} is not a regular file (a link or a directory); rtcal does not follow it")
        try:
            db = cls._connect(path)
            method = db.execute("SELECT value FROM meta WHERE key = 'method'").fetchone()
        except sqlite3.DatabaseError as exc:
            raise StoreUnusable(f"{path} is not a usable run store ({exc}); the run may have been killed while it "
                                "was being created, before any reading: start it again with `rtcal run … --out`") from None
        if method is None:
            db.close()
            raise StoreUnusable(f"{path} holds no procedure (killed while it was being created, before any reading): "
                                "start the run again with `rtcal run … --out`")
        columns = {row[1] for row in db.execute("PRAGMA table_info(readings)")}
        if "attempt" not in columns:  # a store from before attempts: each planned reading was attempted once
            db.execute("ALTER TABLE readings ADD COLUMN attempt INTEGER")
            db.execute("CREATE INDEX IF NOT EXISTS readings_by_plan ON readings(plan_index, attempt)")
        return cls(db, path)

    @staticmethod
    def _connect(path: Path) -> sqlite3.Connection:
        db = sqlite3.connect(path, isolation_level=None, timeout=10.0)
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=FULL")
        return db

    def keep_meta(self, provider: Callable[[], dict[str, str]] | None) -> None:
        """Write ``provider()``'s metadata in every later transaction, so that state outside the
        store (e.g. a simulated bench's fault-request counters) is as durable as the readings."""
        self._extra_meta = provider

    def new_attempt(self) -> int:
        """The number of a new attempt at a planned reading (one writer: the run directory is locked)."""
        self._next_attempt += 1
        return self._next_attempt - 1

    def set_meta(self, meta: dict[str, str]) -> None:
        with self._transaction():
            self._upsert_meta(meta)

    def _upsert_meta(self, meta: dict[str, str]) -> None:
        self._db.executemany("INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)", [(k, str(v)) for k, v in meta.items()])

    def meta(self) -> dict[str, str]:
        return dict(self._db.execute("SELECT key, value FROM meta"))

    def add_readings(self, readings: Iterable[Reading]) -> None:
        """Append readings in one durable transaction (call before the next motion)."""
        rows = [tuple(getattr(r, c) for c in READING_COLUMNS) for r in readings]
        placeholders = ", ".join("?" for _ in READING_COLUMNS)
        with self._transaction():
            self._db.executemany(f"INSERT INTO readings({', '.join(READING_COLUMNS)}) VALUES ({placeholders})", rows)
            self._keep()

    def add_event(self, t_s: float, kind: str, message: str, instrument: str | None = None) -> None:
        with self._transaction():
            self._db.execute("INSERT INTO events(t_s, kind, instrument, message) VALUES (?, ?, ?, ?)", (t_s, kind, instrument, message))
            self._keep()

    def _keep(self) -> None:
        if self._extra_meta is not None:
            self._upsert_meta(self._extra_meta())

    def readings(self, instrument: str | None = None, quantity: str | None = None) -> Iterator[Reading]:
        sql = f"SELECT {', '.join(READING_COLUMNS)} FROM readings"
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
            yield Reading(*row)

    def done_plan_indices(self) -> set[int]:
        """Planned readings stored by an attempt that skipped nothing and was not rejected (each
        attempt is committed whole)."""
        return {row[0] for row in self._db.execute(
            "SELECT DISTINCT plan_index FROM readings r WHERE plan_index IS NOT NULL AND quantity NOT IN (?, ?) AND NOT EXISTS "
            "(SELECT 1 FROM readings s WHERE s.plan_index = r.plan_index AND s.attempt IS r.attempt AND s.quantity IN (?, ?))",
            MARKERS + MARKERS)}

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

    def export_csv(self, directory: Path) -> tuple[int, int]:
        """readings.csv (every column) and events.csv, streamed row by row; returns the row counts."""
        import csv

        counts = []
        for name, columns, table in (("readings.csv", ("id",) + READING_COLUMNS, "readings"),
                                     ("events.csv", ("id", "t_s", "kind", "instrument", "message"), "events")):
            n = 0
            with (directory / name).open("w", newline="", encoding="utf-8") as fh:
                w = csv.writer(fh)
                w.writerow(columns)
                for row in self._db.execute(f"SELECT {', '.join(columns)} FROM {table} ORDER BY id"):
                    w.writerow("" if v is None else v for v in row)
                    n += 1
            counts.append(n)
        return counts[0], counts[1]

    def close(self) -> None:
        self._db.close()

    class _Tx:
        def __init__(self, db: sqlite3.Connection):
            self.db = db

        def __enter__(self) -> None:
            self.db.execute("BEGIN IMMEDIATE")

        def __exit__(self, exc_type, exc, tb) -> None:
            self.db.execute("COMMIT" if exc_type is None else "ROLLBACK")

    def _transaction(self) -> "_Tx":
        return RunStore._Tx(self._db)


def _fsync_dir(directory: Path) -> None:
    """Make a new directory entry durable (a power loss must not lose the store's name)."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)

