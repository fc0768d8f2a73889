"""An operator step confirmed from elsewhere: the waiting operator continues on Enter at its terminal or on
a remote confirm (whichever comes first), refuses a stray confirm, waits without a terminal only when the run
can be reached, and ends its wait on an abort; the engine hands it the control channel's confirm and
publishes what the person is asked; `rtcal control … confirm` reaches it over the control socket."""

from __future__ import annotations

import io
import os
import threading
import time

import pytest

from rtcal.clock import VirtualClock
from rtcal.engine.engine import Engine
from rtcal.engine.steps import OperatorStep
from rtcal.methods.abbe.plan import reseat_step
from rtcal.methods.multistation.plan import tracer_instruction
from rtcal.live.control import ControlRefused, ControlServer, new_token, send_control
from rtcal.procedure.models import FaultPolicy
from rtcal.engine.operator import (ConsoleOperator, NothingToConfirm, OperatorCancelled, OperatorUnavailable,
                                      WaitingOperator)
from tests.test_engine import FakeProbe, FakeStage, TwoDevicePlan
from tests.polling import wait_for as poll_until


def reseat(offset_deg: float, message: str = "seated") -> OperatorStep:
    """The Abbe method's polygon seating as its plan asks a person for it (15° faces)."""
    return reseat_step(offset_deg, 15.0, False, message, 0.0)


def wait_for(predicate, timeout_s: float = 10.0):
    """tests.polling.wait_for every 0.01 s (threads in this process: quick)."""
    return poll_until(predicate, timeout_s, 0.01)


class Waiting(threading.Thread):
    """One operator step of ``operator`` in a thread of its own (as the engine's thread waits in it)."""

    def __init__(self, operator: WaitingOperator, step=lambda op: op.perform(reseat(15.0))):
        super().__init__(daemon=True)
        self.operator, self.step, self.error = operator, step, None
        self.start()

    def run(self) -> None:
        try:
            self.step(self.operator)
        except BaseException as exc:  # noqa: BLE001 — the test looks at it
            self.error = exc


def operator(**kw) -> tuple[WaitingOperator, list]:
    heard: list = []
    op = WaitingOperator(poll_s=0.02, **{"terminal": lambda: None, "log": io.StringIO(), **kw})
    op.listen(lambda instruction, answer: heard.append((instruction, answer)))
    return op, heard


def test_a_remote_confirm_continues_and_a_stray_one_is_refused():
    op, heard = operator(remote=True, run_dir="runs/x")
    assert op.confirm() is False  # nothing waits: refused, nothing changes
    t = Waiting(op)
    wait_for(lambda: op.asking)
    assert "Seat the polygon turned by 1 face from its home seating" in op.asking
    time.sleep(0.1)
    assert t.is_alive()  # it waits
    assert op.confirm() is True
    t.join(5)
    assert not t.is_alive() and t.error is None
    assert op.confirm() is False and op.asking is None
    assert heard == [(heard[0][0], ""), (None, "remotely")] and "Seat the polygon" in heard[0][0]
    assert "`rtcal control runs/x confirm --step 1`" in op._log.getvalue() and "live page" in op._log.getvalue()


def test_a_late_confirm_for_a_step_already_answered_never_releases_the_next():
    """Step 1 confirmed (at the terminal, say); a Done still on its way for step 1 arrives while step 2
    (a fault to clear) waits: refused, step 2 still waits; a confirm naming step 2 releases it."""
    op, heard = operator(remote=True, run_dir="runs/x")
    first = Waiting(op)
    wait_for(lambda: op.asking)
    assert op.step == 1 and op.confirm(1) is True
    first.join(5)
    second = Waiting(op, lambda o: o.clear_fault("stage: E-stop"))
    wait_for(lambda: op.asking)
    assert op.step == 2 and op.confirm(1) is False  # the late Done for step 1
    time.sleep(0.1)
    assert second.is_alive() and op.asking
    assert op.confirm(2) is True
    second.join(5)
    assert not second.is_alive() and second.error is None
    assert [answer for instruction, answer in heard if instruction is None] == ["remotely", "remotely"]


