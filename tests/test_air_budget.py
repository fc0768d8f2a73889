"""Air without an environment sensor: a Type B source from the ranges the procedure states, checked
against simulated truth.

The bench (tests/data/mc/air_drift_bench.yaml) has little noise (0.02 µm lengths, 0.05 µm CMM) so
that the air matters. It is run as it is (steady standard air) and, with the same seed, with the air
drifting linearly over the whole run by +1 K / +5 hPa (the index falls 0.93 ppm and rises 1.34 ppm)
and by −1 K / +5 hPa (both raise the index: 2.27 ppm) — every value inside the procedure's stated
ranges (±1 K, ±5 hPa, ±10 % RH about standard air). The same seed makes the same noise, so the
difference d of the two runs' deviations is the air's doing alone.

Tolerances, from the drift injected: each quantity goes from the middle of its range to one end
(its mean over the run is half its bound and so is its half change), so each of its two inputs sits
at √6/2 = 1.22 σ of the budget's model (σ = bound/√6); the air's shift is a sum over two quantities
of two inputs each and cannot exceed √(2·2)·1.22 σ = √6·u_air per target (Cauchy–Schwarz): checked
for every estimator. The recommended estimator's U (k = 2) must cover its whole error against truth:
with the air at 1.2–1.7 σ of its model and the noise random, U covers about 95 % of the targets
(the cooler drift takes both quantities to the index's adverse ends at once, the corner of the
model's distribution, where a target may fall just outside): at least 90 % of the targets over the
runs are asserted. The network and shared_dead_path estimate the air's course from the lengths against the CMM's
points where they know it (rtcal/solvers/station_budget.py: air_course_hats): their air line is that estimate's
uncertainty, and the drift no longer needs it. So that the drift is shown to matter on this bench, each drift run
also solves shared_dead_path with the course NOT solved (``solve_air_course=False``: the air left to its range's worst
case, as before the course was solved) beside paper, which takes the air so too: over these estimators the same U
without the air component must cover under 90 % of the targets, so a budget that forgot air fails this test (the
guard runs on estimators that exist in every run, so it cannot pass for want of one).

The Monte Carlo with the air drawn within its ranges as the budget models it is the `air_drift` case
of tests/test_uncertainty_campaign.py.
"""

from __future__ import annotations

from pathlib import Path
from unittest import mock

import numpy as np
import pytest
import yaml

from rtcal.methods.multistation import method
from rtcal.methods.multistation.method import not_included, shared_dead_path_estimate
from rtcal.methods import load_procedure
from rtcal.run.runner import run_procedure
from rtcal.solvers.station_budget import AIR_COURSE_SOURCE, AIR_DRIFT_SOURCE

REPO = Path(__file__).resolve().parents[1]
MC = REPO / "tests" / "data" / "mc"
PROCEDURE = MC / "air_drift.yaml"
DRIFTS = {"warmer": (1.0, 500.0), "cooler": (-1.0, 500.0)}  # over the whole run: K, Pa


def _bench(tmp: Path, name: str, seed: int, drift: tuple[float, float] | None, hours: float) -> Path:
    data = yaml.safe_load((MC / "air_drift_bench.yaml").read_text())
    data["seed"] = seed
    if drift is not None:
        dT, dp = drift
        data["environment"] = {"air_temperature_c": 20.0, "air_temperature_drift_k_per_h": dT / hours,
                               "air_pressure_pa": 101325.0, "air_pressure_drift_pa_per_h": dp / hours}
    path = tmp / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _estimates(results) -> dict[str, dict[str, np.ndarray]]:
    return {name: _fields(e) for name, e in results.estimates.items()}


def _fields(e) -> dict[str, np.ndarray]:
    comps = {c.source: np.array([v or 0.0 for v in c.contribution_arcsec]) for c in e.uncertainty_budget.components}
    return {"cum": np.array(e.cumulative_deviation_arcsec, float), "u": np.array(e.cumulative_uncertainty_arcsec, float),
            # the network and shared_dead_path estimate the course where the lengths know it: that line instead
            "air": comps.get(AIR_DRIFT_SOURCE, comps.get(AIR_COURSE_SOURCE, np.zeros(len(e.cumulative_deviation_arcsec))))}


def _run_with_course_unsolved(tmp_path: Path, bench: Path, out: str):
    """The run's results and shared_dead_path on the same data with the air's course NOT solved (its estimate as
    results.json holds it): the estimator as it was before it solved the course, the air its range's worst case."""
    solve, unsolved = method.solve_shared_dead_path, []

    def both(*args, **kwargs):
        unsolved.append(solve(*args, **kwargs, solve_air_course=False))
        return solve(*args, **kwargs)

    with mock.patch.object(method, "solve_shared_dead_path", both):
        results = run_procedure(PROCEDURE, bench, out_dir=tmp_path / out, show_progress=False, outputs=False).results
    assert len(unsolved) == 1
    return results, shared_dead_path_estimate(unsolved[0], [])


