"""`rtcal compare`: two runs of the same axis side by side — before and after compensation, or
months apart (drift). Per target and direction the change of the mean deviation and whether it
exceeds the combined expanded uncertainty U_c = 2·√(u_first² + u_second²) of the two means (two runs are
independent measurements); the ISO 230-2 parameters of both; one plot with both curves and
their U (k = 2) bands."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from rtcal.deliverables.deviations import PositioningDeviations
from rtcal.deliverables.evaluation import evaluate
from rtcal.results.model import Analysis, RunResults, TargetedEstimate


def estimate_targets(analysis: Analysis, table: PositioningDeviations) -> list[tuple[float, int]]:
    """(target, direction) of each value of the recommended estimate's cumulative deviation: its own
    targets, or the nominal angles in the table's one direction."""
    e = analysis.recommended_estimate()
    if e is None:
        return []
    if isinstance(e, TargetedEstimate):
        return [(float(t), int(d)) for t, d in zip(e.target_deg, e.target_direction)]
    direction = int(table.direction[0]) if len(table) else 1
    return [(float(t), direction) for t in analysis.nominal_angles_deg]


def mean_curve(table: PositioningDeviations, results: RunResults | None, wrap: bool = True) -> dict[tuple[float, int], tuple[float, float]]:
    """(target, direction) → (mean deviation, its standard uncertainty). From a run, the recommended
    estimate's own cumulative deviation and u (its covariance knows what the runs share); from a
    CSV, the mean over the runs with u = RMS(u)/√n (independent rows assumed; the RMS over the rows
    that have a u). ``wrap``: targets taken modulo 360° (to match two runs; rows at 0° and 360° are
    one target); from a CSV in ascending target order, ↑ before ↓."""

    def key(t: float) -> float:
        return round(float(t) % 360.0 if wrap else float(t), 6)

    e = results.recommended_estimate() if results is not None else None
    if results is not None and e is not None:
        return {(key(t), d): (float(x), float(u))
                for (t, d), x, u in zip(estimate_targets(results, table), e.cumulative_deviation_arcsec,
                                        e.cumulative_uncertainty_arcsec)
                if x is not None and u is not None}
    ok = np.isfinite(table.deviation_arcsec)
    angles = np.round(np.asarray(table.target_deg, float)[ok], 6)
    angles = np.round(np.mod(angles, 360.0), 6) if wrap else angles
    direction = np.asarray(table.direction, int)[ok]
    x, u = np.asarray(table.deviation_arcsec, float)[ok], np.asarray(table.uncertainty_arcsec, float)[ok]
    # one sort groups the rows by (target, direction): n log n in rows, however many targets there are
    groups, group = np.unique(np.column_stack([angles, -direction]), axis=0, return_inverse=True)
    group = group.ravel()
    n = np.bincount(group, minlength=len(groups))
    mean = np.bincount(group, weights=x, minlength=len(groups)) / n
    u_known = np.isfinite(u)
    n_u = np.bincount(group, weights=u_known, minlength=len(groups))
    with np.errstate(invalid="ignore", divide="ignore"):  # a group without any u: NaN
        u2 = np.bincount(group, weights=np.where(u_known, u, 0.0) ** 2, minlength=len(groups)) / n_u
        u_mean = np.where(n_u > 0, np.sqrt(u2 / n), np.nan)
    return {(float(t), -int(d)): (float(m), float(v)) for (t, d), m, v in zip(groups, mean, u_mean)}


def compare(a: tuple[PositioningDeviations, RunResults | None], b: tuple[PositioningDeviations, RunResults | None],
            names: tuple[str, str]) -> dict[str, Any]:
    ca, cb = mean_curve(*a), mean_curve(*b)
    common = sorted(set(ca) & set(cb), key=lambda k: (-k[1], k[0]))
    rows = []
    for key in common:
        (xa, ua), (xb, ub) = ca[key], cb[key]
        Uc = 2.0 * float(np.hypot(ua, ub))
        change = xb - xa
        rows.append({"target_deg": key[0], "direction": key[1], "a_arcsec": round(xa, 4), "b_arcsec": round(xb, 4),
                     "change_arcsec": round(change, 4), "combined_U_arcsec": round(Uc, 4) if np.isfinite(Uc) else None,
                     "exceeds_U": bool(abs(change) > Uc) if np.isfinite(Uc) else None})
    ea, eb = evaluate(a[0], "iso230-2"), evaluate(b[0], "iso230-2")
    keys = ("E_up", "E_down", "E", "M", "B", "B_mean", "R", "A")
    return {
        "a": names[0], "b": names[1],
        "targets_compared": len(rows),
        "targets_changed": sum(1 for r in rows if r["exceeds_U"]),
        "only_in_a": len(set(ca) - set(cb)), "only_in_b": len(set(cb) - set(ca)),
        "iso230_2": {k: {"a": ea[k], "b": eb[k]} for k in keys},
        "per_target": rows,
        "note": "change = b − a of the mean deviation; it exceeds U when |change| > 2·√(u_a² + u_b²)",
    }


