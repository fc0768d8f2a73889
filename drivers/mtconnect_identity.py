"""A machine's identification from an MTConnect agent's probe (read-only HTTP GET): wires only.

MTConnect (docs/protocols/mtconnect.md): an agent answers ``GET http://HOST:PORT/probe`` (every
device) or ``GET http://HOST:PORT/DEVICE/probe`` (one device) with an ``MTConnectDevices`` XML
document; each ``Device`` element carries ``uuid`` and ``name`` attributes and a ``Description``
child whose attributes are ``manufacturer``, ``model``, ``serialNumber`` and ``station``. An agent
that cannot answer sends an ``MTConnectError`` document (``Errors/Error`` with ``errorCode``).

The reply is untrusted input: at most :data:`MAX_BYTES`, a document type declaration (and with it
any entity, the "billion laughs" expansion) refused before parsing, no redirect followed, every
value a bounded line of text."""

from __future__ import annotations

import re
import urllib.error
import urllib.request
from typing import Any
from urllib.parse import urlsplit, urlunsplit
from xml.etree import ElementTree

from drivers.errors import InstrumentError

MAX_BYTES = 4_000_000  # a probe of a large cell is some hundred kB
FIELDS = {"manufacturer": "manufacturer", "model": "model", "serialNumber": "serial_number"}


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *args: Any, **kwargs: Any) -> None:
        return None  # an agent answers where it is asked; a redirect is reported, not followed


def probe_url(address: str) -> str:
    """``http://HOST:PORT/DEVICE`` → ``…/DEVICE/probe``; ``http://HOST:PORT`` → ``…/probe`` (ValueError: not HTTP)."""
    parts = urlsplit(address)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ValueError(f"{address[:80]}: not an MTConnect agent's address (http://HOST:PORT/DEVICE)")
    path = parts.path.rstrip("/")
    if not path.endswith("/probe"):
        path += "/probe"
    return urlunsplit((parts.scheme, parts.netloc, path, "", ""))


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _text(value: str | None, limit: int = 200) -> str | None:
    if value is None:
        return None
    text = " ".join(re.sub(r"[\x00-\x1f\x7f-\x9f]", " ", value).split())
    return text[:limit] if text else None


def parse_probe(data: bytes, where: str, device: str | None = None) -> dict[str, Any]:
    """The identification in a probe document (InstrumentError: not one, an agent's error, several devices unnamed)."""
    head = data[:4096].lower()
    if b"<!doctype" in head or b"<!entity" in data.lower():
        raise InstrumentError("machine", f"{where}: the reply declares a document type or entities: refused (an "
                                         "MTConnect probe has none)")
    try:
        root = ElementTree.fromstring(data)
    except ElementTree.ParseError as exc:
        raise InstrumentError("machine", f"{where}: not XML ({exc})") from None
    if _local(root.tag) == "MTConnectError":
        errors = [f"{e.get('errorCode', '?')}: {_text(e.text) or ''}".strip() for e in root.iter() if _local(e.tag) == "Error"]
        raise InstrumentError("machine", f"{where}: the agent answered with an error ({'; '.join(errors)[:200] or 'none given'})")
    if _local(root.tag) != "MTConnectDevices":
        raise InstrumentError("machine", f"{where}: not an MTConnect probe (its root is {_local(root.tag)[:40]!r})")
    devices = [e for e in root.iter() if _local(e.tag) == "Device"]
    if device is not None:
        devices = [d for d in devices if d.get("name") == device or d.get("uuid") == device] or devices
    if not devices:
        raise InstrumentError("machine", f"{where}: the probe lists no Device")
    if len(devices) > 1:
        names = ", ".join(str(_text(d.get("name"), 40)) for d in devices[:6])
        raise InstrumentError("machine", f"{where}: {len(devices)} devices ({names}): name one (http://HOST:PORT/DEVICE)")
    d = devices[0]
    description = next((c for c in d if _local(c.tag) == "Description"), None)
    out: dict[str, Any] = {"machine": _text(d.get("name"), 200), "uuid": _text(d.get("uuid"), 200)}
    for attribute, key in FIELDS.items():
        out[key] = _text(description.get(attribute)) if description is not None else None
    out["year_of_construction"] = None  # (MTConnect's Description has none)
    out["software_revision"] = None
    out["description"] = _text(description.text, 300) if description is not None else None
    return out


def read_identity(address: str, timeout_s: float = 5.0) -> dict[str, Any]:
    """The identification of the device at ``http://HOST:PORT/DEVICE`` (its agent's probe)."""
    try:
        url = probe_url(address)
    except ValueError as exc:
        raise InstrumentError("machine", str(exc)) from None
    device = urlsplit(url).path.rstrip("/").rsplit("/", 2)[-2] if urlsplit(url).path.count("/") >= 2 else None
    opener = urllib.request.build_opener(_NoRedirect)
    request = urllib.request.Request(url, headers={"Accept": "application/xml"}, method="GET")
    try:
        with opener.open(request, timeout=timeout_s) as reply:
            data = reply.read(MAX_BYTES + 1)
    except urllib.error.HTTPError as exc:
        body = exc.read(MAX_BYTES + 1) if exc.fp is not None else b""
        if body and b"MTConnectError" in body[:2000]:
            parse_probe(body, url)
        raise InstrumentError("machine", f"{url}: HTTP {exc.code} {exc.reason}") from None
    except (urllib.error.URLError, OSError) as exc:
        raise InstrumentError("machine", f"{url}: no answer ({getattr(exc, 'reason', exc)})") from None
    if len(data) > MAX_BYTES:
        raise InstrumentError("machine", f"{url}: the reply is larger than {MAX_BYTES} bytes: not a probe")
    return parse_probe(data, url, device)
