"""The periodic positioning error of a rotary axis from a fine-step test over one period and a little
more (ISO 230-2:2014 Annex C), as pure functions: arrays in, a typed result out.

ISO 230-2:2014's scope says its Annex C "contains considerations related to periodic positioning
error"; the annex's own text could not be reached (docs/evaluation.md). What is computed, rtcal's
reading, labelled as such wherever it is shown:

- the periodic positioning error per direction: the range, over the targets of one period, of the
  mean positional deviation x̄_i (mean over the runs) less the slow error the short arc also holds
  (a polynomial of degree ``trend_degree`` in the angle, per direction, fitted jointly with the
  harmonics below so that neither takes the other's part); the figure of the axis is the larger of
  the two directions;
- its U (k = 2) as that of a difference of two means: 2·√(u_a² + u_b²), u the standard uncertainty of
  each of the two extreme means (the scatter over the runs, pooled over the direction's targets, /√n,
  and the reading's digit/√12);
- the harmonic analysis rtcal uses for whole turns (:func:`rtcal.solvers.harmonics.fit_harmonics`)
  at the period's orders: order N·k per turn for k = 1…K, N = 360°/period, each named by its period
  in degrees and in worm revolutions (worm ratio / order), with its amplitude, σ and significance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rtcal.solvers.harmonics import HarmonicFit, fit_harmonics


@dataclass(frozen=True)
class PeriodicTerm:
    order: int  # cycles per table turn
    period_deg: float
    period_worm_revolutions: float | None  # worm ratio / order (None: no worm ratio stated)
    amplitude_arcsec: float
    amplitude_sigma_arcsec: float
    phase_deg: float
    significant: bool
    threshold_arcsec: float


@dataclass(frozen=True)
class PeriodicResult:
    period_deg: float
    targets_per_period: int
    per_direction_arcsec: dict[int, float]  # direction → range of the detrended means over one period
    per_direction_u_arcsec: dict[int, float]  # its standard uncertainty (k = 1)
    terms: list[PeriodicTerm]
    target_deg: np.ndarray  # per (direction, target): the curve the figure is the range of
    direction: np.ndarray
    residual_arcsec: np.ndarray  # x̄_i less the slow part
    residual_u_arcsec: np.ndarray
    fitted_arcsec: np.ndarray  # the harmonics' sum at the same points
    fit: HarmonicFit


def harmonics_per_period(targets_per_period: int, most: int = 4) -> int:
    """How many harmonics of the period the steps resolve with room to spare (four samples per cycle)."""
    return max(1, min(most, targets_per_period // 4))


def periodic_error(angle_deg: np.ndarray, direction: np.ndarray, values_arcsec: np.ndarray, period_deg: float,
                   start_deg: float, worm_ratio: float | None = None, floor_arcsec: float = 0.0,
                   trend_degree: int = 2) -> PeriodicResult:
    """The figure and the harmonics of one fine-step test (each visit's angle, direction and value:
    the table's positioning error up to a constant per direction, arcsec). ``floor_arcsec``: the
    reading's digit/√12 (a mean of runs that read alike still has it)."""
    angle_deg, direction = np.asarray(angle_deg, float), np.asarray(direction, int)
    values = np.asarray(values_arcsec, float)
    ok = np.isfinite(values)
    angle_deg, direction, values = angle_deg[ok], direction[ok], values[ok]
    per_turn = 360.0 / period_deg
    base = int(round(per_turn))
    if abs(per_turn - base) > 1e-6 or base < 1:
        raise ValueError(f"a period of {period_deg:g}° does not divide the turn: 360°/period must be a whole number")
    in_period = (angle_deg >= start_deg - 1e-9) & (angle_deg <= start_deg + period_deg + 1e-9)
    per = len(np.unique(np.round(angle_deg[in_period], 9)))
    if per < 8:
        raise ValueError(f"{per} targets within one period of {period_deg:g}°: at least 8 are needed to see its shape")
    orders = [base * k for k in range(1, harmonics_per_period(per - 1) + 1)]
    groups = (direction < 0).astype(int)
    fit = fit_harmonics(np.radians(angle_deg), values, orders, groups, floor_sigma=floor_arcsec, trend_degree=trend_degree)
    assert fit.trend is not None
    detrended = values - fit.trend
    keys = sorted({(int(d), round(float(a), 9)) for d, a in zip(direction, angle_deg)}, key=lambda k: (-k[0], k[1]))
    t_deg = np.array([k[1] for k in keys])
    t_dir = np.array([k[0] for k in keys])
    mean, count = np.empty(len(keys)), np.empty(len(keys))
    squares, dof = {1: 0.0, -1: 0.0}, {1: 0, -1: 0}
    for i, (d, a) in enumerate(keys):
        x = detrended[(direction == d) & (np.abs(angle_deg - a) < 1e-9)]
        mean[i], count[i] = float(np.mean(x)), len(x)
        squares[d] += float(np.sum((x - mean[i]) ** 2))
        dof[d] += len(x) - 1
    # the scatter over the runs pooled per direction (a few runs give a poor s at one target, and the
    # extremes of a range are where a small s would understate it)
    pooled = {d: math.sqrt(squares[d] / dof[d]) if dof[d] else 0.0 for d in squares}
    u = np.array([math.sqrt(pooled[d] ** 2 / n + floor_arcsec**2) for (d, _), n in zip(keys, count)])
    theta = np.radians(t_deg)
    fitted = sum((t.amplitude * np.sin(t.order * theta + t.phase_rad) for t in fit.terms), np.zeros(len(theta)))
    per_dir, per_dir_u = {}, {}
    for d in sorted(set(t_dir.tolist()), reverse=True):
        sel = np.flatnonzero((t_dir == d) & (t_deg >= start_deg - 1e-9) & (t_deg <= start_deg + period_deg + 1e-9))
        hi, lo = sel[np.argmax(mean[sel])], sel[np.argmin(mean[sel])]
        per_dir[d] = float(mean[hi] - mean[lo])
        per_dir_u[d] = float(math.hypot(u[hi], u[lo]))
    terms = [PeriodicTerm(t.order, 360.0 / t.order, None if worm_ratio is None else worm_ratio / t.order, t.amplitude,
                          t.amplitude_sigma, float(np.degrees(t.phase_rad)), t.significant, t.threshold) for t in fit.terms]
    return PeriodicResult(period_deg, per, per_dir, per_dir_u, terms, t_deg, t_dir, mean, u, fitted, fit)
