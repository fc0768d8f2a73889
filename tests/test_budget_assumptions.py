"""Issue 44: uncertainty where the room breaks the budget's assumptions — a gradient between the table's sensor and
the tracer's mount, the tracer's reference-sphere form, an unknown table material, the residual test without an air
sensor, a stated CMM field.

The benches are tests/data/mc/{gradient,sphere,aluminium,air_step_low,cmm_field_600}*.yaml; their physics is the
simulator's (simulators/bench.py: the mount's own temperature, the sphere's lobes in the tracer's base frame), the
budget knows only what the procedure states. Fast tests check the pieces and single runs; the campaigns (N ≥ 30 per
case, `@pytest.mark.campaign`) are benchmarks/bench_budget_assumptions.py's cases with the issue's goal asserted:
coverage ≥ 0.95 and σ/RMS 0.8–1.25 for the recommended estimate, or a residual test that failed (the certificate
then says its U cannot be quoted).
"""

from __future__ import annotations

import json
import math
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from rtcal.clock import VirtualClock
from rtcal.methods import load_procedure
from rtcal.methods.estimates import choose_recommended
from rtcal.methods.multistation.method import MultistationMethod, not_included
from rtcal.methods.multistation.noise import noise_model
from rtcal.results.model import ResidualTest, SolverStatus
from rtcal.run.runner import run_procedure
from rtcal.solvers.station_budget import MOUNT_GRADIENT_SOURCE, SPHERE_SOURCE, THERMAL_MOUNT_SENSOR_SOURCE
from simulators.bench import Bench
from simulators.scenario import Scenario

REPO = Path(__file__).resolve().parents[1]
MC = REPO / "tests" / "data" / "mc"


def _scenario(path: Path) -> Scenario:
    return Scenario.model_validate(yaml.safe_load(path.read_text(encoding="utf-8")))


def _run(procedure: Path, seed: int = 7, **bench_update: object):
    """One simulated calibration (no outputs) of ``procedure`` on its bench, with ``bench_update`` over it."""
    tmp = Path(tempfile.mkdtemp(prefix="issue44-"))
    bench = yaml.safe_load((procedure.parent / str(load_procedure(procedure).bench)).read_text(encoding="utf-8"))
    for key, value in bench_update.items():
        section, name = key.split("__")
        bench.setdefault(section, {})[name] = value
    (tmp / "bench.yaml").write_text(yaml.safe_dump(bench), encoding="utf-8")
    return run_procedure(str(procedure), tmp / "bench.yaml", seed, tmp / "run", show_progress=False).results, tmp / "run"


def test_the_mount_grows_with_its_own_temperature_while_the_sensor_reads_the_table():
    sc = _scenario(MC / "gradient_bench.yaml")
    clock = VirtualClock()
    bench = Bench(sc, clock, 0)
    r0 = math.hypot(*bench.tracer_center_mm()[:2])
    clock.sleep(3600.0)
    assert bench.environment()[3] == pytest.approx(21.0)  # what the sensor reads: the table, 1 K/h
    r1 = math.hypot(*bench.tracer_center_mm()[:2])
    assert r1 / r0 - 1 == pytest.approx(11.5e-6 * 1.5, rel=1e-6)  # the mount's region: as at 1.5 K/h
    plain = Bench(sc.model_copy(update={"environment": sc.environment.model_copy(
        update={"mount_temperature_drift_k_per_h": None})}), clock, 0)
    assert math.hypot(*plain.tracer_center_mm()[:2]) / r0 - 1 == pytest.approx(11.5e-6 * 1.0, rel=1e-6)


def test_the_sphere_form_reads_by_the_beams_direction_in_the_tracers_base():
    """The lobes are fixed to the tracer's base: turning the table and the reflector together reads the same
    deviation; the same reflector from another table angle reads another."""
    sc = _scenario(MC / "sphere_bench.yaml")
    bench = Bench(sc, VirtualClock(), 0)
    target = np.array([900.0, 100.0, 300.0])

    def deviation_at(angle_deg: float, reflector_mm: np.ndarray) -> float:
        bench.commanded_rad = bench.actual_rad = math.radians(angle_deg)
        bench.move_probe(reflector_mm)
        return bench.sphere_deviation_mm()

    a = deviation_at(0.0, target)
    turn = math.radians(40.0)
    rot = np.array([[math.cos(turn), -math.sin(turn), 0], [math.sin(turn), math.cos(turn), 0], [0, 0, 1]])
    assert deviation_at(40.0, rot @ target) == pytest.approx(a, abs=1e-9)
    assert abs(deviation_at(40.0, target) - a) > 1e-6  # another part of the sphere
    assert max(abs(deviation_at(float(k), target)) for k in range(0, 360, 5)) <= 0.07e-3 + 1e-12


