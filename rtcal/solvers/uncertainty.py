"""Linearised (GUM) uncertainty of a least-squares estimate whose inputs have several sources of error.

An estimator x̂ = argmin ½‖f(x; y)‖² responds to small changes δy of its inputs (lengths, CMM
points, …) as δx̂ = −H·δf with H = (JᵀJ)⁺Jᵀ (the estimator's own, unweighted, normal
equations; the same formula holds for any estimator linear to first order) and δf the change
of the residuals the inputs cause. A *source* is described by that change per standard
deviation of each of its q independent inputs, the N×q matrix F (or a length-N vector for a
source acting on each residual alone), so that it contributes

    cov(x̂)_source = θ · (H F)(H F)ᵀ

with θ = 1 for a Type B source (its σ stated: a certificate, a specification, a bound) and θ
estimated from the same residuals for a Type A source, by restricted maximum likelihood
(REML, Fisher scoring) on the model V = Σ θ_k F_k F_kᵀ: a source common to many residuals (a
CMM point seen from every station) and one per residual (tracer noise) leave different
patterns in the residuals, so the data tell their sizes apart. The stated σ of a Type A source
only sets its reference scale.

Everything here is arrays in, arrays out: the models that build F live with their methods. F keeps
its source's structure (:mod:`rtcal.solvers.structure`: a vector for one input per residual,
:class:`~rtcal.solvers.structure.Grouped` for inputs shared by a group of residuals — a CMM point,
a stage visit —, a dense (N, q) or :class:`~rtcal.solvers.structure.Factored` for a few inputs
common to many), and V = Σ θ·F·Fᵀ is never formed: REML, the residual test and the propagation
work in that structure at a cost linear in the residuals. A new source is a new effect of one of
those shapes.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from rtcal.solvers.structure import (
    Arrow,
    Effect,
    Grouped,
    Restricted,
    column_basis,
    diagonal_of,
    effect_rows,
    grouped_of,
    scaled,
    sum_of_squares,
    times_effect,
    transposed_times,
)

SourceType = Literal["A", "B"]
Placement = tuple[str, np.ndarray]


@dataclass(frozen=True)
class Source:
    """One source of input uncertainty, by its effect on the residuals per 1σ of its inputs.

    ``effect``: (N,) for one independent input per residual, (N, q) dense for q inputs that each
    move many residuals (a CMM scale, the air's index), :class:`~rtcal.solvers.structure.Grouped`
    for inputs each shared by a group of residuals (a CMM point, a stage visit) or
    :class:`~rtcal.solvers.structure.Factored` (a sparse map times a dense mix). ``sigma`` is the 1σ
    the effect is scaled to, in ``unit``; for Type A it is the reference the estimated scale
    multiplies.
    """

    name: str
    type: SourceType
    effect: Effect
    sigma: float
    unit: str
    note: str = ""


@dataclass(frozen=True)
class VarianceEstimate:
    """REML scales of the Type A sources (1 = as stated) with their standard errors."""

    scale: dict[str, float]
    scale_sigma: dict[str, float]
    iterations: int
    converged: bool

    def sigma(self, source: Source) -> float:
        """The source's 1σ as estimated (its stated σ for Type B)."""
        return source.sigma * float(np.sqrt(self.scale.get(source.name, 1.0)))


@dataclass(frozen=True)
class _Layout:
    """Where each effect's columns go in :class:`rtcal.solvers.structure.Restricted`: the diagonal sources
    summed into d, the grouped sources over the grouping with the most groups as the block, the rest as random
    globals. ``places[k]``: ("diagonal", diag(F·Fᵀ)), ("block", its block columns) or ("global", its global
    columns)."""

    places: list[Placement]
    block_group: np.ndarray | None
    block_groups: int
    block_members: list[int]  # the effects in the block, in column order
    randoms: list[int]  # the effects among the random globals, in column order

    @classmethod
    def of(cls, effects: list[Effect]) -> "_Layout":
        places: list[Placement] = [("diagonal", np.zeros(0))] * len(effects)
        grouped: list[tuple[int, Grouped]] = []
        others: list[int] = []
        for k, e in enumerate(effects):
            diagonal = diagonal_of(e)
            if diagonal is not None:
                places[k] = ("diagonal", diagonal)
                continue
            g = grouped_of(e)
            if g is not None:
                grouped.append((k, g))
            else:
                others.append(k)
        members: list[int] = []
        group, groups = None, 0
        if grouped:
            _, widest = max(grouped, key=lambda kg: kg[1].groups)
            group, groups = widest.group, widest.groups
            c = 0
            for k, g in grouped:
                if g.groups == groups and np.array_equal(g.group, group):
                    members.append(k)
                    places[k] = ("block", np.arange(c, c + g.width))
                    c += g.width
                else:
                    others.append(k)
        q = 0
        randoms = sorted(others)
        for k in randoms:
            e = effects[k]
            width = np.asarray(e).shape[1] if isinstance(e, np.ndarray) else e.shape[1]
            places[k] = ("global", np.arange(q, q + width))
            q += width
        return cls(places, group, groups, members, randoms)

    def restricted(self, effects: list[Effect], scales: list[float], rows: int, floor: float = 0.0, jacobian: Any = None,
                   jacobian_mix: np.ndarray | None = None) -> Restricted:
        """P for V = Σ scale_k·F_k·F_kᵀ (the block unscaled, its columns scaled by √scale)."""
        d = np.full(rows, floor)
        for k, (kind, where) in enumerate(self.places):
            if kind == "diagonal":
                d = d + scales[k] * where
        block = None
        block_scale = None
        if self.block_members:
            assert self.block_group is not None
            grouped = [grouped_of(effects[k]) for k in self.block_members]
            block = Grouped(np.hstack([g.values for g in grouped if g is not None]), self.block_group, self.block_groups)
            block_scale = np.concatenate([np.full(len(self.places[k][1]), np.sqrt(scales[k])) for k in self.block_members])
        randoms = [scaled(effects[k], float(np.sqrt(scales[k]))) if scales[k] != 1.0 else effects[k] for k in self.randoms]
        return Restricted(d, block, randoms, jacobian, jacobian_mix, block_scale)


def reml_scales(jacobian: np.ndarray | Any, residuals: np.ndarray, sources: list[Source],
                max_iterations: int = 60, tolerance: float = 1e-4, floor: float = 1e-14) -> VarianceEstimate:
    """Estimate the variance scales θ of the Type A sources by REML (Fisher scoring).

    The Type B sources enter V with θ = 1. Scales are kept ≥ ``floor`` (a noise-free bench
    estimates them ≈ 0 and V must stay invertible). One source must act on every residual
    (V positive definite). ``jacobian``: dense or scipy.sparse (N×p). V is kept in its sources'
    structure (:mod:`rtcal.solvers.structure`: diagonal, one block per CMM point, low rank), so that
    P·r, every tr(P·V_k) and tr(P·V_k·P·V_l) cost O(N·(c + G)²), G the global columns (the
    estimator's unknowns and the low-rank sources): linear in the readings. With C the mixed-model
    matrix and P·F_k = D⁻¹X·C⁻¹Λ_k·θ_k^(−½) (the dense form is tests/dense_reference.py):

    - diagonal V_k = diag(x): tr(P·V_k) = Σ x/d − Σ x·h/d², h_i = x_i·C⁻¹·x_iᵀ, and
      tr(P·diag(x)·P·diag(y)) = Σ x·y/d² − 2Σ x·y·h/d³ + tr(C⁻¹Q_x·C⁻¹Q_y), Q_x = XᵀD⁻¹diag(x)D⁻¹X;
    - a source of the block (the CMM points): F_kᵀPF_l = (A_u·N_u)_kl − B_u,k·M·B_u,lᵀ per group plus low
      rank, and tr(P·diag(x)·P·V_k) = tr(C⁻¹Q_x·C⁻¹·Λ_k/θ_k), both taken of F_k unscaled
      (:class:`~rtcal.solvers.structure.Restricted`): θ → 0 on a noise-free bench does not underflow;
    - a random global source: the same through (I − ΛC⁻¹) over its columns, divided by θ.
    """
    r = np.asarray(residuals, float)
    N = len(r)
    p = int(jacobian.shape[1])
    a_sources = [s for s in sources if s.type == "A"]
    if not a_sources:
        return VarianceEstimate({}, {}, 0, True)
    is_a = [s.type == "A" for s in sources]
    a_index = [k for k, a in enumerate(is_a) if a]
    # a first guess that already fits the residuals' size: scale every Type A source together
    total_trace = sum(sum_of_squares(s.effect) for s in a_sources)
    theta = np.full(len(a_index), max(float(r @ r) / max(total_trace * (1.0 - p / max(N, 1)), 1e-300), floor))
    effects = [s.effect for s in sources]
    layout = _Layout.of(effects)  # where each source's columns go (θ moves none)
    kinds = [layout.places[k] for k in a_index]
    info = np.eye(len(theta))
    converged = False
    it = 0
    for it in range(1, max_iterations + 1):
        scale = dict(zip(a_index, theta))
        R = layout.restricted(effects, [scale.get(k, 1.0) for k in range(len(sources))], N, 1e-300, jacobian)
        Pr = R.apply(r)
        h = R.hat() if any(kind == "diagonal" for kind, _ in kinds) else np.zeros(N)
        dinv = R.dinv
        diagP = dinv - h * dinv**2
        arrows: dict[int, Arrow] = {}
        score = np.empty(len(theta))
        for i, (k, (kind, where)) in enumerate(zip(a_index, kinds)):
            if kind == "diagonal":
                arrows[i] = R.arrow(where * dinv**2)
                score[i] = 0.5 * (float(np.sum(Pr**2 * where)) - float(np.sum(diagP * where)))
                continue
            FtPr = transposed_times(sources[k].effect, Pr)
            trace = (R.trace_block_complement(where) if kind == "block"
                     else float(np.trace(R.global_complement(where, where))) / theta[i])
            score[i] = 0.5 * (float(FtPr @ FtPr) - trace)
        for i in range(len(theta)):
            for j in range(i, len(theta)):
                (ki, wi), (kj, wj) = kinds[i], kinds[j]
                if ki == "diagonal" and kj == "diagonal":
                    val = (float(np.sum(wi * wj * dinv**2)) - 2.0 * float(np.sum(wi * wj * dinv**3 * h))
                           + R.trace_hqhq(arrows[i], arrows[j]))
                elif "diagonal" in (ki, kj):
                    d_i, c_j = (i, j) if ki == "diagonal" else (j, i)
                    kind, where = kinds[c_j]
                    val = (R.trace_block(arrows[d_i], where) if kind == "block"
                           else R.trace_hqhq(arrows[d_i], R.global_selector(where)) / theta[c_j])
                elif ki == "block" and kj == "block":
                    val = R.norm2_block(wi, wj)
                elif "block" in (ki, kj):
                    b, g = (i, j) if ki == "block" else (j, i)
                    val = R.norm2_block_global(kinds[b][1], kinds[g][1], float(np.sqrt(theta[g])))
                else:
                    val = float(np.sum(R.global_complement(wi, wj) ** 2)) / (theta[i] * theta[j])
                info[i, j] = info[j, i] = 0.5 * val
        step = np.linalg.lstsq(info, score, rcond=None)[0]
        new = np.maximum(theta + step, floor * np.max(np.abs(theta)) + 1e-300)
        change = np.max(np.abs(new - theta) / np.maximum(np.abs(theta), 1e-300))
        theta = new
        if change < tolerance:
            converged = True
            break
    cov = np.linalg.pinv(info)
    return VarianceEstimate({s.name: float(t) for s, t in zip(a_sources, theta)},
                            {s.name: float(np.sqrt(max(cov[k, k], 0.0))) for k, s in enumerate(a_sources)},
                            it, converged)


@dataclass(frozen=True)
class BudgetComponent:
    """One source's contribution to the covariance of a deviation vector (arcsec²)."""

    name: str
    type: SourceType
    sigma: float  # the input's 1σ as used (estimated for Type A)
    unit: str
    covariance_arcsec2: np.ndarray
    estimated: bool = False
    note: str = ""

    @property
    def uncertainty_arcsec(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance_arcsec2), 0.0, None))


