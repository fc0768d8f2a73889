"""The laser-tracer multi-station method (seed 000): measure, analyse, write files, report."""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from drivers import factory
from rtcal.solvers.air import index_sensitivity, standard_air_n
from rtcal.run.dataset import multistation_data
from rtcal.deliverables.deviations import PositioningDeviations
from rtcal.procedure.models import LaserTracerMultistation
from rtcal.deliverables.figures import plt
from rtcal.methods.estimates import (
    choose_recommended,
    deviation_block,
    run_estimators,
    status_lines,
)
from rtcal.sequencer.multistation import (
    MultistationInstrumentSet,
    planned_readings,
    run_multistation,
)
from rtcal.solvers.air import correct_lengths
from rtcal.solvers.lm import LMParameters
from rtcal.solvers.network import CMM_NAMES, NetworkEstimate, solve_network
from rtcal.solvers.paper000 import PAPER_NOTES, PaperEstimate, StationChain, solve_paper
from rtcal.solvers.selfcal import initial_guesses
from rtcal.solvers.shared_dead_path import (
    SharedDeadPathEstimate,
    solve_shared_dead_path,
)
from rtcal.solvers.station_budget import StationBudget, StationNoiseModel
from rtcal.solvers.station_data import MultistationData
from rtcal.run.store import RunStore
from simulators.bench import Bench
from simulators.instruments import (
    SimCmm,
    SimEnvironmentSensor,
    SimLaserTracer,
    SimStage,
)
from simulators.scenario import AngularHarmonic, LinearHarmonic, Scenario
from simulators.truth import station_truth


def _round(values, digits: int = 6):
    return np.round(np.asarray(values, dtype=float), digits).tolist()


def noise_model(proc: LaserTracerMultistation, estimate: bool = True) -> StationNoiseModel:
    """The procedure's ``uncertainty`` section as the solvers' noise model (``estimate``: Type A
    sizes from the readings; False: as stated, for a prediction)."""
    u = proc.uncertainty
    em = u.error_motions
    return StationNoiseModel(
        length_noise_um=u.laser_tracer_noise_um, length_noise_ppm=u.laser_tracer_noise_ppm,
        point_noise_um=u.cmm_point_noise_um, stage_repeatability_arcsec=u.stage_repeatability_arcsec,
        cmm_scale_ppm=u.cmm_scale_ppm, cmm_squareness_arcsec=u.cmm_squareness_arcsec,
        error_motion_radial_um=em.radial_um, error_motion_axial_um=em.axial_um, error_motion_tilt_arcsec=em.tilt_arcsec,
        error_motion_max_order=em.max_order, tilt_center_z_mm=em.tilt_center_z_mm, estimate=estimate,
        air_index_sigma=air_index_sigma(proc))


def air_index_sigma(proc: LaserTracerMultistation) -> float:
    """1σ of the air's index the lengths are corrected with, from the sensor's stated uncertainty (0: no sensor)."""
    if proc.instruments.environment is None:
        return 0.0
    e = proc.uncertainty.environment
    dT, dp, dh = index_sensitivity()
    return float(np.sqrt((dT * e.air_temperature_k) ** 2 + (dp * e.air_pressure_pa) ** 2 + (dh * e.humidity_pct) ** 2))


def corrected_for_air(data: MultistationData, proc: LaserTracerMultistation) -> MultistationData:
    """The lengths as geometric lengths, each corrected with the air's index at its reading."""
    if data.air_index is None:
        return data
    nominal = np.deg2rad(data.nominal_angles_deg)
    axis = np.array(proc.solver.axis_point_mm)

    def fix(lengths, index, segments, guess):
        stations = initial_guesses(np.asarray(guess, float), nominal, axis, data.points_mm, lengths)[:, :3]
        return correct_lengths(lengths, index, segments, data.points_mm, stations, standard_air_n())

    others = tuple(replace(o, lengths_mm=fix(o.lengths_mm, o.air_index, o.segments, proc.second_mount.first_station_guess_mm))
                   for o in data.other_mounts)
    return replace(data, lengths_mm=fix(data.lengths_mm, data.air_index, data.segments, proc.solver.first_station_guess_mm),
                   other_mounts=others)


