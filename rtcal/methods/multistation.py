"""The laser-tracer multi-station method (seed 000): measure, analyse, write files, report."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np

from rtcal.dataset import multistation_data
from rtcal.procedure.models import LaserTracerMultistation
from rtcal.report import plt
from rtcal.sequencer.multistation import MultistationInstrumentSet, planned_readings, run_multistation
from rtcal.solvers.lm import LMParameters
from rtcal.solvers.paper000 import PAPER_NOTES, PaperEstimate, StationChain, solve_paper
from rtcal.solvers.shared_dead_path import SharedDeadPathEstimate, solve_shared_dead_path
from rtcal.store import RunStore
from simulators.bench import Bench
from drivers import factory
from simulators.instruments import SimCmm, SimLaserTracer, SimStage
from simulators.truth import station_truth


def _round(values, digits: int = 6):
    return np.round(np.asarray(values, dtype=float), digits).tolist()


def chain_dict(ch: StationChain, uncertainty_arcsec: np.ndarray) -> dict[str, Any]:
    """What every station-based estimator reports: eq. 33 deviations, eq. 34 σ, eq. 36, the chain."""
    dev = np.asarray(ch.deviation_arcsec)
    return {
        "deviation_arcsec": _round(dev, 4),
        "cumulative_deviation_arcsec": _round(np.concatenate([[0.0], np.cumsum(dev)]), 4),
        "uncertainty_arcsec": _round(uncertainty_arcsec, 4),
        "sigma_arcsec": round(float(ch.sigma_arcsec), 4),
        "algorithm_error_arcsec": float(ch.algorithm_error_arcsec),
        "plane": {"a": ch.plane.a, "b": ch.plane.b, "c": ch.plane.c, "e": ch.plane.e},
        "projected_stations_mm": [_round(p) for p in ch.projected_mm],
        "center_mm": _round(ch.center_mm),
    }


def paper_estimate_dict(est: PaperEstimate) -> dict[str, Any]:
    """The ``estimates.paper`` block: the printed method, station by station."""
    return {
        **chain_dict(est.chain, est.uncertainty_arcsec),
        "stations_mm": [_round([*f.center_mm, f.dead_path_mm]) for f in est.stations],
        "station_rms_residual_um": _round([f.rms_residual_um for f in est.stations], 4),
        "station_iterations": [f.iterations for f in est.stations],
        "converged": all(f.converged for f in est.stations),
        "notes": list(PAPER_NOTES),
    }


def shared_dead_path_dict(est: SharedDeadPathEstimate) -> dict[str, Any]:
    """The ``estimates.shared_dead_path`` block: all stations jointly, one dead path per segment."""
    return {
        **chain_dict(est.chain, est.uncertainty_arcsec),
        "stations_mm": [_round(c) for c in est.centers_mm],
        "dead_paths_mm": {str(int(s)): round(float(d), 6) for s, d in zip(est.segment_ids, est.dead_paths_mm)},
        "rms_residual_um": round(est.rms_residual_um, 4),
        "converged": est.converged,
    }


def write_deviation_csv(run_dir: Path, results: dict[str, Any]) -> Path:
    """One row per station: nominal angle, then each estimator's step deviation and uncertainty."""
    path = run_dir / "deviations.csv"
    angles = results["nominal_angles_deg"]
    names = list(results["estimates"])
    truth = results.get("truth", {}).get("deviation_arcsec")
    header = ["station", "nominal_angle_deg"]
    for n in names:
        header += [f"{n}_deviation_arcsec", f"{n}_uncertainty_arcsec", f"{n}_cumulative_arcsec"]
    if truth is not None:
        header.append("truth_deviation_arcsec")
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for j, angle in enumerate(angles):
            row: list[Any] = [j + 1, angle]
            for n in names:
                e = results["estimates"][n]
                row += ["" if j == 0 else e["deviation_arcsec"][j - 1],
                        "" if j == 0 else e["uncertainty_arcsec"][j - 1],
                        e["cumulative_deviation_arcsec"][j]]
            if truth is not None:
                row.append("" if j == 0 else round(truth[j - 1], 4))
            w.writerow(row)
    return path


def lm_parameters(proc: LaserTracerMultistation) -> LMParameters:
    lm = proc.solver.lm
    return LMParameters(beta=lm.beta, sigma=lm.sigma, epsilon=lm.epsilon,
                        mu0=None if lm.mu0 == "residual_norm" else float(lm.mu0), max_iterations=lm.max_iterations)