@dataclass(frozen=True)
class DeviationBudget:
    """The uncertainty budget of a deviation vector: one component per source, and their sum."""

    components: list[BudgetComponent] = field(default_factory=list)

    @property
    def covariance_arcsec2(self) -> np.ndarray:
        return sum((c.covariance_arcsec2 for c in self.components[1:]), self.components[0].covariance_arcsec2.copy())

    @property
    def uncertainty_arcsec(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance_arcsec2), 0.0, None))

    def transformed(self, matrix: np.ndarray) -> "DeviationBudget":
        """The budget of A·x (e.g. per-step differences of a cumulative deviation)."""
        A = np.asarray(matrix, float)
        return DeviationBudget([BudgetComponent(c.name, c.type, c.sigma, c.unit, A @ c.covariance_arcsec2 @ A.T,
                                                c.estimated, c.note) for c in self.components])


def propagate(influence: np.ndarray, sources: list[Source], variances: VarianceEstimate,
              output_jacobian: np.ndarray) -> list[BudgetComponent]:
    """Each source through the estimator (``influence`` = H restricted to the parameters the
    output depends on, m' × N) and the output's Jacobian: G·H·F·θ·(G·H·F)ᵀ per source, F in its
    structure (m × q, never N × N)."""
    G = np.asarray(output_jacobian, float) @ np.asarray(influence, float)
    out = []
    for s in sources:
        GF = times_effect(G, s.effect)
        theta = variances.scale.get(s.name, 1.0) if s.type == "A" else 1.0
        out.append(BudgetComponent(s.name, s.type, variances.sigma(s), s.unit, theta * (GF @ GF.T), s.type == "A", s.note))
    return out