def not_included(proc: LaserTracerMultistation) -> list[str]:
    """Type B sources the procedure did not state: the budget is silent on them, and says so."""
    u = proc.uncertainty
    out = []
    if max(u.error_motions.radial_um, u.error_motions.axial_um, u.error_motions.tilt_arcsec) == 0:
        out.append("error motions: no bounds stated (uncertainty.error_motions); one tracer mount cannot separate "
                   "them from the rotation, so a table with error motions is off by more than this budget says")
    if u.cmm_scale_ppm == 0 and u.cmm_squareness_arcsec == 0:
        out.append("CMM scale and squareness: not stated (uncertainty.cmm_scale_ppm, cmm_squareness_arcsec)")
    if u.stage_repeatability_arcsec == 0:
        out.append("stage repeatability per visit: not stated (uncertainty.stage_repeatability_arcsec)")
    return out


def chain_dict(ch: StationChain, budget: StationBudget, omitted: list[str]) -> dict[str, Any]:
    """What every station-based estimator reports: the deviations and their budget, eq. 34 and 36, the chain."""
    return {
        **deviation_block(ch.cumulative_deviation_arcsec, budget.cumulative, not_included=omitted),
        "eq34_sigma_arcsec": round(float(ch.sigma_arcsec), 4),
        "algorithm_error_arcsec": float(ch.algorithm_error_arcsec),
        "estimated_noise": {"tracer_length_noise_um_at_1m": round(float(budget.estimated_sigma("tracer length noise")), 5),
                            "cmm_point_noise_um": round(float(budget.estimated_sigma("CMM point noise")), 5)},
        "plane": {"a": ch.plane.a, "b": ch.plane.b, "c": ch.plane.c, "e": ch.plane.e},
        "projected_stations_mm": [_round(p) for p in ch.projected_mm],
        "center_mm": _round(ch.center_mm),
    }


def paper_estimate_dict(est: PaperEstimate, omitted: list[str]) -> dict[str, Any]:
    """The ``estimates.paper`` block: the printed method, station by station."""
    return {
        **chain_dict(est.chain, est.budget, omitted),
        "stations_mm": [_round([*f.center_mm, f.dead_path_mm]) for f in est.stations],
        "station_rms_residual_um": _round([f.rms_residual_um for f in est.stations], 4),
        "station_iterations": [f.iterations for f in est.stations],
        "converged": est.converged,
        "message": est.message,
        "notes": list(PAPER_NOTES),
    }


def shared_dead_path_dict(est: SharedDeadPathEstimate, omitted: list[str]) -> dict[str, Any]:
    """The ``estimates.shared_dead_path`` block: all stations jointly, one dead path per segment."""
    return {
        **chain_dict(est.chain, est.budget, omitted),
        "stations_mm": [_round(c) for c in est.centers_mm],
        "dead_paths_mm": {str(int(s)): round(float(d), 6) for s, d in zip(est.segment_ids, est.dead_paths_mm)},
        "rms_residual_um": round(est.rms_residual_um, 4),
        "converged": est.converged,
        "message": est.message + ("" if est.budget.variances.converged else
                                  "; the noise sizes (REML) did not converge: the uncertainty is less certain"),
    }


def network_dict(est: NetworkEstimate, omitted: list[str]) -> dict[str, Any]:
    """The ``estimates.network`` block: one adjustment of axis, angles, dead paths, CMM and points
    (and, with a second mount, the error motions it separated)."""
    omitted = [o for o in omitted if not o.startswith("CMM scale")]  # solved here, not a Type B input
    em = est.error_motions
    if em is not None:
        omitted = [o for o in omitted if not o.startswith("error motions")]  # measured here
    motions = {}
    if em is not None:
        motions["error_motions"] = {
            "note": "per station at the mounts' plane, synchronous: the mean and the once-per-turn part removed (they "
                    "belong to the axis average line, its direction and the mounts' positions); the tilt is the one about "
                    "the horizontal axis perpendicular to the line joining the mounts (`tilt_axis_deg`): the tilt about "
                    "that line cannot be seen, nor the axial motion EZC apart from it",
            "EXC_um": _round(em.radial_um[:, 0], 4), "EYC_um": _round(em.radial_um[:, 1], 4),
            "EXC_sigma_um": _round(em.radial_sigma_um[:, 0], 4), "EYC_sigma_um": _round(em.radial_sigma_um[:, 1], 4),
            "tilt_arcsec": _round(em.tilt_arcsec, 4), "tilt_sigma_arcsec": _round(em.tilt_sigma_arcsec, 4),
            "tilt_axis_deg": _round(em.tilt_axis_deg, 3),
            "mounts_mm": [_round(p) for p in est.mounts_mm],
        }
    return {
        **deviation_block(est.cumulative_deviation_arcsec, est.budget, not_included=omitted),
        "estimated_noise": {"tracer_length_noise_um_at_1m": round(est.sigma_length_um, 5), "cmm_point_noise_um": round(est.sigma_point_um, 5)},
        "cmm_errors": {name: {"value": round(float(v), 4), "sigma": round(float(s), 4) if np.isfinite(s) else None}
                       for name, v, s in zip(CMM_NAMES, est.cmm_errors, est.cmm_errors_sigma)},
        "axis_point_mm": _round(est.axis_point_mm), "axis_direction": _round(est.axis_direction, 9),
        "radius_mm": round(est.radius_mm, 6),
        "stations_mm": [_round(p) for p in est.stations_mm],
        "dead_paths_mm": {str(int(s)): round(float(d), 6) for s, d in zip(est.segment_ids, est.dead_paths_mm)},
        "rms_length_residual_um": round(est.rms_length_residual_um, 4),
        "rms_point_residual_um": round(est.rms_point_residual_um, 4),
        **motions,
        "converged": est.converged,
        "message": est.message,
    }


