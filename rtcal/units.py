"""Unit conversions used at the edges (YAML, CLI, reports).

The numeric core works in mm and radians; names carry their unit (``_um``, ``_arcsec``...).
"""

from __future__ import annotations

import math

ARCSEC_PER_RAD: float = 180.0 / math.pi * 3600.0
RAD_PER_ARCSEC: float = 1.0 / ARCSEC_PER_RAD
MM_PER_UM: float = 1e-3


def arcsec_to_rad(value_arcsec):
    """Arcseconds → radians (works on floats and numpy arrays)."""
    return value_arcsec * RAD_PER_ARCSEC


def rad_to_arcsec(value_rad):
    """Radians → arcseconds (works on floats and numpy arrays)."""
    return value_rad * ARCSEC_PER_RAD


def um_to_mm(value_um):
    """Micrometres → millimetres."""
    return value_um * MM_PER_UM
