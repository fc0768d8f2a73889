"""The engine on its own: a plan defined here (a stage and a probe, no YAML, no solver) run against fake
devices with faults injected step by step, every fault policy, pause / resume / abort from another
thread, the one safe-state path, and the walker that times the shipped plans without instruments."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from drivers.errors import InstrumentFault
from drivers.interfaces import FieldDescription, Instrument, StopSeen, Value
from rtcal.clock import VirtualClock
from rtcal.engine.engine import AbortRequested, Engine
from rtcal.engine.faults import RunAborted
from rtcal.engine.plan import Entry
from rtcal.engine.steps import Move, OperatorStep, Read, ReadSamples, Settle, Validate
from rtcal.engine.walk import Timing, walk
from rtcal.methods import METHODS
from rtcal.methods import load_procedure
from rtcal.procedure.models import FaultPolicy
from rtcal.engine.checks import Contradiction

ROOT = Path(__file__).resolve().parents[1]


class FakeStage:
    """Moves where told (time passes at 10°/s), unless the test scripted a fault for that call."""

    step_deg = 0.0

    def __init__(self, clock: VirtualClock, faults: dict[int, str] | None = None):
        self.clock, self.faults, self.calls, self.at, self.stopped = clock, faults or {}, 0, 0.0, 0

    def check_target(self, angle: float) -> None:
        if abs(angle) > 360:
            raise InstrumentFault("stage", f"target {angle} outside the limits")

    def position_deg(self) -> float:
        return self.at

    def move_to(self, angle: float) -> None:
        self.calls += 1
        if self.faults.get(self.calls) == "fault":
            raise InstrumentFault("stage", f"scripted fault at call {self.calls}")
        self.clock.sleep(abs(angle - self.at) / 10.0)
        self.at = angle

    def recover(self) -> None:
        pass

    def stop(self) -> None:
        self.stopped += 1

    def wait_stopped(self) -> StopSeen:
        return StopSeen(True, f"{self.at:g}°")


class FakeProbe(Instrument):
    """Reads the stage's angle times two; scripted calls fault, or read a value the plan's check refuses.
    It describes its one value, as every instrument does: the engine reads through ``read_values``."""

    kind = "probe"
    fields = (FieldDescription("twice_deg", "deg", "the stage's angle, twice"),)

    def __init__(self, stage: FakeStage, faults: dict[int, str] | None = None):
        self.stage, self.faults, self.calls = stage, faults or {}, 0

    def read(self) -> float:
        self.calls += 1
        kind = self.faults.get(self.calls)
        if kind == "fault":
            raise InstrumentFault("probe", f"scripted fault at read {self.calls}")
        if kind == "interrupt":
            raise KeyboardInterrupt
        return 999.0 if kind == "wrong" else 2.0 * self.stage.at

    def recover(self) -> None:
        pass

    def _raw_values(self, wanted: frozenset[str]) -> dict[str, Value]:
        return {"twice_deg": Value(self.read(), "deg")}


class TwoDevicePlan:
    """A method defined in the tests: visit each target, read the probe twice, check it against the command."""

    method = "test_two_device"
    retake_skipped = True

    def __init__(self, targets: list[float], probe_policy: FaultPolicy, stage_policy: FaultPolicy | None = None,
                 groups: int = 1):
        self.targets = targets
        self.policies = {"stage": stage_policy or FaultPolicy(retries=0, backoff_s=0.0), "probe": probe_policy}
        per = len(targets) // groups
        self.entries = [Entry(k, k // per, {"plan_index": k, "commanded_angle_deg": t}, {"target_deg": t}, f"visit {k}")
                        for k, t in enumerate(targets)]
        self.forgot = 0

    def prologue(self):
        yield Validate("stage", tuple(self.targets))

    def enter_group(self, entry, first):
        yield OperatorStep(f"set up group {entry.group}", f"set-up {entry.group}",
                           lambda hands, group=entry.group: hands.set_up(group), "set up", seconds=30.0)

    def positions_unknown(self):
        self.forgot += 1

    def leave_group(self, group, segment):
        return None

    def attempt(self, entry):
        target = self.targets[entry.index]
        yield Move("stage", target, what=f"move to {target}")
        yield Settle(1.0)
        for s in range(2):
            value = yield Read("probe", ("twice_deg",), None, 2 * target, "probe", sample=s)
            if abs(value - 2 * target) > 1e-9:
                raise Contradiction("probe", f"read {value} where {2 * target} was expected")


class Operator:
    """The simulated operator of the tests' bench: it carries each step out with its own hands."""

    def __init__(self):
        self.steps: list[tuple] = []

    def perform(self, step: OperatorStep) -> None:
        if step.simulate is not None:
            step.simulate(self)

    def hands(self):
        return self

    def set_up(self, group: int) -> None:
        self.steps.append(("set_up", group))

    def clear_fault(self, message: str) -> None:
        self.steps.append(("clear_fault", message))


