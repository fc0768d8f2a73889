"""Calibration intervals an assessor accepts: ILAC-G24:2022 / OIML D 10:2022's methods, chosen per
machine axis in the catalogue's policy file, each due date given with its method and the data it
rests on (docs/catalog.md, "Intervals"; the methods' sources in /work/shared/reference and README).

- ``fixed``: a fixed interval (``interval_days``), brought forward to the date E's trend reaches its
  limit when that comes sooner (``trend_guard``, rtcal's behaviour before policies).
- ``staircase`` (G24 method 1, "automatic adjustment"): at each calibration the next interval is
  extended (× ``extend_factor``) when the as-found E lies within ``extend_below`` of its limit,
  shortened (× ``shorten_factor``) when it lies beyond the limit, kept otherwise; bounded by
  ``min_days`` … ``max_days``.
- ``control_chart`` (G24 method 2): per charted parameter (E, M, B, R, A with a limit) the drift of
  each period — the as-found value minus the value the item was left at the calibration before
  (its as-left run, else that as-found) over the days between — fitted as one rate (weights from
  the runs' U); the next due date is where the value the item was left at, plus that drift, plus
  ``coverage_k`` times its standard uncertainty (the runs' u, the rate's u over the time ahead),
  reaches the limit: the earliest over the parameters, bounded by ``min_days`` … ``max_days``.
- ``in_use`` (G24 method 3): ``interval_hours`` of the machine's use, from its hours
  (``rtcal catalog hours``: given, or read from its OPC UA server); the date is where the hours
  since the calibration reach it at the rate the readings show, at most ``max_days``.

An axis is judged by its as-found runs: a run declared as found, or saying nothing and not the
second of a pair (rtcal/catalog/history.py); an entry a later one supersedes counts as that one."""

from __future__ import annotations

import math
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from rtcal.catalog.history import current, pair_info, time_of, trend
from rtcal.catalog.schema import normal_text

Method = Literal["fixed", "staircase", "control_chart", "in_use"]
NAMES = {"fixed": "fixed interval", "staircase": "ILAC-G24 method 1 (staircase)",
         "control_chart": "ILAC-G24 method 2 (control chart, drift regression)",
         "in_use": "ILAC-G24 method 3 (in-use time)"}
DAY = timedelta(days=1)


class AxisPolicy(BaseModel):
    """How one machine axis's next due date is found (see the module's docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    serial_number: str = Field("", max_length=100, description="the machine (empty: the default policy)")
    axis: str = Field("", max_length=50, description="one axis (empty: every axis of the machine)")
    method: Method = Field("fixed", description="fixed, staircase (G24 method 1), control_chart (2) or in_use (3)")
    interval_days: float = Field(365.0, gt=0.0, le=3650.0, description="fixed: the interval; staircase and "
                                 "control_chart: the first interval, before the data say more, days")
    trend_guard: bool = Field(True, description="fixed: due sooner when E's trend reaches its limit sooner")
    extend_below: float = Field(0.8, gt=0.0, lt=1.0, description="staircase: extend when as-found E ≤ this fraction of its limit")
    extend_factor: float = Field(1.25, gt=1.0, le=4.0, description="staircase: the interval × this when extended")
    shorten_factor: float = Field(0.5, gt=0.0, lt=1.0, description="staircase: the interval × this when as found beyond the limit")
    min_days: float = Field(30.0, gt=0.0, le=3650.0, description="the shortest interval, days")
    max_days: float = Field(730.0, gt=0.0, le=3650.0, description="the longest interval, days")
    parameters: list[Literal["E", "M", "B", "R", "A"]] = Field(["E", "M", "B", "R", "A"], min_length=1,
                                                               description="control_chart: the parameters charted")
    coverage_k: float = Field(2.0, ge=0.0, le=5.0, description="control_chart: the predicted value plus k·u reaches the limit")
    interval_hours: float = Field(2000.0, gt=0.0, le=1e6, description="in_use: hours of use between calibrations")

    _names = field_validator("serial_number", "axis")(lambda cls, text: normal_text(text))

    @model_validator(mode="after")
    def _bounds(self) -> AxisPolicy:
        if self.min_days > self.max_days:
            raise ValueError(f"min_days {self.min_days:g} is more than max_days {self.max_days:g}")
        return self


class Policy(BaseModel):
    """The catalogue's interval policy: a default and the machine axes that differ."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    default: AxisPolicy = Field(AxisPolicy(), description="every machine axis `axes` does not name")
    axes: list[AxisPolicy] = Field([], max_length=100_000, description="per machine (and axis) its own policy")

    @model_validator(mode="after")
    def _named(self) -> Policy:
        seen = set()
        for k, p in enumerate(self.axes):
            if not p.serial_number:
                raise ValueError(f"axes.{k}: give the machine's serial_number (the default is `default:`)")
            if (p.serial_number, p.axis) in seen:
                raise ValueError(f"axes.{k}: {p.serial_number} {p.axis or '(every axis)'} is named twice")
            seen.add((p.serial_number, p.axis))
        return self

    def of(self, serial: str, axis: str) -> AxisPolicy:
        """The axis's own policy, else its machine's, else the default."""
        serial, axis = normal_text(serial), normal_text(axis)
        return next((p for p in self.axes if p.serial_number == serial and p.axis == axis),
                    next((p for p in self.axes if p.serial_number == serial and not p.axis), self.default))