def write_deviation_csv(run_dir: Path, results: dict[str, Any]) -> Path:
    """One row per station: nominal angle, then each estimator's cumulative and per-step deviation with 1σ."""
    path = run_dir / "deviations.csv"
    angles = results["nominal_angles_deg"]
    names = list(results["estimates"])
    truth = results.get("truth", {}).get("cumulative_deviation_arcsec")
    header = ["station", "nominal_angle_deg"]
    for n in names:
        header += [f"{n}_cumulative_arcsec", f"{n}_cumulative_u_arcsec", f"{n}_step_deviation_arcsec", f"{n}_step_u_arcsec"]
    if truth is not None:
        header.append("truth_cumulative_arcsec")
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for j, angle in enumerate(angles):
            row: list[Any] = [j + 1, angle]
            for n in names:
                e = results["estimates"][n]
                row += [e["cumulative_deviation_arcsec"][j], e["cumulative_uncertainty_arcsec"][j],
                        "" if j == 0 else e["deviation_arcsec"][j - 1], "" if j == 0 else e["uncertainty_arcsec"][j - 1]]
            if truth is not None:
                row.append(round(truth[j], 4))
            w.writerow(row)
    return path


def _random_series(sigma: float, max_order: int, rng: np.random.Generator, cls):
    """A random Fourier series of orders 1..K with σ at every angle: coefficients N(0, σ²/K)."""
    if sigma <= 0:
        return []
    a, b = rng.normal(0.0, sigma / np.sqrt(max_order), (2, max_order))
    key = "amplitude_um" if cls is LinearHarmonic else "amplitude_arcsec"
    return [cls(order=k + 1, **{key: float(np.hypot(a[k], b[k]))}, phase_deg=float(np.degrees(np.arctan2(b[k], a[k]))))
            for k in range(max_order)]


def draw_systematics(proc: LaserTracerMultistation, scenario: Scenario, rng: np.random.Generator) -> Scenario:
    """A bench whose unknown systematic errors are drawn as the procedure's budget models them:
    CMM scales and squarenesses N(0, u), error motions as random series with σ = bound/√2
    (for `rtcal uncertainty`; DESIGN.md: GUM Supplement 1)."""
    u = proc.uncertainty
    em = u.error_motions
    k = em.max_order
    cmm = scenario.cmm.model_copy(update={
        "scale_error_ppm": tuple(float(x) for x in rng.normal(0.0, u.cmm_scale_ppm, 3)),
        "squareness_xy_arcsec": float(rng.normal(0.0, u.cmm_squareness_arcsec)),
        "squareness_xz_arcsec": float(rng.normal(0.0, u.cmm_squareness_arcsec)),
        "squareness_yz_arcsec": float(rng.normal(0.0, u.cmm_squareness_arcsec))})
    r, ax, t = em.radial_um / np.sqrt(2), em.axial_um / np.sqrt(2), em.tilt_arcsec / np.sqrt(2)
    stage = scenario.stage.model_copy(update={
        "radial_motion_x": _random_series(r, k, rng, LinearHarmonic), "radial_motion_y": _random_series(r, k, rng, LinearHarmonic),
        "axial_motion": _random_series(ax, k, rng, LinearHarmonic),
        "tilt_motion_x": _random_series(t, k, rng, AngularHarmonic), "tilt_motion_y": _random_series(t, k, rng, AngularHarmonic),
        "tilt_center_height_mm": em.tilt_center_z_mm - scenario.stage.axis_point_mm[2]})
    return scenario.model_copy(update={"cmm": cmm, "stage": stage})


