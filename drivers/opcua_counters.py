"""A machine's hours of use over OPC UA (OPC 40001-1 Machinery §14, the operation counter building
block): wires only. Read-only: the first (or the named) machine under ``Machines`` (as
drivers/opcua_identity.py finds it), its ``OperationCounters`` object, and the Duration property
``OperationDuration`` (how long it performed an activity; else ``PowerOnDuration``), in ms
(OPC 10000-100 §4.5.5) → hours. docs/protocols/opcua.md gives the sources."""

from __future__ import annotations

import asyncio
import math
from typing import Any

from drivers.errors import InstrumentError
from drivers.opcua_identity import machine_part

PROPERTIES = ("OperationDuration", "PowerOnDuration")  # in the order preferred: use, else powered


async def _read(address: str, timeout_s: float, machine: str | None) -> float:
    from asyncua import Client

    client = Client(url=address, timeout=timeout_s)
    async with client:
        try:
            counters, _ = await machine_part(client, address, machine, "OperationCounters")
        except InstrumentError as exc:
            if "OperationCounters" not in str(exc):
                raise
            raise InstrumentError("machine", f"{str(exc).removeprefix('machine: ')} (OPC 40001-1 §14): give the "
                                             "hours with --hours") from None
        found: dict[str, Any] = {}
        for prop in await counters.get_children():
            browse = str((await prop.read_browse_name()).Name)
            if browse in PROPERTIES:
                found[browse] = await prop.read_value()
        for wanted in PROPERTIES:
            value = found.get(wanted)
            if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value >= 0:
                return float(value) / 3_600_000.0
        raise InstrumentError("machine", f"{address}: OperationCounters holds no OperationDuration or PowerOnDuration "
                                         "(a Duration in ms)")


def read_hours(address: str, timeout_s: float = 5.0, machine: str | None = None) -> float:
    """The machine's hours of use at ``opc.tcp://HOST:PORT``."""
    if not address.startswith("opc.tcp://"):
        raise InstrumentError("machine", f"{address}: not an OPC UA address (opc.tcp://HOST:PORT)")
    try:
        return asyncio.run(asyncio.wait_for(_read(address, timeout_s, machine), timeout_s * 3))
    except InstrumentError:
        raise
    except (OSError, asyncio.TimeoutError, TimeoutError) as exc:
        raise InstrumentError("machine", f"{address}: no answer ({type(exc).__name__})") from None
    except Exception as exc:  # asyncua's own: the server answered wrongly
        raise InstrumentError("machine", f"{address}: {type(exc).__name__}: {str(exc)[:200]}") from None
