"""Self-calibration of laser-tracer stations from interferometric lengths (seed 000, eqs. 1–10).

The paper's per-station model: for station j the unknowns are its reference centre
(X, Y, Z) and a dead path d, and the CMM points are taken as exact, so that

    f_i(X, Y, Z, d) = |A_i − P_j| − d − l_ij        (eq. 5)

is solved station by station with the LM iteration of :mod:`rtcal.solvers.lm`.
All lengths in mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from rtcal.solvers.lm import LMParameters, LMResult, levenberg_marquardt


@dataclass(frozen=True)
class StationFit:
    """One station: centre (mm), dead path (mm), fit diagnostics."""

    center_mm: np.ndarray
    dead_path_mm: float
    rms_residual_um: float
    covariance_mm2: np.ndarray  # 4×4 of (X, Y, Z, d) from σ̂²(JᵀJ)⁻¹
    iterations: int
    converged: bool
    message: str


def station_residuals(x: np.ndarray, points_mm: np.ndarray, lengths_mm: np.ndarray) -> np.ndarray:
    """Eq. 5: |A_i − P| − d − l_i for x = (X, Y, Z, d)."""
    return np.linalg.norm(points_mm - x[:3], axis=1) - x[3] - lengths_mm


def station_jacobian(x: np.ndarray, points_mm: np.ndarray, lengths_mm: np.ndarray) -> np.ndarray:
    """Eq. 10's n×4 matrix: ((X−x_i)/L, (Y−y_i)/L, (Z−z_i)/L, −1)."""
    diff = x[:3] - points_mm
    dist = np.linalg.norm(diff, axis=1)
    return np.column_stack([diff / dist[:, None], -np.ones(len(points_mm))])


def _covariance(result_residuals: np.ndarray, jacobian: np.ndarray) -> np.ndarray:
    """σ̂²(JᵀJ)⁻¹ with σ̂² = ‖f‖²/(n − p): the linearised covariance of the unknowns."""
    n, p = jacobian.shape
    dof = max(n - p, 1)
    s2 = float(result_residuals @ result_residuals) / dof
    return s2 * np.linalg.pinv(jacobian.T @ jacobian)


def _fit(result: LMResult) -> StationFit:
    rms = float(np.sqrt(np.mean(result.residuals**2))) * 1e3
    return StationFit(
        center_mm=result.x[:3].copy(),
        dead_path_mm=float(result.x[3]),
        rms_residual_um=rms,
        covariance_mm2=_covariance(result.residuals, result.jacobian),
        iterations=result.iterations,
        converged=result.converged,
        message=result.message,
    )


def solve_station(
    points_mm: np.ndarray, lengths_mm: np.ndarray, x0: np.ndarray, params: LMParameters = LMParameters()
) -> StationFit:
    """Self-calibrate one station with the paper's LM from the guess x0 = (X, Y, Z, d)."""
    points_mm = np.asarray(points_mm, dtype=float)
    lengths_mm = np.asarray(lengths_mm, dtype=float)
    result = levenberg_marquardt(
        lambda x: station_residuals(x, points_mm, lengths_mm),
        lambda x: station_jacobian(x, points_mm, lengths_mm),
        np.asarray(x0, dtype=float),
        params,
    )
    return _fit(result)


def solve_station_scipy(points_mm: np.ndarray, lengths_mm: np.ndarray, x0: np.ndarray) -> StationFit:
    """The same problem solved by scipy's MINPACK LM: the independent cross-check."""
    points_mm = np.asarray(points_mm, dtype=float)
    lengths_mm = np.asarray(lengths_mm, dtype=float)
    sol = least_squares(
        station_residuals,
        np.asarray(x0, dtype=float),
        jac=station_jacobian,
        args=(points_mm, lengths_mm),
        method="lm",
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
    )
    result = LMResult(sol.x, sol.fun, sol.jac, int(sol.nfev), bool(sol.success), str(sol.message), 0.0)
    return _fit(result)


def initial_guesses(
    first_guess_mm: np.ndarray,
    angles_rad: np.ndarray,
    axis_point_mm: np.ndarray,
    points_mm: np.ndarray,
    lengths_mm: np.ndarray,
) -> np.ndarray:
    """Starting (X, Y, Z, d) for every station.

    Station 1's nominal centre is rotated about the nominal axis (vertical through
    ``axis_point_mm``) by each station's nominal angle; d follows from the first point's
    length, d = |A_1 − P_j| − l_1j (eq. 1).
    """
    first = np.asarray(first_guess_mm, dtype=float)
    rel = first[:2] - axis_point_mm[:2]
    delta = np.asarray(angles_rad, dtype=float) - angles_rad[0]
    c, s = np.cos(delta), np.sin(delta)
    xy = np.column_stack([c * rel[0] - s * rel[1], s * rel[0] + c * rel[1]]) + axis_point_mm[:2]
    centers = np.column_stack([xy, np.full(len(delta), first[2])])
    d = np.linalg.norm(points_mm[0] - centers, axis=1) - lengths_mm[0, :]
    return np.column_stack([centers, d])
