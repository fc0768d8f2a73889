"""A machine's identification over OPC UA (OPC 40001-1 Machinery, Basic Building Blocks): wires only.

What is read, in order (docs/protocols/opcua.md cites each step):

1. the namespace array: the indices of the Machinery (``http://opcfoundation.org/UA/Machinery/``) and
   DI (``http://opcfoundation.org/UA/DI/``) namespaces, looked up by URI on each connection;
2. the ``Machines`` folder **by its standard NodeId**, ``i=1001`` of the Machinery namespace (never a
   node found by its name: any vendor may name a folder "Machines");
3. its machines; one is chosen by name (``?machine=NAME``: BrowseName or DisplayName), by serial number
   (``?serial=SN``, or the procedure's ``serial_number``), or as the only one — several and no choice,
   or a choice two machines match, is refused;
4. the machine's ``DI:Identification`` and, of its properties, only the standard ones **by their
   qualified browse names**: ``DI:Manufacturer``, ``DI:Model``, ``DI:SerialNumber``,
   ``DI:SoftwareRevision`` and ``Machinery:YearOfConstruction`` (a vendor property named SerialNumber
   in another namespace is not the nameplate's).

Each value is checked for its type before it leaves here: text (String, or LocalizedText's text; a
whole number given for a String is taken as its decimal digits), a year (UInt16, or a DateTime's year);
an array, a structure or a text longer than :data:`MAX_TEXT_CHARS` is refused in one line naming the
property. Browsing is bounded (:data:`MAX_MACHINES`, :data:`MAX_PROPERTIES`).

Sessions: None/None unless the client's certificate is configured (``RTCAL_OPCUA_CERT``,
``RTCAL_OPCUA_KEY``, optionally ``RTCAL_OPCUA_SERVER_CERT`` to pin the server's): then the strongest
SignAndEncrypt endpoint the server offers. A server that admits only signed and encrypted sessions
and no certificate configured is one line saying which variables to set."""

from __future__ import annotations

import asyncio
import datetime as _dt
import logging
import os
from typing import Any
from urllib.parse import parse_qsl, urlsplit

from drivers.errors import InstrumentError

MACHINERY_URI = "http://opcfoundation.org/UA/Machinery/"
DI_URI = "http://opcfoundation.org/UA/DI/"
MACHINES_FOLDER_ID = 1001  # OPC 40001-1: the Machines object's NodeId in the Machinery namespace
logging.getLogger("asyncua").setLevel(logging.ERROR)  # its security-policy notices are not the user's concern
FIELDS = {"Manufacturer": "manufacturer", "Model": "model", "SerialNumber": "serial_number",
          "YearOfConstruction": "year_of_construction", "SoftwareRevision": "software_revision"}
MACHINERY_FIELDS = ("YearOfConstruction",)  # in the Machinery namespace; the rest are DI's (OPC 10000-100)
TEXT_FIELDS = ("Manufacturer", "Model", "SerialNumber", "SoftwareRevision")
MAX_TEXT_CHARS = 1000  # far beyond any nameplate's text; the procedure's validators then apply their own limits
MAX_MACHINES = 1000
MAX_PROPERTIES = 1000
CERT_ENV, KEY_ENV, SERVER_CERT_ENV = "RTCAL_OPCUA_CERT", "RTCAL_OPCUA_KEY", "RTCAL_OPCUA_SERVER_CERT"
# the SignAndEncrypt policies asyncua speaks, strongest first (OPC 10000-7 security policies)
POLICIES = ("Aes256Sha256RsaPss", "Aes128Sha256RsaOaep", "Basic256Sha256")


class IdentityError(InstrumentError):
    """The server answered, but not with a nameplate rtcal can use (exit 1, one line)."""


def shown(value: Any, limit: int = 80) -> str:
    """A value for a message: printable (control and format characters escaped), bounded."""
    text = value if isinstance(value, str) else repr(value)
    text = "".join(c if c.isprintable() else f"\\u{ord(c):04x}" for c in text[: 4 * limit])
    return text if len(text) <= limit else text[: limit - 1] + "…"


def split_address(address: str) -> tuple[str, dict[str, str]]:
    """``opc.tcp://HOST:PORT[/path][?machine=NAME|serial=SN]`` → the endpoint URL and the choice."""
    if not address.startswith("opc.tcp://"):
        raise InstrumentError("machine", f"{shown(address)}: not an OPC UA address (opc.tcp://HOST:PORT)")
    parts = urlsplit(address)
    options = dict(parse_qsl(parts.query, keep_blank_values=True))
    unknown = sorted(set(options) - {"machine", "serial"})
    if unknown:
        raise InstrumentError("machine", f"{shown(address)}: unknown option {shown(unknown[0], 40)} (machine=NAME or "
                                         "serial=SN choose one of several machines)")
    if "machine" in options and "serial" in options:
        raise InstrumentError("machine", f"{shown(address)}: give machine= or serial=, not both")
    return parts._replace(query="", fragment="").geturl(), options


