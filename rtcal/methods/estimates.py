"""What every estimate reports, and which one a certificate should quote.

Every estimate under ``results.json["estimates"][name]`` carries the same block: the
cumulative positioning deviation (actual − commanded relative to the first target; ISO 230-1
ECC for a C axis) with its standard uncertainty, expanded uncertainty (k = 2), covariance and
budget, and its per-step differences (seed 000's eq. 33 Δθ) with theirs. ``recommended`` names
the estimate to quote: converged, and the smallest uncertainty among those that did.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from rtcal.solvers.uncertainty import DeviationBudget, difference_matrix

COVERAGE_FACTOR = 2.0


def _round(values, digits: int = 4) -> list:
    return [None if not np.isfinite(v) else round(float(v), digits) for v in np.asarray(values, float).ravel()]


def budget_dict(budget: DeviationBudget, not_included: list[str] | None = None) -> dict[str, Any]:
    """The GUM table: per source its type, input σ and contribution per target; combined u and U."""
    u = budget.uncertainty_arcsec
    return {
        "components": [{
            "source": c.name, "type": c.type, "input_sigma": round(float(c.sigma), 6), "unit": c.unit,
            "estimated_from_data": c.estimated, "note": c.note,
            "contribution_arcsec": _round(c.uncertainty_arcsec),
        } for c in budget.components],
        "combined_arcsec": _round(u),
        "expanded_arcsec": _round(COVERAGE_FACTOR * u),
        "coverage_factor": COVERAGE_FACTOR,
        "not_included": list(not_included or []),
    }


def deviation_block(cumulative_arcsec: np.ndarray, budget: DeviationBudget, steps: np.ndarray | None = None,
                    not_included: list[str] | None = None) -> dict[str, Any]:
    """The standard keys of an estimate from its cumulative deviation and that deviation's budget.

    ``steps`` (k×n) forms the per-step deviations from the cumulative ones (default: consecutive
    differences, so that the cumulative deviation is 0, Δθ1, Δθ1 + Δθ2, …).
    """
    cum = np.asarray(cumulative_arcsec, float)
    D = difference_matrix(len(cum)) if steps is None else np.asarray(steps, float)
    step_budget = budget.transformed(D)
    u = budget.uncertainty_arcsec
    return {
        "deviation_arcsec": _round(D @ cum),
        "uncertainty_arcsec": _round(step_budget.uncertainty_arcsec),
        "cumulative_deviation_arcsec": _round(cum),
        "cumulative_uncertainty_arcsec": _round(u),
        "cumulative_expanded_uncertainty_arcsec": _round(COVERAGE_FACTOR * u),
        "cumulative_covariance_arcsec2": [_round(row, 6) for row in budget.covariance_arcsec2],
        "uncertainty_budget": budget_dict(budget, not_included),
    }


def choose_recommended(estimates: dict[str, dict[str, Any]], status: dict[str, dict[str, str]]) -> str | None:
    """The estimate a certificate should quote: converged first, then the smallest RMS uncertainty."""
    def key(name: str):
        u = np.array([v for v in estimates[name]["cumulative_uncertainty_arcsec"][1:] if v is not None], float)
        return (status.get(name, {}).get("status") != "converged", float(np.sqrt(np.mean(u**2))) if u.size else np.inf)

    names = sorted(estimates, key=key)
    return names[0] if names else None


ESTIMATOR_ERRORS = (ValueError, ArithmeticError, np.linalg.LinAlgError)


def run_estimators(solvers: dict[str, Callable[[], dict[str, Any]]]) -> tuple[dict[str, dict], dict[str, dict[str, str]]]:
    """Run every estimator; one that cannot run is recorded as failed and hides none of the others.

    Each solver returns its estimate block (with ``converged`` and ``message``); the status of
    each is ``converged``, ``not converged`` (results kept, flagged) or ``failed`` (no results).
    """
    estimates: dict[str, dict] = {}
    status: dict[str, dict[str, str]] = {}
    for name, solve in solvers.items():
        try:
            block = solve()
        except ESTIMATOR_ERRORS as exc:
            status[name] = {"status": "failed", "message": f"could not run: {exc}"}
            continue
        estimates[name] = block
        status[name] = {"status": "converged" if block.get("converged") else "not converged",
                        "message": str(block.get("message", ""))}
    return estimates, status


def status_lines(results: dict[str, Any]) -> list[str]:
    """One line per estimator that did not converge or could not run (empty when all is well)."""
    return [f"estimator {name} {st['status']}: {st['message']}" for name, st in results.get("solver_status", {}).items()
            if st["status"] != "converged"]


def finite_or_none(values) -> list[float | None]:
    """JSON has no NaN: missing values (no face in front, say) become null."""
    out = []
    for v in values:
        v = float(v)
        out.append(None if v != v else round(v, 4))
    return out