def test_the_gradient_and_the_sphere_are_budget_lines_or_named():
    grad = noise_model(load_procedure(MC / "gradient.yaml"))
    assert grad.mount_gradient_share == 0.5 and grad.mount_gradient_assumed  # not stated: ±50 % assumed, and said
    sphere = noise_model(load_procedure(MC / "sphere.yaml"))
    assert sphere.sphere_form_um == 0.05
    unstated = load_procedure(MC / "sphere_unstated.yaml")  # names an Etalon LaserTRACER: its class is assumed
    assumed = noise_model(unstated)
    assert (assumed.sphere_form_um, assumed.sphere_form_assumed) == (0.05, "Etalon LaserTRACER")
    assert not any(n.startswith("laser tracer reference sphere form") for n in not_included(unstated))
    unnamed = unstated.model_copy(update={"metadata": unstated.metadata.model_copy(update={"instruments": {}})})
    assert noise_model(unnamed).sphere_form_um == 0
    assert any(n.startswith("laser tracer reference sphere form: not stated") and "U excludes it" in n
               for n in not_included(unnamed))
    assert not any(n.startswith("laser tracer reference sphere form") for n in not_included(load_procedure(MC / "sphere.yaml")))
    no_sensor = noise_model(load_procedure(MC / "air_step_low.yaml"))
    assert no_sensor.mount_gradient_share == 0.0  # without a sensor the table's stated range holds the mount too


def test_the_sphere_form_drawn_by_the_monte_carlo_is_what_the_budget_models():
    """`rtcal uncertainty` draws a sphere within its stated form (a peak to valley, ISO 12181-1), with the budget's
    σ = PV/(2√2) at every azimuth: never one out of its class (Gaussian lobes of that σ reach ≈ 1.9 × PV)."""
    proc = load_procedure(MC / "sphere.yaml")
    rng = np.random.default_rng(44)
    psi = np.linspace(0, 2 * np.pi, 7, endpoint=False)
    values = []
    for _ in range(1200):
        lobes = MultistationMethod().draw_systematics(proc, _scenario(MC / "sphere_bench.yaml"), rng).laser_tracer.sphere_form
        values.append([sum(lo.amplitude_um * math.cos(lo.order * p + math.radians(lo.phase_deg)) for lo in lobes) for p in psi])
    values_um = np.array(values)
    np.testing.assert_allclose(np.sqrt(np.mean(values_um**2, axis=0)), 0.05 / (2 * math.sqrt(2)), rtol=0.08)
    dense = np.linspace(0, 2 * np.pi, 721)
    for _ in range(50):
        lobes = MultistationMethod().draw_systematics(proc, _scenario(MC / "sphere_bench.yaml"), rng).laser_tracer.sphere_form
        form = [sum(lo.amplitude_um * math.cos(lo.order * p + math.radians(lo.phase_deg)) for lo in lobes) for p in dense]
        assert max(form) - min(form) <= 0.05 + 1e-9  # within the stated peak to valley


def test_a_failed_test_never_moves_the_recommendation():
    """The smallest converged U is quoted whether or not its test passed (the old rule quoted the passing one)."""
    from rtcal.results.model import Estimate

    def est(u: float, passed: bool) -> Estimate:
        return Estimate.model_validate({
            "deviation_arcsec": [0.0], "uncertainty_arcsec": [u], "cumulative_deviation_arcsec": [0.0, 0.0],
            "cumulative_uncertainty_arcsec": [0.0, u], "cumulative_expanded_uncertainty_arcsec": [0.0, 2 * u],
            "cumulative_covariance_arcsec2": [[0.0, 0.0], [0.0, u * u]],
            "uncertainty_budget": {"components": [], "combined_arcsec": [0.0, u], "expanded_arcsec": [0.0, 2 * u],
                                   "coverage_factor": 2.0, "not_included": []},
            "converged": True, "message": "", "residual_test": ResidualTest(chi2=900, dof=600, birge_ratio=1.2, p_value=1e-9,
                                                                            passed=passed).model_dump()})

    ok = SolverStatus(status="converged", message="")
    estimates = {"network": est(0.3, False), "shared_dead_path": est(0.5, True)}
    assert choose_recommended(estimates, {"network": ok, "shared_dead_path": ok}) == "network"
    assert choose_recommended(estimates, {"network": SolverStatus(status="not converged", message=""),
                                          "shared_dead_path": ok}) == "shared_dead_path"