BIRGE_LIMIT = 1.5  # (against the stated noise alone, seed 001's test) residuals this much larger than the noise explains
P_LIMIT = 1e-3  # … and χ² this improbable under it
FALSE_ALARM_RATE = 0.01  # (against the whole budget, seed 000's test) the share of benches as budgeted it fails


@dataclass(frozen=True)
class ResidualCheck:
    """The residuals against a model of what moves them, at the sizes as stated (χ² and Birge ratio √(χ²/ν)).

    The Type A sizes are estimated from these same residuals, so a test against them would always
    pass; against the stated sizes, a model error (CMM geometry beyond the model, a warming table
    the lengths were not corrected for) shows as residuals the stated sources cannot explain.

    ``whole_budget``: the covariance is every source of the budget that moves the residuals and χ² is
    exactly χ²(ν) on a bench as budgeted (:func:`residual_check` with the estimator's Jacobian), so the
    test fails at p < :data:`FALSE_ALARM_RATE` alone, which is then its false-alarm rate; with ``sources_scored``
    stated Type B sources also scored one by one (:func:`source_scores`), the whole χ² at half that and the worst
    source at half that over their number (Bonferroni: the same rate together). Otherwise (the stated noise alone)
    it fails only at Birge > 1.5 and p < 0.001."""

    chi2: float
    dof: int
    birge_ratio: float
    p_value: float
    whole_budget: bool = False
    sources_scored: int = 0  # Type B sources of few inputs whose inputs the residuals were also tested on
    worst_source: str = ""  # the one the residuals put furthest from its stated σ
    worst_source_p: float = 1.0  # its p-value (χ² of its score, :func:`source_scores`)

    @property
    def passed(self) -> bool:
        if self.whole_budget and self.sources_scored:  # the two tests share the false-alarm rate (Bonferroni)
            return (self.p_value >= FALSE_ALARM_RATE / 2
                    and self.worst_source_p >= FALSE_ALARM_RATE / (2 * self.sources_scored))
        if self.whole_budget:
            return self.p_value >= FALSE_ALARM_RATE
        return not (self.p_value < P_LIMIT and self.birge_ratio > BIRGE_LIMIT)

    @property
    def source_failed(self) -> bool:
        """Failed on one source's inputs: the readings put a stated systematic error beyond its stated σ."""
        return bool(self.sources_scored) and self.worst_source_p < FALSE_ALARM_RATE / (2 * self.sources_scored)

    def words(self) -> str:
        verdict = "passes" if self.passed else "FAILS"
        limit = FALSE_ALARM_RATE / 2 if self.sources_scored else FALSE_ALARM_RATE
        against = (f"the whole budget, p = {self.p_value:.2g}, failing below {limit:g}" if self.whole_budget
                   else "the stated noise")
        failed = ("; the budget does not explain the data — a systematic error it does not model (CMM geometry "
                  "beyond scales and squarenesses, a warming table, air); its U is not a coverage interval")
        if self.source_failed:
            failed = (f"; the readings put '{self.worst_source}' beyond its stated uncertainty (p = {self.worst_source_p:.2g}"
                      f" over {self.sources_scored} stated sources) — a stated value is wrong; its U is not a coverage interval")
        return (f"{verdict} its residual test: Birge ratio {self.birge_ratio:.2f} (χ² = {self.chi2:.0f} for {self.dof} "
                f"degrees of freedom against {against}{'' if self.passed else failed})")


