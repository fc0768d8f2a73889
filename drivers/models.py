"""The instrument models rtcal speaks: one named product per driver, chosen by an address's ``model=``.

Each kind of instrument has one built-in product, its default. An installed package adds a
model through the entry-point group ``rtcal.drivers`` (docs/drivers.md): the entry point's
name is the model name, its object a driver class with the attributes a built-in has
(``kind``, ``model``, ``schemes``, ``framing``, ``options``) and the constructor
``(address, timeout_s, **context)``. The names below are a contract other tools rely on.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any

from drivers.errors import AddressError
from drivers.interfaces import a_kind
from rtcal.registry import Registry

ENTRY_POINT_GROUP = "rtcal.drivers"



@dataclass(frozen=True)
class Framing:
    """A serial line's settings: what the product uses unless the address says otherwise."""

    baud: int = 9600
    bytesize: int = 8
    parity: str = "N"
    stopbits: int = 1

    def __str__(self) -> str:
        return f"{self.baud} {self.bytesize}{self.parity}{self.stopbits}"


@dataclass(frozen=True)
class Model:
    """A model as the registry knows it; ``target`` is ``module:Class``, imported when first opened."""

    name: str
    kind: str
    target: str
    schemes: tuple[str, ...] = ("serial",)
    framing: Framing | None = None
    options: dict[str, tuple[float, float, bool]] = field(default_factory=dict)  # the model's own address options
    plugin: str = ""  # the distribution that registered it; "" for a built-in

    def driver_class(self) -> Any:
        module, _, name = self.target.partition(":")
        try:
            return getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError) as exc:
            raise AddressError(f"model {self.name!r}: its driver {self.target} cannot be loaded ({exc})") from None


def builtin_framing(name: str) -> Framing:
    """A built-in serial model's framing (each has one: the table below)."""
    framing = BUILTIN[name].framing
    if framing is None:
        raise KeyError(f"built-in model {name!r} has no serial framing")
    return framing


def _builtin(name: str, kind: str, target: str, schemes: tuple[str, ...] = ("serial",), framing: Framing | None = None) -> Model:
    return Model(name, kind, target, schemes, framing)


# framing defaults: the public sources of each are in docs/protocols/
BUILTIN: dict[str, Model] = {m.name: m for m in (
    _builtin("oriental-az", "stage", "drivers.modbus_stage:ModbusStage", ("modbus-tcp", "modbus-rtu"),
             Framing(115200, 8, "E", 1)),
    _builtin("pi-gcs", "stage", "drivers.pi_gcs:PiGcsStage", framing=Framing(115200, 8, "N", 1)),
    _builtin("linuxcnc", "stage", "drivers.linuxcnc_stage:LinuxCncStage", ("linuxcncrsh",)),
    _builtin("linuxcnc-trt", "machine_tool", "drivers.linuxcnc_machine:LinuxCncMachine", ("linuxcncrsh",)),
    _builtin("ipp", "cmm", "drivers.ipp_cmm:IppCmm", ("ipp",)),
    _builtin("rtcal-line", "laser_tracer", "drivers.serial_instruments:LineLaserTracer", framing=Framing(115200, 8, "N", 1)),
    _builtin("qsb", "encoder", "drivers.serial_instruments:QsbEncoder", framing=Framing(230400, 8, "N", 1)),
    _builtin("elcomat", "autocollimator", "drivers.serial_instruments:ElcomatAutocollimator", framing=Framing(19200, 8, "N", 1)),
    _builtin("sylvac", "dial_indicator", "drivers.serial_instruments:SylvacIndicator", framing=Framing(4800, 7, "E", 2)),
    _builtin("vaisala-ptu300", "environment", "drivers.vaisala:VaisalaPtu300", framing=Framing(4800, 7, "E", 1)),
    _builtin("vaisala-ptb330", "environment", "drivers.vaisala:VaisalaPtb330", framing=Framing(4800, 7, "E", 1)),
)}
DEFAULT_MODEL = {"stage": "oriental-az", "cmm": "ipp", "laser_tracer": "rtcal-line", "encoder": "qsb",
                 "autocollimator": "elcomat", "dial_indicator": "sylvac", "environment": "vaisala-ptu300",
                 "machine_tool": "linuxcnc-trt"}

def model_of(name: str, cls: Any, plugin: str) -> Model:
    """A plugin's model, from its driver class's declared attributes (loaded when the models are first asked for:
    they are needed to validate an address)."""
    return Model(name, cls.kind, f"{cls.__module__}:{cls.__qualname__}", tuple(getattr(cls, "schemes", ("serial",))),
                 getattr(cls, "framing", None), dict(getattr(cls, "options", {})), plugin or "plugin")


MODELS: Registry[Model] = Registry("model", ENTRY_POINT_GROUP, BUILTIN, model_of, lambda group: entry_points(group=group))
"""Every model by name: the built-in ones (records naming their driver class, imported when one is opened) and
installed plugins' (a built-in name is never replaced)."""


def plugins() -> dict[str, Model]:
    """Models installed packages register (read once per process); a built-in name is never replaced."""
    return MODELS.plugins()


def all_models() -> dict[str, Model]:
    return {**BUILTIN, **plugins()}


def find_model(name: str) -> Model:
    """The model of that name, or AddressError listing the known ones (or why a plugin's failed)."""
    if name in BUILTIN:
        return BUILTIN[name]
    model = plugins().get(name)
    if model is None and name in MODELS.broken:
        raise AddressError(f"model {name!r}: plugin {MODELS.broken[name]}")
    if model is None:
        raise AddressError(f"unknown model {name!r} (known: {', '.join(sorted(all_models()))})")
    return model


def model_for(kind: str, options: dict[str, str], scheme: str = "") -> Model:
    """The model an address names for an instrument of ``kind`` (without ``model=``: the kind's
    default, or the one built-in model of the kind that speaks the address's ``scheme``)."""
    if kind not in DEFAULT_MODEL and "model" not in options:  # an installed kind: its one installed model
        return _installed_model_of(kind)
    name = options.get("model", DEFAULT_MODEL.get(kind, ""))
    if "model" not in options and scheme and scheme not in BUILTIN[name].schemes:
        speaking = [m.name for m in BUILTIN.values() if m.kind == kind and scheme in m.schemes]
        name = speaking[0] if len(speaking) == 1 else name
    model = find_model(name)
    if model.kind != kind:
        raise AddressError(f"model {model.name!r} is a {model.kind.replace('_', ' ')}, not a {kind.replace('_', ' ')}")
    return model


def _installed_model_of(kind: str) -> Model:
    """An installed kind has no built-in model: the address names one with ``model=``, unless one is installed."""
    models = sorted(m.name for m in plugins().values() if m.kind == kind)
    if len(models) != 1:
        raise AddressError(f"{a_kind(kind)} has no built-in model: name its model with model= "
                           f"({'installed: ' + ', '.join(models) if models else 'none is installed'})")
    return find_model(models[0])
