"""Serial instruments, one class per product (docs/protocols/serial.md gives each fact's public source).

- autocollimator, Möller-Wedel ELCOMAT (``elcomat``): ``a\\r\\n`` → ``4 003 <x> <y>\\r`` (arcsec)
- dial indicator, Sylvac (``sylvac``): ``?\\r`` → the displacement in mm, one line; 4800 7E2
- encoder counter, US Digital QSB (``qsb``): ``R0E\\r\\n`` → ``r0E<8 hex>[<8 hex timestamp>][!]\\r\\n``;
  end of response, mode and counter mode written at open, version read as identity
- laser tracer, rtcal's adapter protocol (``rtcal-line``): ``REF`` → ``OK REF <segment>``;
  ``LEN?`` → ``LEN <nm> <segment>`` or ``ERR LOST`` (no public protocol exists: a vendor-SDK bridge speaks it)

The Vaisala environment sensors are in :mod:`drivers.vaisala`.
"""

from __future__ import annotations

import re

from drivers.addresses import Address
from drivers.errors import InstrumentFault, TrackingLost
from drivers.interfaces import Autocollimator, DialIndicator, Encoder, LaserTracer, LengthReading
from drivers.models import BUILTIN, Framing
from drivers.serial_line import SerialLine

NUMBER = r"[+-]?\d+(?:\.\d+)?"


def match_reply(name: str, pattern: re.Pattern, reply: str) -> re.Match:
    m = pattern.fullmatch(reply)
    if m is None:
        raise InstrumentFault(name, f"unexpected reply {reply[:80]!r}")
    return m


def within(name: str, what: str, value: float, low: float, high: float) -> float:
    if not low <= value <= high:  # also false for NaN
        raise InstrumentFault(name, f"{what} {value:.6g} outside what it can measure [{low:g}, {high:g}]")
    return value


class SerialInstrument:
    """A product on one serial line: the model's framing, overridable by the address."""

    model: str = ""
    kind: str = ""
    schemes = ("serial",)
    options: dict = {}
    framing: Framing = Framing()
    terminator = b"\r"  # of replies
    line: SerialLine

    def open_line(self, name: str, address: Address, timeout_s: float) -> None:
        self.line = SerialLine(name, address, self.framing, timeout_s, self.terminator)

    def close(self) -> None:
        self.line.close()


class ElcomatAutocollimator(SerialInstrument, Autocollimator):
    """An absolute measurement: the reply's first two fields must be ``4 003`` (the only pair a
    public driver accepts for it); any other pair is no valid reading."""

    name = "autocollimator"
    model, kind, framing = "elcomat", "autocollimator", BUILTIN["elcomat"].framing
    REQUEST = b"a\r\n"
    REPLY = re.compile(rf"(\d+) (\d+) ({NUMBER}) ({NUMBER})")
    RANGE_ARCSEC = 3600.0  # an ELCOMAT's field is some ±1000″; beyond a degree is no autocollimator reading

    def __init__(self, address: Address, timeout_s: float = 1.0, **_: object):
        self.open_line(self.name, address, timeout_s)

    def read_arcsec(self) -> tuple[float, float]:
        m = match_reply(self.name, self.REPLY, self.line.query(self.REQUEST).strip())
        if (m.group(1), m.group(2)) != ("4", "003"):
            raise InstrumentFault(self.name, f"no valid absolute measurement (codes {m.group(1)} {m.group(2)}; "
                                             "no reflection in range?)")
        r = self.RANGE_ARCSEC
        return (within(self.name, "X angle ″", float(m.group(3)), -r, r),
                within(self.name, "Y angle ″", float(m.group(4)), -r, r))


class SylvacIndicator(SerialInstrument, DialIndicator):
    """The reading in the display unit: mm, or inches when the reply says ``in``. The digit layout
    is not published: any signed decimal, spaces between sign and digits allowed."""

    model, kind, framing = "sylvac", "dial_indicator", BUILTIN["sylvac"].framing
    REQUEST = b"?\r"
    REPLY = re.compile(r"\s*([+-]?)\s*(\d+(?:\.\d*)?|\.\d+)\s*(mm|in|inch)?\s*", re.IGNORECASE)
    RANGE_MM = 100.0  # the longest Sylvac stroke

    def __init__(self, address: Address, timeout_s: float = 1.0, name: str = "dial_indicator", **_: object):
        self.name = name
        self.open_line(name, address, timeout_s)

    def read_um(self) -> float:
        reply = self.line.query(self.REQUEST)
        if not reply.strip():
            raise InstrumentFault(self.name, "empty reply: the indicator is initialising (or asleep)")
        m = match_reply(self.name, self.REPLY, reply)
        value = float(m.group(1) + m.group(2)) * (25.4 if (m.group(3) or "").lower().startswith("in") else 1.0)
        return within(self.name, "displacement mm", value, -self.RANGE_MM, self.RANGE_MM) * 1000.0


