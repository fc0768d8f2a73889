"""How long the operator's control requests take to be answered while someone on the computer
attacks the live page's server (issue 40, item 4).

    python benchmarks/bench_live_abort.py [--counts 64 256 1000] [--repeat 5] [--flood-s 5]

A real `rtcal run --live` (the ISO 230-2 procedure on the simulated bench, in real time, paused
through its control socket so it lasts) is attacked from this process by N connections of each
kind (one byte each; event streams never read; POST bodies dribbled a byte a second), then a flood
that reopens at once every connection the server closes, then all three kinds at once. Under each,
POST api/pause with the token is timed ``--repeat`` times (the run stays paused); the run is
aborted last, under the three kinds at once. Under the flood, each pause is timed as sent
once, then as the page sends it (up to five tries 0.25 s apart when no answer comes). Prints the median and worst answer time and how many
requests got no answer.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rtcal.live.control import send_control  # noqa: E402
from tests import hostile_http  # noqa: E402
from tests.test_live_end import short_iso, start_live_run, state  # noqa: E402


def _time(url: str, token: str, repeat: int, tries: int = 1) -> tuple[list[float], list[str]]:
    """``repeat`` pauses of the paused run (each answered 202, nothing changes): their times, and
    what came instead of an answer (``tries``: as the page, sent again after no answer)."""
    times, failed = [], []
    for _ in range(repeat):
        status, seconds = hostile_http.timed_post(url, "pause", token, tries=tries)
        if status == 202:
            times.append(seconds)
        else:
            failed.append(str(status))
    return times, failed


def _line(label: str, times: list[float], failed: list[str]) -> None:
    shown = (f"median {statistics.median(times) * 1000:7.1f} ms, worst {max(times) * 1000:7.1f} ms"
             if times else "no answer")
    why = f" ({', '.join(sorted(set(failed)))})" if failed else ""
    print(f"{label:52} {shown}; {len(times)} answered, {len(failed)} not{why}", flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", type=int, nargs="+", default=[64, 256, 1000])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--flood-s", type=float, default=5.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = Path(tmp) / "run"
        proc, url, token = start_live_run(short_iso(Path(tmp), runs=5), run_dir)
        try:
            send_control(run_dir, token, "pause")
            host, port = url.removeprefix("http://").rstrip("/").rsplit(":", 1)
            _line("no attack", *_time(url, token, args.repeat))
            for n in args.counts:
                for kind in ("one_byte", "streams", "slow_bodies"):
                    attack = getattr(hostile_http, kind)(host, int(port), n)
                    time.sleep(1.0)
                    try:
                        _line(f"{n} {kind.replace('_', '-')} connections ({attack.still_open()} held)",
                              *_time(url, token, args.repeat))
                    finally:
                        attack.close()
            for threads in (2, 8):
                for tries in (1, 5):
                    attack = hostile_http.flood(host, int(port), hold=200, threads=threads)
                    try:
                        time.sleep(1.0)
                        t0, times, failed = time.monotonic(), [], []
                        while time.monotonic() - t0 < args.flood_s:
                            got, lost = _time(url, token, 1, tries)
                            times += got
                            failed += lost
                        opened = attack.opened  # type: ignore[attr-defined]
                        _line(f"flood, {threads} threads, {opened} opened; {tries} {'try' if tries == 1 else 'tries'}",
                              times, failed)
                    finally:
                        attack.close()
            n = max(args.counts)
            attacks = [hostile_http.streams(host, int(port), n), hostile_http.one_byte(host, int(port), n),
                       hostile_http.slow_bodies(host, int(port), n)]
            try:
                time.sleep(1.5)
                _line(f"{3 * n} connections of the three kinds", *_time(url, token, args.repeat))
                status, seconds = hostile_http.timed_post(url, "abort", token)
                print(f"{'abort, ' + str(3 * n) + ' connections of the three kinds':52} {status} in "
                      f"{seconds * 1000:.1f} ms", flush=True)
            finally:
                for a in attacks:
                    a.close()
            proc.wait(120)
            print(f"the run ended with exit {proc.returncode} ({state(url)['state'] if proc.poll() is None else 'gone'})")
        finally:
            if proc.poll() is None:
                proc.kill()
    return 0


if __name__ == "__main__":
    sys.exit(main())
