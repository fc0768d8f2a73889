"""Cross-calibration of table and polygon by closure: no trusted polygon needed (beyond seed 001).

The polygon is seated at several whole-face offsets; each autocollimator reading is

    x = εz(table angle) + f(face in front) + c(seating, direction)

Face errors close (Σf = 0, the faces go once round), and the table error is known up to one
constant per set of table angles that share seating offsets (Σεz = 0 over each such set: both
directions of a pass share the autocollimator's zero, so a reversal between them stays in
εz). With at least two seatings a whole number of faces apart, and offsets whose differences
have no factor in common with the face count, the system is solvable; the least-squares
solution under these constraints (KKT) gives both error sets, their covariance
σ̂²·(constrained inverse), and the linear map from the readings to them (for propagation).
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
    solution_map: np.ndarray  # (table, faces, groups) = solution_map @ values


def solve_closure(
    values: np.ndarray,
    table_index: np.ndarray,
    face_index: np.ndarray,
    group_index: np.ndarray,
    table_direction: np.ndarray,
    faces: int,
) -> ClosureResult:
    """Solve x = εz[table] + f[face] + c[group]; ``table_direction[t]`` labels table key t's direction
    (kept for the caller; the constraints follow from which keys share groups)."""
    x = np.asarray(values, float)
    t_idx, f_idx, g_idx = (np.asarray(a, int) for a in (table_index, face_index, group_index))
    n_t, n_g = len(table_direction), int(g_idx.max()) + 1
    p = n_t + faces + n_g
    A = np.zeros((len(x), p))
    rows = np.arange(len(x))
    A[rows, t_idx] = 1.0
    A[rows, n_t + f_idx] = 1.0
    A[rows, n_t + faces + g_idx] = 1.0
    components = _table_components(t_idx, g_idx, n_t, n_g)
    C = np.zeros((1 + len(components), p))
    C[0, n_t : n_t + faces] = 1.0
    for r, keys in enumerate(components, start=1):
        C[r, keys] = 1.0
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
    solution_map = kkt_inv[:p, :p] @ A.T
    resid = x - A @ coef
    dof = max(len(x) - (p - len(C)), 1)
    sigma = float(np.sqrt(resid @ resid / dof))
    cov = sigma**2 * kkt_inv[:p, :p]
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return ClosureResult(coef[:n_t], sd[:n_t], coef[n_t : n_t + faces], sd[n_t : n_t + faces],
                         coef[n_t + faces :], float(np.sqrt(np.mean(resid**2))), sigma, solution_map)


def _table_components(t_idx: np.ndarray, g_idx: np.ndarray, n_t: int, n_g: int) -> list[list[int]]:
    """Sets of table keys tied together through shared groups (each has one free constant)."""
    parent = list(range(n_t + n_g))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for t, g in zip(t_idx, g_idx):
        parent[find(int(t))] = find(n_t + int(g))
    out: dict[int, list[int]] = {}
    for t in range(n_t):
        out.setdefault(find(t), []).append(t)
    return list(out.values())
