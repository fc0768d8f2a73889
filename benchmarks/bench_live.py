"""The cost of watching: a run with the live view served and N browsers' event streams
connected, against the same run unwatched.

    python benchmarks/bench_live.py [--viewers 20] [--repeat 3]

The run is the ISO 230-2 procedure on the in-process simulated bench (virtual clock), so it is
bound by the CPU and writes its readings far faster than a run in real time: the worst case for
the view, which polls the store read-only. The viewers are another process (their own CPU is not
the run's), each holding /api/events open as the page does. Prints the fastest and median wall
time of each, and the CPU time of this process (the run and the server's threads), which the
machine's other load disturbs less. Goal (issue 24): under 5 %.
"""

from __future__ import annotations

import argparse
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


def one_run(out: Path, viewers: int) -> tuple[float, float, str]:
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
        t0, c0 = time.perf_counter(), time.process_time()
        run_procedure(PROCEDURE, out_dir=out, show_progress=False, outputs=False)
        elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
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
    args = parser.parse_args()
    times: dict[int, list[float]] = {0: [], args.viewers: []}
    cpus: dict[int, list[float]] = {0: [], args.viewers: []}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.repeat):
            for n in (0, args.viewers):  # interleaved: the machine's other load falls on both alike
                t, cpu, note = one_run(Path(tmp) / f"run-{k}-{n}", n)
                times[n].append(t)
                cpus[n].append(cpu)
                print(f"run {k + 1}, {n:2d} viewers: {t:6.2f} s wall, {cpu:6.2f} s CPU{note}", flush=True)
    for label, data in (("wall", times), ("CPU", cpus)):
        for stat in (min, statistics.median):
            base, watched = stat(data[0]), stat(data[args.viewers])
            print(f"{label} {stat.__name__:6s}: unwatched {base:.2f} s, with {args.viewers} viewers {watched:.2f} s: "
                  f"{100 * (watched - base) / base:+.1f} % (goal: under 5 %)")

if __name__ == "__main__":
    main()
