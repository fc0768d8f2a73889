"""A run ended mid-move stops the machine at once, whoever ends it (issue 36): SIGHUP (a closed SSH
session) and SIGQUIT go through the one safe-state path as Ctrl-C does, and an abort from
`rtcal control` or the live page interrupts the motion in progress instead of waiting for it to end.

The wired runs go over the Modbus drive of the simulators, whose motions here take wall time (a
table turning at a few degrees a second): the drive records where and when a STOP ended a motion."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest
import yaml

from drivers.interfaces import StopSeen
from rtcal.clock import RealClock
from rtcal.engine.engine import AbortRequested, Engine, MeasuringFinished
from rtcal.engine.signals import Interrupted, ending_signals
from rtcal.procedure.models import FaultPolicy
from simulators.servers.hub import SimulatorHub
from tests.polling import wait_for
from tests.test_engine import FakeProbe, Operator, TwoDevicePlan
from tests.test_live_run import BENCH, ISO, _scenario, start_run

REPO = Path(__file__).resolve().parents[1]
SPEED_DEG_PER_S = 9.0  # the long move below (0° → 45°) takes 5 s
LONG_MOVE_TO_DEG = 45.0  # from 0°, approached from below: straight there
BOUND_S = 0.1  # from the request (acknowledged abort, signal sent) to the STOP at the drive


def short_iso(tmp_path: Path) -> Path:
    """The shipped ISO test on two targets, two runs each way: each long move of a few seconds."""
    data = yaml.safe_load(ISO.read_text(encoding="utf-8"))
    data.pop("bench", None)
    data["settle_time_s"] = 0.05
    data["steps"].update(targets_deg=[0, 45], runs=2)
    path = tmp_path / "iso_short.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


def status_of(run_dir: Path) -> str:
    with sqlite3.connect(f"file:{run_dir / 'run.sqlite'}?mode=ro", uri=True) as db:
        return db.execute("SELECT value FROM meta WHERE key = 'status'").fetchone()[0]


def abort_events(run_dir: Path) -> list[str]:
    with sqlite3.connect(f"file:{run_dir / 'run.sqlite'}?mode=ro", uri=True) as db:
        return [m for (m,) in db.execute("SELECT message FROM events WHERE kind = 'abort' ORDER BY id")]


def stopped_events(run_dir: Path) -> list[str]:
    with sqlite3.connect(f"file:{run_dir / 'run.sqlite'}?mode=ro", uri=True) as db:
        return [m for (m,) in db.execute("SELECT message FROM events WHERE kind = 'stopped' ORDER BY id")]


def mid_long_move(hub: SimulatorHub, proc: subprocess.Popen) -> None:
    """Wait until the table is well into its long move."""
    wait_for(lambda: proc.poll() is not None or hub.drive.moving_to_deg == pytest.approx(LONG_MOVE_TO_DEG, abs=0.01), 60)
    assert proc.poll() is None, proc.communicate()[1]
    time.sleep(0.4)
    assert hub.drive.moving_to_deg == pytest.approx(LONG_MOVE_TO_DEG, abs=0.01)


def stopped_mid_move(hub: SimulatorHub, asked_s: float) -> float:
    """The STOP came while the table turned, far short of the target; seconds from ``asked_s`` to it."""
    assert hub.drive.stopped, "the drive received no STOP while it moved"
    when_s, where_deg, target_deg = hub.drive.stopped[0]
    assert target_deg == pytest.approx(LONG_MOVE_TO_DEG, abs=0.01) and where_deg < target_deg - 5 * SPEED_DEG_PER_S * BOUND_S
    return when_s - asked_s


@pytest.mark.parametrize("name", ["SIGHUP", "SIGQUIT"])
def test_a_signal_mid_move_stops_the_drive_records_it_and_resume_finishes(tmp_path, name):
    run_dir = tmp_path / "run"
    with SimulatorHub(_scenario(tmp_path, "none"), seed=1, stage_wall_speed_deg_per_s=SPEED_DEG_PER_S) as hub:
        addresses = json.dumps(dict(hub.addresses))
        proc, _ = start_run("run", str(short_iso(tmp_path)), "--instruments", addresses, "--out", str(run_dir))
        try:
            mid_long_move(hub, proc)
            sent_s = time.monotonic()
            os.kill(proc.pid, getattr(signal, name))
            _, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
        took_s = stopped_mid_move(hub, sent_s)
        print(f"{name}: STOP at the drive {took_s * 1000:.1f} ms after the signal")
        assert took_s < BOUND_S
        # the drive's feedback read until it no longer changed: the store says where the table came to rest
        (stopped,) = stopped_events(run_dir)
        assert abs(float(stopped.split("at rest at ")[1].rstrip("°")) - hub.drive.stopped[0][1]) < 0.01, stopped
        assert proc.returncode == 130, err
        assert f"rtcal: interrupted by {name}; every reading taken so far is in {run_dir}/run.sqlite" in err
        assert f"rtcal resume {run_dir}" in err
        assert "Traceback" not in err
        assert status_of(run_dir) == "interrupted"
        assert any(f"interrupted by {name}" in m for m in abort_events(run_dir))
        assert not (run_dir / "results.json").exists()
        hub.drive.wall_speed_deg_per_s = None  # the resume at full speed
        resumed = subprocess.run([sys.executable, "-m", "rtcal.cli", "resume", str(run_dir), "--instruments", addresses],
                                 cwd=REPO, capture_output=True, text=True, timeout=120)
    assert resumed.returncode == 0, resumed.stderr
    assert status_of(run_dir) == "solved" and (run_dir / "results.json").is_file()


@pytest.mark.parametrize("by", ["control", "page"])
def test_an_abort_mid_move_stops_the_drive_at_once(tmp_path, by):
    """`rtcal control … abort` (or the page's Abort) during a 5 s move: the drive is stopped within
    BOUND_S of the acknowledgement, the run exits 130 without results or certificate, and the store
    holds the abort with who asked."""
    run_dir = tmp_path / "run"
    with SimulatorHub(_scenario(tmp_path, "none"), seed=1, stage_wall_speed_deg_per_s=SPEED_DEG_PER_S) as hub:
        live = ("--live", "127.0.0.1:0") if by == "page" else ()
        proc, seen = start_run("run", str(short_iso(tmp_path)), "--instruments", json.dumps(dict(hub.addresses)),
                               "--out", str(run_dir), *live)
        try:
            mid_long_move(hub, proc)
            asked_s = time.monotonic()
            if by == "control":
                control = subprocess.run([sys.executable, "-m", "rtcal.cli", "control", str(run_dir), "abort", "--token",
                                          seen["control token"]], cwd=REPO, capture_output=True, text=True, timeout=30)
                assert control.returncode == 0, control.stderr
            else:
                request = urllib.request.Request(seen["live view"] + "api/abort", method="POST", data=b"",
                                                 headers={"Authorization": f"Bearer {seen['control token']}"})
                with urllib.request.urlopen(request, timeout=10) as reply:
                    assert reply.status == 202
            acknowledged_s = time.monotonic()
            _, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
        after_ack_s = stopped_mid_move(hub, acknowledged_s)
        print(f"abort by {by}: STOP at the drive {after_ack_s * 1000:.1f} ms after the acknowledgement, "
              f"{(after_ack_s + acknowledged_s - asked_s) * 1000:.1f} ms after the request was sent")
        assert after_ack_s < BOUND_S
    assert proc.returncode == 130, err
    who = "`rtcal control`" if by == "control" else "the live page"
    assert f"rtcal: aborted by {who}; every reading taken so far is in {run_dir}/run.sqlite" in err
    assert status_of(run_dir) == "interrupted"
    assert any(f"aborted by {who}" in m for m in abort_events(run_dir))
    assert not (run_dir / "results.json").exists() and not (run_dir / "certificate.json").exists()


class SlowStage:
    """A stage whose move takes real time and whose stop ends it (a thread waits on the stop)."""

    step_deg = 0.0

    def __init__(self, move_s: float):
        self.move_s, self.at, self.stopped = move_s, 0.0, []
        self._stop = threading.Event()

    def check_target(self, angle: float) -> None:
        pass

    def move_to(self, angle: float) -> None:
        if not self._stop.wait(self.move_s if angle != self.at else 0.0):
            self.at = angle

    def stop(self) -> None:
        self.stopped.append(time.monotonic())
        self._stop.set()

    def wait_stopped(self) -> StopSeen:
        return StopSeen(True, f"{self.at:g}°")

    def recover(self) -> None:
        pass


def test_an_abort_interrupts_the_move_in_the_engines_thread():
    """In process, the engine in the main thread: an abort from another thread cuts a 3 s move."""
    stage = SlowStage(3.0)
    docs: list[tuple[str, dict]] = []
    engine = Engine({"stage": stage, "probe": FakeProbe(stage)}, RealClock(), Operator(), [lambda n, d: docs.append((n, d))])
    asked: list[float] = []

    def abort() -> None:
        asked.append(time.monotonic())
        engine.request_abort("a test")

    threading.Timer(0.3, abort).start()
    started = time.monotonic()
    with pytest.raises(AbortRequested, match="aborted by a test"):
        engine.run(TwoDevicePlan([0.0, 10.0], FaultPolicy()))
    assert time.monotonic() - started < 1.0  # not the 3 s of the move
    assert stage.stopped and stage.stopped[0] - asked[0] < BOUND_S
    assert engine.state == "aborted"
    assert [d["message"] for n, d in docs if n == "event" and d["kind"] == "abort"] == [
        "aborted by a test: every machine the run moved was stopped (stage seen at rest at 0°); `rtcal resume` goes on"]
    assert signal.getsignal(signal.SIGHUP) is signal.SIG_DFL  # the run's routing is gone with it


def test_an_abort_once_measuring_finished_is_refused_not_lost():
    """An abort acknowledged is always taken; after the last reading it is refused, never acknowledged and ignored."""
    stage = SlowStage(0.0)
    engine = Engine({"stage": stage, "probe": FakeProbe(stage)}, RealClock(), Operator())
    assert engine.run(TwoDevicePlan([0.0, 10.0], FaultPolicy())) == 2
    with pytest.raises(MeasuringFinished, match="finished measuring"):
        engine.request_abort("a test")
    stage = SlowStage(0.0)
    late = Engine({"stage": stage, "probe": FakeProbe(stage)}, RealClock(), Operator(),
                  [lambda n, d: n == "done" and d["done"] == 2 and late.request_abort("a test")])
    with pytest.raises(AbortRequested, match="aborted by a test"):  # asked while the last reading was committed
        late.run(TwoDevicePlan([0.0, 10.0], FaultPolicy()))


def test_every_ending_signal_is_routed():
    names = set(ending_signals().values())
    assert {"SIGHUP", "SIGINT", "SIGQUIT", "SIGTERM", "SIGUSR1", "SIGALRM"} <= names
    assert not names & {"SIGKILL", "SIGSEGV", "SIGCHLD", "SIGWINCH", "SIGURG"}
    assert isinstance(Interrupted("SIGHUP"), KeyboardInterrupt)


def test_the_progress_outlives_its_console():
    """After SIGHUP the terminal is gone and a write to it fails (EIO): the run's stop must not fail with it."""
    from rtcal.engine.subscribers import ConsoleProgress

    class Hungup:
        def write(self, text: str) -> int:
            raise OSError(5, "Input/output error")

        def flush(self) -> None:
            raise OSError(5, "Input/output error")

        def isatty(self) -> bool:
            return True

    progress = ConsoleProgress(Hungup())
    progress("start", {"planned": 2, "done": 0, "t_s": 0.0})
    progress("done", {"done": 1, "faults": 0, "t_s": 1.0})
    progress("stop", {"state": "aborted", "reason": "interrupted by SIGHUP", "t_s": 1.0})


def test_a_signal_while_the_results_are_computed_writes_none_and_is_recorded(tmp_path, monkeypatch):
    """Every reading taken, then SIGHUP while solving: no results or certificate, the status
    `interrupted` and an abort event (not `measured` and silence); a resume computes and writes them."""
    from rtcal.run import runner

    procedure = short_iso(tmp_path)
    run_dir = tmp_path / "run"
    solved = runner.evaluation_of

    def hung_up(analysis):
        raise Interrupted("SIGHUP")

    monkeypatch.setattr(runner, "evaluation_of", hung_up)
    with pytest.raises(Interrupted):
        runner.run_procedure(procedure, BENCH, out_dir=run_dir, show_progress=False)
    assert status_of(run_dir) == "interrupted"
    assert any("interrupted by SIGHUP while the results were computed" in m for m in abort_events(run_dir))
    assert not (run_dir / "results.json").exists() and not (run_dir / "certificate.json").exists()
    monkeypatch.setattr(runner, "evaluation_of", solved)
    runner.resume_run(run_dir, show_progress=False)
    assert status_of(run_dir) == "solved" and (run_dir / "certificate.json").is_file()


def test_rtcal_control_says_why_an_abort_after_measuring_is_refused(tmp_path):
    from rtcal.live.control import ControlRefused, ControlServer, new_token, send_control

    stage = SlowStage(0.0)
    engine = Engine({"stage": stage, "probe": FakeProbe(stage)}, RealClock(), Operator())
    engine.run(TwoDevicePlan([0.0, 10.0], FaultPolicy()))
    token = new_token()
    with ControlServer(tmp_path, token, engine):
        with pytest.raises(ControlRefused, match="could not abort: the run has finished measuring") as refused:
            send_control(tmp_path, token, "abort")
    assert refused.value.reason == "failed"


class StopTakesTime(SlowStage):
    """Its stop takes 0.2 s, and a second Ctrl-C comes while it runs (an impatient operator)."""

    def stop(self) -> None:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)  # the signal arrives here
        super().stop()