def run_plan(plan, stage_faults=None, probe_faults=None, before=None):
    clock = VirtualClock()
    stage = FakeStage(clock, stage_faults)
    probe = FakeProbe(stage, probe_faults)
    docs: list[tuple[str, dict]] = []
    engine = Engine({"stage": stage, "probe": probe}, clock, Operator(), [lambda n, d: docs.append((n, d))])
    if before:
        before(engine)
    error = None
    try:
        stored = engine.run(plan)
    except BaseException as exc:  # noqa: BLE001 — the test looks at what the engine raised
        stored, error = None, exc
    readings = [r for n, d in docs if n == "readings" for r in d["readings"]]
    events = [d for n, d in docs if n == "event"]
    return stored, error, readings, events, stage, engine, docs


def test_plan_lists_its_steps_without_instruments():
    plan = TwoDevicePlan([0.0, 10.0, 20.0], FaultPolicy())
    w = walk(plan, Timing(stage_speed_deg_per_s=10.0), listing=True)
    assert [type(s).__name__ for s in w.listing[:7]] == ["Validate", "OperatorStep", "Move", "Settle", "Read", "Read", "Move"]
    assert [s.target for s in w.listing if isinstance(s, Move)] == [0.0, 10.0, 20.0]
    assert (w.planned_readings, w.instrument_readings) == (3, 6)
    assert w.steps == {"Validate": 1, "OperatorStep": 1, "Move": 3, "Settle": 3, "Read": 6}
    assert w.duration_s == pytest.approx(2.0 + 3.0 + 30.0)  # 20° at 10°/s, three settles, the set-up


@pytest.mark.parametrize("name", ["laser_tracer_multistation", "encoder_abbe_error", "iso230_2_polygon"])
def test_a_shipped_plan_is_data_listed_without_instruments(name):
    """Every step of a shipped plan is a frozen value naming its instrument; every reading names fields its
    instrument's kind describes, so the engine can read it through ``read_values`` (no step carries a driver call)."""
    from dataclasses import FrozenInstanceError, fields

    from drivers.factory import kind_of
    from drivers.kinds import describe_kind

    proc = load_procedure(ROOT / "procedures" / f"{name}.yaml")
    w = walk(METHODS[proc.method].plan(proc, set()), Timing(stage_speed_deg_per_s=10.0), listing=True)
    reads = [s for s in w.listing if isinstance(s, (Read, ReadSamples))]
    assert len(reads) >= w.planned_readings
    for step in reads:
        named = step.fields if isinstance(step, Read) else (step.field,)
        assert set(named) <= set(describe_kind(kind_of(step.instrument))), step
        assert not any(callable(getattr(step, f.name)) for f in fields(step) if f.name != "check"), step
    with pytest.raises(FrozenInstanceError):
        reads[0].instrument = "somewhere else"  # type: ignore[misc]


def test_clean_run_commits_each_attempt_and_emits_documents():
    plan = TwoDevicePlan([0.0, 10.0, 20.0], FaultPolicy())
    stored, error, readings, events, stage, engine, docs = run_plan(plan)
    assert error is None and stored == 3
    assert [(r.plan_index, r.sample, r.value) for r in readings] == [(0, 0, 0.0), (0, 1, 0.0), (1, 0, 20.0), (1, 1, 20.0),
                                                                     (2, 0, 40.0), (2, 1, 40.0)]
    assert len({r.attempt for r in readings}) == 3
    names = [n for n, _ in docs]
    assert names[0] == "start" and names[-1] == "stop" and names.count("done") == 3
    assert [e["kind"] for e in events] == ["operator"]
    assert stage.stopped == 0 and engine.state == "running"


