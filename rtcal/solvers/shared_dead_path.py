"""Joint self-calibration with one dead path per uninterrupted tracking segment (beyond the paper).

The tracer's count is continuous while it tracks, so every length of a segment shares one
dead path D_s. Solving all stations together with

    f_ij = |A_i − P_j| − D_s(i,j) − l_ij

removes the near-degeneracy of the per-station model (a station's position along the line of
sight against its own d): with the paper's geometry and 0.2 µm noise the deviation error drops
from about 3″ to about 0.5″ RMS (docs/paper000.md; measured in tests/test_shared_dead_path.py).
CMM points are taken as exact, as in the paper. Lengths in mm. A length touches one station's three
coordinates and one dead path: the Jacobian is sparse and the normal equations are (3m + segments)²,
whatever the number of lengths (:func:`least_squares_sparse`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

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
    air_course_hats,
    air_course_seen,
    air_course_tested_steps,
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
    solve_air_course: bool = True,
) -> SharedDeadPathEstimate:
    """Stations and segment dead paths from n×m lengths whose segment numbers are ``data.segments``.

    Without an air sensor (``noise.air_index_bound``) and with ``solve_air_course`` the uncorrected index's course over
    the run is solved beside them where the lengths see it (:func:`rtcal.solvers.station_budget.air_course_seen`);
    elsewhere the budget quotes the stated range's worst case."""
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
    # the table's growth per sensed kelvin beyond the α the lengths were corrected with, ppm/K (solved when given)
    growth = None if data.growth_mm_per_ppm is None else np.asarray(data.growth_mm_per_ppm[0], float)[valid]
    g = 0 if growth is None else 1
    x0 = np.concatenate([guess[:, :3].ravel(), d0, np.zeros(g)])
    run_fraction = data.run_fraction()[0][pi, sj]
    fit = _adjust(points, pi, sj, seg_index, obs, m, k, growth, None, x0)
    x, f, J, converged, message = fit
    course: np.ndarray | None = None  # the air's course (no sensor): its columns, mm per ppm
    observations = StationObservations(pi, sj, data.stage_visits[pi, sj], points, data.point_visit_counts,
                                       run_fraction,
                                       None if (mo := data.material_offsets_k()) is None else mo[0][pi, sj])
    if converged and noise.air_index_bound > 0 and solve_air_course:
        # no air sensor: the course beside the model (hats; the points are known, so even its constant is seen), then
        # where the course jumps a free step at each reading there, chosen as the residual test chooses them (its
        # weighted fit of the hats on the fit without the course); each pass kept only where the lengths see it
        centers0 = x[: 3 * m].reshape(m, 3)
        chain0 = chain_from_stations(centers0, nominal_angles_rad)
        distances_mm = np.linalg.norm(points[pi] - centers0[sj], axis=1)
        hats = air_course_hats(distances_mm, run_fraction, noise, drop_constant=False)
        p = len(x)
        if hats.shape[1] and len(obs) > p + hats.shape[1]:
            seen = _adjust(points, pi, sj, seg_index, obs, m, k, growth, hats, np.concatenate([x, np.zeros(hats.shape[1])]))
            if seen[3] and air_course_seen(_course_sigma_ppm(seen[2], seen[1], p), noise):
                fit, course = seen, hats
                steps = air_course_tested_steps(J, f, observations, centers0, nominal_angles_rad, chain0.center_mm,
                                                chain0.plane.normal, noise)
                if steps.shape[1] and len(obs) > p + hats.shape[1] + steps.shape[1]:
                    both = np.hstack([hats, steps])
                    stepped = _adjust(points, pi, sj, seg_index, obs, m, k, growth, both,
                                      np.concatenate([seen[0], np.zeros(steps.shape[1])]))
                    if not stepped[3]:  # a step the hats and the other steps already span (the test's SVD drops it
                        # from its rank; the normal equations cannot): only the independent steps
                        steps = _independent(np.asarray(seen[2].toarray()), steps)
                        both = np.hstack([hats, steps])
                        stepped = _adjust(points, pi, sj, seg_index, obs, m, k, growth, both,
                                          np.concatenate([seen[0], np.zeros(steps.shape[1])]))
                    if stepped[3]:
                        fit, course = stepped, both
    x, f, J, converged, message = fit
    centers = x[: 3 * m].reshape(m, 3)
    chain = chain_from_stations(centers, nominal_angles_rad)
    budget = station_budget(J, f, np.arange(3 * m).reshape(m, 3), observations, centers, nominal_angles_rad,
                            chain.center_mm, chain.plane.normal, cumulative_function(nominal_angles_rad), noise,
                            air_course_columns=None if course is None else np.arange(3 * m + k + g, len(x)))
    return SharedDeadPathEstimate(
        centers, x[3 * m : 3 * m + k].copy(), seg_ids, float(np.sqrt(np.mean(f**2))) * 1e3,
        chain, budget, converged, message,
    )


