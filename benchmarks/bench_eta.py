"""The time left as the live page shows it, against the time the run then really took: every shipped
procedure run in real time on rtcal's protocol simulators, as `rtcal sim serve` and `rtcal run
--instruments` run it (the hub in this process: settle times waited, every reading over its wire, the
simulated operator doing the operator steps at once), each run after the other.

    python benchmarks/bench_eta.py [--procedures iso230_2_polygon periodic_error] [--stage-speed]

A thread reads the page's state (rtcal.live.storeview, as `rtcal view` reads it) every 0.5 s; at 1, 2, 5,
10, 20, 30 and 60 minutes the time left it then showed is compared with the time the run then still took
to its results (measuring, solving and writing). Prints per procedure the walk's duration, the real one,
the error at each mark (page − real, in % of the real time left), the worst error from the first minute on
while at least 30 s remained (and the same for the time left to the last reading alone), the estimate before
the first reading, and the time from the last reading to the results against the solving and writing the
estimate held. ``--stage-speed``: the simulated
drive turns at the bench's speed in wall time (a real table) instead of at once. Goal (issue 46): within
10 % from the first minute on.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rtcal.engine.walk import Timing, walk  # noqa: E402
from rtcal.live.storeview import StoreView  # noqa: E402
from rtcal.methods import METHODS, load_procedure  # noqa: E402
from rtcal.run.runner import resolve_scenario, run_procedure  # noqa: E402
from simulators.servers.hub import SimulatorHub  # noqa: E402

MARKS_MIN = (1, 2, 5, 10, 20, 30, 60)
SHIPPED = ("encoder_abbe_error", "iso230_2_polygon", "iso230_2_verification", "periodic_error", "polygon_closure",
           "laser_tracer_multistation")


class PageWatch:
    """``on_engine``: from the engine's start, the page's time left every ``every_s`` of wall time."""

    def __init__(self, every_s: float = 0.5):
        self.every_s = every_s
        self.samples: list[tuple[float, float | None, float]] = []  # (wall s since the start, time left, solving in it)
        self.last_reading_s: float | None = None  # when the page first showed every planned reading done
        self.solving_s: float | None = None  # the solving and writing the page's time left holds
        self.t0: float | None = None
        self._stop = threading.Event()

    def __call__(self, engine, run_dir: Path):
        view = StoreView(run_dir, 0.0)
        self.t0 = time.monotonic()

        def watch() -> None:
            while not self._stop.wait(self.every_s):
                state = view.state()
                t = time.monotonic() - self.t0
                if state["state"] == "running":
                    self.samples.append((t, state["eta_s"], state["solving_s"] or 0.0))
                    self.solving_s = state["solving_s"]
                if self.last_reading_s is None and state["planned_readings"] and \
                        state["done_readings"] >= state["planned_readings"]:
                    self.last_reading_s = t

        threading.Thread(target=watch, name="bench-eta-watch", daemon=True).start()
        return None

    def stop(self) -> None:
        self._stop.set()


def one(name: str, stage_speed: bool) -> dict:
    path = REPO / "procedures" / f"{name}.yaml"
    proc = load_procedure(path)
    scenario, _ = resolve_scenario(path, proc, None)
    walked = walk(METHODS[proc.method].plan(proc, set(), 0, 0.0), Timing.of_scenario(scenario)).duration_s
    speed = {"stage_wall_speed_deg_per_s": scenario.stage.speed_deg_per_s} if stage_speed else {}
    watch = PageWatch()
    with SimulatorHub(scenario, seed=scenario.seed, **speed) as hub, tempfile.TemporaryDirectory() as tmp:
        run_procedure(path, out_dir=Path(tmp) / "run", show_progress=False, addresses=dict(hub.addresses),
                      on_engine=watch)
        assert watch.t0 is not None
        end_s = time.monotonic() - watch.t0
    watch.stop()
    samples = [(t, eta) for t, eta, _ in watch.samples if eta is not None]
    last = watch.last_reading_s  # the measuring alone: the time left less its solving, against the time to the last reading
    measuring = [100 * abs(eta - solving - (last - t)) / (last - t) for t, eta, solving in watch.samples
                 if eta is not None and last is not None and t >= 60 and last - t >= 30]
    errors = {}
    for mark in MARKS_MIN:
        before = [(t, eta) for t, eta in samples if t <= 60 * mark]
        if 60 * mark < end_s and before:
            t, eta = before[-1]
            errors[mark] = 100 * (eta - (end_s - t)) / (end_s - t)
    late = [100 * abs(eta - (end_s - t)) / (end_s - t) for t, eta in samples if t >= 60 and end_s - t >= 30]
    first = samples[0] if samples else (0.0, None)
    return {"name": name, "walked_s": walked, "end_s": end_s, "errors": errors, "worst": max(late, default=None),
            "first": first, "after_s": None if watch.last_reading_s is None else end_s - watch.last_reading_s,
            "solving_s": watch.solving_s, "worst_measuring": max(measuring, default=None)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--procedures", nargs="+", default=list(SHIPPED), choices=SHIPPED)
    ap.add_argument("--stage-speed", action="store_true", help="the drive turns at the bench's speed in wall time")
    args = ap.parse_args()
    print(f"time left on the live page against the real time left (page − real, % of the real), real clock, "
          f"rtcal's simulators{' (drive at the bench speed)' if args.stage_speed else ' (drive moves at once)'}")
    head = " | ".join(f"{m:>3} min" for m in MARKS_MIN)
    print(f"| procedure | walked | real (to results) | before the first reading | {head} | worst from 1 min "
          f"| … to the last reading | after the last reading: real / estimated |")
    print("|---|---|---|---|" + "---|" * len(MARKS_MIN) + "---|---|---|")
    for name in args.procedures:
        r = one(name, args.stage_speed)
        t, eta = r["first"]
        start = "–" if eta is None else f"{eta:.0f} s for {r['end_s'] - t:.0f} s"
        cells = " | ".join(f"{r['errors'][m]:+6.1f} %" if m in r["errors"] else "      " for m in MARKS_MIN)
        worst = "–" if r["worst"] is None else f"{r['worst']:.1f} %"
        after = "–" if r["after_s"] is None else f"{r['after_s']:.0f} s / {r['solving_s'] or 0:.0f} s"
        measuring = "–" if r["worst_measuring"] is None else f"{r['worst_measuring']:.1f} %"
        print(f"| {name} | {r['walked_s']:.0f} s | {r['end_s']:.0f} s | {start} | {cells} | {worst} | {measuring} | {after} |",
              flush=True)


if __name__ == "__main__":
    main()
