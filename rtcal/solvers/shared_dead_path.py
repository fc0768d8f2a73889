"""Joint self-calibration with one dead path per uninterrupted tracking segment (beyond the paper).

The tracer's count is continuous while it tracks, so every length of a segment shares one
dead path D_s. Solving all stations together with

    f_ij = |A_i − P_j| − D_s(i,j) − l_ij

removes the near-degeneracy of the per-station model (a station's position along the line of
sight against its own d): with the paper's geometry and 0.2 µm noise the deviation error drops
from about 3″ to about 0.5″ RMS (docs/paper000.md; measured in tests/test_shared_dead_path.py).
CMM points are taken as exact, as in the paper. Lengths in mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rtcal.solvers.paper000 import (
    StationChain,
    chain_from_stations,
    cumulative_function,
)
from rtcal.solvers.selfcal import initial_guesses
from rtcal.solvers.station_budget import (
    StationBudget,
    StationNoiseModel,
    StationObservations,
    station_budget,
)
from rtcal.solvers.station_data import MultistationData


@dataclass(frozen=True)
class SharedDeadPathEstimate:
    centers_mm: np.ndarray  # m×3
    dead_paths_mm: np.ndarray  # one per segment, in segment order
    segment_ids: np.ndarray  # the segment numbers the dead paths belong to
    rms_residual_um: float
    chain: StationChain
    budget: StationBudget
    converged: bool
    message: str


def solve_shared_dead_path(
    data: MultistationData,
    first_station_guess_mm: np.ndarray,
    axis_point_mm: np.ndarray = np.zeros(3),
    noise: StationNoiseModel = StationNoiseModel(),
) -> SharedDeadPathEstimate:
    """Stations and segment dead paths from n×m lengths whose segment numbers are ``data.segments``."""
    points = np.asarray(data.points_mm, dtype=float)
    lengths = np.asarray(data.lengths_mm, dtype=float)
    nominal_angles_rad = np.deg2rad(data.nominal_angles_deg)
    n, m = lengths.shape
    valid = np.isfinite(lengths)  # NaN: a reading that was skipped
    pi, sj = np.nonzero(valid)  # point and station of each observation
    obs = lengths[valid]
    if len(obs) < 3 * m + 1:
        raise ValueError(f"{len(obs)} lengths for {3 * m} station coordinates and the dead paths")
    seg_ids, seg_index = np.unique(np.asarray(data.segments)[valid], return_inverse=True)
    k = len(seg_ids)
    guess = initial_guesses(first_station_guess_mm, nominal_angles_rad, np.asarray(axis_point_mm, float), points, lengths)
    start = np.linalg.norm(points[pi] - guess[sj, :3], axis=1) - obs
    d0 = [float(np.mean(start[seg_index == s])) for s in range(k)]
    x0 = np.concatenate([guess[:, :3].ravel(), d0])
    rows = np.arange(len(obs))

    def residuals(x: np.ndarray) -> np.ndarray:
        centers = x[: 3 * m].reshape(m, 3)
        return np.linalg.norm(points[pi] - centers[sj], axis=1) - x[3 * m :][seg_index] - obs

    def jacobian(x: np.ndarray) -> np.ndarray:
        centers = x[: 3 * m].reshape(m, 3)
        diff = centers[sj] - points[pi]
        unit = diff / np.linalg.norm(diff, axis=1)[:, None]
        J = np.zeros((len(obs), 3 * m + k))
        for c in range(3):
            J[rows, 3 * sj + c] = unit[:, c]
        J[rows, 3 * m + seg_index] = -1.0
        return J

    from scipy.optimize import least_squares  # here: scipy.optimize costs every command 0.2 s at import

    sol = least_squares(residuals, x0, jac=jacobian, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    centers = sol.x[: 3 * m].reshape(m, 3)
    chain = chain_from_stations(centers, nominal_angles_rad)
    observations = StationObservations(pi, sj, data.stage_visits[pi, sj], points, data.point_visit_counts,
                                       data.run_fraction()[0][pi, sj],
                                       None if (mo := data.material_offsets_k()) is None else mo[0][pi, sj])
    budget = station_budget(sol.jac, sol.fun, np.arange(3 * m).reshape(m, 3), observations, centers, nominal_angles_rad,
                            chain.center_mm, chain.plane.normal, cumulative_function(nominal_angles_rad), noise)
    converged = bool(sol.success) and sol.status > 0
    return SharedDeadPathEstimate(
        centers, sol.x[3 * m :].copy(), seg_ids, float(np.sqrt(np.mean(sol.fun**2))) * 1e3,
        chain, budget, converged, str(sol.message),
    )
