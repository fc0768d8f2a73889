"""The instrument kinds: the built-in ones and those installed packages add, one registry.

A kind is one interface, a subclass of :class:`drivers.interfaces.Instrument` that declares

- ``kind``: its name (a Python identifier; an installed kind's entry point has the same name),
- ``fields``: a tuple of :class:`drivers.interfaces.FieldDescription`, every value it reads — what
  ``describe()``, ``rtcal probe`` and a plan's ``Read`` name, the quantities and units a run stores
  and the store's ``descriptions`` rows; a field's ``physical_range`` (optional) is what no instrument
  of the kind can read beyond, refused like a non-finite value,
- ``_raw_values``: its adapter from its own read methods to those named values.

An installed package adds a kind through the entry-point group ``rtcal.instrument_kinds`` (name: the
kind, value: ``module:InterfaceClass``), its drivers through ``rtcal.drivers`` (drivers/models.py).
The entry points are read once per process, when a kind is first asked for that is not built in;
a plugin that fails to load or is malformed is left out and named in :attr:`KindRegistry.broken`
(one line), so a broken package never stops the built-in kinds, and none replaces a built-in kind.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any

from rtcal.registry import Registry
from drivers.interfaces import (PURPOSES, Autocollimator, Cmm, DialIndicator, Encoder, EnvironmentSensor,
                                FieldDescription, Instrument, LaserTracer, MachineTool, RotaryStage, Value,
                                check_described)

ENTRY_POINT_GROUP = "rtcal.instrument_kinds"
# the store's marker quantities (rtcal/store/runstore.py MARKERS): no described field may be stored under them
RESERVED_QUANTITIES = ("skipped", "rejected")


@dataclass(frozen=True)
class Kind:
    """An instrument kind as the registry knows it."""

    name: str
    interface: type[Instrument]
    fields: Mapping[str, FieldDescription]
    plugin: str = ""  # the distribution that registered it; "" for a built-in


BUILTIN = {c.kind: f"drivers.interfaces:{c.__name__}" for c in (
    RotaryStage, Cmm, LaserTracer, Encoder, Autocollimator, DialIndicator, EnvironmentSensor, MachineTool)}
"""The built-in kinds, registered as a plugin's are (by name and ``module:Interface``; their tables are
drivers/interfaces.py's DESCRIPTIONS)."""


def _number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _field_problem(f: Any) -> str:
    """What is wrong with one declared field ("" if nothing)."""
    if not isinstance(f, FieldDescription):
        return f"{str(f)[:40]!r} is not a FieldDescription"
    if not (isinstance(f.name, str) and f.name.isidentifier()):
        return f"field name {str(f.name)[:40]!r} is not an identifier"
    if not (isinstance(f.unit, str) and f.unit.strip()) or not (isinstance(f.what, str) and f.what.strip()):
        return f"{f.name}: give its unit and what it is"
    if f.dtype not in ("number", "integer") or f.probe_nan not in ("null", "omit", "keep"):
        return f"{f.name}: dtype must be 'number' or 'integer', probe_nan 'null', 'omit' or 'keep'"
    r = f.physical_range
    if r is not None and not (isinstance(r, tuple) and len(r) == 2 and _number(r[0]) and _number(r[1]) and r[0] < r[1]):
        return f"{f.name}: physical_range {str(r)[:40]} is not (lowest, highest) finite numbers"
    return ""


def kind_from(name: str, interface: Any, plugin: str) -> Kind:
    """An installed kind, checked: ValueError/TypeError saying in one line what is wrong."""
    if not (isinstance(interface, type) and issubclass(interface, Instrument)):
        raise TypeError(f"{getattr(interface, '__name__', str(interface)[:60])} is not an Instrument subclass "
                        f"(drivers.interfaces)")
    if interface.kind != name:
        raise ValueError(f"its entry point is {name!r} but its interface declares kind {interface.kind!r}")
    if not name.isidentifier():
        raise ValueError(f"kind {name[:40]!r} is not an identifier")
    declared = getattr(interface, "fields", None)
    if not isinstance(declared, tuple) or not declared:
        raise ValueError("it declares no `fields` (a tuple of FieldDescription)")
    problems = [p for p in map(_field_problem, declared) if p]
    if problems:
        raise ValueError(f"its fields: {problems[0]}")
    quantities = [f.quantity(p) for f in declared for p in PURPOSES]
    clash = sorted({q for q in quantities if quantities.count(q) > 1} | set(quantities) & set(RESERVED_QUANTITIES))
    if clash:
        raise ValueError(f"its fields: {', '.join(clash)} stored twice or under a marker's name")
    if interface._raw_values is Instrument._raw_values:
        raise TypeError("it lacks _raw_values (its adapter from its read methods to the described values)")
    return Kind(name, interface, interface.described_fields(), plugin)


def kind_of_entry(name: str, interface: Any, plugin: str) -> Kind:
    """A kind from what its table entry or entry point names: a built-in's description is DESCRIPTIONS', an
    installed one's is checked (:func:`kind_from`)."""
    if not plugin:
        return Kind(name, interface, interface.described_fields())
    return kind_from(name, interface, plugin)


class KindRegistry(Registry[Kind]):
    """Every instrument kind by name: the built-in ones, then installed plugins' (read once, on first use)."""

    def unknown(self, name: str) -> str:
        """Why ``name`` is not a kind: one line a person can act on."""
        self.plugins()
        if name in self.broken:
            return f"instrument kind {name!r}: its plugin {self.broken[name]}"
        return f"unknown kind {name!r} (known: {', '.join(self)})"


KINDS = KindRegistry("kind", ENTRY_POINT_GROUP, BUILTIN, kind_of_entry, lambda group: entry_points(group=group))
"""Every instrument kind, by name (built in, and installed plugins')."""


def describe_kind(kind: str) -> dict[str, FieldDescription]:
    """The description of every instrument of ``kind`` (KeyError for a kind rtcal does not know)."""
    return dict(KINDS[kind].fields)


def recorded(kind: str, *names: str, purpose: str = "") -> tuple[tuple[str, str], ...]:
    """(quantity, unit) of each named field of ``kind`` read for ``purpose``: what a plan's Read stores."""
    table = KINDS[kind].fields
    return tuple((table[n].quantity(purpose), table[n].unit) for n in names)


def check_values(kind: str, values: Mapping[str, object], fields: Collection[str] | None = None) -> dict[str, Value]:
    """``values`` as the kind's description says they must be (:func:`drivers.interfaces.check_described`)."""
    return check_described(kind, KINDS[kind].fields, values, fields)