@dataclass(frozen=True)
class Covariance:
    """V = Σ F·Fᵀ over some effects (the sources at their stated sizes, the error motions through the
    stations), kept as those effects: never N×N (:mod:`rtcal.solvers.structure`)."""

    effects: tuple[Effect, ...]

    @classmethod
    def of_sources(cls, sources: list[Source]) -> "Covariance":
        """V of the sources at their stated sizes (θ = 1)."""
        return cls(tuple(s.effect for s in sources))

    def plus(self, *effects: Effect) -> "Covariance":
        return Covariance(self.effects + tuple(effects))

    @property
    def rows(self) -> int:
        return effect_rows(self.effects[0]) if self.effects else 0

    def restricted(self, jacobian: Any = None, jacobian_mix: np.ndarray | None = None) -> Restricted | None:
        """P for V and J (None when V has no positive diagonal part to build it on)."""
        layout = _Layout.of(list(self.effects))
        d = sum((w for kind, w in layout.places if kind == "diagonal"), np.zeros(self.rows))
        if not np.all(d > 0):
            return None
        return layout.restricted(list(self.effects), [1.0] * len(self.effects), self.rows, 0.0, jacobian, jacobian_mix)


SCORED_MAX_INPUTS = 12  # a Type B source of at most this many inputs (a scale, a coefficient, a few lobes) is scored
SEEN_SHARE = 1e-3  # directions of a source the residuals see at less than this share of its variance are not scored