def _value(name: str, value: Any) -> Any:
    """A property's value as rtcal takes it, or ValueError naming what the server sent instead."""
    from asyncua import ua

    if isinstance(value, (list, tuple)):
        raise ValueError(f"{name} is an array of {len(value)} values, not one value as OPC "
                         f"{'40001-1' if name in MACHINERY_FIELDS else '10000-100'} defines it")
    if name == "YearOfConstruction":
        if isinstance(value, _dt.datetime):  # a DateTime where the UInt16 belongs: its year
            return value.year
        if isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= 9999:
            return value
        raise ValueError(f"YearOfConstruction is {shown(value, 40)}, not a year (UInt16, e.g. 2021)")
    if isinstance(value, ua.LocalizedText):
        value = value.Text or ""
    elif isinstance(value, int) and not isinstance(value, bool):  # an Int32 serial number: its digits
        value = str(value)
    if not isinstance(value, str):
        raise ValueError(f"{name} is a {type(value).__name__}, not text (String or LocalizedText)")
    if len(value) > MAX_TEXT_CHARS:
        raise ValueError(f"{name} is {len(value)} characters long (at most {MAX_TEXT_CHARS}): not a nameplate's text")
    return value


async def _namespaces(client: Any, address: str) -> tuple[int, int]:
    array = await client.get_namespace_array()
    if not isinstance(array, list) or len(array) > 10_000:
        raise IdentityError("machine", f"{address}: its namespace array is not a list of URIs")
    found = {}
    for uri in (MACHINERY_URI, DI_URI):
        if uri not in array:
            raise IdentityError("machine", f"{address}: the server has no namespace {uri}: no OPC 40001-1 identification")
        found[uri] = array.index(uri)
    return found[MACHINERY_URI], found[DI_URI]


async def _machines(client: Any, address: str, mns: int) -> list[tuple[Any, str, str]]:
    """(node, BrowseName, DisplayName) of every machine in the standard Machines folder."""
    from asyncua import ua

    folder = client.get_node(f"ns={mns};i={MACHINES_FOLDER_ID}")
    try:
        await folder.read_browse_name()
    except ua.UaStatusCodeError:
        raise IdentityError("machine", f"{address}: no Machines folder at its standard NodeId (ns={mns};i="
                                       f"{MACHINES_FOLDER_ID}, OPC 40001-1 §5.2): the server does not follow OPC 40001-1") from None
    children = await folder.get_children(nodeclassmask=ua.NodeClass.Object)
    if len(children) > MAX_MACHINES:
        raise IdentityError("machine", f"{address}: Machines holds {len(children)} objects (at most {MAX_MACHINES})")
    out = []
    for node in children:
        browse = await node.read_browse_name()
        display = await node.read_display_name()
        out.append((node, str(browse.Name or ""), str(display.Text or "")))
    if not out:
        raise IdentityError("machine", f"{address}: Machines is empty")
    return out


async def _nameplate(node: Any, mns: int, di: int, address: str, label: str) -> dict[str, Any]:
    """The standard properties of a machine's DI:Identification, by qualified name."""
    from asyncua import ua

    ident = None
    for child in await node.get_children(nodeclassmask=ua.NodeClass.Object):
        name = await child.read_browse_name()
        if name.Name == "Identification" and name.NamespaceIndex in (di, mns):
            ident = child
            break
    if ident is None:
        raise IdentityError("machine", f"{address}: machine {shown(label, 60)} has no Identification (DI:Identification)")
    props = await ident.get_children(nodeclassmask=ua.NodeClass.Variable)  # its properties (and any component)
    if len(props) > MAX_PROPERTIES:
        raise IdentityError("machine", f"{address}: {shown(label, 60)}'s Identification holds {len(props)} properties")
    out: dict[str, Any] = {}
    for prop in props:
        qn = await prop.read_browse_name()
        want = mns if qn.Name in MACHINERY_FIELDS else di
        if qn.Name in FIELDS and qn.NamespaceIndex == want and FIELDS[qn.Name] not in out:
            try:
                out[FIELDS[qn.Name]] = _value(qn.Name, await prop.read_value())
            except ValueError as exc:
                raise IdentityError("machine", f"{address}: machine {shown(label, 60)}: {exc}") from None
    return out


def _choose(machines: list[tuple[Any, str, str, dict[str, Any]]], options: dict[str, str], serial: str | None,
            address: str) -> tuple[str, dict[str, Any]]:
    """The one machine the address or the procedure names, or the only one; else IdentityError."""
    listed = ", ".join(f"{shown(b, 40)} (serial {shown(p.get('serial_number') or '?', 30)})" for _, b, _, p in machines[:10])
    if "machine" in options:
        want = options["machine"]
        found = [m for m in machines if want in (m[1], m[2])]
        what = f"machine={shown(want, 60)}"
    elif "serial" in options or (serial and len(machines) > 1):
        want = options.get("serial", serial or "")
        found = [m for m in machines if m[3].get("serial_number") == want]
        what = f"serial number {shown(want, 60)}"
    else:
        if len(machines) > 1:
            raise IdentityError("machine", f"{address}: {len(machines)} machines under Machines ({listed}): name one "
                                           "(?machine=NAME or ?serial=SN in the address, or the procedure's serial_number)")
        return machines[0][1], machines[0][3]
    if not found:
        raise IdentityError("machine", f"{address}: no machine with {what} under Machines ({listed})")
    if len(found) > 1:
        raise IdentityError("machine", f"{address}: {len(found)} machines match {what} ({listed}): ambiguous; name one "
                                       "by ?machine=NAME")
    return found[0][1], found[0][3]


