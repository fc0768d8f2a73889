"""A rotary axis's ISO 230-1 error parameters besides its positioning error, as a volumetric
compensation takes them: error motions per angle (EXC, EYC, EZC in mm; EAC, EBC in rad) and location
errors (X0C, Y0C in mm; A0C, B0C in rad), each with where it came from.

A method's outputs make them from its results (``iso230_1_errors()``: the Abbe method's dial
indicators give EYC and EAC, seed 000's second tracer mount EXC, EYC, EAC, EBC and its network the
location; the R-test's eight location errors are the same :class:`LocationErrors` the kinematics
formats take); a format that takes them (rtcal/compensation/isg_volcomp.py) writes them. Plain data,
so this layer needs nothing above it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rtcal.compensation.kinematics import LocationErrors

RAD_PER_ARCSEC = math.pi / 648_000.0
MOTION_UNITS = {"EXC": "mm", "EYC": "mm", "EZC": "mm", "EAC": "rad", "EBC": "rad"}


@dataclass(frozen=True)
class ErrorMotions:
    """Error motions of the C axis at ascending angles in [0, 360): ``values`` per ISO 230-1 name
    (only those measured; mm or rad, :data:`MOTION_UNITS`), ``u`` the largest standard uncertainty
    of each over the angles (absent: not stated), ``source`` the run and method, ``note`` where they
    were measured and what they leave out."""

    angle_deg: np.ndarray
    values: dict[str, np.ndarray]
    source: str
    note: str
    u: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        unknown = set(self.values) - set(MOTION_UNITS)
        if unknown:  # a misspelt name would be written as a parameter the control reads
            raise ValueError(f"not an error motion of a C axis: {', '.join(sorted(unknown))}")

    def widest_gap_deg(self) -> float:
        """The widest gap between neighbouring angles over one turn."""
        a = np.sort(np.mod(np.asarray(self.angle_deg, float), 360.0))
        return float(np.max(np.diff(np.concatenate([a, [a[0] + 360.0]])))) if len(a) else 360.0

    def at(self, angle_deg: np.ndarray) -> dict[str, np.ndarray]:
        """Each motion at ``angle_deg``, linear between the measured angles around the turn (as the
        control interpolates its table)."""
        a = np.mod(np.asarray(self.angle_deg, float), 360.0)
        order = np.argsort(a)
        return {name: np.interp(np.mod(angle_deg, 360.0), a[order], np.asarray(v, float)[order], period=360.0)
                for name, v in self.values.items()}


@dataclass(frozen=True)
class MeasuredLocation:
    """Location errors as every method states them (:class:`rtcal.compensation.kinematics.LocationErrors`:
    seed 000's X0C, Y0C, A0C, B0C, the R-test's eight, in µm and arcsec with u) and the run they came from."""

    errors: LocationErrors
    source: str

    def in_si(self) -> dict[str, tuple[float, float, str]]:
        """ISO 230-1 name → (value, u, unit) in mm or rad, as a volumetric compensation takes them."""
        out = {}
        for symbol, v in self.errors.values.items():
            name, unit = symbol.split("_")
            scale, si = (1e-3, "mm") if unit == "um" else (RAD_PER_ARCSEC, "rad")
            out[name] = (v.value * scale, v.u * scale, si)
        return out
