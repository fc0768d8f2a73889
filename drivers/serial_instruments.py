"""Serial instruments, one class per product (docs/protocols/serial.md gives each fact's public source).

- autocollimator, Möller-Wedel ELCOMAT (``elcomat``): ``a\\r\\n`` → ``4 003 <x> <y>\\r`` (arcsec)
- dial indicator, Sylvac (``sylvac``): ``MM\\r`` and ``UNI?\\r`` at open (the reply carries no unit),
  then ``?\\r`` → the displacement, one line; ``ERRn`` the instrument's error; echo tolerated; 4800 7E2
- encoder counter, US Digital QSB (``qsb``): ``R0E\\r\\n`` → ``r0E<8 hex>[<8 hex timestamp>][!]\\r\\n``;
  end of response, mode and counter mode written at open, version read as identity
- laser tracer, rtcal's adapter protocol (``rtcal-line``): ``REF`` → ``OK REF <segment>``;
  ``LEN?`` → ``LEN <nm> <segment>`` or ``ERR LOST`` (no public protocol exists: a vendor-SDK bridge speaks it);
  ``ID?`` → ``ID <text>`` at open (optional: ``ERR CMD``), the identity
- dial indicator: ``ID?`` at open (OPTO-RS: ``SY<instrument>.<option>…``), the identity where it answers

The Vaisala environment sensors are in :mod:`drivers.vaisala`.
"""

from __future__ import annotations

import re
import time

from drivers.addresses import Address
from drivers.errors import InstrumentError, InstrumentFault, TrackingLost
from drivers.interfaces import Autocollimator, DialIndicator, Encoder, LaserTracer, LengthReading
from drivers.models import Framing, builtin_framing
from drivers.serial_line import SerialLine

NUMBER = r"[+-]?\d+(?:\.\d+)?"
QSB_SIMULATED_VERSION = 0x5111A7ED
"""The VERSION register rtcal's QSB simulator answers: the QSB's identity is 8 hex digits, so the simulator is
told by this value (no QSB firmware of US Digital's is known to report it) and the driver names it SIMULATED."""


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
    options: dict[str, tuple[float, float, bool]] = {}
    framing: Framing = Framing()
    terminator = b"\r"  # of replies
    line: SerialLine

    def open_line(self, name: str, address: Address, timeout_s: float) -> None:
        self.line = SerialLine(name, address, self.framing, timeout_s, self.terminator)

    def close(self) -> None:
        self.line.close()


class ElcomatAutocollimator(SerialInstrument, Autocollimator):
    """An absolute measurement ``a`` → ``4 <status> <x> <y>``: the status's last digit says which axes
    are valid (dls-controls/elcomat3000: 1 X, 2 Y, 3 both, 0 none). ``read_arcsec`` needs X, the
    angle about the table axis every run measures: X invalid is a fault, Y invalid is NaN.
    ``d`` → ``8 <serial> <day> <month> <year> <focal length>`` is the identity."""

    name = "autocollimator"
    model, kind, framing = "elcomat", "autocollimator", builtin_framing("elcomat")
    REQUEST = b"a\r\n"
    REPLY = re.compile(rf"(\d+) (\d+) ({NUMBER}) ({NUMBER})")
    IDENTITY = re.compile(r"8 (\S+) (\d+) (\d+) (\d+) (\d+(?:\.\d+)?)")
    VALID = {"0": (False, False), "1": (True, False), "2": (False, True), "3": (True, True)}
    RANGE_ARCSEC = 3600.0  # an ELCOMAT's field is some ±1000″; beyond a degree is no autocollimator reading

    def __init__(self, address: Address, timeout_s: float = 1.0, **_: object):
        self.open_line(self.name, address, timeout_s)
        self._identity = ""
        try:
            m = self.IDENTITY.fullmatch(self.line.query(b"d\r\n").strip())
        except InstrumentError:
            m = None  # a unit that does not answer d still measures: no identity
        if m is not None:
            self._identity = (f"Möller-Wedel ELCOMAT, serial number {m.group(1)}, focal length {m.group(5)} mm, "
                              f"date {m.group(2)}.{m.group(3)}.{m.group(4)}")

    def identity(self) -> str:
        return self._identity

    def read_axes_arcsec(self) -> tuple[float, float]:
        m = match_reply(self.name, self.REPLY, self.line.query(self.REQUEST).strip())
        status = m.group(2)
        valid = self.VALID.get(status[-1:]) if m.group(1) == "4" else None
        if valid is None or not any(valid):
            raise InstrumentFault(self.name, f"no valid absolute measurement (codes {m.group(1)} {status}; "
                                             "no reflection in range?)")
        r = self.RANGE_ARCSEC
        x = within(self.name, "X angle ″", float(m.group(3)), -r, r) if valid[0] else float("nan")
        y = within(self.name, "Y angle ″", float(m.group(4)), -r, r) if valid[1] else float("nan")
        return x, y

    def read_arcsec(self) -> tuple[float, float]:
        x, y = self.read_axes_arcsec()
        if x != x:
            raise InstrumentFault(self.name, "X axis not valid (status: Y only): no reading about the table axis")
        return x, y


