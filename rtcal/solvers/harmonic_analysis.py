"""Harmonic analysis of a periodic error: value(θ) = Σ A·sin(nθ + φ) + offset per group.

Least squares rather than an FFT, so that samples need not be evenly spaced, several passes
may each carry their own unknown offset (a re-seated polygon, another direction), and every
amplitude gets a 1σ from the fit's residuals. Orders that the sampling cannot resolve
(n ≥ U/2 for U distinct angles, the Nyquist limit), or that would leave fewer than half the
samples as degrees of freedom, are not fitted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class HarmonicTerm:
    order: int
    amplitude: float
    phase_rad: float
    amplitude_sigma: float
    phase_sigma_rad: float

    @property
    def significant(self) -> bool:
        """Amplitude above three of its standard deviations."""
        return self.amplitude > 3.0 * self.amplitude_sigma


@dataclass(frozen=True)
class HarmonicFit:
    terms: list[HarmonicTerm]
    offsets: np.ndarray  # one per group
    residual_rms: float
    sigma: float  # residual standard deviation, with the fit's degrees of freedom


def resolvable_orders(angles_rad: np.ndarray, max_order: int, n_offsets: int = 1) -> list[int]:
    """Orders 1..K: below the Nyquist limit of the distinct sampled angles, and few enough that
    the fit keeps at least half its samples as degrees of freedom (2K + offsets ≤ N/2), so
    that the residual gives an honest σ."""
    angles = np.asarray(angles_rad, float)
    distinct = np.unique(np.round(np.mod(angles, 2 * np.pi), 9) % np.round(2 * np.pi, 9))
    nyquist = (len(distinct) - 1) // 2
    by_dof = (len(angles) // 2 - n_offsets) // 2
    return list(range(1, max(0, min(max_order, nyquist, by_dof)) + 1))


def fit_harmonics(angles_rad: np.ndarray, values: np.ndarray, orders: list[int], groups: np.ndarray | None = None) -> HarmonicFit:
    """Fit A_n, φ_n for the given orders and one offset per group (all one group by default)."""
    theta = np.asarray(angles_rad, dtype=float)
    y = np.asarray(values, dtype=float)
    groups = np.zeros(len(y), dtype=int) if groups is None else np.unique(np.asarray(groups), return_inverse=True)[1]
    n_groups = int(groups.max()) + 1 if len(groups) else 1
    cols = [np.sin(n * theta) for n in orders] + [np.cos(n * theta) for n in orders]
    offsets = np.zeros((len(y), n_groups))
    offsets[np.arange(len(y)), groups] = 1.0
    A = np.column_stack(cols + [offsets]) if cols else offsets
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    resid = y - A @ coef
    dof = max(len(y) - A.shape[1], 1)
    sigma = float(np.sqrt(resid @ resid / dof))
    cov = sigma**2 * np.linalg.pinv(A.T @ A)
    k = len(orders)
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
        terms.append(HarmonicTerm(n, amp, float(np.arctan2(b, a)), float(np.sqrt(max(amp_var, 0.0))), float(np.sqrt(max(ph_var, 0.0)))))
    return HarmonicFit(terms, coef[2 * k :], float(np.sqrt(np.mean(resid**2))), sigma)
