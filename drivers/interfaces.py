"""The instrument interfaces. Units live in names; every method may raise :mod:`drivers.errors`.

A backend (in-process simulation, Modbus drive, serial ASCII instrument, TCP CMM) implements
one of these; the sequencer sees nothing else. Motions block until in position.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from drivers.errors import OutOfLimits


class Instrument(ABC):
    """Common life cycle: a name for messages, connect on construction, close when done."""

    name: str = "instrument"
    model: str = ""  # the product whose protocol a real-transport driver speaks (drivers/models.py)
    # how the protocol keeps other clients out while rtcal holds the instrument, as a certificate
    # states it; empty: the protocol cannot tell whether another client reaches the instrument
    exclusive_access: str = ""

    def close(self) -> None:  # noqa: B027 — optional for backends without a session
        """Release the transport; idempotent."""

    def identity(self) -> str:
        """What the instrument says it is (model, version, serial number), where its protocol can ask; else ""."""
        return ""

    def recover(self) -> None:  # noqa: B027 — most instruments latch nothing
        """Clear what the instrument latched after an error (a drive alarm, a CMM's error state)
        so that the next request can succeed; the fault policies call it before a retry."""


class RotaryStage(Instrument):
    """A rotary table driven to commanded angles (degrees, counterclockwise positive)."""

    limits_deg: tuple[float, float] = (-360.0, 360.0)
    step_deg: float = 0.0  # the smallest motion the drive makes (0: continuous); bounds how far its feedback may sit from the command

    def check_target(self, angle_deg: float) -> None:
        lo, hi = self.limits_deg
        if not (lo <= angle_deg <= hi) or not np.isfinite(angle_deg):
            raise OutOfLimits(self.name, f"target {angle_deg:.6f}° outside soft limits [{lo}, {hi}]°")

    @abstractmethod
    def home(self) -> None: ...

    @abstractmethod
    def move_to(self, angle_deg: float) -> None:
        """Move to the commanded angle; blocks until in position."""

    @abstractmethod
    def position_deg(self) -> float:
        """The angle the drive believes it is at (commanded or feedback)."""

    def feedback_deg(self) -> float:
        """The angle the drive's position feedback reports (its encoder), checked against the command
        after every move and around every reading; a drive without feedback reports its position."""
        return self.position_deg()

    @abstractmethod
    def stop(self) -> None: ...

    def reset_alarm(self) -> None:  # noqa: B027 — drives without alarms need nothing
        """Clear a drive alarm so that it can move again (not an emergency stop)."""

    def recover(self) -> None:
        self.reset_alarm()


class Cmm(Instrument):
    """A CMM moving its probe (here carrying the tracer's cat-eye reflector); mm, CMM frame."""

    volume_min_mm: tuple[float, float, float] = (-np.inf, -np.inf, -np.inf)
    volume_max_mm: tuple[float, float, float] = (np.inf, np.inf, np.inf)

    def check_target(self, xyz_mm: np.ndarray) -> None:
        xyz = np.asarray(xyz_mm, dtype=float)
        if not (np.all(np.isfinite(xyz)) and np.all(xyz >= self.volume_min_mm) and np.all(xyz <= self.volume_max_mm)):
            raise OutOfLimits(self.name, f"target {np.round(xyz, 3).tolist()} mm outside the measuring volume "
                                         f"{list(self.volume_min_mm)}..{list(self.volume_max_mm)}")

    @abstractmethod
    def home(self) -> None: ...

    @abstractmethod
    def move_to(self, xyz_mm: np.ndarray) -> None: ...

    @abstractmethod
    def position_mm(self) -> np.ndarray:
        """The probe position the CMM reports (its scales), mm."""

    @abstractmethod
    def stop(self) -> None: ...


@dataclass(frozen=True)
class LengthReading:
    """A relative interferometric length (mm) and the tracking segment it belongs to."""

    length_mm: float
    segment: int


class LaserTracer(Instrument):
    """An interferometer that tracks a reflector: relative length from its last reference."""

    @abstractmethod
    def reference(self) -> int:
        """(Re)establish the count at the present reflector position; returns the new segment number."""

    @abstractmethod
    def read_length(self) -> LengthReading:
        """One relative length; raises TrackingLost if tracking was lost since the reference."""


class Encoder(Instrument):
    @abstractmethod
    def read_angle_deg(self) -> float: ...


class Autocollimator(Instrument):
    @abstractmethod
    def read_arcsec(self) -> tuple[float, float]:
        """(x, y) deflection of the reflected beam, arcsec; x is the angle about the table axis."""

    def read_axes_arcsec(self) -> tuple[float, float]:
        """(x, y) as the instrument validates each axis: NaN for an axis it reports invalid while the
        other is good (what `rtcal probe` shows as null); ``read_arcsec`` is what a run uses."""
        return self.read_arcsec()


class DialIndicator(Instrument):
    @abstractmethod
    def read_um(self) -> float: ...


@dataclass(frozen=True)
class EnvironmentReading:
    """Air and material conditions at one moment: °C, Pa, % RH, °C (NaN: not measured by this sensor)."""

    air_temperature_c: float
    air_pressure_pa: float
    humidity_pct: float
    material_temperature_c: float = float("nan")


class EnvironmentSensor(Instrument):
    """A weather station for the interferometer's air and a material probe on the table."""

    @abstractmethod
    def read(self) -> EnvironmentReading: ...