DEFAULT = Policy()


def load_policy(path: Path) -> str:
    """A policy file's text, once it validates (FileProblems: located lines naming each key)."""
    from rtcal.procedure.yamlfile import read_text, validate_text

    text = read_text(path)
    validate_text(text, Policy, str(path))
    return text


def _finite(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) else None


def as_found(rows: list[dict[str, Any]]) -> list[tuple[datetime, dict[str, Any], dict[str, Any] | None]]:
    """(time, the as-found run, the run the item was left at before it — the previous pair's as-left, else the
    previous as-found; None for the first) of an axis's current entries, oldest first."""
    rows = current(rows)
    left_of = {p.found: p.left for p in pair_info(rows)}
    second = set(left_of.values())
    out: list[tuple[datetime, dict[str, Any], dict[str, Any] | None]] = []
    before: dict[str, Any] | None = None
    for k, r in enumerate(rows):
        t = time_of(r)
        if t is None or k in second:
            continue
        out.append((t, r, before))
        before = rows[left_of[k]] if k in left_of else r
    return out


def _day(t: datetime) -> str:
    return t.date().isoformat()


def _bounded(last: datetime, days: float, p: AxisPolicy) -> tuple[datetime, str]:
    clipped = min(max(days, p.min_days), p.max_days)
    note = "" if clipped == days else f" (bounded to {clipped:.0f} d: min_days {p.min_days:g}, max_days {p.max_days:g})"
    return last + timedelta(days=clipped), note


def _fixed(rows: list[dict[str, Any]], last: datetime, p: AxisPolicy) -> dict[str, Any]:
    due = last + timedelta(days=p.interval_days)
    data = f"last calibration {_day(last)} + {p.interval_days:g} d"
    if p.trend_guard:
        t = trend(current(rows))
        reach = t["E_reaches_limit_utc"]
        if reach is not None and (when := datetime.fromisoformat(reach)) < due:
            due = max(when, last)
            data += f"; sooner: E's trend {t['E_trend_arcsec_per_year']:+.3f}″/year reaches its limit {t['E_limit_arcsec']:g}″ " \
                    f"on {reach[:10]}"
    return {"due": _day(due), "data": data}


def _staircase(rows: list[dict[str, Any]], last: datetime, p: AxisPolicy) -> dict[str, Any]:
    interval, steps = p.interval_days, []
    for t, r, _ in as_found(rows):
        e, limit = _finite(r.get("E_arcsec")), _finite(r.get("E_limit_arcsec"))
        if e is None or limit is None or limit <= 0:
            steps.append(f"{_day(t)}: as found, no E against a limit: interval kept at {interval:.0f} d")
            continue
        ratio = abs(e) / limit
        before = interval
        if ratio > 1.0:
            interval, why = max(interval * p.shorten_factor, p.min_days), f"beyond its limit: × {p.shorten_factor:g}"
        elif ratio <= p.extend_below:
            interval, why = min(interval * p.extend_factor, p.max_days), \
                f"≤ {p.extend_below:.0%} of its limit: × {p.extend_factor:g}"
        else:
            why = f"between {p.extend_below:.0%} and 100 % of its limit: kept"
        steps.append(f"{_day(t)}: as found E {e:.2f}″ of its limit {limit:g}″ ({ratio:.0%}, {why}): "
                     f"{before:.0f} d → {interval:.0f} d")
    due = last + timedelta(days=interval)
    data = (f"last calibration {_day(last)} + {interval:.0f} d; " + (steps[-1] if steps else
            f"no as-found E yet: the first interval {p.interval_days:g} d"))
    return {"due": _day(due), "data": data, "interval_days": round(interval, 1), "steps": steps}


