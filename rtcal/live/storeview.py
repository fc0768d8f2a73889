"""A run as the live view sees it, read from its SQLite store read-only.

Every poll opens a fresh read-only connection (``mode=ro``) and reads one snapshot in one read
transaction: in WAL mode a reader never blocks the engine's writes, and nothing here writes, so
`rtcal view` can watch a run of another process, in progress or finished, without touching it.
What only grows (the planned readings done, the latest value of each instrument, completion
times for the rate, the progress grid) is accumulated from the readings added since the last poll,
so a poll costs the new rows, not the whole store nor every planned reading: the count done is a
running total and the grid changes only in the rows a new reading touched.

The engine writes its state into the store's meta (``engine_state``, ``planned_readings``,
``current``, and ``operator_waiting`` while an operator step waits for a person); a store written
before it knew them is read from ``status``, the stored procedure and the last reading instead.
"""

from __future__ import annotations

import bisect
import json
import math
import os
import sqlite3
import threading
import time
from collections import deque
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import quote

from rtcal.store.runstore import MARKERS, REJECTED, RunStore, StoredDescription, described_in

STATES = ("starting", "running", "paused", "stopping", "finished", "failed", "aborted")
FINAL_STATES = ("finished", "failed", "aborted")
# the runner's `status` before the engine wrote `engine_state`
STATUS_STATES = {"running": "running", "solved": "finished", "measured": "finished", "aborted": "aborted",
                 "interrupted": "aborted"}
REPORT_FILES = ("report.pdf", "report.html")  # the only files of the run directory the view serves
READING_FIELDS = ("id", "t_s", "instrument", "quantity", "value", "unit", "plan_index", "attempt", "run", "direction",
                  "commanded_angle_deg", "station", "point", "seating", "sample")
EVENT_FIELDS = ("id", "t_s", "kind", "instrument", "message")
RATE_WINDOW = 50  # completions the rate (and so the ETA) is taken from
MARKING_KEYS = ("seed", "simulators", "operator_address", "machine_identity", "rehearsed")  # what the marking reads
_MARKS = ", ".join(f"'{m}'" for m in MARKERS)


def open_read_only(path: Path) -> sqlite3.Connection:
    """A read-only connection that never creates a file, blocks the writer or changes a byte.

    While a writer has the store open (its -wal and -shm beside it) ``mode=ro`` reads through
    them; without them ``mode=ro`` would create both, so a closed store is read as ``immutable``
    (as :func:`rtcal.store.runstore.check_store` does). A poll that races a writer opening the store
    reads a moment's old snapshot; the next poll opens afresh."""
    live = os.path.lexists(f"{path}-wal") and os.path.lexists(f"{path}-shm")
    mode = "mode=ro" if live else "immutable=1"
    db = sqlite3.connect(f"file:{quote(str(path.absolute()))}?{mode}", uri=True, timeout=2.0, isolation_level=None,
                         check_same_thread=False)
    columns = {row[1] for row in db.execute("PRAGMA main.table_info(readings)")}
    if columns and "attempt" not in columns:  # a store from before attempts: each planned reading attempted once
        db.execute("CREATE TEMP VIEW readings AS SELECT *, NULL AS attempt FROM main.readings")  # in memory only
    db.execute("PRAGMA query_only=1")
    return db


@dataclass
class _Planned:
    """What is known of one planned reading: its labels and whether an attempt stored it whole."""

    run: int | None
    direction: int | None
    target_deg: float | None
    point: int | None
    station: int | None
    seating: int | None
    status: str = "pending"  # done | rejected | skipped (the last attempt's fate until one is done)


