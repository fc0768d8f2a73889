"""One process owns a run directory: two `rtcal resume` of one interrupted run started at once
never both measure (the OS lock on RUN_DIR/.rtcal.lock), and no planned reading is stored twice."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.test_crash_resume import NOISE_FREE, PROCEDURE, _check_store, _run_and_kill


def _two_resumes(tmp_path: Path, trial: int) -> tuple[list[int], str]:
    out = tmp_path / f"run{trial}"
    db = out / "run.sqlite"
    assert _run_and_kill(["run", str(PROCEDURE), "--scenario", str(NOISE_FREE), "--out", str(out)], db, 40 + 7 * trial)
    procs = [subprocess.Popen([sys.executable, "-m", "rtcal.cli", "resume", str(out)], stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    results = [(p.wait(timeout=120), p.stderr.read()) for p in procs]
    _check_store(db, 704, "laser_tracer")  # every planned reading once, none twice
    assert "Traceback" not in "".join(err for _, err in results)
    busy = [err for code, err in results if code == 2]
    assert all("in use by process" in err for err in busy), busy
    starts = json.loads((out / "results.json").read_text())["starts"]
    return sorted(code for code, _ in results), f"starts={starts}"


def _trials(tmp_path: Path, n: int) -> None:
    outcomes = [_two_resumes(tmp_path, t) for t in range(n)]
    for codes, starts in outcomes:
        # either the second found the run owned (exit 2), or it started after the first had finished
        # and found a finished run, which it leaves as it is (exit 0, no new start counted)
        assert codes in ([0, 2], [0, 0]), (codes, starts)
        assert starts == "starts=2", starts
    assert any(codes == [0, 2] for codes, _ in outcomes), outcomes  # the race was really run


def test_two_resumes_at_once_one_proceeds(tmp_path):
    """3 interrupted runs, each resumed by two processes started together (20 under `-m campaign`:
    measured 20 of 20 with one exit 0 and one exit 2, no reading stored twice)."""
    _trials(tmp_path, 3)


@pytest.mark.campaign
def test_two_resumes_at_once_twenty_times(tmp_path):
    _trials(tmp_path, 20)
