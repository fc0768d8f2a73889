"""Is the reported σ right? The two questions of issue 20, settled with enough trials.

    python benchmarks/bench_sigma.py network [--stations 72] [--points 1000] [--seeds 60]
    python benchmarks/bench_sigma.py two-mount [--trials 200] [--seed 25] [--workers 1]

``network``: the synthetic network of benchmarks/bench_network.py (no systematic errors: tracer
and CMM noise, the CMM's scales solved) solved once per seed. Prints, over the seeds, the RMS error
against truth and the RMS reported 1σ per target and overall, their ratio with its 1σ (bootstrap
over seeds), and how one seed's RMS over the targets spreads — the errors of the 71 cumulative
targets are strongly correlated, so a single seed's RMS is one draw of a few degrees of freedom,
not a measure of σ.

``two-mount``: ``rtcal uncertainty`` on tests/data/mc/second_mount.yaml (network only), the error
motions drawn in balanced pairs (``--balanced``: antithetic, moment-matched, so the systematic
draws add no sampling noise to the squared errors). Prints the ratio per target with its 1σ
(≈ ratio/√(2N)).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))


def network_study(m: int, n: int, seeds: int) -> None:
    from threadpoolctl import threadpool_limits

    from bench_network import network_data
    from rtcal.solvers.network import solve_network
    from rtcal.solvers.station_budget import StationNoiseModel

    errs, us = [], []
    t0 = time.perf_counter()
    with threadpool_limits(1):
        for s in range(seeds):
            data, first, truth = network_data(m, n, seed=s)
            est = solve_network(data, first, np.zeros(3),
                                StationNoiseModel(length_noise_um=0.2, length_noise_ppm=0.0, point_noise_um=1.0))
            errs.append(est.cumulative_deviation_arcsec - truth)
            us.append(est.budget.uncertainty_arcsec)
    e, u = np.array(errs)[:, 1:], np.array(us)[:, 1:]
    rng = np.random.default_rng(0)
    boot = [np.sqrt(np.mean(u[k] ** 2)) / np.sqrt(np.mean(e[k] ** 2)) for k in rng.integers(0, seeds, (2000, seeds))]
    per_target = np.sqrt(np.mean(u**2, 0)) / np.sqrt(np.mean(e**2, 0))
    per_seed = np.sqrt(np.mean(e**2, 1)) / np.sqrt(np.mean(u**2, 1))
    overall = np.sqrt(np.mean(u**2)) / np.sqrt(np.mean(e**2))
    print(f"network {m} stations × {n} points, {seeds} seeds ({time.perf_counter() - t0:.0f} s):")
    print(f"  RMS error {np.sqrt(np.mean(e**2)):.4f}″, RMS reported 1σ {np.sqrt(np.mean(u**2)):.4f}″")
    print(f"  reported σ / RMS error overall {overall:.3f} ± {np.std(boot):.3f} (1σ, bootstrap over seeds); per target "
          f"{per_target.min():.2f}–{per_target.max():.2f} (each ± {1 / np.sqrt(2 * seeds):.2f})")
    print(f"  one seed's RMS error / its RMS reported 1σ: median {np.median(per_seed):.2f}, 5–95 % "
          f"{np.percentile(per_seed, 5):.2f}–{np.percentile(per_seed, 95):.2f}, max {per_seed.max():.2f}; seed 0 (what "
          f"bench_network.py prints) {per_seed[0]:.2f}")


def two_mount_study(trials: int, seed: int, workers: int) -> None:
    from rtcal.cli import main

    src = REPO / "tests" / "data" / "mc"
    with tempfile.TemporaryDirectory(prefix="sigma-") as tmp:
        folder = Path(tmp)
        (folder / "second_mount_bench.yaml").write_text((src / "second_mount_bench.yaml").read_text())
        text = (src / "second_mount.yaml").read_text().replace("uncertainty:", "solver: {estimators: [network]}\nuncertainty:", 1)
        (folder / "p.yaml").write_text(text)
        t0 = time.perf_counter()
        code = main(["uncertainty", str(folder / "p.yaml"), "--trials", str(trials), "--balanced", "--seed", str(seed),
                     "--workers", str(workers), "--out", str(folder / "mc")])
        if code != 0:
            raise SystemExit(code)
        s = json.loads((folder / "mc" / "uncertainty.json").read_text())
    e = s["estimators"]["network"]
    ratio = np.array(e["ratio"][1:], float)
    print(f"two-mount network, {trials} balanced trials, seed {seed} ({time.perf_counter() - t0:.0f} s): reported σ / RMS "
          f"error per target {', '.join(f'{r:.2f}' for r in ratio)} (each ± {np.mean(ratio) / np.sqrt(2 * trials):.2f}); "
          f"first step after the reference {ratio[0]:.2f}; overall {e['overall']['rms_reported_sigma_arcsec']}″ / "
          f"{e['overall']['rms_error_arcsec']}″")


def main() -> None:
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="study", required=True)
    net = sub.add_parser("network")
    net.add_argument("--stations", type=int, default=72)
    net.add_argument("--points", type=int, default=1000)
    net.add_argument("--seeds", type=int, default=60)
    two = sub.add_parser("two-mount")
    two.add_argument("--trials", type=int, default=200)
    two.add_argument("--seed", type=int, default=25)
    two.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    if args.study == "network":
        network_study(args.stations, args.points, args.seeds)
    else:
        two_mount_study(args.trials, args.seed, args.workers)


if __name__ == "__main__":
    main()
