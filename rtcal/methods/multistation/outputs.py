"""The multi-station method's outputs (seed 000): deviations.csv, deviation.png, its report
sections and console summary, all from the typed results."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from rtcal.api import (RAD_PER_ARCSEC, ErrorMotions, Estimate, LocationErrors, MeasuredLocation, decimals, fmt, legend_below,
                       plt, round_up, significant, status_lines, u_text)
from rtcal.deliverables.certificate import largest
from rtcal.methods.multistation.results import MultistationResults
from rtcal.results.model import AXIS_CONVENTION, NetworkEstimate, PaperEstimate, StationChainEstimate

ESTIMATOR_LABELS = {
    "paper": "each station alone (as first published)",
    "shared_dead_path": "stations together (one dead path per tracking segment)",
    "network": "whole network (one circle, CMM solved)",
}


def _values(values: list[float | None]) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], float)


def expanded(u: float, scale: float = 1.0) -> tuple[str, int]:
    """U = 2u (times ``scale``) rounded up to two significant digits (GUM 7.2.6), and the decimals it has,
    to which the value is then rounded."""
    U = round_up(2.0 * u * scale)  # the one rounding of U (rtcal/deliverables/rounding.py)
    if U is None or not U > 0 or not math.isfinite(U):
        return "0", 0
    places = decimals(U)
    return f"{U:.{places}f}", places


def _with_u(value: float, u: float, scale: float = 1.0) -> tuple[str, str]:
    U, decimals = expanded(u, scale)
    return f"{value * scale:+.{decimals}f}", U


LOCATION_NOTE = ("ISO 230-7 location errors of the rotary axis from the network adjustment, " + AXIS_CONVENTION
                 + ". U expanded uncertainty (k = 2).")
MOTIONS_NOTE = ("Synchronous error motions per target from the second tracer mount (ISO 230-7): their mean and the "
                "once-per-turn part that turns with the table removed; EXC, EYC radial at the mounts' plane; EAC, EBC tilt "
                "about X and Y (right-hand). The tilt about the line joining the two mounts is not seen: its part of EAC, "
                "EBC is the procedure's stated bound, and so is its part of U. U expanded uncertainty (k = 2).")


def location_tables(results: MultistationResults) -> list[dict[str, Any]]:
    """The certificate's tables of the axis's location errors and (two mounts) error motions: each a
    heading, a note stating the convention, a header and rows (empty: no network estimate)."""
    if results.axis_location is None:
        return []
    loc = results.axis_location
    rows = []
    for symbol, meaning, v, u, unit, scale in (
            ("X0C", "X of the axis average line at z = 0", loc.x0c_mm, loc.x0c_mm_u, " µm", 1e3),
            ("Y0C", "Y of the axis average line at z = 0", loc.y0c_mm, loc.y0c_mm_u, " µm", 1e3),
            ("A0C", "squareness of the axis about X", loc.a0c_arcsec, loc.a0c_arcsec_u, "″", 1.0),
            ("B0C", "squareness of the axis about Y", loc.b0c_arcsec, loc.b0c_arcsec_u, "″", 1.0)):
        value, U = _with_u(v, u, scale)
        rows.append((symbol, meaning, f"{value}{unit}", f"{U}{unit}"))
    tables = [{"heading": "Location of the rotary axis (ISO 230-7)", "note": LOCATION_NOTE,
               "header": ["symbol", "meaning", "value", "U (k = 2)"], "rows": rows}]
    if results.error_motions:
        motion_rows = []
        for t in results.error_motions:
            cells = [f"{t.target_deg:g}"]
            for v, u in ((t.exc_um, t.exc_um_u), (t.eyc_um, t.eyc_um_u), (t.eac_arcsec, t.eac_arcsec_u),
                         (t.ebc_arcsec, t.ebc_arcsec_u)):
                cells.append(" ± ".join(_with_u(v, u)))
            motion_rows.append(tuple(cells))
        tables.append({"heading": "Error motions of the rotary axis per target (ISO 230-7)", "note": MOTIONS_NOTE,
                       "header": ["target / °", "EXC / µm ± U", "EYC / µm ± U", "EAC / ″ ± U", "EBC / ″ ± U"],
                       "rows": motion_rows})
    return tables


class MultistationOutputs:
    """What a multi-station run hands the user besides the files every run has."""

    def __init__(self, results: MultistationResults):
        self.results = results

    def iso230_1_errors(self) -> tuple[ErrorMotions | None, MeasuredLocation | None]:
        """The axis's location errors from the network (X0C, Y0C in mm, A0C, B0C in rad, CMM frame) and,
        with a second tracer mount, its error motions per target (EXC, EYC in mm, EAC, EBC in rad), as a
        volumetric compensation takes them."""
        r = self.results
        source = f"{Path(r.procedure.path).name or r.method} (laser-tracer multi-station method, {r.started_utc or 'time not recorded'})"
        motions = location = None
        if r.error_motions:
            t = r.error_motions
            values = {"EXC": np.array([m.exc_um for m in t]) * 1e-3, "EYC": np.array([m.eyc_um for m in t]) * 1e-3,
                      "EAC": np.array([m.eac_arcsec for m in t]) * RAD_PER_ARCSEC,
                      "EBC": np.array([m.ebc_arcsec for m in t]) * RAD_PER_ARCSEC}
            u = {"EXC": max(m.exc_um_u for m in t) * 1e-3, "EYC": max(m.eyc_um_u for m in t) * 1e-3,
                 "EAC": max(m.eac_arcsec_u for m in t) * RAD_PER_ARCSEC, "EBC": max(m.ebc_arcsec_u for m in t) * RAD_PER_ARCSEC}
            motions = ErrorMotions(np.array([m.target_deg % 360.0 for m in t]), values, source,
                                   "EXC, EYC radial at the tracer mounts' plane, EAC, EBC tilt about X and Y, their mean and "
                                   "the once-per-turn part that turns with the table removed (ISO 230-7); the tilt about "
                                   "the line joining the mounts is not seen", u)
        if r.axis_location is not None:
            loc = r.axis_location
            location = MeasuredLocation(LocationErrors.of({
                "X0C_um": (loc.x0c_mm * 1e3, loc.x0c_mm_u * 1e3), "Y0C_um": (loc.y0c_mm * 1e3, loc.y0c_mm_u * 1e3),
                "A0C_arcsec": (loc.a0c_arcsec, loc.a0c_arcsec_u), "B0C_arcsec": (loc.b0c_arcsec, loc.b0c_arcsec_u)},
                loc.frame), source)
        return motions, location

    def _by_recommended(self) -> list[tuple[str, Estimate]]:
        """Every estimate, the recommended one first."""
        return sorted(self.results.estimates.items(), key=lambda item: item[0] != self.results.recommended)

    def write_files(self, run_dir: Path) -> list[Path]:
        return [self.write_deviation_csv(run_dir), self.plot_deviation(run_dir)]

    def certificate_tables(self) -> list[dict[str, Any]]:
        """The axis's location errors and error motions (ISO 230-7)."""
        return location_tables(self.results)

    def write_deviation_csv(self, run_dir: Path) -> Path:
        """One row per station: nominal angle, then each estimator's cumulative and per-step deviation with 1σ."""
        r = self.results
        path = run_dir / "deviations.csv"
        estimates = r.estimates.items()
        truth = None if r.truth is None else r.truth.cumulative_deviation_arcsec
        header = ["station", "nominal_angle_deg"]
        for n, _ in estimates:
            header += [f"{n}_cumulative_arcsec", f"{n}_cumulative_u_arcsec", f"{n}_step_deviation_arcsec", f"{n}_step_u_arcsec"]
        if truth is not None:
            header.append("truth_cumulative_arcsec")
        with path.open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(header)
            for j, angle in enumerate(r.nominal_angles_deg):
                row: list[object] = [j + 1, angle]
                for _, e in estimates:
                    row += [e.cumulative_deviation_arcsec[j], e.cumulative_uncertainty_arcsec[j],
                            "" if j == 0 else e.deviation_arcsec[j - 1], "" if j == 0 else e.uncertainty_arcsec[j - 1]]
                if truth is not None:
                    row.append(round(truth[j], 4))
                w.writerow(row)
        return path

    def plot_deviation(self, run_dir: Path) -> Path:
        """Main panel: the cumulative deviation of every estimator, the recommended one with its U (k = 2)
        band; lower panel: the paper's per-step Δθ (eq. 33) with 1σ bars. Truth where simulated."""
        r = self.results
        angles = np.array(r.nominal_angles_deg, float)
        rec = r.recommended
        ordered = self._by_recommended()
        fig, (ax, ax2) = plt.subplots(2, 1, figsize=(8.5, 8.2), sharex=True, gridspec_kw={"height_ratios": [3, 2]},
                                      layout="constrained")
        for k, (name, est) in enumerate(ordered):
            cum, u = _values(est.cumulative_deviation_arcsec), _values(est.cumulative_uncertainty_arcsec)
            label = ESTIMATOR_LABELS.get(name, name)
            if name == rec:
                ax.fill_between(angles, cum - 2 * u, cum + 2 * u, color="C0", alpha=0.2, lw=0,
                                label=f"ECC, {label}: ±U (k = 2)")
                ax.plot(angles, cum, "o-", color="C0", lw=2, label=f"ECC, {label} — recommended")
            else:
                ax.errorbar(angles, cum, yerr=2 * u, fmt="s--", color=f"C{k + 1}", ms=4, lw=1, capsize=3,
                            label=f"ECC, {label}, bars ±U (k = 2)")
            step, su = _values(est.deviation_arcsec), _values(est.uncertainty_arcsec)
            offset = (k - (len(ordered) - 1) / 2) * 0.012 * (angles.max() - angles.min())
            ax2.errorbar(angles[1:] + offset, step, yerr=2 * su, fmt="o" if name == rec else "s", ms=4, capsize=3,
                         color="C0" if name == rec else f"C{k + 1}",
                         label=f"Δθ, {ESTIMATOR_LABELS.get(name, name)}, bars ±U (k = 2)")
        if r.truth is not None:
            ax.plot(angles, r.truth.cumulative_deviation_arcsec, "kx:", label="ECC, truth (simulated bench)")
            ax2.plot(angles[1:], r.truth.deviation_arcsec, "kx", label="Δθ, truth (simulated bench)")
        for a in (ax, ax2):
            a.axhline(0.0, color="0.6", lw=0.8)
            a.grid(alpha=0.3)
        ax.set_ylabel("cumulative positioning deviation ECC / ″\n(actual − commanded, relative to the first station)")
        ax2.set_ylabel("per-step deviation Δθ / ″\n(actual − nominal step)")
        ax2.set_xlabel("commanded table angle / °  (" + ("positive" if angles[-1] > angles[0] else "negative") + " approach)")
        ax2.set_xticks(angles, [f"{a:g}" for a in angles], fontsize=8)
        legend_below(fig)
        ax.set_title(r.procedure.name or r.method, fontsize=11)  # as written: figures.py reads no mathtext
        path = run_dir / "deviation.png"
        fig.savefig(path, dpi=120)
        plt.close(fig)
        return path

    def budget_table(self, est: Estimate) -> list[str]:
        """The uncertainty budget as a Markdown table: one row per source, one column per target."""
        angles = self.results.nominal_angles_deg
        b = est.uncertainty_budget
        head = "| source | type | input σ | " + " | ".join(f"{a:g}°" for a in angles[1:]) + " |"
        lines = [head, "|" + "---|" * (3 + len(angles) - 1)]
        for c in b.components:
            origin = " (from the data)" if c.estimated_from_data else ""
            cells = [c.source, c.type, f"{significant(c.input_sigma)} {c.unit}{origin}"]
            cells += [fmt(v, ".3f") for v in c.contribution_arcsec[1:]]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("| **combined u** | | | " + " | ".join(f"**{fmt(v, '.3f')}**" for v in b.combined_arcsec[1:]) + " |")
        lines.append("| **U (k = 2)** | | | " + " | ".join(f"**{fmt(v, '.3f')}**" for v in b.expanded_arcsec[1:]) + " |")
        lines.append("")
        lines += [f"- not included: {n}" for n in b.not_included]
        return lines + [""]

    def report_body(self) -> list[str]:
        """The recommended result first (cumulative deviation with U), then every estimator, the budget, the paper's gaps."""
        r = self.results
        angles = r.nominal_angles_deg
        rec = r.recommended
        ordered = self._by_recommended()
        truth = None if r.truth is None else r.truth.cumulative_deviation_arcsec
        lines = []
        e = r.recommended_estimate()
        if e is not None:
            lines += [f"## Result: cumulative positioning deviation ECC ({ESTIMATOR_LABELS.get(str(rec), str(rec))}, recommended)",
                      "", "Actual − commanded angle relative to the first station, arcsec; u standard uncertainty, "
                      "U expanded uncertainty (k = 2).", "",
                      "| station | commanded / ° | ECC / ″ | u / ″ | U (k = 2) / ″ |" + (" truth / ″ |" if truth else ""),
                      "|---|---|---|---|---|" + ("---|" if truth else "")]
            for j, a in enumerate(angles):
                cells = [f"P{j + 1}", f"{a:g}", fmt(e.cumulative_deviation_arcsec[j], "+.3f"),
                         fmt(e.cumulative_uncertainty_arcsec[j], ".3f"), fmt(e.cumulative_expanded_uncertainty_arcsec[j], ".3f")]
                if truth:
                    cells.append(f"{truth[j]:+.3f}")
                lines.append("| " + " | ".join(cells) + " |")
            lines += ["", "![deviation](deviation.png)", ""]
        names = [n for n, _ in ordered]
        lines += ["## Every estimator", "",
                  "| station | " + " | ".join(f"{n}: ECC / ″ (u)" for n in names) + " | "
                  + " | ".join(f"{n}: Δθ / ″ (u)" for n in names) + " |",
                  "|" + "---|" * (1 + 2 * len(names))]
        for j in range(len(angles)):
            cells = [f"P{j + 1}"]
            for _, est in ordered:
                cells.append(f"{fmt(est.cumulative_deviation_arcsec[j], '+.3f')} ({fmt(est.cumulative_uncertainty_arcsec[j], '.3f')})")
            for _, est in ordered:
                cells.append("" if j == 0 else f"{fmt(est.deviation_arcsec[j - 1], '+.3f')} ({fmt(est.uncertainty_arcsec[j - 1], '.3f')})")
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
        for n, est in ordered:
            st = r.solver_status[n]
            if not isinstance(est, (StationChainEstimate, NetworkEstimate)):
                continue
            noise = est.estimated_noise
            said = (f"noise estimated from the readings: tracer {noise.tracer_length_noise_um_at_1m:.3f} µm at 1 m, "
                    f"CMM points {noise.cmm_point_noise_um:.3f} µm")
            if isinstance(est, StationChainEstimate):
                lines.append(f"- {n}: {st.status} ({st.message}); σΔθ = {est.eq34_sigma_arcsec:.2f}″ is the paper's "
                             f"eq. 34 statistic of the deviations, not an uncertainty; algorithm error (eq. 36) "
                             f"{est.algorithm_error_arcsec:.2e}″; {said}")
            else:
                cmm = ", ".join(f"{k} {v.value:+.3f} ± {fmt(v.sigma, '.3f')}" for k, v in est.cmm_errors.items())
                lines.append(f"- {n}: {st.status} ({st.message}); {said}; the CMM's errors found (1σ): {cmm}")
        for n, failed in r.solver_status.items():
            if failed.status == "failed":
                lines.append(f"- {n}: **failed** — {failed.message}")
        lines += ["", "`paper` is the printed method (one dead path per station); `shared_dead_path` solves all stations "
                  "together with one dead path per uninterrupted tracking segment; `network` adjusts everything at once: the "
                  "stations on one circle about one axis (one angle each), the CMM points as observations weighted by their "
                  "noise, and the CMM's scales and squarenesses.", ""]
        net = r.estimates.network
        if net is not None:
            lines += ["## The CMM, checked by the network adjustment", "",
                      "Scale and squareness errors of the CMM found from the traceable tracer lengths (1σ):", "",
                      "| parameter | value | 1σ |", "|---|---|---|"]
            lines += [f"| {k} | {v.value:+.3f} | {fmt(v.sigma, '.3f')} |" for k, v in net.cmm_errors.items()] + [""]
            em = net.error_motions
            if em is not None:
                lines += ["## Error motions, separated by the second tracer mount", "", em.note[0].upper() + em.note[1:] + ".", "",
                          "| station | angle / ° | EXC / µm (1σ) | EYC / µm (1σ) | tilt / ″ (1σ) | tilt axis / ° |",
                          "|---|---|---|---|---|---|"]
                for j, a in enumerate(angles):
                    lines.append(f"| P{j + 1} | {a:g} | {em.EXC_um[j]:+.3f} ({em.EXC_sigma_um[j]:.3f}) | "
                                 f"{em.EYC_um[j]:+.3f} ({em.EYC_sigma_um[j]:.3f}) | "
                                 f"{em.tilt_arcsec[j]:+.2f} ({em.tilt_sigma_arcsec[j]:.2f}) | "
                                 f"{em.tilt_axis_deg[j]:.0f} |")
                lines.append("")
        for t in location_tables(r):
            lines += [f"## {t['heading']}", "", t["note"], "", "| " + " | ".join(t["header"]) + " |",
                      "|" + "---|" * len(t["header"])] + ["| " + " | ".join(row) + " |" for row in t["rows"]] + [""]
        if e is not None:
            lines += [f"## Uncertainty budget of the cumulative deviation ({rec}), contributions u / ″ per station", ""]
            lines += self.budget_table(e)
        paper = r.estimates.paper
        notes = paper.notes if isinstance(paper, PaperEstimate) else []
        if notes:
            lines += ["## Where the printed equations and the paper's figures differ", ""] + [f"- {n}" for n in notes] + [""]
        return lines

    def certificate_figures(self) -> list[tuple[str, str]]:
        return [("deviation.png", "Cumulative positioning deviation ECC from each way of solving the stations (the "
                                  "recommended one with its U band) and the deviation of each step Δθ (actual − nominal "
                                  "step); every band and bar is ±U (k = 2).")]

    def estimate_words(self) -> str:
        """The recommended estimate as the certificate names it."""
        return {"paper": "each station solved on its own, as the method was first published",
                "shared_dead_path": "all stations solved together, one tracer dead path per tracking segment",
                "network": "one adjustment of the whole network (axis, stations, CMM points and CMM geometry)"}.get(
                    self.results.recommended or "", "the recommended estimate")

    def method_name(self) -> str:
        return ("Laser tracer multi-station method: a laser tracer on the table, its reflector moved through points by a "
                "CMM while the table indexes through the stations; the stations self-calibrated from the tracer's "
                "interferometric lengths")

    def method_text(self) -> list[str]:
        rec = self.results.recommended
        return [
            "Laser tracer multi-station method: the laser tracer sits on the table; a CMM moves its cat-eye reflector through "
            "a set of points while the table indexes through the stations, and the tracer measures interferometric lengths. "
            "The tracer's reference centre at each station is self-calibrated from the lengths; the stations lie on a circle "
            "about the rotation axis, and the angle between them gives the positioning deviation.",
            "The stations are solved in up to three ways: each station on its own as the method was first published (one "
            "dead path per station, then a plane and a circle through the centres); all stations together with one tracer "
            "dead path per tracking segment; and one adjustment of the whole network (axis, radius, station angles, the "
            "CMM points as weighted observations, the CMM's scales and squarenesses). The certificate quotes the one that "
            f"converged with the smallest uncertainty: {self.estimate_words()}. Each estimate's residuals are tested "
            "against its whole budget; a failure is stated with the quoted estimate, never answered by quoting another, "
            "which shares the readings and the budget's assumptions.",
            "Uncertainty (GUM): the tracer's and the CMM's noise are estimated from the readings (Type A); stage "
            "repeatability, CMM geometry, error motions and the air's refractive index as the procedure states them "
            "(Type B); all propagated through the estimator with their correlations.",
            *self._room_paragraph(),
        ]

    def _room_paragraph(self) -> list[str]:
        """Where the budget allows for the room and the tracer beyond the sensors' readings (the lines it carries)."""
        e = self.results.recommended_estimate()
        names = {c.source for c in e.uncertainty_budget.components} if e is not None else set()
        parts = []
        if any(n.startswith("thermal expansion: temperature probe on the tracer's mount") for n in names):
            parts.append("a second probe on the tracer's mount reads the region that carries the tracer: the lengths are "
                         "corrected with its temperature, not the table sensor's, so a gradient between the two is "
                         "measured rather than budgeted (the probe's stated uncertainty and noise are its lines; a "
                         "gradient it cannot see, within the mount, is budgeted only where a share is stated)")
        if any(n.startswith("thermal expansion: the tracer's mount against") for n in names):
            parts.append("the table's sensor does not sit where the tracer is mounted: the mount's temperature change may "
                         "differ from the sensor's by the stated share (or ±50 % when none is stated), a line of its own; "
                         "where the sensor reads the table change by 0.2 K or more over the run, the estimates that solve "
                         "all stations together and the whole network solve the table's growth per sensed kelvin from the readings (another material "
                         "than the α assumed, or such a gradient, moves the stations in a pattern the lengths "
                         "determine), and these lines then contribute only what the solution leaves; a gradient that "
                         "changes while the sensor's reading does not is not included")
        sphere = [n for n in names if n.startswith("laser tracer reference sphere form")]
        if sphere:
            within = ("as its certificate's map says, the lengths corrected by the map and only its uncertainty left"
                      if "map" in sphere[0] else "within its tracer's specified class (assumed, not stated)"
                      if sphere[0].endswith("assumed") else "within its stated form")
            parts.append(f"the tracer's reference sphere is out of round {within}, fixed to the tracer's "
                         "base that turns with the table, so each station reads the points through another part of it "
                         "(a direction-dependent systematic of the tracer)")
        if not parts:
            return []
        return ["Beyond the sensors' readings the budget allows for: " + "; ".join(parts) + "."]

    def summary(self) -> list[str]:
        """The console: the recommended cumulative deviation with U, then what did not converge."""
        r = self.results
        lines = []
        e = r.recommended_estimate()
        if e is not None:
            cum = ", ".join(fmt(v, "+.2f") for v in e.cumulative_deviation_arcsec)
            lines.append(f"cumulative positioning deviation ECC (arcsec, {r.recommended}, recommended): {cum}")
            lines.append(f"expanded uncertainty U (k = 2) up to {u_text(largest(e.cumulative_expanded_uncertainty_arcsec))}″")
            lines += [f"assumed: {c.source}" for c in e.uncertainty_budget.components if c.source.endswith("assumed")]
            test = getattr(e, "residual_test", None)
            if test is not None and not test.passed:  # quoted, with what its U leaves out (never another instead)
                lines.append(f"{r.recommended} FAILS its residual test (p = {test.p_value:.2g}): its U is not a coverage "
                             "interval for the error the residuals show; the certificate says so")
        for name, est in r.estimates.items():
            if name != r.recommended:
                lines.append(f"also {name}: U (k = 2) up to {u_text(largest(est.cumulative_expanded_uncertainty_arcsec))}″")
        loc = r.axis_location
        if loc is not None:
            parts = [f"{sym} {' ± '.join(_with_u(v, u, scale))}{unit}" for sym, v, u, unit, scale in (
                ("X0C", loc.x0c_mm, loc.x0c_mm_u, " µm", 1e3), ("Y0C", loc.y0c_mm, loc.y0c_mm_u, " µm", 1e3),
                ("A0C", loc.a0c_arcsec, loc.a0c_arcsec_u, "″", 1.0), ("B0C", loc.b0c_arcsec, loc.b0c_arcsec_u, "″", 1.0))]
            lines.append("axis location (ISO 230-7, CMM frame, ± U): " + ", ".join(parts))
        return lines + status_lines(r)
