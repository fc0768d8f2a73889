"""Estimator results → the run directory's machine-readable files (results.json, deviations.csv)."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

from rtcal.solvers.paper000 import PAPER_NOTES, PaperEstimate, StationChain
from rtcal.solvers.shared_dead_path import SharedDeadPathEstimate


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


def write_results(run_dir: Path, results: dict[str, Any]) -> Path:
    path = run_dir / "results.json"
    path.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    return path


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
