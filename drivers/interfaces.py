"""The instrument interfaces. Units live in names; every method may raise :mod:`drivers.errors`.

A backend (in-process simulation, Modbus drive, serial ASCII instrument, TCP CMM) implements
one of these; the engine sees nothing else. Motions block until in position.

Every mover (a stage, a CMM) stops in two parts: ``stop()`` sends the stop at once, and
``wait_stopped()`` says whether the machine was then *seen* to stop — its position read until it
no longer changes (:func:`watch_still`) — and where. A stop acknowledged is not a machine at rest
(linuxcncrsh acknowledges an abort queued behind the move it should cut), so the engine writes
"stopped" only where a position was seen still, and names every machine that may still move.
"""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable, Collection, Mapping, NamedTuple, Sequence

import numpy as np

from drivers.errors import OutOfLimits

# what a reading is taken for, beside the reading itself (""): the same field read again to check a
# position already read ("check"), after the other readings to see the machine stood still ("after"),
# or back at a tracking segment's reference point ("return")
PURPOSES = ("", "check", "after", "return")


@dataclass(frozen=True)
class FieldDescription:
    """One value an instrument kind reads (as ophyd's ``describe``): described once per kind, so a plan,
    the store, the dataset and ``rtcal probe`` take its name and unit from here and never spell them.

    ``recorded_as`` names a purpose's stored quantity where it is not ``{purpose}_{name}`` (stores
    written before the descriptions keep their names). ``may_be_nan``: NaN means "not measured" (a sensor
    without a material probe, an axis the instrument reports invalid), never a fault. How ``rtcal probe``
    shows it (its documented keys): ``probe_key`` ("": its name; None: not shown), divided by
    ``probe_divisor``, NaN as null, omitted or kept (``probe_nan``)."""

    name: str
    unit: str
    what: str
    dtype: str = "number"  # "number" (a float) or "integer"
    may_be_nan: bool = False
    recorded_as: Mapping[str, str] = field(default_factory=dict)
    probe_key: str | None = ""
    probe_divisor: float = 1.0
    probe_nan: str = "keep"  # "null", "omit" or "keep"
    # (lowest, highest) no instrument of the kind can read beyond: a value outside is refused, not stored
    # (None: the built-in kinds' fences in drivers/fence.py hold their ranges)
    physical_range: tuple[float, float] | None = None

    def quantity(self, purpose: str = "") -> str:
        """The quantity a reading of this field taken for ``purpose`` is stored under."""
        if purpose not in PURPOSES:
            raise ValueError(f"unknown purpose {purpose!r} (known: {', '.join(p or '(none)' for p in PURPOSES)})")
        if not purpose:
            return self.name
        return self.recorded_as.get(purpose, f"{purpose}_{self.name}")


class Value(NamedTuple):
    """A named reading's value with its unit (what :meth:`Instrument.read_values` returns per field)."""

    value: float
    unit: str


def _fields(*fields: FieldDescription) -> dict[str, FieldDescription]:
    return {f.name: f for f in fields}


# one table per instrument kind: every value an instrument of the kind reads
DESCRIPTIONS: dict[str, dict[str, FieldDescription]] = {
    "stage": _fields(FieldDescription("position_deg", "deg", "the angle the drive believes it is at (commanded or feedback)"),
                     FieldDescription("feedback_deg", "deg", "the table angle its position feedback (encoder) reports",
                                      recorded_as={"after": "feedback_after_deg"}, probe_key=None)),
    "cmm": _fields(*(FieldDescription(f"position_{a}_mm", "mm", f"the probe's {a} coordinate its scales report, CMM frame",
                                      probe_key=f"{a}_mm") for a in "xyz")),
    "laser_tracer": _fields(FieldDescription("length_mm", "mm", "the relative interferometric length since the last reference"),
                            FieldDescription("segment", "1", "the tracking segment the length belongs to", "integer",
                                             probe_key=None)),
    "encoder": _fields(FieldDescription("angle_deg", "deg", "the angle the encoder under test counts")),
    "autocollimator": _fields(
        FieldDescription("x_arcsec", "arcsec", "the deflection about the table axis (the face's angle)", may_be_nan=True,
                         probe_nan="null"),
        FieldDescription("y_arcsec", "arcsec", "the deflection about the horizontal axis (the face's tilt)", may_be_nan=True,
                         probe_nan="null")),
    "dial_indicator": _fields(FieldDescription("y_um", "um", "the indicator's displacement (the table's radial motion)",
                                               probe_key="displacement_mm", probe_divisor=1000.0)),
    # NaN: not measured by this sensor (EnvironmentReading); a plan stores only what was measured
    "environment": _fields(FieldDescription("air_temperature_c", "degC", "the air temperature on the beam path", may_be_nan=True),
                           FieldDescription("air_pressure_pa", "Pa", "the air pressure", may_be_nan=True),
                           FieldDescription("humidity_pct", "%", "the air's relative humidity", may_be_nan=True),
                           FieldDescription("material_temperature_c", "degC", "the table's material temperature",
                                            may_be_nan=True, probe_nan="omit"),
                           FieldDescription("mount_temperature_c", "degC", "a second material probe's: the region that "
                                            "carries the tracer (its mount), where the table's sensor is elsewhere",
                                            may_be_nan=True, probe_nan="omit")),
    # a machine tool's joints as its controller reports them; a rotary axis the machine lacks reads NaN
    "machine_tool": _fields(*(FieldDescription(f"position_{a}_mm", "mm", f"the {a.upper()} joint's position the control "
                                               "reports, machine frame", physical_range=(-1e5, 1e5)) for a in "xyz"),
                            *(FieldDescription(f"position_{a}_deg", "deg", f"the {a.upper()} joint's position the control "
                                               "reports (NaN: the machine has no such axis)", may_be_nan=True,
                                               probe_nan="omit", physical_range=(-36_000.0, 36_000.0)) for a in "abc")),
}


