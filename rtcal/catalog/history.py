"""A machine axis's history: as-found / as-left pairs, E's trend per year and the date it reaches
its limit, the next due date.

Pairs: two calibrations of one axis within :data:`PAIR_WINDOW_DAYS` of each other are an adjustment
(compensation) between them: the first is as found, the second as left.

Trend: a weighted least-squares line E(t) = a + b·t through the runs that show the machine as it
drifted (every run except the as-left of a pair: an as-left run is the state a compensation has
just made, not drift), each weighted by 1/u² with u = U/2 (U: E's expanded uncertainty, k = 2).
b is E's trend per year; its U is 2·√Var(b) from the fit's covariance (the runs' own u, not the
scatter). The predicted date is where the line reaches E's acceptance limit (the latest run's),
given only when b > 0 and at least two runs at different times enter the fit, and only within
:data:`HORIZON_YEARS` of the first run fitted: a flat or barely rising line (three equal E, or
20.0″ then 20.0001″ a year later) reaches it "beyond 100 years", not at a date no calendar holds.

An entry whose time cannot be read (a catalogue from before entries were checked at add) is
listed but left out of pairs, trend and due date: one odd entry never breaks a list."""

from __future__ import annotations

import math
from datetime import datetime, timedelta, timezone
from typing import Any

from rtcal.catalog.schema import PARAMETERS, normal_text
from rtcal.deliverables.rounding import u_text, value_text

PAIR_WINDOW_DAYS = 14.0
INTERVAL_DAYS = 365.0  # the recalibration interval when the trend says nothing sooner
YEAR_DAYS = 365.25
HORIZON_YEARS = 100.0  # a limit date further than this from the first run fitted is not given
BEYOND = f"beyond {HORIZON_YEARS:g} years"
METHOD = ("weighted linear fit of E over time (weights 1/u², u = U/2) through every run except the as-left run of an "
          f"as-found/as-left pair (two runs within {PAIR_WINDOW_DAYS:g} days: the second follows a compensation and "
          "shows no drift); U of the trend 2·sqrt(Var(b)); limit date where the line reaches E's limit")


def e_text(row: dict[str, Any]) -> str:
    """E ± U as the certificate states them (U rounded up to two digits, E to its place): one
    string for the console and the page."""
    if row.get("E_arcsec") is None:
        return "–"
    return f"{value_text(row['E_arcsec'], row.get('E_U_arcsec'))} ± {u_text(row.get('E_U_arcsec'))}"


def _time(text: str) -> datetime:
    t = datetime.fromisoformat(text)
    return t if t.tzinfo else t.replace(tzinfo=timezone.utc)


def time_of(row: dict[str, Any]) -> datetime | None:
    """An entry's measured time, or None when it cannot be read (or lies where arithmetic on it
    would leave the calendar)."""
    try:
        t = _time(str(row.get("measured_utc") or ""))
    except (ValueError, TypeError):
        return None
    return t if 1900 <= t.year <= 2900 else None


