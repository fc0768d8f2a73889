"""Outputs checked against the store: digests that bind results.json and run.sqlite together.

results.json records (``digests``) a SHA-256 of the store's readings and events and one of the
procedure, bench and seed the results were computed from; the store records (meta
``results_sha256``) the SHA-256 of the results.json the run wrote. An edit to either file is
found by every command that reads a run (:func:`check_run`), and ``rtcal verify`` recomputes the
results from the store. results.json also records (``digests.deliverables_sha256``, schema 1.3) the
SHA-256 of every other file the run wrote — certificate.json, report.md/.html/.pdf,
positioning_deviations.csv, the figures — taken after they were written and before results.json
was: ``rtcal verify`` checks each (:func:`check_deliverables`). No digest covers a path: a run
directory copied elsewhere stays valid.
"""

from __future__ import annotations

import hashlib
import json
import os
import sqlite3
from contextlib import closing
from pathlib import Path
from typing import Iterable
from urllib.parse import quote

from drivers.addresses import redact_tokens
from rtcal.results.io import FILENAME as RESULTS_FILENAME, ResultsError, results_json
from rtcal.results.model import DELIVERABLE_DIGESTS_SINCE, STORE_DIGESTS_SINCE, Digests, RunResults
from rtcal.store.runstore import CONTEXT, EVENT_COLUMNS, READING_COLUMNS, RunStore

RESULTS_DIGEST_KEY = "results_sha256"  # store meta: the digest of the results.json the run wrote
# what of the store's metadata the results were computed from (paths and times are left out: a copy stays valid)
PROCEDURE_KEYS = ("method", "procedure_yaml", "instruments", "scenario_yaml", "seed")


class IntegrityError(ResultsError):
    """results.json and run.sqlite do not match (exit 2): the message names the mismatch."""


def _rows_digest(rows: Iterable[tuple], count: list[int]) -> str:
    h = hashlib.sha256()
    for row in rows:
        h.update(json.dumps(list(row), ensure_ascii=True, allow_nan=True).encode())
        h.update(b"\n")
        count[0] += 1
    return h.hexdigest()


def store_digests(db: sqlite3.Connection) -> Digests:
    """The digests of a store's readings, events and procedure, through any connection to it."""
    readings, events = [0], [0]
    has_context = any(row[1] == CONTEXT for row in db.execute("PRAGMA table_info(readings)"))
    reading_rows = db.execute(f"SELECT {', '.join(READING_COLUMNS)}{', ' + CONTEXT if has_context else ''} FROM readings "
                              "ORDER BY id")
    # a row's declared context is covered where it has one; a row without (every row before context columns) is
    # digested as it always was, so a run's digest does not change with the store's schema
    readings_sha = _rows_digest((row[:-1] if has_context and row[-1] is None else row for row in reading_rows), readings)
    events_sha = _rows_digest(db.execute(f"SELECT {', '.join(EVENT_COLUMNS)} FROM events ORDER BY id"), events)
    meta = dict(db.execute("SELECT key, value FROM meta"))
    procedure = {k: redact_tokens(meta.get(k, "")) for k in PROCEDURE_KEYS}
    procedure_sha = hashlib.sha256(json.dumps(procedure, sort_keys=True).encode()).hexdigest()
    return Digests(algorithm="sha256", readings_sha256=readings_sha, readings=readings[0], events_sha256=events_sha,
                   events=events[0], procedure_sha256=procedure_sha)


def digests_of(store: RunStore) -> Digests:
    return store_digests(store._db)  # noqa: SLF001 — the store's own connection, inside the run's lock


def results_digest(results: RunResults) -> str:
    """The SHA-256 of the results.json text :func:`rtcal.results.write_results` writes for ``results``."""
    return hashlib.sha256(results_json(results).encode("utf-8")).hexdigest()


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def deliverable_digests(folder: Path) -> dict[str, str]:
    """The SHA-256 of every file written into ``folder`` (its path there, ``/``-separated) but
    results.json, which records them: what the run's deliverables are, as written."""
    folder = Path(folder)
    found = {}
    for path in sorted(folder.rglob("*")):
        name = path.relative_to(folder).as_posix()
        if path.is_file() and not path.is_symlink() and name != RESULTS_FILENAME:
            found[name] = _file_sha256(path)
    return found


def check_deliverables(run_dir: str | Path, results: RunResults) -> list[tuple[str, str]]:
    """Each deliverable results.json records a digest of, and what it is now: ``as written``,
    ``EDITED`` (its bytes are not those the run wrote), ``missing`` or ``not a regular file``
    (a link or a folder in its place). Empty when the file records no deliverables (before 1.3)."""
    run_dir = Path(run_dir)
    recorded = results.digests.deliverables_sha256 if results.digests is not None else None
    status = []
    for name, digest in sorted((recorded or {}).items()):
        path = run_dir / name
        if not os.path.lexists(path):
            status.append((name, "missing"))
        elif path.is_symlink() or not path.is_file():
            status.append((name, "not a regular file"))
        else:
            status.append((name, "as written" if _file_sha256(path) == digest else "EDITED"))
    return status