def a_kind(kind: str) -> str:
    """``kind`` as a message names one instrument of it: "an inclinometer", "a dial indicator"."""
    return ("an " if kind[:1] in "aeiou" else "a ") + kind.replace("_", " ")


class ReadingOutsideDescription(ValueError):
    """A reading that is not what its instrument's description says (a name, a unit, NaN)."""


def check_described(kind: str, table: Mapping[str, FieldDescription], values: Mapping[str, object],
                    fields: Collection[str] | None = None) -> dict[str, Value]:
    """``values`` as the kind's description ``table`` says they must be: every described name (of
    ``fields``, if given), no other, each a :class:`Value` in the described unit, finite unless the field
    may be NaN, and within the field's physical range if it states one (by kind name: drivers/kinds.py)."""
    if fields is not None:
        unknown = sorted(set(fields) - set(table))
        if unknown:
            raise ReadingOutsideDescription(f"{', '.join(unknown)}: not described for a {kind.replace('_', ' ')}")
        table = {n: f for n, f in table.items() if n in fields}
    if not isinstance(values, Mapping):
        raise ReadingOutsideDescription(f"the reading {str(values)[:60]!r} is not named values")
    extra, missing = sorted(set(values) - set(table)), sorted(set(table) - set(values))
    if extra or missing:
        raise ReadingOutsideDescription(
            f"the reading's names {sorted(map(str, values))} are not the {kind.replace('_', ' ')}'s described "
            f"{sorted(table)}" + (f" (not described: {', '.join(map(str, extra))})" if extra else "")
            + (f" (missing: {', '.join(missing)})" if missing else ""))
    out = {}
    for name, f in table.items():
        v = values[name]
        if not isinstance(v, tuple) or len(v) != 2:
            raise ReadingOutsideDescription(f"{name}: {str(v)[:40]!r} is not a value with its unit")
        number, unit = v
        if unit != f.unit:
            raise ReadingOutsideDescription(f"{name} in {str(unit)[:20]!r}; its description says {f.unit!r}")
        if isinstance(number, bool) or not isinstance(number, (int, float, np.integer, np.floating)):
            raise ReadingOutsideDescription(f"{name}: {str(number)[:40]!r} is not a number")
        if not math.isfinite(float(number)) and not (f.may_be_nan and math.isnan(float(number))):
            raise ReadingOutsideDescription(f"{name} is {float(number)}: not a reading")
        if f.dtype == "integer" and not float(number).is_integer():
            raise ReadingOutsideDescription(f"{name} is {float(number)}: its description says a whole number")
        lo, hi = f.physical_range or (-math.inf, math.inf)
        if not lo <= float(number) <= hi and not math.isnan(float(number)):
            raise ReadingOutsideDescription(f"{name} {float(number):.9g} {f.unit} is outside what {a_kind(kind)} can read "
                                            f"({lo:g} … {hi:g} {f.unit})")
        out[name] = Value(float(number), f.unit)
    return out


SIMULATED_MARK = "SIMULATED"
"""What rtcal's protocol simulators put into their identity replies (a model or serial string, within the
format each product's reply allows: docs/protocols/): a run whose instrument says it is marked simulated."""


