"""The budget's mathematics in its dense N×N form: the reference the structured code is checked against.

These are the forms rtcal computed before issue 43 (rtcal/solvers/uncertainty.py at ecb2add): V built
as an N×N matrix, REML by Woodbury over dense N×(q + p) factors, the residual test projected with
the full SVD of the Jacobian and a Cholesky factor of QᵀVQ, the estimator's influence as pinv(J).
They are the clearest statement of what is computed, and cost O(N³): for small networks only
(tests/test_structured_budget.py compares them with rtcal.solvers.structure to 1e-9).
"""

from __future__ import annotations

import numpy as np

from rtcal.solvers.structure import dense_effect
from rtcal.solvers.uncertainty import ResidualCheck, Source, residual_check


def dense_covariance(sources: list[Source], rows: int, scales: dict[str, float] | None = None) -> np.ndarray:
    """V = Σ θ·F·Fᵀ, N×N (θ = 1 unless ``scales`` names the source)."""
    V = np.zeros((rows, rows))
    for s in sources:
        e = dense_effect(s.effect)
        t = (scales or {}).get(s.name, 1.0)
        V += t * (np.diag(e**2) if e.ndim == 1 else e @ e.T)
    return V


def dense_residual_check(residuals: np.ndarray, covariance: np.ndarray, parameters: int,
                         jacobian: np.ndarray | None = None) -> ResidualCheck | None:
    """The residual test with V whole: z = Qᵀr (Q the full SVD's left null space) against QᵀVQ by its Cholesky
    factor, or rᵀV⁻¹r with ν = N − parameters — rtcal keeps this form for a dense V (the R-test's few poses)."""
    return residual_check(residuals, covariance, parameters, jacobian=jacobian)


def dense_reml(jacobian: np.ndarray, residuals: np.ndarray, sources: list[Source], max_iterations: int = 60,
               tolerance: float = 1e-4, floor: float = 1e-14) -> tuple[dict[str, float], dict[str, float], int]:
    """REML scales of the Type A sources by Fisher scoring with P = V⁻¹ − V⁻¹J(JᵀV⁻¹J)⁺JᵀV⁻¹ built N×N,
    with the start, floor, step and stop of rtcal.solvers.uncertainty.reml_scales: (scales, their
    standard errors, iterations)."""
    J = np.asarray(jacobian, float)
    r = np.asarray(residuals, float)
    N, p = J.shape
    a_sources = [s for s in sources if s.type == "A"]
    mats = {s.name: dense_covariance([s], N) for s in sources}
    total_trace = sum(float(np.trace(mats[s.name])) for s in a_sources)
    theta = np.full(len(a_sources), max(float(r @ r) / max(total_trace * (1.0 - p / max(N, 1)), 1e-300), floor))
    info = np.eye(len(theta))
    it = 0
    for it in range(1, max_iterations + 1):
        scale = {s.name: t for s, t in zip(a_sources, theta)}
        V = sum((scale.get(s.name, 1.0) * mats[s.name] for s in sources), np.zeros((N, N))) + np.eye(N) * 1e-300
        Vi = np.linalg.inv(V)
        P = Vi - Vi @ J @ np.linalg.pinv(J.T @ Vi @ J) @ J.T @ Vi
        Pr = P @ r
        score = np.array([0.5 * (Pr @ mats[s.name] @ Pr - np.trace(P @ mats[s.name])) for s in a_sources])
        PV = [P @ mats[s.name] for s in a_sources]
        info = np.array([[0.5 * np.sum(a * b.T) for b in PV] for a in PV])
        step = np.linalg.lstsq(info, score, rcond=None)[0]
        new = np.maximum(theta + step, floor * np.max(np.abs(theta)) + 1e-300)
        change = np.max(np.abs(new - theta) / np.maximum(np.abs(theta), 1e-300))
        theta = new
        if change < tolerance:
            break
    cov = np.linalg.pinv(info)
    return ({s.name: float(t) for s, t in zip(a_sources, theta)},
            {s.name: float(np.sqrt(max(cov[k, k], 0.0))) for k, s in enumerate(a_sources)}, it)


def dense_propagate(influence: np.ndarray, sources: list[Source], scales: dict[str, float],
                    output_jacobian: np.ndarray) -> list[np.ndarray]:
    """G·H·θF·Fᵀ·Hᵀ·Gᵀ per source, F dense."""
    G = np.asarray(output_jacobian, float) @ np.asarray(influence, float)
    out = []
    for s in sources:
        F = dense_effect(s.effect)
        F = np.diag(F) if F.ndim == 1 else F
        out.append(scales.get(s.name, 1.0) * (G @ F @ F.T @ G.T))
    return out