class _Progress:
    """The planned readings by row (run and direction, or CMM point) and column (target angle, or station),
    kept as readings arrive: a planned reading that changes touches its one cell and its row; the page's
    grid is rebuilt only in the rows touched since it was last asked for."""

    def __init__(self) -> None:
        self.by_run: bool | None = None
        self.plans: dict[int, _Planned] = {}
        self.columns: dict[str, float] = {}
        self.cols_sorted: list[str] = []
        self.order: dict[str, tuple] = {}
        self.rows_sorted: list[str] = []
        self.cells: dict[str, dict[str, dict[int, str]]] = {}  # row → column → {plan index: status}
        self.row_out: dict[str, dict[str, Any]] = {}
        self.dirty: set[str] = set()
        self.out: dict[str, Any] | None = None

    def place(self, k: int, p: _Planned) -> tuple[str, str, tuple, float]:
        if self.by_run:
            arrow = "↑" if (p.direction or 0) > 0 else "↓"
            row = (f"seating {p.seating + 1} · " if p.seating else "") + f"run {(p.run or 0) + 1} {arrow}"
            col_key = p.target_deg if p.target_deg is not None else float(p.station or 0)
            return row, f"{col_key:g}°", (p.seating or 0, p.run or 0, -(p.direction or 0)), col_key
        row = (f"mount {p.seating + 1} · " if p.seating else "") + f"point {(p.point or 0) + 1}"
        return row, f"station {(p.station or 0) + 1}", (p.seating or 0, p.point or 0), float(p.station or 0)

    def update(self, k: int, p: _Planned) -> None:
        """A planned reading seen for the first time or whose status changed."""
        self.plans[k] = p
        by_run = bool(self.by_run) or (p.run is not None and p.direction is not None)
        if by_run != self.by_run:  # the grid's kind is decided (or changes): lay every planned reading out again
            self.by_run = by_run
            self.columns, self.cols_sorted, self.order, self.rows_sorted, self.cells = {}, [], {}, [], {}
            self.row_out = {}
            for index in sorted(self.plans):
                self._put(index, self.plans[index])
        else:
            self._put(k, p)
        self.out = None

    def _put(self, k: int, p: _Planned) -> None:
        row, col, row_key, col_key = self.place(k, p)
        if row not in self.order:
            self.order[row] = row_key
            bisect.insort(self.rows_sorted, row, key=lambda r: self.order[r])
            self.cells[row] = {}
        if col not in self.columns:
            self.columns[col] = col_key
            bisect.insort(self.cols_sorted, col, key=lambda c: self.columns[c])
            self.dirty.update(self.rows_sorted)  # every row gains the column
        self.cells[row].setdefault(col, {})[k] = p.status
        self.dirty.add(row)

    def _cell(self, statuses: dict[int, str]) -> str:
        """Done once any planned reading of the cell is; else the latest one's status."""
        return "done" if "done" in statuses.values() else statuses[max(statuses)]

    def snapshot(self) -> dict[str, Any] | None:
        if not self.plans:
            return None
        if self.out is None:
            for row in self.dirty:
                values = {col: self._cell(st) for col, st in self.cells[row].items()}
                self.row_out[row] = {"label": row, "cells": [values.get(c, "pending") for c in self.cols_sorted],
                                     "done": sum(1 for v in values.values() if v == "done")}
            self.dirty.clear()
            self.out = {"axis": "target" if self.by_run else "station", "columns": list(self.cols_sorted),
                        "rows": [self.row_out[r] for r in self.rows_sorted]}
        return self.out


@dataclass
class _Accumulated:
    last_id: int = 0
    plans: dict[int, _Planned] = field(default_factory=dict)
    done: int = 0  # planned readings stored whole: a running total
    progress: _Progress = field(default_factory=_Progress)
    completions: deque = field(default_factory=lambda: deque(maxlen=RATE_WINDOW))  # (reading id, t_s)
    latest: dict[tuple[str, str], dict[str, Any]] = field(default_factory=dict)
    newest_t_s: float | None = None
    described: dict[tuple[str, str], StoredDescription] = field(default_factory=dict)