def target_labels(results: dict[str, Any]) -> list[str]:
    arrow = "↑" if results["nominal_angles_deg"][-1] > results["nominal_angles_deg"][0] else "↓"
    return [f"{a:g}{arrow}" for a in results["nominal_angles_deg"]]


def lm_parameters(proc: LaserTracerMultistation) -> LMParameters:
    lm = proc.solver.lm
    return LMParameters(beta=lm.beta, sigma=lm.sigma, epsilon=lm.epsilon,
                        mu0=None if lm.mu0 == "residual_norm" else float(lm.mu0), max_iterations=lm.max_iterations)


def plan_length(proc: LaserTracerMultistation) -> int:
    return len(planned_readings(proc))


def sim_instruments(proc: LaserTracerMultistation, bench: Bench) -> MultistationInstrumentSet:
    env = SimEnvironmentSensor(bench) if proc.instruments.environment is not None else None
    return MultistationInstrumentSet(stage=SimStage(bench), cmm=SimCmm(bench), laser_tracer=SimLaserTracer(bench), environment=env)


def transport_instruments(proc: LaserTracerMultistation) -> MultistationInstrumentSet:
    i = proc.instruments
    stage = factory.open_stage(i.stage.address, i.stage.soft_limits_deg, i.stage.timeout_s)
    cmm = factory.open_cmm(i.cmm.address, i.cmm.volume_min_mm, i.cmm.volume_max_mm, i.cmm.timeout_s, i.cmm.tool)
    tracer = factory.open_laser_tracer(i.laser_tracer.address, i.laser_tracer.timeout_s)
    env = factory.open_environment(i.environment.address, i.environment.timeout_s) if i.environment is not None else None
    return MultistationInstrumentSet(stage=stage, cmm=cmm, laser_tracer=tracer, environment=env)


def prepare(proc: LaserTracerMultistation, operator) -> dict[str, str]:
    """Nothing to fix before the first motion."""
    return {}


def measure(proc: LaserTracerMultistation, inst: MultistationInstrumentSet, store: RunStore, clock, operator, progress,
            generation: int = 0) -> None:
    run_multistation(proc, inst, store, clock, progress, operator)


ESTIMATOR_LABELS = {
    "paper": "paper (as printed: one dead path per station)",
    "shared_dead_path": "shared dead path (one per tracking segment)",
    "network": "network (one circle, CMM solved)",
}


def analyse(proc: LaserTracerMultistation, store: RunStore, bench: Bench | None, estimate_noise: bool = True) -> dict[str, Any]:
    """Logged readings → every estimator that can run (a failure is recorded, not fatal), the
    recommended one, its positioning-deviation table, and the truth of a simulated run."""
    angles = proc.stations.angles_deg()
    data = corrected_for_air(multistation_data(store, angles, len(proc.points_array()), proc.mounts), proc)
    guess, axis = np.array(proc.solver.first_station_guess_mm), np.array(proc.solver.axis_point_mm)
    noise, omitted = noise_model(proc, estimate_noise), not_included(proc)
    solvers = {
        "paper": lambda: paper_estimate_dict(solve_paper(data, guess, axis, lm_parameters(proc), noise), omitted),
        "shared_dead_path": lambda: shared_dead_path_dict(solve_shared_dead_path(data, guess, axis, noise), omitted),
        "network": lambda: network_dict(solve_network(
            data, guess, axis, noise, mount_guesses_mm=[np.array(proc.second_mount.first_station_guess_mm)] if proc.second_mount else None),
            omitted),
    }
    estimates, status = run_estimators({k: f for k, f in solvers.items() if k in proc.solver.estimators})
    segments = len(set(data.segments[np.isfinite(data.lengths_mm)].tolist()))
    if segments > 1 and "paper" in estimates:
        estimates["paper"]["notes"].append(
            f"The tracer was referenced {segments} times (re-acquisitions or resumed starts): the per-station model "
            "then carries one dead path per station and segment, which weakens it further; shared_dead_path does not "
            "suffer from this.")
    recommended = choose_recommended(estimates, status)
    direction = 1 if proc.stations.approach == "positive" else -1
    out: dict[str, Any] = {
        "nominal_angles_deg": [float(a) for a in angles],
        "raw_readings": data.raw_readings,
        "environment": data.environment,
        "recommended": recommended,
        "solver_status": status,
        "estimates": estimates,
    }
    if recommended is not None:
        e = estimates[recommended]
        table = PositioningDeviations(np.asarray(angles, float), np.full(len(angles), direction), np.ones(len(angles), int),
                                      np.array(e["cumulative_deviation_arcsec"], float),
                                      np.array(e["cumulative_uncertainty_arcsec"], float), estimator=recommended)
        out["positioning_deviations"] = table.to_dict()
    if bench is not None:
        out["truth"] = station_truth(bench, angles, direction)
    return out