def test_a_second_signal_does_not_cut_the_stop_short():
    stage = StopTakesTime(3.0)
    docs: list[tuple[str, dict]] = []
    engine = Engine({"stage": stage, "probe": FakeProbe(stage)}, RealClock(), Operator(), [lambda n, d: docs.append((n, d))])
    threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT)).start()
    with pytest.raises(KeyboardInterrupt) as caught:  # (without the routing a bare one: never out of this test)
        engine.run(TwoDevicePlan([0.0, 10.0], FaultPolicy()))
    assert stage.stopped, "the stop was cut short"
    assert isinstance(caught.value, Interrupted) and str(caught.value) == "interrupted by SIGINT (Ctrl-C)"
    assert docs[-1][0] == "stop" and engine.state == "aborted"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


class StillTurning(SlowStage):
    """A table that keeps turning after its stop (a stop the controller queued behind the move), read
    through the default watch of every RotaryStage; ``settles_s`` > 0: it comes to rest that long after."""

    still_within_deg = 1e-4

    def __init__(self, move_s: float, settles_s: float | None = None):
        super().__init__(move_s)
        self.settles_s = settles_s

    def feedback_deg(self) -> float:
        if not self.stopped:
            return self.at
        turning_s = time.monotonic() - self.stopped[0]
        if self.settles_s is not None:
            turning_s = min(turning_s, self.settles_s)
        return 21.0 + 10.0 * turning_s  # 10 °/s on from 21°

    def wait_stopped(self) -> StopSeen:
        from drivers.interfaces import RotaryStage
        return RotaryStage.wait_stopped(self, timeout_s=1.0)  # type: ignore[arg-type]