class SylvacIndicator(SerialInstrument, DialIndicator):
    """A Sylvac indicator on its Opto-RS cable. The reply ``[sign or space][digits].[decimals]CR``
    carries no unit (OPTO-RS manual): at open the driver sends ``MM`` and asks ``UNI?``, and refuses
    an indicator that does not confirm mm — an inch display would read 25.4 times too small. A unit
    that echoes commands (UniCal manual) is tolerated: a line that repeats the request is skipped.
    ``ERRn`` is the instrument's own error."""

    model, kind, framing = "sylvac", "dial_indicator", builtin_framing("sylvac")
    REQUEST = b"?\r"
    REPLY = re.compile(r"\s*([+-]?)\s*(\d+(?:\.\d*)?|\.\d+)\s*(mm)?\s*", re.IGNORECASE)
    ERROR = re.compile(r"\s*ERR\s*(\d)\s*", re.IGNORECASE)
    # "User's manual for OPTO-RS cable connections" p. 12: "0: sensor error (e.g. speed, scale distance) 1: incorrect
    # command 2: parity error (duplex instruments only) 3: exceeded measurement range"
    ERRORS = {"0": "sensor error", "1": "incorrect command: the indicator did not understand the request",
              "2": "parity error: check the line's framing, 4800 baud 7E2", "3": "measuring range exceeded"}
    RANGE_MM = 100.0  # the longest Sylvac stroke
    QUIET_S = 0.15  # after MM: whatever the indicator sends back (an echo) arrives within this
    AFTER_MM_MAX_BYTES, AFTER_MM_MAX_S = 256, 1.0  # more, or longer, is an indicator sending on its own, not an echo

    def __init__(self, address: Address, timeout_s: float = 1.0, name: str = "dial_indicator", **_: object):
        self.name = name
        self.open_line(name, address, timeout_s)
        try:
            self._set_mm(timeout_s)
            self._identity = self._ask_id()
        except BaseException:
            self.line.close()
            raise

    def _set_mm(self, timeout_s: float) -> None:
        """``MM``, then ``UNI?`` must answer mm (the reply to a reading has no unit to check later)."""
        self.line.write(b"MM\r")
        port = self.line.port
        start = time.monotonic()
        received = 0
        try:
            port.timeout = self.QUIET_S
            while chunk := port.read_until(b"\r", 64):  # an echo of MM, or an acknowledgement: not needed
                received += len(chunk)
                if received > self.AFTER_MM_MAX_BYTES or time.monotonic() - start > self.AFTER_MM_MAX_S:
                    raise InstrumentFault(self.name, f"the indicator keeps sending after MM ({received} bytes in "
                                                     f"{time.monotonic() - start:.1f} s; an echo of MM is 3): it "
                                                     "transmits on its own — switch its continuous output off at the "
                                                     "instrument (rtcal asks for each reading with ?)")
        finally:
            port.timeout = timeout_s
        unit = self._reply(b"UNI?\r").strip().upper()
        if "MM" in unit:
            return
        said = f"UNI? answered {unit[:20]!r}"
        if "IN" in unit:
            raise InstrumentFault(self.name, f"the indicator stays in inches after MM ({said}): set its unit to mm "
                                             "at the instrument; readings would be 25.4 times too small")
        raise InstrumentFault(self.name, f"the indicator did not confirm its unit is mm ({said}); its replies carry "
                                         "no unit, so rtcal does not read it")

    IDENTIFICATION = re.compile(r"SY[0-9A-Z]{1,10}(?:\.[0-9A-Za-z]{1,20}){0,4}")

    def _ask_id(self) -> str:
        """``ID?`` (a duplex instrument's identification, OPTO-RS manual: ``SY<instrument>.<option>…``); an
        instrument that does not know it (``ERR1``) or answers otherwise has no identity."""
        try:
            reply = self._reply(b"ID?\r").strip()
        except InstrumentError:
            return ""
        return f"Sylvac {reply}" if self.IDENTIFICATION.fullmatch(reply) else ""

    def identity(self) -> str:
        return self._identity

    def _reply(self, request: bytes) -> str:
        """The reply line, past an echo of the request; ``ERRn`` raised with its meaning."""
        line = self.line.query(request)
        if line.strip() == request.decode("ascii").strip():
            line = self.line.read_line(request)
        m = self.ERROR.fullmatch(line)
        if m is not None:
            meaning = self.ERRORS.get(m.group(1), "see the instrument's manual")
            raise InstrumentFault(self.name, f"indicator error ERR{m.group(1)} ({meaning}) in reply to {request.strip()!r}")
        return line

    def read_um(self) -> float:
        reply = self._reply(self.REQUEST)
        if not reply.strip():
            raise InstrumentFault(self.name, "empty reply: the indicator is initialising (or asleep)")
        m = match_reply(self.name, self.REPLY, reply)
        value = float(m.group(1) + m.group(2))
        return within(self.name, "displacement mm", value, -self.RANGE_MM, self.RANGE_MM) * 1000.0


