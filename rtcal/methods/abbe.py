"""The encoder Abbe-error method (seed 001): measure, analyse, write files, report."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

from drivers import factory
from rtcal.run.dataset import abbe_visits
from rtcal.deliverables.deviations import PositioningDeviations
from rtcal.procedure.models import EncoderAbbeError
from rtcal.methods.estimates import finite_or_none
from rtcal.deliverables.figures import plt
from rtcal.methods.estimates import (
    choose_recommended,
    deviation_block,
    run_estimators,
    status_lines,
)
from rtcal.sequencer.abbe import AbbeInstrumentSet, planned_visits, run_abbe
from rtcal.solvers.abbe import (
    AbbeEstimate,
    AbbeNoise,
    AbbeSetup,
    analyse_abbe,
    steps_within_directions,
)
from rtcal.solvers.harmonics import HarmonicFit
from rtcal.solvers.uncertainty import BudgetComponent, DeviationBudget
from rtcal.run.store import RunStore
from simulators.bench import Bench
from simulators.instruments import (
    SimAutocollimator,
    SimDialIndicator,
    SimEncoder,
    SimStage,
)
from simulators.scenario import Scenario
from simulators.truth import abbe_truth

NOTES = (
    "Seed 001's equations (1) and (2) are missing from its text; rtcal uses the model its words give: "
    "tangential grating shift Δt = δy + Zs·εx and encoder error Δt/rE (positive: the encoder reads more).",
    "Indicator, encoder and autocollimator zeros are arbitrary but constant while the polygon stays seated: encoder "
    "errors are given up to one constant per seating (mean over the faces removed, the same for both directions); "
    "εz relative to the first target of the first direction, so that the reversal between directions shows.",
)


def draw_systematics(proc: EncoderAbbeError, scenario: Scenario, rng: np.random.Generator) -> Scenario:
    """Nothing systematic to draw: the polygon's certificate error is drawn afresh with each
    trial's seed (the bench's certificate is truth plus its stated uncertainty)."""
    return scenario


def target_labels(results: dict[str, Any]) -> list[str]:
    a = results["estimates"][results["recommended"]]
    return [f"{t:g}{'↑' if d > 0 else '↓'}" for t, d in zip(a["target_deg"], a["target_direction"])]


def plan_length(proc: EncoderAbbeError) -> int:
    return len(planned_visits(proc))


def sim_instruments(proc: EncoderAbbeError, bench: Bench) -> AbbeInstrumentSet:
    return AbbeInstrumentSet(SimStage(bench), SimEncoder(bench), SimAutocollimator(bench),
                             (SimDialIndicator(bench, 0), SimDialIndicator(bench, 1)))


def transport_instruments(proc: EncoderAbbeError) -> AbbeInstrumentSet:
    i = proc.instruments
    return AbbeInstrumentSet(
        factory.open_stage(i.stage.address, i.stage.soft_limits_deg, i.stage.timeout_s),
        factory.open_encoder(i.encoder.address, i.encoder.timeout_s),
        factory.open_autocollimator(i.autocollimator.address, i.autocollimator.timeout_s),
        (factory.open_dial_indicator(i.dial_indicator_1.address, "dial_indicator_1", i.dial_indicator_1.timeout_s),
         factory.open_dial_indicator(i.dial_indicator_2.address, "dial_indicator_2", i.dial_indicator_2.timeout_s)),
    )


def prepare(proc: EncoderAbbeError, operator) -> dict[str, str]:
    """Before any motion: fix the polygon certificate; the store records it for the analysis."""
    return {"polygon_certificate_arcsec": json.dumps(resolve_certificate(proc, operator))}


def measure(proc: EncoderAbbeError, inst: AbbeInstrumentSet, store: RunStore, clock, operator, progress,
            generation: int = 0) -> None:
    run_abbe(proc, inst, store, clock, operator, progress, generation)


class CertificateUnavailable(Exception):
    """``certificate_arcsec: bench`` on a bench that cannot hand one over (hardware)."""


def resolve_certificate(proc: EncoderAbbeError, operator) -> list[float] | None:
    """The face errors the analysis will use, fixed before the first motion (None: closure)."""
    cert = proc.polygon.certificate_arcsec
    if cert == "none":
        return None
    if cert == "bench":
        values = operator.polygon_certificate_arcsec()
        if values is None:
            raise CertificateUnavailable("polygon.certificate_arcsec: `bench` takes a simulated polygon's certificate; "
                                         f"on hardware list the certificate's {proc.polygon.faces} face errors (arcsec)")
        if len(values) != proc.polygon.faces:
            raise CertificateUnavailable(f"the bench's polygon has {len(values)} faces, the procedure {proc.polygon.faces}")
        return [float(v) for v in values]
    return [float(v) for v in cert]


def harmonics_dict(fit: HarmonicFit) -> list[dict[str, Any]]:
    return [{"order": t.order, "amplitude": round(t.amplitude, 4), "amplitude_sigma": round(t.amplitude_sigma, 4),
             "phase_deg": round(float(np.degrees(t.phase_rad)), 3), "phase_sigma_deg": round(float(np.degrees(t.phase_sigma_rad)), 3),
             "significant": bool(t.significant), "threshold": round(t.threshold, 4), "aliased": t.aliased} for t in fit.terms]


def noise_model(proc: EncoderAbbeError, estimate: bool = True) -> AbbeNoise:
    u = proc.uncertainty
    return AbbeNoise(u.autocollimator_noise_arcsec, u.autocollimator_resolution_arcsec, u.stage_repeatability_arcsec,
                     u.encoder_noise_arcsec, u.encoder_resolution_arcsec, u.indicator_noise_um, u.indicator_resolution_um,
                     proc.polygon.certificate_uncertainty_arcsec, estimate)


def not_included(proc: EncoderAbbeError) -> list[str]:
    u, out = proc.uncertainty, []
    if proc.steps.runs < 2 and proc.polygon.certificate_arcsec != "none":
        if u.autocollimator_noise_arcsec == 0 and u.stage_repeatability_arcsec == 0:
            out.append("autocollimator noise and stage repeatability: not stated (uncertainty section) and one run "
                       "cannot estimate them")
    if proc.polygon.certificate_arcsec != "none" and proc.polygon.certificate_uncertainty_arcsec == 0:
        out.append("polygon certificate: no uncertainty stated (polygon.certificate_uncertainty_arcsec)")
    return out


def estimate_dict(est: AbbeEstimate, source: str, omitted: list[str]) -> dict[str, Any]:
    residual = est.residual_arcsec[np.isfinite(est.residual_arcsec)]
    ref = est.reference
    return {
        "target_deg": [round(float(a), 6) for a in ref.target_deg],
        "target_direction": [int(d) for d in ref.direction],
        **deviation_block(ref.cumulative_arcsec, ref.budget, ref.steps, omitted),
        "random_error_from": ref.random_source,
        "converged": True,  # a linear estimate: nothing to iterate
        "message": "linear least squares",
        "angle_deg": [round(float(a), 6) for a in est.angle_deg],
        "direction": [int(d) for d in est.direction],
        "tilt_x_arcsec": finite_or_none(est.tilt_x_arcsec),
        "radial_y_um": finite_or_none(est.radial_y_um),
        "predicted_encoder_error_arcsec": finite_or_none(est.predicted_encoder_error_arcsec),
        "predicted_encoder_error_sigma_arcsec": finite_or_none(est.predicted_sigma_arcsec),
        "measured_encoder_error_arcsec": finite_or_none(est.measured_encoder_error_arcsec),
        "measured_encoder_error_sigma_arcsec": finite_or_none(est.measured_sigma_arcsec),
        "residual_arcsec": finite_or_none(est.residual_arcsec),
        "residual_sigma_arcsec": finite_or_none(est.residual_sigma_arcsec),
        "positioning_error_arcsec": finite_or_none(est.positioning_error_arcsec),
        "positioning_error_sigma_arcsec": finite_or_none(est.positioning_sigma_arcsec),
        "encoder_vs_command_arcsec": finite_or_none(est.encoder_vs_command_arcsec),
        "residual_rms_arcsec": round(float(np.sqrt(np.mean(residual**2))), 4) if residual.size else None,
        "reversal_arcsec": None if est.reversal_arcsec is None else round(est.reversal_arcsec, 4),
        "reversal_reference_arcsec": None if est.reversal_reference_arcsec is None else round(est.reversal_reference_arcsec, 4),
        "repeatability_arcsec": None if est.repeatability_arcsec is None else round(est.repeatability_arcsec, 4),
        "extrapolation_factor": round(est.extrapolation_factor, 6),
        "face_errors_used_arcsec": finite_or_none(est.face_error_arcsec),
        "polygon_source": source,
        "harmonics": {name: harmonics_dict(fit) for name, fit in est.harmonics.items()},
        "harmonic_warnings": {name: fit.warnings for name, fit in est.harmonics.items() if fit.warnings},
        "notes": list(NOTES),
    }


def closure_dict(est: AbbeEstimate) -> dict[str, Any]:
    """The closure's own table errors, referred to the first target like every estimate (with the
    per-visit random error the analysis used: the closure residuals', or the stated one)."""
    c = est.closure
    sigma = est.random_sigma_arcsec
    n_t = len(c.table_error)
    ref = 0  # keys are sorted positive direction first, then by angle
    R = np.eye(n_t) - np.outer(np.ones(n_t), np.eye(n_t)[ref])
    cov = sigma**2 * (R @ c.solution_map[:n_t]) @ (R @ c.solution_map[:n_t]).T
    estimated = est.random_sigma_type == "A"
    budget = DeviationBudget([BudgetComponent("closure residuals (autocollimator, repeatability)" if estimated else
                                              "autocollimator and stage, as stated", "A" if estimated else "B", sigma, "″",
                                              cov, estimated, "per reading")])
    dirs = np.asarray(est.closure_table_direction)
    return {
        "target_deg": [round(float(a), 6) for a in est.closure_table_angle_deg],
        "target_direction": [int(d) for d in dirs],
        **deviation_block(R @ c.table_error, budget, steps_within_directions(dirs)),
        "converged": True,
        "message": "linear least squares with closure constraints",
        "table_angle_deg": [round(float(a), 6) for a in est.closure_table_angle_deg],
        "direction": [int(d) for d in dirs],
        "table_error_arcsec": finite_or_none(c.table_error),
        "table_uncertainty_arcsec": finite_or_none(c.table_sigma),
        "face_error_arcsec": finite_or_none(c.face_error),
        "face_uncertainty_arcsec": finite_or_none(c.face_sigma),
        "seating_offset_arcsec": finite_or_none(c.offsets),
        "residual_rms_arcsec": round(c.residual_rms, 4),
    }


