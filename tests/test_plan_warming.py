"""Issue 28, item 6: `rtcal plan --target-u 1.0` in a real room — the table warming 0.3 K/h, a sensor
reading it — proposes U ≤ 1″ (k = 2) in ≤ 2.0 h including the operator's steps (moving and
re-referencing the tracer, every tracer sample), and the proposal holds in the Monte Carlo.

The bench (tests/data/plan/warming_bench.yaml) is paper 000's with the table and the tracer on it growing
11.5 ppm/K about the axis and the table warming 0.3 K/h from 20 °C; the procedure is the shipped one.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
from pathlib import Path

import pytest
import yaml

from rtcal.cli import main
from rtcal.methods.multistation import planner as msp
from rtcal.methods.planner import Candidate
from rtcal.planning import levers as lv
from rtcal.methods import load_procedure
from rtcal.methods.multistation.procedure import LaserTracerMultistation, MultistationDurations
from simulators.scenario import Scenario

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "procedures" / "laser_tracer_multistation.yaml"
WARMING = Path(__file__).parent / "data" / "plan" / "warming_bench.yaml"
TWO_HOURS_S = 7200.0


def _base() -> tuple[Candidate, LaserTracerMultistation]:
    proc = load_procedure(SHIPPED)
    assert isinstance(proc, LaserTracerMultistation)
    scenario = Scenario.model_validate(yaml.safe_load(WARMING.read_text(encoding="utf-8")))
    return lv.base_plan(SHIPPED, scenario), proc


def test_the_walk_counts_what_the_simulated_clock_counts_operator_steps_included():
    """The search orders its candidates by the walked machine time: it must be the simulated run's (the
    time a plan is proposed with), and a second mount must cost the operator's move and a new reference."""
    base, proc = _base()
    one = msp.station_major(msp.concurrent_motions(msp.shortest_point_path(msp.point_layers(base, 2))))
    two = msp.station_major(msp.concurrent_motions(msp.shortest_point_path(msp.point_layers(msp.second_mount(base, proc), 2))))
    walked_one, walked_two = lv.walked_duration_s(one), lv.walked_duration_s(two)
    d = MultistationDurations()
    # the operator moves the tracer, then references it anew (the machines' first approach counted once: ≤ 60 s)
    assert walked_two == pytest.approx(2 * walked_one + d.move_tracer_s, abs=60.0)
    assert walked_two > 2 * walked_one + 0.9 * d.move_tracer_s
    assert lv.walked_duration_s(msp.more_samples(one, 4)) - walked_one == pytest.approx(
        3 * d.tracer_sample_s * (32 * proc.stations.count + 1), rel=1e-6)  # every sample takes its time (+1: the
    #                                                               length read again where the tracer was referenced)
    grid = msp.point_layers(base, 2)
    assert lv.walked_duration_s(msp.shortest_point_path(grid)) < lv.walked_duration_s(grid)  # the CMM's path is shorter
    simulated = lv.evaluate(two)
    assert simulated.duration_s == pytest.approx(walked_two, abs=1.0)


def test_the_warming_room_proposal_meets_two_hours_and_one_arcsec():
    """The search on the warming bench (the planner's walk orders the candidates, each predicted U is a
    noise-free run's budget): the proposal's U ≤ 0.9″ (1″ less the 10 % margin) and machine time ≤ 2 h,
    with the table's expansion stated so that the sensor's temperature corrects the lengths."""
    base, proc = _base()
    p = lv.propose(base, proc, 1.0, explain=False)
    assert p.best is not None, [o.summary() for o in p.tried]
    best = p.best
    assert best.expanded_max_arcsec <= 0.9 and best.recommended == "network"
    assert best.duration_s <= TWO_HOURS_S
    assert best.duration_s == pytest.approx(lv.walked_duration_s(best.plan), abs=1.0)
    data = best.plan.procedure
    assert data["second_mount"] and data["uncertainty"]["table_expansion_ppm_per_k"] == 11.5
    # every plan tried before it is shorter (the search's order) and none of them reached the goal
    assert all(o.expanded_max_arcsec > 0.9 for o in p.tried[:-1])
    assert all(o.duration_s <= best.duration_s + 1.0 for o in p.tried)


def _plan_json(args: list[str]) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(args) == 0
    return json.loads(out.getvalue())


@pytest.mark.campaign
def test_the_warming_room_proposal_is_covered_campaign(tmp_path):
    """`rtcal plan --target-u 1.0 --scenario WARMING` then `rtcal uncertainty` on what it wrote (its bench
    warming 0.3 K/h beside it; every noise, the CMM's errors and the error motions drawn): the reported U
    ≤ 1″ at every target and it covers the error at ≥ 95 % of the (trial, target) pairs (108 balanced trials,
    the fewest `--balanced` takes here: measured 95.8 % of 1080, reported U at most 0.72″, RMS σ / RMS error
    0.318″ / 0.320″; 40 plain trials gave 94.0 %, within their sampling); each lever's effect is in the JSON
    and their times add up to the proposal's."""
    out = tmp_path / "u1.yaml"
    plan = _plan_json(["plan", str(SHIPPED), "--scenario", str(WARMING), "--target-u", "1.0", "--out", str(out),
                       "--json", "--no-levers"])
    proposal = plan["proposal"]["plan"]
    assert proposal["duration_s"] <= TWO_HOURS_S and proposal["expanded_uncertainty_max_arcsec"] <= 0.9
    buys = proposal["levers_buy"]
    assert [b["lever"] for b in buys] == proposal["changes"]
    assert sum(b["seconds"] for b in buys) == pytest.approx(proposal["duration_s"] - plan["duration_s"], abs=1.0)
    bench = yaml.safe_load(out.with_name("u1.bench.yaml").read_text(encoding="utf-8"))
    assert bench["environment"]["material_temperature_drift_k_per_h"] == 0.3
    mc = tmp_path / "mc"
    assert main(["uncertainty", str(out), "--trials", "108", "--balanced", "--workers", "2", "--out", str(mc)]) == 0
    s = json.loads((mc / "uncertainty.json").read_text())
    e = s["estimators"][s["recommended"]]
    print(f"recommended {s['recommended']}: coverage {e['overall']['coverage_k2']:.3f}, reported U max "
          f"{2 * max(e['rms_reported_sigma_arcsec'][1:]):.3f}″, 2 × RMS error {2 * e['overall']['rms_error_arcsec']:.3f}″")
    assert s["failed_trials"] == 0
    assert 2 * max(e["rms_reported_sigma_arcsec"][1:]) <= 1.0
    assert e["overall"]["coverage_k2"] >= 0.95
    assert math.isfinite(e["overall"]["rms_error_arcsec"])
