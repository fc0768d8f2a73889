"""Commissioning a rig: ``rtcal probe`` (one instrument) and ``rtcal check`` (every instrument a
procedure needs), before a calibration is left running overnight.

A probe opens the instrument at its address with the model's driver, asks who it is where the
protocol can (``identity``), takes one reading — after one recovery, as a fault policy's retry
would (a CMM in its error state is cleared) — and closes it again. Nothing moves.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import textwrap
from dataclasses import dataclass, field
from typing import Any, Callable, TypeVar

import numpy as np

from drivers import factory
from drivers.addresses import AddressError
from drivers.errors import InstrumentError, TrackingLost
from drivers.interfaces import (Autocollimator, Cmm, DialIndicator, Encoder, EnvironmentSensor, Instrument, LaserTracer,
                                RotaryStage)
from drivers.kinds import KINDS

@dataclass
class ProbeResult:
    kind: str
    address: str
    model: str
    identity: str = ""
    reading: dict[str, float | None] = field(default_factory=dict)  # None: an axis the instrument reports invalid

    def as_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "address": self.address, "model": self.model, "identity": self.identity,
                "reading": self.reading}


_T = TypeVar("_T")


def _retrying(instrument: Instrument, read: Callable[[], _T], attempts: int = 3) -> _T:
    """``read()``, recovering the instrument between attempts (a CMM's error state, a drive alarm)."""
    for attempt in range(attempts):
        try:
            return read()
        except InstrumentError:
            if attempt == attempts - 1:
                raise
            try:
                instrument.recover()
            except InstrumentError:
                pass
    raise AssertionError("unreachable")


def read_once(kind: str, instrument: Instrument) -> dict[str, float | None]:
    """One reading, under the keys ``rtcal probe`` documents: the fields the instrument's description
    shows (drivers/interfaces.py: ``probe_key``, ``probe_divisor``, ``probe_nan``), whatever its kind."""
    shown = {name: f for name, f in instrument.describe().items() if f.probe_key is not None}
    try:
        values = instrument.read_values(shown)
    except TrackingLost:  # never referenced, or the beam was lost: reference where the reflector is, then read
        getattr(instrument, "reference")()
        values = instrument.read_values(shown)
    reading: dict[str, float | None] = {}
    for name, f in shown.items():
        value = values[name].value / f.probe_divisor
        if math.isnan(value) and f.probe_nan == "omit":
            continue
        reading[f.probe_key or name] = None if math.isnan(value) and f.probe_nan == "null" else float(value)
    return reading


def probe(kind: str, address: str, timeout_s: float = 2.0, **context: Any) -> ProbeResult:
    """Open, identify, read once, close. AddressError for a malformed address; InstrumentError else."""
    if kind not in KINDS:
        raise AddressError(KINDS.unknown(kind))
    _, model = factory.resolve(kind, address)
    if kind == "dial_indicator":
        context.setdefault("name", "dial_indicator")
    if kind in ("cmm", "stage", "machine_tool"):
        context["may_move"] = False  # a probe never moves a machine: an unhomed CMM is refused, never homed
    instrument = factory.open_instrument(kind, address, timeout_s, **context)
    try:
        identity = instrument.identity()
        reading = _retrying(instrument, lambda: read_once(kind, instrument))
    finally:
        try:
            instrument.close()
        except InstrumentError:
            pass
    return ProbeResult(kind, address, model.name, identity, reading)


def format_probe(result: ProbeResult, as_json: bool) -> str:
    if as_json:
        return json.dumps(result.as_dict())
    lines = [f"{result.kind} ({result.model}) at {result.address}", f"  identity: {result.identity or '(the protocol has no identity query)'}"]
    lines += [f"  {key}: {'not valid' if value is None else format(value, '.9g')}" for key, value in result.reading.items()]
    return "\n".join(lines)


# -- rtcal check -------------------------------------------------------------------------------------

@dataclass
class CheckRow:
    instrument: str
    model: str
    status: str  # "ready", "simulated", "FAILED"
    detail: str  # the reading, or what failed
    identity: str = ""
    calibration_due: str = ""  # from the procedure's metadata ("" when it states none)


def _probe_context(kind: str, name: str, choice: Any) -> dict[str, Any]:
    """What the driver is built with, as a run builds it, less the CMM's homing (a probe never homes a machine)."""
    context = factory.kind_context(kind, name, choice)
    context.pop("home", None)
    return context


def _in_range(name: str, choice: Any, reading: dict[str, float | None]) -> str:
    """What is wrong with a reading for this procedure ("" if nothing): stage limits, CMM volume."""
    if name == "stage":
        lo, hi = choice.soft_limits_deg
        position = reading["position_deg"]
        if position is not None and not lo <= position <= hi:
            return f"position {reading['position_deg']:.4f}° outside the procedure's soft limits [{lo:g}, {hi:g}]°"
    if name == "autocollimator" and reading["x_arcsec"] is None:
        return "X axis not valid (the autocollimator sees no face about the table axis): a run needs it"
    if name == "cmm":
        xyz = np.array([reading["x_mm"], reading["y_mm"], reading["z_mm"]])
        if np.any(xyz < choice.volume_min_mm) or np.any(xyz > choice.volume_max_mm):
            return (f"position {np.round(xyz, 3).tolist()} mm outside the procedure's volume "
                    f"{list(choice.volume_min_mm)}..{list(choice.volume_max_mm)} mm")
    return ""


def _summary(reading: dict[str, float | None]) -> str:
    return ", ".join(f"{k} {'not valid' if v is None else format(v, '.6g')}" for k, v in reading.items())


def check(proc, addresses: dict[str, str] | None = None, operator_address: str = "") -> list[CheckRow]:
    """One row per instrument the procedure needs: probed at its address and checked against the
    procedure's ranges, or marked simulated (in-process, nothing to check)."""
    instruments = proc.instruments
    rows: list[CheckRow] = []
    for name in instruments.present():
        choice = getattr(instruments, name)
        kind = choice.kind_of(name)
        if choice.is_sim:
            rows.append(CheckRow(name, "sim", "simulated", "in process, on the bench"))
            continue
        model = factory.resolve(kind, choice.address)[1].name
        try:
            result = probe(kind, choice.address, choice.timeout_s, **_probe_context(kind, name, choice))
        except InstrumentError as exc:
            rows.append(CheckRow(name, model, "FAILED", str(exc).removeprefix(f"{exc.instrument}: ")))
            continue
        problem = _in_range(name, choice, result.reading)
        rows.append(CheckRow(name, model, "FAILED" if problem else "ready", problem or _summary(result.reading), result.identity))
    if operator_address:
        from rtcal.engine.operator import OperatorUnavailable, RemoteSimOperator

        try:
            RemoteSimOperator(operator_address, timeout_s=2.0).ping()
            rows.append(CheckRow("operator", "sim-operator", "ready", "answers, and let us in"))
        except OperatorUnavailable as exc:
            rows.append(CheckRow("operator", "sim-operator", "FAILED", str(exc).removeprefix("operator: ")))
    return with_due_dates(rows, proc)


def with_due_dates(rows: list[CheckRow], proc, today: _dt.date | None = None) -> list[CheckRow]:
    """Every row with its instrument's calibration due date, a row per reference standard that is
    not probed (the polygon), and FAILED for one past its due date today: a run would refuse it."""
    today = today or _dt.datetime.now(_dt.timezone.utc).date()
    records = proc.metadata.instruments
    listed = {r.instrument for r in rows}
    rows = rows + [CheckRow(name, "–", "standard", "reference standard, not probed")
                   for name in records if name not in listed]
    out = []
    for r in rows:
        due = records[r.instrument].calibration_due if r.instrument in records else ""
        r.calibration_due = due or ("–" if r.instrument != "operator" else "")
        if due and _dt.date.fromisoformat(due) < today:
            r.status, r.detail = "FAILED", f"past its calibration due date {due}: a run refuses it"
        out.append(r)
    return out


WRAP_COLUMNS = {4: 30, 5: 16}  # the reading and the identity wrap at a word (never cut): the table fits 100 columns


def format_table(rows: list[CheckRow]) -> str:
    """One table, its long cells wrapped at word boundaries onto continuation lines: nothing is cut."""
    header = ("instrument", "model", "status", "due", "reading or problem", "identity")  # due: of its calibration
    cells = [header] + [(r.instrument, r.model, r.status, r.calibration_due, r.detail, r.identity) for r in rows]
    wrapped = [[textwrap.wrap(c, WRAP_COLUMNS[i], break_long_words=False, break_on_hyphens=False) or [""]
                if i in WRAP_COLUMNS else [c] for i, c in enumerate(row)] for row in cells]
    widths = [max(len(line) for row in wrapped for line in row[i]) for i in range(len(header))]
    lines = []
    for row in wrapped:
        for k in range(max(len(col) for col in row)):
            lines.append("  ".join((col[k] if k < len(col) else "").ljust(widths[i]) for i, col in enumerate(row)).rstrip())
    return "\n".join(lines)
