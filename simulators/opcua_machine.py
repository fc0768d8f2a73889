"""Simulated machines' OPC 40001-1 identification over OPC UA (asyncua's server, loopback), laid out as
the companion specification says (docs/protocols/opcua.md):

- the ``Machines`` folder at its standard NodeId ``i=1001`` of the Machinery namespace, organised by
  ``Objects``, holding one object per machine (two here: the table rtcal's procedures name, serial
  number ``SIM-230-2``, and a second machine beside it, as a lab's server for a cell shows);
- each machine's ``Identification`` an AddIn (``HasAddIn``) with BrowseName ``DI:Identification``, whose
  properties are ``DI:Manufacturer``, ``DI:Model`` (LocalizedText), ``DI:SerialNumber``,
  ``DI:SoftwareRevision`` (String) and ``Machinery:YearOfConstruction`` (UInt16);
- a decoy: a vendor property also named ``SerialNumber`` (in a vendor namespace, after the standard one),
  which a client that matches names without their namespace would read instead of the nameplate's.

The model names say ``SIMULATED`` (within what the nameplate's LocalizedText holds): a run whose item was
identified here is a rehearsal, and says so. Tests lay out hostile servers with the same class: other
value types (``ua.Variant``), several machines, no standard folder, a server that admits only signed and
encrypted sessions (``security="sign-and-encrypt"``, a self-signed server certificate)."""

from __future__ import annotations

import asyncio
import logging
import threading
from pathlib import Path
from typing import Any

DI_URI = "http://opcfoundation.org/UA/DI/"
MACHINERY_URI = "http://opcfoundation.org/UA/Machinery/"
VENDOR_URI = "http://rtcal.invalid/SimulatedMachineVendor/"  # a vendor's own namespace (the decoy's)
MACHINES_FOLDER_ID = 1001  # OPC 40001-1: the Machines object, NodeId i=1001 in the Machinery namespace
logging.getLogger("asyncua").setLevel(logging.ERROR)  # its security-policy notices are not the user's concern
DEFAULT_IDENTITY = {"Manufacturer": "rtcal simulated machines", "Model": "Parker 200RT worm-drive stage (SIMULATED)",
                    "SerialNumber": "SIM-230-2", "YearOfConstruction": 2021, "SoftwareRevision": "1.0.0"}
SECOND_MACHINE = ("SimulatedLathe", {"Manufacturer": "rtcal simulated machines", "Model": "two-axis lathe (SIMULATED)",
                                     "SerialNumber": "SIM-LATHE-7", "YearOfConstruction": 2019,
                                     "SoftwareRevision": "2.3.1"})
DECOY_SERIAL = "VENDOR-DECOY-0000"
MACHINERY_PROPERTIES = ("YearOfConstruction",)  # the rest of the nameplate is DI's


def default_machines() -> dict[str, dict[str, Any]]:
    """What `rtcal sim serve --opcua` serves: the table the shipped procedures name, and a second machine."""
    return {"SimulatedTable": dict(DEFAULT_IDENTITY), SECOND_MACHINE[0]: dict(SECOND_MACHINE[1])}


async def _serve(host: str, port: int, machines: dict[str, dict[str, Any]], decoy: bool, standard_folder: bool,
                 security: str | None, certificate: tuple[Path, Path] | None, ready: threading.Event,
                 stop: asyncio.Event, bound: list[str], hours: float | None = None) -> None:
    from asyncua import Server, ua

    server = Server()
    await server.init()
    server.set_endpoint(f"opc.tcp://{host}:{port}/")
    server.set_server_name("rtcal simulated machines")
    if security == "sign-and-encrypt":  # only signed and encrypted sessions: no None endpoint at all
        assert certificate is not None
        server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
        await server.load_certificate(str(certificate[0]))
        await server.load_private_key(str(certificate[1]))
    di = await server.register_namespace(DI_URI)
    mns = await server.register_namespace(MACHINERY_URI)
    vendor = await server.register_namespace(VENDOR_URI)
    folder_id = f"ns={mns};i={MACHINES_FOLDER_ID}" if standard_folder else f"ns={vendor};s=Machines"
    folder = await server.nodes.objects.add_folder(folder_id, ua.QualifiedName("Machines", mns))
    for machine, identity in machines.items():
        node = await folder.add_object(f"ns={mns};s={machine}", ua.QualifiedName(machine, vendor))
        ident = await _add_in(server, node, f"ns={mns};s={machine}.Identification", ua.QualifiedName("Identification", di))
        for name, value in identity.items():
            ns = mns if name in MACHINERY_PROPERTIES else di
            await ident.add_property(f"ns={mns};s={machine}.{name}", ua.QualifiedName(name, ns), _variant(name, value))
        if hours is not None:  # OPC 40001-1 §14: the operation counters, Durations in ms (OPC 10000-100 §4.5.5)
            counters = await _add_in(server, node, f"ns={mns};s={machine}.OperationCounters",
                                     ua.QualifiedName("OperationCounters", di))
            for name, value in (("OperationDuration", hours), ("PowerOnDuration", hours * 1.5)):
                await counters.add_property(f"ns={mns};s={machine}.{name}", ua.QualifiedName(name, di),
                                            ua.Variant(value * 3_600_000.0, ua.VariantType.Double))
        if decoy:  # after the standard one: a client matching bare names (the last it finds) reads this one
            _rename(server, await ident.add_property(f"ns={vendor};s={machine}.VendorSerialNumber",
                                                     ua.QualifiedName("VendorSerialNumber", vendor),
                                                     ua.Variant(DECOY_SERIAL, ua.VariantType.String)),
                    ident, ua.QualifiedName("SerialNumber", vendor))
    async with server:
        binary: Any = server.bserver
        sock = binary._server.sockets[0]  # noqa: SLF001 — the port the OS gave (port 0)
        bound.append(f"opc.tcp://{host}:{sock.getsockname()[1]}")
        ready.set()
        await stop.wait()


