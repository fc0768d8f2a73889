"""How long a command takes before it does anything (issue 36, item 18): every rtcal command pays
its imports, so `rtcal --help` and `rtcal validate` are timed against the floor of any command that
reads a procedure, ``python -c "import numpy, yaml, pydantic"``.

    python benchmarks/bench_startup.py [--repeat 9]

Prints the best of N wall times of each and the ratios (goal: --help within 2.5×, validate within
4× of the floor). Bytecode is written and used as on a user's machine (PYTHONDONTWRITEBYTECODE is
unset for the children), so the first repeat warms the cache and the best of the rest is reported.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
COMMANDS = {
    "floor (import numpy, yaml, pydantic)": [sys.executable, "-c", "import numpy, yaml, pydantic"],
    "rtcal --help": [sys.executable, "-m", "rtcal.cli", "--help"],
    "rtcal validate (shipped multistation)": [sys.executable, "-m", "rtcal.cli", "validate",
                                              str(REPO / "procedures" / "laser_tracer_multistation.yaml")],
}


def best_s(argv: list[str], repeat: int) -> float:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    times = []
    for _ in range(repeat + 1):
        t0 = time.perf_counter()
        subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, cwd=REPO, check=True)
        times.append(time.perf_counter() - t0)
    return min(times[1:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=9)
    args = parser.parse_args()
    results = {name: best_s(argv, args.repeat) for name, argv in COMMANDS.items()}
    floor = next(iter(results.values()))
    for name, seconds in results.items():
        print(f"{name:40s} {seconds * 1000:7.0f} ms  {seconds / floor:4.2f}× the floor")


if __name__ == "__main__":
    main()
