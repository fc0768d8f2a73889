"""A new instrument kind as an installed plugin (entry point ``rtcal.instrument_kinds``): an
inclinometer, an electronic level standing on the rotary table, reading the table's tilt about its
own x and y axes.

The kind is its interface: ``kind``, its ``fields`` (what every inclinometer reads, in which unit,
and the physical range no level reads beyond) and ``_raw_values``, the adapter from its own read
method to those named values. From them rtcal describes it, stores its readings under the described
quantities and units (with the store's ``descriptions`` rows), fences a driver's readings and lets
``rtcal probe`` show it; nothing in rtcal names it. :class:`SimInclinometer` is its simulation, here
and not in simulators/: a kind's package brings what it needs, reading the simulated bench through
rtcal.api's ``SimBench`` (the plugin imports rtcal only from rtcal.api).
"""

from __future__ import annotations

import math
from abc import abstractmethod
import numpy as np

from rtcal.api import FieldDescription, Instrument, SimBench, Value

TILT_RANGE_ARCSEC = 36_000.0  # ±10°: an electronic level's widest range; a reading beyond is no reading


class Inclinometer(Instrument):
    """An electronic level on the table: its tilt about the table's x and y axes, arcsec."""

    kind = "inclinometer"
    fields = (
        FieldDescription("tilt_x_arcsec", "arcsec", "the table's tilt about its x axis, as the level on it reads",
                         physical_range=(-TILT_RANGE_ARCSEC, TILT_RANGE_ARCSEC)),
        FieldDescription("tilt_y_arcsec", "arcsec", "the table's tilt about its y axis, as the level on it reads",
                         physical_range=(-TILT_RANGE_ARCSEC, TILT_RANGE_ARCSEC)),
    )

    @abstractmethod
    def read_tilt_arcsec(self) -> tuple[float, float]:
        """(x, y) tilt of the level, arcsec, each about the table's own axis (it turns with the table)."""

    def _raw_values(self, wanted: frozenset[str]) -> dict[str, Value]:
        x, y = self.read_tilt_arcsec()
        return {"tilt_x_arcsec": Value(x, "arcsec"), "tilt_y_arcsec": Value(y, "arcsec")}


class SimInclinometer(Inclinometer):
    """A level on the simulated bench: the axis's tilt and the table's tilt error motion (εx, εy) at its
    angle, seen in the table's turning frame, plus the level's zero offset and noise. Without a bench it
    reads its zero offset plus noise from its own random stream."""

    name = "inclinometer"

    def __init__(self, bench: SimBench | None = None, noise_arcsec: float = 0.2, resolution_arcsec: float = 0.1,
                 zero_arcsec: tuple[float, float] = (1.5, -0.8), seed: int = 0):
        self.bench = bench
        self.noise_arcsec, self.resolution_arcsec, self.zero_arcsec = noise_arcsec, resolution_arcsec, zero_arcsec
        self._rng = bench.rng("inclinometer") if bench is not None else np.random.default_rng(seed)

    def _table_tilt_arcsec(self) -> tuple[float, float]:
        """The table's tilt in its own frame (0 without a bench)."""
        if self.bench is None:
            return 0.0, 0.0
        tx, ty = self.bench.table_tilt_arcsec()  # the housing's frame
        angle = math.radians(self.bench.table_angle_deg())
        c, s = math.cos(angle), math.sin(angle)
        return tx * c + ty * s, -tx * s + ty * c  # the level turns with the table

    def read_tilt_arcsec(self) -> tuple[float, float]:
        if self.bench is not None:
            self.bench.reading()
        tilt = self._table_tilt_arcsec()
        step = self.resolution_arcsec
        x, y = (t + z + self.noise_arcsec * float(self._rng.standard_normal()) for t, z in zip(tilt, self.zero_arcsec))
        return round(x / step) * step, round(y / step) * step
