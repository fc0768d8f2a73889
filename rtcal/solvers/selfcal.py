"""Self-calibration of laser-tracer stations from interferometric lengths (seed 000, eqs. 1–10).

The paper's per-station model: for station j the unknowns are its reference centre
(X, Y, Z) and a dead path d, and the CMM points are taken as exact, so that

    f_i(X, Y, Z, d) = |A_i − P_j| − d − l_ij        (eq. 5)

is solved station by station with the LM iteration of :mod:`rtcal.solvers.lm`.
When the tracer was re-referenced within a station's lengths (a beam break, a resumed run),
each tracking segment gets its own d: x = (X, Y, Z, d_0, …, d_k−1). With one segment this is
exactly eq. 5. All lengths in mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rtcal.solvers.lm import LMParameters, LMResult, levenberg_marquardt


@dataclass(frozen=True)
class StationFit:
    """One station: centre (mm), dead path (mm), fit diagnostics."""

    center_mm: np.ndarray
    dead_path_mm: float  # of the first segment
    rms_residual_um: float
    jacobian: np.ndarray  # of the residuals at the solution, columns (X, Y, Z, d…)
    residuals: np.ndarray  # eq. 5 at the solution, mm
    iterations: int
    converged: bool
    message: str


def station_residuals(x: np.ndarray, points_mm: np.ndarray, lengths_mm: np.ndarray, seg: np.ndarray | None = None) -> np.ndarray:
    """Eq. 5: |A_i − P| − d_seg(i) − l_i for x = (X, Y, Z, d_0, …)."""
    d = x[3:][seg] if seg is not None else x[3]
    return np.linalg.norm(points_mm - x[:3], axis=1) - d - lengths_mm


def station_jacobian(x: np.ndarray, points_mm: np.ndarray, lengths_mm: np.ndarray, seg: np.ndarray | None = None) -> np.ndarray:
    """Eq. 10's matrix: ((X−x_i)/L, (Y−y_i)/L, (Z−z_i)/L, −1 in the column of the point's segment)."""
    diff = x[:3] - points_mm
    dist = np.linalg.norm(diff, axis=1)
    k = len(x) - 3
    d_cols = np.zeros((len(points_mm), k))
    d_cols[np.arange(len(points_mm)), seg if seg is not None else 0] = -1.0
    return np.column_stack([diff / dist[:, None], d_cols])


def _fit(result: LMResult) -> StationFit:
    rms = float(np.sqrt(np.mean(result.residuals**2))) * 1e3
    return StationFit(
        center_mm=result.x[:3].copy(),
        dead_path_mm=float(result.x[3]),
        rms_residual_um=rms,
        jacobian=np.asarray(result.jacobian, float),
        residuals=np.asarray(result.residuals, float),
        iterations=result.iterations,
        converged=result.converged,
        message=result.message,
    )


def solve_station(
    points_mm: np.ndarray, lengths_mm: np.ndarray, x0: np.ndarray, params: LMParameters = LMParameters(),
    seg: np.ndarray | None = None,
) -> StationFit:
    """Self-calibrate one station with the paper's LM from the guess x0 = (X, Y, Z, d_0, …).

    ``seg`` gives each length's segment as an index into the d's (None: one segment)."""
    points_mm = np.asarray(points_mm, dtype=float)
    lengths_mm = np.asarray(lengths_mm, dtype=float)
    result = levenberg_marquardt(
        lambda x: station_residuals(x, points_mm, lengths_mm, seg),
        lambda x: station_jacobian(x, points_mm, lengths_mm, seg),
        np.asarray(x0, dtype=float),
        params,
    )
    return _fit(result)


def solve_station_scipy(points_mm: np.ndarray, lengths_mm: np.ndarray, x0: np.ndarray, seg: np.ndarray | None = None) -> StationFit:
    """The same problem solved by scipy's MINPACK LM: the independent cross-check."""
    points_mm = np.asarray(points_mm, dtype=float)
    lengths_mm = np.asarray(lengths_mm, dtype=float)
    from scipy.optimize import least_squares  # here: scipy.optimize costs every command 0.2 s at import

    sol = least_squares(
        station_residuals,
        np.asarray(x0, dtype=float),
        jac=station_jacobian,
        args=(points_mm, lengths_mm, seg),
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
    length, d = |A_1 − P_j| − l_1j (eq. 1), or the first point measured at that station.
    """
    first = np.asarray(first_guess_mm, dtype=float)
    rel = first[:2] - axis_point_mm[:2]
    delta = np.asarray(angles_rad, dtype=float) - angles_rad[0]
    c, s = np.cos(delta), np.sin(delta)
    xy = np.column_stack([c * rel[0] - s * rel[1], s * rel[0] + c * rel[1]]) + axis_point_mm[:2]
    centers = np.column_stack([xy, np.full(len(delta), first[2])])
    first_row = np.argmax(np.isfinite(lengths_mm), axis=0)
    cols = np.arange(lengths_mm.shape[1])
    d = np.linalg.norm(points_mm[first_row] - centers, axis=1) - lengths_mm[first_row, cols]
    return np.column_stack([centers, d])