class QsbEncoder(SerialInstrument, Encoder):
    """A quadrature counter: degrees = count × 360 / counts_per_rev (from the address).

    At open: end of response CR LF without timestamp or spaces (EOR 0x15 ← 3), quadrature mode
    (MODE 0x00 ← 0), counter ×4 free-running (MDR0 0x03 ← 3), then the version register (0x14)
    as identity. A reply is the lower-case response letter, the register, 8 hex digits, an
    optional 8-hex timestamp and an optional ``!``; the count is 32-bit two's complement."""

    name = "encoder"
    model, kind, framing = "qsb", "encoder", builtin_framing("qsb")
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
        simulated = " (rtcal's simulator: SIMULATED)" if self._version == QSB_SIMULATED_VERSION else ""
        return f"US Digital QSB, VERSION register 0x{self._version:08X}{simulated}"

    def read_angle_deg(self) -> float:
        count = self._exchange("R0E", "r", 0x0E)
        if count & 0x80000000:
            count -= 1 << 32
        return count * 360.0 / self.counts_per_rev


class LineLaserTracer(SerialInstrument, LaserTracer):
    name = "laser_tracer"
    model, kind, framing = "rtcal-line", "laser_tracer", builtin_framing("rtcal-line")
    REF_REPLY = re.compile(r"OK REF (\d{1,9})")
    LEN_REPLY = re.compile(rf"LEN ({NUMBER}) (\d{{1,9}})|ERR (\w+)")
    RANGE_MM = 100_000.0  # a tracer follows a reflector within some 20 m; a length change beyond 100 m is garbage

    ID_REPLY = re.compile(r"ID (.{1,200})")

    def __init__(self, address: Address, timeout_s: float = 1.0, **_: object):
        self.terminator = b"\r\n"
        self.open_line(self.name, address, timeout_s)
        self._identity = ""
        try:  # optional in the protocol: a bridge that does not know it answers ERR CMD
            m = self.ID_REPLY.fullmatch(self.line.query(b"ID?\r\n").strip())
        except InstrumentError:
            m = None
        if m is not None:
            self._identity = m.group(1)

    def identity(self) -> str:
        return self._identity

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
