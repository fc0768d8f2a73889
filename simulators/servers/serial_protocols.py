"""Instrument ends of the serial ASCII protocols, backed by the simulated instruments.

Each handler turns one request line into one reply (bytes in, bytes out, terminators included)
and knows nothing of pseudo-terminals or sockets: :mod:`simulators.servers.hub` carries bytes.
"""

from __future__ import annotations

from typing import Protocol

from drivers.errors import InstrumentFault, TrackingLost
from simulators.instruments import SimAutocollimator, SimDialIndicator, SimEncoder, SimEnvironmentSensor, SimLaserTracer


class LineHandler(Protocol):
    terminator: bytes  # of requests
    reply_terminator: bytes

    def handle(self, request: bytes) -> bytes: ...

    def counted(self, request: bytes) -> bool:
        """Whether a request is a reading (the fault injector counts readings)."""


class FaultyLine:
    """Wraps a line handler with the bench's fault injector: one draw per reading.

    beam_break interrupts the tracer's beam (the reply then says so); no_reply answers nothing;
    garbled answers noise; truncated stops half-way, without the terminator. A faulted request
    does not reach the instrument, as in process.
    """

    def __init__(self, handler: LineHandler, name: str, bench):
        self.handler, self.name, self.bench = handler, name, bench
        self.terminator = handler.terminator

    def handle(self, request: bytes) -> bytes:
        fault = self.bench.faults.draw(self.name) if self.handler.counted(request) else None
        if fault is None:
            return self.handler.handle(request)
        if fault.kind == "beam_break":
            self.bench.beam_broken = True
            return self.handler.handle(request)
        if fault.kind == "no_reply":
            return b""
        if fault.kind == "garbled":
            return b"\x15#?%!~" + self.handler.reply_terminator
        return b"0 +1"  # truncated: no terminator follows


class ElcomatHandler:
    reply_terminator = b"\r"
    terminator = b"\r"

    def __init__(self, instrument: SimAutocollimator):
        self.instrument = instrument

    def counted(self, request: bytes) -> bool:
        return True

    def handle(self, request: bytes) -> bytes:
        if request.strip() != b"M":
            return b"9 0 0\r"
        try:
            x, y = self.instrument.read_arcsec()
        except InstrumentFault:
            return b"1 0 0\r"
        return f"0 {x:+.4f} {y:+.4f}\r".encode()


class SylvacHandler:
    reply_terminator = b"\r"
    terminator = b"\r"

    def __init__(self, instrument: SimDialIndicator):
        self.instrument = instrument

    def counted(self, request: bytes) -> bool:
        return True

    def handle(self, request: bytes) -> bytes:
        if request.strip() != b"?":
            return b"ERR3\r"
        return f"{self.instrument.read_um() / 1000.0:+.6f}\r".encode()


class QsbHandler:
    reply_terminator = b"\r\n"
    terminator = b"\r"

    def __init__(self, instrument: SimEncoder, counts_per_rev: int):
        self.instrument = instrument
        self.counts_per_rev = counts_per_rev

    def counted(self, request: bytes) -> bool:
        return True

    def handle(self, request: bytes) -> bytes:
        if request.strip().upper() != b"R0E":
            return b"!\r\n"
        count = round(self.instrument.read_angle_deg() / 360.0 * self.counts_per_rev)
        return f"0E{count & 0xFFFFFFFF:08X}\r\n".encode()


class TracerHandler:
    reply_terminator = b"\r\n"
    terminator = b"\n"

    def __init__(self, instrument: SimLaserTracer):
        self.instrument = instrument

    def counted(self, request: bytes) -> bool:
        return request.strip() == b"LEN?"

    def handle(self, request: bytes) -> bytes:
        command = request.strip()
        if command == b"REF":
            return f"OK REF {self.instrument.reference()}\r\n".encode()
        if command == b"LEN?":
            try:
                r = self.instrument.read_length()
            except TrackingLost:
                return b"ERR LOST\r\n"
            return f"LEN {r.length_mm * 1e6:.3f} {r.segment}\r\n".encode()
        return b"ERR CMD\r\n"


class EnvironmentHandler:
    """rtcal's environment line protocol: ``MEAS?`` → ``T=<°C> P=<Pa> RH=<%> TM=<°C>``."""

    reply_terminator = b"\r\n"
    terminator = b"\n"

    def __init__(self, instrument: SimEnvironmentSensor):
        self.instrument = instrument

    def counted(self, request: bytes) -> bool:
        return True

    def handle(self, request: bytes) -> bytes:
        if request.strip() != b"MEAS?":
            return b"ERR CMD\r\n"
        r = self.instrument.read()
        return (f"T={r.air_temperature_c:.4f} P={r.air_pressure_pa:.2f} RH={r.humidity_pct:.2f} "
                f"TM={r.material_temperature_c:.4f}\r\n").encode()
