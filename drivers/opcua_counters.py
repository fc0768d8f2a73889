"""A machine's hours of use over OPC UA (OPC 40001-1 Machinery §14, the operation counter building
block): wires only. Read-only: the machine the address chooses, found and secured as
drivers/opcua_identity.py finds its identification, its ``DI:OperationCounters`` object, and the
Duration property ``OperationDuration`` (how long it performed an activity; else ``PowerOnDuration``),
in ms (OPC 10000-100 §4.5.5) → hours. docs/protocols/opcua.md gives the sources."""

from __future__ import annotations

import asyncio
import math
from typing import Any

from drivers.errors import InstrumentError
from drivers.opcua_identity import _secure, chosen_machine, shown, split_address

PROPERTIES = ("OperationDuration", "PowerOnDuration")  # in the order preferred: use, else powered


async def _read(address: str, timeout_s: float) -> float:
    from asyncua import Client, ua

    url, _ = split_address(address)
    client = Client(url=url, timeout=timeout_s)
    await _secure(client, url, address)
    async with client:
        node, name, _, di = await chosen_machine(client, address)
        counters = None
        for child in await node.get_children(nodeclassmask=ua.NodeClass.Object):
            qn = await child.read_browse_name()
            if qn.Name == "OperationCounters" and qn.NamespaceIndex == di:
                counters = child
        if counters is None:
            raise InstrumentError("machine", f"{address}: machine {shown(name, 60)} has no OperationCounters (OPC 40001-1 "
                                             "§14): give the hours with --hours")
        found: dict[str, Any] = {}
        for prop in await counters.get_children(nodeclassmask=ua.NodeClass.Variable):
            qn = await prop.read_browse_name()
            if qn.Name in PROPERTIES and qn.NamespaceIndex == di and str(qn.Name) not in found:
                found[str(qn.Name)] = await prop.read_value()
        for wanted in PROPERTIES:
            value = found.get(wanted)
            if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value >= 0:
                return float(value) / 3_600_000.0
        raise InstrumentError("machine", f"{address}: OperationCounters holds no OperationDuration or PowerOnDuration "
                                         "(a Duration in ms)")


def read_hours(address: str, timeout_s: float = 5.0) -> float:
    """The machine's hours of use at ``opc.tcp://HOST:PORT[?machine=NAME|serial=SN]`` (the machine chosen
    as its identification is)."""
    split_address(address)  # an address that is none: one line before any connection
    try:
        return asyncio.run(asyncio.wait_for(_read(address, timeout_s), timeout_s * 3))
    except InstrumentError:
        raise
    except (OSError, asyncio.TimeoutError, TimeoutError) as exc:
        raise InstrumentError("machine", f"{address}: no answer ({type(exc).__name__})") from None
    except Exception as exc:  # asyncua's own: the server answered wrongly
        raise InstrumentError("machine", f"{address}: {type(exc).__name__}: {str(exc)[:200]}") from None