class QsbEncoder(SerialInstrument, Encoder):
    """A quadrature counter: degrees = count × 360 / counts_per_rev (from the address).

    At open: end of response CR LF without timestamp or spaces (EOR 0x15 ← 3), quadrature mode
    (MODE 0x00 ← 0), counter ×4 free-running (MDR0 0x03 ← 3), then the version register (0x14)
    as identity. A reply is the lower-case response letter, the register, 8 hex digits, an
    optional 8-hex timestamp and an optional ``!``; the count is 32-bit two's complement."""

    name = "encoder"
    model, kind, framing = "qsb", "encoder", BUILTIN["qsb"].framing
    terminator = b"\n"
    REPLY = re.compile(r"([rwse]) ?([0-9A-F]{2}) ?([0-9A-F]{8})(?: ?([0-9A-F]{8}))? ?(!)?", re.IGNORECASE)
    SETUP = ((0x15, 0x03), (0x00, 0x00), (0x03, 0x03))

    def __init__(self, address: Address, timeout_s: float = 1.0, **_: object):
        self.counts_per_rev = address.option("counts_per_rev", 2**30)
        self.open_line(self.name, address, timeout_s)
        try:
            for register, value in self.SETUP:
                self._exchange(f"W{register:02X}{value:02X}", "w", register)
            self._version = self._exchange("R14", "r", 0x14)
        except BaseException:
            self.line.close()
            raise

    def _exchange(self, command: str, letter: str, register: int) -> int:
        reply = self.line.query(command.encode("ascii") + b"\r\n")
        m = match_reply(self.name, self.REPLY, reply.strip())
        if m.group(1).lower() == "e":
            raise InstrumentFault(self.name, f"{command}: the counter answered with an error {reply[:40]!r}")
        if m.group(1).lower() != letter or int(m.group(2), 16) != register:
            raise InstrumentFault(self.name, f"{command}: reply {reply[:40]!r} is not for register {register:02X}")
        return int(m.group(3), 16)

    def identity(self) -> str:
        return f"US Digital QSB, VERSION register 0x{self._version:08X}"

    def read_angle_deg(self) -> float:
        count = self._exchange("R0E", "r", 0x0E)
        if count & 0x80000000:
            count -= 1 << 32
        return count * 360.0 / self.counts_per_rev


class LineLaserTracer(SerialInstrument, LaserTracer):
    name = "laser_tracer"
    model, kind, framing = "rtcal-line", "laser_tracer", BUILTIN["rtcal-line"].framing
    REF_REPLY = re.compile(r"OK REF (\d{1,9})")
    LEN_REPLY = re.compile(rf"LEN ({NUMBER}) (\d{{1,9}})|ERR (\w+)")
    RANGE_MM = 100_000.0  # a tracer follows a reflector within some 20 m; a length change beyond 100 m is garbage

    def __init__(self, address: Address, timeout_s: float = 1.0, **_: object):
        self.terminator = b"\r\n"
        self.open_line(self.name, address, timeout_s)

    def reference(self) -> int:
        return int(match_reply(self.name, self.REF_REPLY, self.line.query(b"REF\r\n")).group(1))

    def read_length(self) -> LengthReading:
        m = match_reply(self.name, self.LEN_REPLY, self.line.query(b"LEN?\r\n"))
        if m.group(3) == "LOST":
            raise TrackingLost(self.name, "tracer error LOST: tracking lost")
        if m.group(3):
            raise InstrumentFault(self.name, f"tracer error {m.group(3)}")
        length_mm = within(self.name, "length mm", float(m.group(1)) * 1e-6, -self.RANGE_MM, self.RANGE_MM)
        return LengthReading(length_mm, int(m.group(2)))
