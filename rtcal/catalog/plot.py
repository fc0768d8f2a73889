"""``catalog history --plot``: a machine's E ± U over time per axis, with E's trend line and its band
(U of the line, k = 2, from the fit's covariance), the acceptance limit, failures marked, as-left
runs drawn open and superseded entries faint. Every text is drawn as written (no mathtext)."""

from __future__ import annotations

import math
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

from rtcal.catalog.history import YEAR_DAYS, by_axis, current, pair_info, time_of, trend


def _ok(value: Any) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value)


def plot_history(rows: list[dict[str, Any]], path: Path) -> str:
    """Draw the plot into ``path`` (PNG); the line that says what was drawn."""
    from matplotlib.dates import AutoDateLocator, ConciseDateFormatter, date2num

    from rtcal.deliverables.figures import plt

    fig, ax = plt.subplots(figsize=(9, 5))
    drawn = failures = trends = 0
    for k, (axis, axis_rows) in enumerate(sorted(by_axis(rows).items())):
        colour = f"C{k % 10}"
        live = current(axis_rows)
        left = {live[p.left]["run_id"] for p in pair_info(live)} | {r["run_id"] for r in live if r.get("state") == "as_left"}
        live_ids = {r["run_id"] for r in live}
        rs = [r for r in axis_rows if time_of(r) is not None and _ok(r["E_arcsec"])]
        drawn += len(rs)
        for r in rs:
            t, e = date2num(time_of(r)), r["E_arcsec"]
            u = r["E_U_arcsec"] if _ok(r["E_U_arcsec"]) else 0.0
            faint = r["run_id"] not in live_ids
            ax.errorbar([t], [e], yerr=[u], fmt="o", color=colour, capsize=3, alpha=0.35 if faint else 1.0,
                        mfc="white" if r["run_id"] in left else colour)
        ax.plot([], [], "o", color=colour, label=f"axis {axis}: E ± U (k = 2); open: as left")
        bad = [r for r in rs if r["verdict"] == "fail" and r["run_id"] in live_ids]
        if bad:
            failures += len(bad)
            ax.plot(date2num([time_of(r) for r in bad]), [r["E_arcsec"] for r in bad], "x", color="red", markersize=14,
                    markeredgewidth=2.5, label=f"axis {axis}: failed ({len(bad)})")
        t = trend(axis_rows)
        limit = t["E_limit_arcsec"]
        if limit is not None:
            ax.axhline(limit, color="red", linestyle="--", label=f"axis {axis}: E's limit {limit:g}″")
        fit = t.get("fit")
        if fit is not None:
            trends += 1
            t0 = datetime.fromisoformat(fit["t0_utc"])
            end = datetime.fromisoformat(fit["last_utc"]) + timedelta(days=YEAR_DAYS)
            if t["E_reaches_limit_utc"] is not None:
                end = max(end, min(datetime.fromisoformat(t["E_reaches_limit_utc"]) + timedelta(days=90),
                                   t0 + timedelta(days=20 * YEAR_DAYS)))
            n = 100
            times = [t0 + (end - t0) * i / n for i in range(n + 1)]
            x = [(ti - t0).total_seconds() / 86400 / YEAR_DAYS for ti in times]
            line = [fit["intercept_arcsec"] + fit["slope_arcsec_per_year"] * xi for xi in x]
            band = [2 * math.sqrt(max(0.0, fit["var_intercept"] + xi * xi * fit["var_slope"] + 2 * xi * fit["cov"]))
                    for xi in x]
            ax.plot(date2num(times), line, "-", color=colour,
                    label=f"axis {axis}: trend {t['E_trend_arcsec_per_year']:+.2f} ± {t['E_trend_U_arcsec_per_year']:.2f} ″/year")
            ax.fill_between(date2num(times), [v - b for v, b in zip(line, band)], [v + b for v, b in zip(line, band)],
                            color=colour, alpha=0.15, label=f"axis {axis}: U of the trend (k = 2)")
    locator = AutoDateLocator()
    ax.xaxis.set_major_locator(locator)
    ax.xaxis.set_major_formatter(ConciseDateFormatter(locator))  # dates a person reads, minutes to decades
    ax.set_ylabel("E (arcsec)")
    ax.set_xlabel("measured (UTC)")
    ax.set_title(f"{rows[0]['serial_number']}: ISO 230-2 E over time")
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return (f"plot: wrote {path} (E ± U of {drawn} calibration{'s' if drawn != 1 else ''}, {trends} trend"
            f"{'s' if trends != 1 else ''} with its band, {failures} failure{'s' if failures != 1 else ''} marked)")