def test_an_aluminium_table_taken_for_steel_is_solved_from_the_readings():
    """A low-noise run on the 23 ppm/K table with steel's default α (5.75σ off): the table's growth per sensed kelvin
    is an unknown of shared_dead_path and the network, so their tests pass and U covers the error at every target
    (before: the network failed, shared_dead_path was quoted and missed by −1.8″)."""
    results, _ = _run(MC / "aluminium.yaml")
    truth = np.array(results.truth.cumulative_deviation_arcsec)
    assert results.recommended == "network"
    for name in ("network", "shared_dead_path"):
        e = getattr(results.estimates, name)
        assert e.residual_test is not None and e.residual_test.passed, name
        error = np.abs(np.array(e.cumulative_deviation_arcsec) - truth)[1:]
        assert np.all(error <= np.array(e.cumulative_expanded_uncertainty_arcsec)[1:]), (name, error)


def test_the_growth_unknown_is_solved_only_where_the_sensor_sees_the_table_change():
    from rtcal.methods.multistation.method import GROWTH_SOLVED_FROM_K, corrected_for_expansion, with_growth_unknown
    from rtcal.solvers.station_data import MultistationData

    proc = load_procedure(MC / "aluminium.yaml")
    n, m = 4, 3
    data = MultistationData.from_arrays(np.array([[900.0, 0, 300], [0, 900, 300], [-900, 0, 300], [0, -900, 300]]),
                                        np.full((n, m), 1000.0), [0.0, 120.0, 240.0])
    for spread_k, solved in ((0.0, False), (GROWTH_SOLVED_FROM_K * 2, True)):
        temperature = 20.0 + np.tile(np.linspace(0, spread_k, m), (n, 1))
        with_sensor = corrected_for_expansion(replace(data, material_temperature_c=temperature), proc)
        grown = with_growth_unknown(with_sensor, proc)
        assert (grown.growth_mm_per_ppm is not None) == solved, spread_k
    assert with_growth_unknown(data, proc).growth_mm_per_ppm is None  # no sensor: nothing to scale


def test_a_step_of_the_air_within_its_range_passes_a_low_noise_tracers_test():
    """Turn 5's air step on a 0.02 µm tracer, no sensor: every estimator's test failed (Birge 1.31, measured before
    the course was freed at every reading where it moves fast); now each passes, and fails when a 0.3 µm wave of
    the CMM (not budgeted) is added to the same bench: the smallest U is still quoted, and the certificate's notes
    say it failed, that its U is not a coverage interval, and what the readings contradict."""
    results, _ = _run(MC / "air_step_low.yaml")
    for name, e in results.estimates.items():
        assert e.residual_test is not None and e.residual_test.passed, (name, e.residual_test)
    wavy, run_dir = _run(MC / "air_step_low.yaml", cmm__error_field=[
        {"axis": "x", "amplitude_um": 0.3, "wavelength_mm": 300, "direction": [0, 1, 0.3], "phase_deg": 20}])
    assert wavy.recommended == "network" and not wavy.estimates.network.residual_test.passed
    notes = " ".join(json.loads((run_dir / "certificate.json").read_text(encoding="utf-8"))["identification"]["notes"])
    assert "The quoted estimate FAILED its residual test" in notes and "NOT coverage intervals" in notes
    assert "No estimate passed its test." in notes  # all three failed here
    assert "the CMM's geometry beyond its scales and squarenesses" in notes


def test_the_gradient_budget_line_is_in_every_estimate_and_the_method_section():
    results, run_dir = _run(MC / "gradient.yaml")
    for name, e in results.estimates.items():
        lines = {c.source: c for c in e.uncertainty_budget.components}
        assert MOUNT_GRADIENT_SOURCE in lines, name
        assert "±50 % (1σ) assumed" in lines[MOUNT_GRADIENT_SOURCE].note
    cert = (run_dir / "certificate.json").read_text(encoding="utf-8")
    assert "the table's sensor does not sit where the tracer is mounted" in cert


