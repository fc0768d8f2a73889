"""Human-facing outputs of a run: the deviation plot and a short Markdown report."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def plot_deviation(run_dir: Path, results: dict[str, Any]) -> Path:
    """Deviation per station (eq. 33) with 1σ bars, one series per estimator, truth if known."""
    angles = results["nominal_angles_deg"]
    stations = list(range(2, len(angles) + 1))
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for name, est in results["estimates"].items():
        ax.errorbar(stations, est["deviation_arcsec"], yerr=est.get("uncertainty_arcsec"), marker="o", capsize=3, label=name)
    truth = results.get("truth", {}).get("deviation_arcsec")
    if truth is not None:
        ax.plot(stations, truth, "k--", marker="x", label="truth (simulated)")
    ax.axhline(0.0, color="0.7", lw=0.8)
    ax.set_xlabel("station")
    ax.set_ylabel("angular positioning deviation Δθ / arcsec")
    ax.set_xticks(stations, [f"P{s}\n{angles[s - 1]:g}°" for s in stations], fontsize=8)
    ax.set_title(results.get("procedure", {}).get("name") or "angular positioning deviation")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    path = run_dir / "deviation.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def write_report(run_dir: Path, results: dict[str, Any]) -> Path:
    """A short Markdown report: setup, deviations table, figures, notes, events."""
    angles = results["nominal_angles_deg"]
    lines = [f"# rtcal run — {results['procedure'].get('name') or results['method']}", ""]
    lines += [f"- method: `{results['method']}`", f"- software: rtcal {results['rtcal_version']}",
              f"- seed: {results['seed']}", f"- raw readings: {results['raw_readings']}",
              f"- bench: {'simulated' if 'truth' in results else 'hardware'}", ""]
    names = list(results["estimates"])
    truth = results.get("truth", {}).get("deviation_arcsec")
    head = "| station | angle / ° | " + " | ".join(f"{n} Δθ / ″ (1σ)" for n in names) + (" | truth / ″ |" if truth else " |")
    lines += [head, "|" + "---|" * (2 + len(names) + (1 if truth else 0))]
    for j in range(1, len(angles)):
        cells = [f"P{j + 1}", f"{angles[j]:g}"]
        for n in names:
            e = results["estimates"][n]
            cells.append(f"{e['deviation_arcsec'][j - 1]:+.2f} ({e['uncertainty_arcsec'][j - 1]:.2f})")
        if truth:
            cells.append(f"{truth[j - 1]:+.2f}")
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    for n in names:
        e = results["estimates"][n]
        lines.append(f"- {n}: σΔθ (eq. 34) = ±{e['sigma_arcsec']:.2f}″, algorithm error (eq. 36) = ±{e['algorithm_error_arcsec']:.2e}″")
    lines += ["", "![deviation](deviation.png)", ""]
    notes = results["estimates"].get("paper", {}).get("notes", [])
    if notes:
        lines += ["## Where the printed equations and the paper's figures differ", ""] + [f"- {n}" for n in notes] + [""]
    if results.get("events"):
        lines += ["## Events", ""] + [f"- t = {ev['t_s']:.1f} s, {ev['kind']}: {ev['message']}" for ev in results["events"]] + [""]
    path = run_dir / "report.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path