def analyse(proc: EncoderAbbeError, store: RunStore, bench: Bench | None, estimate_noise: bool = True) -> dict[str, Any]:
    visits = abbe_visits(store, proc.polygon.seatings_deg)
    recorded = json.loads(store.meta().get("polygon_certificate_arcsec", "null"))
    cert = None if recorded is None else np.asarray(recorded, float)
    setup = AbbeSetup(proc.polygon.faces, proc.geometry.indicator_heights_mm, proc.geometry.grating_offset_mm,
                      proc.geometry.encoder_radius_mm, cert, proc.max_harmonic_order, noise_model(proc, estimate_noise))
    omitted = not_included(proc)
    holder: dict[str, AbbeEstimate] = {}

    def abbe() -> dict[str, Any]:
        holder["est"] = analyse_abbe(visits, setup)
        return estimate_dict(holder["est"], "closure" if cert is None else "certificate", omitted)

    solvers = {"abbe": abbe}
    if cert is None:
        solvers["closure"] = lambda: closure_dict(holder["est"])
    estimates, status = run_estimators(solvers)
    recommended = choose_recommended(estimates, status)
    out: dict[str, Any] = {
        "nominal_angles_deg": estimates["abbe"]["angle_deg"] if "abbe" in estimates else [],
        "raw_readings": len(store.done_plan_indices()),  # visits taken whole (as multistation counts); skipped ones apart
        "recommended": recommended,
        "solver_status": status,
        "estimates": estimates,
    }
    if "est" in holder:
        ref = holder["est"].reference
        out["positioning_deviations"] = PositioningDeviations(
            ref.rows_target_deg, ref.rows_direction, ref.rows_run, ref.rows_arcsec, ref.rows_uncertainty_arcsec,
            estimator="abbe", notes=(f"εz from the autocollimator on the polygon ({'closure' if cert is None else 'certificate'}), "
                                     "relative to the first target of the first direction",)).to_dict()
    if bench is not None and "abbe" in estimates:
        a = estimates["abbe"]
        out["truth"] = abbe_truth(bench, np.array(a["angle_deg"]), np.array(a["direction"]),
                                  np.array(a["target_deg"]), np.array(a["target_direction"]))
    return out