def aborted_after(stage: SlowStage, after_s: float) -> tuple[list[dict], pytest.ExceptionInfo]:
    """The engine's events when a remote abort comes ``after_s`` into its first move, and the abort raised."""
    docs: list[tuple[str, dict]] = []
    engine = Engine({"stage": stage, "probe": FakeProbe(stage)}, RealClock(), Operator(), [lambda n, d: docs.append((n, d))])
    threading.Timer(after_s, engine.request_abort, ("a test",)).start()
    with pytest.raises(AbortRequested) as caught:
        engine.run(TwoDevicePlan([0.0, 10.0], FaultPolicy()))
    return [d for n, d in docs if n == "event"], caught


def test_a_machine_not_seen_at_rest_is_named_with_its_last_position_never_called_stopped():
    """Issue 40: the run wrote "every machine the run moved was stopped" while LinuxCNC's table went on
    turning. A position that still changes after the watch is a `moving` event naming the machine and
    its last position, the abort event says so, and the exception carries it for the console."""
    events, caught = aborted_after(StillTurning(3.0), 0.3)
    moving = [e for e in events if e["kind"] == "moving"]
    assert len(moving) == 1 and moving[0]["instrument"] == "stage", events
    last_deg = float(moving[0]["message"].split("last seen at ")[1].split("°")[0])
    assert 21.0 + 10.0 * 0.9 < last_deg < 21.0 + 10.0 * 1.5  # the position read as the 1 s watch ended
    assert "position still changed 1 s after the stop" in moving[0]["message"]
    (abort,) = [e["message"] for e in events if e["kind"] == "abort"]
    assert "was stopped" not in abort and "stage may still be moving (last seen at" in abort
    assert any("stage may still be moving" in note for note in caught.value.__notes__)


