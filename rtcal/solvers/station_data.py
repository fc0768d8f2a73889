"""The seed-000 solvers' input: lengths per point and station, with how they were taken."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MountReadings:
    """The lengths taken with the tracer on another mount of the table (the same points and stations)."""

    lengths_mm: np.ndarray  # n×m, NaN where skipped
    segments: np.ndarray  # n×m
    visits: np.ndarray  # n×m stage visits, numbered after the first mount's
    air_index: np.ndarray | None = None  # n×m refractive index of the air at each length (None: not measured)
    times_s: np.ndarray | None = None  # n×m time of each length on the run's clock, s (None: not known)
    material_temperature_c: np.ndarray | None = None  # n×m the table's temperature at each length (None: not measured)
    mount_temperature_c: np.ndarray | None = None  # n×m the tracer's mount's, a second probe (None: not measured)


@dataclass(frozen=True)
class MultistationData:
    """Arrays for the seed-000 solvers, from the raw readings (mm).

    ``visits`` numbers the stage visits: lengths taken while the table stood still share one
    (station-major order: a station's lengths; point-major: each length its own). ``point_visits``
    counts the CMM readings averaged into each point.
    """

    points_mm: np.ndarray  # n×3, CMM-reported, averaged over visits
    lengths_mm: np.ndarray  # n×m, tracer samples averaged; NaN where the reading was skipped
    segments: np.ndarray  # n×m tracking segment of each length (−1 where skipped)
    nominal_angles_deg: np.ndarray  # m
    raw_readings: int = 0  # planned readings present (point, station pairs with a length)
    visits: np.ndarray | None = None  # n×m stage visit of each length (−1 where skipped)
    point_visits: np.ndarray | None = None  # n
    other_mounts: tuple[MountReadings, ...] = ()  # the network estimator uses them; the others use the first mount
    air_index: np.ndarray | None = None  # n×m refractive index of the air at each length (None: not measured)
    environment: dict | None = None  # summary of the recorded air and material conditions, for the report
    times_s: np.ndarray | None = None  # n×m time of each length on the run's clock, s (None: not known)
    material_temperature_c: np.ndarray | None = None  # n×m the table's temperature at each length (None: not measured)
    mount_temperature_c: np.ndarray | None = None  # n×m the tracer's mount's, a second probe (None: not measured)
    # per mount n×m: how much each length shortens per ppm/K of the table's growth per sensed kelvin beyond the α it
    # was corrected with, mm (None: not solved — no sensor on a table that changes temperature)
    growth_mm_per_ppm: tuple[np.ndarray, ...] | None = None

    @classmethod
    def from_arrays(cls, points_mm, lengths_mm, nominal_angles_deg, segments=None) -> "MultistationData":
        """One continuous count, each length its own stage visit, each point read once (synthetic data)."""
        lengths = np.asarray(lengths_mm, float)
        n, m = lengths.shape
        seg = np.zeros((n, m), int) if segments is None else np.asarray(segments, int)
        return cls(np.asarray(points_mm, float), lengths, seg, np.asarray(nominal_angles_deg, float),
                   int(np.isfinite(lengths).sum()))

    @property
    def stage_visits(self) -> np.ndarray:
        n, m = self.lengths_mm.shape
        return np.arange(n * m).reshape(n, m) if self.visits is None else np.asarray(self.visits)

    @property
    def point_visit_counts(self) -> np.ndarray:
        return np.ones(len(self.points_mm)) if self.point_visits is None else np.asarray(self.point_visits, float)

    def run_fraction(self) -> list[np.ndarray]:
        """Per mount (the first, then ``other_mounts``): each length's place in the run, n×m, −1 at the
        first length of the whole run, +1 at its last (NaN where skipped). Without recorded times the
        lengths are taken as evenly spaced in the order they are stored (point-major, mount by mount)."""
        lengths = [np.asarray(self.lengths_mm, float)] + [np.asarray(o.lengths_mm, float) for o in self.other_mounts]
        recorded = [self.times_s] + [o.times_s for o in self.other_mounts]
        known = [t for t in recorded if t is not None]
        if len(known) < len(recorded):
            size = lengths[0].size
            known = [np.arange(k * size, (k + 1) * size, dtype=float).reshape(lengths[0].shape) for k in range(len(lengths))]
        times = [np.where(np.isfinite(L), np.asarray(t, float), np.nan) for t, L in zip(known, lengths)]
        every = np.concatenate([t[np.isfinite(t)] for t in times])
        if every.size == 0:
            return [np.full(L.shape, np.nan) for L in lengths]
        lo, hi = float(every.min()), float(every.max())
        span = hi - lo if hi > lo else 1.0
        return [2.0 * (t - lo) / span - 1.0 for t in times]

    def material_offsets_k(self) -> list[np.ndarray] | None:
        """Per mount: the table's temperature above 20 °C at each length, n×m (a length without its own
        reading takes the mean of the others); None when the table's temperature was not measured."""
        recorded = [self.material_temperature_c] + [o.material_temperature_c for o in self.other_mounts]
        temps = [t for t in recorded if t is not None]
        if len(temps) < len(recorded) or not any(np.isfinite(t).any() for t in temps):
            return None
        mean = float(np.nanmean(np.concatenate([np.asarray(t, float).ravel() for t in temps])))
        return [np.where(np.isfinite(t), t, mean) - 20.0 for t in temps]
