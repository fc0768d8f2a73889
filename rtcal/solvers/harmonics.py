"""Periodic errors: a list of harmonics, value(θ) = Σ amplitude · sin(order·θ + phase), and their analysis.

One evaluation for the whole project (:class:`Harmonic`, :func:`evaluate`): the bench uses it to make
errors, the tests and the harmonic analysis use it to check them.

Harmonic analysis (:func:`fit_harmonics`): value(θ) = Σ A·sin(nθ + φ) + offset per group.

Least squares rather than an FFT, so that samples need not be evenly spaced, several passes
may each carry their own unknown offset (a re-seated polygon, another direction), and every
amplitude gets a 1σ from the fit's residuals.

Which orders a sampling resolves: with U distinct angles, orders n < U/2 fully (Nyquist). For
U even, order U/2 shows only one part at the sample points — its cosine about a sampled angle θ0,
cos(U/2·(θ − θ0)), since sin(U/2·(θ − θ0)) vanishes there (θ0 = 0 when 0 is sampled; a grid
offset by half its step, as a polygon seated between faces gives, sees the other part):
it is fitted as that one column and reported ``aliased`` — its visible amplitude |A·sin φ| is a
lower bound, its phase unknown; orders above U/2 alias onto lower ones, which a warning says.
Orders are also limited so that the fit keeps at least half its samples as degrees of freedom.

Significance: under "no such harmonic" an order's two coefficients are normal with the same 1σ
σ_c, so A²/(2σ_c²) is χ²₂/2; with σ_c from the residuals (ν degrees of freedom) the statistic is
F(2, ν), and an order is significant when its chance is below α/K for K orders tested
(Bonferroni: at most α chance of any false flag per series). Where a stated floor per sample
(the readings' resolution/√12, or numerical noise — a noise-free fit has residuals at rounding
level and would otherwise call 10⁻¹⁴″ significant) exceeds the residual σ, σ_c is taken as known
and the threshold is Rayleigh's, P(A > t) = exp(−t²/2σ_c²). Coarsely quantised readings of a
smooth motion (a 1 µm dial indicator on a shaft that moves a few µm) are not white noise: the
rounding error repeats with the motion and puts spurious harmonics at particular orders. A
caller that knows the quantisation passes per-order ``quantisation_threshold``s (what rounding
alone produces, simulated), and an order must exceed those too.

Separability (``alternatives_up_to``): on irregular targets the fitted orders are not orthogonal
to the orders above them, so an unmodelled order m leaks into the fitted ones — at the ISO test's
12 targets a 6″ 12th harmonic shows as 0.8–4.1″ at orders 2–5, each far above the noise. An order
is a significant harmonic of the table only if the targets can tell it from such leakage: for each
order n that passes the test above and each unmodelled order m ≤ M (M: the Nyquist order of the
coarsest even grid holding every target, at most the caller's limit; above it an order is the
mirror of a lower one at every such target), the series is fitted with the
significant orders and m, and again without n: if n's two coefficients then explain no more than
two coefficients of noise would (2·F(2, ν) σ², or χ²₂ σ² with a known σ, at the same family level —
a nested test), m takes n's share at these targets and the data cannot tell n from m: n is reported
not significant, ``not_separable_from`` names every such m, and a warning says so. An m orthogonal
to n at the targets (two orders below the Nyquist order of an even grid) takes nothing. A metrologist's
reading: the harmonic is not a property of the table the data prove, it is one the design cannot
distinguish from another; denser or evenly spaced targets resolve it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable

import numpy as np


@dataclass(frozen=True)
class Harmonic:
    """One term: amplitude (in the caller's unit) · sin(order·θ + phase_rad)."""

    order: int
    amplitude: float
    phase_rad: float


def evaluate(harmonics: Iterable[Harmonic], theta_rad):
    """Σ amplitude·sin(order·θ + phase) at θ (radians; float or array). Empty → 0."""
    theta = np.asarray(theta_rad, dtype=float)
    total = np.zeros_like(theta)
    for h in harmonics:
        total = total + h.amplitude * np.sin(h.order * theta + h.phase_rad)
    return total if total.ndim else float(total)


FAMILY_ALPHA = 0.01  # chance of any false "significant" in one series
NUMERICAL_FLOOR = 1e-9  # relative to the series' largest value


@dataclass(frozen=True)
class HarmonicTerm:
    order: int
    amplitude: float
    phase_rad: float
    amplitude_sigma: float
    phase_sigma_rad: float
    significant: bool = False
    threshold: float = 0.0  # amplitude above which this order counts as significant
    aliased: bool = False  # the Nyquist order: only |A·sin φ| is visible, phase unknown
    not_separable_from: tuple[int, ...] = ()  # unmodelled orders that explain the data as well as this one


@dataclass(frozen=True)
class HarmonicFit:
    terms: list[HarmonicTerm]
    offsets: np.ndarray  # one per group
    residual_rms: float
    sigma: float  # residual standard deviation, with the fit's degrees of freedom
    warnings: list[str] = field(default_factory=list)
    trend: np.ndarray | None = None  # the offsets (and a trend_degree's polynomial) at each sample


def distinct_angles(angles_rad: np.ndarray) -> np.ndarray:
    angles = np.asarray(angles_rad, float)
    return np.unique(np.round(np.mod(angles, 2 * np.pi), 9) % np.round(2 * np.pi, 9))


def resolvable_orders(angles_rad: np.ndarray, max_order: int, n_offsets: int = 1) -> list[int]:
    """Orders 1..K: below the Nyquist limit of the distinct sampled angles, and few enough that
    the fit keeps at least half its samples as degrees of freedom (2K + offsets ≤ N/2), so
    that the residual gives an honest σ."""
    angles = np.asarray(angles_rad, float)
    nyquist = (len(distinct_angles(angles)) - 1) // 2
    by_dof = (len(angles) // 2 - n_offsets) // 2
    return list(range(1, max(0, min(max_order, nyquist, by_dof)) + 1))


def nyquist_order(angles_rad: np.ndarray) -> int | None:
    """U/2 when the U distinct angles are evenly spaced and U is even (its cosine part is seen)."""
    d = distinct_angles(angles_rad)
    if len(d) < 4 or len(d) % 2:
        return None
    gaps = np.diff(np.concatenate([d, [d[0] + 2 * np.pi]]))
    return len(d) // 2 if np.allclose(gaps, gaps[0], atol=1e-7) else None


def grid_nyquist(angles_rad: np.ndarray, cap: int) -> int:
    """The Nyquist order of the coarsest even grid (360°/N, N ≤ 2·cap, through any first angle) holding
    every sampled angle (at 10⁻⁶° resolution), else ``cap``: the highest order the targets could tell
    from a lower one. Aliasing depends on the spacing, not on where the grid starts: 24 angles at
    7.5° + k·15° mirror order 23 onto order 1 as 0° + k·15° do."""
    micro = np.round(np.degrees(distinct_angles(angles_rad)) * 1e6).astype(np.int64) % 360_000_000
    micro = (micro - micro[0]) % 360_000_000 if len(micro) else micro
    step = int(np.gcd.reduce(np.concatenate([micro, [360_000_000]])))
    return min(cap, 360_000_000 // step // 2)


def _design(theta: np.ndarray, orders: list[int], groups: np.ndarray, aliased_order: int | None,
            theta0: float = 0.0, trend_degree: int = 0) -> tuple[np.ndarray, int]:
    groups = np.unique(np.asarray(groups), return_inverse=True)[1]
    n_groups = int(groups.max()) + 1 if len(groups) else 1
    cols = [np.sin(n * theta) for n in orders] + [np.cos(n * theta) for n in orders]
    if aliased_order is not None:
        cols.append(np.cos(aliased_order * (theta - theta0)))  # the part the grid through θ0 sees
    if trend_degree and len(theta):  # a slow error over a short arc: powers of the centred, scaled angle per group
        t = theta - 0.5 * (theta.min() + theta.max())
        t = t / (np.max(np.abs(t)) or 1.0)
        for g in range(n_groups):
            cols += [np.where(groups == g, t**p, 0.0) for p in range(1, trend_degree + 1)]
    offsets = np.zeros((len(theta), n_groups))
    offsets[np.arange(len(theta)), groups] = 1.0
    return (np.column_stack(cols + [offsets]) if cols else offsets), n_groups


def harmonic_amplitudes(angles_rad: np.ndarray, values: np.ndarray, orders: list[int], groups: np.ndarray) -> np.ndarray:
    """Fitted amplitude per order only (no statistics), of one series or of each column of
    ``values`` (samples × series): for simulating what an error alone produces."""
    A, _ = _design(np.asarray(angles_rad, float), orders, groups, None)
    coef = np.linalg.lstsq(A, np.asarray(values, float), rcond=None)[0]
    k = len(orders)
    return np.hypot(coef[:k], coef[k : 2 * k]).T


def smooth_values(angles_rad: np.ndarray, values: np.ndarray, orders: list[int], groups: np.ndarray) -> np.ndarray:
    """The harmonic model of a series evaluated at its own samples."""
    A, _ = _design(np.asarray(angles_rad, float), orders, groups, None)
    return A @ np.linalg.lstsq(A, np.asarray(values, float), rcond=None)[0]


def fit_harmonics(angles_rad: np.ndarray, values: np.ndarray, orders: list[int], groups: np.ndarray | None = None,
                  floor_sigma: float = 0.0, aliased_order: int | None = None, max_order: int | None = None,
                  alpha: float = FAMILY_ALPHA, quantisation_threshold: dict[int, float] | None = None,
                  alternatives_up_to: int | None = None, trend_degree: int = 0) -> HarmonicFit:
    """Fit A_n, φ_n for the given orders (and the cosine part of ``aliased_order``) plus one offset
    per group (all one group by default). ``floor_sigma`` is the smallest per-sample σ the
    readings can have (resolution/√12); ``max_order`` the highest order asked for (for the warning);
    ``alternatives_up_to``: test each significant order against unmodelled orders up to this one
    (separability, module docstring; None: not tested). ``trend_degree``: a polynomial of that
    degree in the angle per group besides its offset — the slow error over a short arc of fine steps
    (a periodic-error test), which would otherwise leak into the orders; ``offsets`` then holds
    each group's constant, and ``trend`` the whole fitted slow part at each sample."""
    theta = np.asarray(angles_rad, dtype=float)
    y = np.asarray(values, dtype=float)
    theta0 = float(distinct_angles(theta)[0]) if aliased_order is not None and len(theta) else 0.0
    A, n_groups = _design(theta, orders, np.zeros(len(y), int) if groups is None else groups, aliased_order, theta0,
                          trend_degree)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    quantisation_threshold = quantisation_threshold or {}
    resid = y - A @ coef
    dof = max(len(y) - A.shape[1], 1)
    sigma = float(np.sqrt(resid @ resid / dof))
    floor = max(floor_sigma, NUMERICAL_FLOOR * float(np.max(np.abs(y))) if y.size else 0.0)
    sigma_eff = max(sigma, floor)
    estimated = sigma >= floor  # σ from the residuals (F and t), or a known floor (Rayleigh and normal)
    cov = sigma_eff**2 * np.linalg.pinv(A.T @ A)
    k = len(orders)
    tested = k + (aliased_order is not None)
    p_each = alpha / max(tested, 1)
    # scipy.stats here, not at import: importing it costs every rtcal command about 0.4 s
    from scipy.stats import chi2 as chi2_dist, f as f_dist, norm, t as t_dist

    z = float(np.sqrt(2.0 * f_dist.isf(p_each, 2, dof))) if estimated else float(np.sqrt(2.0 * np.log(1.0 / p_each)))
    terms = []
    for i, n in enumerate(orders):
        a, b = coef[i], coef[k + i]  # A sin(nθ+φ) = A cosφ·sin nθ + A sinφ·cos nθ
        amp = float(np.hypot(a, b))
        va, vb, cab = cov[i, i], cov[k + i, k + i], cov[i, k + i]
        if amp > 0:
            amp_var = (a * a * va + b * b * vb + 2 * a * b * cab) / amp**2
            ph_var = (b * b * va + a * a * vb - 2 * a * b * cab) / amp**4
        else:
            amp_var, ph_var = (va + vb) / 2, np.pi**2
        threshold = max(z * float(np.sqrt((va + vb) / 2)), quantisation_threshold.get(n, 0.0))
        terms.append(HarmonicTerm(n, amp, float(np.arctan2(b, a)), float(np.sqrt(max(amp_var, 0.0))),
                                  float(np.sqrt(max(ph_var, 0.0))), amp > threshold, threshold))
    warnings: list[str] = []
    if alternatives_up_to is not None:
        crit = 2.0 * float(f_dist.isf(p_each, 2, dof)) if estimated else float(chi2_dist.isf(p_each, 2))
        terms = _separability(theta, y, groups, terms, aliased_order, theta0, sigma_eff, crit,
                              alternatives_up_to, warnings)
    if aliased_order is None and max_order is not None and orders and max_order > orders[-1]:
        d = distinct_angles(theta)
        gaps = np.diff(np.concatenate([d, [d[0] + 2 * np.pi]]))
        if not np.allclose(gaps, gaps[0], atol=1e-7):
            warnings.append(f"the {len(d)} angles are unevenly spaced: orders above {orders[-1]} are not resolved and "
                            "an error of such an order shows in the fitted ones")
    if aliased_order is not None:
        b = float(coef[2 * k])
        sd = float(np.sqrt(cov[2 * k, 2 * k]))
        # one visible coefficient: |b| > t has probability 2·(1 − Φ(t/σ)); the same family level
        threshold = float(t_dist.isf(p_each / 2.0, dof) if estimated else norm.isf(p_each / 2.0)) * sd
        # b = A·sin(n·θ0 + φ): reported as the phase that puts all of A in the visible part
        phase = float(np.angle(np.exp(1j * (np.sign(b) * np.pi / 2 - aliased_order * theta0)))) if b else 0.0
        terms.append(HarmonicTerm(aliased_order, abs(b), phase, sd, np.pi, abs(b) > threshold, threshold, aliased=True))
        if abs(b) > threshold:
            warnings.append(f"order {aliased_order} is at the Nyquist limit of {2 * aliased_order} evenly spaced angles and "
                            f"present: only one part is seen ({abs(b):.3g} = |A·sin(φ + {aliased_order}·θ0)| with θ0 = "
                            f"{np.degrees(theta0):.4g}°, a sampled angle: a lower bound of its amplitude; phase unknown)")
            if max_order is not None and max_order > aliased_order:
                warnings.append(f"orders above {aliased_order} cannot be resolved by this sampling: any such error "
                                "aliases onto lower orders")
    slow = 2 * k + (aliased_order is not None)  # the trend's columns and the offsets follow the orders'
    return HarmonicFit(terms, coef[A.shape[1] - n_groups:], float(np.sqrt(np.mean(resid**2))), sigma, warnings,
                       A[:, slow:] @ coef[slow:])


def _separability(theta: np.ndarray, y: np.ndarray, groups: np.ndarray | None, terms: list[HarmonicTerm],
                  aliased_order: int | None, theta0: float, sigma: float, crit: float, up_to: int,
                  warnings: list[str]) -> list[HarmonicTerm]:
    """Each significant order against every unmodelled order m ≤ ``up_to`` (module docstring): not
    significant, with the orders it cannot be told from, where m in the model takes its share."""
    g = np.zeros(len(y), int) if groups is None else np.asarray(groups)
    fitted = {t.order for t in terms if not t.aliased} | ({aliased_order} if aliased_order is not None else set())
    candidates = [m for m in range(1, up_to + 1) if m not in fitted]
    significant = [t.order for t in terms if t.significant and not t.aliased]
    if not candidates or not significant or sigma <= 0:
        return terms
    # n against m: with m in the model too (the significant orders and m), does n still explain what
    # n's two coefficients must (rss without n minus rss with it, a nested 2-coefficient test at crit)?
    # An m the targets mirror onto n takes n's share and n is not separable from it; an m orthogonal
    # to n at these targets (any two orders below the Nyquist order of an even grid) takes nothing.
    def rss(orders: list[int]) -> float:
        A, _ = _design(theta, orders, g, aliased_order, theta0)
        r = y - A @ np.linalg.lstsq(A, y, rcond=None)[0]
        return float(r @ r)

    out = []
    for t in terms:
        if not t.significant or t.aliased:
            out.append(t)
            continue
        rest = [o for o in significant if o != t.order]
        confused = [m for m in candidates if (rss(rest + [m]) - rss(significant + [m])) / sigma**2 <= crit]
        if confused:
            t = HarmonicTerm(t.order, t.amplitude, t.phase_rad, t.amplitude_sigma, t.phase_sigma_rad, False, t.threshold,
                             t.aliased, tuple(confused))
            which = f"order {confused[0]}" if len(confused) == 1 else "orders " + ", ".join(map(str, confused))
            warnings.append(f"order {t.order} ({t.amplitude:.4g}) cannot be separated from {which} at these "
                            f"{len(distinct_angles(theta))} angles: with {which} in the model, order {t.order} "
                            "no longer explains a significant part of the data (leakage of an unmodelled order "
                            "through the targets); not reported as significant")
        out.append(t)
    return out
