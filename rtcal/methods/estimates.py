"""What every estimate reports, and which one a certificate should quote.

Every estimate under ``estimates.<name>`` of results.json carries the same block
(:class:`rtcal.results.model.DeviationBlock`): the
cumulative positioning deviation (actual − commanded relative to the first target; ISO 230-1
ECC for a C axis) with its standard uncertainty, expanded uncertainty (k = 2), covariance and
budget, and its per-step differences (seed 000's eq. 33 Δθ) with theirs. ``recommended`` names
the estimate to quote: converged, and the smallest uncertainty among those that did, whether or not its residual
test passed (a failure is stated, never solved by quoting a worse estimate: :func:`choose_recommended`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Literal, Protocol, Sequence, TypeVar

import numpy as np

from rtcal.results.model import (BudgetComponent, DeviationBlock, Estimate, QuantityComponent, QuantityEstimate, ResidualTest,
                                 SolverStatus, UncertaintyBudget)
from rtcal.solvers.uncertainty import DeviationBudget, ResidualCheck, difference_matrix

COVERAGE_FACTOR = 2.0


def _round(values: Iterable[float] | np.ndarray, digits: int = 4) -> list[float | None]:
    return [None if not np.isfinite(v) else round(float(v), digits) for v in np.asarray(values, float).ravel()]


def uncertainty_budget(budget: DeviationBudget, not_included: list[str] | None = None) -> UncertaintyBudget:
    """The GUM table: per source its type, input σ and contribution per target; combined u and U."""
    u = budget.uncertainty_arcsec
    return UncertaintyBudget(
        components=[BudgetComponent(
            source=c.name, type=c.type, input_sigma=round(float(c.sigma), 6), unit=c.unit,
            estimated_from_data=c.estimated, note=c.note, contribution_arcsec=_round(c.uncertainty_arcsec),
        ) for c in budget.components],
        combined_arcsec=_round(u),
        expanded_arcsec=_round(COVERAGE_FACTOR * u),
        coverage_factor=COVERAGE_FACTOR,
        not_included=list(not_included or []),
    )


def deviation_block(cumulative_arcsec: np.ndarray, budget: DeviationBudget, steps: np.ndarray | None = None,
                    not_included: list[str] | None = None) -> DeviationBlock:
    """The standard keys of an estimate from its cumulative deviation and that deviation's budget.

    ``steps`` (k×n) forms the per-step deviations from the cumulative ones (default: consecutive
    differences, so that the cumulative deviation is 0, Δθ1, Δθ1 + Δθ2, …).
    """
    cum = np.asarray(cumulative_arcsec, float)
    D = difference_matrix(len(cum)) if steps is None else np.asarray(steps, float)
    step_budget = budget.transformed(D)
    u = budget.uncertainty_arcsec
    return DeviationBlock(
        deviation_arcsec=_round(D @ cum),
        uncertainty_arcsec=_round(step_budget.uncertainty_arcsec),
        cumulative_deviation_arcsec=_round(cum),
        cumulative_uncertainty_arcsec=_round(u),
        cumulative_expanded_uncertainty_arcsec=_round(COVERAGE_FACTOR * u),
        cumulative_covariance_arcsec2=[_round(row, 6) for row in budget.covariance_arcsec2],
        uncertainty_budget=uncertainty_budget(budget, not_included),
    )


@dataclass(frozen=True)
class QuantitySource:
    """One source of a :func:`quantity_estimate`'s budget: its standard uncertainty ``input_sigma`` in
    ``input_unit`` and what it contributes to each target's standard uncertainty, in the result's unit
    (the sources are taken as independent: u² = Σ contribution²)."""

    source: str
    type: Literal["A", "B"]
    input_sigma: float
    input_unit: str
    contribution: Sequence[float]
    estimated: bool = False
    note: str = ""


def quantity_estimate(quantity: str, unit: str, target_deg: Sequence[float], target_direction: Sequence[int],
                      value: Sequence[float] | np.ndarray, sources: Sequence[QuantitySource],
                      not_included: Sequence[str] = (), message: str = "", converged: bool = True,
                      digits: int = 4) -> QuantityEstimate:
    """A result in its own quantity and unit (:class:`~rtcal.results.model.QuantityEstimate`) per target and
    direction, with its GUM budget: u from the independent sources, U = k·u (k = 2)."""
    n = len(target_deg)
    contributions = np.array([np.broadcast_to(np.asarray(s.contribution, float), (n,)) for s in sources]).reshape(len(sources), n)
    u = np.sqrt(np.sum(contributions**2, axis=0)) if len(sources) else np.full(n, np.nan)
    return QuantityEstimate(
        quantity=quantity, unit=unit, target_deg=[float(x) for x in target_deg],
        target_direction=[1 if d > 0 else -1 for d in target_direction],
        value=_round(value, digits), standard_uncertainty=_round(u, digits),
        expanded_uncertainty=_round(COVERAGE_FACTOR * u, digits), coverage_factor=COVERAGE_FACTOR,
        budget=[QuantityComponent(source=s.source, type=s.type, input_sigma=round(float(s.input_sigma), 6), unit=s.input_unit,
                                  estimated_from_data=s.estimated, note=s.note, contribution=_round(c, digits))
                for s, c in zip(sources, contributions)],
        not_included=list(not_included), converged=converged, message=message)


def residual_test(check: ResidualCheck | None) -> ResidualTest | None:
    """A solver's :class:`rtcal.solvers.uncertainty.ResidualCheck` as results (None: nothing tested)."""
    if check is None:
        return None
    return ResidualTest(chi2=round(check.chi2, 3), dof=check.dof, birge_ratio=round(check.birge_ratio, 4),
                        p_value=float(check.p_value), passed=check.passed)


