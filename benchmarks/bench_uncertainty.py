"""Wall time of `rtcal uncertainty` on one process and on the process pool: the parallel speed-up.

    python benchmarks/bench_uncertainty.py [--trials N] [--procedure PATH]

Prints the wall time per trial in one process (BLAS free to use every core) and on a pool of
one worker per core (each single-threaded), and their ratio.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rtcal.cli import main as rtcal  # noqa: E402


def wall(args: list[str]) -> float:
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        assert rtcal(args) == 0
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--procedure", default=str(REPO / "procedures" / "laser_tracer_multistation.yaml"))
    args = parser.parse_args()
    cores = os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as tmp:
        base = ["uncertainty", args.procedure, "--trials", str(args.trials)]
        one = wall(base + ["--workers", "1", "--out", f"{tmp}/one"])
        pool = wall(base + ["--workers", str(cores), "--out", f"{tmp}/pool"])
    print(f"{args.trials} trials of {Path(args.procedure).name}: one process {one:.1f} s ({one / args.trials:.2f} s/trial), "
          f"{cores} workers {pool:.1f} s ({pool / args.trials:.2f} s/trial): speed-up {one / pool:.2f}× on {cores} cores")


if __name__ == "__main__":
    main()