def drift(points: list[tuple[float, float, float, float]]) -> tuple[float, float] | None:
    """The drift rate per day and its standard uncertainty from periods (days, change, u of the change,
    u of the value left at), weighted by 1/u² of each period's rate; the rate's u is the larger of its
    stated one and the scatter between periods (Birge). None: no period."""
    use = [(d, c, u) for d, c, u, _ in points if d > 0 and u > 0]
    if not use:
        return None
    w = [(d / u) ** 2 for d, _, u in use]
    rates = [c / d for d, c, _ in use]
    sw = sum(w)
    rate = sum(wi * ri for wi, ri in zip(w, rates)) / sw
    u_rate = math.sqrt(1 / sw)
    if len(use) > 1:
        chi2 = sum(wi * (ri - rate) ** 2 for wi, ri in zip(w, rates)) / (len(use) - 1)
        u_rate *= max(1.0, math.sqrt(chi2))
    return rate, u_rate


def _chart(rows: list[dict[str, Any]], last: datetime, p: AxisPolicy) -> dict[str, Any]:
    found = as_found(rows)
    best: tuple[float, str] | None = None
    charts: dict[str, Any] = {}
    for name in p.parameters:
        pts, periods = [], []
        for t, r, before in found:
            v, u = _finite(r.get(f"{name}_arcsec")), _finite(r.get(f"{name}_U_arcsec"))
            if v is None:
                continue
            pts.append({"measured_utc": t.isoformat(), "value_arcsec": v, "U_arcsec": u})
            bt = time_of(before) if before else None
            bv = _finite(before.get(f"{name}_arcsec")) if before else None
            bu = _finite(before.get(f"{name}_U_arcsec")) if before else None
            if bt is not None and bv is not None:
                periods.append(((t - bt).total_seconds() / 86400, v - bv,
                                math.hypot((u or 0) / 2, (bu or 0) / 2) or 1e-3, (bu or 0) / 2))
        limit = next((lv for _, r, _ in reversed(found) if (lv := _finite(r.get(f"{name}_limit_arcsec"))) is not None), None)
        chart: dict[str, Any] = {"points": pts, "limit_arcsec": limit, "periods": len(periods)}
        charts[name] = chart
        fit = drift(periods)
        if limit is None or fit is None or not pts:
            continue
        rate, u_rate = fit
        chart.update(drift_arcsec_per_year=round(rate * 365.25, 4), drift_u_arcsec_per_year=round(u_rate * 365.25, 4))
        left = _left_now(rows) or found[-1][1]
        start_t, start = time_of(left), _finite(left.get(f"{name}_arcsec"))
        start_u = (_finite(left.get(f"{name}_U_arcsec")) or 0) / 2
        if start is None or start_t is None:
            continue
        u_meas = (_finite(pts[-1]["U_arcsec"]) or 0.0) / 2
        days = _reaches(start, start_u, u_meas, rate, u_rate, limit, p.coverage_k, p.max_days + 1)
        chart["reaches_limit_days"] = None if days is None else round(days, 1)
        if days is not None:
            days += (start_t - last).total_seconds() / 86400
            words = (f"{name}: left at {start:.2f}″ on {_day(start_t)}, drift {rate * 365.25:+.3f} ± {u_rate * 365.25:.3f}″/year "
                     f"over {len(periods)} period{'s' if len(periods) != 1 else ''}: {start:.2f}″ + drift + "
                     f"{p.coverage_k:g}·u reaches its limit {limit:g}″ after {days:.0f} d")
            if best is None or days < best[0]:
                best = (days, words)
    if best is None:
        fallback = p.interval_days if not any(c["periods"] for c in charts.values()) else p.max_days
        due, note = _bounded(last, fallback, p)
        why = ("no period yet (an as-found run after one before it): the first interval" if fallback == p.interval_days
               else "no charted parameter reaches its limit within max_days")
        return {"due": _day(due), "data": f"last calibration {_day(last)} + {fallback:g} d: {why}{note}", "charts": charts}
    due, note = _bounded(last, best[0], p)
    return {"due": _day(due), "data": f"last calibration {_day(last)}; {best[1]}{note}", "charts": charts}