def test_retry_then_success():
    plan = TwoDevicePlan([0.0, 10.0], FaultPolicy(retries=2, backoff_s=0.5))
    stored, error, readings, events, *_ = run_plan(plan, probe_faults={3: "fault"})
    assert error is None and stored == 2
    assert [e["kind"] for e in events] == ["operator", "fault", "retry"]


def test_skip_marks_the_attempt_and_retakes_it_after_the_pass():
    plan = TwoDevicePlan([0.0, 10.0, 20.0], FaultPolicy(retries=0, backoff_s=0.0, then="skip"))
    stored, error, readings, events, *_ = run_plan(plan, probe_faults={3: "fault"})
    assert error is None and stored == 3
    skipped = [r for r in readings if r.quantity == "skipped"]
    assert [(r.plan_index, r.instrument, r.sample) for r in skipped] == [(1, "probe", 0)]
    # the retake comes after the pass: plan index 1 is taken again last, in an attempt of its own
    assert [r.plan_index for r in readings if r.quantity == "twice_deg"][-2:] == [1, 1]
    assert len({r.attempt for r in readings if r.plan_index == 1}) == 2


def test_contradiction_is_kept_rejected_and_retaken():
    plan = TwoDevicePlan([0.0, 10.0], FaultPolicy(retries=1, backoff_s=0.0))
    stored, error, readings, events, *_ = run_plan(plan, probe_faults={3: "wrong"})
    assert error is None and stored == 2
    rejected = [r for r in readings if r.quantity == "rejected"]
    assert [(r.plan_index, r.instrument) for r in rejected] == [(1, "probe")]
    assert any(r.value == 999.0 for r in readings)  # the contradicted value is kept, marked by its attempt
    assert [e["kind"] for e in events][-2:] == ["fault", "retry"]


def test_abort_policy_stops_the_moved_devices_and_keeps_the_attempt():
    plan = TwoDevicePlan([0.0, 10.0, 20.0], FaultPolicy(retries=0, backoff_s=0.0, then="abort"))
    stored, error, readings, events, stage, engine, docs = run_plan(plan, probe_faults={3: "fault"})
    assert isinstance(error, RunAborted)
    assert stage.stopped == 1 and engine.state == "failed"
    assert [r.quantity for r in readings if r.plan_index == 1] == ["skipped"]  # the attempt in hand, marked
    assert [e["kind"] for e in events][-3:] == ["fault", "abort", "stopped"]
    assert events[-1]["instrument"] == "stage" and events[-1]["message"] == "stopped: seen at rest at 10°"


def test_ctrl_c_mid_attempt_stops_the_stage_and_keeps_what_was_read():
    plan = TwoDevicePlan([0.0, 10.0, 20.0], FaultPolicy())
    stored, error, readings, events, stage, engine, docs = run_plan(plan, probe_faults={4: "interrupt"})
    assert isinstance(error, KeyboardInterrupt)
    assert stage.stopped == 1 and engine.state == "aborted"
    kept = [(r.plan_index, r.quantity) for r in readings if r.plan_index == 1]
    assert kept == [(1, "twice_deg"), (1, "skipped")]
    assert docs[-1][0] == "stop"


def test_skips_in_a_row_abort():
    plan = TwoDevicePlan([0.0, 10.0, 20.0, 30.0], FaultPolicy(retries=0, backoff_s=0.0, then="skip", max_skips_in_a_row=2))
    stored, error, *_ = run_plan(plan, probe_faults={k: "fault" for k in range(1, 40)})
    assert isinstance(error, RunAborted)