def _version(results: RunResults) -> tuple[int, int]:
    major, _, minor = results.schema_version.partition(".")
    return int(major), int(minor)


def missing_digests(results: RunResults, path: Path) -> str:
    """Why a results.json that should carry digests but carries none is not rtcal's, or "": a file
    of schema 1.2 or later always records its store's, one of 1.3 or later its deliverables'."""
    version = results.schema_version
    if results.digests is None and _version(results) >= STORE_DIGESTS_SINCE:
        return (f"{path}: records no digests of its run's store, yet its schema_version {version} is one rtcal always "
                "writes them in: not a file rtcal wrote")
    if results.digests is not None and results.digests.deliverables_sha256 is None \
            and _version(results) >= DELIVERABLE_DIGESTS_SINCE:
        return (f"{path}: records no digests of its certificate, reports and CSV, yet its schema_version {version} is "
                "one rtcal always writes them in: not a file rtcal wrote")
    return ""


def _read_only(path: Path) -> sqlite3.Connection:
    """The store opened read-only: checking a run changes no byte of it."""
    mode = "mode=ro" if os.path.lexists(f"{path}-wal") else "immutable=1"
    return sqlite3.connect(f"file:{quote(str(path.absolute()))}?{mode}", uri=True, timeout=10.0)


def check_run(run_dir: str | Path, results: RunResults) -> list[str]:
    """Refuse (IntegrityError, naming the mismatch) a results.json that does not match its run's
    store. Returns warnings: a file from before schema 1.2 without a store cannot be checked."""
    run_dir = Path(run_dir)
    path, store_path = run_dir / RESULTS_FILENAME, run_dir / RunStore.FILENAME
    if not store_path.is_file() or store_path.is_symlink():
        if missing_digests(results, path):
            raise IntegrityError(missing_digests(results, path))
        if results.digests is not None:
            raise IntegrityError(f"{path}: records digests of its run's store, but {store_path} is missing: the results "
                                 "cannot be checked against the readings (copy the whole run directory)")
        return [f"{path} carries no digests (written before schema 1.2) and has no {RunStore.FILENAME} beside it: "
                "it is not checked against any readings"]
    try:
        with closing(_read_only(store_path)) as db:
            recorded = db.execute("SELECT value FROM meta WHERE key = ?", (RESULTS_DIGEST_KEY,)).fetchone()
            found = store_digests(db) if results.digests is not None else None
    except sqlite3.DatabaseError as exc:
        raise IntegrityError(f"{store_path}: cannot be read to check {path} against it ({exc})") from None
    actual = hashlib.sha256(path.read_bytes()).hexdigest()
    if recorded is None:
        if results.digests is not None:
            raise IntegrityError(f"{store_path}: holds no digest of the results.json its run wrote, yet {path} records "
                                 "digests: the store was edited or belongs to another run")
        if missing_digests(results, path):
            raise IntegrityError(missing_digests(results, path))
        return [f"{path} was written before schema 1.2: it carries no digests and is not checked against {store_path}"]
    if recorded[0] != actual:
        raise IntegrityError(f"{path}: does not match the digest {store_path} recorded when the run wrote it "
                             f"(sha256 {actual[:12]}…, recorded {recorded[0][:12]}…): the file was edited after the run; "
                             f"`rtcal verify {run_dir}` recomputes the results from the readings")
    if results.digests is None:
        raise IntegrityError(f"{path}: records no digests of the store, which recorded this file's: not a file rtcal wrote")
    if missing_digests(results, path):
        raise IntegrityError(missing_digests(results, path))
    mismatch = compare_digests(results.digests, found)
    if mismatch:
        raise IntegrityError(f"{store_path}: {mismatch} do not match the digest {path} records: the store was edited "
                             "after the results were computed from it")
    return []


def compare_digests(recorded: Digests, found: Digests | None) -> str:
    """What differs ("its readings (1200 now, 1201 recorded)"), or "" when all match."""
    if found is None:
        return "its readings"
    parts = []
    if (recorded.readings_sha256, recorded.readings) != (found.readings_sha256, found.readings):
        parts.append(f"its readings ({found.readings} now, {recorded.readings} recorded)")
    if (recorded.events_sha256, recorded.events) != (found.events_sha256, found.events):
        parts.append(f"its events ({found.events} now, {recorded.events} recorded)")
    if recorded.procedure_sha256 != found.procedure_sha256:
        parts.append("its procedure, bench or seed")
    return " and ".join(parts)