def _check_drift(tmp_path: Path, seed: int) -> tuple[int, int, int, int, list[str]]:
    """Runs the still bench and both drifts with one seed: the targets of the recommended estimator whose
    error U covers, their number; over the estimators that take the air as its range's worst case (paper, and
    shared_dead_path with the course not solved), the (estimator, target) pairs U without the air component covers and
    their number; a line of figures per drift."""
    still = run_procedure(PROCEDURE, _bench(tmp_path, f"still{seed}", seed, None, 1.0), out_dir=tmp_path / f"still{seed}",
                          show_progress=False, outputs=False).results
    hours = still.measurement_duration_s / 3600.0
    base = _estimates(still)
    covered = total = covered_without_air = total_without = 0
    lines = []
    for label, drift in DRIFTS.items():
        r, unsolved = _run_with_course_unsolved(tmp_path, _bench(tmp_path, f"{label}{seed}", seed, drift, hours),
                                                f"{label}{seed}")
        assert abs(r.measurement_duration_s - still.measurement_duration_s) < 1.0  # the drift spans the run
        truth = np.array(r.truth.cumulative_deviation_arcsec, float)
        for name, e in _estimates(r).items():
            assert np.all(e["air"][1:] > 0), (name, "the budget has no air component")
            d = e["cum"] - base[name]["cum"]
            # √6·u_air (see the module's docstring) and 0.002″ for the solvers' own rounding (results.json: 4 digits)
            assert np.all(np.abs(d[1:]) <= np.sqrt(6) * e["air"][1:] + 2e-3), (label, name, d, e["air"])
        rec = _estimates(r)[r.recommended]
        err = np.abs(rec["cum"] - truth)[1:]
        U = 2 * rec["u"][1:]
        covered, total = covered + int(np.sum(err <= U)), total + len(err)
        worst_case = {"paper": dict(r.estimates.items())["paper"], "shared_dead_path, course not solved": unsolved}
        for name, model in worst_case.items():
            assert any(c.source == AIR_DRIFT_SOURCE for c in model.uncertainty_budget.components), (name, "not the worst case")
            e = _fields(model)
            U_without_air = 2 * np.sqrt(np.clip(e["u"] ** 2 - e["air"] ** 2, 0, None))[1:]
            covered_without_air += int(np.sum(np.abs(e["cum"] - truth)[1:] <= U_without_air))
            total_without += len(U_without_air)
        lines.append(f"seed {seed} {label}: {r.recommended} |error|/U max {np.max(err / U):.2f}; U without air covers "
                     f"{covered_without_air}/{total_without} of {', '.join(worst_case)}")
    return covered, total, covered_without_air, total_without, lines


def _assert_covered(outcomes: list[tuple[int, int, int, int, list[str]]]) -> None:
    covered, total, without, total_without = (sum(o[k] for o in outcomes) for k in range(4))
    print(*(line for o in outcomes for line in o[4]),
          f"U covers {covered}/{total} targets, without air {without}/{total_without}", sep="\n")
    assert covered >= 0.9 * total, (covered, total)
    assert total_without and without < 0.9 * total_without, (
        "the drift does not matter on this bench: the test could not fail", without, total_without)


def test_without_a_sensor_air_is_named_in_not_included_when_no_range_is_stated(tmp_path):
    proc = yaml.safe_load(PROCEDURE.read_text())
    del proc["uncertainty"]["environment"]
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump({**proc, "bench": None}))
    omitted = not_included(load_procedure(path))
    assert any(o.startswith("air:") and "temperature" in o and "pressure" in o for o in omitted), omitted
    stated = not_included(load_procedure(PROCEDURE))
    assert not any(o.startswith("air:") for o in stated), stated
    with_sensor = {**proc, "bench": None, "instruments": {"environment": {"backend": "sim"}}}
    path.write_text(yaml.safe_dump(with_sensor))
    assert not any(o.startswith("air:") for o in not_included(load_procedure(path)))


def test_a_drift_within_the_stated_ranges_is_covered_and_air_is_in_the_budget(tmp_path):
    _assert_covered([_check_drift(tmp_path, 1)])


@pytest.mark.campaign
def test_a_drift_within_the_stated_ranges_is_covered_on_more_seeds(tmp_path):
    _assert_covered([_check_drift(tmp_path, seed) for seed in (2, 3, 4, 5, 6, 7)])
