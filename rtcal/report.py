"""Shared pieces of the run outputs: results.json, the Markdown report frame, plot styling."""

from __future__ import annotations

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
    lines += [f"- method: `{results['method']}`", f"- software: rtcal {results['rtcal_version']}",
              f"- raw readings: {results['raw_readings']}"]
    if isinstance(results.get("instruments"), dict):
        lines += ["- instruments:"] + [f"  - {k}: `{v}`" for k, v in results["instruments"].items()]
    else:
        lines += [f"- instruments: {results.get('instruments')}, seed {results['seed']}"]
    lines.append("")
    lines += body
    if results.get("events"):
        lines += ["## Events", ""] + [f"- t = {ev['t_s']:.1f} s, {ev['kind']}: {ev['message']}" for ev in results["events"]] + [""]
    path = run_dir / "report.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def finite_or_none(values) -> list[float | None]:
    """JSON has no NaN: missing values (no face in front, say) become null."""
    out = []
    for v in values:
        v = float(v)
        out.append(None if v != v else round(v, 4))
    return out
