"""The Levenberg–Marquardt iteration of seed 000 (eqs. 6–17), for any small least-squares problem.

Minimises F(x) = ½‖f(x)‖² (eq. 6). Each iteration solves (JᵀJ + µI)h = −Jᵀf (eq. 10),
rates the step by the gain ratio r = ΔF/Δq (eq. 16), updates µ by eq. 17 (×0.1 above 0.75,
×10 below 0.25), and takes the Armijo step βᵐh with the smallest m ≥ 0 such that
F(x + βᵐh) ≤ F(x) + σβᵐ gᵀh (eqs. 11–14, which the paper writes once per unknown; one
condition on F is what they mean together).

The paper's "allowable error ε" has no printed test. Taken alone, "the accepted step is below
ε" stops too early: a damped step is small whenever µ is large against the smallest eigenvalue
of JᵀJ (the station's weak line-of-sight direction), and started at the true station the
printed test stopped up to 2 µm (6″) from the least-squares optimum while calling it converged.
So the iteration is converged only when the accepted step is below ε in every component (ε in
the unknowns' unit, mm here) **and** the undamped Gauss–Newton step — to first order the
distance to the optimum — is below ``gn_tolerance``; or when the gradient vanishes to machine
precision. It gives up after ``max_iterations`` (``converged`` False, saying so).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

ResidualFn = Callable[[np.ndarray], np.ndarray]
JacobianFn = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class LMParameters:
    """The paper's tuning: β and σ of the line search, ε the allowable step, µ0 the damping."""

    beta: float = 0.55
    sigma: float = 0.4
    epsilon: float = 1e-4
    mu0: float | None = 0.75  # None: µ0 = ‖f(x0)‖, the paper's rule (which gave it 0.75)
    max_iterations: int = 200
    max_line_search: int = 60
    gn_tolerance: float = 1e-6  # mm: the undamped Gauss–Newton step must be below this too (1 nm ≈ 0.003″ at 65 mm)

    def __post_init__(self) -> None:
        if not (0.0 < self.beta < 1.0 and 0.0 < self.sigma < 1.0):
            raise ValueError("β and σ must lie in (0, 1)")
        if self.epsilon <= 0.0 or self.gn_tolerance <= 0.0:
            raise ValueError("ε and the Gauss–Newton tolerance must be positive")


@dataclass(frozen=True)
class LMResult:
    """Solution, final residuals and how the iteration ended."""

    x: np.ndarray
    residuals: np.ndarray
    jacobian: np.ndarray
    iterations: int
    converged: bool
    message: str
    mu: float


def levenberg_marquardt(
    fun: ResidualFn, jac: JacobianFn, x0: np.ndarray, params: LMParameters = LMParameters()
) -> LMResult:
    """Minimise ½‖fun(x)‖² from x0 with the paper's LM iteration and line search."""
    x = np.asarray(x0, dtype=float).copy()
    f = fun(x)
    cost = 0.5 * float(f @ f)
    mu = float(np.linalg.norm(f)) if params.mu0 is None else float(params.mu0)
    mu = max(mu, 1e-12)
    eye = np.eye(x.size)
    for iteration in range(1, params.max_iterations + 1):
        J = jac(x)
        g = J.T @ f
        if np.max(np.abs(g)) <= 1e-15 * max(1.0, np.max(np.abs(J))):
            return LMResult(x, f, J, iteration - 1, True, "gradient vanished", mu)
        JtJ = J.T @ J
        h = np.linalg.solve(JtJ + mu * eye, -g)
        predicted = float(g @ h + 0.5 * h @ JtJ @ h)  # q(h) − q(0), negative
        f_full = fun(x + h)
        actual = 0.5 * float(f_full @ f_full) - cost
        ratio = actual / predicted if predicted < 0.0 else -np.inf
        if ratio > 0.75:
            mu *= 0.1
        elif ratio < 0.25:
            mu *= 10.0
        slope = float(g @ h)
        step = 1.0
        for _ in range(params.max_line_search):
            f_try = f_full if step == 1.0 else fun(x + step * h)
            cost_try = 0.5 * float(f_try @ f_try)
            if cost_try <= cost + params.sigma * step * slope:
                break
            step *= params.beta
        else:
            return LMResult(x, f, J, iteration, False, "not converged: the line search found no descent", mu)
        x = x + step * h
        f, cost = f_try, cost_try
        if np.max(np.abs(step * h)) < params.epsilon:
            J = jac(x)
            gauss_newton = np.linalg.lstsq(J, -f, rcond=None)[0]
            if np.max(np.abs(gauss_newton)) < params.gn_tolerance:
                return LMResult(x, f, J, iteration, True, "step below ε and Gauss–Newton step below tolerance", mu)
    return LMResult(x, f, jac(x), params.max_iterations, False,
                    f"not converged: iteration limit ({params.max_iterations}) reached", mu)