class Instrument(ABC):
    """Common life cycle: a name for messages, connect on construction, close when done.

    Every kind also reads uniformly: :meth:`describe` (its kind's table, once per device) and
    :meth:`read_values` (named values with units), adapters over the kind's own read methods."""

    kind: str = ""  # which table of DESCRIPTIONS describes it (an installed kind declares ``fields``: drivers/kinds.py)
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

    @classmethod
    def described_fields(cls) -> dict[str, FieldDescription]:
        """The kind's one table: a built-in kind's in DESCRIPTIONS, an installed kind's ``fields``."""
        declared = getattr(cls, "fields", None)
        if isinstance(declared, tuple):
            return {f.name: f for f in declared}
        return dict(DESCRIPTIONS[cls.kind])

    def describe(self) -> dict[str, FieldDescription]:
        """Name → description of every value :meth:`read_values` gives (the kind's one table)."""
        return type(self).described_fields()

    def read_values(self, fields: Collection[str] | None = None) -> dict[str, Value]:
        """One reading as named values with units (every described field, or those named), checked
        against :meth:`describe`."""
        wanted = frozenset(self.describe() if fields is None else fields)
        values = self._raw_values(wanted)
        return check_described(self.kind, self.describe(), {n: v for n, v in values.items() if n in wanted}, wanted)

    def _raw_values(self, wanted: frozenset[str]) -> dict[str, Value]:
        """The kind's adapter: its own read methods, called once each for what ``wanted`` needs."""
        raise NotImplementedError(f"{type(self).__name__} does not read")


STILL_S = 0.25  # a position that has not changed for this long, read again and again, is a machine at rest
STOP_WATCH_S = 5.0  # the longest a stop is watched: a table still turning after it is reported as moving
STOP_POLL_S = 0.02


@dataclass(frozen=True)
class StopSeen:
    """What a mover's stop was seen to do: ``still`` when its position was read unchanged for
    STILL_S after the stop; ``where`` the last position read, with its unit ("" when none could be);
    ``why`` says why it was not seen still."""

    still: bool
    where: str = ""
    why: str = ""


def watch_still(read: Callable[[], Any], show: Callable[[Any], str], tolerance: float, timeout_s: float = STOP_WATCH_S,
                still_s: float = STILL_S, poll_s: float = STOP_POLL_S, busy: Callable[[], bool] | None = None) -> StopSeen:
    """Read the position (``read``) until it stays within ``tolerance`` of one value for ``still_s``
    (a machine at rest), at most ``timeout_s``; a position that cannot be read is no machine seen at
    rest. ``show`` writes a position with its unit. ``busy``, asked after each reading, is the
    controller's word that a move still executes: while it says so the position is not at rest,
    however long it stays (a controller's report that stops being refreshed — LinuxCNC's task
    process starved on a loaded host — repeats its last position unchanged, and that it was moving)."""
    started = time.monotonic()
    last: Any = None
    anchor: Any = None  # the reading the position has stayed within tolerance of, since anchor_s
    anchor_s = started
    try:
        while True:
            last = read()
            moving = busy is not None and busy()
            now_s = time.monotonic()
            if anchor is None or moving or float(np.max(np.abs(np.asarray(last, float) - np.asarray(anchor, float)))) > tolerance:
                anchor, anchor_s = (None if moving else last), now_s
            elif now_s - anchor_s >= still_s:
                return StopSeen(True, show(last))
            if now_s - started >= timeout_s:
                return StopSeen(False, show(last), f"its controller still executed a move {timeout_s:g} s after the stop"
                                if moving else f"its position still changed {timeout_s:g} s after the stop")
            time.sleep(poll_s)
    except Exception as exc:  # noqa: BLE001 — a dead line: the machine was not seen to stop, which is the answer
        return StopSeen(False, show(last) if last is not None else "", f"its position could not be read ({exc})")


class RotaryStage(Instrument):
    """A rotary table driven to commanded angles (degrees, counterclockwise positive)."""

    kind = "stage"

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
    def stop(self) -> None:
        """Send the stop at once (the safe state): never waits for a motion to end."""

    # a table creeping this little in STILL_S is at rest (an encoder may flicker by a count)
    still_within_deg: float = 1e-4

    def wait_stopped(self, timeout_s: float = STOP_WATCH_S) -> StopSeen:
        """After :meth:`stop`: the feedback position read until it no longer changes (:func:`watch_still`)."""
        return watch_still(self.feedback_deg, lambda deg: f"{deg:.6f}°", max(self.still_within_deg, 2 * self.step_deg),
                           timeout_s)

    def reset_alarm(self) -> None:  # noqa: B027 — drives without alarms need nothing
        """Clear a drive alarm so that it can move again (not an emergency stop)."""

    def recover(self) -> None:
        self.reset_alarm()

    def _raw_values(self, wanted: frozenset[str]) -> dict[str, Value]:
        read = {"position_deg": self.position_deg, "feedback_deg": self.feedback_deg}
        return {n: Value(f(), "deg") for n, f in read.items() if n in wanted}