def _series(results: dict[str, Any], key: str, direction: int) -> tuple[np.ndarray, np.ndarray]:
    a = results["estimates"]["abbe"]
    sel = [i for i, d in enumerate(a["direction"]) if d == direction]
    x = np.array([a["angle_deg"][i] for i in sel])
    y = np.array([np.nan if a[key][i] is None else a[key][i] for i in sel], dtype=float)
    return x, y


def _directions(results: dict[str, Any]) -> list[int]:
    return sorted(set(results["estimates"]["abbe"]["direction"]), reverse=True)


def _figure(run_dir: Path, name: str, draw) -> Path:
    fig, ax = plt.subplots(figsize=(8, 4.2))
    draw(ax)
    ax.set_xlabel("table angle / °")
    ax.set_xlim(0, 360)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = run_dir / name
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_files(run_dir: Path, results: dict[str, Any]) -> list[Path]:
    """abbe_steps.csv and figures in the manner of seed 001's Figures 9–12, plus harmonics and closure."""
    a = results["estimates"]["abbe"]
    keys = ["angle_deg", "direction", "tilt_x_arcsec", "radial_y_um", "predicted_encoder_error_arcsec",
            "measured_encoder_error_arcsec", "residual_arcsec", "positioning_error_arcsec", "encoder_vs_command_arcsec"]
    csv_path = run_dir / "abbe_steps.csv"
    with csv_path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(keys)
        for i in range(len(a["angle_deg"])):
            w.writerow(["" if a[k][i] is None else a[k][i] for k in keys])
    dirs = _directions(results)
    tag = {1: "↑", -1: "↓"}

    def fig9(ax):
        for d in dirs:
            ax.plot(*_series(results, "tilt_x_arcsec", d), marker=".", label=f"tilt εx / ″ {tag[d]}")
            ax.plot(*_series(results, "radial_y_um", d), marker=".", ls="--", label=f"radial δy / µm {tag[d]}")
        ax.set_title("Fig. 9 — tilt motion about X and radial motion in Y (from the dial indicators)")

    def fig10(ax):
        enc_zero = None
        for k, d in enumerate(dirs):
            x, y = _series(results, "positioning_error_arcsec", d)
            _, u = _series(results, "positioning_error_sigma_arcsec", d)
            ok = np.isfinite(y)
            ax.fill_between(x[ok], (y - 2 * u)[ok], (y + 2 * u)[ok], color=f"C{2 * k}", alpha=0.2, lw=0,
                            label=f"εz {tag[d]} ±U (k = 2)")
            ax.plot(x[ok], y[ok], marker="o", color=f"C{2 * k}", label=f"εz (autocollimator + polygon) {tag[d]}")
            xe, ye = _series(results, "encoder_vs_command_arcsec", d)
            if enc_zero is None:  # the encoder's zero is arbitrary: refer it to the same first target
                first = x[ok][0]
                enc_zero = ye[np.argmin(np.abs(xe - first))]
            ax.plot(xe, ye - enc_zero, marker=".", ls="--", lw=0.8, color=f"C{2 * k + 1}", label=f"encoder − command {tag[d]}")
        rev = a.get("reversal_reference_arcsec")
        ax.set_ylabel("εz (ECC) / ″, relative to the first target")
        ax.set_title("Fig. 10 — angular positioning error" + (f"; reversal ↑ − ↓ = {rev:+.2f}″" if rev is not None else ""))

    def fig11(ax):
        for k, d in enumerate(dirs):
            x, y = _series(results, "predicted_encoder_error_arcsec", d)
            _, u = _series(results, "predicted_encoder_error_sigma_arcsec", d)
            ax.errorbar(x, y, yerr=u, fmt=".-", capsize=2, lw=0.8, color=f"C{2 * k}", label=f"predicted (δy + Zs·εx)/rE {tag[d]}, ±1σ")
            x, y = _series(results, "measured_encoder_error_arcsec", d)
            _, u = _series(results, "measured_encoder_error_sigma_arcsec", d)
            ok = np.isfinite(y)
            ax.errorbar(x[ok], y[ok], yerr=u[ok], fmt="o", capsize=2, color=f"C{2 * k + 1}",
                        label=f"measured (encoder − reference) {tag[d]}, ±1σ")
        ax.set_ylabel("encoder error / ″ (mean over the faces removed)")
        ax.set_title("Fig. 11 — predicted and measured encoder error")

    def fig12(ax):
        for k, d in enumerate(dirs):
            x, y = _series(results, "residual_arcsec", d)
            _, u = _series(results, "residual_sigma_arcsec", d)
            ok = np.isfinite(y)
            ax.errorbar(x[ok], y[ok], yerr=2 * u[ok], fmt="o", capsize=2, color=f"C{2 * k}",
                        label=f"measured − predicted {tag[d]}, ±2σ")
        ax.axhline(0, color="0.6", lw=0.8)
        ax.set_ylabel("residual / ″")
        ax.set_title(f"Fig. 12 — residual (RMS {a['residual_rms_arcsec']}″)")

    paths = [csv_path] + [_figure(run_dir, n, f) for n, f in (("fig09_tilt_radial.png", fig9), ("fig10_positioning.png", fig10),
                                                              ("fig11_encoder_error.png", fig11), ("fig12_residual.png", fig12))]
    fig, ax = plt.subplots(figsize=(8, 4.2))
    series = [s for s in ("positioning_error_arcsec", "encoder_vs_command_arcsec", "measured_encoder_error_arcsec",
                          "predicted_encoder_error_arcsec") if s in a["harmonics"]]
    width = 0.8 / max(len(series), 1)
    for k, s in enumerate(series):
        terms = a["harmonics"][s]
        ax.bar([t["order"] + (k - len(series) / 2 + 0.5) * width for t in terms], [t["amplitude"] for t in terms],
               width, yerr=[t["amplitude_sigma"] for t in terms], label=s.removesuffix("_arcsec"))
    ax.set_xlabel("harmonic order (per revolution)")
    ax.set_ylabel("amplitude / arcsec")
    ax.set_title("Harmonic analysis")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(run_dir / "harmonics.png", dpi=110)
    plt.close(fig)
    paths.append(run_dir / "harmonics.png")
    if "closure" in results["estimates"]:
        c = results["estimates"]["closure"]
        fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 6))
        ax1.errorbar(range(len(c["face_error_arcsec"])), c["face_error_arcsec"], yerr=c["face_uncertainty_arcsec"], marker="o", capsize=3)
        ax1.set_xlabel("polygon face")
        ax1.set_ylabel("face error / ″")
        for d in sorted(set(c["direction"]), reverse=True):
            sel = [i for i, x in enumerate(c["direction"]) if x == d]
            ax2.errorbar([c["table_angle_deg"][i] for i in sel], [c["table_error_arcsec"][i] for i in sel],
                         yerr=[c["table_uncertainty_arcsec"][i] for i in sel], marker="o", capsize=3, label=tag[d])
        ax2.set_xlabel("table angle / °")
        ax2.set_ylabel("table error εz / ″")
        ax2.legend()
        ax1.set_title("Closure: polygon face errors and table errors, separated (1σ)")
        fig.tight_layout()
        fig.savefig(run_dir / "closure.png", dpi=110)
        plt.close(fig)
        paths.append(run_dir / "closure.png")
    return paths