def source_scores(P: Restricted, residuals: np.ndarray, scored: list[tuple[str, np.ndarray]]) -> list[tuple[str, float, int]]:
    """(name, p, rank) per source: are the residuals consistent with the source's inputs at their stated σ?

    A source of few inputs ζ ~ N(0, I) (its effect F per 1σ) moves the residuals along F; its score s = FᵀPr has
    covariance FᵀPVPF = FᵀPF on a bench as budgeted (PVP = P), so T = sᵀ(FᵀPF)⁺s is χ²(rank) exactly. The whole χ²
    spreads one source's excursion over ν degrees of freedom (an α 5.75σ off adds ≈ 33 to a χ² of 680 ± 37, which
    passes); its own score keeps it in one (T ≈ 33 on 1 degree of freedom). Directions the residuals see at less
    than :data:`SEEN_SHARE` of their variance (taken up by the estimator's unknowns) are not scored."""
    from scipy.stats import chi2 as chi2_dist

    out = []
    r = np.asarray(residuals, float)
    for name, F in scored:
        PF = np.column_stack([P.apply(f) for f in F.T])
        w, vec = np.linalg.eigh(0.5 * (F.T @ PF + PF.T @ F))
        keep = w > SEEN_SHARE
        if not np.any(keep):
            continue
        z = vec[:, keep].T @ (PF.T @ r)
        out.append((name, float(chi2_dist.sf(float(np.sum(z**2 / w[keep])), int(np.sum(keep)))), int(np.sum(keep))))
    return out


def scorable(sources: list[Source], skip: tuple[str, ...] = ()) -> list[tuple[str, np.ndarray]]:
    """The Type B sources of few inputs, dense (:data:`SCORED_MAX_INPUTS`), for :func:`source_scores`."""
    return [(s.name, np.asarray(s.effect, float)) for s in sources if s.type == "B" and s.name not in skip
            and isinstance(s.effect, np.ndarray) and s.effect.ndim == 2 and 0 < s.effect.shape[1] <= SCORED_MAX_INPUTS]