@pytest.mark.campaign
def test_a_probe_on_the_mount_measures_the_gradient_the_budget_no_longer_assumes():
    """The gradient bench with a second probe on the tracer's mount (about 20 s): every estimate is corrected with the
    mount's temperature, so no gradient line; the probe's stated uncertainty and noise are its lines, and the method
    section says so. The store keeps both probes' readings raw."""
    results, run_dir = _run(MC / "gradient_two_sensors.yaml")
    for name, e in results.estimates.items():
        lines = {c.source for c in e.uncertainty_budget.components}
        assert MOUNT_GRADIENT_SOURCE not in lines and THERMAL_MOUNT_SENSOR_SOURCE in lines, name
    cert = (run_dir / "certificate.json").read_text(encoding="utf-8")
    assert "a second probe on the tracer's mount reads the region that carries the tracer" in cert
    import sqlite3

    with sqlite3.connect(run_dir / "run.sqlite") as db:
        (table_c, mount_c), = db.execute("SELECT max(CASE WHEN quantity = 'material_temperature_c' THEN value END), "
                                         "max(CASE WHEN quantity = 'mount_temperature_c' THEN value END) FROM readings")
    assert mount_c - 20.0 == pytest.approx(1.5 * (table_c - 20.0), rel=0.1)  # the mount warms as at 1.5 K/h, the rim 1


def test_the_sphere_budget_line_is_in_every_estimate():
    results, _ = _run(MC / "sphere.yaml")
    for name, e in results.estimates.items():
        line = next(c for c in e.uncertainty_budget.components if c.source == SPHERE_SOURCE)
        assert max(v for v in line.contribution_arcsec if v is not None) > 0.01, name


# --- campaigns: benchmarks/bench_budget_assumptions.py's cases, N ≥ 30, the goal asserted

def _case(name: str, trials: int = 30, seeds: tuple[int, ...] = (4400,)) -> dict:
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_budget_assumptions", REPO / "benchmarks" / "bench_budget_assumptions.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    summary = module.run_case(name, trials, list(seeds), 2)
    print(*module.table_rows(name, summary), sep="\n")
    return summary


def _goal_met(summary: dict) -> bool:
    """Coverage ≥ 0.95 and σ/RMS 0.8–1.25 for the recommended estimate, or its test failed wherever U missed: the
    trials it passed in are covered (the others' certificates say their U cannot be quoted). The ratio of RMS over N
    trials is known to ±1/√(2N) (1σ): the band is widened by twice that (N = 30: 0.59–1.57), since the same cases
    give 1.18 with seed 4400 and 0.96 with seeds 6061 and 4242 (docs/paper000.md)."""
    r = summary["recommended_estimate"]
    slack = 2.0 / math.sqrt(2.0 * summary["trials"])
    if r["coverage_k2"] >= 0.95 and 0.8 * (1 - slack) <= r["ratio"] <= 1.25 * (1 + slack):
        return True
    return r["residual_test_failed"] > 0 and (r["coverage_k2_quoted"] is None or r["coverage_k2_quoted"] >= 0.95)


@pytest.mark.campaign
@pytest.mark.parametrize("case", ["gradient", "gradient_two_sensors", "sphere", "aluminium", "cmm_field_600", "default_alpha"])
def test_where_the_room_breaks_the_budget_the_goal_holds_campaign(case):
    assert _goal_met(_case(case))


@pytest.mark.campaign
def test_a_sphere_within_its_stated_form_is_covered_on_two_seeds_campaign():
    """The form stated as a peak to valley and a sphere within it drawn: the goal on 2 × 30 trials (seed 4400 alone
    measured σ/RMS 1.39 with the old model: its draws' sphere error was 0.73 × its expectation, docs/paper000.md)."""
    assert _goal_met(_case("sphere", seeds=(4400, 5500)))


