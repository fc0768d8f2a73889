"""Wall time of the paper-000 run over real transports against `rtcal sim serve`.

    python benchmarks/bench_transport.py [--repeat N]

Starts the protocol simulators in a separate process (Modbus TCP stage, I++ CMM, tracer on a
pseudo-terminal), runs the procedure with a virtual clock, and prints best and median times.
Goal: under 60 s on a 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rtcal.run.runner import run_procedure  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    procedure = REPO / "procedures" / "laser_tracer_multistation.yaml"
    scenario = REPO / "procedures" / "scenarios" / "paper000_bench.yaml"
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.repeat):
            server = subprocess.Popen([sys.executable, "-m", "rtcal.cli", "sim", "serve", "--scenario", str(scenario)],
                                      stdout=subprocess.PIPE, text=True)
            try:
                addresses = json.loads(server.stdout.readline())
                t0 = time.perf_counter()
                run_procedure(procedure, out_dir=Path(tmp) / f"r{k}", show_progress=False, addresses=addresses, virtual_clock=True)
                times.append(time.perf_counter() - t0)
            finally:
                server.terminate()
                server.wait(10)
    print(f"paper-000 run over transports (704 readings): best {min(times):.2f} s, "
          f"median {statistics.median(times):.2f} s over {len(times)}")


if __name__ == "__main__":
    main()