class Cmm(Instrument):
    """A CMM moving its probe (here carrying the tracer's cat-eye reflector); mm, CMM frame."""

    kind = "cmm"

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
    def stop(self) -> None:
        """Send the stop at once (the safe state): never waits for a motion to end."""

    still_within_mm: float = 1e-3  # a probe creeping this little in STILL_S is at rest

    def wait_stopped(self, timeout_s: float = STOP_WATCH_S) -> StopSeen:
        """After :meth:`stop`: the scales read until they no longer change (:func:`watch_still`)."""
        return watch_still(self.position_mm, lambda xyz: "(" + ", ".join(f"{v:.4f}" for v in xyz) + ") mm",
                           self.still_within_mm, timeout_s)

    def _raw_values(self, wanted: frozenset[str]) -> dict[str, Value]:
        return {f"position_{a}_mm": Value(float(v), "mm") for a, v in zip("xyz", self.position_mm())}


@dataclass(frozen=True)
class LengthReading:
    """A relative interferometric length (mm) and the tracking segment it belongs to."""

    length_mm: float
    segment: int


class LaserTracer(Instrument):
    """An interferometer that tracks a reflector: relative length from its last reference."""

    kind = "laser_tracer"

    @abstractmethod
    def reference(self) -> int:
        """(Re)establish the count at the present reflector position; returns the new segment number."""

    @abstractmethod
    def read_length(self) -> LengthReading:
        """One relative length; raises TrackingLost if tracking was lost since the reference."""

    def _raw_values(self, wanted: frozenset[str]) -> dict[str, Value]:
        r = self.read_length()
        return {"length_mm": Value(r.length_mm, "mm"), "segment": Value(r.segment, "1")}


class Encoder(Instrument):
    kind = "encoder"

    @abstractmethod
    def read_angle_deg(self) -> float: ...

    def _raw_values(self, wanted: frozenset[str]) -> dict[str, Value]:
        return {"angle_deg": Value(self.read_angle_deg(), "deg")}


class Autocollimator(Instrument):
    kind = "autocollimator"

    @abstractmethod
    def read_arcsec(self) -> tuple[float, float]:
        """(x, y) deflection of the reflected beam, arcsec; x is the angle about the table axis."""

    def read_axes_arcsec(self) -> tuple[float, float]:
        """(x, y) as the instrument validates each axis: NaN for an axis it reports invalid while the
        other is good (what `rtcal probe` shows as null); ``read_arcsec`` is what a run uses."""
        return self.read_arcsec()

    def _raw_values(self, wanted: frozenset[str]) -> dict[str, Value]:
        x, y = self.read_axes_arcsec()
        return {"x_arcsec": Value(x, "arcsec"), "y_arcsec": Value(y, "arcsec")}


class DialIndicator(Instrument):
    kind = "dial_indicator"

    @abstractmethod
    def read_um(self) -> float: ...

    def _raw_values(self, wanted: frozenset[str]) -> dict[str, Value]:
        return {"y_um": Value(self.read_um(), "um")}


@dataclass(frozen=True)
class EnvironmentReading:
    """Air and material conditions at one moment: °C, Pa, % RH, °C, °C (NaN: not measured by this sensor).
    ``mount_temperature_c``: a second material probe on the region that carries the tracer (its mount), so that a
    gradient between the table's sensor and the mount is measured, not budgeted."""

    air_temperature_c: float
    air_pressure_pa: float
    humidity_pct: float
    material_temperature_c: float = float("nan")
    mount_temperature_c: float = float("nan")


class EnvironmentSensor(Instrument):
    """A weather station for the interferometer's air and a material probe on the table."""

    kind = "environment"

    @abstractmethod
    def read(self) -> EnvironmentReading: ...

    def _raw_values(self, wanted: frozenset[str]) -> dict[str, Value]:
        r = self.read()
        return {f.name: Value(float(getattr(r, f.name)), f.unit) for f in DESCRIPTIONS["environment"].values()}


MACHINE_AXES = ("x", "y", "z", "a", "b", "c")