def test_pause_holds_at_a_checkpoint_then_resume_approaches_anew():
    plan = TwoDevicePlan([0.0, 10.0, 20.0, 30.0], FaultPolicy())
    seen: dict[str, object] = {}

    def control(engine: Engine) -> None:
        original = engine._take

        def take(entry, done_count):  # pause after the first reading is committed
            ok = original(entry, done_count)
            if entry.index == 0:
                engine.request_pause()

                def later():
                    time.sleep(0.3)
                    seen["state"], seen["moves"] = engine.state, engine.devices["stage"].calls
                    time.sleep(0.2)
                    seen["moves_after"] = engine.devices["stage"].calls
                    engine.request_resume()

                threading.Thread(target=later, daemon=True).start()
            return ok

        engine._take = take

    stored, error, readings, events, stage, engine, docs = run_plan(plan, before=control)
    assert error is None and stored == 4
    assert seen["state"] == "paused" and seen["moves"] == seen["moves_after"] == 1  # the stage held still
    assert [e["kind"] for e in events] == ["operator", "pause", "resume"]
    assert plan.forgot == 1


def test_remote_abort_while_paused_stops_like_ctrl_c():
    plan = TwoDevicePlan([0.0, 10.0, 20.0], FaultPolicy())

    def control(engine: Engine) -> None:
        engine.request_pause()
        threading.Timer(0.2, engine.request_abort).start()

    stored, error, readings, events, stage, engine, docs = run_plan(plan, before=control)
    assert isinstance(error, AbortRequested) and isinstance(error, KeyboardInterrupt)
    assert stage.stopped == 1 and engine.state == "aborted"
    assert {r.plan_index for r in readings} == {0}


@pytest.mark.slow
@pytest.mark.parametrize("name", ["laser_tracer_multistation.yaml", "iso230_2_polygon.yaml", "concurrent"])
def test_walk_predicts_the_virtual_clock_of_the_run(name, tmp_path):
    """The walker's duration against the simulated run's clock (the same speeds, no noise); "concurrent": seed 000
    with the table and the CMM moving together."""
    from simulators.scenario_file import load_scenario
    from rtcal.run.runner import resolve_scenario, run_procedure

    path = ROOT / "procedures" / (name if name != "concurrent" else "laser_tracer_multistation.yaml")
    if name == "concurrent":
        text = path.read_text(encoding="utf-8")
        assert "concurrent_motions" not in text
        (tmp_path / "scenarios").mkdir()
        bench = ROOT / "procedures" / "scenarios" / "paper000_bench.yaml"
        (tmp_path / "scenarios" / bench.name).write_text(bench.read_text(encoding="utf-8"), encoding="utf-8")
        path = tmp_path / "concurrent.yaml"
        path.write_text(text + "\nconcurrent_motions: true\n", encoding="utf-8")
    proc = load_procedure(path)
    scenario, _ = resolve_scenario(path, proc, None)
    method = METHODS[proc.method]
    predicted = walk(method.plan(proc, set()), Timing.of_scenario(scenario))
    assert predicted.planned_readings == method.plan_length(proc)
    outcome = run_procedure(path, out_dir=tmp_path / "run", show_progress=False, outputs=False)
    measured = outcome.results.measurement_duration_s
    print(f"{name}: walked {predicted.duration_s:.1f} s, run's virtual clock {measured:.1f} s")
    assert predicted.duration_s == pytest.approx(measured, rel=0.01)
    assert load_scenario  # imported for the loader's side effects on the models


def test_concurrent_motions_save_machine_time_on_the_seed_000_plan():
    from rtcal.run.runner import resolve_scenario

    path = ROOT / "procedures" / "laser_tracer_multistation.yaml"
    proc = load_procedure(path)
    scenario, _ = resolve_scenario(path, proc, None)
    method = METHODS[proc.method]
    timing = Timing.of_scenario(scenario)
    one = walk(method.plan(proc, set()), timing)
    both = walk(METHODS[proc.method].plan(proc.model_copy(update={"concurrent_motions": True}), set()), timing)
    saved = one.duration_s - both.duration_s
    print(f"seed 000 plan: {one.duration_s:.0f} s one motion at a time, {both.duration_s:.0f} s with the table and the "
          f"CMM moving together: {saved:.0f} s ({100 * saved / one.duration_s:.1f} %) saved")
    assert 0 < saved < one.motion_s
    assert both.planned_readings == one.planned_readings


