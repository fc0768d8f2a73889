"""rtcal driver plugin: the ACME laser-tracer bridge (a fictitious product for rtcal's tests).

The bridge sits between a tracer's vendor SDK and a serial line and speaks rtcal's adapter
protocol (docs/protocols/serial.md, "rtcal-line").
Installed, it adds the model ``acme-bridge`` for laser tracers: an address such as
``socket://10.0.0.7:4001?model=acme-bridge`` selects it.
"""

from __future__ import annotations

import re

from rtcal.api import Address, Framing, InstrumentFault, LaserTracer, LengthReading, SerialLine, TrackingLost


class AcmeBridgeTracer(LaserTracer):
    kind = "laser_tracer"  # which instrument of a procedure it can be
    model = "acme-bridge"  # the name `model=` gives (the entry point's name)
    schemes = ("serial",)  # a device path or socket://
    framing = Framing(115200, 8, "N", 1)  # the line's defaults; the address's baud/bytesize/parity/stopbits win
    options: dict[str, tuple[float, float, bool]] = {}  # its own address options: name → (lowest, highest, whole number)
    name = "laser_tracer"

    LENGTH = re.compile(r"LEN ([+-]?\d+(?:\.\d+)?) (\d{1,9})|ERR (\w+)")

    def __init__(self, address: Address, timeout_s: float = 1.0, **context: object):
        self.line = SerialLine(self.name, address, self.framing, timeout_s, terminator=b"\r\n")

    def identity(self) -> str:
        return "ACME laser-tracer bridge"

    def reference(self) -> int:
        reply = self.line.query(b"REF\r\n")
        m = re.fullmatch(r"OK REF (\d{1,9})", reply)
        if m is None:
            raise InstrumentFault(self.name, f"unexpected reply {reply[:80]!r}")
        return int(m.group(1))

    def read_length(self) -> LengthReading:
        reply = self.line.query(b"LEN?\r\n")
        m = self.LENGTH.fullmatch(reply)
        if m is None:
            raise InstrumentFault(self.name, f"unexpected reply {reply[:80]!r}")
        if m.group(3) == "LOST":
            raise TrackingLost(self.name, "the bridge reports the beam lost")
        if m.group(3):
            raise InstrumentFault(self.name, f"bridge error {m.group(3)}")
        return LengthReading(float(m.group(1)) * 1e-6, int(m.group(2)))

    def close(self) -> None:
        self.line.close()
