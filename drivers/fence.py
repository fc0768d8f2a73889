"""One fence around every driver: each value any model returns is checked before anything uses it.

The factory (drivers/factory.py) wraps every instance it opens — built-in or plugin — so no
driver can bypass the check: a reading must be a real number, finite, within the physical range
of its kind (below) and in the kind's unit; an identity is text of at most MAX_IDENTITY_CHARS
shown characters; a plugin whose constructor or method raises anything but the typed
:mod:`drivers.errors` is an :class:`InstrumentFault` naming the plugin (exit 1, one line).
"""

from __future__ import annotations

import inspect
import math
from typing import Any, Callable, Collection, Mapping, NoReturn

import numpy as np

from drivers.addresses import AddressError
from drivers.errors import InstrumentError, InstrumentFault
from drivers.interfaces import (Autocollimator, Cmm, DialIndicator, Encoder, EnvironmentReading, EnvironmentSensor,
                                FieldDescription, Instrument, LaserTracer, LengthReading, MachineTarget, MachineTool,
                                ReadingOutsideDescription, RotaryStage, StopSeen, Value, STOP_WATCH_S)
from drivers.kinds import KINDS, check_values, describe_kind

MAX_IDENTITY_CHARS = 200
# per kind: the unit its readings are in (what a driver class's ``reading_unit`` must say, if it says one)
UNITS = {"stage": "deg", "cmm": "mm", "laser_tracer": "mm", "encoder": "deg", "autocollimator": "arcsec",
         "dial_indicator": "um", "environment": "degC, Pa, %RH"}
# physical ranges: what no instrument of the kind can read beyond (a value past them is a fault, not a reading)
STAGE_BEYOND_LIMITS_DEG = 360.0  # a table is never a turn beyond its soft limits; INT_MIN feedback is
STAGE_RANGE_DEG = 36_000.0  # without limits: a hundred turns either way
CMM_RANGE_MM = 100_000.0  # no CMM is 100 m long
TRACER_RANGE_MM = 100_000.0  # a tracer's relative length beyond 100 m
ENCODER_RANGE_DEG = 36_000.0  # a multi-turn count of a hundred turns
AUTOCOLLIMATOR_RANGE_ARCSEC = 3_600.0  # autocollimators measure within about ±1000″
DIAL_RANGE_UM = 100_000.0  # a dial indicator's travel is at most 100 mm
MACHINE_RANGE = 100_000.0  # a machine tool's joint beyond 100 m (or a hundred turns and more) is no reading
ENVIRONMENT_RANGES = {"air_temperature_c": (-50.0, 100.0), "air_pressure_pa": (30_000.0, 150_000.0),
                      "humidity_pct": (0.0, 100.0), "material_temperature_c": (-50.0, 100.0),
                      "mount_temperature_c": (-50.0, 100.0)}


def shown_identity(text: Any) -> str:
    """An identity as rtcal prints and stores it: text, control characters escaped, bounded."""
    if not isinstance(text, str):
        text = "" if text is None else repr(text)
    text = "".join(c if c.isprintable() else f"\\x{ord(c):02x}" if ord(c) < 256 else f"\\u{ord(c):04x}"
                   for c in text[: 4 * MAX_IDENTITY_CHARS])
    return text if len(text) <= MAX_IDENTITY_CHARS else text[: MAX_IDENTITY_CHARS - 1] + "…"