def test_a_machine_that_comes_to_rest_is_stopped_where_it_was_seen():
    events, caught = aborted_after(StillTurning(3.0, settles_s=0.3), 0.3)
    assert not [e for e in events if e["kind"] == "moving"]
    assert [e["message"] for e in events if e["kind"] == "stopped"] == ["stopped: seen at rest at 24.000000°"]
    (abort,) = [e["message"] for e in events if e["kind"] == "abort"]
    assert "every machine the run moved was stopped (stage seen at rest at 24.000000°)" in abort
    assert not getattr(caught.value, "__notes__", [])


def test_a_machine_whose_position_cannot_be_read_after_the_stop_may_still_be_moving():
    from drivers.interfaces import watch_still

    def dead() -> float:
        raise ConnectionResetError("the line died")

    seen = watch_still(dead, lambda deg: f"{deg}°", 1e-4, timeout_s=0.5)
    assert not seen.still and seen.where == "" and "could not be read" in seen.why and "the line died" in seen.why


def test_a_report_repeated_while_the_controller_still_executes_its_move_is_not_a_machine_at_rest():
    """Seen on a loaded host: linuxcncrsh repeated one position for 0.3 s while the table turned on 3°
    (LinuxCNC's status not refreshed), and the stop was said seen at rest there. The same status said
    RUNNING: while the controller says a move executes, no unchanged position is rest."""
    from drivers.interfaces import watch_still

    reads = []

    def read() -> float:  # 20 readings (≥ 0.4 s at one per 20 ms, > STILL_S) the same, then where it stopped
        reads.append(1)
        return 21.0 if len(reads) <= 20 else 24.0

    seen = watch_still(read, lambda deg: f"{deg}°", 1e-4, busy=lambda: len(reads) <= 20)
    assert seen.still and seen.where == "24.0°"
    reads.clear()
    assert watch_still(read, lambda deg: f"{deg}°", 1e-4).where == "21.0°"  # without the controller's word: fooled
    reads.clear()
    never = watch_still(read, lambda deg: f"{deg}°", 1e-4, timeout_s=0.3, busy=lambda: True)
    assert not never.still and "still executed a move" in never.why


def test_the_console_says_which_machine_may_still_be_moving(capsys):
    from rtcal.cli.run import _say_still_moving

    exc = KeyboardInterrupt("interrupted by SIGINT (Ctrl-C)")
    exc.__notes__ = ["(the status could not be recorded)", "WARNING: stage may still be moving (last seen at 45.100000°): "
                     "its position still changed 5 s after the stop; stop it at the machine"]
    _say_still_moving(exc)
    assert capsys.readouterr().err == ("rtcal: WARNING: stage may still be moving (last seen at 45.100000°): its position "
                                       "still changed 5 s after the stop; stop it at the machine\n")
