"""Periodic errors as lists of harmonics: value(θ) = Σ amplitude · sin(order·θ + phase).

One evaluation for the whole project: the bench uses it to make errors, the tests and the
harmonic analysis use it to check them.
"""

from __future__ import annotations

from dataclasses import dataclass
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