class StoreView:
    """The live view's reader of one run directory; thread-safe, shared by every connection."""

    def __init__(self, run_dir: Path, min_interval_s: float = 0.25):
        self.run_dir = Path(run_dir)
        self.path = self.run_dir / RunStore.FILENAME
        self.min_interval_s = min_interval_s
        self._lock = threading.Lock()
        self._acc = _Accumulated()
        self._state: dict[str, Any] | None = None
        self._state_at = 0.0
        self._planned_cache: tuple[str, int | None] | None = None
        self._result_cache: tuple[tuple[int, int], dict[str, Any] | None] | None = None
        self._result_stamp: tuple[int, int] | None = None
        self._marking_cache: tuple[str, str] | None = None

    # -- connections ------------------------------------------------------------------------
    def _connect(self) -> sqlite3.Connection | None:
        if not self.path.is_file():
            return None
        try:
            return open_read_only(self.path)
        except sqlite3.Error:
            return None

    # -- the state ----------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        """``/api/state``: recomputed at most every ``min_interval_s`` whoever asks."""
        with self._lock:
            now = time.monotonic()
            if self._state is None or now - self._state_at >= self.min_interval_s:
                try:
                    self._state = self._read_state()
                except sqlite3.Error as exc:  # a store being created or checkpointed: the last state stands
                    if self._state is None:
                        self._state = self._empty_state(f"the store cannot be read yet ({exc})")
                self._state_at = now
            return self._state

    def _empty_state(self, note: str) -> dict[str, Any]:
        return {"state": "starting", "method": None, "planned_readings": None, "done_readings": 0, "eta_s": None,
                "clock": "real", "ends_utc": None, "solving_s": None, "marking": "",
                "faults": 0, "current": {}, "name": None, "last_reading_id": 0, "latest": [], "progress": None,
                "events_count": 0, "result": None, "note": note, "operator": None}

    def _read_state(self) -> dict[str, Any]:
        db = self._connect()
        if db is None:
            return self._empty_state("no run store yet")
        with closing(db):
            db.execute("BEGIN")  # one snapshot for every query below
            meta = dict(db.execute("SELECT key, value FROM meta"))
            hi = int(db.execute("SELECT COALESCE(MAX(id), 0) FROM readings").fetchone()[0])
            self._accumulate(db, hi)
            faults = int(db.execute("SELECT COUNT(*) FROM events WHERE kind = 'fault'").fetchone()[0])
            n_events = int(db.execute("SELECT COUNT(*) FROM events").fetchone()[0])
            last = db.execute("SELECT plan_index, commanded_angle_deg, run, direction, point, station, seating "
                              "FROM readings WHERE plan_index IS NOT NULL AND id <= ? ORDER BY id DESC LIMIT 1",
                              (hi,)).fetchone()
            db.execute("COMMIT")
        acc = self._acc
        state = engine_state(meta)
        planned = self._planned(meta)
        done = acc.done
        operator = operator_of(meta) if state not in FINAL_STATES else None
        eta_s = self._eta_s(state, planned, done, meta.get("eta_s"))
        clock = "virtual" if meta.get("clock") == "virtual" else "real"
        at = eta_at(meta)
        if eta_s is not None and at is not None and clock == "real" and state == "running" and operator is None:
            eta_s = round(max(eta_s - max(time.time() - at["utc"], 0.0), 0.0), 0)  # counted down since it was estimated
        return {
            "state": state,
            "method": meta.get("method"),
            "planned_readings": planned,
            "done_readings": done,
            "eta_s": eta_s,
            "clock": clock,
            "ends_utc": ends_utc(meta, clock, at, eta_s) if state not in FINAL_STATES else None,
            "solving_s": at["after_s"] if at is not None and clock == "real" else None,
            "marking": self._marking(meta),
            "faults": faults,
            "current": current_of(meta, last),
            "name": _procedure_name(meta),
            "last_reading_id": hi,
            "latest": self._latest(),
            "progress": self._progress(),
            "events_count": n_events,
            "result": self._result() if state == "finished" else None,
            "note": None,
            "operator": operator,
        }

    def _accumulate(self, db: sqlite3.Connection, hi: int) -> None:
        """Take in the readings stored since the last poll (ids last_id+1 … hi, whole attempts:
        the engine commits each attempt in one transaction)."""
        acc = self._acc
        if hi < acc.last_id:  # the store was replaced: start again
            self._acc = acc = _Accumulated()
        if hi == acc.last_id:
            return
        acc.described = described_in(db)  # what each quantity is: the view shows by it, never by an instrument's name
        rows = db.execute(
            "SELECT plan_index, attempt, SUM(quantity IN (" + _MARKS + ")), SUM(quantity = ?), MAX(id), MAX(t_s), "
            "MIN(run), MIN(direction), MIN(commanded_angle_deg), MIN(point), MIN(station), MIN(seating) "
            "FROM readings WHERE id > ? AND id <= ? AND plan_index IS NOT NULL GROUP BY plan_index, attempt "
            "ORDER BY MAX(id)", (REJECTED, acc.last_id, hi))
        for k, _attempt, markers, rejected, max_id, max_t, run, direction, target, point, station, seating in rows:
            plan = acc.plans.get(k)
            if plan is None:
                plan = acc.plans[k] = _Planned(run, direction, target, point, station, seating)
            elif plan.status == "done":
                continue
            if not markers:
                plan.status = "done"
                acc.done += 1
                acc.completions.append((int(max_id), float(max_t)))
            else:
                plan.status = "rejected" if rejected else "skipped"
            acc.progress.update(k, plan)
        for instrument, quantity, value, unit, t_s, rid in db.execute(
                "SELECT instrument, quantity, value, unit, t_s, MAX(id) FROM readings WHERE id > ? AND id <= ? "
                "AND quantity NOT IN (" + _MARKS + ") GROUP BY instrument, quantity", (acc.last_id, hi)):
            d = acc.described.get((instrument, quantity))
            acc.latest[(instrument, quantity)] = {"instrument": instrument, "quantity": quantity, "value": value,
                                                  "unit": unit, "t_s": t_s, "id": rid,
                                                  "kind": None if d is None else d.kind,
                                                  "what": None if d is None else d.what}
        newest = db.execute("SELECT MAX(t_s) FROM readings WHERE id > ? AND id <= ?", (acc.last_id, hi)).fetchone()[0]
        if newest is not None:
            acc.newest_t_s = float(newest)
        acc.last_id = hi

    def _eta_s(self, state: str, planned: int | None, done: int, stored: str | None = None) -> float | None:
        """Time left: the engine's estimate (the one its log prints, rtcal.engine.subscribers.Eta),
        else at the rate of the last completions (s per planned reading, on the run's clock); null
        until two completions on one clock give a rate."""
        if state == "finished":
            return 0.0
        if state in ("failed", "aborted") or planned is None:
            return None
        try:
            eta = float(stored or "nan")
        except ValueError:
            eta = math.nan
        if math.isfinite(eta) and eta >= 0:
            return round(eta, 1)
        tail = list(self._acc.completions)
        start = len(tail) - 1
        while start > 0 and tail[start - 1][1] <= tail[start][1]:  # a resumed run's clock may start again at 0
            start -= 1
        tail = tail[start:]
        if len(tail) < 2 or tail[-1][1] <= tail[0][1]:
            return None
        rate_s = (tail[-1][1] - tail[0][1]) / (len(tail) - 1)
        return round(rate_s * max(planned - done, 0), 1)

    def _marking(self, meta: dict[str, str]) -> str:
        """What the run is if it calibrates nothing — simulated, rehearsed — in the words its certificate will
        carry (:func:`rtcal.run.runner.simulation_of` over the store's meta); "" for real instruments."""
        key = "\0".join(meta.get(k, "") for k in MARKING_KEYS)
        if self._marking_cache is None or self._marking_cache[0] != key:
            from rtcal.run.runner import simulation_of

            found = simulation_of(meta, in_process=bool(meta.get("seed")))  # only an in-process bench has a seed
            self._marking_cache = (key, found.statement if found is not None else "")
        return self._marking_cache[1]

    def _latest(self) -> list[dict[str, Any]]:
        """The newest value of each instrument and quantity, with its age behind the newest
        reading of the run (run clock, s)."""
        newest = self._acc.newest_t_s
        out = []
        for (instrument, quantity), r in sorted(self._acc.latest.items()):
            age = None if newest is None else round(max(newest - r["t_s"], 0.0), 3)
            value = r["value"] if isinstance(r["value"], (int, float)) and math.isfinite(r["value"]) else None
            out.append({**r, "value": value, "age_s": age})
        return out

    def _progress(self) -> dict[str, Any] | None:
        """Planned readings by row (run and direction, or CMM point) and column (target angle, or
        station), as far as the store shows them: pending cells appear once a row has begun."""
        return self._acc.progress.snapshot()

    def _planned(self, meta: dict[str, str]) -> int | None:
        """Planned readings: the engine's count, else the stored procedure's plan length."""
        text = meta.get("planned_readings")
        if text is not None:
            try:
                return int(text)
            except ValueError:
                return None
        key = f"{meta.get('method')}\0{meta.get('large')}\0{meta.get('procedure_yaml')}"
        if self._planned_cache is None or self._planned_cache[0] != key:
            self._planned_cache = (key, planned_from_procedure(meta))
        return self._planned_cache[1]

    def _result(self) -> dict[str, Any] | None:
        """The finished run's result in brief, from its results.json (validated; cached by mtime)."""
        path = self.run_dir / "results.json"
        try:
            st = path.stat()
        except OSError:
            return None
        stamp = (st.st_mtime_ns, st.st_size)
        cached = self._result_cache
        if (cached is None or cached[0] != stamp) and self._result_stamp != stamp:
            self._result_stamp = stamp  # solved once per version of the file, aside: it takes seconds

            def solve() -> None:
                brief = result_brief(self.run_dir)
                self._result_cache = (stamp, brief)
                self._state_at = 0.0  # the next poll shows it

            threading.Thread(target=solve, name="rtcal-live-result", daemon=True).start()
        return cached[1] if cached is not None else None

    def finish(self) -> None:
        """The run has ended: its next state is read afresh, with the result solved now (not aside),
        so the last state a page gets carries it."""
        path = self.run_dir / "results.json"
        try:
            st = path.stat()
        except OSError:
            st = None
        if st is not None:
            stamp = (st.st_mtime_ns, st.st_size)
            if self._result_cache is None or self._result_cache[0] != stamp:
                self._result_cache, self._result_stamp = (stamp, result_brief(self.run_dir)), stamp
        with self._lock:
            self._state_at = -1e9

    # -- what the event stream sends -------------------------------------------------------------
    def readings_after(self, last_id: int, limit: int = 2000) -> list[dict[str, Any]]:
        """Readings with an id above ``last_id``, oldest first (marker rows included: the page
        leaves a rejected or skipped attempt out of its plot)."""
        db = self._connect()
        if db is None:
            return []
        with closing(db):
            cur = db.execute(f"SELECT {', '.join(READING_FIELDS)} FROM readings WHERE id > ? ORDER BY id LIMIT ?",
                             (int(last_id), int(limit)))
            return [_finite(dict(zip(READING_FIELDS, row))) for row in cur]

    def events_after(self, last_id: int, limit: int = 500) -> list[dict[str, Any]]:
        db = self._connect()
        if db is None:
            return []
        with closing(db):
            cur = db.execute(f"SELECT {', '.join(EVENT_FIELDS)} FROM events WHERE id > ? ORDER BY id LIMIT ?",
                             (int(last_id), int(limit)))
            return [dict(zip(EVENT_FIELDS, row)) for row in cur]


