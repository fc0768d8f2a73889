"""The cost of watching: a run with the live view served and N browsers' event streams
connected, against the same run unwatched.

    python benchmarks/bench_live.py [--viewers 20] [--repeat 3] [--wired]

The run is the ISO 230-2 procedure on the in-process simulated bench (virtual clock), so it is
bound by the CPU and writes its readings far faster than a run in real time: the worst case for
the view, which polls the store read-only. ``--wired``: the same procedure over the wires of
`rtcal sim serve` in real time (settle times waited, about two minutes a run), as `rtcal run
--live` on hardware would be watched. The viewers are another process (their own CPU is not
the run's), each holding /api/events open as the page does. Prints the fastest and median wall
time of each, and the CPU time of this process (the run and the server's threads), which the
machine's other load disturbs less. Goal (issue 24): under 5 %.
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

from rtcal.live.server import LiveServer  # noqa: E402
from rtcal.run.runner import run_procedure  # noqa: E402

PROCEDURE = REPO / "procedures" / "iso230_2_polygon.yaml"

VIEWERS = r"""
import http.client, sys, threading, time
port, n = int(sys.argv[1]), int(sys.argv[2])
counts = [0] * n
def view(i):
    while True:
        try:
            c = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
            c.request("GET", "/api/events")
            r = c.getresponse()
            while True:
                chunk = r.read1(65536)
                if not chunk:
                    break
                counts[i] += chunk.count(b"event: reading")
        except OSError:
            time.sleep(0.2)
for i in range(n):
    threading.Thread(target=view, args=(i,), daemon=True).start()
print("ready", flush=True)
sys.stdin.readline()
print(min(counts), max(counts), flush=True)
"""


def one_run(out: Path, viewers: int, wired: bool = False) -> tuple[float, float, str]:
    out.mkdir()
    server = watchers = None
    note = ""
    if viewers:
        server = LiveServer(out, port=0)
        server.start()
        watchers = subprocess.Popen([sys.executable, "-c", VIEWERS, str(server.port), str(viewers)],
                                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert watchers.stdout.readline().strip() == "ready"
        time.sleep(1.0)  # every stream connected
    try:
        sim = None
        addresses = None
        if wired:
            sim = subprocess.Popen([sys.executable, "-m", "rtcal.cli", "sim", "serve", "--scenario",
                                    str(REPO / "procedures" / "scenarios" / "abbe_bench.yaml")],
                                   stdout=subprocess.PIPE, text=True)
            addresses = json.loads(sim.stdout.readline())
        try:
            t0, c0 = time.perf_counter(), time.process_time()
            run_procedure(PROCEDURE, out_dir=out, show_progress=False, outputs=False, addresses=addresses)
            elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
        finally:
            if sim is not None:
                sim.terminate()
                sim.wait(10)
        if watchers is not None:
            time.sleep(1.5)  # the streams catch up with the last readings
            lo, hi = watchers.communicate("\n", timeout=30)[0].split()
            note = f"  (each viewer received {lo}–{hi} reading events)"
    finally:
        if watchers is not None and watchers.poll() is None:
            watchers.kill()
        if server is not None:
            server.stop()
    return elapsed, cpu, note


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--viewers", type=int, default=20)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--wired", action="store_true", help="over `rtcal sim serve` in real time")
    args = parser.parse_args()
    times: dict[int, list[float]] = {0: [], args.viewers: []}
    cpus: dict[int, list[float]] = {0: [], args.viewers: []}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.repeat):
            for n in (0, args.viewers):  # interleaved: the machine's other load falls on both alike
                t, cpu, note = one_run(Path(tmp) / f"run-{k}-{n}", n, args.wired)
                times[n].append(t)
                cpus[n].append(cpu)
                print(f"run {k + 1}, {n:2d} viewers: {t:6.2f} s wall, {cpu:6.2f} s CPU{note}", flush=True)
    for stat in (min, statistics.median):
        base, watched = stat(times[0]), stat(times[args.viewers])
        print(f"wall {stat.__name__:6s}: unwatched {base:.2f} s, with {args.viewers} viewers {watched:.2f} s: "
              f"{100 * (watched - base) / base:+.1f} % (goal: under 5 %)")
    extra = statistics.median(cpus[args.viewers]) - statistics.median(cpus[0])
    print(f"CPU of watching (median): {extra:+.2f} s, {100 * extra / statistics.median(times[args.viewers]):.1f} % of "
          "one core over the run")

if __name__ == "__main__":
    main()
