"""Synthetic seed-000 datasets made independently of the bench: stations on a circle, exact lengths.

Used to check the solvers against known truth without the sequencer in the way.
"""

from __future__ import annotations

import numpy as np

from rtcal.methods.multistation.procedure import GridPlan
from rtcal.solvers.station_data import MultistationData
from rtcal.units import arcsec_to_rad

PAPER_ANGLES_RAD = np.deg2rad(-145.0 + 30.0 * np.arange(11))
TRACER_RADIUS_MM, TRACER_AZIMUTH_DEG, TRACER_HEIGHT_MM = 65.33, -29.2, 122.5
FIRST_GUESS_MM = np.array([-64.9938, -6.6256, 122.5133])


def stations_mm(actual_angles_rad: np.ndarray) -> np.ndarray:
    phi = np.asarray(actual_angles_rad) + np.deg2rad(TRACER_AZIMUTH_DEG)
    return np.column_stack([TRACER_RADIUS_MM * np.cos(phi), TRACER_RADIUS_MM * np.sin(phi), np.full(len(phi), TRACER_HEIGHT_MM)])


def data(points_mm: np.ndarray, lengths_mm: np.ndarray, segments: np.ndarray | None = None) -> MultistationData:
    """The solvers' input for the paper's stations from synthetic arrays."""
    return MultistationData.from_arrays(points_mm, lengths_mm, np.rad2deg(PAPER_ANGLES_RAD), segments)


def dataset(positioning_error_arcsec: np.ndarray, length_noise_um: float = 0.0, rng: np.random.Generator | None = None):
    """(points n×3, lengths n×m, true per-step deviations arcsec) for the paper's plan."""
    points = GridPlan().points_mm()
    actual = PAPER_ANGLES_RAD + arcsec_to_rad(np.asarray(positioning_error_arcsec, float))
    centers = stations_mm(actual)
    dist = np.linalg.norm(points[:, None, :] - centers[None, :, :], axis=2)
    lengths = dist - dist[0, 0]  # one continuous count, referenced at point 1, station 1
    if length_noise_um:
        lengths = lengths + 1e-3 * length_noise_um * rng.standard_normal(lengths.shape)
    true_dev = np.diff(np.asarray(positioning_error_arcsec, float))
    return points, lengths, true_dev
