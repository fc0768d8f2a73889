"""The seed-000 estimator as printed: per-station LM → SVD plane → projection → circle → angles.

Input is the logged dataset as arrays; output is a typed result. Differences between the
printed equations and the printed figures are recorded in :data:`PAPER_NOTES` so that the
results and the report can say them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rtcal.solvers.geometry import (
    Plane,
    adjacent_angles_rad,
    algorithm_error_rad,
    fit_circle_center,
    fit_plane,
    plane_tilt_rad,
    project_to_plane,
    sigma_eq34,
)
from rtcal.solvers.lm import LMParameters
from rtcal.solvers.selfcal import StationFit, initial_guesses, solve_station
from rtcal.units import rad_to_arcsec

PAPER_NOTES: tuple[str, ...] = (
    "Eq. 29 is printed as xc = uc - X'; the centring u = X - X' makes it xc = uc + X' (likewise yc), "
    "which rtcal uses; it reproduces the paper's centre.",
    "Eq. 34 is computed as printed with m = number of stations; on the paper's Table 3 it gives "
    "0.80 arcsec where the paper reports 0.9 (m = 10 would give 0.88).",
    "Eq. 36 is computed as printed at the nominal step angle; with the paper's fitted plane it gives "
    "about 3e-5 arcsec where the paper reports 0.4 arcsec.",
    "Eq. 33 is a per-step deviation (actual minus nominal angle between adjacent stations), not the "
    "cumulative positioning error; rtcal reports both.",
)


@dataclass(frozen=True)
class StationChain:
    """Plane, projection, circle and angles from a set of station centres."""

    plane: Plane
    projected_mm: np.ndarray
    plane_lambda_mm: np.ndarray
    center_mm: np.ndarray
    step_angles_rad: np.ndarray
    deviation_arcsec: np.ndarray
    sigma_arcsec: float
    algorithm_error_arcsec: float


@dataclass(frozen=True)
class PaperEstimate:
    """The paper estimator's result; ``uncertainty_arcsec`` is rtcal's addition (1σ, linearised)."""

    stations: list[StationFit]
    chain: StationChain
    uncertainty_arcsec: np.ndarray


def chain_from_stations(stations_mm: np.ndarray, nominal_angles_rad: np.ndarray) -> StationChain:
    """Eqs. 18–36 from station centres (m×3, mm) and their nominal table angles (rad)."""
    stations_mm = np.asarray(stations_mm, dtype=float)
    nominal = np.asarray(nominal_angles_rad, dtype=float)
    if stations_mm.shape[0] < 3:
        raise ValueError("at least 3 stations are needed for a plane and a circle")
    plane = fit_plane(stations_mm)
    projected, lam = project_to_plane(stations_mm, plane)
    center = fit_circle_center(projected, plane)
    steps = adjacent_angles_rad(projected, center)
    nominal_steps = np.abs(np.diff(nominal))
    deviation = rad_to_arcsec(steps - nominal_steps)
    sigma = sigma_eq34(deviation, len(stations_mm))
    alpha = plane_tilt_rad(plane)
    step = float(np.median(nominal_steps))
    alg = abs(rad_to_arcsec(algorithm_error_rad(step, alpha)))
    return StationChain(plane, projected, lam, center, steps, deviation, sigma, alg)


def block_covariance(station_cov_mm2: list[np.ndarray]) -> np.ndarray:
    """3m×3m covariance of independent stations from their (X, Y, Z, …) covariances."""
    m = len(station_cov_mm2)
    cov = np.zeros((3 * m, 3 * m))
    for j, c in enumerate(station_cov_mm2):
        cov[3 * j : 3 * j + 3, 3 * j : 3 * j + 3] = c[:3, :3]
    return cov


def deviation_uncertainty(stations_mm: np.ndarray, cov_mm2: np.ndarray, nominal_angles_rad: np.ndarray) -> np.ndarray:
    """1σ of each deviation (arcsec): the 3m×3m station covariance propagated through the chain.

    The chain's Jacobian is taken by central differences (0.1 µm steps, far inside its linear
    range).
    """
    base = np.asarray(stations_mm, dtype=float)
    m = base.shape[0]
    h = 1e-4
    jac = np.zeros((m - 1, 3 * m))
    for k in range(3 * m):
        plus, minus = base.copy(), base.copy()
        plus.flat[k] += h
        minus.flat[k] -= h
        jac[:, k] = (
            chain_from_stations(plus, nominal_angles_rad).deviation_arcsec
            - chain_from_stations(minus, nominal_angles_rad).deviation_arcsec
        ) / (2 * h)
    return np.sqrt(np.clip(np.diag(jac @ cov_mm2 @ jac.T), 0.0, None))


def _station_problem(points_mm: np.ndarray, lengths: np.ndarray, segments: np.ndarray, guess: np.ndarray):
    """One station's valid lengths, their segment indices and a start with one d per segment."""
    valid = np.isfinite(lengths)
    seg_ids, seg = np.unique(segments[valid], return_inverse=True)
    if valid.sum() < 3 + len(seg_ids) + 1:
        raise ValueError(f"a station has {int(valid.sum())} lengths for {3 + len(seg_ids)} unknowns")
    pts, ls = points_mm[valid], lengths[valid]
    dist = np.linalg.norm(pts - guess[:3], axis=1)
    d0 = [float(np.mean((dist - ls)[seg == s])) for s in range(len(seg_ids))]
    return pts, ls, seg, np.concatenate([guess[:3], d0])


def solve_paper(
    points_mm: np.ndarray,
    lengths_mm: np.ndarray,
    nominal_angles_rad: np.ndarray,
    first_station_guess_mm: np.ndarray,
    axis_point_mm: np.ndarray = np.zeros(3),
    params: LMParameters = LMParameters(),
    segments: np.ndarray | None = None,
) -> PaperEstimate:
    """Run the printed method on n points × m stations of lengths (mm, n×m; NaN: not measured).

    ``segments`` (n×m) names each length's tracking segment; a station whose lengths span
    several segments gets one dead path per segment (the printed model has one)."""
    points_mm = np.asarray(points_mm, dtype=float)
    lengths_mm = np.asarray(lengths_mm, dtype=float)
    n, m = lengths_mm.shape
    if points_mm.shape != (n, 3):
        raise ValueError(f"points are {points_mm.shape}, lengths are {lengths_mm.shape}: need n×3 and n×m")
    segments = np.zeros((n, m), int) if segments is None else np.asarray(segments)
    guesses = initial_guesses(
        first_station_guess_mm, nominal_angles_rad, np.asarray(axis_point_mm, float), points_mm, lengths_mm
    )
    fits = []
    for j in range(m):
        pts, ls, seg, x0 = _station_problem(points_mm, lengths_mm[:, j], segments[:, j], guesses[j])
        fits.append(solve_station(pts, ls, x0, params, seg if seg.max() > 0 else None))
    centers = np.array([f.center_mm for f in fits])
    chain = chain_from_stations(centers, nominal_angles_rad)
    unc = deviation_uncertainty(centers, block_covariance([f.covariance_mm2 for f in fits]), nominal_angles_rad)
    return PaperEstimate(fits, chain, unc)