def test_enter_at_the_terminal_continues_and_an_early_enter_does_not():
    r, w = os.pipe()
    out = io.StringIO()
    try:
        op, heard = operator(terminal=lambda: r, out=out)  # not remote: the terminal alone would do
        os.write(w, b"\n")  # pressed before the instruction was shown
        t = Waiting(op, lambda o: o.perform(OperatorStep(tracer_instruction(1, "the second mount"), "moved", task="move the laser tracer")))
        wait_for(lambda: "press Enter" in out.getvalue())
        time.sleep(0.15)
        assert t.is_alive()  # the early Enter confirmed nothing
        os.write(w, b"\n")
        t.join(5)
        assert not t.is_alive() and t.error is None
        assert heard[-1] == (None, "at the terminal")
        assert "Move the laser tracer to mount 2 (the second mount)" in out.getvalue()
        # with a terminal a remote confirm still comes first when it does
        t = Waiting(op)
        wait_for(lambda: op.asking)
        assert op.confirm() is True
        t.join(5)
        assert t.error is None and heard[-1] == (None, "remotely")
    finally:
        os.close(r)
        os.close(w)


def test_without_a_terminal_it_waits_only_when_the_run_can_be_reached():
    op, heard = operator(remote=False)
    with pytest.raises(OperatorUnavailable) as unreachable:
        op.perform(reseat(0.0))
    with pytest.raises(OperatorUnavailable) as console:  # the same message as before (pytest's stdin is no terminal)
        ConsoleOperator().perform(reseat(0.0))
    assert str(unreachable.value) == str(console.value) and "no terminal" in str(console.value)
    with pytest.raises(OperatorUnavailable, match="no terminal"):
        op.clear_fault("stage: e-stop")
    assert heard == []  # never asked


def test_an_abort_ends_the_wait():
    op, heard = operator(remote=True)
    t = Waiting(op, lambda o: o.clear_fault("stage: e-stop"))
    wait_for(lambda: op.asking)
    assert "Clear the fault (stage: e-stop)" in op.asking
    op.cancel()
    t.join(5)
    assert isinstance(t.error, OperatorCancelled) and isinstance(t.error, KeyboardInterrupt)
    assert heard[-1] == (None, "") and op.confirm() is False


class ReseatPlan(TwoDevicePlan):
    """The engine's test plan with the polygon seated by a person before each group."""

    def enter_group(self, entry, first):
        yield reseat(15.0 * entry.group, f"polygon seated (seating {entry.group + 1})")


def engine_run(plan, op, probe_faults=None):
    clock = VirtualClock()
    stage = FakeStage(clock)
    docs: list = []
    engine = Engine({"stage": stage, "probe": FakeProbe(stage, probe_faults)}, clock, op, [lambda n, d: docs.append((n, d))])
    result: dict = {}

    def run() -> None:
        try:
            result["stored"] = engine.run(plan)
        except BaseException as exc:  # noqa: BLE001
            result["error"] = exc

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return engine, stage, docs, result, thread


def asked(docs) -> list:
    return [d["instruction"] for n, d in docs if n == "operator"]


def test_the_engine_hands_the_confirm_to_the_waiting_operator():
    op, _ = operator(remote=True)
    engine, stage, docs, result, thread = engine_run(ReseatPlan([0.0, 10.0, 20.0, 30.0], FaultPolicy(), groups=2), op)
    for seating in (1, 2):
        wait_for(lambda: len(asked(docs)) == 2 * seating - 1)  # asked, not yet answered
        assert ("Seat the polygon in its home seating (faces in front of the autocollimator at table angles k·"
                if seating == 1 else "Seat the polygon turned by 1 face from") in asked(docs)[-1]  # not "by 0 face(s)"
        engine.request_confirm()
    thread.join(10)
    assert result == {"stored": 4}
    assert asked(docs)[1::2] == [None, None]
    kinds = [d["kind"] for n, d in docs if n == "event"]
    assert kinds == ["confirm", "operator", "confirm", "operator"]  # each step logged once done, after its confirm
    with pytest.raises(NothingToConfirm):  # nothing waits any more
        engine.request_confirm()