def residual_check(residuals: np.ndarray, covariance: Covariance | np.ndarray, parameters: int,
                   jacobian: Any = None, jacobian_r: np.ndarray | None = None,
                   scored: list[tuple[str, np.ndarray]] | None = None) -> ResidualCheck | None:
    """χ² of the residuals under the covariance V of what moves them (None when nothing is left to test:
    ν < 1, or V without a positive diagonal part).

    Without ``jacobian``: χ² = rᵀV⁻¹r with ν = N − parameters (exact when the estimator weighted with V⁻¹).
    With the Jacobian J (dense or sparse) of an unweighted least-squares estimator: its residuals are
    r = Q·Qᵀ·e (Q an orthonormal basis of J's left null space, e the inputs' errors), so z = Qᵀr has
    covariance QᵀVQ and χ² = zᵀ(QᵀVQ)⁻¹z is exactly χ²(N − rank J) when e ~ N(0, V), whatever V's
    correlations (a CMM point common to every station's length): the test is then the whole budget's
    (``whole_budget``). Q(QᵀVQ)⁻¹Qᵀ is REML's P = V⁻¹ − V⁻¹J(JᵀV⁻¹J)⁺JᵀV⁻¹, so χ² = rᵀPr, computed in V's
    structure with J's column space of the rank the SVD of J counts (:func:`rtcal.solvers.structure.column_basis`;
    ``jacobian_r``: J's R factor when at hand). A dense V (a small problem: the R-test's poses) is taken as it is
    (:func:`_dense_residual_check`, O(N³))."""
    from scipy.stats import chi2 as chi2_dist

    if isinstance(covariance, np.ndarray):
        return _dense_residual_check(residuals, covariance, parameters,
                                     None if jacobian is None else np.asarray(jacobian.toarray() if hasattr(jacobian, "toarray")
                                                                              else jacobian, float))
    r = np.asarray(residuals, float)
    if jacobian is not None:
        basis, rank = column_basis(jacobian if hasattr(jacobian, "tocsr") else _sparse(jacobian), jacobian_r)
        dof = len(r) - rank
        P = covariance.restricted(jacobian, basis) if dof >= 1 else None
    else:
        dof = len(r) - int(parameters)
        P = covariance.restricted() if dof >= 1 else None
    if P is None:
        return None
    chi2 = max(P.quadratic(r), 0.0)  # a form of a positive semi-definite P: below 0 only by rounding (exact readings)
    check = ResidualCheck(chi2, dof, float(np.sqrt(chi2 / dof)), float(chi2_dist.sf(chi2, dof)), jacobian is not None)
    scores = source_scores(P, r, scored) if scored and jacobian is not None else []
    if not scores:
        return check
    name, p, _ = min(scores, key=lambda x: x[1])
    return replace(check, sources_scored=len(scores), worst_source=name, worst_source_p=p)


def _dense_residual_check(residuals: np.ndarray, covariance: np.ndarray, parameters: int,
                          jacobian: np.ndarray | None = None) -> ResidualCheck | None:
    """:func:`residual_check` with V an N×N array: with the Jacobian, z = Qᵀr (Q the left null space of J, from
    its full SVD) against QᵀVQ by its Cholesky factor; without it rᵀV⁻¹r with ν = N − parameters (None: ν < 1 or V
    not positive definite). The statement the structured form is checked against (tests/test_structured_budget.py)."""
    from scipy.stats import chi2 as chi2_dist

    r = np.asarray(residuals, float)
    V = np.asarray(covariance, float)
    if jacobian is not None:
        J = np.asarray(jacobian, float)
        left, sv, _ = np.linalg.svd(J, full_matrices=True)
        rank = int(np.sum(sv > sv[0] * max(J.shape) * np.finfo(float).eps)) if sv.size else 0
        Q = left[:, rank:]
        r, V = Q.T @ r, Q.T @ V @ Q
        parameters = 0
    dof = len(r) - int(parameters)
    if dof < 1:
        return None
    try:
        L = np.linalg.cholesky(V)
    except np.linalg.LinAlgError:
        return None
    z = np.linalg.solve(L, r)
    chi2 = float(z @ z)
    return ResidualCheck(chi2, dof, float(np.sqrt(chi2 / dof)), float(chi2_dist.sf(chi2, dof)), jacobian is not None)


def _sparse(matrix: np.ndarray) -> Any:
    import scipy.sparse as sp

    return sp.csr_matrix(np.asarray(matrix, float))


def stated_covariance(sources: list[Source]) -> Covariance:
    """V = Σ F·Fᵀ of the sources at their stated sizes (θ = 1), in their structure."""
    return Covariance.of_sources(sources)


def difference_matrix(n: int) -> np.ndarray:
    """(n−1)×n: per-step differences of an n-vector (x1 − x0, x2 − x1, …)."""
    return np.eye(n)[1:] - np.eye(n)[:-1]
