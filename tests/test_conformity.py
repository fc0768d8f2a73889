"""Conformity (docs/conformity.md): the decision rules, the verdicts on simulated benches inside,
outside and at a limit, and the expanded uncertainty U of the ISO 230-2 parameters checked by a
Monte Carlo of whole simulated ISO 230-2 tests against the bench's truth.

The noise is what procedures/scenarios/abbe_bench.yaml injects: stage repeatability 0.3″ per
visit, autocollimator noise 0.2″ with a 0.1″ digit, polygon certificate 0.1″ per face (drawn
afresh with every seed), five runs each way at 12 targets. Every tolerance below follows from
the number of trials: a coverage of 95 % over N trials is a binomial count, and the lower bounds
are its 0.1 % quantiles (24 of 30, 365 of 400).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from rtcal.cli import main
from rtcal.deliverables.conformity import decide, means_of, parameter_form
from rtcal.deliverables.deviations import PositioningDeviations
from rtcal.methods import read_results
from rtcal.run.runner import run_procedure

REPO = Path(__file__).resolve().parents[1]
ISO = REPO / "procedures" / "iso230_2_polygon.yaml"
BENCH = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"


def _procedure(tmp_path: Path, acceptance: dict | None, name: str = "iso.yaml", sensor: bool = True) -> Path:
    """The shipped ISO procedure with the given acceptance section (none: without), its bench
    given with scenario_path by each run (``sensor=False``: without the environment sensor)."""
    data = yaml.safe_load(ISO.read_text())
    data.pop("acceptance", None)
    data.pop("bench", None)
    if not sensor:
        data["instruments"].pop("environment")
    if acceptance is not None:
        data["acceptance"] = acceptance
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True))
    return path


@pytest.fixture
def procedure_file(tmp_path):
    return lambda acceptance, name="iso.yaml", sensor=True: _procedure(tmp_path, acceptance, name, sensor)


def _scaled_bench(tmp_path: Path, factor: float) -> Path:
    """The ISO bench with its positioning error and reversal scaled: E scales with them exactly."""
    data = yaml.safe_load(BENCH.read_text())
    stage = data["stage"]
    stage["positioning_error"] = [{**h, "amplitude_arcsec": h["amplitude_arcsec"] * factor} for h in stage["positioning_error"]]
    stage["reversal_arcsec"] = stage["reversal_arcsec"] * factor
    path = tmp_path / f"bench_{factor:.4f}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _true_E(results) -> float:
    return float(np.ptp(results.truth.cumulative_deviation_arcsec))


def test_decision_rules():
    """ILAC-G8 simple acceptance and ISO 14253-1 guarded acceptance at and around the limit."""
    assert decide("simple", 9.99, 10.0, 1.0) == ("pass", 0.0)
    assert decide("simple", 10.0, 10.0, 1.0) == ("pass", 0.0)
    assert decide("simple", 10.01, 10.0, 1.0) == ("fail", 0.0)
    assert decide("guarded", 8.99, 10.0, 1.0) == ("pass", 1.0)
    assert decide("guarded", 9.5, 10.0, 1.0) == ("undecided", 1.0)
    assert decide("guarded", 10.5, 10.0, 1.0) == ("undecided", 1.0)
    assert decide("guarded", 11.01, 10.0, 1.0) == ("fail", 1.0)
    assert decide("guarded", None, 10.0, 1.0)[0] == "undecided"  # a parameter the data do not define
    assert decide("guarded", 5.0, 10.0, None)[0] == "undecided"  # no U: nothing is proven


def test_inside_passes_outside_fails_at_the_limit_undecided(tmp_path, procedure_file):
    """Three benches, one limit E ≤ 40″: the axis' true E at half the limit, 1.6 times it, and at
    it. Under guarded acceptance the first passes, the second fails and the third is undecided
    (its measured E lies within U of the limit); simple acceptance decides the third by the side
    its measured value falls on."""
    limit = 40.0
    first = run_procedure(_procedure_with(procedure_file, None), scenario_path=BENCH, seed=5,
                          out_dir=tmp_path / "truth", outputs=False).results
    e0 = _true_E(first)
    verdicts = {}
    for label, ratio in (("inside", 0.5), ("outside", 1.6), ("at", 1.0)):
        bench = _scaled_bench(tmp_path, ratio * limit / e0)
        for rule in ("guarded", "simple"):
            proc = _procedure_with(procedure_file, {"decision_rule": rule, "limits_arcsec": {"E": limit}})
            r = run_procedure(proc, scenario_path=bench, seed=5, out_dir=tmp_path / f"{label}-{rule}", outputs=False).results
            assert abs(_true_E(r) - ratio * limit) < 1e-3  # the bench is what the test says it is
            c = r.conformity.per_limit["E"]
            assert c.value_arcsec == r.evaluation.iso230_2.E and c.limit_arcsec == limit
            verdicts[label, rule] = (c.verdict, c.value_arcsec, c.expanded_uncertainty_arcsec, r.conformity.verdict)
    assert verdicts["inside", "guarded"][0] == verdicts["inside", "guarded"][3] == "pass"
    assert verdicts["outside", "guarded"][0] == verdicts["outside", "guarded"][3] == "fail"
    verdict, value, U, overall = verdicts["at", "guarded"]
    assert abs(value - limit) <= U and verdict == overall == "undecided"
    assert verdicts["at", "simple"][0] == ("pass" if value <= limit else "fail")
    assert verdicts["inside", "simple"][0] == "pass" and verdicts["outside", "simple"][0] == "fail"


def _procedure_with(make, acceptance):
    return make(acceptance, name=f"iso-{acceptance['decision_rule'] if acceptance else 'none'}.yaml")


def test_results_console_and_certificate_carry_the_verdict(tmp_path, capsys):
    """The shipped ISO procedure's acceptance section: the verdict per limit in results.json, the
    console (with the parameters) and the certificate's first page, with the rule stated."""
    import pymupdf

    out = tmp_path / "run"
    assert main(["run", str(ISO), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    r = read_results(out)
    c = r.conformity
    assert c is not None and c.decision_rule == "guarded" and set(c.per_limit) == {"E", "M", "B", "R", "A", "band"}
    assert f"conformity (guarded acceptance, ISO 14253-1): {c.verdict.upper()}" in printed
    assert "ISO 230-2:2014: E " in printed and "over 12 targets × 2 directions" in printed
    for k, v in c.per_limit.items():
        assert f": {v.verdict}" in printed and v.verdict in ("pass", "fail", "undecided")
        assert v.guard_band_arcsec == v.expanded_uncertainty_arcsec  # guarded: w = U
    page1 = pymupdf.open(out / "report.pdf")[0].get_text()
    assert f"Conformity: {c.verdict.upper()}" in page1 and "ISO 14253-1:2017" in page1


def test_the_linear_forms_give_the_evaluated_values(tmp_path, procedure_file):
    """Each parameter's extremes reproduce the ISO 230-2 value the evaluation computed."""
    r = run_procedure(procedure_file(None), scenario_path=BENCH, seed=3, out_dir=tmp_path / "r", outputs=False).results
    iso = r.evaluation.iso230_2
    means = means_of(iso, r, PositioningDeviations.from_model(r.positioning_deviations))
    for symbol in ("E", "E_up", "E_down", "M", "B", "R", "R_up", "R_down", "A", "A_up", "A_down"):
        form = parameter_form(symbol, iso, means)
        assert form is not None and abs(form.value(means) - getattr(iso, symbol)) < 2e-3, symbol


def _monte_carlo(tmp_path: Path, make, trials: int) -> dict[str, np.ndarray]:
    """Per parameter: (measured − true, U) over whole simulated ISO tests with fresh noise and a
    fresh polygon certificate error. Truth: the bench's systematic εz per target and direction
    and its repeatability σ (the axis' parameter, which the test's runs sample)."""
    sigma = yaml.safe_load(BENCH.read_text())["stage"]["repeatability_arcsec"]
    limits = {"E": 100.0, "M": 100.0, "B": 100.0, "R": 100.0, "A": 100.0}
    proc = make({"decision_rule": "guarded", "limits_arcsec": limits}, name="mc.yaml", sensor=False)  # faster, no change
    rows: dict[str, list[tuple[float, float]]] = {k: [] for k in limits}
    for seed in range(2000, 2000 + trials):
        r = run_procedure(proc, scenario_path=BENCH, seed=seed, out_dir=tmp_path / f"t{seed}", outputs=False).results
        e = r.recommended_estimate()
        truth = dict(zip(zip(e.target_deg, e.target_direction), r.truth.cumulative_deviation_arcsec))
        targets = sorted({t for t, _ in truth})
        up, down = np.array([truth[t, 1] for t in targets]), np.array([truth[t, -1] for t in targets])
        true = {"E": max(up.max(), down.max()) - min(up.min(), down.min()), "M": np.ptp((up + down) / 2),
                "B": np.abs(up - down).max(), "R": 4 * sigma + np.abs(up - down).max(),
                "A": max(up.max(), down.max()) + 2 * sigma - min(up.min(), down.min()) + 2 * sigma}
        for k, c in r.conformity.per_limit.items():
            rows[k].append((c.value_arcsec - true[k], c.expanded_uncertainty_arcsec))
    return {k: np.array(v) for k, v in rows.items()}


def test_U_covers_the_error_of_the_parameters_short(tmp_path, procedure_file):
    """30 simulated ISO tests: |measured − true| ≤ U for E, M and B in at least 24 (the 0.1 %
    quantile of a binomial count at 95 %), and U not inflated: the RMS error is at least half
    the mean u = U/2 (a U twice too large gives about 0.4)."""
    found = _monte_carlo(tmp_path, procedure_file, 30)
    for k in ("E", "M", "B"):
        err, U = found[k][:, 0], found[k][:, 1]
        assert np.sum(np.abs(err) <= U) >= 24, (k, np.abs(err) / U)
        assert np.sqrt(np.mean(err**2)) / np.mean(U / 2) > 0.5, k


@pytest.mark.campaign
def test_U_covers_the_error_of_the_parameters_campaign(tmp_path, procedure_file):
    """400 simulated ISO tests (about 2 minutes): coverage of U for E, M, B, R, A at least 365 of
    400 (the 0.1 % quantile of a binomial count at 95 %), the RMS error of E and M between 0.7
    and 1.3 times the mean u (one target decides each extreme there: U = 2u, which must fit)."""
    found = _monte_carlo(tmp_path, procedure_file, 400)
    for k, a in found.items():
        err, U = a[:, 0], a[:, 1]
        print(f"{k}: coverage {np.mean(np.abs(err) <= U):.3f}, mean error {err.mean():+.3f}″, RMS error "
              f"{np.sqrt(np.mean(err ** 2)):.3f}″, mean u {np.mean(U / 2):.3f}″")
        assert np.sum(np.abs(err) <= U) >= 365, k
    for k in ("E", "M"):
        ratio = np.sqrt(np.mean(found[k][:, 0] ** 2)) / np.mean(found[k][:, 1] / 2)
        assert 0.7 < ratio < 1.3, (k, ratio)