def with_residual_test(message: str, check: ResidualCheck | None) -> str:
    """The solver's message and, where its residuals were tested, the verdict in words."""
    return message if check is None else f"{message}; {check.words()}"


RESIDUAL_FAILURE = "its residual test failed"  # the words every failed estimate's not_included entry carries


def not_covered(not_included: list[str], check: ResidualCheck | None, causes: Iterable[str] = ()) -> list[str]:
    """The budget's ``not_included`` and, when its residual test failed, the error it failed on: a certificate
    that quotes the estimate then says its U leaves that error out, and what the failure means — the budget's
    assumptions the data contradict (``causes``: the method's, in words)."""
    if check is None or check.passed:
        return not_included
    said = list(causes)
    meaning = ("" if not said else "; the readings contradict what the budget assumed — one of: " + "; ".join(said))
    if check.source_failed:  # one stated source is off: say which, first
        meaning = (f"; the readings contradict what the budget assumed — one of: '{check.worst_source}' is beyond its "
                   f"stated uncertainty (p = {check.worst_source_p:.2g})" + "".join(f"; {c}" for c in said))
    return [*not_included, f"a systematic error the residuals show and the budget does not model ({RESIDUAL_FAILURE}: "
            f"χ² = {check.chi2:.0f} for {check.dof} degrees of freedom, p = {check.p_value:.2g}): U is not a "
            f"coverage interval for it{meaning}"]


class Result(Protocol):
    """What every estimator's result says of how it ended (an :class:`Estimate`, a :class:`QuantityEstimate`)."""

    @property
    def converged(self) -> bool: ...

    @property
    def message(self) -> str: ...


R = TypeVar("R", bound=Result)


def _uncertainties(result: Result) -> list[float | None]:
    """What a result's "smallest uncertainty" is measured on: an angular estimate's cumulative u after the first
    target (0 there by construction), a quantity's standard uncertainty."""
    if isinstance(result, Estimate):
        return list(result.cumulative_uncertainty_arcsec[1:])
    if isinstance(result, QuantityEstimate):
        return list(result.standard_uncertainty)
    return []


def choose_recommended(estimates: dict[str, R], status: dict[str, SolverStatus]) -> str | None:
    """The estimate a certificate should quote: converged first, then the smallest RMS uncertainty.

    A failed residual test does not move the choice. The estimators share the readings and the budget's model of
    the room (the same α, air, CMM, tracer); the test of the most precise one sees the most, so a failure there is
    an error the others share while their weaker tests pass (an aluminium table corrected as steel: the network
    fails, shared_dead_path passes and is as wrong). Quoting another would hide it; the certificate quotes the
    best estimate and states that its U is not a coverage interval, and why (:func:`not_covered`)."""
    def key(name: str) -> tuple[bool, float]:
        u = np.array([v for v in _uncertainties(estimates[name]) if v is not None], float)
        st = status.get(name)
        return (st is None or st.status != "converged", float(np.sqrt(np.mean(u**2))) if u.size else np.inf)

    names = sorted(estimates, key=key)
    return names[0] if names else None


ESTIMATOR_ERRORS = (ValueError, ArithmeticError, np.linalg.LinAlgError)


def run_estimators(solvers: dict[str, Callable[[], R]]) -> tuple[dict[str, R], dict[str, SolverStatus]]:
    """Run every estimator; one that cannot run is recorded as failed and hides none of the others.

    Each solver returns its estimate (with ``converged`` and ``message``); the status of each is
    ``converged``, ``not converged`` (results kept, flagged) or ``failed`` (no results).
    """
    estimates: dict[str, R] = {}
    status: dict[str, SolverStatus] = {}
    for name, solve in solvers.items():
        try:
            block = solve()
        except ESTIMATOR_ERRORS as exc:
            status[name] = SolverStatus(status="failed", message=f"could not run: {exc}")
            continue
        estimates[name] = block
        status[name] = SolverStatus(status="converged" if block.converged else "not converged", message=block.message)
    return estimates, status


def finite_or_none(values: Iterable[float] | np.ndarray) -> list[float | None]:
    """JSON has no NaN: missing values (no face in front, say) become null."""
    out = []
    for v in values:
        v = float(v)
        out.append(None if v != v else round(v, 4))
    return out
