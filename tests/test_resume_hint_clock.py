"""Resuming as the run says: the printed `rtcal resume` command works as printed (a wired run's
--instruments named as given, never a token), the resume goes on on the clock the run was started on,
and its clock goes on from where the run stopped (times only grow; the duration counts every start)."""

from __future__ import annotations

import json
import os
import re
import select
import shlex
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rtcal.clock import RealClock
from rtcal.store.hint import OPERATOR_TOKEN_ENV, PLACEHOLDER, resume_hint
from rtcal.store.runstore import RunStore
from tests.polling import stored_plan_indices

REPO = Path(__file__).resolve().parents[1]
PROCEDURE = REPO / "tests" / "data" / "small_multistation.yaml"  # 64 planned readings, about 5 s wired
ENV = {**os.environ, "PYTHONPATH": str(REPO)}  # the subprocesses import this tree's rtcal
HINT = re.compile(r"`(rtcal resume [^`]*)`")
TOKEN = "s3cr3t-token-value"


# -- the hint -------------------------------------------------------------------------------------

def _store_with_operator(run_dir: Path, operator: str) -> None:
    run_dir.mkdir()
    RunStore.create(run_dir, {"method": "laser_tracer_multistation", "operator_address": operator}).close()


def test_a_file_of_addresses_is_named_and_inline_json_comes_back_as_typed(tmp_path):
    run = tmp_path / "my run"  # a path the shell would split is quoted
    assert f"--instruments {tmp_path / 'a.json'}`" in resume_hint(run, str(tmp_path / "a.json"))
    inline = '{"stage": "modbus-tcp://127.0.0.1:5020?unit=1"}'
    command = HINT.search(resume_hint(run, inline)).group(1)
    assert shlex.split(command) == ["rtcal", "resume", str(run), "--instruments", inline]


def test_a_token_is_never_printed(tmp_path):
    inline = json.dumps({"operator": f"sim-operator://127.0.0.1:1?token={TOKEN}"})
    hint = resume_hint(tmp_path / "run", inline)
    assert TOKEN not in hint and f"--instruments {PLACEHOLDER}`" in hint and f"({PLACEHOLDER}: " in hint


def test_a_stored_redacted_operator_asks_for_the_addresses_unless_the_token_is_in_the_environment(tmp_path, monkeypatch):
    wired, plain = tmp_path / "wired", tmp_path / "plain"
    _store_with_operator(wired, f"sim-operator://127.0.0.1:1?token={TOKEN}")  # the store redacts it
    _store_with_operator(plain, "")
    monkeypatch.delenv(OPERATOR_TOKEN_ENV, raising=False)
    assert HINT.search(resume_hint(wired)).group(1) == f"rtcal resume {wired} --instruments {PLACEHOLDER}"
    assert HINT.search(resume_hint(plain)).group(1) == f"rtcal resume {plain}"
    monkeypatch.setenv(OPERATOR_TOKEN_ENV, TOKEN)
    assert HINT.search(resume_hint(wired)).group(1) == f"rtcal resume {wired}"


def test_a_real_clock_goes_on_from_where_the_run_stopped():
    clock = RealClock(1717.5)
    first = clock.now_s()
    assert 1717.5 <= first < 1718.5 and clock.now_s() >= first


def test_an_in_process_run_refuses_the_real_clock(tmp_path):
    out = tmp_path / "run"
    run = subprocess.Popen([sys.executable, "-m", "rtcal.cli", "run", str(PROCEDURE), "--out", str(out)],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=ENV)
    _interrupt_after(run, out / "run.sqlite", 3)
    _, err = run.communicate(timeout=60)
    if run.returncode == 0:
        pytest.skip("the in-process run finished before it could be interrupted")
    refused = subprocess.run([sys.executable, "-m", "rtcal.cli", "resume", str(out), "--real-clock"],
                             capture_output=True, text=True, env=ENV, timeout=60)
    assert refused.returncode == 2 and "--real-clock" in refused.stderr and "Traceback" not in refused.stderr


# -- a wired run interrupted and resumed by the printed command ----------------------------------

def _interrupt_after(run: subprocess.Popen, db: Path, planned_readings: int) -> None:
    deadline = time.monotonic() + 60
    while stored_plan_indices(db) < planned_readings and run.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    if run.poll() is None:
        run.send_signal(signal.SIGINT)


def _reading_times(db: Path) -> list[float]:
    with sqlite3.connect(db) as c:
        return [t for (t,) in c.execute("SELECT t_s FROM readings ORDER BY id")]


