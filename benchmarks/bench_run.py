"""Wall time of a full simulated run and of the seed-000 solver chain on the paper's 704 lengths.

    python benchmarks/bench_run.py [--repeat N]

Prints one line per figure (best and median of N repeats). Goals: a full simulated run under
10 s on a 2-core machine.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rtcal.run.runner import run_procedure  # noqa: E402
from rtcal.solvers.paper000 import solve_paper  # noqa: E402
from rtcal.solvers.shared_dead_path import solve_shared_dead_path  # noqa: E402
from tests.synthetic import FIRST_GUESS_MM, data, dataset  # noqa: E402


def timed(fn, repeat: int) -> list[float]:
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    procedure = REPO / "procedures" / "laser_tracer_multistation.yaml"
    abbe = REPO / "procedures" / "encoder_abbe_error.yaml"
    with tempfile.TemporaryDirectory() as tmp:
        counter = iter(range(10**6))
        run_times = timed(lambda: run_procedure(procedure, out_dir=Path(tmp) / f"r{next(counter)}", show_progress=False), args.repeat)
        abbe_times = timed(lambda: run_procedure(abbe, out_dir=Path(tmp) / f"r{next(counter)}", show_progress=False), args.repeat)
    rng = np.random.default_rng(0)
    points, lengths, _ = dataset(np.zeros(11), 0.2, rng)
    assert lengths.size == 704
    solve_times = timed(lambda: solve_paper(data(points, lengths), FIRST_GUESS_MM), args.repeat)
    shared_times = timed(lambda: solve_shared_dead_path(data(points, lengths), FIRST_GUESS_MM), args.repeat)
    for name, ts in (("full simulated run (paper-000 procedure, 704 readings)", run_times),
                     ("paper solver chain on 704 lengths (with REML and the budget)", solve_times),
                     ("shared-dead-path solver on 704 lengths (with REML and the budget)", shared_times),
                     ("full simulated run (seed-001 procedure, 96 visits, 5 figures)", abbe_times)):
        print(f"{name}: best {min(ts):.3f} s, median {statistics.median(ts):.3f} s over {len(ts)}")


if __name__ == "__main__":
    main()