def _left_now(rows: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The run that shows the state the item was last left in (the newest current entry)."""
    dated = [r for r in current(rows) if time_of(r) is not None]
    return dated[-1] if dated else None


def _reaches(start: float, u_start: float, u_meas: float, rate: float, u_rate: float, limit: float, k: float,
             horizon_days: float) -> float | None:
    """Days until start + rate·t + k·sqrt(u_start² + u_meas² + (u_rate·t)²) first reaches the limit (None: not within the horizon)."""
    def upper(t: float) -> float:
        return start + rate * t + k * math.sqrt(u_start ** 2 + u_meas ** 2 + (u_rate * t) ** 2)

    if upper(0.0) >= limit:
        return 0.0
    if upper(horizon_days) < limit:
        return None
    lo, hi = 0.0, horizon_days
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if upper(mid) < limit else (lo, mid)
    return hi


def _in_use(rows: list[dict[str, Any]], last: datetime, p: AxisPolicy, hours: list[tuple[datetime, float]]) -> dict[str, Any]:
    readings = sorted((t, h) for t, h in hours if math.isfinite(h))
    if len(readings) < 2:
        due, note = _bounded(last, p.interval_days, p)
        return {"due": _day(due), "data": f"last calibration {_day(last)} + {p.interval_days:g} d: the machine's hours are "
                                           f"not known at two times (`rtcal catalog hours`){note}"}
    (t0, h0), (t1, h1) = readings[0], readings[-1]
    span_days = (t1 - t0).total_seconds() / 86400
    rate = (h1 - h0) / span_days if span_days > 0 else 0.0
    at_cal = _hours_at(readings, last)
    used = h1 - at_cal
    if rate <= 0:
        due, note = _bounded(last, p.max_days, p)
        return {"due": _day(due), "data": f"last calibration {_day(last)}: the machine's hours did not rise "
                                           f"({h0:g} h on {_day(t0)}, {h1:g} h on {_day(t1)}): max_days{note}"}
    days = (t1 - last).total_seconds() / 86400 + (p.interval_hours - used) / rate
    due, note = _bounded(last, days, p)
    return {"due": _day(due), "data": f"last calibration {_day(last)} at {at_cal:.0f} h; {used:.0f} h used by {_day(t1)} "
                                       f"({h1:g} h), {rate:.1f} h/day since {_day(t0)}: {p.interval_hours:g} h reached after "
                                       f"{days:.0f} d{note}",
            "hours_per_day": round(rate, 3)}


def _hours_at(readings: list[tuple[datetime, float]], when: datetime) -> float:
    """The machine's hours at ``when``, interpolated (or extrapolated at the ends) between readings."""
    before = [r for r in readings if r[0] <= when]
    after = [r for r in readings if r[0] >= when]
    if not before:  # before the first reading: the line through the first two
        (ta, ha), (tb, hb) = readings[0], readings[1]
    elif not after:  # after the last: through the last two
        (ta, ha), (tb, hb) = readings[-2], readings[-1]
    else:
        (ta, ha), (tb, hb) = before[-1], after[0]
    if tb == ta:
        return ha
    return ha + (hb - ha) * (when - ta).total_seconds() / (tb - ta).total_seconds()


def next_due(rows: list[dict[str, Any]], policy: AxisPolicy, hours: list[tuple[datetime, float]] | None = None,
             retired: dict[str, Any] | None = None) -> dict[str, Any]:
    """An axis's next due date with its method and the data it rests on: {"due": YYYY-MM-DD or None,
    "method": words, "data": words, …} (rows of one axis, oldest first)."""
    name = NAMES[policy.method]
    if retired is not None:
        return {"due": None, "method": name, "data": f"retired on {str(retired['at_utc'])[:10]}: {retired['reason']}",
                "retired": True}
    last = max((t for r in rows if (t := time_of(r)) is not None), default=None)
    if last is None:
        return {"due": None, "method": name, "data": "no entry has a time rtcal can read"}
    if policy.method == "staircase":
        found = _staircase(rows, last, policy)
    elif policy.method == "control_chart":
        found = _chart(rows, last, policy)
    elif policy.method == "in_use":
        found = _in_use(rows, last, policy, hours or [])
    else:
        found = _fixed(rows, last, policy)
    return {"method": name, **found}


def overdue_words(due: str | None, today: datetime | None = None) -> str:
    """"overdue since …", "due in N days" or "" (no date)."""
    if not due:
        return ""
    today = today or datetime.now(timezone.utc)
    days = (datetime.fromisoformat(due).replace(tzinfo=timezone.utc) - today.replace(hour=0, minute=0, second=0,
                                                                                    microsecond=0)).days
    return f"overdue since {due}" if days < 0 else ("due today" if days == 0 else f"due in {days} d")