def write_files(run_dir: Path, results: dict[str, Any]) -> list[Path]:
    return [write_deviation_csv(run_dir, results), plot_deviation(run_dir, results)]


def _values(est: dict[str, Any], key: str) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in est[key]], float)


def plot_deviation(run_dir: Path, results: dict[str, Any]) -> Path:
    """Main panel: the cumulative deviation of every estimator, the recommended one with its U (k = 2)
    band; lower panel: the paper's per-step Δθ (eq. 33) with 1σ bars. Truth where simulated."""
    angles = np.array(results["nominal_angles_deg"], float)
    rec = results.get("recommended")
    names = sorted(results["estimates"], key=lambda n: n != rec)
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(8.5, 7.5), sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    truth = results.get("truth", {})
    for k, name in enumerate(names):
        est = results["estimates"][name]
        cum, u = _values(est, "cumulative_deviation_arcsec"), _values(est, "cumulative_uncertainty_arcsec")
        label = ESTIMATOR_LABELS.get(name, name)
        if name == rec:
            ax.fill_between(angles, cum - 2 * u, cum + 2 * u, color="C0", alpha=0.2, lw=0,
                            label=f"{label}: ±U (k = 2)")
            ax.plot(angles, cum, "o-", color="C0", lw=2, label=f"{label} — recommended")
        else:
            ax.errorbar(angles, cum, yerr=2 * u, fmt="s--", color=f"C{k + 1}", ms=4, lw=1, capsize=3,
                        label=f"{label}, bars ±U (k = 2)")
        step, su = _values(est, "deviation_arcsec"), _values(est, "uncertainty_arcsec")
        offset = (k - (len(names) - 1) / 2) * 0.012 * (angles.max() - angles.min())
        ax2.errorbar(angles[1:] + offset, step, yerr=su, fmt="o" if name == rec else "s", ms=4, capsize=3,
                     color="C0" if name == rec else f"C{k + 1}", label=f"{name}, bars ±1σ")
    if "cumulative_deviation_arcsec" in truth:
        ax.plot(angles, truth["cumulative_deviation_arcsec"], "kx:", label="truth (simulated bench)")
        ax2.plot(angles[1:], truth["deviation_arcsec"], "kx", label="truth (simulated bench)")
    for a in (ax, ax2):
        a.axhline(0.0, color="0.6", lw=0.8)
        a.grid(alpha=0.3)
    ax.set_ylabel("cumulative positioning deviation ECC / ″\n(actual − commanded, relative to the first station)")
    ax2.set_ylabel("per-step deviation Δθ / ″\n(eq. 33: actual − nominal step)")
    ax2.set_xlabel("commanded table angle / °  (" + ("positive" if angles[-1] > angles[0] else "negative") + " approach)")
    ax2.set_xticks(angles, [f"{a:g}" for a in angles], fontsize=8)
    ax.legend(fontsize=8, loc="best")
    ax2.legend(fontsize=8, loc="best")
    name = results.get("procedure", {}).get("name") or results["method"]
    ax.set_title(_mathtext_safe(name), fontsize=11)
    fig.tight_layout()
    path = run_dir / "deviation.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _mathtext_safe(text: str) -> str:
    """A title exactly as the user wrote it: matplotlib would read ``$…$`` as mathtext."""
    return text.replace("$", r"\$")


