"""Shared pieces of the run outputs: results.json, the Markdown report frame, plot styling."""

from __future__ import annotations

import datetime as _dt
import json
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402,F401  (re-exported for the method modules)


def write_results(run_dir: Path, results: dict[str, Any]) -> Path:
    path = run_dir / "results.json"
    path.write_text(json.dumps(results, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    return path


def write_report(run_dir: Path, results: dict[str, Any], body: list[str]) -> Path:
    """The Markdown report: a header every run shares, the method's body, the run's events."""
    lines = [f"# rtcal run — {results['procedure'].get('name') or results['method']}", ""]
    for name, st in results.get("solver_status", {}).items():
        if st["status"] != "converged":
            lines.append(f"> **Estimator `{name}` {st['status']}**: {st['message']}")
            lines.append(">")
    if results.get("bench") and results["bench"].startswith("ideal bench"):
        lines += [f"> **Note:** {results['bench']}.", ""]
    lines += [f"- method: `{results['method']}`", f"- software: rtcal {results['rtcal_version']}",
              f"- started: {results.get('started_utc') or '?'} (UTC); measured until {results.get('finished_utc') or '?'}; "
              f"report written {_dt.datetime.now(_dt.timezone.utc).isoformat(timespec='seconds')}",
              f"- measurement duration: {results.get('measurement_duration_s')} s"
              + (" of simulated time (virtual clock: settle times and motions were not waited for)"
                 if results.get("clock") == "virtual" else ""),
              f"- raw readings: {results['raw_readings']}"]
    if isinstance(results.get("instruments"), dict):
        lines += ["- instruments:"] + [f"  - {k}: `{v}`" for k, v in results["instruments"].items()]
    else:
        lines += [f"- instruments: {results.get('instruments')}, bench `{results.get('bench')}`, seed {results['seed']}"]
    if results.get("recommended"):
        lines.append(f"- recommended estimate: `{results['recommended']}` (converged, smallest uncertainty)")
    lines.append("")
    lines += body
    lines += events_section(results.get("events", []))
    path = run_dir / "report.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


NOTABLE_EVENTS = ("fault", "retry", "reacquire", "skip", "pause", "abort", "resume")


def events_section(events: list[dict], limit: int = 60) -> list[str]:
    """Counts of every kind of event, then the faults and the actions taken, in order."""
    if not events:
        return []
    counts: dict[str, int] = {}
    for ev in events:
        counts[ev["kind"]] = counts.get(ev["kind"], 0) + 1
    lines = ["## Events", "", ", ".join(f"{k}: {n}" for k, n in counts.items()), ""]
    notable = [ev for ev in events if ev["kind"] in NOTABLE_EVENTS]
    for ev in notable[:limit]:
        who = f" ({ev['instrument']})" if ev.get("instrument") else ""
        lines.append(f"- t = {ev['t_s']:.1f} s, {ev['kind']}{who}: {ev['message']}")
    if len(notable) > limit:
        lines.append(f"- … {len(notable) - limit} more in results.json and run.sqlite")
    return lines + [""]


def finite_or_none(values) -> list[float | None]:
    """JSON has no NaN: missing values (no face in front, say) become null."""
    out = []
    for v in values:
        v = float(v)
        out.append(None if v != v else round(v, 4))
    return out
