"""Why the axis location's u covers (issue 29): its first-order error model checked bench by bench.

    PYTHONPATH=$PWD python benchmarks/bench_axis_location.py [--benches 100] [--draws 6000]

On the two-mount benches of tests/test_axis_location.py, for each bench:
- the location's actual error against its first-order prediction G·(H·e − S⁻¹Λ·x_m), e the noise the
  bench drew (tracer lengths, CMM points), x_m its true error motions in the network's parametrisation
  (δ at the circle's centre, ε), H and S⁻¹ the adjustment's (docs/paper000.md, "Location errors");
- u against σ_true, the standard deviation of that error over the bench's draws (the Type A sizes at
  their true values instead of the REML estimates), and the coverage P(|error| ≤ 2u) it implies.
Then the stated model of the error motions C against the bench's own draws, projected on what the
location sees of them (``--draws`` benches drawn, no solving).

The solver's internals are read by wrapping two of its functions (this script only; rtcal does not
expose them). Prints the worst |actual − predicted|/u, the expected RMS error/u and coverage per value.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.stats import norm

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import test_axis_location as T  # noqa: E402  (the benches and their truth)
from rtcal.solvers import network as N  # noqa: E402
from rtcal.solvers.location import location_jacobian, stated_motion_covariance  # noqa: E402

_seen: dict = {}
_unseen, _propagate = N._unseen_motions, N.propagate


def _spy_unseen(S_inv, lay, prior, nominal, lever_mm, noise):
    _seen.update(S_inv=S_inv, lay=lay, prior=prior, nominal=nominal, lever=lever_mm, noise=noise)
    return _unseen(S_inv, lay, prior, nominal, lever_mm, noise)


def _spy_propagate(H, sources, variances, G):
    if G.shape[0] == 4:  # the location's propagation
        _seen["H"] = H
    return _propagate(H, sources, variances, G)


N._unseen_motions, N.propagate = _spy_unseen, _spy_propagate


def true_motions(bench, lay, lever_mm: float) -> np.ndarray:
    """The bench's error motions at the targets as the network's unknowns (δ at the circle's centre, ε)."""
    x = np.zeros(lay.g)
    for j, th in enumerate(np.deg2rad(T.ANGLES_DEG)):
        d, ex, ey = bench.error_motions(th)
        x[lay.delta.start + 3 * j: lay.delta.start + 3 * j + 3] = d + np.array([ey * lever_mm, -ex * lever_mm, 0.0])
        x[lay.eps.start + 2 * j: lay.eps.start + 2 * j + 2] = [ex, ey]
    return x


def one_bench(seed: int):
    """(error, first-order prediction, u, σ_true) of X0C, Y0C, A0C, B0C on bench ``seed`` (two mounts)."""
    rng = np.random.default_rng([29, 2, seed])
    bench = T._bench(rng)
    state = rng.bit_generator.state
    data, first = T.readings(bench, 2, rng)
    exact_rng = np.random.default_rng()
    exact_rng.bit_generator.state = state
    exact, _ = T.readings(bench, 2, exact_rng, tracer_um=0.0, point_um=0.0)
    est = N.solve_network(data, first[0] + rng.normal(0.0, 0.3, 3), noise=T.noise_model(), mount_guesses_mm=[first[1]],
                          options=N.NetworkOptions(check_residuals=False))
    lay, S_inv, (idx, sigma) = _seen["lay"], _seen["S_inv"], _seen["prior"]
    e = np.concatenate([(data.lengths_mm - exact.lengths_mm).ravel(), (data.other_mounts[0].lengths_mm
                        - exact.other_mounts[0].lengths_mm).ravel(), (data.points_mm - exact.points_mm).ravel()])
    J = location_jacobian(est.axis_point_mm, est.axis_direction[:2])
    G = np.zeros((4, lay.g))
    G[:, lay.c], G[:, lay.a] = J[:, :3], J[:, 3:]
    lam = np.zeros(lay.g)
    lam[idx] = 1.0 / sigma**2
    lever = est.axis_point_mm[2] - bench.tilt_center[2] - bench.axis_point_mm[2]
    predicted = G @ (_seen["H"] @ e) - G @ (S_inv @ (lam * true_motions(bench, lay, lever)))
    loc = est.axis_location
    assert loc is not None, est.message
    error = loc.values - T.true_location(bench)
    parts = dict(loc.components)
    scale = est.variances.scale
    true_var = sum(s**2 / scale.get(name, 1.0) for name, s in parts.items())  # Type A sizes at the truth (θ = 1)
    return error, predicted, loc.sigma, np.sqrt(true_var)


def model_against_draws(draws: int) -> np.ndarray:
    """Var(what the location takes of the motions) over ``draws`` benches' own motions ÷ the stated model's."""
    one_bench(0)  # the geometry's S⁻¹ and priors
    lay, S_inv, (idx, sigma) = _seen["lay"], _seen["S_inv"], _seen["prior"]
    order = np.column_stack([lay.delta.start + 3 * np.arange(lay.m) + k for k in range(3)]
                            + [lay.eps.start + 2 * np.arange(lay.m) + k for k in range(2)]).ravel()
    weight = dict(zip(idx.tolist(), (1.0 / sigma**2).tolist()))
    J = location_jacobian(np.array([0.8, -0.5, 162.5]), np.array([-9.7e-5, -1.45e-4]))
    G = np.zeros((4, lay.g))
    G[:, lay.c], G[:, lay.a] = J[:, :3], J[:, 3:]
    W = -(G @ S_inv)[:, order] * np.array([weight[i] for i in order])
    C = stated_motion_covariance(_seen["nominal"], _seen["lever"], _seen["noise"])
    X = np.array([true_motions(T._bench(np.random.default_rng([11, s])), lay, _seen["lever"])[order] for s in range(draws)])
    return ((X @ W.T) ** 2).mean(0) / np.einsum("ij,jk,ik->i", W, C, W)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--benches", type=int, default=100)
    ap.add_argument("--draws", type=int, default=6000)
    a = ap.parse_args()
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):  # small matrices: one BLAS thread is faster (tests/test_axis_location.py)
        rows = [one_bench(s) for s in range(a.benches)]
    err, pred, u, s_true = (np.array(v) for v in zip(*rows))
    names = ", ".join(T.LOCATION_LABELS)
    print(f"{a.benches} benches, two mounts ({names})")
    print("  worst |actual − first-order prediction| / u:", np.abs((err - pred) / u).max(0).round(4))
    print("  u / σ_true, mean and range:", (u / s_true).mean(0).round(4), (u / s_true).min(0).round(3), (u / s_true).max(0).round(3))
    print("  expected RMS error/u:", np.sqrt(((s_true / u) ** 2).mean(0)).round(4))
    print("  expected coverage of U (k = 2):", (2 * norm.cdf(2 * u / s_true) - 1).mean(0).round(4))
    print("  measured RMS error/u on these benches:", np.sqrt(((err / u) ** 2).mean(0)).round(3))
    print(f"  motions: drawn ÷ stated variance over {a.draws} benches (±{np.sqrt(2 / a.draws):.3f}):",
          model_against_draws(a.draws).round(3))


if __name__ == "__main__":
    main()