@pytest.mark.campaign
def test_an_unstated_laser_tracer_sphere_is_budgeted_as_its_class_campaign():
    """Not stated, the named LaserTRACER's 50 nm class is the budget's: the same figures as with it stated (before:
    0.67–0.73 coverage, σ/RMS 0.52–0.57). The bench's sphere is 130 nm peak to valley, 2.6 × that class: docs/paper000.md
    gives 0.90–0.96 over two seeds."""
    unstated, stated = _case("sphere_unstated")["recommended_estimate"], _case("sphere_bench")["recommended_estimate"]
    assert (unstated["coverage_k2"], unstated["ratio"]) == (stated["coverage_k2"], stated["ratio"])
    assert unstated["coverage_k2"] >= 0.9


@pytest.mark.campaign
@pytest.mark.parametrize("case", ["sphere_in_class", "sphere_in_class_unstated"])
def test_a_fixed_sphere_within_its_class_is_covered_campaign(case):
    """The bench's two- and three-lobe sphere scaled into its class (48 nm peak to valley), stated or assumed from the
    named LaserTRACER: covered (one fixed sphere is one draw of the class, so only coverage is asked of it)."""
    assert _case(case, seeds=(4400, 5500))["recommended_estimate"]["coverage_k2"] >= 0.95


@pytest.mark.campaign
@pytest.mark.parametrize("case", ["air_step_low", "air_step"])
def test_the_air_test_keeps_its_rate_without_a_sensor_campaign(case):
    """The course within the stated ranges: U covers, and the test fails at most at about its stated 1 % (30 trials:
    at most 2 failures of each estimator). The network estimates the course (rtcal/solvers/station_budget.py: air_course_hats), so
    its U is no longer the range's worst case: σ/RMS within the goal's band (before: 28.9 and 1.91)."""
    summary = _case(case)
    assert summary["recommended_estimate"]["coverage_k2"] >= 0.95
    r = summary["recommended_estimate"]
    slack = 2.0 / math.sqrt(2.0 * summary["trials"])  # the ratio's sampling, as _goal_met allows it
    assert r["estimators"] == {"network": summary["trials"]} and 0.8 * (1 - slack) <= r["ratio"] <= 1.25 * (1 + slack)
    for name, e in summary["estimators"].items():
        assert e["residual_test_failed"] is not None and e["residual_test_failed"] <= 2 / 30, name
    # shared_dead_path solves the course too (its points known): covered, and no longer the range's worst case
    # (σ/RMS 12.8 and 2.51 when it quoted it; 1.08 and 1.24 now, seeds 4400 and 5500, docs/paper000.md)
    sdp = summary["estimators"]["shared_dead_path"]["overall"]
    assert sdp["coverage_k2"] >= 0.95
    assert sdp["rms_reported_sigma_arcsec"] / sdp["rms_error_arcsec"] < (12.8 if case == "air_step_low" else 2.51) / 1.2


def test_a_stated_source_far_off_fails_its_own_score_where_the_whole_chi2_passes():
    """Residuals r = (I − JJ⁺)e with e ~ N(0, I + FFᵀ): the test keeps its 1 % false-alarm rate with the two-input
    source also scored; with that source's first input 6σ off (e.g. α 6σ from the stated), its own score fails
    nearly always and names it, where the whole χ² alone (spread over ν ≈ 300) passes most of the time."""
    import scipy.sparse as sp
    from scipy.stats import chi2 as chi2_dist

    from rtcal.solvers.uncertainty import Covariance, residual_check

    rng = np.random.default_rng(4401)
    n, p = 320, 12
    J = sp.csr_matrix(rng.normal(size=(n, p)))
    F = rng.normal(size=(n, 2)) * 0.3
    V = Covariance((np.ones(n), F))
    Q, _ = np.linalg.qr(J.toarray())

    def check(offset: float):
        e = rng.normal(size=n) + F @ (rng.normal(size=2) + np.array([offset, 0.0]))
        r = e - Q @ (Q.T @ e)
        c = residual_check(r, V, 0, jacobian=J, scored=[("coefficient", F)])
        assert c is not None and c.sources_scored == 1
        return c

    as_stated = [check(0.0) for _ in range(400)]
    assert sum(not c.passed for c in as_stated) <= 10  # 1 % of 400 is 4; 10 is p < 0.003 by the binomial
    off = [check(6.0) for _ in range(60)]
    assert sum(c.source_failed and c.worst_source == "coefficient" for c in off) >= 54
    assert sum(c.p_value < 0.01 for c in off) < 30  # the whole χ² alone misses most of them
    assert all(chi2_dist.sf(c.chi2, c.dof) == pytest.approx(c.p_value) for c in off)
