"""Conformity: the ISO 230-2 parameters against the procedure's acceptance limits, under a stated
decision rule, with the expanded uncertainty U of each parameter (docs/conformity.md).

The measurand is the axis' parameter: E, M, B and the band are functions of the mean deviations
x̄ per target and direction; R and A add the scatter s. Each parameter is the largest (less the
smallest) of linear terms g·x̄ + h·s over the targets. The errors of x̄ are normal with the
covariance C of the recommended estimate (the reference standard, the reference's noise and the
axis' own scatter averaged over the runs, with their correlations); those of s follow its
sampling distribution with n − 1 degrees of freedom. A maximum's error lies between the error of
the truly largest term's estimate and the largest error of the terms that could be the largest,
so U is the Φ(2) quantile of the latter (2u when one target decides). A pure function of the
evaluation, the positioning-deviation table and the estimate's covariance;
``tests/test_conformity.py`` checks U against a Monte Carlo of simulated benches.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rtcal.deliverables.deviations import PositioningDeviations
from rtcal.deliverables.rounding import round_up
from rtcal.deliverables.comparison import estimate_targets
from rtcal.results.model import Analysis, Conformity, Iso230Evaluation, IsoTarget, LimitConformity, RunResults

K = 2.0  # coverage factor of every U here

RULES = {
    "simple": "Simple acceptance (ILAC-G8:09/2019): a parameter passes when its measured value does not exceed the "
              "limit; the measurement uncertainty does not enter the decision (the risk of a wrong decision is shared, "
              "up to 50 % for a value at the limit).",
    "guarded": "Guarded acceptance (ISO 14253-1:2017) with a guard band w = U (k = 2): conformity is proven when the "
               "measured value does not exceed the limit less U, non-conformity when it exceeds the limit plus U; "
               "between the two neither is proven and the verdict is undecided.",
}
NOTES = (
    "U of each parameter from the covariance of the mean deviations per target and direction (the recommended "
    "estimate's) and, for R and A, the sampling distribution of each s (n − 1 degrees of freedom): the Φ(2) quantile "
    "of the largest error its maximum (less its minimum) can have over the targets that could be the extreme ones; "
    "for a single normal error that is U = 2u (docs/conformity.md).",
    "The measurand is the axis' parameter (its systematic mean deviations and its scatter), of which this test's runs "
    "are a sample; s includes the reference's own noise per reading (the data cannot tell it from the axis' scatter).",
)


@dataclass(frozen=True)
class Means:
    """The mean deviations x̄ per (target, direction), their scatter s and counts n, and the covariance of x̄."""

    keys: list[tuple[float, int]]
    mean: np.ndarray
    s: np.ndarray  # NaN where n < 2
    n: np.ndarray
    cov: np.ndarray
    cov_source: str

    def index(self, target: float, direction: int) -> int | None:
        try:
            return self.keys.index((round(target, 6), direction))
        except ValueError:
            return None

    def draws(self) -> tuple[np.ndarray, np.ndarray]:
        """DRAWS samples of the errors of x̄ (normal, covariance C) and of s (its sampling
        distribution), the same for every parameter of the run (a fixed seed: reproducible)."""
        if not hasattr(self, "_draws"):
            rng = np.random.default_rng(20140915)
            w, v = np.linalg.eigh((self.cov + self.cov.T) / 2)
            e_m = rng.standard_normal((DRAWS, len(w))) @ (v * np.sqrt(np.clip(w, 0.0, None))).T
            nu = np.maximum(self.n - 1, 1)
            s = np.where(np.isfinite(self.s), self.s, 0.0)
            e_s = s * (np.sqrt(rng.chisquare(nu, (DRAWS, len(nu))) / nu) - 1.0)
            object.__setattr__(self, "_draws", (e_m, e_s))
        return getattr(self, "_draws")

    def u_s(self) -> np.ndarray:
        """Sampling standard uncertainty of each s: s·√(1 − c4²)/c4 with n − 1 degrees of freedom."""
        out = np.full(len(self.s), np.nan)
        for k, (s, n) in enumerate(zip(self.s, self.n)):
            if n >= 2 and np.isfinite(s):
                c4 = math.exp(0.5 * math.log(2.0 / (n - 1)) + math.lgamma(n / 2) - math.lgamma((n - 1) / 2))
                out[k] = s * math.sqrt(1.0 - c4**2) / c4
        return out


def means_of(evaluation: Iso230Evaluation, analysis: Analysis, table: PositioningDeviations) -> Means:
    """x̄, s and n per (target, direction) from the evaluation, and the covariance of x̄ from the
    recommended estimate (or, without one, from the rows' u: fully correlated within a target and
    direction, independent between them — larger than the truth for every difference of means)."""
    keys, mean, s, n = [], [], [], []
    for t in evaluation.per_target:
        for d, m, sd, count in ((1, t.mean_up, t.s_up, t.n_up), (-1, t.mean_down, t.s_down, t.n_down)):
            if m is not None:
                keys.append((round(t.target_deg, 6), d))
                mean.append(m)
                s.append(np.nan if sd is None else sd)
                n.append(count)
    cov = np.full((len(keys), len(keys)), np.nan)
    e = analysis.recommended_estimate()
    if e is not None:
        where = {(round(t, 6), d): j for j, (t, d) in enumerate(estimate_targets(analysis, table))}
        rows = [r for r in (where.get(k) for k in keys) if r is not None]
        if len(rows) == len(keys):
            c = np.array([[np.nan if v is None else v for v in row] for row in e.cumulative_covariance_arcsec2], float)
            cov = c[np.ix_(rows, rows)]
    source = "the covariance of the recommended estimate's mean deviations"
    if not np.all(np.isfinite(cov)):
        u2: dict[tuple[float, int], list[float]] = {}
        for t, d, u in zip(table.target_deg, table.direction, table.uncertainty_arcsec):
            if np.isfinite(u):
                u2.setdefault((round(float(t), 6), int(d)), []).append(float(u) ** 2)
        cov = np.diag([float(np.mean(u2[k])) if k in u2 else np.nan for k in keys])
        source = ("the rows' u, taken fully correlated within a target and direction and independent between them "
                  "(the estimate's covariance was not available)")
    return Means(keys, np.array(mean, float), np.array(s, float), np.array(n, int), cov, source)


DRAWS = 10_000  # samples of the errors of the means and scatters (a fixed seed: a run's U is reproducible)
CANDIDATE_SIGMAS = 4.0  # a target further below the largest than this many σ of the difference cannot be the largest
LEVEL = 0.977249868  # Φ(2): the quantile that is k = 2 for a single normal error


@dataclass(frozen=True)
class Term:
    """One candidate of a maximum (or minimum): its estimate g·x̄ + h·s."""

    g: np.ndarray
    h: np.ndarray

    def value(self, means: Means) -> float:
        s = np.where(self.h != 0, means.s, 0.0)
        return float(self.g @ means.mean + self.h @ s)


@dataclass(frozen=True)
class Extremes:
    """A parameter P = max(top) − min(bottom) (``bottom`` empty: P = max(top))."""

    top: list[Term]
    bottom: list[Term]

    def value(self, means: Means) -> float:
        return max(t.value(means) for t in self.top) - (min(t.value(means) for t in self.bottom) if self.bottom else 0.0)

    def expanded_uncertainty(self, means: Means) -> float | None:
        """U: the Φ(2) quantile of the largest error the maximum (less the minimum) can have.

        P̂ − P lies between the error of the true extreme target's estimate (a normal error) and
        max_i ε_i − min_j ε_j over the candidates i, j that could be the true extremes; the Φ(2)
        quantile of the latter is U. With one candidate each it is 2·u of the linear form."""
        u_s = means.u_s()
        terms = self.top + self.bottom
        if any(np.any((t.h != 0) & ~np.isfinite(u_s)) for t in terms) or not np.all(np.isfinite(means.cov)):
            return None
        s = np.where(np.isfinite(means.s), means.s, 0.0)
        var_s = np.where(np.isfinite(u_s), u_s, 0.0) ** 2

        def candidates(ts: list[Term], sign: float) -> list[Term]:
            """The terms that could be the true extreme: within CANDIDATE_SIGMAS of the measured one."""
            values = np.array([sign * t.value(means) for t in ts])
            best = ts[int(np.argmax(values))]
            keep = []
            for t, v in zip(ts, values):
                dg, dh = t.g - best.g, t.h - best.h
                sd = math.sqrt(max(float(dg @ means.cov @ dg + dh**2 @ var_s), 0.0))
                if values.max() - v <= CANDIDATE_SIGMAS * sd + 1e-12:
                    keep.append(t)
            return keep

        top, bottom = candidates(self.top, 1.0), candidates(self.bottom, -1.0) if self.bottom else []
        if len(top) + len(bottom) <= 2:  # one target decides each extreme: the linear form, U = 2u
            g = sum((t.g for t in top), np.zeros(len(s))) - sum((t.g for t in bottom), np.zeros(len(s)))
            h = sum((t.h for t in top), np.zeros(len(s))) - sum((t.h for t in bottom), np.zeros(len(s)))
            return 2.0 * math.sqrt(max(float(g @ means.cov @ g + h**2 @ var_s), 0.0))
        e_m, e_s = means.draws()

        def largest_error(ts: list[Term], sign: float) -> np.ndarray:
            G, H = np.array([t.g for t in ts]), np.array([t.h for t in ts])
            return (sign * (e_m @ G.T + e_s @ H.T)).max(axis=1)

        spread = largest_error(top, 1.0) + (largest_error(bottom, -1.0) if bottom else 0.0)
        return float(np.quantile(spread, LEVEL))


def _unit(n: int, *terms: tuple[int, float]) -> np.ndarray:
    v = np.zeros(n)
    for k, c in terms:
        v[k] += c
    return v


def _both(means: Means, t: IsoTarget) -> tuple[int, int] | None:
    up, down = means.index(t.target_deg, 1), means.index(t.target_deg, -1)
    return None if up is None or down is None else (up, down)


def _span(means: Means, ks: list[int], spread: float) -> Extremes | None:
    """max(x̄ + spread·s) − min(x̄ − spread·s) over the keys ks (E with spread 0, A with 2)."""
    if not ks:
        return None
    n = len(means.keys)
    return Extremes([Term(_unit(n, (k, 1.0)), _unit(n, (k, spread))) for k in ks],
                    [Term(_unit(n, (k, 1.0)), _unit(n, (k, -spread))) for k in ks])


def parameter_form(symbol: str, evaluation: Iso230Evaluation, means: Means) -> Extremes | None:
    """An ISO 230-2 parameter as the extremes of linear terms in x̄ and s (None: not defined)."""
    n = len(means.keys)
    pairs = [p for t in evaluation.per_target if (p := _both(means, t)) is not None]
    with_s = [k for k in range(n) if means.n[k] >= 2 and np.isfinite(means.s[k])]
    side = 1 if symbol.endswith("_up") else -1 if symbol.endswith("_down") else 0
    if symbol in ("E_up", "E_down"):
        return _span(means, [k for k in range(n) if means.keys[k][1] == side], 0.0)
    if symbol == "E":
        return _span(means, list(range(n)), 0.0)
    if symbol in ("A_up", "A_down"):
        return _span(means, [k for k in with_s if means.keys[k][1] == side], 2.0)
    if symbol == "A":
        both = [k for p in pairs for k in p]
        return _span(means, both, 2.0) if all(k in with_s for k in both) else None
    if symbol == "M":
        mid = [Term(_unit(n, (a, 0.5), (b, 0.5)), np.zeros(n)) for a, b in pairs]
        return Extremes(mid, mid) if pairs else None

    def reversal(a: int, b: int) -> tuple[np.ndarray, float]:  # |B_i| = sign·(x̄↑ − x̄↓), the sign as measured
        sign = 1.0 if means.mean[a] >= means.mean[b] else -1.0
        return _unit(n, (a, sign), (b, -sign)), sign

    if symbol == "B":
        return Extremes([Term(reversal(a, b)[0], np.zeros(n)) for a, b in pairs], []) if pairs else None
    if symbol in ("R_up", "R_down"):
        ks = [k for k in with_s if means.keys[k][1] == side]
        return Extremes([Term(np.zeros(n), _unit(n, (k, 4.0))) for k in ks], []) if ks else None
    if symbol == "R":
        if not pairs or not all(a in with_s and b in with_s for a, b in pairs):
            return None
        terms = []
        for a, b in pairs:
            terms += [Term(reversal(a, b)[0], _unit(n, (a, 2.0), (b, 2.0))),
                      Term(np.zeros(n), _unit(n, (a, 4.0))), Term(np.zeros(n), _unit(n, (b, 4.0)))]
        return Extremes(terms, [])
    raise ValueError(f"unknown parameter {symbol}")


def decide(rule: str, value: float | None, limit: float, U: float | None) -> tuple[str, float]:
    """(verdict, guard band) of one value against its limit under the rule (U: its expanded uncertainty)."""
    if value is None:
        return "undecided", 0.0
    if rule == "simple":
        return ("pass" if value <= limit else "fail"), 0.0
    if U is None:
        return "undecided", 0.0
    w = U
    return ("pass" if value <= limit - w else "fail" if value > limit + w else "undecided"), w


def band_conformity(rule: str, band: float, means: Means) -> LimitConformity:
    """Every mean deviation within ±band: the target that decides (the first to fail, else the
    first undecided, else the one closest to the band)."""
    n = len(means.keys)
    judged = []
    for k in range(n):
        var = float(means.cov[k, k])
        u = math.sqrt(var) if np.isfinite(var) and var >= 0 else None
        verdict, w = decide(rule, abs(float(means.mean[k])), band, None if u is None else round_up(K * u))
        judged.append((verdict, abs(float(means.mean[k])) + w - band, k, u, w))
    rank = {"fail": 0, "undecided": 1, "pass": 2}
    verdict, _, k, u, w = min(judged, key=lambda j: (rank[j[0]], -j[1]))
    return LimitConformity(limit_arcsec=band, value_arcsec=round(abs(float(means.mean[k])), 4),
                           expanded_uncertainty_arcsec=None if u is None else round_up(K * u), guard_band_arcsec=round(w, 4),
                           verdict=verdict, target_deg=means.keys[k][0], direction=means.keys[k][1])


def assess(decision_rule: str, limits: list[tuple[str, float]], band_arcsec: float | None,
           evaluation: Iso230Evaluation, analysis: Analysis, table: PositioningDeviations) -> Conformity:
    """The verdict per limit and overall (fail if any fails, else undecided if any is, else pass)."""
    means = means_of(evaluation, analysis, table)
    per_limit: dict[str, LimitConformity] = {}
    notes = list(NOTES) + [f"Covariance of the means: {means.cov_source}."]
    for symbol, limit in limits:
        value = getattr(evaluation, symbol)
        form = parameter_form(symbol, evaluation, means) if value is not None else None
        U = None if form is None else round_up(form.expanded_uncertainty(means))  # rounded once: what every page shows
        verdict, w = decide(decision_rule, value, limit, U)
        if value is None:
            notes.append(f"{symbol} is not defined by these data (see the evaluation's notes): undecided.")
        per_limit[symbol] = LimitConformity(limit_arcsec=limit, value_arcsec=value,
                                            expanded_uncertainty_arcsec=U,
                                            guard_band_arcsec=round(w, 4), verdict=verdict)
    if band_arcsec is not None:
        per_limit["band"] = band_conformity(decision_rule, band_arcsec, means)
    verdicts = {c.verdict for c in per_limit.values()}
    overall = "fail" if "fail" in verdicts else "undecided" if "undecided" in verdicts else "pass"
    return Conformity(decision_rule=decision_rule, rule=RULES[decision_rule], verdict=overall, coverage_factor=K,
                      per_limit=per_limit, notes=notes)


PARAMETERS = ("E_up", "E_down", "E", "M", "B", "R_up", "R_down", "R", "A_up", "A_down", "A")


def parameter_uncertainties(results: RunResults) -> dict[str, float | None]:
    """U (k = 2) of every ISO 230-2 parameter the run's evaluation defines (None: not defined)."""
    if results.evaluation is None or results.positioning_deviations is None:
        return {}
    iso = results.evaluation.iso230_2
    means = means_of(iso, results, PositioningDeviations.from_model(results.positioning_deviations))
    out: dict[str, float | None] = {}
    for symbol in PARAMETERS:
        form = parameter_form(symbol, iso, means) if getattr(iso, symbol) is not None else None
        out[symbol] = None if form is None else form.expanded_uncertainty(means)
    return out