async def _add_in(server: Any, parent: Any, node_id: str, name: Any) -> Any:
    """An object below ``parent`` by a ``HasAddIn`` reference (OPC 10000-100), as 40001-1 adds the Identification."""
    from asyncua import Node, ua

    item = ua.AddNodesItem()
    item.RequestedNewNodeId = ua.NodeId.from_string(node_id)
    item.BrowseName = name
    item.NodeClass = ua.NodeClass.Object
    item.ParentNodeId = parent.nodeid
    item.ReferenceTypeId = ua.NodeId.from_string(f"i={ua.ObjectIds.HasAddIn}")
    item.TypeDefinition = ua.NodeId.from_string(f"i={ua.ObjectIds.BaseObjectType}")
    attrs = ua.ObjectAttributes()
    attrs.DisplayName = ua.LocalizedText(name.Name)
    item.NodeAttributes = attrs
    result = (await server.iserver.isession.add_nodes([item]))[0]
    result.StatusCode.check()
    return Node(server.iserver.isession, result.AddedNodeId)


def _rename(server: Any, node: Any, parent: Any, name: Any) -> None:
    """Give ``node`` the BrowseName ``name`` in the address space itself: asyncua refuses a second property
    of one name below a parent whatever its namespace, which OPC UA allows (a qualified name is both)."""
    from asyncua import ua

    space = server.iserver.aspace
    space[node.nodeid].attributes[ua.AttributeIds.BrowseName].value = ua.DataValue(ua.Variant(name, ua.VariantType.QualifiedName))
    for ref in space[parent.nodeid].references:
        if ref.NodeId == node.nodeid:
            ref.BrowseName = name


def _variant(name: str, value: Any) -> Any:
    """The property's value as the nameplate types it; a ``ua.Variant`` as given (a hostile server's)."""
    from asyncua import ua

    if isinstance(value, ua.Variant):
        return value
    if name == "YearOfConstruction":
        return ua.Variant(value, ua.VariantType.UInt16)
    if name in ("Manufacturer", "Model"):
        return ua.Variant(ua.LocalizedText(value), ua.VariantType.LocalizedText)
    return ua.Variant(value, ua.VariantType.String)


class OpcUaMachine:
    """A server in a thread: ``address`` once started; ``close()`` stops it. ``identity`` updates the first
    machine's nameplate (the single-machine server of the older tests); ``machines`` replaces the layout
    (name → nameplate); ``decoy`` adds the vendor SerialNumber; ``standard_folder=False`` puts Machines at a
    vendor NodeId (a server that does not follow 40001-1); ``security="sign-and-encrypt"`` with
    ``certificate=(cert.der, key.pem)`` admits only signed and encrypted sessions; ``hours`` gives every
    machine OperationCounters (OperationDuration, PowerOnDuration: 40001-1 §14)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, machine: str = "SimulatedTable",
                 identity: dict[str, Any] | None = None, machines: dict[str, dict[str, Any]] | None = None,
                 decoy: bool = True, standard_folder: bool = True, security: str | None = None,
                 certificate: tuple[Path, Path] | None = None, hours: float | None = None) -> None:
        self._ready = threading.Event()
        self._bound: list[str] = []
        self._loop = asyncio.new_event_loop()
        self._stop = asyncio.Event()
        layout = machines if machines is not None else {machine: {**DEFAULT_IDENTITY, **(identity or {})}}
        args = (host, port, layout, decoy, standard_folder, security, certificate, self._ready, self._stop, self._bound,
                hours)
        self._failure: list[BaseException] = []
        self._thread = threading.Thread(target=self._main, args=(_serve(*args),), daemon=True)
        self._thread.start()
        if not self._ready.wait(30) or not self._bound:
            raise RuntimeError(f"the simulated OPC UA machine did not start: {self._failure[:1]}")
        self.address = self._bound[0]

    def _main(self, serve: Any) -> None:
        try:
            self._loop.run_until_complete(serve)
        except BaseException as exc:  # noqa: BLE001 — reported by the constructor
            self._failure.append(exc)
            self._ready.set()

    def close(self) -> None:
        self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(10)
