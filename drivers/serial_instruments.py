"""Serial ASCII instruments, each a small declarative class: request, reply pattern, parse.

Protocols (docs/protocols/serial.md):
- autocollimator, ELCOMAT style: ``M\\r`` → ``<status> <x> <y>\\r`` (status 0 valid; arcsec)
- dial indicator, Sylvac style: ``?\\r`` → ``+0.00123\\r`` (mm), or ``ERR<n>\\r``
- encoder counter, US Digital QSB style: ``R0E\\r`` → ``0E<8 hex digits>\\r\\n`` (32-bit count)
- laser tracer, rtcal line protocol: ``REF\\r\\n`` → ``OK REF <segment>``; ``LEN?\\r\\n`` →
  ``LEN <nm> <segment>`` or ``ERR LOST``
- environment sensor, rtcal line protocol: ``MEAS?\\r\\n`` → ``T=<°C> P=<Pa> RH=<%> TM=<°C>``
"""

from __future__ import annotations

import re

from drivers.addresses import Address
from drivers.errors import InstrumentFault, TrackingLost
from drivers.interfaces import (
    Autocollimator,
    DialIndicator,
    Encoder,
    EnvironmentReading,
    EnvironmentSensor,
    LaserTracer,
    LengthReading,
)
from drivers.serial_line import SerialLine

NUMBER = r"[+-]?\d+(?:\.\d+)?"


def _match(name: str, pattern: re.Pattern, reply: str) -> re.Match:
    m = pattern.fullmatch(reply)
    if m is None:
        raise InstrumentFault(name, f"unexpected reply {reply[:80]!r}")
    return m


def _within(name: str, what: str, value: float, low: float, high: float) -> float:
    if not low <= value <= high:  # also false for NaN
        raise InstrumentFault(name, f"{what} {value:.6g} outside what it can measure [{low:g}, {high:g}]")
    return value


class ElcomatAutocollimator(Autocollimator):
    name = "autocollimator"
    REQUEST = b"M\r"
    REPLY = re.compile(rf"(\d) ({NUMBER}) ({NUMBER})")
    STATUS = {1: "no reflection in range", 2: "weak light", 3: "two reflections"}
    RANGE_ARCSEC = 3600.0  # an ELCOMAT's field is ±1000″; beyond a degree is no autocollimator reading

    def __init__(self, address: Address, timeout_s: float = 1.0):
        self.line = SerialLine(self.name, address.path, int(address.option("baud", 9600)), timeout_s)

    def read_arcsec(self) -> tuple[float, float]:
        m = _match(self.name, self.REPLY, self.line.query(self.REQUEST))
        status = int(m.group(1))
        if status:
            raise InstrumentFault(self.name, f"status {status}: {self.STATUS.get(status, 'unknown')}")
        r = self.RANGE_ARCSEC
        return (_within(self.name, "X angle ″", float(m.group(2)), -r, r),
                _within(self.name, "Y angle ″", float(m.group(3)), -r, r))

    def close(self) -> None:
        self.line.close()


class SylvacIndicator(DialIndicator):
    REQUEST = b"?\r"
    REPLY = re.compile(rf"({NUMBER})|ERR(\d+)")
    ERRORS = {1: "out of range", 2: "sensor not ready", 3: "command unknown"}
    RANGE_MM = 100.0  # the longest Sylvac stroke

    def __init__(self, address: Address, name: str = "dial_indicator", timeout_s: float = 1.0):
        self.name = name
        self.line = SerialLine(name, address.path, int(address.option("baud", 4800)), timeout_s)

    def read_um(self) -> float:
        m = _match(self.name, self.REPLY, self.line.query(self.REQUEST))
        if m.group(2):
            raise InstrumentFault(self.name, f"ERR{m.group(2)}: {self.ERRORS.get(int(m.group(2)), 'unknown')}")
        return _within(self.name, "displacement mm", float(m.group(1)), -self.RANGE_MM, self.RANGE_MM) * 1000.0

    def close(self) -> None:
        self.line.close()


class QsbEncoder(Encoder):
    """A quadrature counter: degrees = count × 360 / counts_per_rev (from the address)."""

    name = "encoder"
    REQUEST = b"R0E\r"
    REPLY = re.compile(r"0E([0-9A-Fa-f]{8})")

    def __init__(self, address: Address, timeout_s: float = 1.0):
        self.counts_per_rev = address.option("counts_per_rev", 2**30)
        self.line = SerialLine(self.name, address.path, int(address.option("baud", 230400)), timeout_s, terminator=b"\r\n")

    def read_angle_deg(self) -> float:
        m = _match(self.name, self.REPLY, self.line.query(self.REQUEST))
        count = int(m.group(1), 16)
        if count & 0x80000000:
            count -= 1 << 32
        return count * 360.0 / self.counts_per_rev

    def close(self) -> None:
        self.line.close()


class LineLaserTracer(LaserTracer):
    name = "laser_tracer"
    REF_REPLY = re.compile(r"OK REF (\d{1,9})")
    LEN_REPLY = re.compile(rf"LEN ({NUMBER}) (\d{{1,9}})|ERR (\w+)")
    RANGE_MM = 100_000.0  # a tracer follows a reflector within some 20 m; a length change beyond 100 m is garbage

    def __init__(self, address: Address, timeout_s: float = 1.0):
        self.line = SerialLine(self.name, address.path, int(address.option("baud", 115200)), timeout_s, terminator=b"\r\n")

    def reference(self) -> int:
        return int(_match(self.name, self.REF_REPLY, self.line.query(b"REF\r\n")).group(1))

    def read_length(self) -> LengthReading:
        m = _match(self.name, self.LEN_REPLY, self.line.query(b"LEN?\r\n"))
        if m.group(3) == "LOST":
            raise TrackingLost(self.name, "tracer error LOST: tracking lost")
        if m.group(3):
            raise InstrumentFault(self.name, f"tracer error {m.group(3)}")
        length_mm = _within(self.name, "length mm", float(m.group(1)) * 1e-6, -self.RANGE_MM, self.RANGE_MM)
        return LengthReading(length_mm, int(m.group(2)))

    def close(self) -> None:
        self.line.close()


class LineEnvironmentSensor(EnvironmentSensor):
    """Air temperature, pressure, humidity and the table's temperature, checked physically plausible."""

    name = "environment"
    REPLY = re.compile(rf"T=({NUMBER}) P=({NUMBER}) RH=({NUMBER}) TM=({NUMBER})")
    RANGES = ((-40.0, 80.0, "air temperature °C"), (50000.0, 150000.0, "pressure Pa"), (0.0, 100.0, "humidity %"),
              (-40.0, 150.0, "material temperature °C"))

    def __init__(self, address: Address, timeout_s: float = 1.0):
        self.line = SerialLine(self.name, address.path, int(address.option("baud", 9600)), timeout_s, terminator=b"\r\n")

    def read(self) -> EnvironmentReading:
        m = _match(self.name, self.REPLY, self.line.query(b"MEAS?\r\n"))
        values = [float(v) for v in m.groups()]
        for v, (lo, hi, what) in zip(values, self.RANGES):
            if not lo <= v <= hi:
                raise InstrumentFault(self.name, f"{what} {v:g} outside [{lo:g}, {hi:g}]")
        return EnvironmentReading(*values)

    def close(self) -> None:
        self.line.close()
