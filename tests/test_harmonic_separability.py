"""An order the targets cannot tell from an unmodelled one is not a significant harmonic of the table
(rtcal.solvers.harmonics: separability), checked against simulated truths."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from rtcal.cli import main
from rtcal.solvers.harmonics import Harmonic, evaluate, fit_harmonics, grid_nyquist, resolvable_orders

REPO = Path(__file__).resolve().parents[1]
ISO = REPO / "procedures" / "iso230_2_polygon.yaml"
BENCH = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"
ISO_TARGETS_DEG = [0, 15, 45, 90, 105, 150, 180, 210, 240, 270, 315, 330]


def _series(truth: list[Harmonic], seed: int, runs: int = 5, noise_arcsec: float = 0.3):
    """Both directions (an 8″ reversal), ``runs`` passes over the ISO procedure's targets."""
    rng = np.random.default_rng(seed)
    theta = np.tile(np.radians(ISO_TARGETS_DEG), 2 * runs)
    groups = np.repeat([0, 1], runs * len(ISO_TARGETS_DEG))
    y = evaluate(truth, theta) + 8.0 * groups + rng.normal(0.0, noise_arcsec, theta.size)
    return theta, y, groups


def _fit(theta, y, groups, separate: bool = True):
    orders = resolvable_orders(theta, 24, 2)
    return fit_harmonics(theta, y, orders, groups, max_order=24,
                         alternatives_up_to=grid_nyquist(theta, 24) if separate else None)


def test_grid_nyquist():
    assert grid_nyquist(np.radians(ISO_TARGETS_DEG), 24) == 12  # a 15° grid: 24 points
    assert grid_nyquist(np.radians(np.arange(0, 360, 15)), 24) == 12
    assert grid_nyquist(np.radians(np.arange(0, 360, 5)), 24) == 24  # capped
    assert grid_nyquist(np.radians([0, 17.3, 101.9, 233.3]), 24) == 24
    assert grid_nyquist(np.radians(np.arange(7.5, 360, 15)), 24) == 12  # the same grid, started elsewhere


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_twelfth_harmonic_leaking_into_low_orders_is_not_significant(seed):
    truth = [Harmonic(1, 20.0, np.radians(40)), Harmonic(12, 6.0, np.radians(-30))]
    theta, y, groups = _series(truth, seed)
    plain = _fit(theta, y, groups, separate=False)
    assert [t.order for t in plain.terms if t.significant] != [1]  # the leakage the check is for
    fit = _fit(theta, y, groups)
    assert [t.order for t in fit.terms if t.significant] == [1]
    order4 = next(t for t in fit.terms if t.order == 4)
    assert order4.amplitude > 3.0 and 12 in order4.not_separable_from
    assert any("cannot be separated from" in w and "order 4" in w for w in fit.warnings)


@pytest.mark.parametrize("phase_deg", [0.0, 77.0, -120.0])
def test_real_orders_one_and_three_are_found(phase_deg):
    truth = [Harmonic(1, 20.0, np.radians(40)), Harmonic(3, 5.0, np.radians(phase_deg))]
    theta, y, groups = _series(truth, 5)
    fit = _fit(theta, y, groups)
    assert [t.order for t in fit.terms if t.significant] == [1, 3]
    for t in fit.terms:
        if t.significant:
            expected = next(h.amplitude for h in truth if h.order == t.order)
            assert abs(t.amplitude - expected) <= 3 * t.amplitude_sigma
            assert not t.not_separable_from


def test_an_order_orthogonal_at_the_targets_takes_nothing():
    """24 targets a 15° grid apart: orders 1 and 10 are orthogonal there. A real 10th order beside a
    weak real order 1 does not make order 1 \"not separable\" (it did when the test asked only whether
    m in n's place fits as well)."""
    truth = [Harmonic(1, 1.5, np.radians(70)), Harmonic(10, 1.5, np.radians(10))]
    rng = np.random.default_rng(3)
    theta = np.tile(np.radians(np.arange(0, 360, 15)), 4)
    groups = np.repeat([0, 1], theta.size // 2)
    y = evaluate(truth, theta) + rng.normal(0.0, 0.3, theta.size)
    fit = fit_harmonics(theta, y, [1, 2, 3, 4, 5], groups, max_order=24, alternatives_up_to=grid_nyquist(theta, 24))
    order1 = next(t for t in fit.terms if t.order == 1)
    assert order1.significant and not order1.not_separable_from, order1


def _run_iso(tmp_path: Path, positioning: list[dict]) -> dict:
    bench = yaml.safe_load(BENCH.read_text())
    bench["stage"]["positioning_error"] = positioning
    scenario = tmp_path / "bench.yaml"
    scenario.write_text(yaml.safe_dump(bench))
    out = tmp_path / "run"
    assert main(["run", str(ISO), "--scenario", str(scenario), "--out", str(out)]) == 0
    return json.loads((out / "results.json").read_text())["estimates"]["abbe"]


def test_iso_run_on_the_shipped_bench_reports_only_order_one(tmp_path, capsys):
    bench = yaml.safe_load(BENCH.read_text())
    a = _run_iso(tmp_path, bench["stage"]["positioning_error"])
    terms = a["harmonics"]["positioning_error_arcsec"]
    assert [t["order"] for t in terms if t["significant"]] == [1]
    assert 12 in next(t for t in terms if t["order"] == 4)["not_separable_from"]
    out = capsys.readouterr().out
    assert "positioning_error: significant harmonics 1× " in out and "not separable at these targets" in out


def test_iso_run_with_orders_one_and_three(tmp_path):
    truth = [{"order": 1, "amplitude_arcsec": 20.0, "phase_deg": 40}, {"order": 3, "amplitude_arcsec": 5.0, "phase_deg": 0}]
    terms = _run_iso(tmp_path, truth)["harmonics"]["positioning_error_arcsec"]
    found = {t["order"]: t for t in terms if t["significant"]}
    assert sorted(found) == [1, 3]
    for h in truth:
        t = found[h["order"]]
        assert abs(t["amplitude"] - h["amplitude_arcsec"]) <= 2 * t["amplitude_sigma"] + 0.01
        assert "not_separable_from" not in t
