"""A rotary axis's ISO 230-1 error parameters besides its positioning error, as a volumetric
compensation takes them: error motions per angle (EXC, EYC, EZC in mm; EAC, EBC in rad) and location
errors (X0C, Y0C in mm; A0C, B0C in rad), each with where it came from.

A method's outputs make them from its results (``iso230_1_errors()``: the Abbe method's dial
indicators give EYC and EAC, seed 000's second tracer mount EXC, EYC, EAC, EBC and its network the
location); a format that takes them (rtcal/compensation/isg_volcomp.py) writes them. Plain data with
SI-like units, so this layer needs nothing above it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

RAD_PER_ARCSEC = math.pi / 648_000.0
MOTION_UNITS = {"EXC": "mm", "EYC": "mm", "EZC": "mm", "EAC": "rad", "EBC": "rad"}
LOCATION_UNITS = {"X0C": "mm", "Y0C": "mm", "A0C": "rad", "B0C": "rad"}


def _known(values: Mapping[str, object], units: Mapping[str, str], what: str) -> None:
    """Only ISO 230-1's names of the kind (a misspelt one would be written as a parameter the control reads)."""
    unknown = set(values) - set(units)
    if unknown:
        raise ValueError(f"not {what} of a C axis: {', '.join(sorted(unknown))}")


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
        _known(self.values, MOTION_UNITS, "an error motion")

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
class LocationErrors:
    """The C axis's location errors (:data:`LOCATION_UNITS`), their standard uncertainties, the run
    and method they came from and the frame they are in."""

    values: dict[str, float]
    source: str
    frame: str
    u: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _known(self.values, LOCATION_UNITS, "a location error")
