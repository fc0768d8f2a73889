"""The multi-station method's own checks (seed 000): a tracer length against the nominal geometry,
and the tracer back at its tracking segment's reference point (drift, creep). A failure is a
:class:`~rtcal.engine.checks.Contradiction`, never a result."""

from __future__ import annotations

import numpy as np

from rtcal.api import Contradiction


class TracerCheck:
    """Tracer lengths against the nominal geometry: the change since the tracer's reference is the
    change of the distance from the nominal station centre to the commanded point."""

    def __init__(self, first_guesses_mm: list[np.ndarray], axis_point_mm: np.ndarray, angles_deg: np.ndarray,
                 points_mm: np.ndarray, tolerance_mm: float):
        delta = np.radians(np.asarray(angles_deg, float) - angles_deg[0])
        c, s = np.cos(delta), np.sin(delta)
        axis = np.asarray(axis_point_mm, float)
        self.distance_mm = []  # per mount: (points × stations) nominal distances
        for first in first_guesses_mm:
            rel = np.asarray(first, float)[:2] - axis[:2]
            centres = np.column_stack([c * rel[0] - s * rel[1] + axis[0], s * rel[0] + c * rel[1] + axis[1],
                                       np.full(len(delta), float(first[2]))])
            self.distance_mm.append(np.linalg.norm(np.asarray(points_mm)[:, None, :] - centres[None, :, :], axis=2))
        self.tolerance_mm = tolerance_mm
        self.reference: tuple[int, int, int] | None = None

    def referenced(self, mount: int, point: int, station: int) -> None:
        self.reference = (mount, point, station)

    def check(self, length_mm: float, mount: int, point: int, station: int) -> None:
        if self.reference is None:
            return
        k, i, j = self.reference
        expected = self.distance_mm[mount][point, station] - self.distance_mm[k][i, j]
        if not abs(length_mm - expected) <= self.tolerance_mm:
            raise Contradiction("stage", f"the laser tracer's length at point {point + 1}, station {station + 1} is "
                                         f"{length_mm:.3f} mm where the nominal geometry expects {expected:.3f} mm: "
                                         f"{length_mm - expected:+.3f} mm apart (tolerance {self.tolerance_mm:g} mm, "
                                         "verification.tracer_tolerance_mm): the table or the CMM is not where it was "
                                         "commanded, or solver.first_station_guess_mm does not describe this set-up")


class TracerReturnCheck:
    """The tracer's length where its tracking segment was referenced, measured again (at the end
    of each pass, before the tracer is moved, before a stop): a count that drifted or creeps shows
    as a length away from the reference's. Tolerance: 5σ of the difference of two visits (the
    tracer's a + b·L per sample, the CMM's point noise, the table's repeatability at the tracer's
    radius), plus the stated ``drift_um`` (the air between the two, thermal drift)."""

    def __init__(self, tracer_noise_um: float, tracer_noise_ppm: float, cmm_noise_um: float, repeatability_arcsec: float,
                 radius_mm: float, drift_um: float):
        self.tracer_noise_um, self.tracer_noise_ppm = tracer_noise_um, tracer_noise_ppm
        self.cmm_noise_um = cmm_noise_um
        self.repeat_um = float(np.radians(repeatability_arcsec / 3600.0)) * radius_mm * 1e3
        self.drift_um = drift_um
        self.first: dict[int, float] = {}  # segment → mean length at its reference point, first visit

    def tolerance_um(self, distance_mm: float, samples: int) -> float:
        tracer = self.tracer_noise_um + self.tracer_noise_ppm * distance_mm * 1e-3
        sigma = np.sqrt(2.0 * tracer**2 / samples + 2.0 * self.cmm_noise_um**2 + 2.0 * self.repeat_um**2)
        return 5.0 * float(sigma) + self.drift_um

    def referenced(self, segment: int, lengths_mm: list[float]) -> None:
        """The first reading at the reference point of a new segment."""
        self.first.setdefault(segment, float(np.mean(lengths_mm)))

    def check(self, segment: int, lengths_mm: list[float], distance_mm: float, where: str) -> None:
        if segment not in self.first:
            return
        apart_um = (float(np.mean(lengths_mm)) - self.first[segment]) * 1e3
        tol = self.tolerance_um(distance_mm, len(lengths_mm))
        if not abs(apart_um) <= tol:
            raise Contradiction("laser_tracer", f"back at {where}, where tracking segment {segment} was referenced, the "
                                                f"tracer's length is {apart_um:+.1f} µm from its first reading there (tolerance "
                                                f"{tol:.2g} µm: 5σ of the stated noise, verification.tracer_drift_um): the "
                                                "count drifts or creeps; every length of the segment is suspect")
