"""Issue 20's two σ questions: a short CI check of the sparse network over many seeds; the long trials
under `pytest -m campaign` (the 72 × 1000 network over 100 seeds and the two-mount network over 30
seeds below, and the two-mount case of tests/test_uncertainty_campaign.py: 200 balanced trials of
whole runs per target); figures: `python benchmarks/bench_sigma.py`.

Neither reported σ was too small: the two-mount network's first step came out at 0.70 over 18 seeds,
the 72 × 1000 network at 0.055″ against one seed's 0.094″ — sampling, settled with enough trials
(docs/paper000.md)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from rtcal.solvers.network import solve_network
from rtcal.solvers.station_budget import StationNoiseModel

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))


def _network_ratio(m: int, n: int, seeds: int) -> tuple[float, float, np.ndarray]:
    """Over ``seeds`` synthetic networks (benchmarks/bench_network.py): the pooled reported σ / RMS error
    over targets and seeds, its 1σ by bootstrap over seeds, and the per-target ratios."""
    from bench_network import network_data

    from threadpoolctl import threadpool_limits

    errs, us = [], []
    with threadpool_limits(1):  # small matrices: threads cost more than they give
        for s in range(seeds):
            data, first, truth = network_data(m, n, seed=s)
            est = solve_network(data, first, np.zeros(3), StationNoiseModel(length_noise_um=0.2, length_noise_ppm=0.0,
                                                                              point_noise_um=1.0))
            errs.append((est.cumulative_deviation_arcsec - truth)[1:])
            us.append(est.budget.uncertainty_arcsec[1:])
    e, u = np.array(errs), np.array(us)
    pooled = lambda k: np.sqrt(np.mean(u[k] ** 2)) / np.sqrt(np.mean(e[k] ** 2))  # noqa: E731
    boot = [pooled(k) for k in np.random.default_rng(0).integers(0, seeds, (1000, seeds))]
    return float(pooled(np.arange(seeds))), float(np.std(boot)), np.sqrt(np.mean(u**2, 0) / np.mean(e**2, 0))


@pytest.mark.parametrize("seeds", [pytest.param(16, id="16-seeds"), pytest.param(40, id="40-seeds", marks=pytest.mark.campaign)])
def test_the_sparse_network_reports_the_sigma_of_its_errors(seeds):
    """24 stations × 200 points: the pooled ratio over 40 seeds is known to about ±6 % (bootstrap,
    printed), over 16 (CI's share: each solve takes seconds) to about ±10 %; it must lie within 3σ of 1."""
    ratio, sd, _ = _network_ratio(24, 200, seeds)
    print(f"24 × 200, {seeds} seeds: reported σ / RMS error {ratio:.3f} ± {sd:.3f}")
    assert abs(ratio - 1) < 3 * sd, (ratio, sd)


@pytest.mark.campaign
def test_the_72_by_1000_network_reports_the_sigma_of_its_errors():
    """100 seeds (about 6 min): pooled ratio within 3σ of 1 (σ ≈ 3 %), every target within 0.8–1.25
    (each known to ±7 %)."""
    ratio, sd, per_target = _network_ratio(72, 1000, 100)
    print(f"72 × 1000, 100 seeds: {ratio:.3f} ± {sd:.3f}; per target {per_target.min():.2f}–{per_target.max():.2f}")
    assert abs(ratio - 1) < 3 * sd and np.all((per_target > 0.8) & (per_target < 1.25)), (ratio, sd, per_target)


@pytest.mark.campaign
def test_the_two_mount_network_reports_the_sigma_of_its_errors_at_every_target():
    """The two-mount network of tests/test_network.py (0.5 µm radial and 1″ tilt error motions, measured
    from mounts at 65 mm and 130 mm), 0.2 µm length noise, 30 seeds (about 80 s; in CI the two-mount
    network is checked on 3 datasets by tests/test_network.py): per target, the first step after the
    reference included, the ratio is known to ±1/√60 ≈ 13 %; every target within 0.6–1.5 (3σ), and the
    pooled ratio within 0.8–1.25."""
    from tests.test_network import _two_mount_data

    noise = StationNoiseModel(length_noise_um=0.2, length_noise_ppm=0.0, point_noise_um=0.1)
    errs, us = [], []
    for seed in range(30):
        data, P, truth, _ = _two_mount_data(0.2, np.random.default_rng(100 + seed))
        est = solve_network(data, P[0, 0], noise=noise, mount_guesses_mm=[P[1, 0]])
        errs.append((est.cumulative_deviation_arcsec - truth)[1:])
        us.append(est.budget.uncertainty_arcsec[1:])
    e, u = np.array(errs), np.array(us)
    per_target = np.sqrt(np.mean(u**2, 0) / np.mean(e**2, 0))
    pooled = float(np.sqrt(np.mean(u**2) / np.mean(e**2)))
    print(f"two mounts, 30 seeds: per target {np.round(per_target, 2)}, pooled {pooled:.3f}")
    assert np.all((per_target > 0.6) & (per_target < 1.5)), per_target
    assert 0.8 < pooled < 1.25, pooled
