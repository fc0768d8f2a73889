"""The time left, as the log and the live page say it: one estimate (the walk of what remains, each
operator step at its stated duration), true within ±25 % at a quarter of the run and after a resume,
on the virtual clock where it is deterministic."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from rtcal.engine.engine import AbortRequested
from rtcal.live.storeview import StoreView
from rtcal.methods import read_results
from rtcal.run.runner import resume_run, run_procedure

REPO = Path(__file__).resolve().parents[1]
ISO = REPO / "procedures" / "iso230_2_polygon.yaml"
LOGGED = re.compile(r"readings (\d+)/(\d+) .* about (?:(\d+):)?(\d+):(\d+) left")


def reseated_iso(tmp_path: Path) -> Path:
    """ISO 230-2 on 24 targets, the polygon seated twice (a stated 60 s re-seat between)."""
    data = yaml.safe_load(ISO.read_text(encoding="utf-8"))
    (tmp_path / "bench.yaml").write_bytes((ISO.parent / data["bench"]).read_bytes())
    data["bench"] = "bench.yaml"
    data["steps"]["targets_deg"] = [15 * k for k in range(24)]
    data["steps"]["runs"] = 2
    data["polygon"]["seatings_deg"] = [0, 7.5]
    path = tmp_path / "iso24.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


class Watch:
    """``on_engine``: at every planned reading done, the run's clock and the page's time left (read
    from the store as the live view reads it); ``abort_at`` done readings, a remote abort."""

    def __init__(self, abort_at: int | None = None):
        self.seen: dict[int, tuple[float, float | None]] = {}
        self.abort_at = abort_at

    def __call__(self, engine: Any, run_dir: Path):
        def on(name: str, doc: dict[str, Any]) -> None:
            if name == "done":
                self.seen[doc["done"]] = (doc["t_s"], StoreView(run_dir, 0.0).state()["eta_s"])
                if self.abort_at is not None and doc["done"] >= self.abort_at:
                    engine.request_abort()
        engine.subscribers.append(on)
        return None


def logged(err: str) -> dict[int, float]:
    """done → the time left the log printed with it."""
    return {int(m[1]): 3600 * int(m[3] or 0) + 60 * int(m[4]) + int(m[5]) for m in LOGGED.finditer(err)}


def check(watch: Watch, log: dict[int, float], end_s: float, at_done: int) -> None:
    t_s, page = watch.seen[at_done]
    actual = end_s - t_s
    assert page is not None and abs(page - actual) <= 0.25 * actual, (page, actual)
    assert abs(log[at_done] - page) <= max(0.03 * page, 1.0), (log[at_done], page)


def test_the_time_left_counts_the_stated_reseat_and_is_true_at_a_quarter(tmp_path, capsys):
    watch = Watch()
    run_procedure(reseated_iso(tmp_path), out_dir=tmp_path / "run", show_progress=True, on_engine=watch)
    end_s = read_results(tmp_path / "run").measurement_duration_s
    log = logged(capsys.readouterr().err)
    planned = max(watch.seen)
    quarter = min(k for k in log if k >= planned // 4)
    check(watch, log, end_s, quarter)


def test_after_a_resume_the_time_left_is_that_of_the_remaining_steps(tmp_path, capsys):
    procedure = reseated_iso(tmp_path)
    with pytest.raises(AbortRequested):
        run_procedure(procedure, out_dir=tmp_path / "run", show_progress=True, on_engine=Watch(abort_at=60))
    capsys.readouterr()
    watch = Watch()
    resume_run(tmp_path / "run", show_progress=True, on_engine=watch)
    end_s = read_results(tmp_path / "run").measurement_duration_s
    log = logged(capsys.readouterr().err)
    first = min(k for k in log if k in watch.seen)
    check(watch, log, end_s, first)


class _CountingWalk(dict):
    """A plan walk's entry times that count how often an entry is looked up."""

    lookups = 0

    def __getitem__(self, key: Any) -> Any:
        type(self).lookups += 1
        return super().__getitem__(key)


def test_the_time_left_keeps_running_totals_not_a_sum_over_the_plan_per_document():
    """Issue 43: at every document the time left summed every pending entry (quadratic in the plan: 2.8 million
    steps for 2 376 readings). It is now a running total: each done entry is looked up once, and the time left
    equals the sum over what is still pending."""
    from rtcal.engine.subscribers import Eta

    entries = _CountingWalk({k: (10.0 + k % 7, 2.0 if k % 50 == 0 else 0.0) for k in range(5000)})
    eta = Eta(entries, virtual_clock=True)
    eta("start", {"t_s": 0.0})
    for k in range(2500):
        eta("done", {"index": k, "t_s": 12.0 * (k + 1)})
        eta.eta_s()
    assert _CountingWalk.lookups <= 2500  # one per entry done; none for the 2 500 calls of the time left
    pending = [entries.get(k) for k in range(2500, 5000)]
    pace = min(max(eta.machine_s / eta.walked_s, 0.2), 5.0)
    assert eta.eta_s() == pytest.approx(pace * sum(t - o for t, o in pending) + sum(o for _, o in pending), rel=1e-12)