def _adjust(points: np.ndarray, pi: np.ndarray, sj: np.ndarray, seg_index: np.ndarray, obs: np.ndarray, m: int,
            k: int, growth: np.ndarray | None, course_mm_per_ppm: np.ndarray | None,
            x0: np.ndarray) -> tuple[np.ndarray, np.ndarray, Any, bool, str]:
    """The least-squares adjustment of stations (3m), segment dead paths (k), the growth κ (when given) and the air's
    course (its columns, when given: each length reads long by course·c)."""
    rows = np.arange(len(obs))
    g = 0 if growth is None else 1
    C = np.zeros((len(obs), 0)) if course_mm_per_ppm is None else np.asarray(course_mm_per_ppm, float)
    c0 = 3 * m + k + g

    def residuals(x: np.ndarray) -> np.ndarray:
        centers = x[: 3 * m].reshape(m, 3)
        f = np.linalg.norm(points[pi] - centers[sj], axis=1) - x[3 * m : 3 * m + k][seg_index] - obs
        if growth is not None:
            f = f - growth * x[3 * m + k]
        return f + C @ x[c0:] if C.shape[1] else f

    def jacobian(x: np.ndarray) -> Any:
        import scipy.sparse as sp

        centers = x[: 3 * m].reshape(m, 3)
        diff = centers[sj] - points[pi]
        unit = diff / np.linalg.norm(diff, axis=1)[:, None]
        values = np.column_stack([unit, -np.ones(len(obs))] + ([] if growth is None else [-growth]))
        cols = np.column_stack([3 * sj[:, None] + np.arange(3), 3 * m + seg_index]
                               + ([] if growth is None else [np.full(len(obs), 3 * m + k)]))
        J = sp.csr_matrix((values.ravel(), (np.repeat(rows, 4 + g), cols.ravel())), shape=(len(obs), c0))
        return sp.hstack([J, sp.csr_matrix(C)]).tocsr() if C.shape[1] else J

    return least_squares_sparse(residuals, jacobian, x0)