def report_body(results: dict[str, Any]) -> list[str]:
    """The recommended εz per target and direction with u and U first, then the budget, the
    encoder analysis, harmonics and closure."""
    a = results["estimates"]["abbe"]
    rec = results.get("recommended") or "abbe"
    e = results["estimates"][rec]
    truth = results.get("truth", {}).get("cumulative_deviation_arcsec") if rec == "abbe" else None
    lines = [f"## Result: angular positioning deviation ECC ({rec}, recommended)", "",
             "εz = actual − commanded angle, relative to the first target of the first direction, arcsec; u standard "
             "uncertainty, U expanded uncertainty (k = 2); ↑ positive, ↓ negative approach.", "",
             "| target / ° | direction | ECC / ″ | u / ″ | U (k = 2) / ″ |" + (" truth / ″ |" if truth else ""),
             "|---|---|---|---|---|" + ("---|" if truth else "")]
    for j, (t, d) in enumerate(zip(e["target_deg"], e["target_direction"])):
        cells = [f"{t:g}", "↑" if d > 0 else "↓", f"{e['cumulative_deviation_arcsec'][j]:+.3f}",
                 f"{e['cumulative_uncertainty_arcsec'][j]:.3f}", f"{e['cumulative_expanded_uncertainty_arcsec'][j]:.3f}"]
        if truth:
            cells.append(f"{truth[j]:+.3f}")
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "![fig10](fig10_positioning.png)", "", "## Uncertainty budget (contributions u / ″; first and largest targets)", ""]
    b = e["uncertainty_budget"]
    worst = int(np.argmax(b["combined_arcsec"]))
    lines += ["| source | type | input σ | at the largest u | RMS over targets |", "|---|---|---|---|---|"]
    for c in b["components"]:
        contrib = np.array(c["contribution_arcsec"], float)
        origin = " (from the data)" if c["estimated_from_data"] else ""
        lines.append(f"| {c['source']} | {c['type']} | {c['input_sigma']:.3g} {c['unit']}{origin} | {contrib[worst]:.3f} | "
                     f"{float(np.sqrt(np.mean(contrib[1:] ** 2))):.3f} |")
    comb = np.array(b["combined_arcsec"], float)
    lines += [f"| **combined u** | | | **{comb[worst]:.3f}** | **{float(np.sqrt(np.mean(comb[1:] ** 2))):.3f}** |", ""]
    lines += [f"- not included: {n}" for n in b["not_included"]] + [""]
    lines += ["## Encoder error (seed 001)", "",
              f"- polygon face errors from: {a['polygon_source']}; random error of the reference from: {a['random_error_from']}",
              f"- extrapolation factor a = (Zs − L1)/(L2 − L1) = {a['extrapolation_factor']:.3f} "
              f"(indicator errors reach the grating ×{abs(1 - a['extrapolation_factor']) + abs(a['extrapolation_factor']):.2f})",
              f"- residual (measured − predicted encoder error): RMS {a['residual_rms_arcsec']}″"]
    if a["reversal_reference_arcsec"] is not None:
        lines.append(f"- reversal B = ↑ − ↓: {a['reversal_reference_arcsec']:+.2f}″ from the autocollimator, "
                     f"{a['reversal_arcsec']:+.2f}″ from the encoder")
    if a.get("repeatability_arcsec") is not None:
        lines.append(f"- repeatability of εz over the runs (pooled 1σ): {a['repeatability_arcsec']:.3f}″")
    lines += ["", "## Harmonics (significant: above the family-wise 1 % threshold, the readings' resolution and what "
              "rounding alone produces)", "", "| series | order | amplitude | 1σ | phase / ° |", "|---|---|---|---|---|"]
    for name, terms in a["harmonics"].items():
        for t in terms:
            if t["significant"]:
                phase = "unknown (Nyquist)" if t.get("aliased") else f"{t['phase_deg']:.1f}"
                lines.append(f"| {name} | {t['order']} | {t['amplitude']:.3f} | {t['amplitude_sigma']:.3f} | {phase} |")
    for name, warns in a.get("harmonic_warnings", {}).items():
        lines += [f"- {name}: {w}" for w in warns]
    lines.append("")
    if "closure" in results["estimates"]:
        c = results["estimates"]["closure"]
        lines += ["## Closure", "", f"Face errors and table errors separated from {len(c['seating_offset_arcsec'])} "
                  f"seatings; residual RMS {c['residual_rms_arcsec']}″; 1σ of a face error up to "
                  f"{max(c['face_uncertainty_arcsec']):.3f}″.", "", "![closure](closure.png)", ""]
    lines += [f"![{n}]({n}.png)" for n in ("fig09_tilt_radial", "fig11_encoder_error", "fig12_residual", "harmonics")]
    lines += ["", "## Notes", ""] + [f"- {n}" for n in a["notes"]] + [""]
    return lines


