"""A simulated machine's OPC 40001-1 identification over OPC UA (asyncua's server, loopback):
Objects/Machines/<machine>/Identification with Manufacturer, Model, SerialNumber, SoftwareRevision
(DI namespace) and YearOfConstruction (Machinery namespace), as a real machine's server lays them out;
with ``hours``, its OperationCounters too (OperationDuration, PowerOnDuration)."""

from __future__ import annotations

import asyncio
import threading
import logging
from typing import Any

DI_URI = "http://opcfoundation.org/UA/DI/"
MACHINERY_URI = "http://opcfoundation.org/UA/Machinery/"
logging.getLogger("asyncua").setLevel(logging.ERROR)  # its security-policy notices are not the user's concern
DEFAULT_IDENTITY = {"Manufacturer": "rtcal simulated machines", "Model": "Parker 200RT worm-drive stage (simulated)",
                    "SerialNumber": "SIM-230-2", "YearOfConstruction": 2021, "SoftwareRevision": "1.0.0"}


async def _serve(host: str, port: int, machine: str, identity: dict[str, Any], ready: threading.Event,
                 stop: asyncio.Event, bound: list[str], hours: float | None = None) -> None:
    from asyncua import Server, ua

    server = Server()
    await server.init()
    server.set_endpoint(f"opc.tcp://{host}:{port}/")
    server.set_server_name("rtcal simulated machine")
    di = await server.register_namespace(DI_URI)
    mns = await server.register_namespace(MACHINERY_URI)
    machines = await server.nodes.objects.add_folder(f"ns={mns};s=Machines", ua.QualifiedName("Machines", mns))
    node = await machines.add_object(f"ns={mns};s={machine}", ua.QualifiedName(machine, mns))
    ident = await node.add_object(f"ns={mns};s={machine}.Identification", ua.QualifiedName("Identification", di))
    for name, value in identity.items():
        ns = mns if name == "YearOfConstruction" else di
        variant = ua.Variant(value, ua.VariantType.UInt16) if name == "YearOfConstruction" else \
            ua.Variant(ua.LocalizedText(value) if name in ("Manufacturer", "Model") else value)
        await ident.add_property(f"ns={mns};s={machine}.{name}", ua.QualifiedName(name, ns), variant)
    if hours is not None:  # OPC 40001-1 §14: the operation counters, durations in ms (OPC 10000-100 §4.5.5)
        counters = await node.add_object(f"ns={mns};s={machine}.OperationCounters", ua.QualifiedName("OperationCounters", di))
        for name, value in (("OperationDuration", hours), ("PowerOnDuration", hours * 1.5)):
            await counters.add_property(f"ns={mns};s={machine}.{name}", ua.QualifiedName(name, di),
                                        ua.Variant(value * 3_600_000.0, ua.VariantType.Double))
    async with server:
        binary: Any = server.bserver
        sock = binary._server.sockets[0]  # noqa: SLF001 — the port the OS gave (port 0)
        bound.append(f"opc.tcp://{host}:{sock.getsockname()[1]}")
        ready.set()
        await stop.wait()


class OpcUaMachine:
    """A server in a thread: ``address`` once started; ``close()`` stops it."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, machine: str = "SimulatedTable",
                 identity: dict[str, Any] | None = None, hours: float | None = None) -> None:
        self._ready = threading.Event()
        self._bound: list[str] = []
        self._loop = asyncio.new_event_loop()
        self._stop = asyncio.Event()
        args = (host, port, machine, {**DEFAULT_IDENTITY, **(identity or {})}, self._ready, self._stop, self._bound, hours)
        self._thread = threading.Thread(target=self._loop.run_until_complete, args=(_serve(*args),), daemon=True)
        self._thread.start()
        if not self._ready.wait(30) or not self._bound:
            raise RuntimeError("the simulated OPC UA machine did not start")
        self.address = self._bound[0]

    def close(self) -> None:
        self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(10)