def test_console_progress_writes_a_line_every_10_percent_or_60_s_in_a_log():
    import io

    from rtcal.engine.subscribers import ConsoleProgress

    stream, wall = io.StringIO(), [0.0]
    progress = ConsoleProgress(stream, bar=False, now=lambda: wall[0])
    progress("start", {"planned": 40, "done": 0, "t_s": 0.0})
    for k in range(1, 41):
        progress("attempt", {"label": {"target_deg": 15.0 * k, "run": 1, "direction": "↑"}})
        wall[0] += 1.0 if k != 2 else 61.0  # one slow reading: a line after 60 s although no 10 % has passed
        progress("done", {"done": k, "faults": 1 if k > 30 else 0, "t_s": 10.0 * k})
    progress("stop", {"state": "measured"})
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("rtcal: readings 2/40 (5 %) · target 30°, run 1, direction ↑ · about 6:20 left, ends about ")
    assert lines[0].endswith(" · 0 faults")
    assert [line.split()[2] for line in lines[1:]] == [f"{4 * k}/40" for k in range(1, 11)]
    assert lines[-1].endswith("· 1 fault") and "left" in lines[-2]
    simulated = ConsoleProgress(io.StringIO(), bar=False, virtual_clock=True)  # the bench's time, not the wall's
    simulated("start", {"planned": 4, "done": 0, "t_s": 0.0})
    simulated("done", {"done": 1, "faults": 0, "t_s": 30.0})
    assert "about 1:30 left on the virtual clock" in simulated.line()


def test_store_writer_keeps_where_the_engine_is(tmp_path):
    import json

    from rtcal.engine.subscribers import StoreWriter
    from rtcal.store.runstore import Reading, RunStore

    store = RunStore.create(tmp_path, {"method": "test"})
    writer = StoreWriter(store)
    writer("start", {"planned": 3})
    writer("state", {"state": "running"})
    writer("attempt", {"index": 1, "label": {"target_deg": 15.0}})
    writer("readings", {"readings": [Reading(1.0, "probe", "x", 1.0, "deg", plan_index=1, attempt=0)]})
    meta = store.meta()
    assert (meta["planned_readings"], meta["engine_state"]) == ("3", "running")
    assert json.loads(meta["current"]) == {"target_deg": 15.0, "plan_index": 1}
    store.close()


def test_store_writer_writes_the_time_left_with_the_readings_not_in_a_transaction_of_its_own(tmp_path):
    """Issue 43: every planned reading done cost a second durable transaction for the time left (two fsyncs a
    reading). It now rides in the next reading's transaction, and has one of its own only after a second of
    wall time without; the store then holds the time left as of the last reading done."""
    from rtcal.engine.subscribers import ETA_KEY, Eta, StoreWriter
    from rtcal.store.runstore import Reading, RunStore

    store = RunStore.create(tmp_path, {"method": "test"})
    wall = [0.0]
    eta = Eta({k: (10.0, 0.0) for k in range(100)}, virtual_clock=True)
    writer = StoreWriter(store, eta, now=lambda: wall[0])
    transactions = []
    real = store._transaction
    store._transaction = lambda: (transactions.append(1), real())[1]  # type: ignore[method-assign]
    for doc in (("start", {"planned": 100, "done": 0, "t_s": 0.0}), ("state", {"state": "running", "t_s": 0.0})):
        eta(*doc)
        writer(*doc)
    transactions.clear()
    for k in range(50):
        writer("readings", {"readings": [Reading(10.0 * k, "probe", "x", 1.0, "deg", plan_index=k, attempt=k)]})
        done = ("done", {"index": k, "done": k + 1, "t_s": 10.0 * (k + 1)})
        eta(*done)
        writer(*done)
        wall[0] += 0.01  # a simulated run: 10 ms of wall time a reading
    assert len(transactions) <= 50 + 2  # one per reading (and one when a second has passed)
    writer("readings", {"readings": [Reading(500.0, "probe", "x", 1.0, "deg", plan_index=50, attempt=50)]})
    assert store.meta()[ETA_KEY] == f"{eta.eta_s():.1f}"  # as of the last reading done
    wall[0] += 5.0  # a run in real time: the time left is written when the reading is done
    eta("done", {"index": 50, "done": 51, "t_s": 510.0})
    writer("done", {"index": 50, "done": 51, "t_s": 510.0})
    assert store.meta()[ETA_KEY] == f"{eta.eta_s():.1f}"
    store.close()
