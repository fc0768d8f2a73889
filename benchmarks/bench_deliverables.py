"""`rtcal evaluate`, `compensate` and `compare` at size: 10 000, 100 000 and 200 000 rows.

    python benchmarks/bench_deliverables.py [--rows 10000 100000 200000] [--timeout 120]

Each size is a deviation CSV with (almost) every row its own target — the worst case for work
grouped by target: rows/2 distinct targets over one turn, both directions, one run, a 3″ first
harmonic and 0.2″ noise. Each command runs as `python -m rtcal.cli` in its own process (wall
time including the interpreter's start, about 1 s) and is stopped at --timeout. Goal: every
command at most n log n in rows — the 200 000-row time about twice the 100 000-row time, not
four times — and under 30 s at 200 000 rows on 2 cores. CPU time is printed beside wall time: on
a machine others share, it is the figure that compares.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def deviation_csv(path: Path, rows: int, seed: int = 0) -> Path:
    """rows/2 targets 360°/(rows/2) apart, each approached once in each direction."""
    rng = np.random.default_rng(seed)
    targets = np.linspace(0.0, 360.0, rows // 2, endpoint=False)
    lines = ["target_deg,direction,run,deviation_arcsec,uncertainty_arcsec"]
    for d, offset in ((1, 0.5), (-1, -0.5)):
        x = 3.0 * np.sin(np.radians(targets)) + offset + 0.2 * rng.standard_normal(len(targets))
        lines += [f"{t:.9g},{d},1,{v:.4f},0.1000" for t, v in zip(targets, x)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def timed(args: list[str], timeout_s: float) -> str:
    """CPU time (user + system: what a busy machine does not inflate) and wall time of one command in
    its own process, or how it failed."""
    before, t0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    try:
        done = subprocess.run([sys.executable, "-m", "rtcal.cli", *args], cwd=REPO, capture_output=True, text=True,
                              timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return f"> {timeout_s:.0f} s wall (stopped)"
    wall, after = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if done.returncode != 0:
        return f"exit {done.returncode}: {done.stderr.strip()[-120:]}"
    return f"{cpu:.1f} s cpu ({wall:.1f} wall)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, nargs="+", default=[10_000, 100_000, 200_000])
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds before a command is stopped")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        print(f"{'rows':>8}  {'evaluate':>24}  {'compensate':>24}  {'compare':>24}")
        for rows in args.rows:
            a = deviation_csv(folder / f"a{rows}.csv", rows, seed=1)
            b = deviation_csv(folder / f"b{rows}.csv", rows, seed=2)
            times = [timed(["evaluate", str(a)], args.timeout),
                     timed(["compensate", str(a), "--format", "linuxcnc", "--step-deg", "15", "--out", str(folder / f"c{rows}.comp")],
                           args.timeout),
                     timed(["compare", str(a), str(b), "--json", "--out", str(folder / f"cmp{rows}")], args.timeout)]
            print(f"{rows:>8}  " + "  ".join(f"{t:>24}" for t in times), flush=True)


if __name__ == "__main__":
    main()