def plan_length(proc: LaserTracerMultistation) -> int:
    return len(planned_readings(proc))


def sim_instruments(proc: LaserTracerMultistation, bench: Bench) -> MultistationInstrumentSet:
    return MultistationInstrumentSet(stage=SimStage(bench), cmm=SimCmm(bench), laser_tracer=SimLaserTracer(bench))


def transport_instruments(proc: LaserTracerMultistation) -> MultistationInstrumentSet:
    i = proc.instruments
    stage = factory.open_stage(i.stage.address, i.stage.soft_limits_deg, i.stage.timeout_s)
    cmm = factory.open_cmm(i.cmm.address, i.cmm.volume_min_mm, i.cmm.volume_max_mm, i.cmm.timeout_s)
    tracer = factory.open_laser_tracer(i.laser_tracer.address, i.laser_tracer.timeout_s)
    return MultistationInstrumentSet(stage=stage, cmm=cmm, laser_tracer=tracer)


def prepare(proc: LaserTracerMultistation, operator) -> dict[str, str]:
    """Nothing to fix before the first motion."""
    return {}


def measure(proc: LaserTracerMultistation, inst: MultistationInstrumentSet, store: RunStore, clock, operator, progress,
            generation: int = 0) -> None:
    run_multistation(proc, inst, store, clock, progress, operator)


def analyse(proc: LaserTracerMultistation, store: RunStore, bench: Bench | None) -> dict[str, Any]:
    """Logged readings → both estimators (and the truth of a simulated run)."""
    angles = proc.stations.angles_deg()
    data = multistation_data(store, angles, len(proc.points_array()))
    nominal = np.deg2rad(angles)
    guess, axis = np.array(proc.solver.first_station_guess_mm), np.array(proc.solver.axis_point_mm)
    paper = solve_paper(data.points_mm, data.lengths_mm, nominal, guess, axis, lm_parameters(proc), data.segments)
    shared = solve_shared_dead_path(data.points_mm, data.lengths_mm, data.segments, nominal, guess, axis)
    paper_block = paper_estimate_dict(paper)
    segments = len(set(data.segments[np.isfinite(data.lengths_mm)].tolist()))
    if segments > 1:
        paper_block["notes"].append(
            f"The tracer was referenced {segments} times (re-acquisitions or resumed starts): the per-station model "
            "then carries one dead path per station and segment, which weakens it further; shared_dead_path does not "
            "suffer from this.")
    out: dict[str, Any] = {
        "nominal_angles_deg": [float(a) for a in angles],
        "raw_readings": data.raw_readings,
        "estimates": {"paper": paper_block, "shared_dead_path": shared_dead_path_dict(shared)},
    }
    if bench is not None:
        out["truth"] = station_truth(bench, angles, 1 if proc.stations.approach == "positive" else -1)
    return out


def write_files(run_dir: Path, results: dict[str, Any]) -> list[Path]:
    return [write_deviation_csv(run_dir, results), plot_deviation(run_dir, results)]


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


def report_body(results: dict[str, Any]) -> list[str]:
    """Deviation table per estimator, σ and algorithm error, the figure, the paper's gaps."""
    angles = results["nominal_angles_deg"]
    names = list(results["estimates"])
    truth = results.get("truth", {}).get("deviation_arcsec")
    head = "| station | angle / ° | " + " | ".join(f"{n} Δθ / ″ (1σ)" for n in names) + (" | truth / ″ |" if truth else " |")
    lines = [head, "|" + "---|" * (2 + len(names) + (1 if truth else 0))]
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
    lines += ["", "`paper` is the printed method (one dead path per station); `shared_dead_path` solves all stations "
              "together with one dead path per uninterrupted tracking segment.", "", "![deviation](deviation.png)", ""]
    notes = results["estimates"].get("paper", {}).get("notes", [])
    if notes:
        lines += ["## Where the printed equations and the paper's figures differ", ""] + [f"- {n}" for n in notes] + [""]
    return lines


def summary(results: dict[str, Any]) -> list[str]:
    lines = []
    for name, est in results["estimates"].items():
        devs = ", ".join(f"{v:+.2f}" for v in est["deviation_arcsec"])
        lines.append(f"{name}: deviation per station (arcsec) {devs}; 1σ ≤ {max(est['uncertainty_arcsec']):.2f}″, "
                     f"σΔθ (eq. 34) = ±{est['sigma_arcsec']:.2f}″")
    return lines
