"""The run store: one SQLite file per run holding every raw reading as it was taken.

Each reading is committed (WAL journal, synchronous=FULL) before the sequencer commands the
next motion, so a run killed at any point keeps every reading already taken. The store also
keeps the procedure and scenario text, the seed and the software version, so a run directory
says how it was made.
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator

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
    plan_index INTEGER
);
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
    "plan_index",
)


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


class RunStore:
    """A run's database file. Use :meth:`create` for a new run and :meth:`open` to read one."""

    FILENAME = "run.sqlite"

    def __init__(self, connection: sqlite3.Connection, path: Path):
        self._db = connection
        self.path = path

    @classmethod
    def create(cls, run_dir: Path, meta: dict[str, str]) -> "RunStore":
        run_dir.mkdir(parents=True, exist_ok=True)
        path = run_dir / cls.FILENAME
        if path.exists():
            raise FileExistsError(f"{path} already holds a run; choose another --out directory")
        store = cls(cls._connect(path), path)
        store._db.executescript(SCHEMA)
        store.set_meta(meta)
        return store

    @classmethod
    def open(cls, run_dir: Path) -> "RunStore":
        path = run_dir / cls.FILENAME
        if not path.exists():
            raise FileNotFoundError(f"no run store at {path}")
        return cls(cls._connect(path), path)

    @staticmethod
    def _connect(path: Path) -> sqlite3.Connection:
        db = sqlite3.connect(path, isolation_level=None)
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=FULL")
        return db

    def set_meta(self, meta: dict[str, str]) -> None:
        with self._transaction():
            self._db.executemany("INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)", [(k, str(v)) for k, v in meta.items()])

    def meta(self) -> dict[str, str]:
        return dict(self._db.execute("SELECT key, value FROM meta"))

    def add_readings(self, readings: Iterable[Reading]) -> None:
        """Append readings in one durable transaction (call before the next motion)."""
        rows = [tuple(getattr(r, c) for c in READING_COLUMNS) for r in readings]
        placeholders = ", ".join("?" for _ in READING_COLUMNS)
        with self._transaction():
            self._db.executemany(f"INSERT INTO readings({', '.join(READING_COLUMNS)}) VALUES ({placeholders})", rows)

    def add_event(self, t_s: float, kind: str, message: str, instrument: str | None = None) -> None:
        with self._transaction():
            self._db.execute("INSERT INTO events(t_s, kind, instrument, message) VALUES (?, ?, ?, ?)", (t_s, kind, instrument, message))

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
        """Planned readings already stored (each committed whole, so present means complete)."""
        return {row[0] for row in self._db.execute("SELECT DISTINCT plan_index FROM readings WHERE plan_index IS NOT NULL")}

    def skipped_plan_indices(self) -> set[int]:
        """Planned readings the fault policy skipped (they are done; their data are missing)."""
        return {row[0] for row in self._db.execute("SELECT DISTINCT plan_index FROM readings WHERE quantity = 'skipped'")}

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