def budget_table(est: dict[str, Any], angles: list[float]) -> list[str]:
    """The uncertainty budget as a Markdown table: one row per source, one column per target."""
    b = est["uncertainty_budget"]
    head = "| source | type | input σ | " + " | ".join(f"{a:g}°" for a in angles[1:]) + " |"
    lines = [head, "|" + "---|" * (3 + len(angles) - 1)]
    for c in b["components"]:
        origin = " (from the data)" if c["estimated_from_data"] else ""
        cells = [c["source"], c["type"], f"{c['input_sigma']:.3g} {c['unit']}{origin}"]
        cells += [f"{v:.3f}" for v in c["contribution_arcsec"][1:]]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("| **combined u** | | | " + " | ".join(f"**{v:.3f}**" for v in b["combined_arcsec"][1:]) + " |")
    lines.append("| **U (k = 2)** | | | " + " | ".join(f"**{v:.3f}**" for v in b["expanded_arcsec"][1:]) + " |")
    lines.append("")
    lines += [f"- not included: {n}" for n in b["not_included"]]
    return lines + [""]


def report_body(results: dict[str, Any]) -> list[str]:
    """The recommended result first (cumulative deviation with U), then every estimator, the budget, the paper's gaps."""
    angles = results["nominal_angles_deg"]
    rec = results.get("recommended")
    names = sorted(results["estimates"], key=lambda n: n != rec)
    truth = results.get("truth", {}).get("cumulative_deviation_arcsec")
    lines = []
    if rec:
        e = results["estimates"][rec]
        lines += [f"## Result: cumulative positioning deviation ECC ({ESTIMATOR_LABELS.get(rec, rec)}, recommended)", "",
                  "Actual − commanded angle relative to the first station, arcsec; u standard uncertainty, "
                  "U expanded uncertainty (k = 2).", "",
                  "| station | commanded / ° | ECC / ″ | u / ″ | U (k = 2) / ″ |" + (" truth / ″ |" if truth else ""),
                  "|---|---|---|---|---|" + ("---|" if truth else "")]
        for j, a in enumerate(angles):
            cells = [f"P{j + 1}", f"{a:g}", f"{e['cumulative_deviation_arcsec'][j]:+.3f}",
                     f"{e['cumulative_uncertainty_arcsec'][j]:.3f}", f"{e['cumulative_expanded_uncertainty_arcsec'][j]:.3f}"]
            if truth:
                cells.append(f"{truth[j]:+.3f}")
            lines.append("| " + " | ".join(cells) + " |")
        lines += ["", "![deviation](deviation.png)", ""]
    lines += ["## Every estimator", "",
              "| station | " + " | ".join(f"{n}: ECC / ″ (u)" for n in names) + " | " + " | ".join(f"{n}: Δθ / ″ (u)" for n in names) + " |",
              "|" + "---|" * (1 + 2 * len(names))]
    for j in range(len(angles)):
        cells = [f"P{j + 1}"]
        for n in names:
            e = results["estimates"][n]
            cells.append(f"{e['cumulative_deviation_arcsec'][j]:+.3f} ({e['cumulative_uncertainty_arcsec'][j]:.3f})")
        for n in names:
            e = results["estimates"][n]
            cells.append("" if j == 0 else f"{e['deviation_arcsec'][j - 1]:+.3f} ({e['uncertainty_arcsec'][j - 1]:.3f})")
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    for n in names:
        e = results["estimates"][n]
        st = results["solver_status"][n]
        noise = (f"noise estimated from the readings: tracer {e['estimated_noise']['tracer_length_noise_um_at_1m']:.3f} µm at 1 m, "
                 f"CMM points {e['estimated_noise']['cmm_point_noise_um']:.3f} µm")
        if "eq34_sigma_arcsec" in e:
            lines.append(f"- {n}: {st['status']} ({st['message']}); σΔθ = {e['eq34_sigma_arcsec']:.2f}″ is the paper's "
                         f"eq. 34 statistic of the deviations, not an uncertainty; algorithm error (eq. 36) "
                         f"{e['algorithm_error_arcsec']:.2e}″; {noise}")
        else:
            cmm = ", ".join(f"{k} {v['value']:+.3f} ± {v['sigma']:.3f}" for k, v in e.get("cmm_errors", {}).items())
            lines.append(f"- {n}: {st['status']} ({st['message']}); {noise}; the CMM's errors found (1σ): {cmm}")
    for n, st in results.get("solver_status", {}).items():
        if st["status"] == "failed":
            lines.append(f"- {n}: **failed** — {st['message']}")
    lines += ["", "`paper` is the printed method (one dead path per station); `shared_dead_path` solves all stations "
              "together with one dead path per uninterrupted tracking segment; `network` adjusts everything at once: the "
              "stations on one circle about one axis (one angle each), the CMM points as observations weighted by their "
              "noise, and the CMM's scales and squarenesses.", ""]
    net = results["estimates"].get("network")
    if net:
        lines += ["## The CMM, checked by the network adjustment", "",
                  "Scale and squareness errors of the CMM found from the traceable tracer lengths (1σ):", "",
                  "| parameter | value | 1σ |", "|---|---|---|"]
        lines += [f"| {k} | {v['value']:+.3f} | {v['sigma']:.3f} |" for k, v in net["cmm_errors"].items()] + [""]
        em = net.get("error_motions")
        if em:
            lines += ["## Error motions, separated by the second tracer mount", "", em["note"][0].upper() + em["note"][1:] + ".", "",
                      "| station | angle / ° | EXC / µm (1σ) | EYC / µm (1σ) | tilt / ″ (1σ) | tilt axis / ° |",
                      "|---|---|---|---|---|---|"]
            for j, a in enumerate(angles):
                lines.append(f"| P{j + 1} | {a:g} | {em['EXC_um'][j]:+.3f} ({em['EXC_sigma_um'][j]:.3f}) | "
                             f"{em['EYC_um'][j]:+.3f} ({em['EYC_sigma_um'][j]:.3f}) | "
                             f"{em['tilt_arcsec'][j]:+.2f} ({em['tilt_sigma_arcsec'][j]:.2f}) | "
                             f"{em['tilt_axis_deg'][j]:.0f} |")
            lines.append("")
    if rec:
        lines += [f"## Uncertainty budget of the cumulative deviation ({rec}), contributions u / ″ per station", ""]
        lines += budget_table(results["estimates"][rec], angles)
    notes = results["estimates"].get("paper", {}).get("notes", [])
    if notes:
        lines += ["## Where the printed equations and the paper's figures differ", ""] + [f"- {n}" for n in notes] + [""]
    return lines