def _independent(J: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """The columns of ``steps`` that add to J's span and to each other's (pivoted QR of the steps projected off J, unit
    columns), with 1e3 times the SVD's rank margin: the normal equations square J's condition, so a step nearly in
    the span already stalls the adjustment that the residual test's SVD would still count."""
    from scipy.linalg import qr

    Q, sv, _ = np.linalg.svd(J / np.maximum(np.linalg.norm(J, axis=0), 1e-300), full_matrices=False)
    Q = Q[:, sv > sv[0] * max(J.shape) * np.finfo(float).eps]
    S = steps / np.linalg.norm(steps, axis=0)
    rest = S - Q @ (Q.T @ S)
    _, R, order = qr(rest, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    keep = np.sort(order[: int(np.sum(d > max(d[0], 1e-300) * max(S.shape) * np.finfo(float).eps * 1e3))])
    return steps[:, keep]


def _course_sigma_ppm(J: Any, f: np.ndarray, first: int) -> np.ndarray:
    """The σ of the course's unknowns (columns ``first``…) as the least-squares fit knows them: (JᵀJ)⁻¹ times the
    residuals' variance per degree of freedom (the estimator weighs every length alike; the stated sizes play no part
    in it)."""
    normal = np.asarray((J.T @ J).toarray())
    dof = max(len(f) - normal.shape[0], 1)
    try:
        inverse = np.linalg.inv(normal)
    except np.linalg.LinAlgError:
        return np.full(normal.shape[0] - first, np.inf)
    return np.sqrt(np.abs(np.diag(inverse)[first:]) * float(f @ f) / dof)


STEP_TOLERANCE = 1e-13  # converged: the Gauss–Newton step below this share of the unknowns' size (mm: 0.1 pm at 1 m)


def least_squares_sparse(fun: Callable[[np.ndarray], np.ndarray], jac: Callable[[np.ndarray], Any], x0: np.ndarray,
                         max_iterations: int = 100) -> tuple[np.ndarray, np.ndarray, Any, bool, str]:
    """min ½‖f(x)‖² for a sparse Jacobian with few unknowns (stations and dead paths): Gauss–Newton on the p×p
    normal equations, Levenberg–Marquardt damped (µ·diag JᵀJ) while a full step does not lower the cost. Converged
    when the undamped step, or its change of every residual, is below :data:`STEP_TOLERANCE` of the unknowns, that
    last step taken (the
    least-squares optimum to rounding, as MINPACK's xtol = 1e-15 before it), or when no step lowers the cost and the step is within 1e-9 of them
    (the rounding floor of many residuals). Returns x, f(x), J(x) (sparse), converged, how it ended."""
    x = np.asarray(x0, float).copy()
    f = fun(x)
    cost = float(f @ f)
    mu = 0.0
    for it in range(1, max_iterations + 1):
        J = jac(x)
        g = np.asarray(J.T @ f)
        normal = np.asarray((J.T @ J).toarray())
        gn = _solve_normal(normal, -g)
        size = 1.0 + float(np.max(np.abs(x)))
        # or the step moves no length by as much: an unknown in other units (the growth κ, ppm/K, whose column is
        # 1e-4 mm per unit) steps by more than the tolerance at rounding while the lengths no longer move
        still = np.max(np.abs(gn)) <= STEP_TOLERANCE * size
        if still or np.max(np.abs(J @ gn)) <= STEP_TOLERANCE * size:
            x = x + gn  # taken too: the optimum to rounding, whatever the unknowns' size
            return x, fun(x), jac(x), True, (f"converged in {it} iterations (the last Gauss–Newton step "
                                               + ("below" if still else "moving no length by")
                                               + f" {STEP_TOLERANCE:g} of the unknowns)")
        step, trial = gn, fun(x + gn)
        diag = np.diag(normal).copy()
        while float(trial @ trial) > cost:
            mu = max(mu * 10.0, 1e-3)
            if mu > 1e10:
                if np.max(np.abs(gn)) <= 1e-9 * size:
                    return x, f, J, True, f"converged in {it - 1} iterations (at the rounding floor)"
                return x, f, J, False, "not converged: no step lowers the cost"
            step = _solve_normal(normal + mu * np.diag(diag), -g)
            trial = fun(x + step)
        mu = mu / 10.0 if mu > 1e-3 else 0.0
        x, f, cost = x + step, trial, float(trial @ trial)
    return x, f, jac(x), False, f"not converged: iteration limit ({max_iterations}) reached"


def _solve_normal(normal: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    try:
        from scipy.linalg import cho_factor, cho_solve

        return np.asarray(cho_solve(cho_factor(normal), rhs))
    except np.linalg.LinAlgError:
        return np.asarray(np.linalg.lstsq(normal, rhs, rcond=None)[0])