def _finite(row: dict[str, Any]) -> dict[str, Any]:
    """JSON has no NaN or infinity: such a value goes as null."""
    v = row.get("value")
    if isinstance(v, float) and not math.isfinite(v):
        row["value"] = None
    return row


def eta_at(meta: dict[str, str]) -> dict[str, float] | None:
    """When the stored time left was estimated (``{"t_s", "utc", "after_s"}``), None for a store from before."""
    try:
        value = json.loads(meta.get("eta_at") or "null")
        found = {k: float(value[k]) for k in ("t_s", "utc", "after_s")}
    except (ValueError, TypeError, KeyError):
        return None
    return found if all(math.isfinite(v) for v in found.values()) else None


def ends_utc(meta: dict[str, str], clock: str, at: dict[str, float] | None, eta_s: float | None) -> str | None:
    """The expected end, ISO 8601 UTC: on a real clock the wall's time when it was estimated plus the time
    left; on a virtual clock the run's start plus the virtual time then and the time left (as its
    certificate dates a simulated measurement)."""
    import datetime as _dt

    if at is None or eta_s is None:
        return None
    try:
        if clock == "real":
            end = _dt.datetime.fromtimestamp(at["utc"], _dt.timezone.utc) + _dt.timedelta(seconds=float(meta["eta_s"]))
        else:
            end = _dt.datetime.fromisoformat(meta["started_utc"]) + _dt.timedelta(seconds=at["t_s"] + eta_s)
    except (KeyError, ValueError, OverflowError):
        return None
    return end.isoformat(timespec="seconds")