def certificate_figures(results: dict[str, Any]) -> list[tuple[str, str]]:
    return [("deviation.png", "Cumulative positioning deviation ECC of every estimator (the recommended one with its "
                              "U band, k = 2) and the per-step deviation Δθ of seed 000's eq. 33 (bars ±1σ).")]


def method_text(results: dict[str, Any]) -> list[str]:
    rec = results.get("recommended")
    return [
        "Laser tracer multi-station method: the laser tracer sits on the table; a CMM moves its cat-eye reflector through "
        "a set of points while the table indexes through the stations, and the tracer measures interferometric lengths. "
        "The tracer's reference centre at each station is self-calibrated from the lengths; the stations lie on a circle "
        "about the rotation axis, and the angle between them gives the positioning deviation.",
        "Estimators: 'paper' as published (one dead path per station, plane, circle, eq. 32–33); 'shared_dead_path' "
        "(all stations together, one dead path per tracking segment); 'network' (one adjustment of axis, radius, station "
        "angles, CMM points as weighted observations and the CMM's scales and squarenesses). The report quotes the "
        f"recommended one ({rec}): converged, with the smallest uncertainty.",
        "Uncertainty (GUM): the tracer's and the CMM's noise are estimated from the readings (Type A); stage "
        "repeatability, CMM geometry, error motions and the air's refractive index as the procedure states them "
        "(Type B); all propagated through the estimator with their correlations.",
    ]


def summary(results: dict[str, Any]) -> list[str]:
    """The console: the recommended cumulative deviation with U, then what did not converge."""
    lines = []
    rec = results.get("recommended")
    if rec:
        e = results["estimates"][rec]
        cum = ", ".join(f"{v:+.2f}" for v in e["cumulative_deviation_arcsec"])
        lines.append(f"cumulative positioning deviation ECC (arcsec, {rec}, recommended): {cum}")
        lines.append(f"expanded uncertainty U (k = 2) up to {max(e['cumulative_expanded_uncertainty_arcsec']):.2f}″")
    for name, est in results["estimates"].items():
        if name != rec:
            lines.append(f"also {name}: U (k = 2) up to {max(est['cumulative_expanded_uncertainty_arcsec']):.2f}″")
    return lines + status_lines(results)
