"""In-process simulated instruments: the driver interfaces, read off the bench.

Physics comes from :class:`simulators.bench.Bench`; an instrument adds only its own reading
noise and resolution. Motions advance the bench's (virtual) clock by their duration.
"""

from __future__ import annotations

import math

import numpy as np

from drivers.interfaces import (
    Autocollimator,
    Cmm,
    DialIndicator,
    Encoder,
    LaserTracer,
    LengthReading,
    RotaryStage,
)
from drivers.errors import InstrumentFault
from rtcal.units import rad_to_arcsec, um_to_mm
from simulators.bench import Bench


def _quantise(value: float, step: float) -> float:
    return value if step <= 0 else round(value / step) * step


class SimStage(RotaryStage):
    name = "stage"

    def __init__(self, bench: Bench):
        self.bench = bench
        self.limits_deg = tuple(bench.scenario.stage.soft_limits_deg)

    def home(self) -> None:
        self.move_to(0.0)

    def move_to(self, angle_deg: float) -> None:
        self.check_target(angle_deg)
        target = math.radians(angle_deg)
        delta = target - self.bench.commanded_rad
        direction = self.bench.last_direction if delta == 0 else (1 if delta > 0 else -1)
        self.bench.clock.sleep(abs(math.degrees(delta)) / self.bench.scenario.stage.speed_deg_per_s)
        self.bench.move_stage(target, direction)

    def position_deg(self) -> float:
        return math.degrees(self.bench.commanded_rad)

    def stop(self) -> None:
        pass


class SimCmm(Cmm):
    name = "cmm"

    def __init__(self, bench: Bench):
        self.bench = bench
        sc = bench.scenario.cmm
        self.volume_min_mm, self.volume_max_mm = tuple(sc.volume_min_mm), tuple(sc.volume_max_mm)
        self._rng = bench.rng("cmm")
        self._reading_error_mm = np.zeros(3)

    def home(self) -> None:
        self.bench.move_probe(np.zeros(3))

    def move_to(self, xyz_mm: np.ndarray) -> None:
        self.check_target(xyz_mm)
        distance = float(np.linalg.norm(np.asarray(xyz_mm) - self.bench.probe_target_mm))
        self.bench.clock.sleep(distance / self.bench.scenario.cmm.speed_mm_per_s)
        self.bench.move_probe(xyz_mm)
        self._reading_error_mm = um_to_mm(self.bench.scenario.cmm.point_noise_um) * self._rng.standard_normal(3)

    def position_mm(self) -> np.ndarray:
        """The CMM's scales: the target plus this move's point error (fixed while at rest)."""
        return self.bench.probe_target_mm + self._reading_error_mm

    def stop(self) -> None:
        pass


class SimLaserTracer(LaserTracer):
    """Relative length = true length − length at the last reference, plus noise a + b·L."""

    name = "laser_tracer"

    def __init__(self, bench: Bench):
        self.bench = bench
        self._rng = bench.rng("laser_tracer")
        self._reference_mm: float | None = None
        self._segment = -1

    def reference(self) -> int:
        self._reference_mm = self.bench.tracer_length_mm()
        self._segment += 1
        return self._segment

    def read_length(self) -> LengthReading:
        if self._reference_mm is None:
            self.reference()
        length = self.bench.tracer_length_mm()
        lt = self.bench.scenario.laser_tracer
        sigma_mm = um_to_mm(lt.length_noise_um + lt.length_noise_ppm * length * 1e-3)
        return LengthReading(length - self._reference_mm + sigma_mm * self._rng.standard_normal(), self._segment)


class SimEncoder(Encoder):
    """The encoder below the tilt centre: reads the Abbe-shifted grating (seed 001)."""

    name = "encoder"

    def __init__(self, bench: Bench):
        self.bench = bench
        self._rng = bench.rng("encoder")

    def read_angle_deg(self) -> float:
        enc = self.bench.scenario.encoder
        value = rad_to_arcsec(self.bench.encoder_true_rad()) + enc.noise_arcsec * self._rng.standard_normal()
        return _quantise(value, enc.resolution_arcsec) / 3600.0


class SimAutocollimator(Autocollimator):
    """Reads the polygon face in front of it: x about the table axis, arcsec."""

    name = "autocollimator"

    def __init__(self, bench: Bench):
        self.bench = bench
        self._rng = bench.rng("autocollimator")

    def read_arcsec(self) -> tuple[float, float]:
        ac = self.bench.scenario.autocollimator
        x_rad, _ = self.bench.autocollimator_true()
        x = rad_to_arcsec(x_rad) + ac.noise_arcsec * self._rng.standard_normal()
        if abs(x) > ac.range_arcsec:
            raise InstrumentFault(self.name, f"no polygon face within ±{ac.range_arcsec:g}″ (deflection {x:.0f}″)")
        return float(_quantise(x, ac.resolution_arcsec)), 0.0


class SimDialIndicator(DialIndicator):
    """Y displacement of the shaft at a height below the tilt centre, µm."""

    def __init__(self, bench: Bench, index: int):
        self.bench = bench
        self.index = index
        self.name = f"dial_indicator_{index + 1}"
        self._rng = bench.rng(self.name)

    def read_um(self) -> float:
        di = self.bench.scenario.dial_indicators
        y_um = self.bench.shaft_y_mm(di.heights_mm[self.index]) * 1e3 + di.noise_um * self._rng.standard_normal()
        return _quantise(y_um, di.resolution_um)
