"""The encoder Abbe-error method's outputs (seed 001): abbe_steps.csv, Figures 9–12 in the
manner of seed 001, harmonics and closure figures, its report sections and console summary,
all from the typed results."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
from matplotlib.axes import Axes

from rtcal.api import (RAD_PER_ARCSEC, ErrorMotions, Estimate, MeasuredLocation, TargetedEstimate, fmt, legend_below, plt,
                       significant, status_lines, u_text)
from rtcal.deliverables.certificate import largest, period_text, smallest
from rtcal.methods.abbe.results import AbbeResults, ClosureEstimate
from rtcal.results.model import AbbeEstimate, HarmonicTerm, PeriodicError, PeriodicTerm

ARROW = {1: "↑", -1: "↓"}
# ↑ filled circles, ↓ larger hollow squares: where the two directions agree, both stay visible
MARKER: dict[int, dict[str, Any]] = {1: {"marker": "o", "ms": 4}, -1: {"marker": "s", "ms": 7, "mfc": "none"}}


def _figure(run_dir: Path, name: str, draw: Callable[[Axes], None], arc_deg: tuple[float, float] | None = None) -> Path:
    """One per-step figure over the turn, or over ``arc_deg`` (a fine-step test's few degrees)."""
    fig, ax = plt.subplots(figsize=(8, 4.6), layout="constrained")
    draw(ax)
    ax.set_xlabel("table angle / °")
    if arc_deg is not None:
        pad = 0.02 * (arc_deg[1] - arc_deg[0])
        ax.set_xlim(arc_deg[0] - pad, arc_deg[1] + pad)
    else:
        ax.set_xlim(-8, 368)  # a point at 0° (or 360°) stays whole, not cut by the frame
        ax.set_xticks(range(0, 361, 30))
    ax.grid(alpha=0.3)
    legend_below(fig)
    path = run_dir / name
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def period_words(h: PeriodicTerm) -> str:
    """A harmonic's period in degrees and, where the worm ratio is stated, in worm revolutions."""
    return "period " + period_text(h.period_deg, h.period_worm_revolutions)


def periodic_lines(p: PeriodicError | None) -> list[str]:
    """report.md's section on the fine-step test (none without one)."""
    if p is None:
        return []
    lines = ["## Periodic positioning error (ISO 230-2:2014 Annex C)", "", p.definition + ".", "",
             f"- period {p.period_deg:g}°" + (f" (one revolution of the {p.worm_ratio:g}:1 worm)" if p.worm_ratio else "")
             + f"; steps of {p.step_deg:g}° from {p.start_deg:g}°, {p.targets_per_period} targets per period",
             f"- periodic positioning error: **{p.periodic_error_arcsec:.2f}″** (U {u_text(p.expanded_uncertainty_arcsec)}″, "
             f"k = 2); ↑ {fmt(p.periodic_error_up_arcsec, '.2f')}″, ↓ {fmt(p.periodic_error_down_arcsec, '.2f')}″",
             f"- reference: {p.reference}", "", "| order (per turn) | period | amplitude / ″ | 1σ / ″ | phase / ° | significant |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {h.order} | {period_words(h)} | {h.amplitude_arcsec:.3f} | {h.amplitude_sigma_arcsec:.3f} | "
              f"{h.phase_deg:.1f} | {'yes' if h.significant else 'no'} |" for h in p.harmonics]
    return lines + [""] + [f"- {n}" for n in p.notes] + ["", "![periodic_error](periodic_error.png)", ""]


class AbbeOutputs:
    """What an encoder Abbe-error run hands the user besides the files every run has."""

    def __init__(self, results: AbbeResults):
        self.results = results
        abbe = results.estimates.abbe
        if abbe is None:
            raise ValueError("estimates.abbe: missing (results of an encoder Abbe-error run always have it)")
        self.abbe: AbbeEstimate = abbe

    def _recommended(self) -> tuple[str, Estimate]:
        e = self.results.recommended_estimate()
        return (self.results.recommended or "abbe", self.abbe if e is None else e)

    def _series(self, values: list[float | None], direction: int) -> tuple[np.ndarray, np.ndarray]:
        """One per-step series of the given approach: (angle, value), missing values NaN."""
        a = self.abbe
        sel = [i for i, d in enumerate(a.direction) if d == direction]
        x = np.array([a.angle_deg[i] for i in sel])
        y = np.array([np.nan if values[i] is None else values[i] for i in sel], dtype=float)
        return x, y

    def certificate_tables(self) -> list[dict[str, Any]]:
        """None besides the tables every certificate has."""
        return []

    def write_files(self, run_dir: Path) -> list[Path]:
        """abbe_steps.csv and figures in the manner of seed 001's Figures 9–12, plus harmonics and closure."""
        a = self.abbe
        columns: list[tuple[str, Sequence[float | None]]] = [
            ("angle_deg", a.angle_deg), ("direction", a.direction), ("tilt_x_arcsec", a.tilt_x_arcsec),
            ("radial_y_um", a.radial_y_um), ("predicted_encoder_error_arcsec", a.predicted_encoder_error_arcsec),
            ("measured_encoder_error_arcsec", a.measured_encoder_error_arcsec), ("residual_arcsec", a.residual_arcsec),
            ("positioning_error_arcsec", a.positioning_error_arcsec), ("encoder_vs_command_arcsec", a.encoder_vs_command_arcsec)]
        csv_path = run_dir / "abbe_steps.csv"
        with csv_path.open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow([name for name, _ in columns])
            for i in range(len(a.angle_deg)):
                w.writerow(["" if values[i] is None else values[i] for _, values in columns])
        dirs = sorted(set(a.direction), reverse=True)
        series = self._series

        def fig9(ax: Axes) -> None:
            right = ax.twinx()  # two quantities, two units: tilt on the left axis, radial motion on the right
            for k, d in enumerate(dirs):
                ax.plot(*series(a.tilt_x_arcsec, d), **MARKER[d], color=f"C{k}", label=f"tilt εx {ARROW[d]} (left axis, ″)")
                right.plot(*series(a.radial_y_um, d), **MARKER[d], ls="--", color=f"C{k + 2}",
                           label=f"radial δy {ARROW[d]} (right axis, µm)")
            ax.set_ylabel("tilt εx / ″")
            right.set_ylabel("radial δy / µm")
            ax.set_title("Tilt motion about X and radial motion in Y (from the dial indicators)")

        def fig10(ax: Axes) -> None:
            enc_zero = None
            for k, d in enumerate(dirs):
                x, y = series(a.positioning_error_arcsec, d)
                _, u = series(a.positioning_error_sigma_arcsec, d)
                ok = np.isfinite(y)
                ax.fill_between(x[ok], (y - 2 * u)[ok], (y + 2 * u)[ok], color=f"C{2 * k}", alpha=0.2, lw=0,
                                label=f"εz {ARROW[d]} ±U (k = 2)")
                ax.plot(x[ok], y[ok], marker="o", color=f"C{2 * k}", label=f"εz (autocollimator + polygon) {ARROW[d]}")
                xe, ye = series(a.encoder_vs_command_arcsec, d)
                if enc_zero is None:  # the encoder's zero is arbitrary: refer it to the same first target
                    first = x[ok][0]
                    enc_zero = ye[np.argmin(np.abs(xe - first))]
                ax.plot(xe, ye - enc_zero, marker=".", ls="--", lw=0.8, color=f"C{2 * k + 1}",
                        label=f"encoder − command {ARROW[d]}")
            rev = a.reversal_reference_arcsec
            ax.set_ylabel("εz (ECC) / ″, relative to the first target")
            ax.set_title("Angular positioning error" + (f"; reversal ↑ − ↓ = {rev:+.2f}″" if rev is not None else ""))

        def fig11(ax: Axes) -> None:
            for k, d in enumerate(dirs):
                x, y = series(a.predicted_encoder_error_arcsec, d)
                _, u = series(a.predicted_encoder_error_sigma_arcsec, d)
                ax.errorbar(x, y, yerr=2 * u, fmt=".-", capsize=2, lw=0.8, color=f"C{2 * k}",
                            label=f"predicted (δy + Zs·εx)/rE {ARROW[d]}, ±U (k = 2)")
                x, y = series(a.measured_encoder_error_arcsec, d)
                _, u = series(a.measured_encoder_error_sigma_arcsec, d)
                ok = np.isfinite(y)
                ax.errorbar(x[ok], y[ok], yerr=2 * u[ok], ls="none", **MARKER[d], capsize=2, color=f"C{2 * k + 1}",
                            label=f"measured (encoder − reference) {ARROW[d]}, ±U (k = 2)")
            ax.set_ylabel("encoder error / ″ (mean over the faces removed)")
            ax.set_title("Predicted and measured encoder error")

        def fig12(ax: Axes) -> None:
            for k, d in enumerate(dirs):
                x, y = series(a.residual_arcsec, d)
                _, u = series(a.residual_sigma_arcsec, d)
                ok = np.isfinite(y)
                ax.errorbar(x[ok], y[ok], yerr=2 * u[ok], ls="none", **MARKER[d], capsize=2, color=f"C{2 * k}",
                            label=f"measured − predicted {ARROW[d]}, ±U (k = 2)")
            ax.axhline(0, color="0.6", lw=0.8)
            ax.set_ylabel("residual / ″")
            ax.set_title(f"Residual (RMS {a.residual_rms_arcsec}″)")

        p = self.results.periodic_error
        arc = None if p is None else (min(a.angle_deg), max(a.angle_deg))
        paths = [csv_path] + [_figure(run_dir, n, f, arc) for n, f in (
            ("fig09_tilt_radial.png", fig9), ("fig10_positioning.png", fig10),
            ("fig11_encoder_error.png", fig11), ("fig12_residual.png", fig12))]
        if p is not None:
            paths.append(self._plot_periodic(run_dir, p))
        else:
            paths.append(self._plot_harmonics(run_dir))
        if self.results.estimates.closure is not None:
            paths.append(self._plot_closure(run_dir, self.results.estimates.closure))
        return paths

    def _plot_harmonics(self, run_dir: Path) -> Path:
        h = self.abbe.harmonics
        fig, ax = plt.subplots(figsize=(8, 4.6), layout="constrained")
        present: list[tuple[str, list[HarmonicTerm]]] = [
            (name, terms) for name, terms in (("positioning error εz (autocollimator + polygon)", h.positioning_error_arcsec),
                                              ("encoder − command", h.encoder_vs_command_arcsec),
                                              ("encoder error, measured", h.measured_encoder_error_arcsec),
                                              ("encoder error, predicted (Abbe)", h.predicted_encoder_error_arcsec))
            if terms is not None]
        width = 0.8 / max(len(present), 1)
        orders: set[int] = set()
        any_mixed = False
        for k, (label, terms) in enumerate(present):
            xs = [t.order + (k - len(present) / 2 + 0.5) * width for t in terms]
            ax.bar(xs, [t.amplitude for t in terms], width, yerr=[2 * t.amplitude_sigma for t in terms], capsize=2,
                   label=f"{label}, ±U (k = 2)")
            ax.hlines([t.threshold for t in terms], [x - width / 2 for x in xs], [x + width / 2 for x in xs], colors="k",
                      lw=1.2, label="significance threshold (family-wise 1 %)" if k == 0 else "_nolegend_")
            orders |= {t.order for t in terms}
            mixed = [(x, t) for x, t in zip(xs, terms) if t.not_separable_from]
            if mixed:  # leakage of an order the targets cannot resolve: not a harmonic of the table
                ax.bar([x for x, _ in mixed], [t.amplitude for _, t in mixed], width, color="white", edgecolor=f"C{k}",
                       hatch="////", label="_nolegend_")  # hatched in the series' colour: whose bar it is stays visible
                any_mixed = True
        if any_mixed:  # one grey legend entry for the hatching of every series
            ax.fill_between([], [], facecolor="white", edgecolor="0.4", hatch="////",
                            label="hatched: not separable from a higher order at these targets (leakage)")
        ax.set_xticks(sorted(orders), [str(o) for o in sorted(orders)])
        ax.set_xlabel("harmonic order (per revolution)")
        ax.set_ylabel("amplitude / arcsec")
        ax.set_title("Harmonic analysis")
        legend_below(fig)
        path = run_dir / "harmonics.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        return path

    def _plot_periodic(self, run_dir: Path, p: PeriodicError) -> Path:
        """The fine-step curve less the slow part per direction, the period's harmonics over it, the
        period marked: what the periodic positioning error is the range of."""
        fig, ax = plt.subplots(figsize=(8, 4.6), layout="constrained")
        t, d, x = np.array(p.target_deg), np.array(p.direction), np.array(p.residual_arcsec)
        theta = np.radians(np.linspace(t.min(), t.max(), 800))
        fitted = sum((h.amplitude_arcsec * np.sin(h.order * theta + np.radians(h.phase_deg)) for h in p.harmonics),
                     np.zeros(len(theta)))
        for k, sense in enumerate(sorted(set(d.tolist()), reverse=True)):
            sel = d == sense
            ax.plot(t[sel], x[sel], **MARKER[sense], ls="none", color=f"C{k}",
                    label=f"mean deviation less the slow part {ARROW[sense]} (runs averaged)")
        ax.plot(np.degrees(theta), fitted, color="0.3", lw=1, label="harmonics of the period (fitted, both directions)")
        ax.axvspan(p.start_deg, p.start_deg + p.period_deg, color="0.9", zorder=0, label=f"one period ({p.period_deg:g}°)")
        ax.set_xlabel("table angle / °")
        ax.set_ylabel("deviation less the slow part / ″")
        ax.grid(alpha=0.3)
        ax.set_title(f"Periodic positioning error {p.periodic_error_arcsec:.2f}″ (U {u_text(p.expanded_uncertainty_arcsec)}″, "
                     f"k = 2) over {p.period_deg:g}°")
        legend_below(fig)
        path = run_dir / "periodic_error.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        return path

    def _plot_closure(self, run_dir: Path, c: ClosureEstimate) -> Path:
        fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 6.4), layout="constrained")
        faces = np.array(c.face_error_arcsec, float)
        ax1.errorbar(range(len(faces)), faces, yerr=2 * np.array(c.face_uncertainty_arcsec, float), marker="o",
                     capsize=3, label="polygon face error, ±U (k = 2)")
        ax1.set_xlabel("polygon face")
        ax1.set_ylabel("face error / ″\n(closure: their sum is 0)")
        ax1.set_xticks(range(len(faces)))
        table = np.array([np.nan if v is None else v for v in c.table_error_arcsec], float)
        table_u = np.array([np.nan if v is None else v for v in c.table_uncertainty_arcsec], float)
        table = table - table[0]  # the first target of the first direction: the zero of the positioning figure
        for d in sorted(set(c.direction), reverse=True):
            sel = [i for i, x in enumerate(c.direction) if x == d]
            ax2.errorbar([c.table_angle_deg[i] for i in sel], table[sel], yerr=2 * table_u[sel], marker="o", capsize=3,
                         label=f"table error {ARROW[d]}, ±U (k = 2)")
        ax2.set_xlabel("table angle / °")
        ax2.set_ylabel("table error εz / ″\n(relative to the first target)")
        legend_below(fig)
        ax1.set_title("Closure: polygon face errors and table errors, separated")
        path = run_dir / "closure.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        return path

    def report_body(self) -> list[str]:
        """The recommended εz per target and direction with u and U first, then the budget, the
        encoder analysis, harmonics and closure."""
        r, a = self.results, self.abbe
        rec, e = self._recommended()
        truth = r.truth.cumulative_deviation_arcsec if rec == "abbe" and r.truth is not None else None
        lines = [f"## Result: angular positioning deviation ECC ({rec}, recommended)", "",
                 "εz = actual − commanded angle, relative to the first target of the first direction, arcsec; u standard "
                 "uncertainty, U expanded uncertainty (k = 2); ↑ positive, ↓ negative approach.", "",
                 "| target / ° | direction | ECC / ″ | u / ″ | U (k = 2) / ″ |" + (" truth / ″ |" if truth else ""),
                 "|---|---|---|---|---|" + ("---|" if truth else "")]
        targets = zip(e.target_deg, e.target_direction) if isinstance(e, TargetedEstimate) else []
        for j, (target, d) in enumerate(targets):
            cells = [f"{target:g}", ARROW[d], fmt(e.cumulative_deviation_arcsec[j], "+.3f"),
                     fmt(e.cumulative_uncertainty_arcsec[j], ".3f"), fmt(e.cumulative_expanded_uncertainty_arcsec[j], ".3f")]
            if truth:
                cells.append(f"{truth[j]:+.3f}")
            lines.append("| " + " | ".join(cells) + " |")
        lines += ["", "![fig10](fig10_positioning.png)", "", "## Uncertainty budget (contributions u / ″; first and largest targets)", ""]
        b = e.uncertainty_budget
        comb = np.array([np.nan if v is None else v for v in b.combined_arcsec], float)
        worst = int(np.nanargmax(comb)) if np.any(np.isfinite(comb)) else 0
        lines += ["| source | type | input σ | at the largest u | RMS over targets |", "|---|---|---|---|---|"]
        for c in b.components:
            contrib = np.array([np.nan if v is None else v for v in c.contribution_arcsec], float)
            origin = " (from the data)" if c.estimated_from_data else ""
            lines.append(f"| {c.source} | {c.type} | {significant(c.input_sigma)} {c.unit}{origin} | {contrib[worst]:.3f} | "
                         f"{float(np.sqrt(np.mean(contrib[1:] ** 2))):.3f} |")
        lines += [f"| **combined u** | | | **{comb[worst]:.3f}** | **{float(np.sqrt(np.mean(comb[1:] ** 2))):.3f}** |", ""]
        lines += [f"- not included: {n}" for n in b.not_included] + [""]
        lines += ["## Encoder error (seed 001)", "",
                  f"- polygon face errors from: {a.polygon_source}; random error of the reference from: {a.random_error_from}",
                  f"- extrapolation factor a = (Zs − L1)/(L2 − L1) = {a.extrapolation_factor:.3f} "
                  f"(indicator errors reach the grating ×{abs(1 - a.extrapolation_factor) + abs(a.extrapolation_factor):.2f})",
                  f"- residual (measured − predicted encoder error): RMS {a.residual_rms_arcsec}″"]
        if a.reversal_reference_arcsec is not None:
            lines.append(f"- reversal B = ↑ − ↓: {a.reversal_reference_arcsec:+.2f}″ from the autocollimator, "
                         f"{fmt(a.reversal_arcsec, '+.2f')}″ from the encoder")
        if a.repeatability_arcsec is not None:
            lines.append(f"- repeatability of εz over the runs (pooled 1σ): {a.repeatability_arcsec:.3f}″")
        lines += ["", "## Harmonics (significant: above the family-wise 1 % threshold, the readings' resolution and what "
                  "rounding alone produces)", "", "| series | order | amplitude | 1σ | phase / ° |", "|---|---|---|---|---|"]
        for name, terms in a.harmonics.items():
            for t in terms:
                if t.significant:
                    phase = "unknown (Nyquist)" if t.aliased else f"{t.phase_deg:.1f}"
                    lines.append(f"| {name} | {t.order} | {t.amplitude:.3f} | {t.amplitude_sigma:.3f} | {phase} |")
        for name, warns in a.harmonic_warnings.items():
            lines += [f"- {name}: {w}" for w in warns]
        lines.append("")
        closure = r.estimates.closure
        if closure is not None:
            lines += ["## Closure", "", f"Face errors and table errors separated from {len(closure.seating_offset_arcsec)} "
                      f"seatings; residual RMS {closure.residual_rms_arcsec}″; 1σ of a face error up to "
                      f"{fmt(largest(closure.face_uncertainty_arcsec), '.3f')}″.", "", "![closure](closure.png)", ""]
        lines += periodic_lines(r.periodic_error)
        lines += [f"![{n}]({n}.png)" for n in ("fig09_tilt_radial", "fig11_encoder_error", "fig12_residual",
                                                 "harmonics" if r.periodic_error is None else "periodic_error")]
        lines += ["", "## Notes", ""] + [f"- {n}" for n in a.notes] + [""]
        return lines

    def certificate_figures(self) -> list[tuple[str, str]]:
        figs = [("fig10_positioning.png", "angular positioning error εz against the autocollimator and polygon for "
                                          "each approach direction, with its U band (k = 2), and the stage encoder's reading."),
                ("fig09_tilt_radial.png", "tilt (left axis, ″) and radial motion (right axis, µm) of the shaft from the two "
                                          "dial indicators."),
                ("fig11_encoder_error.png", "encoder error, predicted from tilt and radial motion (Abbe) and "
                                            "measured; bars ±U (k = 2)."),
                ("fig12_residual.png", "measured − predicted encoder error; bars ±U (k = 2).")]
        if self.results.periodic_error is not None:
            figs.append(("periodic_error.png", "the fine-step test: mean deviation less the slow error of the arc per "
                                               "direction, the period's harmonics, one period shaded (ISO 230-2:2014 "
                                               "Annex C as rtcal reads it)."))
        if self.results.estimates.closure is not None:
            figs.append(("closure.png", "polygon face errors and table errors separated by closure, the table errors on "
                                        "the zero of Figure 1 (the first target); bars ±U (k = 2)."))
        return figs

    def iso230_1_errors(self) -> tuple[ErrorMotions | None, MeasuredLocation | None]:
        """The error motions the dial indicators measured, as a volumetric compensation takes them: EYC
        (radial motion in Y at the tilt centre, mm) and EAC (tilt about X, rad) per step, the two
        directions averaged and the mean over the turn removed (the indicators' zeros are arbitrary:
        the axis's location is not measured here). EXC and EBC are not measured (one plane)."""
        a = self.abbe
        per: dict[float, list[tuple[float, float]]] = {}
        for angle, t, y in zip(a.angle_deg, a.tilt_x_arcsec, a.radial_y_um):
            if t is not None and y is not None:
                per.setdefault(round(angle % 360.0, 6), []).append((t, y))
        if len(per) < 3:
            return None, None
        angles = np.array(sorted(per))
        tilt = np.array([np.mean([t for t, _ in per[k]]) for k in angles])
        radial = np.array([np.mean([y for _, y in per[k]]) for k in angles])
        r = self.results
        return ErrorMotions(angles, {"EYC": (radial - radial.mean()) * 1e-3, "EAC": (tilt - tilt.mean()) * RAD_PER_ARCSEC},
                            f"{Path(r.procedure.path).name or r.method} (encoder Abbe-error method, {r.started_utc or 'time not recorded'})",
                            "EYC radial motion in Y at the tilt centre, EAC tilt about X, from two dial indicators below "
                            "it (seed 001's model), both directions averaged, mean over the turn removed (the indicators' "
                            "zeros are arbitrary); EXC, EBC not measured (indicators in Y only)"), None

    def estimate_words(self) -> str:
        """The recommended estimate as the certificate names it."""
        return ("the autocollimator on the polygon" if (self.results.recommended or "abbe") == "abbe"
                else "the recommended estimate")

    def method_name(self) -> str:
        faces = len(self.abbe.face_errors_used_arcsec)
        reference = ("its face errors from the polygon's certificate" if self.abbe.polygon_source == "certificate"
                     else "its face errors separated from the table's by closure")
        return (f"Angular positioning deviation against an autocollimator on a {faces}-face optical polygon ({reference}); "
                "the stage encoder's Abbe error from the shaft's tilt and radial motion (two dial indicators)")

    def method_text(self) -> list[str]:
        a = self.abbe
        return [
            "The reference angle comes from an autocollimator on an optical polygon on the table (face errors from its "
            f"{a.polygon_source}); the positioning deviation is the autocollimator reading minus the face error, relative "
            "to the first target. Runs are kept apart; targets are approached from their own side past an overrun.",
            "Abbe analysis of the encoder: two dial indicators on the shaft separate tilt from radial motion, which predicts the "
            f"encoder's misreading (Δt/rE, extrapolation factor {a.extrapolation_factor:.3f}); the measured encoder error "
            "is encoder − reference.",
            f"Uncertainty (GUM): the random error per visit from {a.random_error_from}, the certificate's uncertainty per "
            "face, propagated exactly through the (linear) analysis.",
        ]

    def summary(self) -> list[str]:
        r, a = self.results, self.abbe
        rec, e = self._recommended()
        pred = [abs(v) for v in a.predicted_encoder_error_arcsec if v is not None] or [float("nan")]
        if isinstance(e, TargetedEstimate):
            dirs = len(set(e.target_direction))
            over = f"{len({round(t, 6) for t in e.target_deg})} targets" + (" × 2 directions" if dirs == 2 else "")
        else:
            over = f"{len(e.cumulative_deviation_arcsec)} targets"
        lines = [f"positioning deviation ECC ({rec}, recommended): {fmt(smallest(e.cumulative_deviation_arcsec), '+.2f')}″ … "
                 f"{fmt(largest(e.cumulative_deviation_arcsec), '+.2f')}″ over {over}, U (k = 2) up to "
                 f"{u_text(largest(e.cumulative_expanded_uncertainty_arcsec))}″"
                 + (f"; reversal {a.reversal_reference_arcsec:+.2f}″" if a.reversal_reference_arcsec is not None else ""),
                 f"encoder error predicted from tilt and radial motion: up to ±{max(pred):.2f}″; "
                 f"measured − predicted RMS {a.residual_rms_arcsec}″ (polygon from {a.polygon_source})"]
        for name, terms in (("positioning_error", a.harmonics.positioning_error_arcsec),
                            ("encoder_vs_command", a.harmonics.encoder_vs_command_arcsec)):
            sig = [t for t in terms or [] if t.significant]
            mixed = [t for t in terms or [] if t.not_separable_from]
            if sig:
                lines.append(f"{name}: significant harmonics "
                             + ", ".join(f"{t.order}× {t.amplitude:.2f}″" + (" (Nyquist: lower bound)" if t.aliased else "")
                                         for t in sig))
            if mixed:  # leakage of an order the targets cannot resolve (rtcal.solvers.harmonics: separability)
                lines.append(f"{name}: not separable at these targets (not significant): "
                             + ", ".join(f"{t.order}× {t.amplitude:.2f}″ ~ order {'/'.join(map(str, t.not_separable_from or []))}"
                                         for t in mixed))
        p = r.periodic_error
        if p is not None:
            lines.append(f"periodic positioning error (ISO 230-2:2014 Annex C, rtcal's reading): {p.periodic_error_arcsec:.2f}″ "
                         f"(U {u_text(p.expanded_uncertainty_arcsec)}″, k = 2) over {p.period_deg:g}°; ↑ "
                         f"{fmt(p.periodic_error_up_arcsec, '.2f')}″, ↓ {fmt(p.periodic_error_down_arcsec, '.2f')}″")
            found = [h for h in p.harmonics if h.significant]
            lines.append("harmonics of the period: " + (", ".join(f"{h.order}× ({period_words(h)}) {h.amplitude_arcsec:.2f}″"
                                                                  for h in found) or "none significant"))
        closure = r.estimates.closure
        if closure is not None:
            lines.append(f"closure: polygon face errors 1σ ≤ {fmt(largest(closure.face_uncertainty_arcsec), '.3f')}″, "
                         f"table errors 1σ ≤ {fmt(largest(closure.table_uncertainty_arcsec), '.3f')}″")
        return lines + status_lines(r)
