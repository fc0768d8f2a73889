"""Issue 28: uncertainty that holds in a real room — a warming table, air that does not drift in
straight lines, the autocollimator's own calibration, CMM errors beyond the affine model.

Fast tests check the pieces (the simulator's profiles and growth, the bounded-course bound, the
residual test); the Monte Carlo ones run whole simulated calibrations on the benches in
tests/data/budget/ (shared with no other test): a few trials here, the full campaigns behind
``@pytest.mark.campaign``. Coverage is the share of (trial, target) pairs whose error the
recommended estimate's U (k = 2) covers.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from rtcal.clock import VirtualClock
from rtcal.planning.montecarlo import plan_trials, run_trial, summarize
from rtcal.methods import load_procedure
from rtcal.solvers.station_budget import bounded_course_component
from rtcal.solvers.uncertainty import Covariance, residual_check
from simulators.bench import Bench
from simulators.scenario import Scenario

DATA = Path(__file__).parent / "data" / "budget"


def _scenario(path: Path) -> Scenario:
    return Scenario.model_validate(yaml.safe_load(path.read_text(encoding="utf-8")))


def test_profiles_are_piecewise_linear_from_the_first_reading_and_flat_outside():
    sc = Scenario.model_validate({"environment": {"air_temperature_c": 20.0, "air_temperature_drift_k_per_h": 1.0,
                                                  "air_temperature_profile": [[100, 0.0], [200, 2.0]],
                                                  "material_temperature_profile": [[0, -1.0], [3600, 1.0]]}})
    clock = VirtualClock()
    bench = Bench(sc, clock, 0)
    clock.sleep(360.0)  # before the first reading: the first offsets, plus the drift since the clock's 0
    assert bench.environment()[0] == pytest.approx(20.1)
    assert bench.environment()[3] == pytest.approx(19.0)
    bench.reading()  # the profiles' time 0
    clock.sleep(150.0)  # half-way up the ramp
    t_air, _, _, t_mat = bench.environment()
    assert t_air == pytest.approx(20.0 + 510.0 / 3600.0 + 1.0)
    assert t_mat == pytest.approx(19.0 + 2.0 * 150.0 / 3600.0)
    clock.sleep(10_000.0)  # after the last point: the last offsets
    assert bench.environment()[0] == pytest.approx(20.0 + 10_510.0 / 3600.0 + 2.0)
    assert bench.environment()[3] == pytest.approx(21.0)
    with pytest.raises(ValueError, match="must not decrease"):
        Scenario.model_validate({"environment": {"humidity_profile": [[10, 1.0], [5, 2.0]]}})


def test_the_table_grows_radially_about_the_axis_with_its_temperature():
    sc = Scenario.model_validate({"stage": {"thermal_expansion_ppm_per_k": 11.5},
                                  "environment": {"material_temperature_c": 22.0}})
    warm, cold = Bench(sc, VirtualClock(), 0), Bench(sc.model_copy(update={"environment": sc.environment.model_copy(
        update={"material_temperature_c": 20.0})}), VirtualClock(), 0)
    p_warm, p_cold = warm.tracer_center_mm(), cold.tracer_center_mm()
    r_cold = math.hypot(*p_cold[:2])
    assert math.hypot(*p_warm[:2]) - r_cold == pytest.approx(r_cold * 11.5e-6 * 2.0, rel=1e-6)
    assert p_warm[2] == pytest.approx(p_cold[2])  # radially only
    assert math.atan2(p_warm[1], p_warm[0]) == pytest.approx(math.atan2(p_cold[1], p_cold[0]))


def test_the_bounded_course_covers_every_step_and_cycle_within_the_range():
    """The bound of :func:`bounded_course_component` (σ·√3) is never exceeded by a course within ±B of
    total variation ≤ 4B, whatever the influence; a straight-line model's σ would be (checked: the
    worst course exceeds what a linear drift does)."""
    rng = np.random.default_rng(28)
    m, N, B = 6, 300, 0.7
    W = rng.standard_normal((m, N))
    s = rng.uniform(0.5, 1.5, N)
    t = np.sort(rng.uniform(-1, 1, N))
    c = bounded_course_component("x", W, s, t, B, "K", "")
    bound = np.sqrt(np.diag(c.covariance_arcsec2)) * np.sqrt(3.0)
    worst_seen = np.zeros(m)
    for _ in range(400):
        kind = rng.integers(3)
        if kind == 0:  # a step anywhere between any two levels within the range
            a, b = rng.uniform(-B, B, 2)
            g = np.where(t < rng.uniform(-1, 1), a, b)
        elif kind == 1:  # one cycle of any phase within the range
            g = B * np.sin(np.pi * (t + 1) + rng.uniform(0, 2 * np.pi))
        else:  # a drift
            a, b = rng.uniform(-B, B, 2)
            g = a + (b - a) * (t + 1) / 2
        e = np.abs(W @ (s * g))
        assert np.all(e <= bound * (1 + 1e-9))
        worst_seen = np.maximum(worst_seen, e)
    assert np.all(worst_seen > 0.1 * bound)  # the bound is not vacuous: random courses come within 10× of it
    # the worst step for each target (at the peak of its step response) reaches half the bound or more
    S = np.cumsum((W * s)[:, ::-1], axis=1)[:, ::-1]
    assert np.all(2 * B * np.max(np.abs(S), axis=1) >= bound / 2.5)


def test_the_residual_test_passes_noise_as_stated_and_fails_a_model_error():
    rng = np.random.default_rng(5)
    N, p = 600, 20
    sigma = np.sqrt(rng.uniform(0.5, 2.0, N))
    V = Covariance((sigma,))  # one independent error per residual
    r = rng.standard_normal(N) * sigma
    ok = residual_check(r, V, p)
    assert ok is not None and ok.passed and 0.85 < ok.birge_ratio < 1.15
    bad = residual_check(r + 3.0 * np.sin(np.linspace(0, 6, N)), V, p)
    assert bad is not None and not bad.passed and bad.birge_ratio > 1.5
    assert "FAILS" in bad.words() and "passes" in ok.words()


def _coverage(case: str, trials: int, seed: int = 2800, fixed: bool = False, balanced: bool = False,
              bench: str | None = None) -> dict:
    proc_path = DATA / f"{case}.yaml"
    proc = load_procedure(proc_path)
    bench = _scenario(DATA / f"{bench or case}_bench.yaml")
    tmp = Path(__import__("tempfile").mkdtemp(prefix=f"mc-{case}-"))
    specs = plan_trials(proc_path, proc, bench, trials, seed, tmp, vary_systematics=not fixed, balanced=balanced)
    results = [run_trial(s) for s in specs]
    return summarize(results, results[0]["labels"])


def _recommended_coverage(summary: dict) -> float:
    return summary["estimators"][summary["recommended"]]["overall"]["coverage_k2"]


@pytest.mark.parametrize("case", ["warming_sensor", "air_step"])
def test_a_real_room_is_covered_in_a_few_trials(case):
    """CI's bounded version: two trials; loose (≥ 80 % of the pairs) but it fails when the budget ignores
    the warming or the step (measured before the new terms: 13 % and 86 % at 1 K/h and a 1.8 K step)."""
    summary = _coverage(case, 2)
    assert summary["failed_trials"] == 0
    assert _recommended_coverage(summary) >= 0.8


@pytest.mark.campaign
@pytest.mark.parametrize("case", ["warming_range", "air_step", "air_cycle"])
def test_a_real_room_is_covered_campaign(case):
    """The systematic draws in moment-matched antithetic pairs (`--balanced`): their sampling does not decide."""
    summary = _coverage(case, 40, balanced=True)
    assert _recommended_coverage(summary) >= 0.95


@pytest.mark.campaign
def test_a_warming_table_read_by_the_sensor_costs_nothing_campaign():
    """Warming 1 K/h, corrected from the sensor: the recommended coverage is the cold bench's (same noise,
    same trial seeds) and at least 93 % (measured: 93.75 % both; the network's own calibration on this
    bench, not the warming, keeps it under 95 %; docs/paper000.md)."""
    warm, cold = _coverage("warming_sensor", 40, seed=2801), _coverage("cold_sensor", 40, seed=2801)
    assert _recommended_coverage(warm) >= _recommended_coverage(cold) - 0.01
    assert _recommended_coverage(warm) >= 0.93


@pytest.mark.campaign
def test_the_autocollimator_scale_within_its_certificate_is_covered_campaign():
    """The scale error drawn per trial from its certificate (N(0, u), GUM S1): ≥ 95 % (measured 95.7 % of
    120 × 23). Fixed at the certificate's U (2u, the edge): the term lifts coverage above the budget
    without it (measured 89.7 % against 83.7 %, and 95.0 % against 90.4 % with another seed)."""
    assert _recommended_coverage(_coverage("iso_scale", 120)) >= 0.95
    with_term = _recommended_coverage(_coverage("iso_scale", 40, fixed=True))
    without = _recommended_coverage(_coverage("iso_noterm", 40, fixed=True, bench="iso_scale"))
    assert with_term >= without + 0.03 and with_term >= 0.88


@pytest.mark.campaign
def test_a_smooth_cmm_field_is_covered_or_named_campaign():
    summary = _coverage("cmm_field", 40)
    assert _recommended_coverage(summary) >= 0.95


def test_a_partial_error_motion_bound_and_the_cmm_geometry_are_named():
    from rtcal.methods.multistation.method import not_included

    notes = not_included(load_procedure(Path(__file__).parents[1] / "procedures" / "laser_tracer_multistation.yaml"))
    assert any("axial (EZC)" in n and "no bound stated while the others are" in n for n in notes)
    assert any(n.startswith("CMM geometry beyond") for n in notes)


def test_the_autocollimator_calibration_enters_the_iso_budget():
    from rtcal.run.runner import run_procedure

    run_dir = Path(__import__("tempfile").mkdtemp()) / "run"
    out = run_procedure(str(DATA / "iso_scale.yaml"), DATA / "iso_scale_bench.yaml", 3, run_dir, show_progress=False)
    budget = getattr(out.results.estimates, out.results.recommended).uncertainty_budget
    names = {c.source: c for c in budget.components}
    scale = names["autocollimator calibration (scale)"]
    assert scale.input_sigma == 5000
    assert max(v for v in scale.contribution_arcsec if v is not None) > 0.05  # 0.5 % of deflections of tens of ″
    assert "autocollimator calibration (certificate U)" in names
    # the certificate and the report state it as written, not "5e+03 ppm" (issue 46)
    for name in ("certificate.json", "report.md"):
        text = (run_dir / name).read_text(encoding="utf-8")
        assert "5000 ppm" in text and "e+03" not in text, name


def test_an_estimator_whose_residuals_the_stated_noise_cannot_explain_says_so():
    """A strong smooth CMM field (about 3.5 µm): every seed-000 estimator fails its residual test, says
    so in its status message and residual_test; on the 1 µm bench (same geometry) they pass."""
    from rtcal.run.runner import run_procedure

    out = run_procedure(str(DATA / "cmm_field.yaml"), DATA / "cmm_field_strong_bench.yaml", 5,
                        Path(__import__("tempfile").mkdtemp()) / "run", show_progress=False, outputs=False)
    r = out.results
    for name in ("paper", "shared_dead_path", "network"):
        test = getattr(r.estimates, name).residual_test
        assert test is not None and not test.passed and test.birge_ratio > 1.5
        assert "FAILS its residual test" in r.solver_status[name].message
    # the recommended estimate (none passes) names what its U leaves out, as its message does
    assert any("U is not a coverage interval" in n for n in getattr(r.estimates, r.recommended).uncertainty_budget.not_included)
    from rtcal.methods.multistation.outputs import MultistationOutputs

    assert any("FAILS its residual test" in line for line in MultistationOutputs(r).summary())
