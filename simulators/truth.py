"""Truth summaries of a simulated run, in the shape of the estimates they check."""

from __future__ import annotations

import math

import numpy as np

from rtcal.units import rad_to_arcsec
from simulators.bench import Bench


def station_truth(bench: Bench, angles_deg: np.ndarray, direction: int) -> dict:
    """Per-step and cumulative deviations the stations really had (arcsec).

    ``deviation_arcsec`` is the systematic part (εz with the approach's reversal), the
    quantity a calibration estimates; ``realized_deviation_arcsec`` uses the mean actual
    angle of every visit to the station, so it includes the repeatability the run drew.
    """
    cmd = np.deg2rad(np.asarray(angles_deg, dtype=float))
    systematic = cmd + np.asarray(bench.positioning_error_rad(cmd, direction), dtype=float)
    realized = []
    for c, s in zip(cmd, systematic):
        visits = [mv.actual_rad for mv in bench.truth.stage_moves if math.isclose(mv.commanded_rad, c, abs_tol=1e-12)]
        realized.append(float(np.mean(visits)) if visits else float(s))
    realized = np.array(realized)
    nominal_step = np.abs(np.diff(cmd))
    return {
        "deviation_arcsec": rad_to_arcsec(np.abs(np.diff(systematic)) - nominal_step).tolist(),
        "realized_deviation_arcsec": rad_to_arcsec(np.abs(np.diff(realized)) - nominal_step).tolist(),
        "positioning_error_arcsec": rad_to_arcsec(systematic - cmd).tolist(),
    }


def abbe_truth(bench: Bench, angles_deg: np.ndarray, directions: np.ndarray) -> dict:
    """Per step (commanded angle, direction): the systematic encoder error and εz, arcsec.

    The encoder error is what a noise-free encoder misreads at the step's systematic actual
    angle: Abbe shift/rE, eccentricity and graduation. Also the polygon's true face errors.
    """
    enc, eps = [], []
    for a, d in zip(angles_deg, directions):
        cmd = bench.quantise_command(math.radians(a))
        e = float(bench.positioning_error_rad(cmd, int(d)))
        with bench.stage_state(cmd, cmd + e):
            enc.append(rad_to_arcsec(bench.encoder_error_rad()))
        eps.append(rad_to_arcsec(e))
    return {"encoder_error_arcsec": np.round(enc, 6).tolist(), "positioning_error_arcsec": np.round(eps, 6).tolist(),
            "face_error_arcsec": np.round(bench.face_errors_arcsec, 6).tolist()}
