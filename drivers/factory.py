"""Open a real-transport driver from an address string: the one place addresses meet drivers.

The address's ``model=`` (or the kind's default model, drivers/models.py) names the driver
class; the class is built as ``cls(address, timeout_s, **context)`` with what its kind needs
(stage: soft limits; CMM: volume and tool; dial indicator: its name).
"""

from __future__ import annotations

from typing import Any

from drivers.addresses import Address, AddressError, parse_address, redact_tokens
from drivers.interfaces import (Autocollimator, Cmm, DialIndicator, Encoder, EnvironmentSensor, Instrument, LaserTracer,
                                MachineTool, RotaryStage)
from drivers.fence import fenced, refuse_unfit_class
from drivers.kinds import KINDS
from drivers.models import Model, model_for

# a procedure's instruments and the kind of each (an instrument named after an installed kind is of it: kind_of)
KIND_OF = {"stage": "stage", "cmm": "cmm", "laser_tracer": "laser_tracer", "encoder": "encoder",
           "autocollimator": "autocollimator", "dial_indicator_1": "dial_indicator", "dial_indicator_2": "dial_indicator",
           "environment": "environment", "machine_tool": "machine_tool",
           **{f"nest_indicator_{i}": "dial_indicator" for i in (1, 2, 3)}}


def kind_of(instrument: str, declared: str | None = None) -> str:
    """The kind of a procedure's instrument: the one its section ``declared`` (``kind:``), else KIND_OF's (the
    shipped procedures' names), else the installed kind it is named after (AddressError naming the kind's broken
    plugin, or the known kinds)."""
    if declared is not None:
        if declared not in KINDS:
            raise AddressError(KINDS.unknown(declared))
        return declared
    if instrument in KIND_OF:
        return KIND_OF[instrument]
    if instrument in KINDS:
        return instrument
    raise AddressError(KINDS.unknown(instrument))


class SchemeMismatch(AddressError):
    """An address of another kind than the instrument's model speaks (a CMM at a Modbus address)."""

    def __init__(self, message: str, scheme: str, schemes: tuple[str, ...]):
        super().__init__(message)
        self.scheme, self.schemes = scheme, schemes


def resolve(kind: str, address: str) -> tuple[Address, Model]:
    """The parsed address and its model; AddressError if the address is of another kind or model."""
    parsed = parse_address(address)
    model = model_for(kind, parsed.options, parsed.scheme)
    if parsed.scheme not in model.schemes:
        what = kind.replace("_", " ")
        raise SchemeMismatch(f"{what}: {redact_tokens(address[:200])!r} is a {parsed.scheme} address; a {what} of model {model.name} "
                             f"needs {' or '.join(model.schemes)}", parsed.scheme, model.schemes)
    return parsed, model


def check_address(name: str, address: str, kind: str | None = None) -> None:
    """What procedure validation asks: the address suits the instrument ``name`` of ``kind`` (declared, else by
    its name; AddressError if not)."""
    resolve(kind_of(name, kind), address)


def open_instrument(kind: str, address: str, timeout_s: float, **context: Any) -> Instrument:
    """The driver the address names, inside the fence every reading passes (drivers/fence.py)."""
    parsed, model = resolve(kind, address)
    cls = model.driver_class()
    refuse_unfit_class(kind, model.name, model.plugin, model.target, cls)
    return fenced(kind, model.name, model.plugin, lambda: cls(parsed, timeout_s, **context))


def open_choice(name: str, choice: Any) -> Instrument:
    """A procedure's instrument ``name`` at its section's address, by its kind (its ``kind:``, else its name), with
    what the kind needs from the section: a stage its soft limits, a CMM its volume, tool and homing, a dial
    indicator its name (``choice``: a procedure's InstrumentChoice)."""
    kind = kind_of(name, getattr(choice, "kind", None))
    if choice.address is None:
        raise AddressError(f"{name}: `backend: sim` cannot be opened over a transport; give its address")
    return open_instrument(kind, choice.address, choice.timeout_s, **kind_context(kind, name, choice))


def kind_context(kind: str, name: str, choice: Any) -> dict[str, Any]:
    """What a driver of ``kind`` is built with from the procedure's section besides its address: a stage's soft
    limits, a CMM's volume, tool and homing, a dial indicator's name."""
    if kind == "stage":
        return {"limits_deg": tuple(choice.soft_limits_deg)}
    if kind == "cmm":
        return {"volume_min_mm": tuple(choice.volume_min_mm), "volume_max_mm": tuple(choice.volume_max_mm),
                "tool": choice.tool, "home": choice.home}
    if kind == "dial_indicator":
        return {"name": name}
    return {}


# each kind's fence subclasses the kind's interface (drivers/fence.py): the asserts below only narrow the type
def open_stage(address: str, limits_deg: tuple[float, float], timeout_s: float) -> RotaryStage:
    instrument = open_instrument("stage", address, timeout_s, limits_deg=limits_deg)
    assert isinstance(instrument, RotaryStage)
    return instrument


def open_cmm(address: str, volume_min_mm: Any, volume_max_mm: Any, timeout_s: float, tool: str | None = None,
             home: bool = False) -> Cmm:
    instrument = open_instrument("cmm", address, timeout_s, volume_min_mm=volume_min_mm, volume_max_mm=volume_max_mm,
                                 tool=tool, home=home)
    assert isinstance(instrument, Cmm)
    return instrument


def open_laser_tracer(address: str, timeout_s: float) -> LaserTracer:
    instrument = open_instrument("laser_tracer", address, timeout_s)
    assert isinstance(instrument, LaserTracer)
    return instrument


def open_encoder(address: str, timeout_s: float) -> Encoder:
    instrument = open_instrument("encoder", address, timeout_s)
    assert isinstance(instrument, Encoder)
    return instrument


def open_autocollimator(address: str, timeout_s: float) -> Autocollimator:
    instrument = open_instrument("autocollimator", address, timeout_s)
    assert isinstance(instrument, Autocollimator)
    return instrument


def open_dial_indicator(address: str, name: str, timeout_s: float) -> DialIndicator:
    instrument = open_instrument("dial_indicator", address, timeout_s, name=name)
    assert isinstance(instrument, DialIndicator)
    return instrument


def open_machine_tool(address: str, timeout_s: float, may_move: bool = True) -> MachineTool:
    instrument = open_instrument("machine_tool", address, timeout_s, may_move=may_move)
    assert isinstance(instrument, MachineTool)
    return instrument


def open_environment(address: str, timeout_s: float) -> EnvironmentSensor:
    instrument = open_instrument("environment", address, timeout_s)
    assert isinstance(instrument, EnvironmentSensor)
    return instrument
