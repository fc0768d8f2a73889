"""Truth summaries of a simulated run, in the shape of the estimates they check."""

from __future__ import annotations

import math

import numpy as np

from rtcal.units import rad_to_arcsec
from simulators.bench import Bench


def station_truth(bench: Bench, angles_deg: np.ndarray, direction: int) -> dict:
    """Per-step and cumulative deviations the stations really had (arcsec), signed as the estimates.

    ``deviation_arcsec`` is the systematic part (εz with the approach's reversal), the
    quantity a calibration estimates; ``realized_deviation_arcsec`` uses the mean actual
    angle of every visit to the station, so it includes the repeatability the run drew.
    """
    cmd = np.array([bench.quantise_command(c) for c in np.deg2rad(np.asarray(angles_deg, dtype=float))])
    systematic = np.array([bench.systematic_actual_rad(c, direction) for c in cmd])
    realized = []
    for c, s in zip(cmd, systematic):
        visits = [mv.actual_rad for mv in bench.truth.stage_moves if math.isclose(mv.commanded_rad, c, abs_tol=1e-12)]
        realized.append(float(np.mean(visits)) if visits else float(s))
    realized_rad = np.array(realized)
    error = rad_to_arcsec(systematic - cmd)
    return {
        "deviation_arcsec": np.diff(error).tolist(),
        "cumulative_deviation_arcsec": (error - error[0]).tolist(),
        "realized_deviation_arcsec": np.diff(rad_to_arcsec(realized_rad - cmd)).tolist(),
        "positioning_error_arcsec": error.tolist(),
    }


def _systematic_arcsec(bench: Bench, angle_deg: float, direction: int) -> tuple[float, float]:
    """(εz, encoder error) at a commanded angle approached in ``direction``, without repeatability."""
    with bench.systematic_state(angle_deg, direction) as error_arcsec:
        return error_arcsec, rad_to_arcsec(bench.encoder_error_rad())


def abbe_truth(bench: Bench, angles_deg: np.ndarray, directions: np.ndarray,
               target_deg: np.ndarray | None = None, target_direction: np.ndarray | None = None) -> dict:
    """Per step (commanded angle, direction): the systematic encoder error and εz, arcsec; at the
    targets (if given) εz relative to the first target (the estimates' ECC).

    The encoder error is what a noise-free encoder misreads at the step's systematic actual
    angle: Abbe shift/rE, eccentricity and graduation. Also the polygon's true face errors.
    """
    per_step = [_systematic_arcsec(bench, a, d) for a, d in zip(angles_deg, directions)]
    out = {"encoder_error_arcsec": np.round([p[1] for p in per_step], 6).tolist(),
           "positioning_error_arcsec": np.round([p[0] for p in per_step], 6).tolist(),
           "face_error_arcsec": np.round(bench.face_errors_arcsec, 6).tolist()}
    if target_deg is not None:
        if target_direction is None:
            raise ValueError("target_direction: one approach direction per target")
        eps = np.array([_systematic_arcsec(bench, a, d)[0] for a, d in zip(target_deg, target_direction)])
        out["cumulative_deviation_arcsec"] = np.round(eps - eps[0], 6).tolist()
    return out
