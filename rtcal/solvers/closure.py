"""Cross-calibration of table and polygon by closure: no trusted polygon needed (beyond seed 001).

The polygon is seated at several whole-face offsets; each autocollimator reading is

    x = εz(table angle) + f(face in front) + c(seating, direction)

Face errors close (Σf = 0, the faces go once round), and the table error is known up to a
constant per direction (Σεz = 0). With at least two seatings a whole number of faces apart the
system is solvable; the least-squares solution under these constraints (KKT) gives both error
sets and their covariance σ̂²·(constrained inverse).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ClosureResult:
    table_error: np.ndarray  # per table key, Σ = 0 per direction
    table_sigma: np.ndarray
    face_error: np.ndarray  # per face, Σ = 0
    face_sigma: np.ndarray
    offsets: np.ndarray  # per group
    residual_rms: float
    sigma: float


def solve_closure(
    values: np.ndarray,
    table_index: np.ndarray,
    face_index: np.ndarray,
    group_index: np.ndarray,
    table_direction: np.ndarray,
    faces: int,
) -> ClosureResult:
    """Solve x = εz[table] + f[face] + c[group]; ``table_direction[t]`` labels table key t's direction."""
    x = np.asarray(values, float)
    t_idx, f_idx, g_idx = (np.asarray(a, int) for a in (table_index, face_index, group_index))
    n_t, n_g = len(table_direction), int(g_idx.max()) + 1
    p = n_t + faces + n_g
    A = np.zeros((len(x), p))
    rows = np.arange(len(x))
    A[rows, t_idx] = 1.0
    A[rows, n_t + f_idx] = 1.0
    A[rows, n_t + faces + g_idx] = 1.0
    dirs = np.unique(table_direction)
    C = np.zeros((1 + len(dirs), p))
    C[0, n_t : n_t + faces] = 1.0
    for r, d in enumerate(dirs, start=1):
        C[r, :n_t] = (np.asarray(table_direction) == d).astype(float)
    kkt = np.block([[A.T @ A, C.T], [C, np.zeros((len(C), len(C)))]])
    rhs = np.concatenate([A.T @ x, np.zeros(len(C))])
    try:
        kkt_inv = np.linalg.inv(kkt)
    except np.linalg.LinAlgError:
        raise ValueError("closure is not solvable: the seatings do not connect every face and table angle") from None
    if np.linalg.cond(kkt) > 1e12:
        raise ValueError("closure is not solvable: the seatings do not connect every face and table angle")
    sol = kkt_inv @ rhs
    coef = sol[:p]
    resid = x - A @ coef
    dof = max(len(x) - (p - len(C)), 1)
    sigma = float(np.sqrt(resid @ resid / dof))
    cov = sigma**2 * kkt_inv[:p, :p]
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return ClosureResult(coef[:n_t], sd[:n_t], coef[n_t : n_t + faces], sd[n_t : n_t + faces],
                         coef[n_t + faces :], float(np.sqrt(np.mean(resid**2))), sigma)