def engine_state(meta: dict[str, str]) -> str:
    """The engine's state, or the runner's status mapped onto the engine's states."""
    state = meta.get("engine_state")
    if state in STATES:
        return state
    status = meta.get("status", "")
    if status in STATUS_STATES:
        return STATUS_STATES[status]
    if status == "not started" and meta.get("error"):
        return "failed"
    return "starting"


def operator_of(meta: dict[str, str]) -> dict[str, Any] | None:
    """What the operator is asked now (``{"instruction", "t_s", "step"}``), None when nothing waits."""
    try:
        value = json.loads(meta.get("operator_waiting") or "null")
    except ValueError:
        return None
    if not isinstance(value, dict) or not isinstance(value.get("instruction"), str) or not value["instruction"]:
        return None
    t_s, step = value.get("t_s"), value.get("step")
    return {"instruction": value["instruction"][:2000],
            "t_s": float(t_s) if isinstance(t_s, (int, float)) and math.isfinite(t_s) else None,
            "step": step if isinstance(step, int) and not isinstance(step, bool) else None}


def current_of(meta: dict[str, str], last: tuple | None) -> dict[str, Any]:
    """Where the run is: the engine's ``current`` object, else what the last reading says."""
    text = meta.get("current")
    if text:
        try:
            value = json.loads(text)
            if isinstance(value, dict):
                return value
        except ValueError:
            pass
    if last is None:
        return {}
    plan_index, target, run, direction, point, station, seating = last
    found = {"plan_index": plan_index, "target_deg": target,
             "run": None if run is None else run + 1,
             "direction": None if direction is None else ("+" if direction > 0 else "-"),
             "point": None if point is None else point + 1,
             "station": None if station is None else station + 1,
             "seating": None if seating is None else seating + 1}
    return {k: v for k, v in found.items() if v is not None}


