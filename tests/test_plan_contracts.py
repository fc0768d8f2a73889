"""What a method's plan may say, and what happens when it says something the engine cannot do (issue 41,
item 3): an operator step carries its own words and its simulated action, a plan entry's own context goes
into the store's ``context`` column when the method declares it, and a step the engine does not know or an
undeclared context stops the run safely as ``failed`` with an event saying why — never a traceback that
leaves the run ``interrupted`` with no word."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest

from rtcal.engine.engine import PlanError
from rtcal.engine.operator import BenchOperator, ConsoleOperator, OperatorUnavailable, RemoteSimOperator
from rtcal.engine.plan import Entry
from rtcal.engine.steps import OperatorStep
from rtcal.procedure.models import FaultPolicy
from rtcal.store.runstore import CONTEXT, Reading, RunStore, row_context
from tests.test_engine import TwoDevicePlan, run_plan


class ContextPlan(TwoDevicePlan):
    """The engine's test plan with a context of its own on every entry (the test ball's height)."""

    def __init__(self, targets, heights_mm, **kw):
        super().__init__(targets, FaultPolicy(), **kw)
        self.entries = [Entry(e.index, e.group, {**e.context, "ball_height_mm": h}, e.label, e.what)
                        for e, h in zip(self.entries, heights_mm)]


class UnknownStepPlan(TwoDevicePlan):
    """A plan that yields what is no step (a plugin written against another engine)."""

    def attempt(self, entry):
        yield "mount_ball"


def test_a_declared_context_goes_with_every_reading():
    plan = ContextPlan([0.0, 10.0], [40.0, 60.0])
    from tests.test_engine import FakeProbe, FakeStage, Operator
    from rtcal.clock import VirtualClock
    from rtcal.engine.engine import Engine

    clock = VirtualClock()
    stage = FakeStage(clock)
    docs: list = []
    engine = Engine({"stage": stage, "probe": FakeProbe(stage)}, clock, Operator(), [lambda n, d: docs.append((n, d))],
                    context_columns={"ball_height_mm": "the test ball's height above the table, mm"})
    assert engine.run(plan) == 2
    readings = [r for n, d in docs if n == "readings" for r in d["readings"]]
    assert [(r.plan_index, dict(r.context or {})) for r in readings] == [
        (0, {"ball_height_mm": 40.0}), (0, {"ball_height_mm": 40.0}), (1, {"ball_height_mm": 60.0}),
        (1, {"ball_height_mm": 60.0})]


def test_an_undeclared_context_stops_the_plan_before_anything_moves():
    stored, error, readings, events, stage, engine, docs = run_plan(ContextPlan([0.0, 10.0], [40.0, 60.0]))
    assert isinstance(error, PlanError) and "'ball_height_mm'" in str(error) and "context_columns" in str(error)
    assert stage.calls == 0 and readings == [], "nothing moved, nothing was read"
    assert engine.state == "failed" and events[-1]["kind"] == "abort" and "ball_height_mm" in events[-1]["message"]


def test_a_step_the_engine_does_not_know_is_a_failed_run_with_an_event():
    stored, error, readings, events, stage, engine, docs = run_plan(UnknownStepPlan([0.0, 10.0], FaultPolicy()))
    assert isinstance(error, PlanError) and "str is not a step the engine knows" in str(error)
    assert engine.state == "failed" and [d["state"] for n, d in docs if n == "stop"] == ["failed"]
    assert events[-1]["kind"] == "abort" and "the method's plan" in events[-1]["message"]


def test_an_operator_step_names_no_operator_method():
    """The old form (an operator method's name and its arguments) is refused where the plan makes it."""
    with pytest.raises(TypeError, match="names no operator method"):
        OperatorStep("mount_ball", (40.0,), "ball mounted")  # type: ignore[arg-type]
    step = OperatorStep("Mount the test ball at 40 mm.", "ball mounted", lambda hands: hands.mount_artefact(
        "test_ball", (0.0, 0.0, 40.0)), "mount the test ball")
    with pytest.raises(OperatorUnavailable, match="needs an operator to mount the test ball but there is no terminal"):
        ConsoleOperator().perform(step)  # pytest's stdin is no terminal


def test_the_simulated_operator_does_the_steps_action_on_the_bench_and_over_the_wire():
    from simulators.bench import Bench
    from simulators.scenario import Scenario
    from simulators.servers.hub import SimulatorHub

    step = OperatorStep("Mount the test ball at 40 mm.", "ball mounted", lambda hands: hands.mount_artefact(
        "test_ball", (0.0, 0.0, 40.0)), "mount the test ball")
    bench = Bench(Scenario())
    assert bench.artefact_mm("test_ball") is None
    BenchOperator(bench).perform(step)
    assert bench.artefact_mm("test_ball").tolist() == [0.0, 0.0, 40.0]
    with SimulatorHub(Scenario(), seed=1, serial="tcp") as hub:
        remote = RemoteSimOperator(hub.addresses["operator"])
        remote.ping()
        remote.perform(step)
        assert hub.bench.artefact_mm("test_ball").tolist() == [0.0, 0.0, 40.0]
        assert remote.hands().polygon_certificate_arcsec() == hub.bench.polygon_certificate_arcsec()
        with pytest.raises(OperatorUnavailable, match="refused rng"):
            remote.hands().rng("stage")  # only the bench's operator actions: nothing else of the bench
        with pytest.raises(OperatorUnavailable, match="refused mount_artefact"):
            remote.hands().mount_artefact("ball", "nowhere")


def test_row_context_keeps_the_stores_columns_and_gathers_the_declared_ones():
    row = row_context({"plan_index": 3, "run": 0, "ball_height_mm": 40.0, "tip": 2}, {"ball_height_mm", "tip"})
    assert row == {"plan_index": 3, "run": 0, CONTEXT: {"ball_height_mm": 40.0, "tip": 2}}
    assert row_context(row, {"ball_height_mm", "tip"}) == row, "applied twice it changes nothing"
    assert row_context({"plan_index": 3}) == {"plan_index": 3}
    with pytest.raises(ValueError, match="'tip', which is neither a column"):
        row_context({"plan_index": 3, "tip": 2}, {"ball_height_mm"})


def test_an_old_store_without_the_context_column_reads_resumes_and_keeps_its_digest(tmp_path: Path):
    """A store written before context columns: it opens (the column is added, NULL for every reading), its
    readings read back, and its digest — what its results.json recorded — is the same before and after."""
    from rtcal.run.integrity import store_digests

    store = RunStore.create(tmp_path, {"method": "encoder_abbe_error", "procedure_yaml": ""})
    store.add_readings([Reading(0.0, "encoder", "angle_deg", 1.5, "deg", plan_index=0, attempt=0)])
    store.close()
    with sqlite3.connect(tmp_path / "run.sqlite") as db:
        db.execute(f"ALTER TABLE readings DROP COLUMN {CONTEXT}")
        before = store_digests(db)
    store = RunStore.open(tmp_path)
    assert [(r.value, r.context) for r in store.readings()] == [(1.5, None)]
    store.add_readings([Reading(1.0, "probe", "y_um", 2.0, "um", plan_index=1, attempt=1, context={"ball_height_mm": 40.0})])
    assert [r.context for r in store.readings()] == [None, {"ball_height_mm": 40.0}]
    store.close()
    with sqlite3.connect(tmp_path / "run.sqlite") as db:
        after = store_digests(db)
        stored = db.execute(f"SELECT {CONTEXT} FROM readings ORDER BY id").fetchall()
    assert stored == [(None,), (json.dumps({"ball_height_mm": 40.0}),)]
    assert after.readings == 2 and after.readings_sha256 != before.readings_sha256, "a context is covered by the digest"
    with sqlite3.connect(tmp_path / "run.sqlite") as db:
        db.execute("DELETE FROM readings WHERE id = 2")
        assert store_digests(db).readings_sha256 == before.readings_sha256, "a row without context digests as it did"