def plot_comparison(result: dict[str, Any], a: tuple[PositioningDeviations, RunResults | None],
                    b: tuple[PositioningDeviations, RunResults | None],
                    path: Path) -> Path:
    """Both runs' mean deviation per target and direction on one axis, each with its U (k = 2)
    band; ↑ solid, ↓ dashed; the title names both runs and how many values changed beyond U_c."""
    from matplotlib.patches import Patch

    from rtcal.deliverables.figures import plt

    fig, ax = plt.subplots(figsize=(9.5, 5.2))
    for k, ((table, results), name) in enumerate(zip((a, b), (result["a"], result["b"]))):
        curve = mean_curve(table, results)
        for d, style in ((1, "-"), (-1, "--")):
            keys = sorted(t for t in curve if t[1] == d)
            if not keys:
                continue
            x = np.array([t[0] for t in keys])
            y = np.array([curve[t][0] for t in keys])
            u = np.array([curve[t][1] for t in keys])
            color = f"C{k}"
            if np.all(np.isfinite(u)):
                ax.fill_between(x, y - 2 * u, y + 2 * u, color=color, alpha=0.25, lw=0)
            ax.plot(x, y, style, marker="o" if len(x) <= 500 else None, ms=4, color=color, label=f"{'first' if k == 0 else 'second'}: {name}, {'↑ positive' if d > 0 else '↓ negative'} approach")
    ax.axhline(0, color="0.6", lw=0.8)
    ax.set_xlabel("target (commanded angle) / °")
    ax.set_ylabel("mean positioning deviation (actual − commanded) / ″")
    ax.set_title(f"first: {result['a']}   vs   second: {result['b']}\n{result['targets_changed']} of "
                 f"{result['targets_compared']} target values changed by more than U_c = 2·√(u_first² + u_second²)",
                 fontsize=10)
    ax.grid(alpha=0.3)
    handles, labels = ax.get_legend_handles_labels()
    handles.append(Patch(color="0.5", alpha=0.3, lw=0))
    labels.append("shaded: U (k = 2) of each mean")
    ax.legend(handles, labels, fontsize=8, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def comparison_lines(result: dict[str, Any]) -> list[str]:
    """The comparison as a console table (under 100 columns): per target and direction the first and second run, the
    change and the combined U_c (rounded once, as on a certificate), then the ISO 230-2 parameters."""
    from rtcal.deliverables.rounding import u_text

    def num(v: float | None, sign: str = "+") -> str:
        return "–" if v is None else format(v, f"{sign}.2f")

    # the runs are "first" and "second": "A" and "B" are ISO 230-2 parameters in the same table
    lines = [f"first: {result['a']}", f"second: {result['b']}", "",
             f"{'target / °':>10}  {'dir':>3}  {'first / ″':>9}  {'second / ″':>10}  {'change / ″':>10}  {'U_c / ″':>8}  "
             "beyond U_c"]
    for r in result["per_target"]:
        lines.append(f"{r['target_deg']:>10g}  {'↑' if r['direction'] > 0 else '↓':>3}  {num(r['a_arcsec']):>9}  "
                     f"{num(r['b_arcsec']):>10}  {num(r['change_arcsec']):>10}  {u_text(r['combined_U_arcsec']):>8}  "
                     + ("yes" if r["exceeds_U"] else "no" if r["exceeds_U"] is not None else "–"))
    lines += ["", f"{'ISO 230-2':>10}  {'':>3}  {'first / ″':>9}  {'second / ″':>10}  {'change / ″':>10}"]
    for k, v in result["iso230_2"].items():
        change = None if v["a"] is None or v["b"] is None else v["b"] - v["a"]
        lines.append(f"{k.replace('_up', '↑').replace('_down', '↓').replace('_mean', ' mean'):>10}  {'':>3}  "
                     f"{num(v['a'], ''):>9}  {num(v['b'], ''):>10}  {num(change):>10}")
    changed, compared = result["targets_changed"], result["targets_compared"]
    lines += ["", f"{changed} of {compared} target value{'s' if compared != 1 else ''} changed by more than "
              "U_c = 2·√(u_first² + u_second²) (k = 2)"]
    only = [f"{result[k]} only in the {'first' if k == 'only_in_a' else 'second'}" for k in ("only_in_a", "only_in_b")
            if result[k]]
    if only:
        lines.append("not compared: " + ", ".join(only))
    return lines
