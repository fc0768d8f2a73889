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
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from typing import Any, Callable

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


UNITS = {"um": "µm", "arcsec": "″"}


def location_series(rows: list[dict[str, Any]], located: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    """Each ISO 230-7 location error's values over time (``located``: the catalogue's rows of ``rows``' entries),
    by axis and symbol, each value with its U, k, entry and time, oldest first."""
    order = {r["run_id"]: k for k, r in enumerate(oldest_first(rows))}
    out: dict[str, list[dict[str, Any]]] = {}
    for e in sorted((e for e in located if e["run_id"] in order), key=lambda e: order[e["run_id"]]):
        out.setdefault(e["symbol"], []).append({
            "run_id": e["run_id"], "measured_utc": e["measured_utc"], "axis": e["axis"], "value": e["value"],
            "expanded_uncertainty": e["expanded_uncertainty"], "coverage_factor": e["coverage_factor"]})
    return dict(sorted(out.items(), key=lambda kv: (kv[1][-1]["axis"], kv[0])))


def location_lines(series: dict[str, list[dict[str, Any]]]) -> list[str]:
    """``history``'s lines of the location errors: per symbol, its value ± U at each entry, oldest first."""
    if not series:
        return []
    lines = ["location errors (ISO 230-7), value ± U (k = 2), oldest first:"]
    for symbol, points in series.items():
        name, _, unit = symbol.partition("_")
        values = " · ".join(f"{p['measured_utc'][:16].replace('T', ' ')} {value_text(p['value'], p['expanded_uncertainty'], '+')}"
                            f" ± {u_text(p['expanded_uncertainty'])}" for p in points)
        lines.append(f"  {name} ({UNITS.get(unit, unit)}, axis {points[0]['axis']}): {values}")
    return lines


@dataclass(frozen=True)
class Pair:
    """An as-found / as-left pair of one axis's rows (indices): ``declared`` by the runs, or guessed."""

    found: int
    left: int
    declared: bool


def pair_info(rows: list[dict[str, Any]]) -> list[Pair]:
    """The pairs of one axis's rows (oldest first): a run declared as found and the next run, if it is
    declared as left; else two runs that say nothing within :data:`PAIR_WINDOW_DAYS` (a guess). An
    entry whose time cannot be read is in none."""
    out: list[Pair] = []
    i = 0
    while i + 1 < len(rows):
        a, b = rows[i], rows[i + 1]
        first, second = time_of(a), time_of(b)
        declared = a.get("state") == "as_found" and b.get("state") == "as_left"
        guessed = (not a.get("state") and not b.get("state") and first is not None and second is not None
                   and second - first <= timedelta(days=PAIR_WINDOW_DAYS))
        if first is not None and second is not None and (declared or guessed):
            out.append(Pair(i, i + 1, declared))
            i += 2
        else:
            i += 1
    return out


def pairs(rows: list[dict[str, Any]]) -> list[tuple[int, int]]:
    """(as-found index, as-left index) of each pair (:func:`pair_info`)."""
    return [(p.found, p.left) for p in pair_info(rows)]


def current(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The entries no later entry supersedes (a reissued certificate stands for the one it replaces)."""
    replaced = {r.get("supersedes") for r in rows if r.get("supersedes")}
    return [r for r in rows if r["run_id"] not in replaced]


def trend(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """E's trend per year with its U and the date E reaches its limit (see the module's docstring).
    ``E_reaches_limit`` says it in words: the date, "beyond 100 years", or why there is none."""
    rows = current(rows)
    as_left = {j for _, j in pairs(rows)} | {k for k, r in enumerate(rows) if r.get("state") == "as_left"}
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
    out["fit"] = {"t0_utc": t0.isoformat(), "last_utc": used[-1][0].isoformat(), "intercept_arcsec": a,
                  "slope_arcsec_per_year": b, "var_intercept": sxx / det, "var_slope": s / det, "cov": -sx / det}
    if limit is None:
        out["E_reaches_limit"] = "no limit for E"
    elif b > 0 and (years := (limit - a) / b) > HORIZON_YEARS:
        out["E_reaches_limit"] = BEYOND
    elif b > 0 and years >= -HORIZON_YEARS:  # (a line already over the limit at its first run: a date before it)
        out["E_reaches_limit_utc"] = (t0 + timedelta(days=years * YEAR_DAYS)).isoformat()
        out["E_reaches_limit"] = _reached(out["E_reaches_limit_utc"], "")
    elif a + b * max(x) >= limit:  # flat, falling or barely rising, yet over the limit at the last run fitted
        out["E_reaches_limit_utc"] = t0.isoformat()
        out["E_reaches_limit"] = _reached(out["E_reaches_limit_utc"], " (over its limit from the first run fitted)")
    else:
        out["E_reaches_limit"] = "not on this trend (E does not rise)"
    return out


def _reached(when_utc: str, why: str) -> str:
    """A limit date in words: the date ahead, or "exceeded since" a date already past."""
    if _time(when_utc) <= datetime.now(timezone.utc):
        return f"exceeded since {when_utc[:10]}{why}"
    return f"{when_utc[:10]}{why}"


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
    """Per axis: its entries, pairs (named by certificate number and date) and trend (rows oldest
    first, possibly of several axes)."""
    out: dict[str, Any] = {}
    for axis, rs in by_axis(rows).items():
        live = current(rs)
        out[axis] = {"pairs": [pair_json(live, p) for p in pair_info(live)], "trend": trend(rs), "next_due": next_due(rs),
                     "superseded": {r["run_id"]: s["run_id"] for s in rs if s.get("supersedes")
                                    for r in rs if r["run_id"] == s["supersedes"]}}
    return out


def pair_json(rows: list[dict[str, Any]], p: Pair) -> dict[str, Any]:
    """A pair as a lab manager reads it: each run's certificate number and date, and how it is known."""
    found, left = rows[p.found], rows[p.left]
    return {"as_found": found["run_id"], "as_left": left["run_id"],
            "as_found_certificate": found.get("certificate_number", ""), "as_found_utc": found["measured_utc"],
            "as_left_certificate": left.get("certificate_number", ""), "as_left_utc": left["measured_utc"],
            "declared": p.declared,
            "how": "declared by the runs (as found, as left)" if p.declared else
                   f"a guess: two runs within {PAIR_WINDOW_DAYS:g} days, neither says as found or as left",
            "E_change_arcsec": None if found["E_arcsec"] is None or left["E_arcsec"] is None
            else round(left["E_arcsec"] - found["E_arcsec"], 4)}


def certificate_words(row: dict[str, Any]) -> str:
    """An entry as a person names it: its certificate number and date (the run id when it has no number)."""
    number = row.get("certificate_number") or f"run {str(row['run_id'])[:12]} (no certificate number)"
    return f"{number} ({str(row.get('measured_utc') or '')[:10] or 'date unknown'})"


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


def fleet(rows: list[dict[str, Any]],
          due: Callable[[str, str, list[dict[str, Any]]], dict[str, Any]] | None = None) -> list[dict[str, Any]]:
    """``catalog list``: per machine axis its last calibration, verdict and next due date (``due``: the
    policy's, rtcal/catalog/intervals.py, given (serial, axis, rows); default: a year, or sooner on E's trend)."""
    out = []
    for (sn, axis), rs in by_axis(rows, serial=True).items():
        last = current(rs)[-1]
        found = due(sn, axis, rs) if due is not None else {"due": next_due(rs)}
        out.append({"serial_number": sn, "axis": axis, "machine": last["machine"], "customer": last["customer"],
                    "site": last.get("site", ""), "calibrations": len(rs), "last_utc": last["measured_utc"],
                    "last_run_id": last["run_id"], "last_certificate": last.get("certificate_number", ""),
                    "test": last.get("test") or last.get("method", ""), "verdict": last["verdict"], "E_arcsec": last["E_arcsec"],
                    "E_U_arcsec": last["E_U_arcsec"], "next_due": found["due"],
                    **{f"due_{k}": v for k, v in found.items() if k in ("method", "data", "retired")}})
    return out