def _first_time_of(db: Path, plan_index: int) -> float:
    with sqlite3.connect(db) as c:
        return float(c.execute("SELECT MIN(t_s) FROM readings WHERE plan_index = ?", (plan_index,)).fetchone()[0])


def _results(run_dir: Path) -> dict:
    return json.loads((run_dir / "results.json").read_text())


@pytest.fixture(scope="module")
def addresses_file(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sim")
    sim = subprocess.Popen([sys.executable, "-m", "rtcal.cli", "sim", "serve", "--seed", "5"],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=ENV)
    try:
        ready, _, _ = select.select([sim.stdout], [], [], 30)
        assert ready, "rtcal sim serve printed nothing in 30 s"
        path = folder / "addresses.json"
        path.write_text(sim.stdout.readline())
        yield path
    finally:
        sim.terminate()
        sim.wait(10)


def _run(addresses: Path, out: Path, *more: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "rtcal.cli", "run", str(PROCEDURE), "--instruments", str(addresses),
                             "--virtual-clock", "--out", str(out), *more],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=ENV)


def _printed_resume(err: str) -> list[str]:
    """The resume command the interrupted run printed, as a shell would split it, run as `rtcal`."""
    hints = HINT.findall(err)
    assert hints, err
    words = shlex.split(hints[-1])
    assert words[0] == "rtcal", hints[-1]
    return [sys.executable, "-m", "rtcal.cli", *words[1:]]


def test_the_printed_hint_resumes_a_wired_virtual_clock_run_with_times_and_duration_whole(tmp_path, addresses_file):
    """Was: the hint lacked --instruments (exit 2), the resume ran in real time, the reading times jumped
    back to 0 and the duration counted only part of the run."""
    whole = _run(addresses_file, tmp_path / "whole")
    _, err = whole.communicate(timeout=120)
    assert whole.returncode == 0, err
    uninterrupted_s = _results(tmp_path / "whole")["measurement_duration_s"]

    out = tmp_path / "interrupted"
    run = _run(addresses_file, out)
    _interrupt_after(run, out / "run.sqlite", 20)
    _, err = run.communicate(timeout=60)
    assert run.returncode == 130, err
    assert TOKEN not in err and "token=" not in err
    command = _printed_resume(err)
    assert str(addresses_file) in command, command  # the file given, named

    started = time.monotonic()
    resumed = subprocess.run(command, capture_output=True, text=True, env=ENV, timeout=120)
    assert resumed.returncode == 0, resumed.stderr
    results = _results(out)
    assert results["starts"] == 2 and results["clock"] == "virtual"
    times = _reading_times(out / "run.sqlite")
    assert all(b >= a for a, b in zip(times, times[1:])), "a reading time went backwards"
    # the resume's own cost on top: one more start (re-approach from the start, re-reference the tracer,
    # retake the interrupted reading), which the uninterrupted run paid once before its second reading
    one_start_s = _first_time_of(tmp_path / "whole" / "run.sqlite", plan_index=1)
    assert uninterrupted_s - 1.0 <= results["measurement_duration_s"] <= uninterrupted_s + one_start_s
    assert results["measurement_duration_s"] > 10 * (time.monotonic() - started)  # not the real seconds it took


def test_a_resume_on_the_real_clock_when_asked_still_goes_forward(tmp_path, addresses_file):
    out = tmp_path / "run"
    run = _run(addresses_file, out)
    _interrupt_after(run, out / "run.sqlite", 56)
    _, err = run.communicate(timeout=60)
    assert run.returncode == 130, err
    stopped_s = max(_reading_times(out / "run.sqlite"))
    resumed = subprocess.run([*_printed_resume(err), "--real-clock"], capture_output=True, text=True, env=ENV,
                             timeout=180)
    assert resumed.returncode == 0, resumed.stderr
    results = _results(out)
    times = _reading_times(out / "run.sqlite")
    assert results["clock"] == "real" and all(b >= a for a, b in zip(times, times[1:]))
    assert stopped_s < results["measurement_duration_s"]
    assert any("real clock" in e["message"] for e in results["events"] if e["kind"] == "resume")


def test_after_an_instrument_failure_the_hint_says_the_file_must_hold_the_addresses_that_answer(tmp_path):
    addresses = str(tmp_path / "a.json")
    hint = resume_hint(tmp_path / "run", addresses, instruments_failed=True)
    assert HINT.search(hint).group(1) == f"rtcal resume {tmp_path / 'run'} --instruments {addresses}"
    assert f"write them to {addresses}" in hint
