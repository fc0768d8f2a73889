"""No store is deleted or overwritten unless it is proven empty; a damaged one is left byte for
byte as it is and `rtcal export` salvages what can still be read; a full disk stops a run with
exit 1, the resume hint and its status, and loses no reading.

A full disk is injected in process: the store's connection refuses writes with SQLITE_FULL (what
SQLite raises on ENOSPC) until the space the store reserved is given up, or a report writer
raises ENOSPC.
"""

from __future__ import annotations

import csv
import errno
import hashlib
import os
import re
import shutil
import sqlite3
from pathlib import Path

import pytest

from rtcal.cli import main
from rtcal.store.runstore import SCHEMA, RunStore
from tests.test_crash_resume import _check_store

REPO = Path(__file__).resolve().parents[1]
ABBE = REPO / "procedures" / "encoder_abbe_error.yaml"
PLANNED = 96  # the Abbe procedure's planned readings (2 directions × 48 targets)


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("finished") / "abbe"
    assert main(["run", str(ABBE), "--out", str(run)]) == 0
    return run


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _rows(store: Path) -> dict[str, list[str]]:
    """Every reading as `rtcal export` writes it (None as an empty cell), by id. (`immutable`: a
    read-only connection would leave an empty -wal and -shm beside a closed store.)"""
    with sqlite3.connect(f"file:{store}?immutable=1", uri=True) as db:
        return {str(row[0]): ["" if v is None else str(v) for v in row] for row in db.execute("SELECT * FROM readings")}