def test_a_fault_the_operator_clears_is_confirmed_remotely():
    op, _ = operator(remote=True)
    plan = ReseatPlan([0.0, 10.0], FaultPolicy(retries=0, backoff_s=0.0, then="pause"))
    engine, stage, docs, result, thread = engine_run(plan, op, probe_faults={3: "fault"})
    wait_for(lambda: asked(docs))
    engine.request_confirm()  # the seating
    wait_for(lambda: any(a and a.startswith("Clear the fault (probe:") for a in asked(docs)))
    engine.request_confirm()  # the fault cleared
    thread.join(10)
    assert result == {"stored": 2}
    kinds = [d["kind"] for n, d in docs if n == "event"]
    assert kinds == ["confirm", "operator", "fault", "pause", "confirm"]


def test_an_abort_while_the_operator_is_asked_stops_safe():
    op, _ = operator(remote=True)
    engine, stage, docs, result, thread = engine_run(ReseatPlan([0.0, 10.0, 20.0, 30.0], FaultPolicy(), groups=2), op)
    wait_for(lambda: asked(docs))
    engine.request_confirm()
    wait_for(lambda: len(asked(docs)) == 3)  # the second seating waits; the stage has moved
    engine.request_abort()
    thread.join(10)
    assert isinstance(result["error"], KeyboardInterrupt)
    assert engine.state == "aborted" and stage.stopped == 1
    assert asked(docs)[-1] is None  # the store hears that nothing waits any more


def test_rtcal_control_confirm_over_the_control_socket(tmp_path, capsys):
    from rtcal.cli import main

    op, _ = operator(remote=True)
    engine = Engine({}, VirtualClock(), op)
    token = new_token()
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    with ControlServer(run_dir, token, engine):
        with pytest.raises(ControlRefused) as refused:
            send_control(run_dir, token, "confirm")
        assert refused.value.reason == "nothing"
        assert main(["control", str(run_dir), "confirm", "--token", token]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "no operator step waits" in err
        t = Waiting(op)
        wait_for(lambda: op.asking)
        assert main(["control", str(run_dir), "confirm", "--token", ("y" if token[0] == "x" else "x") + token[1:]]) == 2  # a wrong token
        assert t.is_alive()
        assert main(["control", str(run_dir), "confirm", "--token", token, "--step", "2"]) == 2  # not the step that waits
        assert "operator step 2 does not wait now" in capsys.readouterr().err and t.is_alive()
        assert main(["control", str(run_dir), "confirm", "--token", token, "--step", "1"]) == 0
        t.join(5)
        assert t.error is None and not t.is_alive()


def test_the_seating_instruction_counts_faces_as_a_person_reads_them():
    """Issue 46: "turned by 0 face(s)" for the home seating; one face, two faces, a fraction in degrees."""
    from rtcal.methods.abbe.plan import reseat_instruction

    home = reseat_instruction(0.0, 15.0)
    assert home.startswith("Seat the polygon in its home seating (faces in front of the autocollimator at table angles "
                           "k·15°)") and "0 face" not in home
    assert reseat_instruction(15.0, 15.0).startswith("Seat the polygon turned by 1 face from its home seating")
    assert reseat_instruction(30.0, 15.0).startswith("Seat the polygon turned by 2 faces from")
    assert reseat_instruction(7.5, 15.0).startswith("Seat the polygon turned by 7.5° from")
    assert reseat_instruction(0.0, 15.0, resumed=True).startswith("The run resumes with the polygon in its home seating.")