def _procedure_name(meta: dict[str, str]) -> str | None:
    import yaml

    try:
        data = yaml.safe_load(meta.get("procedure_yaml") or "")
    except yaml.YAMLError:
        return None
    name = data.get("name") if isinstance(data, dict) else None
    return str(name)[:200] if name is not None else None


def planned_from_procedure(meta: dict[str, str]) -> int | None:
    """The stored procedure's plan length, read as `rtcal resume` reads it (None if it cannot be)."""
    from rtcal.methods import METHODS
    from rtcal.procedure.yamlfile import FileProblems, validate_text

    method = meta.get("method")
    if not isinstance(method, str) or method not in METHODS or not meta.get("procedure_yaml"):
        return None
    try:
        proc = validate_text(meta["procedure_yaml"], METHODS[method].procedure_model, "stored procedure",
                             context={"large": bool(meta.get("large"))})
        return int(METHODS[method].plan_length(proc))
    except (FileProblems, ValueError, TypeError):
        return None


def result_brief(run_dir: Path) -> dict[str, Any] | None:
    """The finished run's result as its certificate states it — the marking, the result in brief, the
    conformity and the departures, from the certificate's own builders (the same words and rounded
    numbers) — the lines `rtcal run` prints at the end, the deviation table with U (k = 2) and the report
    files present, from the run's validated results.json."""
    from rtcal.deliverables.certificate import certificate_sections
    from rtcal.deliverables.report import console_lines
    from rtcal.deliverables.rounding import u_text, value_text
    from rtcal.methods import METHODS, read_results
    from rtcal.results import ResultsError

    try:
        results = read_results(run_dir)
        method = METHODS[results.method]
        lines = method.outputs(results).summary() + console_lines(results)
        parts = certificate_sections(results, run_dir, method, ("header", "identification", "result_in_brief", "conformity"))
    except (ResultsError, ValueError, KeyError, OSError) as exc:
        return {"error": f"results.json cannot be read: {exc}"[:300], "lines": [], "deviations": None, "files": []}
    table = results.positioning_deviations
    deviations = None
    if table is not None:
        U = [None if u is None else 2.0 * u for u in table.uncertainty_arcsec]
        deviations = {"estimator": table.estimator, "target_deg": table.target_deg, "direction": table.direction,
                      "run": table.run, "deviation_arcsec": table.deviation_arcsec, "U_arcsec": U,
                      "text": [f"{value_text(d, u, '+')}″" + (f" (U {u_text(u)}″)" if u is not None else "")
                               for d, u in zip(table.deviation_arcsec, U)]}
    files = [f for f in REPORT_FILES if os.path.isfile(run_dir / f) and not os.path.islink(run_dir / f)]
    brief, conformity = parts["result_in_brief"], parts["conformity"]
    departed = next((i.value for i in parts["identification"].items if i.label == "Departures from the method"), "none")
    return {"error": None, "headline": headline(brief, conformity, lines), "marking": parts["header"].marking,
            "not_certificate": parts["header"].not_certificate, "departures": "" if departed == "none" else departed,
            "brief": {"heading": brief.heading, "header": brief.header,
                      "rows": [[k.quantity, k.value_arcsec, k.expanded_uncertainty_arcsec] for k in brief.rows]},
            "conformity": None if conformity is None else {
                "heading": conformity.heading, "verdict": conformity.verdict, "rule": conformity.rule,
                "header": conformity.header,
                "rows": [[r.symbol, r.parameter, r.limit_arcsec, r.value_arcsec, r.expanded_uncertainty_arcsec,
                          r.guard_band_arcsec, r.verdict] for r in conformity.rows]},
            "lines": lines, "deviations": deviations, "files": files}


