"""`rtcal plan`: the budget's dominant sources, each lever's predicted U and machine time, and
`--target-u`'s proposal, verified by the Monte Carlo of whole simulated runs (`rtcal uncertainty`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from rtcal.methods.multistation.procedure import MultistationDurations

from rtcal.cli import main
from rtcal.methods.planner import Candidate
from rtcal.planning import levers as lv
from rtcal.methods import load_procedure
from rtcal.run.runner import resolve_scenario

pytestmark = pytest.mark.xdist_group("plan_levers")  # one worker, in order: the module's proposal computed once

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "procedures" / "laser_tracer_multistation.yaml"
ABBE = REPO / "procedures" / "encoder_abbe_error.yaml"


def _error_motions(sources: dict[str, float]) -> float:
    return float(np.sqrt(sum(v**2 for k, v in sources.items() if k.startswith(lv.ERROR_MOTION_PREFIX))))


@pytest.fixture(scope="module")
def proposal(tmp_path_factory):
    """`rtcal plan SHIPPED --json --target-u 1.0 --out …` once for the module: (JSON, folder)."""
    folder = tmp_path_factory.mktemp("proposal")
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["plan", str(SHIPPED), "--json", "--target-u", "1.0", "--out", str(folder / "proposed.yaml")])
    assert code == 0
    return json.loads(out.getvalue()), folder


def test_plan_json_names_the_dominant_sources_and_every_lever(proposal):
    """One JSON object: U (k = 2) of the recommended estimator at its worst target, the machine time, the
    dominant sources (the error motions one mount cannot separate: most of the variance) and a row per lever.
    Physics the rows must show: the error-motion term falls as 1/R with the tracer's distance from the axis
    (radial motion δ and tilt ε·h both move the tracer sideways by a length, an angle of length/R), to within
    5 % (the estimator's geometry changes a little with R); a second mount measures the error motions, so
    they leave the budget; the lever table's durations are the simulated clock's."""
    plan, _ = proposal
    assert plan["recommended"] and plan["expanded_uncertainty_max_arcsec"] > 0 and plan["duration_s"] > 0
    shares = {d["source"]: d["share"] for d in plan["dominant_sources"]}
    assert sum(v for k, v in shares.items() if k.startswith(lv.ERROR_MOTION_PREFIX)) > 0.7, shares
    rows = {row["lever"]: row for row in plan["levers"]}
    radius = [r for k, r in rows.items() if k.startswith("tracer ")]
    assert len(radius) == 2
    budget = plan["estimators"][plan["recommended"]]["budget"]
    base_em = _error_motions({k: float(np.sqrt(np.mean(np.square(v[1:])))) for k, v in budget.items()})
    for row in radius:
        factor = float(row["lever"].split("×")[1].rstrip(")"))
        ratio = _error_motions(row["sources_rms_arcsec"]) / base_em
        assert abs(ratio * factor - 1) < 0.05, (row["lever"], ratio, factor)
        assert row["duration_s"] == pytest.approx(plan["duration_s"], rel=1e-3)
    two = rows["a second tracer mount opposite the first"]
    assert two["recommended"] == "network" and _error_motions(two["sources_rms_arcsec"]) == 0
    assert two["expanded_uncertainty_max_arcsec"] < plan["expanded_uncertainty_max_arcsec"] / 3
    moving = MultistationDurations()  # the operator moves the tracer and references it again: honest machine time
    assert two["duration_s"] == pytest.approx(2 * plan["duration_s"] + moving.move_tracer_s, rel=0.05)
    assert two["duration_s"] > 2 * plan["duration_s"] + 0.9 * moving.move_tracer_s
    fewer = [r for k, r in rows.items() if "CMM points (2 layers" in k]
    assert fewer and fewer[0]["duration_s"] < 0.6 * plan["duration_s"]


def test_target_u_proposes_a_plan_that_validates_and_writes_nothing_else(proposal):
    plan, folder = proposal
    p = plan["proposal"]
    assert p["reached"] and p["plan"]["expanded_uncertainty_max_arcsec"] <= 1.0 * (1 - p["margin"])
    assert "a second tracer mount opposite the first" in p["plan"]["changes"]
    written = {Path(w).name for w in p["written"]}
    assert written == {"proposed.yaml", "proposed.bench.yaml"}  # the bench moves the tracer: named with it
    assert {f.name for f in folder.iterdir()} == written  # no stray files
    assert main(["validate", str(folder / "proposed.yaml")]) == 0
    proc = load_procedure(folder / "proposed.yaml")
    assert proc.second_mount is not None


def test_the_proposal_is_verified_by_a_small_monte_carlo(proposal, tmp_path):
    """6 simulated runs of the proposed plan (tracer, CMM and stage noise, CMM errors and error motions
    drawn within the stated uncertainties). 6 trials know a target's RMS error to ±1/√12 = 29 % (1σ);
    pooled over the 10 targets (correlated: about 3 independent) to ±1/√(2·6·3) ≈ 17 %. Checked: every
    trial's reported U within the target, and 2 × the pooled RMS error within the target × (1 + 2·17 %).
    The 200-trial verification per target is under `pytest -m campaign`."""
    _, folder = proposal
    out = tmp_path / "mc"
    assert main(["uncertainty", str(folder / "proposed.yaml"), "--trials", "6", "--workers", "2", "--out", str(out)]) == 0
    s = json.loads((out / "uncertainty.json").read_text())
    assert s["failed_trials"] == 0 and s["recommended"] == "network"
    e = s["estimators"]["network"]
    assert max(v for v in e["rms_reported_sigma_arcsec"][1:]) * 2 <= 1.0
    assert 2 * e["overall"]["rms_error_arcsec"] <= 1.0 * (1 + 2 * 0.17), e["overall"]


@pytest.mark.campaign
def test_the_proposal_is_verified_by_200_balanced_runs(proposal, tmp_path):
    """`rtcal uncertainty` with 200 balanced trials: per target the RMS error is known to ±5 % (1σ); the
    verified U (k = 2) = 2 × RMS error must be ≤ 1.0″ at every target, and the reported σ within
    0.8–1.25× the RMS error."""
    _, folder = proposal
    out = tmp_path / "mc"
    assert main(["uncertainty", str(folder / "proposed.yaml"), "--trials", "200", "--balanced", "--workers", "2",
                 "--out", str(out)]) == 0
    s = json.loads((out / "uncertainty.json").read_text())
    e = s["estimators"][s["recommended"]]
    verified = [2 * v for v in e["rms_error_arcsec"][1:]]
    print(f"verified U per target: {', '.join(f'{v:.3f}' for v in verified)}″; ratio {e['ratio'][1:]}")
    assert max(verified) <= 1.0, verified
    assert all(0.8 <= r <= 1.25 for r in e["ratio"][1:]), e["ratio"]


def _fake_outcome(plan: Candidate) -> lv.Outcome:
    """A stand-in prediction: U falls with points and a second mount, time grows with the readings."""
    layers = plan.procedure.get("points", {}).get("layers", 4)
    mounts = 2 if "second_mount" in plan.procedure else 1
    em = 0.0 if mounts == 2 else 6.0
    noise = 1.6 / math.sqrt(layers / 2 * mounts)
    u = math.hypot(em, noise)
    contributions = {"error motions, radial (EXC, EYC)": [0.0, em / 2], "tracer length noise": [0.0, noise / 2]}
    return lv.Outcome(plan, "network", u, 1000.0 * layers * mounts, 176 * layers * mounts, {}, contributions)


def test_the_search_takes_the_shortest_plan_and_skips_one_mount_once_its_error_motions_exceed(tmp_path):
    proc = load_procedure(SHIPPED)
    scenario, _ = resolve_scenario(SHIPPED, proc, None)
    base = lv.base_plan(SHIPPED, scenario)
    p = lv.propose(base, proc, 1.0, margin=0.1, evaluate_plan=_fake_outcome)
    assert p.best is not None and "second_mount" in p.best.plan.procedure
    # two mounts: U = 1.6/√layers — 2 layers 1.13″, 3 layers 0.92″, 4 layers 0.80″: the first within 0.9″ is 4 layers
    assert p.best.plan.procedure["points"]["layers"] == 4 and p.best.duration_s == 8000.0
    assert p.skipped and all("second" not in s for s in p.skipped)
    none = lv.propose(base, proc, 0.1, evaluate_plan=_fake_outcome)
    assert none.best is None and none.smallest is not None
    assert none.smallest.expanded_max_arcsec == min(o.expanded_max_arcsec for o in none.tried)


def test_no_plan_reaches_the_target_exit_1_with_the_smallest_u(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(lv, "evaluate", _fake_outcome)
    out = tmp_path / "never.yaml"
    assert main(["plan", str(SHIPPED), "--target-u", "0.1", "--out", str(out), "--no-levers"]) == 1
    text = capsys.readouterr().out
    assert "no plan reaches U ≤ 0.1″" in text and "the smallest U found is" in text
    assert not out.exists() and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, message", [
    (["--target-u", "1"], "--target-u: give --out FILE.yaml"),
    (["--target-u", "0", "--out", "x.yaml"], "--target-u 0: must be"),
    (["--target-u", "1", "--out", "x.yaml", "--margin", "1.5"], "--margin 1.5: must lie in 0 … 1"),
    (["--out", "x.yaml"], "--out: goes with --target-u"),
    (["--target-u", "1", "--out", "x.yaml", "--optimize", "y.yaml"], "--optimize and --target-u: choose one"),
    (["--max-radius-mm", "-3"], "--max-radius-mm -3: must lie"),
    (["--target-u", "1", "--out", "nowhere/x.yaml"], "--out nowhere/x.yaml: its folder nowhere does not exist"),
])
def test_plan_arguments_are_refused_on_one_line(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    assert main(["plan", str(SHIPPED), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err


def test_abbe_levers_are_its_runs(tmp_path, capsys):
    assert main(["plan", str(ABBE), "--json"]) == 0
    plan = json.loads(capsys.readouterr().out)
    runs = [r for r in plan["levers"] if r["lever"].endswith("runs")]
    assert len(runs) == 2 and all(r["expanded_uncertainty_max_arcsec"] < plan["expanded_uncertainty_max_arcsec"] for r in runs)
    assert all(r["duration_s"] > plan["duration_s"] for r in runs)


def test_a_procedure_of_real_instruments_is_planned_on_the_bench_without_connecting(tmp_path, capsys):
    """Every instrument at an address nobody listens on: the prediction runs on the simulated bench as
    the procedure is written (a connection would fail: exit 1), and the proposal keeps the addresses."""
    text = SHIPPED.read_text()
    for old, new in (("stage: {backend: sim}", 'stage: {address: "modbus-tcp://127.0.0.1:9?unit=1&steps_per_rev=10000&gear=36"}'),
                     ("cmm: {backend: sim, tool: CatEye}", 'cmm: {address: "ipp://127.0.0.1:9", tool: CatEye}'),
                     ("laser_tracer: {backend: sim}", 'laser_tracer: {address: "socket://127.0.0.1:9?model=rtcal-line"}'),
                     ("environment: {backend: sim}", 'environment: {address: "socket://127.0.0.1:9?model=vaisala-ptu300"}')):
        assert old in text
        text = text.replace(old, new, 1)
    (tmp_path / "scenarios").mkdir()
    (tmp_path / "scenarios" / "paper000_bench.yaml").write_text((SHIPPED.parent / "scenarios" / "paper000_bench.yaml").read_text())
    (tmp_path / "hw.yaml").write_text(text)
    assert main(["plan", str(tmp_path / "hw.yaml"), "--json", "--no-levers"]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert main(["plan", str(SHIPPED), "--json", "--no-levers"]) == 0
    on_sim = json.loads(capsys.readouterr().out)
    for key in ("recommended", "expanded_uncertainty_max_arcsec", "duration_s", "raw_readings"):
        assert plan[key] == on_sim[key], key  # the same plan: the same prediction