def certificate_figures(results: dict[str, Any]) -> list[tuple[str, str]]:
    figs = [("fig10_positioning.png", "Angular positioning error εz against the autocollimator and polygon for each approach "
                                      "direction, with its U band (k = 2), and the stage encoder's reading."),
            ("fig11_encoder_error.png", "Encoder error: predicted from tilt and radial motion (Abbe) and measured (±1σ)."),
            ("fig12_residual.png", "Measured − predicted encoder error (±2σ)."),
            ("fig09_tilt_radial.png", "Tilt and radial motion of the shaft from the two dial indicators.")]
    if "closure" in results["estimates"]:
        figs.append(("closure.png", "Polygon face errors and table errors separated by closure (±1σ)."))
    return figs


def method_text(results: dict[str, Any]) -> list[str]:
    a = results["estimates"]["abbe"]
    return [
        "The reference angle comes from an autocollimator on an optical polygon on the table (face errors from its "
        f"{a['polygon_source']}); the positioning deviation is the autocollimator reading minus the face error, relative "
        "to the first target. Runs are kept apart; targets are approached from their own side past an overrun.",
        "Seed 001's Abbe analysis: two dial indicators on the shaft separate tilt from radial motion, which predicts the "
        f"encoder's misreading (Δt/rE, extrapolation factor {a['extrapolation_factor']:.3f}); the measured encoder error "
        "is encoder − reference.",
        f"Uncertainty (GUM): the random error per visit from {a['random_error_from']}, the certificate's uncertainty per "
        "face, propagated exactly through the (linear) analysis.",
    ]