def _finite(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def entry_json(row: dict[str, Any]) -> dict[str, Any]:
    """One entry as ``history --json`` prints it."""
    out = {k: row[k] for k in ("run_id", "serial_number", "axis", "machine", "customer", "measured_utc", "finished_utc",
                               "method", "certificate_number", "verdict", "run_dir")}
    for p in PARAMETERS:
        out[f"{p}_arcsec"] = row[f"{p}_arcsec"]
        out[f"{p}_U_arcsec"] = row[f"{p}_U_arcsec"]
        out[f"{p}_limit_arcsec"] = row[f"{p}_limit_arcsec"]
    for key in ("Pa", "P", "Ps_max", "U_max"):
        out[f"vdi_{key}_arcsec"] = row[f"vdi_{key}_arcsec"]
    import json
    out["location_errors"] = json.loads(row["location_errors"])
    out["digests"] = json.loads(row["digests"])
    return out


def pairs(rows: list[dict[str, Any]]) -> list[tuple[int, int]]:
    """(as-found index, as-left index) of each pair, rows of one axis oldest first (an entry whose
    time cannot be read is in none)."""
    out: list[tuple[int, int]] = []
    i = 0
    while i + 1 < len(rows):
        first, second = time_of(rows[i]), time_of(rows[i + 1])
        if first is not None and second is not None and second - first <= timedelta(days=PAIR_WINDOW_DAYS):
            out.append((i, i + 1))
            i += 2
        else:
            i += 1
    return out


def trend(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """E's trend per year with its U and the date E reaches its limit (see the module's docstring).
    ``E_reaches_limit`` says it in words: the date, "beyond 100 years", or why there is none."""
    as_left = {j for _, j in pairs(rows)}
    used = [(t, e, u) for k, r in enumerate(rows) if k not in as_left
            for t, e, u in [(time_of(r), _finite(r["E_arcsec"]), _finite(r["E_U_arcsec"]))]
            if t is not None and e is not None and u is not None and u > 0]
    limit = next((v for r in reversed(rows) if (v := _finite(r["E_limit_arcsec"])) is not None), None)
    out: dict[str, Any] = {"method": METHOD, "runs_fitted": len(used), "E_trend_arcsec_per_year": None,
                           "E_trend_U_arcsec_per_year": None, "E_limit_arcsec": limit, "E_reaches_limit_utc": None,
                           "E_reaches_limit": "no trend: it needs two runs at different times (as-left runs apart)"}
    if len(used) < 2:
        return out
    t0 = used[0][0]
    x = [(t - t0).total_seconds() / 86400 / YEAR_DAYS for t, _, _ in used]
    y = [e for _, e, _ in used]
    w = [1 / (u / 2) ** 2 for _, _, u in used]
    s, sx, sy = sum(w), sum(wi * xi for wi, xi in zip(w, x)), sum(wi * yi for wi, yi in zip(w, y))
    sxx, sxy = sum(wi * xi * xi for wi, xi in zip(w, x)), sum(wi * xi * yi for wi, xi, yi in zip(w, x, y))
    det = s * sxx - sx * sx
    if not det > 0 or not math.isfinite(det) or max(x) - min(x) < 1e-6:
        return out
    b = (s * sxy - sx * sy) / det
    a = (sxx * sy - sx * sxy) / det
    if not (math.isfinite(a) and math.isfinite(b)):
        return out
    out["E_trend_arcsec_per_year"] = round(b, 4)
    out["E_trend_U_arcsec_per_year"] = round(2 * math.sqrt(s / det), 4)
    if limit is None:
        out["E_reaches_limit"] = "no limit for E"
    elif b > 0 and (years := (limit - a) / b) > HORIZON_YEARS:
        out["E_reaches_limit"] = BEYOND
    elif b > 0 and years >= -HORIZON_YEARS:  # (a line already over the limit at its first run: a date before it)
        out["E_reaches_limit_utc"] = (t0 + timedelta(days=years * YEAR_DAYS)).isoformat()
        out["E_reaches_limit"] = out["E_reaches_limit_utc"][:10]
    elif a + b * max(x) >= limit:  # flat, falling or barely rising, yet over the limit at the last run fitted
        out["E_reaches_limit_utc"] = t0.isoformat()
        out["E_reaches_limit"] = f"{out['E_reaches_limit_utc'][:10]} (over its limit from the first run fitted)"
    else:
        out["E_reaches_limit"] = "not on this trend (E does not rise)"
    return out


def next_due(rows: list[dict[str, Any]]) -> str | None:
    """The last calibration plus the interval, or sooner when the trend reaches the limit sooner
    (at the last calibration when the trend had reached it before); None when no entry's time
    can be read."""
    last = max((t for r in rows if (t := time_of(r)) is not None), default=None)
    if last is None:
        return None
    due = last + timedelta(days=INTERVAL_DAYS)
    reach = trend(rows)["E_reaches_limit_utc"]
    if reach is not None and _time(reach) < due:
        due = max(_time(reach), last)  # a limit the trend passed before the last calibration: due now
    return due.date().isoformat()


def history_document(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per axis: its entries, pairs and trend (rows oldest first, possibly of several axes)."""
    out: dict[str, Any] = {}
    for axis, rs in by_axis(rows).items():
        out[axis] = {
            "pairs": [{"as_found": rs[i]["run_id"], "as_left": rs[j]["run_id"],
                       "E_change_arcsec": None if rs[i]["E_arcsec"] is None or rs[j]["E_arcsec"] is None
                       else round(rs[j]["E_arcsec"] - rs[i]["E_arcsec"], 4)} for i, j in pairs(rs)],
            "trend": trend(rs), "next_due": next_due(rs)}
    return out


def oldest_first(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Entries by their measured time (those whose time cannot be read first, so the last is the
    newest that can)."""
    return sorted(rows, key=lambda r: (time_of(r) is not None, time_of(r) or datetime.min.replace(tzinfo=timezone.utc),
                                       str(r.get("measured_utc"))))


def by_axis(rows: list[dict[str, Any]], serial: bool = False) -> dict[Any, list[dict[str, Any]]]:
    """Entries per axis (per machine axis: ``serial``), names as the catalogue keeps them
    (:func:`~rtcal.catalog.schema.normal_text`, whatever an older entry holds), oldest first."""
    groups: dict[Any, list[dict[str, Any]]] = {}
    for r in rows:
        axis = normal_text(str(r["axis"]))
        groups.setdefault((normal_text(str(r["serial_number"])), axis) if serial else axis, []).append(r)
    return {key: oldest_first(rs) for key, rs in groups.items()}


def fleet(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``catalog list``: per machine axis its last calibration, verdict and next due date."""
    return [{"serial_number": sn, "axis": axis, "machine": rs[-1]["machine"], "customer": rs[-1]["customer"],
             "calibrations": len(rs), "last_utc": rs[-1]["measured_utc"], "last_run_id": rs[-1]["run_id"],
             "verdict": rs[-1]["verdict"], "E_arcsec": rs[-1]["E_arcsec"], "E_U_arcsec": rs[-1]["E_U_arcsec"],
             "next_due": next_due(rs)} for (sn, axis), rs in by_axis(rows, serial=True).items()]
