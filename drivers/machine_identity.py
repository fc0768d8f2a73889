"""A machine's identification, over OPC UA (``opc.tcp://``, OPC 40001-1) or from an MTConnect agent
(``http://``, its probe): the same fields either way (manufacturer, model, serial_number,
year_of_construction, software_revision, the machine's name), for the certificate's item."""

from __future__ import annotations

from typing import Any

from drivers.errors import InstrumentError


def read_machine_identity(address: str, timeout_s: float = 5.0, serial: str | None = None) -> dict[str, Any]:
    """The identification at ``address``; ``serial`` chooses among an OPC UA server's machines (an MTConnect
    agent's device is the one its address names)."""
    if address.startswith("opc.tcp://"):
        from drivers.opcua_identity import read_identity

        return read_identity(address, timeout_s, serial)
    if address.startswith(("http://", "https://")):
        from drivers.mtconnect_identity import read_identity as read_probe

        return read_probe(address, timeout_s)
    raise InstrumentError("machine", f"{address[:80]}: a machine's identification is read over OPC UA "
                                     "(opc.tcp://HOST:PORT) or from an MTConnect agent (http://HOST:PORT/DEVICE)")