def summary(results: dict[str, Any]) -> list[str]:
    a = results["estimates"]["abbe"]
    rec = results.get("recommended") or "abbe"
    e = results["estimates"][rec]
    pred = [abs(v) for v in a["predicted_encoder_error_arcsec"] if v is not None] or [float("nan")]
    lines = [f"positioning deviation ECC ({rec}, recommended): {min(e['cumulative_deviation_arcsec']):+.2f}″ … "
             f"{max(e['cumulative_deviation_arcsec']):+.2f}″ over {len(e['target_deg'])} targets, U (k = 2) up to "
             f"{max(e['cumulative_expanded_uncertainty_arcsec']):.2f}″"
             + (f"; reversal {a['reversal_reference_arcsec']:+.2f}″" if a["reversal_reference_arcsec"] is not None else ""),
             f"encoder error predicted from tilt and radial motion: up to ±{max(pred):.2f}″; "
             f"measured − predicted RMS {a['residual_rms_arcsec']}″ (polygon from {a['polygon_source']})"]
    for series in ("positioning_error_arcsec", "encoder_vs_command_arcsec"):
        sig = [t for t in a["harmonics"].get(series, []) if t["significant"]]
        if sig:
            lines.append(f"{series.removesuffix('_arcsec')}: significant harmonics "
                         + ", ".join(f"{t['order']}× {t['amplitude']:.2f}″" + (" (Nyquist: lower bound)" if t.get("aliased") else "")
                                     for t in sig))
    if "closure" in results["estimates"]:
        c = results["estimates"]["closure"]
        lines.append(f"closure: polygon face errors 1σ ≤ {max(c['face_uncertainty_arcsec']):.3f}″, "
                     f"table errors 1σ ≤ {max(c['table_uncertainty_arcsec']):.3f}″")
    return lines + status_lines(results)
