"""Interval methods on a synthetic fleet (issue 45 item 2): 200 machine axes × 10 years, each axis with
a known drift per hour of use, its own hours per day and random shocks (a crash, a worn bearing); each
calibration is as found, and an axis found beyond half its limit is compensated (an as-left run) back
to its own baseline. Every method schedules the next calibration through the catalogue's own
`next_due` (rtcal/catalog/intervals.py) from the rows a catalogue would hold.

    PYTHONPATH=$PWD python benchmarks/bench_intervals.py [--axes 200] [--years 10] [--seed 45]

Prints per method the end-of-period in-tolerance reliability (the share of as-found calibrations at
which the axis's true E was within its limit) and the calibrations per axis and year, beside a fixed
365-day interval; and the share of axis-days spent beyond the limit.
"""

from __future__ import annotations

import argparse
import math
import random
import sys
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rtcal.catalog.intervals import AxisPolicy, next_due  # noqa: E402

T0 = datetime(2015, 1, 1, tzinfo=timezone.utc)
LIMIT = 60.0
NOISE = 0.5  # 1σ of a measurement of E, ″ (U = 1″, k = 2)
ADJUST_ABOVE = 0.5  # found beyond this fraction of its limit: compensated back to its baseline


@dataclass
class Axis:
    hours_per_day: float
    drift_per_1000_h: float  # ″ of E per 1000 hours of use
    baseline: float  # E just after a compensation, ″
    shocks: list[tuple[float, float]]  # (day, jump ″)


def fleet(n: int, days: float, rng: random.Random) -> list[Axis]:
    out = []
    for _ in range(n):
        shocks, t = [], 0.0
        while True:
            t += rng.expovariate(0.15 / 365.25)  # one shock in 6.7 years on average
            if t > days:
                break
            shocks.append((t, rng.expovariate(1 / 15.0)))
        out.append(Axis(rng.uniform(2.0, 16.0), math.exp(rng.gauss(math.log(4.0), 0.5)), rng.uniform(15.0, 25.0), shocks))
    return out


def simulate(axis: Axis, policy: AxisPolicy, days: float, rng: random.Random) -> tuple[int, int, float]:
    """(as-found calibrations after the first, of them in tolerance, axis-days beyond the limit)."""
    rows: list[dict[str, Any]] = []
    hours: list[tuple[datetime, float]] = []
    left_at, left_day = axis.baseline, 0.0  # the true E the axis was left at, and when

    def true_e(day: float) -> float:
        jumps = sum(j for s, j in axis.shocks if left_day < s <= day)
        return left_at + axis.drift_per_1000_h * axis.hours_per_day * (day - left_day) / 1000.0 + jumps

    def row(day: float, e: float, state: str) -> dict[str, Any]:
        return {"run_id": f"r{len(rows)}", "measured_utc": (T0 + timedelta(days=day)).isoformat(), "E_arcsec": e,
                "E_U_arcsec": 2 * NOISE, "E_limit_arcsec": LIMIT, "state": state, "verdict": "pass" if e <= LIMIT else "fail",
                **{f"{p}_{k}arcsec": None for p in "MBRA" for k in ("", "U_", "limit_")}}

    day, found, in_tol, beyond = 0.0, 0, 0, 0.0
    while day <= days:
        truth = true_e(day)
        if day > 0:
            found += 1
            in_tol += truth <= LIMIT
        measured = truth + rng.gauss(0.0, NOISE)
        rows.append(row(day, measured, "as_found"))
        hours.append((T0 + timedelta(days=day), axis.hours_per_day * day))
        if measured > ADJUST_ABOVE * LIMIT:
            left_at, left_day = axis.baseline + rng.gauss(0.0, 1.0), day
            rows.append(row(day + 0.5, left_at + rng.gauss(0.0, NOISE), "as_left"))
        due = next_due(rows, policy, hours)["due"]
        nxt = (datetime.fromisoformat(due).replace(tzinfo=timezone.utc) - T0).total_seconds() / 86400
        nxt = max(nxt, day + 1.0)
        # days beyond the limit in this period (checked daily)
        beyond += sum(1 for d in range(int(day) + 1, int(min(nxt, days)) + 1) if true_e(d) > LIMIT)
        day = nxt
    return found, in_tol, beyond


POLICIES = {
    "fixed 365 d": AxisPolicy(method="fixed", interval_days=365, trend_guard=False),
    "fixed 365 d, sooner on E's trend (rtcal's default)": AxisPolicy(method="fixed", interval_days=365),
    "G24 method 1, staircase": AxisPolicy(method="staircase", interval_days=365, min_days=90, max_days=730),
    "G24 method 2, control chart": AxisPolicy(method="control_chart", parameters=["E"], interval_days=365, min_days=90,
                                              max_days=730),
    "G24 method 3, in-use 3300 h": AxisPolicy(method="in_use", interval_hours=3300, interval_days=365, min_days=90,
                                              max_days=730),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--axes", type=int, default=200)
    ap.add_argument("--years", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=45)
    args = ap.parse_args()
    days = args.years * 365.25
    axes = fleet(args.axes, days, random.Random(args.seed))
    print(f"{args.axes} axes × {args.years:g} years; drift {min(a.drift_per_1000_h for a in axes):.1f}…"
          f"{max(a.drift_per_1000_h for a in axes):.1f}″ per 1000 h at 2…16 h/day; {sum(len(a.shocks) for a in axes)} "
          f"shocks; limit {LIMIT:g}″; compensated when found beyond {ADJUST_ABOVE:.0%} of it")
    print(f"{'method':52} {'reliability':>11} {'calibrations/axis·year':>23} {'axis-days beyond':>17}")
    for name, policy in POLICIES.items():
        rng = random.Random(args.seed + 1)  # the same measurement noise for every method
        found = in_tol = 0
        beyond = 0.0
        for axis in axes:
            f, i, b = simulate(axis, policy, days, rng)
            found, in_tol, beyond = found + f, in_tol + i, beyond + b
        print(f"{name:52} {100 * in_tol / found:10.1f}% {(found + len(axes)) / (len(axes) * args.years):23.2f} "
              f"{100 * beyond / (len(axes) * days):16.2f}%")


if __name__ == "__main__":
    main()