async def _secure(client: Any, url: str, address: str) -> None:
    """Choose the session's security: the configured client certificate on the strongest SignAndEncrypt
    endpoint, else None/None — refused in one line when the server offers no None endpoint."""
    from asyncua import ua
    from asyncua.crypto import security_policies

    cert, key = os.environ.get(CERT_ENV, ""), os.environ.get(KEY_ENV, "")
    endpoints = await client.connect_and_get_server_endpoints()
    offered = {(e.SecurityPolicyUri.rsplit("#", 1)[-1], e.SecurityMode) for e in endpoints}
    if not (cert or key):
        if ("None", ua.MessageSecurityMode.None_) not in offered:
            modes = ", ".join(sorted(f"{p} {m.name}" for p, m in offered)) or "none"
            raise IdentityError("machine", f"{address}: the server admits only secured sessions ({modes}): set "
                                           f"{CERT_ENV} and {KEY_ENV} to the client certificate and key it trusts "
                                           "(docs/protocols/opcua.md)")
        return
    if not (cert and key):
        raise InstrumentError("machine", f"{CERT_ENV} and {KEY_ENV} go together: the client certificate and its private key")
    policy = next((p for p in POLICIES if (p, ua.MessageSecurityMode.SignAndEncrypt) in offered), None)
    if policy is None:
        raise IdentityError("machine", f"{address}: the server offers no SignAndEncrypt endpoint rtcal speaks "
                                       f"({', '.join(POLICIES)})")
    from cryptography import x509

    try:
        with open(cert, "rb") as fh:
            data = fh.read(1_000_000)
        parsed = x509.load_pem_x509_certificate(data) if data.startswith(b"-----") else x509.load_der_x509_certificate(data)
        uris = parsed.extensions.get_extension_for_class(x509.SubjectAlternativeName).value \
            .get_values_for_type(x509.UniformResourceIdentifier)
    except (OSError, ValueError, x509.ExtensionNotFound) as exc:
        raise InstrumentError("machine", f"{CERT_ENV}={shown(cert)}: not a client certificate with an application URI "
                                         f"({shown(str(exc), 120)})") from None
    if uris:
        client.application_uri = uris[0]  # the session's application URI must be the certificate's
    try:
        await client.set_security(getattr(security_policies, f"SecurityPolicy{policy}"), cert, key,
                                  server_certificate=os.environ.get(SERVER_CERT_ENV) or None,
                                  mode=ua.MessageSecurityMode.SignAndEncrypt)
    except (OSError, ValueError) as exc:
        raise InstrumentError("machine", f"{KEY_ENV}={shown(key)}: cannot be used with {CERT_ENV} "
                                         f"({shown(str(exc), 120)})") from None


async def _read(address: str, timeout_s: float, serial: str | None) -> dict[str, Any]:
    from asyncua import Client

    url, options = split_address(address)
    client = Client(url=url, timeout=timeout_s)
    await _secure(client, url, address)
    async with client:
        _, name, plate, _ = await chosen_machine(client, address, serial)
        out: dict[str, Any] = {"machine": name, **{key: None for key in FIELDS.values()}}
        out.update(plate)
        return out


async def chosen_machine(client: Any, address: str, serial: str | None = None) -> tuple[Any, str, dict[str, Any], int]:
    """The machine the address (or ``serial``) chooses, on a connected ``client``: (its node, its name, its
    nameplate, the DI namespace's index) — what the identification and the operation counters are read from."""
    _, options = split_address(address)
    mns, di = await _namespaces(client, address)
    machines = [(node, browse, display, await _nameplate(node, mns, di, address, browse or display))
                for node, browse, display in await _machines(client, address, mns)]
    name, plate = _choose(machines, options, serial, address)
    return next(m[0] for m in machines if m[1] == name), name, plate, di


def read_identity(address: str, timeout_s: float = 5.0, serial: str | None = None) -> dict[str, Any]:
    """The identification of the machine at ``opc.tcp://HOST:PORT[?machine=NAME|serial=SN]``: the one
    named, or the one whose serial number is ``serial`` when there are several, or the only one. Text
    values are str (unchecked for characters: the caller's validators decide), the year an int, an
    absent property None."""
    split_address(address)  # an address that is none: one line before any connection
    try:
        return asyncio.run(asyncio.wait_for(_read(address, timeout_s, serial), timeout_s * 3))
    except InstrumentError:
        raise
    except (OSError, asyncio.TimeoutError, TimeoutError) as exc:
        raise InstrumentError("machine", f"{shown(address)}: no answer ({type(exc).__name__})") from None
    except Exception as exc:  # asyncua's own (ua.UaError, BadNoMatch…): the server answered wrongly
        raise InstrumentError("machine", f"{shown(address)}: {type(exc).__name__}: {shown(str(exc), 200)}") from None