def _damage(store: Path, kind: str) -> None:
    data = bytearray(store.read_bytes())
    if kind == "cut_short":
        del data[len(data) * 2 // 3:]
    elif kind == "page_overwritten":  # a page in the middle: readings on it are lost, the rest readable
        middle = (len(data) // 4096 // 2) * 4096
        data[middle:middle + 4096] = bytes((k * 37 + 11) % 256 for k in range(4096))
    elif kind == "header_lost":
        data[:100] = bytes(100)
    store.write_bytes(bytes(data))


@pytest.mark.parametrize("kind", ["cut_short", "page_overwritten", "header_lost"])
@pytest.mark.parametrize("alone", [False, True], ids=["with_outputs", "store_alone"])
def test_damaged_store_survives_run_and_resume_and_export_salvages_it(finished, tmp_path, capsys, kind, alone):
    run = tmp_path / "run"
    if alone:
        run.mkdir()
        shutil.copy(finished / "run.sqlite", run / "run.sqlite")
    else:
        shutil.copytree(finished, run)
    store = run / "run.sqlite"
    original = _rows(store)
    _damage(store, kind)
    before = _sha(store)

    assert main(["run", str(ABBE), "--out", str(run)]) == 2  # the advice that used to unlink the store
    err = capsys.readouterr().err
    assert f"--out {run}: its run.sqlite is damaged" in err and f"rtcal export {run}" in err, err
    assert main(["resume", str(run)]) == 2
    err = capsys.readouterr().err
    assert f"{store} is damaged" in err and "left as it is" in err, err
    assert _sha(store) == before and store.exists()
    assert not list(run.glob("run.sqlite-*")), "reading the store left files beside it"

    out = tmp_path / "salvaged"
    assert main(["export", str(run), "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert _sha(store) == before
    with (out / "readings.csv").open(newline="", encoding="utf-8") as fh:
        salvaged = list(csv.reader(fh))[1:]
    assert salvaged, "nothing salvaged"
    assert all(row == original[row[0]] for row in salvaged), "a salvaged reading differs from the one stored"
    assert f"{len(salvaged)} salvaged readings" in captured.out
    lost = int(re.search(r"(\d+) readings cannot", captured.err).group(1))
    if "count of its readings was not readable" in captured.err:
        assert len(salvaged) + lost <= len(original), captured.err
    else:
        assert len(salvaged) + lost == len(original), captured.err


@pytest.mark.parametrize("fill", [None, SCHEMA], ids=["zero_bytes", "schema_only"])
def test_a_store_proven_empty_is_replaced(tmp_path, fill):
    """A zero-byte store, and one with the schema but no procedure, reading or event: a new run
    takes the directory (and only such a store goes)."""
    from rtcal.run.rundir import claim_new_run_dir

    (tmp_path / "run.sqlite").write_bytes(b"")
    if fill:
        with sqlite3.connect(tmp_path / "run.sqlite") as db:
            db.executescript(fill)
    claim_new_run_dir(tmp_path).release()
    assert not (tmp_path / "run.sqlite").exists()


def test_readings_without_a_procedure_are_kept_and_exported(tmp_path, capsys):
    run = tmp_path / "orphan"
    run.mkdir()
    with sqlite3.connect(run / "run.sqlite") as db:
        db.executescript(SCHEMA)
        db.execute("INSERT INTO readings(t_s, instrument, quantity, value, unit) VALUES (1.5, 'encoder', 'angle_deg', 0.25, 'deg')")
    before = _sha(run / "run.sqlite")
    assert main(["run", str(ABBE), "--out", str(run)]) == 2
    assert "holds readings or events (1 rows) but no procedure" in capsys.readouterr().err
    assert main(["resume", str(run)]) == 2
    assert "but no procedure" in capsys.readouterr().err
    assert _sha(run / "run.sqlite") == before
    assert main(["export", str(run)]) == 0
    with (run / "readings.csv").open(newline="") as fh:
        assert [r["value"] for r in csv.DictReader(fh)] == ["0.25"]


def test_resume_removes_what_a_killed_report_writer_left(finished, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(finished, run)
    (run / ".outputs-killed").mkdir()
    (run / ".outputs-killed" / "report.pdf").write_bytes(b"%PDF half")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "keep.txt").write_text("kept")
    (run / ".outputs-link").symlink_to(elsewhere)
    assert main(["resume", str(run)]) == 0
    assert not (run / ".outputs-killed").exists()
    assert (run / ".outputs-link").is_symlink() and (elsewhere / "keep.txt").read_text() == "kept"  # a link is not followed


class FullDisk:
    """A store connection on a disk that fills up after ``writes`` readings transactions: every
    write then fails with SQLITE_FULL — until the store's reserve file is removed (its space is
    free again), or for good with ``reserve_helps=False``."""

    WRITES = ("INSERT", "UPDATE", "DELETE", "COMMIT", "ALTER", "CREATE")

    def __init__(self, db: sqlite3.Connection, reserve: Path, writes: int, reserve_helps: bool):
        self.db, self.reserve, self.left, self.reserve_helps = db, reserve, writes, reserve_helps

    def _check(self, sql: str) -> None:
        if sql.lstrip().upper().startswith("INSERT INTO READINGS"):
            self.left -= 1
        full = self.left < 0 and (self.reserve.exists() or not self.reserve_helps)
        if full and sql.lstrip().upper().startswith(self.WRITES):
            exc = sqlite3.OperationalError("database or disk is full")
            exc.sqlite_errorcode, exc.sqlite_errorname = 13, "SQLITE_FULL"
            raise exc

    def execute(self, sql: str, *args):
        self._check(sql)
        return self.db.execute(sql, *args)

    def executemany(self, sql: str, rows):
        self._check(sql)
        return self.db.executemany(sql, rows)

    @property
    def in_transaction(self) -> bool:
        return self.db.in_transaction

    def close(self) -> None:
        self.db.close()


def _fill_up(monkeypatch, writes: int, reserve_helps: bool = True) -> None:
    real = RunStore._connect

    def connect(path: Path):
        return FullDisk(real(path), Path(path).parent / RunStore.RESERVE_NAME, writes, reserve_helps)

    monkeypatch.setattr(RunStore, "_connect", staticmethod(connect))


@pytest.mark.parametrize("reserve_helps", [True, False], ids=["reserve_takes_the_status", "no_space_at_all"])
def test_disk_full_while_measuring(tmp_path, capsys, monkeypatch, reserve_helps):
    run = tmp_path / "run"
    with monkeypatch.context() as m:
        _fill_up(m, 40, reserve_helps)
        assert main(["run", str(ABBE), "--out", str(run)]) == 1
    err = capsys.readouterr().err
    assert "rtcal: the disk refused a write" in err and f"`rtcal resume {run}` goes on" in err and "Traceback" not in err
    with sqlite3.connect(run / "run.sqlite") as db:
        status = dict(db.execute("SELECT key, value FROM meta"))["status"]
        stored = db.execute("SELECT COUNT(DISTINCT plan_index) FROM readings").fetchone()[0]
    assert stored == 40  # every transaction before the disk filled up, none after
    if reserve_helps:
        assert status == "interrupted"
    else:
        assert status == "running" and "could not be recorded" in err, err
    assert not (run / RunStore.RESERVE_NAME).exists()
    assert main(["resume", str(run)]) == 0  # space again: every planned reading, once
    _check_store(run / "run.sqlite", PLANNED, "encoder")


def test_disk_full_while_writing_the_report(tmp_path, capsys, monkeypatch):
    import rtcal.deliverables.report

    def full(*_):
        raise OSError(errno.ENOSPC, "No space left on device")

    run = tmp_path / "run"
    with monkeypatch.context() as m:
        m.setattr(rtcal.deliverables.report, "write_pdf", full)  # the runner imports it when it writes
        assert main(["run", str(ABBE), "--out", str(run)]) == 1
    err = capsys.readouterr().err
    assert f"the disk refused a write: in {run}: No space left on device" in err and f"`rtcal resume {run}`" in err
    with sqlite3.connect(run / "run.sqlite") as db:
        assert dict(db.execute("SELECT key, value FROM meta"))["status"] == "measured"
    assert not (run / "results.json").exists() and not list(run.glob(".outputs-*"))
    assert main(["resume", str(run)]) == 0
    assert (run / "results.json").exists() and (run / "report.pdf").exists()
    _check_store(run / "run.sqlite", PLANNED, "encoder")