@dataclass(frozen=True)
class MachineTarget:
    """One coordinated move of a machine tool: every axis of ``joints`` (axis letter → mm or deg, the
    machine's axes exactly) arrives together, passing through the waypoints ``via`` in order (each a
    full set of axes), so that a rotary axis can turn while the linear axes follow a path — the
    R-test's nominal sphere path, which a straight joint move would leave by millimetres.

    ``tcp`` False: the values are joints, and a backend interpolates linearly in joint space between
    successive points. ``tcp`` True (tool-centre-point): x, y, z name the point of the table the
    controlled point goes to, by its machine coordinates at A = C = 0 (LinuxCNC's G53 coordinates
    under its table kinematics), and the control's own kinematic model turns it into joints while
    the rotary axes turn — LinuxCNC's ``xyzac-trt-kins``, a simulated control's nominal kinematics:
    a point held fixed on the table is followed by the linear axes however the rotary axes turn, and
    where the control's model is wrong the measured sphere strays (what the R-test sees, and what a
    corrected model removes). Between points a TCP backend interpolates linearly in those
    coordinates; :meth:`MachineTool.joint_positions` says where the joints went."""

    joints: Mapping[str, float]
    via: tuple[Mapping[str, float], ...] = ()
    tcp: bool = False

    def points(self) -> tuple[Mapping[str, float], ...]:
        """Every waypoint, then the target."""
        return (*self.via, self.joints)


class MachineTool(Instrument):
    """A machine tool's axes driven together (linear mm, rotary deg): what the R-test moves. A target
    names every axis of ``axes``; joint targets are refused beyond ``limits`` before anything moves;
    tool-centre-point targets (``MachineTarget.tcp``) only where the backend has the control's
    kinematics (``tcp``), which then refuses joints beyond its limits.

    Stopping is every mover's contract: :meth:`stop` sends the stop at once and never waits for a
    motion to end; :meth:`wait_stopped` then reads the joints until they no longer change — the
    engine writes "stopped" only where it saw that."""

    kind = "machine_tool"

    axes: tuple[str, ...] = ("x", "y", "z", "a", "c")
    limits: Mapping[str, tuple[float, float]] = {}
    tcp: bool = False  # the backend moves tool-centre-point targets through the control's kinematics
    still_within: float = 1e-4  # mm or deg: joints creeping less than this in STILL_S are at rest

    def check_target(self, target: MachineTarget) -> None:
        if target.tcp and not self.tcp:
            raise OutOfLimits(self.name, "a tool-centre-point target, and this machine tool's backend moves joints only")
        for point in target.points():
            if set(point) != set(self.axes):
                raise OutOfLimits(self.name, f"a target names axes {sorted(point)}; this machine's are {list(self.axes)}")
            for axis, value in point.items():
                lo, hi = (-math.inf, math.inf) if target.tcp and axis in "xyz" else self.limits.get(axis, (-math.inf, math.inf))
                if not (math.isfinite(value) and lo <= value <= hi):
                    unit = "mm" if axis in "xyz" else "°"
                    raise OutOfLimits(self.name, f"{axis.upper()} {value:.6g} {unit} outside its limits [{lo:g}, {hi:g}] {unit}")

    @abstractmethod
    def home(self) -> None:
        """Every joint referenced (homed) as the backend allows."""

    @abstractmethod
    def move_to(self, target: MachineTarget) -> None:
        """The coordinated move through ``target.via`` to ``target.joints``; blocks until in position."""

    @abstractmethod
    def joint_positions(self) -> dict[str, float]:
        """Each axis's joint position as the control reports it (mm, deg)."""

    @abstractmethod
    def stop(self) -> None:
        """Send the stop at once (the safe state): never waits for a motion to end."""

    def wait_stopped(self, timeout_s: float = STOP_WATCH_S) -> StopSeen:
        """After :meth:`stop`: the joints read until they no longer change (:func:`watch_still`)."""
        return watch_still(lambda: [self.joint_positions()[a] for a in self.axes], self.show_joints, self.still_within,
                           timeout_s)

    def show_joints(self, values: Sequence[float]) -> str:
        """Joint positions in the order of ``axes``, with their units."""
        return " ".join(f"{a.upper()} {v:.6f}" + (" mm" if a in "xyz" else "°") for a, v in zip(self.axes, values))

    def _raw_values(self, wanted: frozenset[str]) -> dict[str, Value]:
        at = self.joint_positions()
        out = {}
        for axis in MACHINE_AXES:
            unit = "mm" if axis in "xyz" else "deg"
            out[f"position_{axis}_{unit}"] = Value(float(at.get(axis, math.nan)), unit)
        return out
