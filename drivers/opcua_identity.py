"""A machine's identification over OPC UA (OPC 40001-1 Machinery, Basic Building Blocks): wires only.

OPC 40001-1 use cases 5.1 and 5.2 (docs/protocols/opcua.md): the server's ``Objects`` holds
``Machines`` (BrowseName in the Machinery namespace ``http://opcfoundation.org/UA/Machinery/``), one
object per machine, each with an ``Identification`` object whose properties are Manufacturer, Model,
SerialNumber, SoftwareRevision (OPC 10000-100 DI) and YearOfConstruction (Machinery). The namespace
index is looked up by URI on each connection (servers number their namespaces as they please); the
properties are found by name."""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from drivers.errors import InstrumentError

MACHINERY_URI = "http://opcfoundation.org/UA/Machinery/"
logging.getLogger("asyncua").setLevel(logging.ERROR)  # its security-policy notices are not the user's concern
FIELDS = {"Manufacturer": "manufacturer", "Model": "model", "SerialNumber": "serial_number",
          "YearOfConstruction": "year_of_construction", "SoftwareRevision": "software_revision"}


async def machine_part(client: Any, address: str, machine: str | None, part: str) -> tuple[Any, str]:
    """The first (or the named) machine under ``Machines`` and its child ``part`` (Identification,
    OperationCounters): (the part's node, the machine's name); InstrumentError naming what is missing."""
    try:
        ns = await client.get_namespace_index(MACHINERY_URI)
    except ValueError:
        raise InstrumentError("machine", f"{address}: the server has no Machinery namespace ({MACHINERY_URI}): "
                                         "no OPC 40001-1 machine") from None
    machines = await client.nodes.objects.get_child(f"{ns}:Machines")
    children = await machines.get_children()
    names = [str((await c.read_browse_name()).Name) for c in children]
    if not children:
        raise InstrumentError("machine", f"{address}: Machines is empty")
    if machine is not None and machine not in names:
        raise InstrumentError("machine", f"{address}: no machine {machine!r} under Machines ({', '.join(names)})")
    name = machine or names[0]
    found = None
    for c in await children[names.index(name)].get_children():
        if (await c.read_browse_name()).Name == part:
            found = c
    if found is None:
        raise InstrumentError("machine", f"{address}: Machines/{name} has no {part}")
    return found, name


async def _read(address: str, timeout_s: float, machine: str | None) -> dict[str, Any]:
    from asyncua import Client

    client = Client(url=address, timeout=timeout_s)
    async with client:
        ident, name = await machine_part(client, address, machine, "Identification")
        out: dict[str, Any] = {"machine": name}
        for prop in await ident.get_children():
            name = (await prop.read_browse_name()).Name
            if name in FIELDS:
                value = await prop.read_value()
                out[FIELDS[name]] = value.Text if hasattr(value, "Text") else value
        for key in FIELDS.values():
            out.setdefault(key, None)
        return out


def read_identity(address: str, timeout_s: float = 5.0, machine: str | None = None) -> dict[str, Any]:
    """The identification of the first (or the named) machine at ``opc.tcp://HOST:PORT``."""
    if not address.startswith("opc.tcp://"):
        raise InstrumentError("machine", f"{address}: not an OPC UA address (opc.tcp://HOST:PORT)")
    try:
        return asyncio.run(asyncio.wait_for(_read(address, timeout_s, machine), timeout_s * 3))
    except InstrumentError:
        raise
    except (OSError, asyncio.TimeoutError, TimeoutError) as exc:
        raise InstrumentError("machine", f"{address}: no answer ({type(exc).__name__})") from None
    except Exception as exc:  # asyncua's own (ua.UaError, BadNoMatch…): the server answered wrongly
        raise InstrumentError("machine", f"{address}: {type(exc).__name__}: {str(exc)[:200]}") from None