class _Fenced:
    """What every fenced instrument shares: the inner driver, who made it, calls that name a plugin."""

    def __init__(self, inner: Instrument, kind: str, model: str, plugin: str):
        self._inner, self._kind, self._model_name, self._plugin = inner, kind, model, plugin
        # the base class's attributes are the driver's (a class attribute would hide __getattr__)
        name = getattr(inner, "name", kind)
        self.name: str = name if isinstance(name, str) and 0 < len(name) <= 64 else kind
        self.model: str = shown_identity(getattr(inner, "model", model) or model)
        how = getattr(inner, "exclusive_access", "")
        self.exclusive_access: str = shown_identity(how) if how else ""

    def __getattr__(self, attr: str) -> Any:  # what only this driver has (its line, its client)
        return getattr(self._inner, attr)

    def _call(self, method: str, *args: Any, **kwargs: Any) -> Any:
        try:
            return getattr(self._inner, method)(*args, **kwargs)
        except InstrumentError:
            raise
        except Exception as exc:  # noqa: BLE001 — a plugin's failure is the instrument's, named, never a traceback
            if not self._plugin:
                raise
            raise InstrumentFault(self.name, f"{what_plugin(self._model_name, self._plugin)}: {method} raised "
                                             f"{type(exc).__name__}: {shown_identity(str(exc))}") from None

    def _number(self, value: Any, what: str, lo: float, hi: float, unit: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise InstrumentFault(self.name, f"{what}: {shown_identity(repr(value))[:60]} is not a number in {unit}"
                                  f"{self._by()}")
        v = float(value)
        if not math.isfinite(v) or not lo <= v <= hi:
            raise InstrumentFault(self.name, f"{what} {v:.9g} {unit} is outside what a {self._kind.replace('_', ' ')} "
                                  f"can read ({lo:g} … {hi:g} {unit}){self._by()}: not a reading")
        return v

    def _by(self) -> str:
        return f" ({what_plugin(self._model_name, self._plugin)})" if self._plugin else ""

    def close(self) -> None:
        self._call("close")

    def identity(self) -> str:
        return shown_identity(self._call("identity"))

    def recover(self) -> None:
        self._call("recover")

    def describe(self) -> dict[str, FieldDescription]:
        return describe_kind(self._kind)  # a driver that describes itself otherwise is refused when opened

    def read_values(self, fields: Collection[str] | None = None) -> dict[str, Value]:
        """A driver's own ``read_values`` (a plugin's) is checked against the kind's whole description; else
        the kind's adapter over the fenced read methods."""
        try:
            if type(self._inner).read_values is not Instrument.read_values:
                values = check_values(self._kind, self._call("read_values"))
                return values if fields is None else {n: v for n, v in values.items() if n in fields}
            return super().read_values(fields)  # type: ignore[misc]  # the kind's adapter (Instrument.read_values)
        except ReadingOutsideDescription as exc:
            raise InstrumentFault(self.name, f"reading refused: {shown_identity(str(exc))}{self._by()}") from None


class _FencedMover(_Fenced):
    """A stage's or CMM's fence: what the driver saw of its stop, as text rtcal may show."""

    def wait_stopped(self, timeout_s: float = STOP_WATCH_S) -> StopSeen:
        seen = self._call("wait_stopped", timeout_s)
        if not isinstance(seen, StopSeen):
            return StopSeen(False, "", f"its wait_stopped answered {shown_identity(repr(seen))[:60]}, not what it saw"
                                       f"{self._by()}")
        return StopSeen(bool(seen.still), shown_identity(seen.where), shown_identity(seen.why))


def what_plugin(model: str, plugin: str) -> str:
    return f"model {model} of plugin {plugin}" if plugin else f"model {model}"


class FencedStage(_FencedMover, RotaryStage):
    def __init__(self, inner: RotaryStage, kind: str, model: str, plugin: str):
        super().__init__(inner, kind, model, plugin)
        lo, hi = inner.limits_deg
        self.limits_deg = (float(lo), float(hi))
        self.step_deg = float(getattr(inner, "step_deg", 0.0))

    def _range(self) -> tuple[float, float]:
        lo, hi = self.limits_deg
        if math.isfinite(lo) and math.isfinite(hi):
            return lo - STAGE_BEYOND_LIMITS_DEG, hi + STAGE_BEYOND_LIMITS_DEG
        return -STAGE_RANGE_DEG, STAGE_RANGE_DEG

    def home(self) -> None:
        self._call("home")

    def move_to(self, angle_deg: float) -> None:
        self._call("move_to", angle_deg)

    def position_deg(self) -> float:
        return self._number(self._call("position_deg"), "position", *self._range(), "°")

    def feedback_deg(self) -> float:
        return self._number(self._call("feedback_deg"), "feedback position", *self._range(), "°")

    def stop(self) -> None:
        self._call("stop")

    def reset_alarm(self) -> None:
        self._call("reset_alarm")


class FencedCmm(_FencedMover, Cmm):
    def __init__(self, inner: Cmm, kind: str, model: str, plugin: str):
        super().__init__(inner, kind, model, plugin)
        self.volume_min_mm, self.volume_max_mm = inner.volume_min_mm, inner.volume_max_mm

    def home(self) -> None:
        self._call("home")

    def move_to(self, xyz_mm: np.ndarray) -> None:
        self._call("move_to", xyz_mm)

    def position_mm(self) -> np.ndarray:
        value = self._call("position_mm")
        try:
            xyz = list(np.asarray(value, dtype=object).reshape(-1))
        except (TypeError, ValueError):
            xyz = []
        if len(xyz) != 3:
            raise InstrumentFault(self.name, f"position: {shown_identity(repr(value))[:60]} is not three coordinates "
                                  f"in mm{self._by()}")
        return np.array([self._number(v, f"position {axis}", -CMM_RANGE_MM, CMM_RANGE_MM, "mm")
                         for v, axis in zip(xyz, "xyz")])

    def stop(self) -> None:
        self._call("stop")


class FencedMachineTool(_FencedMover, MachineTool):
    def __init__(self, inner: MachineTool, kind: str, model: str, plugin: str):
        super().__init__(inner, kind, model, plugin)
        self.axes = tuple(str(a) for a in inner.axes)
        self.limits = {str(a): (float(lo), float(hi)) for a, (lo, hi) in dict(inner.limits).items()}
        self.tcp = bool(getattr(inner, "tcp", False))

    def home(self) -> None:
        self._call("home")

    def move_to(self, target: MachineTarget) -> None:
        self._call("move_to", target)

    def joint_positions(self) -> dict[str, float]:
        value = self._call("joint_positions")
        if not isinstance(value, Mapping) or set(value) != set(self.axes):
            raise InstrumentFault(self.name, f"joint positions: {shown_identity(repr(value))[:60]} names not this "
                                             f"machine's axes {list(self.axes)}{self._by()}")
        return {a: self._number(value[a], f"joint {a.upper()}", -MACHINE_RANGE, MACHINE_RANGE, "mm" if a in "xyz" else "°")
                for a in self.axes}

    def stop(self) -> None:
        self._call("stop")


class FencedLaserTracer(_Fenced, LaserTracer):
    def reference(self) -> int:
        segment = self._call("reference")
        return int(self._number(segment, "segment", 0, 1e9, "(a count)"))

    def read_length(self) -> LengthReading:
        r = self._call("read_length")
        if not isinstance(r, LengthReading):
            raise InstrumentFault(self.name, f"length: {shown_identity(repr(r))[:60]} is not a length reading{self._by()}")
        length = self._number(r.length_mm, "length", -TRACER_RANGE_MM, TRACER_RANGE_MM, "mm")
        segment = self._number(r.segment, "segment", 0, 1e9, "(a count)")
        return LengthReading(length, int(segment))


class FencedEncoder(_Fenced, Encoder):
    def read_angle_deg(self) -> float:
        return self._number(self._call("read_angle_deg"), "angle", -ENCODER_RANGE_DEG, ENCODER_RANGE_DEG, "°")


class FencedAutocollimator(_Fenced, Autocollimator):
    def read_arcsec(self) -> tuple[float, float]:
        value = self._call("read_arcsec")
        if not isinstance(value, (tuple, list)) or len(value) != 2:
            raise InstrumentFault(self.name, f"reading: {shown_identity(repr(value))[:60]} is not (x, y) in arcsec{self._by()}")
        r = AUTOCOLLIMATOR_RANGE_ARCSEC
        return (self._number(value[0], "x", -r, r, "″"), self._number(value[1], "y", -r, r, "″"))

    def read_axes_arcsec(self) -> tuple[float, float]:
        """As the instrument validates each axis: NaN stands for an axis it reports invalid (not both);
        each axis it gives is checked as :meth:`read_arcsec` checks it."""
        value = self._call("read_axes_arcsec")
        if not isinstance(value, (tuple, list)) or len(value) != 2:
            raise InstrumentFault(self.name, f"reading: {shown_identity(repr(value))[:60]} is not (x, y) in arcsec{self._by()}")
        r = AUTOCOLLIMATOR_RANGE_ARCSEC
        invalid = [isinstance(v, float) and math.isnan(v) for v in value]
        if all(invalid):
            raise InstrumentFault(self.name, f"neither axis valid: not a reading{self._by()}")
        x, y = (math.nan if bad else self._number(v, axis, -r, r, "″") for v, bad, axis in zip(value, invalid, "xy"))
        return x, y


class FencedDialIndicator(_Fenced, DialIndicator):
    def read_um(self) -> float:
        return self._number(self._call("read_um"), "displacement", -DIAL_RANGE_UM, DIAL_RANGE_UM, "µm")


class FencedEnvironmentSensor(_Fenced, EnvironmentSensor):
    def read(self) -> EnvironmentReading:
        r = self._call("read")
        if not isinstance(r, EnvironmentReading):
            raise InstrumentFault(self.name, f"reading: {shown_identity(repr(r))[:60]} is not an environment reading{self._by()}")
        values = {}
        for field, (lo, hi) in ENVIRONMENT_RANGES.items():
            v = getattr(r, field)
            # NaN: not measured by this sensor (declared so by EnvironmentReading); anything else must be in range
            values[field] = v if isinstance(v, float) and math.isnan(v) else self._number(v, field, lo, hi, "")
        return EnvironmentReading(**values)


FENCES: dict[str, Callable[..., Instrument]] = {
    "stage": FencedStage, "cmm": FencedCmm, "laser_tracer": FencedLaserTracer, "encoder": FencedEncoder,
    "autocollimator": FencedAutocollimator, "dial_indicator": FencedDialIndicator, "environment": FencedEnvironmentSensor,
    "machine_tool": FencedMachineTool}


class FencedKind(_Fenced):
    """An installed kind's fence (drivers/kinds.py): its interface's own methods reach the driver through
    :meth:`_Fenced._call`, and its readings are checked where they become values: :meth:`read_values`
    against the kind's description (names, units, finite, within each field's physical range); whatever
    else its adapter raises is the plugin's fault, named."""

    def read_values(self, fields: Collection[str] | None = None) -> dict[str, Value]:
        try:
            return super().read_values(fields)
        except InstrumentError:
            raise
        except Exception as exc:  # noqa: BLE001 — see _Fenced._call
            raise InstrumentFault(self.name, f"{what_plugin(self._model_name, self._plugin)}: its "
                                             f"{self._kind.replace('_', ' ')}'s reading raised {type(exc).__name__}: "
                                             f"{shown_identity(str(exc))}") from None


_KIND_FENCES: dict[type[Instrument], type[Instrument]] = {}  # per installed kind's interface


def _forwarded(method: str) -> Callable[..., Any]:
    def forward(self: _Fenced, *args: Any, **kwargs: Any) -> Any:
        return self._call(method, *args, **kwargs)

    forward.__name__ = forward.__qualname__ = method
    return forward


def fence_class(kind: str) -> Callable[..., Instrument]:
    """The fence of ``kind``: a built-in kind's own, else one made once from an installed kind's interface
    (each public method it adds to Instrument forwarded, so that the driver's own are what run)."""
    if kind in FENCES:
        return FENCES[kind]
    interface = KINDS[kind].interface
    if interface not in _KIND_FENCES:
        own = {name for c in interface.__mro__ if issubclass(c, Instrument) and c is not Instrument
               for name, v in vars(c).items() if not name.startswith("_") and inspect.isfunction(v)}
        _KIND_FENCES[interface] = type(f"Fenced{interface.__name__}", (FencedKind, interface),
                                       {name: _forwarded(name) for name in sorted(own - set(vars(_Fenced)))})
    return _KIND_FENCES[interface]


def reading_unit(kind: str) -> str:
    """The unit a driver class of ``kind`` may declare as its ``reading_unit``: UNITS', or an installed kind's
    fields' units."""
    return UNITS.get(kind) or ", ".join(dict.fromkeys(f.unit for f in describe_kind(kind).values()))


def refuse_unfit_class(kind: str, model: str, plugin: str, target: str, cls: Any) -> None:
    """A driver class that does not subclass its kind's interface (drivers/interfaces.py) is refused
    before it is built (AddressError, exit 2): nothing that is not a stage, say, may move the table —
    its methods' meaning is the interface's contract, not a set of matching names."""
    interface = KINDS[kind].interface
    if isinstance(cls, type) and issubclass(cls, interface):
        return
    needed = sorted(getattr(interface, "__abstractmethods__", ())) + ["close", "identity"]
    lacks = [m for m in needed if not callable(getattr(cls, m, None))]
    what = f"lacks {', '.join(lacks)}" if lacks else f"has {', '.join(needed)} but does not subclass it"
    raise AddressError(f"{what_plugin(model, plugin)} ({target}) is not a {interface.__name__} "
                       f"(drivers.interfaces): it {what}; a {kind.replace('_', ' ')} driver subclasses {interface.__name__}")


def fenced(kind: str, model: str, plugin: str, build: Callable[[], Instrument]) -> Instrument:
    """Build the driver (a plugin's failure named, exit 1) and wrap it in its kind's fence."""
    try:
        inner = build()
    except InstrumentError:
        raise
    except Exception as exc:  # noqa: BLE001 — see _Fenced._call
        if not plugin:
            raise
        raise InstrumentFault(kind, f"{what_plugin(model, plugin)}: could not be opened: its constructor raised "
                                    f"{type(exc).__name__}: {shown_identity(str(exc))}") from None
    unit = getattr(type(inner), "reading_unit", None)  # a plugin may declare the unit its readings are in
    if unit is not None and unit != reading_unit(kind):
        _refuse(inner, kind, f"{what_plugin(model, plugin)} declares its readings in {shown_identity(str(unit))[:20]!r}; "
                             f"a {kind.replace('_', ' ')} reads {reading_unit(kind)}")
    refused = _described_otherwise(kind, inner)
    if refused:
        _refuse(inner, kind, f"{what_plugin(model, plugin)} describes its readings otherwise than a "
                             f"{kind.replace('_', ' ')} reads: {shown_identity(refused)[:120]}")
    return fence_class(kind)(inner, kind, model, plugin)


def _refuse(inner: Any, kind: str, message: str) -> NoReturn:
    """An opened instrument that will not be used: closed (whatever its close does), then the fault."""
    try:
        inner.close()
    except Exception:  # noqa: BLE001, S110 — refused anyway
        pass
    raise InstrumentFault(kind, message)


def _described_otherwise(kind: str, inner: Instrument) -> str:
    """What a driver's own ``describe()`` says that its kind's description does not ("" if nothing)."""
    if type(inner).describe is Instrument.describe:
        return ""
    try:
        own = inner.describe()
        theirs = {str(k): (getattr(f, "name", None), getattr(f, "unit", None)) for k, f in dict(own).items()}
    except Exception as exc:  # noqa: BLE001 — a plugin's describe that fails is a description refused
        return f"describe raised {type(exc).__name__}"
    ours = {k: (f.name, f.unit) for k, f in describe_kind(kind).items()}
    if theirs == ours:
        return ""
    wrong = sorted(set(theirs.items()) ^ set(ours.items()), key=str)
    return ", ".join(f"{k} {v[1]!r}" for k, v in wrong[:4])
