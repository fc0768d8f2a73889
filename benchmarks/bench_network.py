"""The network estimator at size: 72 stations × 1000 points, free points, CMM solved.

    python benchmarks/bench_network.py [--stations 72] [--points 1000] [--no-dense]

Solves the same synthetic network twice, each in its own process so that each peak memory is its
own: rtcal's formulation (points eliminated block by block: a Schur complement of 3×3 blocks) and
the dense formulation (the whole Jacobian as one dense matrix, normal equations solved densely).
Prints wall time, peak resident memory and the error against the injected truth for both, and
their ratio. Goal: under 5 s and 1 GB for the 72 × 1000 network on 2 cores.

The error printed is one seed's: the 71 cumulative targets' errors are strongly correlated, so their
RMS is one draw of a few degrees of freedom (over 100 seeds, one seed's RMS error / its reported 1σ
spreads 0.66–1.47 between its 5th and 95th percentiles, and this seed's is among the largest). Whether
the reported σ matches the errors is `python benchmarks/bench_sigma.py network` (many seeds).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def network_data(m: int, n: int, seed: int = 0):
    """Stations 360°/m apart on a 65 mm circle at 122.5 mm, n points in a 1.2 m box beside the table,
    0.2 µm length noise, 1 µm CMM point noise; εz of 3″ and 1″ harmonics; a CMM off by 5/−3/2 ppm."""
    from rtcal.solvers.network import cmm_matrix
    from rtcal.solvers.station_data import MultistationData

    rng = np.random.default_rng(seed)
    nominal = np.deg2rad(360.0 / m * np.arange(m))
    eps = np.deg2rad((3.0 * np.sin(nominal + 0.3) + 1.0 * np.sin(3 * nominal)) / 3600)
    phi = nominal + eps + np.deg2rad(-29.2)
    stations = np.column_stack([65.33 * np.cos(phi), 65.33 * np.sin(phi), np.full(m, 122.5)])
    points = rng.uniform([500, -600, 0], [1700, 600, 800], (n, 3))
    dist = np.linalg.norm(points[:, None, :] - stations[None], axis=2)
    lengths = dist - dist[0, 0] + 2e-4 * rng.standard_normal(dist.shape)
    reported = points @ np.linalg.inv(cmm_matrix(np.array([5.0, -3.0, 2.0, 0.0, 0.0, 0.0]))).T + 1e-3 * rng.standard_normal(points.shape)
    truth = (eps - eps[0]) * 206264.80624709636
    data = MultistationData.from_arrays(reported, lengths, np.rad2deg(nominal))
    return data, stations[0], truth


def run_sparse(m: int, n: int) -> dict:
    from rtcal.solvers.network import solve_network
    from rtcal.solvers.station_budget import StationNoiseModel

    data, first, truth = network_data(m, n)
    t0 = time.perf_counter()
    est = solve_network(data, first, np.zeros(3), StationNoiseModel(length_noise_um=0.2, length_noise_ppm=0.0, point_noise_um=1.0))
    wall = time.perf_counter() - t0
    return {"wall_s": wall, "error_arcsec": float(np.sqrt(np.mean((est.cumulative_deviation_arcsec - truth)[1:] ** 2))),
            "reported_arcsec": float(np.sqrt(np.mean(est.budget.uncertainty_arcsec[1:] ** 2))), "converged": est.converged}


def run_dense(m: int, n: int) -> dict:
    """The same adjustment (same model, weights as stated, no variance re-estimation) with a dense
    Jacobian and dense normal equations: the baseline the block elimination is measured against."""
    from rtcal.solvers.network import _Layout, _model

    data, first, truth = network_data(m, n)
    lengths, points = data.lengths_mm, data.points_mm
    pi, sj = np.nonzero(np.isfinite(lengths))
    obs = lengths[pi, sj]
    seg = np.zeros(len(obs), int)
    lay = _Layout(m, 1, n, True, True)
    x = np.zeros(lay.size)
    nominal = np.deg2rad(data.nominal_angles_deg)
    x[lay.c] = [0.0, 0.0, first[2]]
    x[lay.r] = float(np.hypot(first[0], first[1]))
    x[lay.phi] = np.arctan2(first[1], first[0]) + nominal - nominal[0]
    x[lay.g:] = points.ravel()
    P0 = x[lay.c] + x[lay.r] * np.column_stack([np.cos(x[lay.phi]), np.sin(x[lay.phi]), np.zeros(m)])
    x[lay.d] = np.mean(np.linalg.norm(points[pi] - P0[sj], axis=1) - obs)
    w_len, w_pts = 1.0 / 2e-4**2, 1.0 / 1e-3**2
    t0 = time.perf_counter()
    for _ in range(20):
        f_len, Jg, Jp, f_pts, Jg_pts, P, A, Minv = _model(x, lay, pi, sj, seg, obs, points, np.zeros(6))
        J = np.zeros((len(obs) + 3 * n, lay.size))
        J[: len(obs), : lay.g] = Jg
        J[np.arange(len(obs))[:, None], lay.g + 3 * pi[:, None] + np.arange(3)] = Jp
        J[len(obs):, : lay.g] = Jg_pts
        for i in range(n):
            J[len(obs) + 3 * i : len(obs) + 3 * i + 3, lay.g + 3 * i : lay.g + 3 * i + 3] = Minv
        sw = np.sqrt(np.concatenate([np.full(len(obs), w_len), np.full(3 * n, w_pts)]))
        f = np.concatenate([f_len, f_pts]) * sw
        J *= sw[:, None]
        step = np.linalg.solve(J.T @ J, -(J.T @ f))
        x = x + step
        del J
        if np.max(np.abs(step)) < 1e-10:
            break
    wall = time.perf_counter() - t0
    phi = x[lay.phi]
    cum = (phi - phi[0] - (nominal - nominal[0])) * 206264.80624709636
    return {"wall_s": wall, "error_arcsec": float(np.sqrt(np.mean((cum - truth)[1:] ** 2)))}


def child(kind: str, m: int, n: int) -> None:
    out = run_sparse(m, n) if kind == "sparse" else run_dense(m, n)
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps(out))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--stations", type=int, default=72)
    parser.add_argument("--points", type=int, default=1000)
    parser.add_argument("--no-dense", action="store_true", help="skip the dense baseline (it needs about 3 GB at full size)")
    parser.add_argument("--child", choices=["sparse", "dense"], help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child, args.stations, args.points)
        return
    results = {}
    for kind in ["sparse"] + ([] if args.no_dense else ["dense"]):
        proc = subprocess.run([sys.executable, __file__, "--child", kind, "--stations", str(args.stations),
                               "--points", str(args.points)], capture_output=True, text=True, check=True)
        results[kind] = json.loads(proc.stdout.strip().splitlines()[-1])
        r = results[kind]
        extra = (f", reported 1σ {r['reported_arcsec']:.3f}″ (one seed: the σ is checked over many by "
                 f"benchmarks/bench_sigma.py network), converged {r['converged']}") if kind == "sparse" else ""
        print(f"{kind:6s} {args.stations} stations × {args.points} points: {r['wall_s']:.2f} s, peak {r['peak_rss_mb']:.0f} MB, "
              f"RMS error {r['error_arcsec']:.3f}″{extra}")
    if "dense" in results:
        s, d = results["sparse"], results["dense"]
        print(f"block elimination against dense: {d['wall_s'] / s['wall_s']:.1f}× faster, "
              f"{d['peak_rss_mb'] / s['peak_rss_mb']:.1f}× less memory")


if __name__ == "__main__":
    main()