def headline(brief: Any, conformity: Any, lines: list[str]) -> str:
    """The result in a sentence, in the certificate's words and numbers: its E row of the result in brief
    (else its first row), U (k = 2), and the conformity verdict with its decision rule; a method with no
    row says its first summary line."""
    rows = list(brief.rows)
    row = next((k for k in rows if k.quantity.startswith("E:")), rows[0] if rows else None)
    if row is None:
        return lines[0] if lines else "measured and solved"
    symbol, _, what = row.quantity.partition(": ") if row.quantity.startswith("E:") else ("", "", row.quantity)
    qualifier, _, meaning = what.rpartition(": ")  # "as ISO 230-2 defines it, not an ISO 230-2 result (…): meaning"
    text = (f"{meaning[:1].upper() + meaning[1:]} {symbol} = {row.value_arcsec} ({row.expanded_uncertainty_arcsec}, k = 2)"
            if symbol else f"{what}: {row.value_arcsec} ({row.expanded_uncertainty_arcsec}, k = 2)")
    text += f", {qualifier}" if symbol and qualifier else ""
    if conformity is None:
        return text + ". The procedure states no acceptance limit."
    rule = conformity.rule.split(")")[0] + ")" if ")" in conformity.rule else conformity.rule
    return f"{text}. {conformity.heading}: {conformity.verdict.upper()} under {rule[:1].lower() + rule[1:]}."
