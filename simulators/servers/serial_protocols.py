"""Instrument ends of the serial protocols, as the named products answer (docs/protocols/), backed
by the simulated instruments.

Each handler turns one request line into one reply (bytes in, bytes out, terminators included)
and knows nothing of pseudo-terminals or sockets: :mod:`simulators.servers.hub` carries bytes.
"""

from __future__ import annotations

import re
from typing import Protocol

from drivers.errors import InstrumentFault, OutOfLimits, TrackingLost
from drivers.serial_instruments import QSB_SIMULATED_VERSION
from drivers.interfaces import EnvironmentReading
from simulators.scenario import STATE_KINDS
from simulators.instruments import (
    SimAutocollimator,
    SimDialIndicator,
    SimEncoder,
    SimEnvironmentSensor,
    SimLaserTracer,
    SimStage,
    _Injecting,
)


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
        self.terminator, self.reply_terminator = handler.terminator, handler.reply_terminator

    def counted(self, request: bytes) -> bool:
        return self.handler.counted(request)

    def handle(self, request: bytes) -> bytes:
        fault = self.bench.faults.draw(self.name) if self.handler.counted(request) else None
        if fault is None:
            return self.handler.handle(request)
        if fault.kind in STATE_KINDS:  # inside the instrument, and it stays: stale, frozen, creep, inch
            instrument = getattr(self.handler, "instrument", None)
            if not isinstance(instrument, _Injecting):  # the scenario allows them only where an instrument holds them
                raise ValueError(f"{self.name}: no instrument behind the line to hold a {fault.kind} fault")
            instrument.afflict(fault)
            return self.handler.handle(request)
        if fault.kind == "beam_break":
            self.bench.beam_broken = True
            return self.handler.handle(request)
        if fault.kind == "no_reply":
            return b""
        if fault.kind == "garbled":
            return b"\x15#?%!~" + self.handler.reply_terminator
        return b"4 003 +1"  # truncated: no terminator follows


class ElcomatHandler:
    """Möller-Wedel ELCOMAT: ``a`` → ``4 003 <x> <y>\\r`` (absolute), ``r`` → ``2 103 <x> <y>\\r``
    (relative; the simulated unit's zero is its absolute zero), arcsec; the status's last digit
    says which axes are valid (dls-controls/elcomat3000: 3 both, 1 X, 2 Y, 0 none — no face in
    range). ``d`` → ``8 <serial> <day> <month> <year> <focal length>``, serial ``SIMULATED``. ``valid_axes`` "x" or "y"
    makes a unit that validates only that axis."""

    reply_terminator = b"\r"
    terminator = b"\n"

    def __init__(self, instrument: SimAutocollimator, valid_axes: str = "xy"):
        self.instrument = instrument
        self.valid_digit = {"xy": b"3", "x": b"1", "y": b"2"}[valid_axes]

    def counted(self, request: bytes) -> bool:
        return request.strip() in (b"a", b"r")

    def handle(self, request: bytes) -> bytes:
        command = request.strip()
        if command == b"d":
            return b"8 SIMULATED 15 01 2026 300\r"  # the serial field says it: a run on it is marked simulated
        if command not in (b"a", b"r"):
            return b""  # what a unit answers to other commands is not published: nothing
        mode, valid = (b"4", b"00" + self.valid_digit) if command == b"a" else (b"2", b"10" + self.valid_digit)
        try:
            x, y = self.instrument.read_arcsec()
        except InstrumentFault:
            return mode + b" " + valid[:1] + b"00 0.0000 0.0000\r"
        return mode + b" " + valid + f" {x:.4f} {y:.4f}\r".encode()


class SylvacHandler:
    """Sylvac indicator on its Opto-RS cable (OPTO-RS manual): ``?`` (or ``PRI?``) → the displacement
    in the display unit, ``[sign or space][digits].[decimals]`` and CR, no unit; ``MM`` / ``IN`` set
    the unit, ``UNI?`` answers it; ``BAT?`` → ``BAT1``; ``ID?`` → ``SY289.1.SIMULATED`` (the identification's
    options field says what it is). ``echo=True`` sends the command back first
    (the UniCal manual: "the instrument echoes the command"); ``inch=True`` starts with an inch
    display; ``accepts_mm=False`` is a unit that stays in inches. Another command: ``ERR1``."""

    reply_terminator = b"\r"
    terminator = b"\r"
    IDENTITY = b"SY289.1.SIMULATED"

    def __init__(self, instrument: SimDialIndicator, echo: bool = False, inch: bool = False, accepts_mm: bool = True):
        self.instrument = instrument
        self.echo, self.inch, self.accepts_mm = echo, inch, accepts_mm

    def counted(self, request: bytes) -> bool:
        return request.strip() in (b"?", b"PRI?")

    def handle(self, request: bytes) -> bytes:
        command = request.strip()
        return (command + b"\r" if self.echo else b"") + self._answer(command)

    def _answer(self, command: bytes) -> bytes:
        if command == b"BAT?":
            return b"BAT1\r"
        if command == b"ID?":  # OPTO-RS: "SY" instrument "." option {"." options}; the options say it
            return self.IDENTITY + b"\r"
        if command in (b"MM", b"IN"):
            self.inch = command == b"IN" or not self.accepts_mm
            return b""
        if command == b"UNI?":
            fault = self.instrument.state_fault
            return b"IN\r" if self.inch or (fault is not None and fault.kind == "inch") else b"MM\r"
        if command not in (b"?", b"PRI?"):
            return b"ERR1\r"
        number = self.instrument.read_um() / 1000.0  # the display's number: inches when it is stuck in inches (fault `inch`)
        fault = self.instrument.state_fault
        stuck_in_inches = fault is not None and fault.kind == "inch"
        text = f"{number:.5f}" if stuck_in_inches else f"{number / 25.4:.5f}" if self.inch else f"{number:.4f}"
        return (text if text.startswith("-") else " " + text).encode() + b"\r"


class QsbHandler:
    """US Digital QSB: ``R<reg>``, ``W<reg><hex>``; reply ``r|w<reg><8 hex>[timestamp]!`` + the end of
    response that register 0x15 (EOR) chooses: bit 0 LF, bit 1 CR, bit 2 timestamp, bit 3 spaces. The
    VERSION register (0x14) holds rtcal's simulator value (its only identity is 8 hex digits)."""

    reply_terminator = b"\r\n"
    terminator = b"\r"  # requests end in CR, LF or CR LF: a lone LF left over is an empty line
    COMMAND = re.compile(rb"([RWS])([0-9A-F]{2})([0-9A-F]{0,8})")
    COUNT, VERSION, EOR = 0x0E, 0x14, 0x15

    def __init__(self, instrument: SimEncoder, counts_per_rev: int):
        self.instrument = instrument
        self.counts_per_rev = counts_per_rev
        self.registers = {0x00: 0, 0x03: 0, 0x04: 0, 0x08: 0, 0x0B: 0, 0x0C: 0, self.VERSION: QSB_SIMULATED_VERSION,
                          self.EOR: 0x03, 0x16: 0}

    def counted(self, request: bytes) -> bool:
        return request.strip().upper() == b"R0E"

    def _reply(self, letter: str, register: int, value: int) -> bytes:
        eor = self.registers[self.EOR]
        sep = " " if eor & 0x08 else ""
        text = f"{letter}{sep}{register:02X}{sep}{value & 0xFFFFFFFF:08X}"
        if eor & 0x04:
            text += f"{sep}{round(self.instrument.bench.clock.now_s() * 1000) & 0xFFFFFFFF:08X}"
        return (text + f"{sep}!" + ("\r" if eor & 0x02 else "") + ("\n" if eor & 0x01 else "")).encode()

    def handle(self, request: bytes) -> bytes:
        m = self.COMMAND.fullmatch(request.strip().upper())
        if m is None or (m.group(1) == b"R" and m.group(3)) or (m.group(1) == b"W" and not m.group(3)):
            return b"e00000000!\r\n"
        register = int(m.group(2), 16)
        if m.group(1) == b"W":
            if register not in self.registers or register in (self.COUNT, self.VERSION):
                return b"e00000000!\r\n"
            self.registers[register] = int(m.group(3), 16)
            return self._reply("w", register, self.registers[register])
        if register == self.COUNT:
            count = round(self.instrument.read_angle_deg() / 360.0 * self.counts_per_rev)
            return self._reply("r" if m.group(1) == b"R" else "s", register, count)
        if register not in self.registers:
            return b"e00000000!\r\n"
        return self._reply("r", register, self.registers[register])


class TracerHandler:
    reply_terminator = b"\r\n"
    terminator = b"\n"

    def __init__(self, instrument: SimLaserTracer):
        self.instrument = instrument

    def counted(self, request: bytes) -> bool:
        return request.strip() == b"LEN?"

    def handle(self, request: bytes) -> bytes:
        command = request.strip()
        if command == b"ID?":  # rtcal's own protocol: the bridge names what it is
            return b"ID rtcal-line laser tracer SIMULATED\r\n"
        if command == b"REF":
            return f"OK REF {self.instrument.reference()}\r\n".encode()
        if command == b"LEN?":
            try:
                r = self.instrument.read_length()
            except TrackingLost:
                return b"ERR LOST\r\n"
            return f"LEN {r.length_mm * 1e6:.3f} {r.segment}\r\n".encode()
        return b"ERR CMD\r\n"


class EnvironmentNow:
    """One moment's conditions, shared by the sensors of one bench: the barometer's SEND takes a
    reading, the thermometer answers from that same moment (a first question takes one)."""

    def __init__(self, instrument: SimEnvironmentSensor):
        self.instrument = instrument
        self.reading: EnvironmentReading | None = None

    def fresh(self) -> EnvironmentReading:
        self.reading = self.instrument.read()
        return self.reading

    def latest(self) -> EnvironmentReading:
        return self.reading or self.fresh()


FORM_TOKEN = re.compile(r'\s*(?:"([^"]*)"|(\d+)\.(\d+)\s+([A-Za-z][A-Za-z0-9]*)|U(\d*)|#([rnt])|(\S+))')


class VaisalaHandler:
    """Vaisala PTU300 or PTB330: ``?`` (the full listing), ``FORM <format>``, ``FORM ?``, ``SEND``,
    ``ERRS``, ``ECHO ON|OFF``, ``S`` (stop), ``R`` (run). ``SEND`` prints the quantities as the FORM
    says: ``"text"``, ``x.y Q`` (x digits, y decimals of P in hPa, T in 'C, RH in %RH), ``Un`` the
    unit of the quantity before, ``#r #n #t``. ECHO is ON as from the factory (PTB330 manual): the
    command comes back first, and a ``>`` prompt follows every answer; ``ECHO OFF`` ends both. In
    RUN mode (``run=True``) the unit sends a reading before answering anything but ``S`` — what a
    client sees that talks to a streaming unit (the hub has no clock of its own to stream with)."""

    reply_terminator = b"\r\n"
    terminator = b"\r"
    UNITS = {"P": "hPa", "T": "'C", "RH": "%RH"}
    DEFAULT_FORM = {"PTU300": '"P=" 6.1 P " " U3 "   T=" 4.1 T " " U2 " RH=" 4.1 RH " " U3 #r #n',
                    "PTB330": '"P=" 6.1 P " " U3 #r #n'}
    MODULES = {"PTU300": ("BARO-1", "EMPTY"), "PTB330": ("BARO-1", "EMPTY", "EMPTY", "EMPTY")}

    def __init__(self, now: EnvironmentNow, model: str = "PTU300", echo: bool = True, run: bool = False):
        self.now, self.model = now, model
        self.quantities = ("P", "T", "RH") if model == "PTU300" else ("P",)
        self.form = self.DEFAULT_FORM[model]
        self.echo, self.run = echo, run

    def counted(self, request: bytes) -> bool:
        return request.strip().upper() == b"SEND"

    def listing(self) -> str:
        """The ``?`` listing: model / version, then Key : value lines ending with the module lines
        (the layout of the PTB330 manual's p. 83 as the references describe it; msl-equipment reads
        to "Module 2" on a PTU300 and "Module 4" on a PTB330)."""
        lines = [f"{self.model} / 1.12", "Serial number  : SIMULATED", "Batch number   : SIM-BATCH",
                 "Adjust. date   : 2026-01-15", "Adjust. info   : VAISALA/HEL", "Date           : 2026-11-27",
                 "Time           : 12:00:00", f"Start mode     : {'RUN' if self.run else 'STOP'}",
                 f"Output format  : {self.form.replace('#', chr(92))}", "Pressure unit  : hPa",
                 f"Serial mode    : {'RUN' if self.run else 'STOP'}", "Baud P D S     : 4800 E 7 1",
                 "Output interval: 1 s", f"Echo           : {'ON' if self.echo else 'OFF'}", "Address        : 0"]
        lines += [f"Module {i + 1}       : {m}" for i, m in enumerate(self.MODULES[self.model])]
        return "".join(line + "\r\n" for line in lines)

    def _send_line(self) -> bytes:
        """SEND's reply: a fresh reading in the current FORM (one FORM accepted only if it formats)."""
        line = self._format(self.form, self.now.fresh())
        if line is None:
            raise ValueError(f"FORM {self.form!r} does not format a reading")
        return line.encode()

    def _format(self, form: str, reading: EnvironmentReading | None) -> str | None:
        """The SEND line for ``form``, or None if the format is not understood (checked with no reading)."""
        values = {} if reading is None else {"P": reading.air_pressure_pa / 100.0, "T": reading.air_temperature_c,
                                             "RH": reading.humidity_pct}
        out, last = [], None
        for m in FORM_TOKEN.finditer(form):
            text, digits, decimals, quantity, unit_width, special, other = m.groups()
            if other is not None or (quantity is not None and quantity.upper() not in self.quantities):
                return None
            if text is not None:
                out.append(text)
            elif quantity is not None:
                last = quantity.upper()
                width = int(digits) + 1 + int(decimals)
                out.append(f"{values.get(last, 0.0):{width}.{decimals}f}")
            elif special is not None:
                out.append({"r": "\r", "n": "\n", "t": "\t"}[special])
            elif last is not None:
                out.append(self.UNITS[last].ljust(int(unit_width or 0)))
        return "".join(out)

    def handle(self, request: bytes) -> bytes:
        echo = request.strip() + b"\r\n" if self.echo else b""
        streamed = b""
        if self.run and request.strip().upper() != b"S":
            streamed = self._send_line()
        reply = self._answer(request)
        return streamed + echo + reply + (b">" if self.echo else b"")

    def _answer(self, request: bytes) -> bytes:
        text = request.decode("ascii", errors="replace").strip()
        command = text.split(" ", 1)[0].upper()
        if command == "?":
            return self.listing().encode()
        if command == "SEND":
            return self._send_line()
        if command == "ERRS":
            return b"No errors\r\n"
        if command == "S":
            self.run = False
            return b""
        if command == "R":
            self.run = True
            return b""
        if command == "ECHO":
            setting = text[4:].strip().upper()
            if setting in ("ON", "OFF"):
                self.echo = setting == "ON"
            elif setting:
                return b"Unknown command\r\n"
            return f"Echo           : {'ON' if self.echo else 'OFF'}\r\n".encode()
        if command == "FORM":
            form = text[4:].strip()
            if form == "?":
                return f"Output format  :{self.form.replace('#', chr(92))}\r\n".encode()
            if self._format(form, None) is None:
                return b"FORM error\r\n"
            self.form = form
            return b"OK\r\n"
        return b"Unknown command\r\n"


class IthxHandler:
    """OMEGA iTHX: ``*SRTC`` / ``*SRTC2`` → probe 1 / 2 °C, ``*SRTF``… °F, ``*SRH`` / ``*SRH2`` → % RH;
    CR ends requests and replies; one decimal, as the iServer prints them. Probe 1 hangs in the
    beam's air, probe 2 touches the table (``on_mount``: a second iTHX, its probe 2 on the tracer's mount)."""

    reply_terminator = b"\r"
    terminator = b"\r"
    COMMAND = re.compile(r"\*SR(TC|TF|H)(2?)")

    def __init__(self, now: EnvironmentNow, on_mount: bool = False):
        self.now = now
        self.on_mount = on_mount

    def counted(self, request: bytes) -> bool:
        return False  # the barometer's SEND is the environment's one counted request

    def handle(self, request: bytes) -> bytes:
        m = self.COMMAND.fullmatch(request.decode("ascii", errors="replace").strip())
        if m is None:
            return b"Serial Time Out\r"  # what msl-equipment saw an iTHX-W answer to a command it lacks
        r = self.now.latest()
        probe_2 = r.mount_temperature_c if self.on_mount else r.material_temperature_c
        celsius = probe_2 if m.group(2) else r.air_temperature_c
        value = {"TC": celsius, "TF": celsius * 9.0 / 5.0 + 32.0, "H": r.humidity_pct}[m.group(1)]
        return f"{value:.1f}\r".encode()


class PiGcsHandler:
    """A PI controller with one rotation axis (``1``), GCS as pipython speaks it (docs/protocols/pi_gcs.md):
    ``*IDN?``, ``SVO``/``SVO?``, ``FRF``/``FRF?``, ``MOV``/``MOV?``, ``POS?``, ``ONT?``, ``ERR?``
    (answers the last error and clears it), ``STP``/``HLT`` (error 10). Requests and answers end in
    LF; a query answers ``1=<value>``; other commands answer nothing. A move needs the servo on and
    the axis referenced (else error 5) and a target inside the travel range (else 7); it is done
    in virtual time, but ``ONT?`` answers 0 once after each move, as a stage still settling would.
    ``VEL?`` answers the scenario's table speed. ``motion_error_moves``: the moves (counted from 1)
    that fail half-way as a real controller's do when the position error grows too large — the
    table stops there, the servo switches off, ``ERR?`` answers 1024 (PI's MS249E §8.7) and ``ONT?``
    stays 0."""

    reply_terminator = b"\n"
    terminator = b"\n"
    IDN = "(c)2026 Physik Instrumente (PI) GmbH & Co. KG, C-863.11, SIMULATED, 01.00.00"  # the serial field says it
    AXIS = "1"

    MOTION_ERROR = 1024

    def __init__(self, stage: SimStage, referenced: bool = False, motion_error_moves: tuple[int, ...] = ()):
        self.stage = stage
        self.motion_error_moves, self.moves = set(motion_error_moves), 0
        self.motion_error_pending = False
        self.servo = False
        self.referenced = referenced
        self.error = 0
        self.target_deg = stage.position_deg()
        self.settling = 0

    def counted(self, request: bytes) -> bool:
        return False  # the stage's faults are the drive model's; this line carries none

    def _fail(self, code: int) -> bytes:
        self.error = self.error or code  # the first error stays until ERR? reads it
        return b""

    def handle(self, request: bytes) -> bytes:
        words = request.decode("ascii", errors="replace").split()
        if not words:
            return b""
        command, args = words[0].upper(), words[1:]
        if command == "*IDN?":
            return (self.IDN + "\n").encode()
        if command == "ERR?":
            code, self.error = self.error, 0
            return f"{code}\n".encode()
        if command in ("STP", "HLT"):
            if command == "HLT" and args and args[0] != self.AXIS:
                return self._fail(15)
            self.settling = 0
            return self._fail(10)
        queries = {"SVO?": lambda: int(self.servo), "FRF?": lambda: int(self.referenced),
                   "POS?": lambda: f"{self.stage.position_deg():.9f}", "MOV?": lambda: f"{self.target_deg:.9f}",
                   "ONT?": self._on_target, "VEL?": lambda: f"{self.stage.bench.scenario.stage.speed_deg_per_s:.6f}"}
        if command in queries:
            if args and args != [self.AXIS]:
                return self._fail(15) or b""
            return f"{self.AXIS}={queries[command]()}\n".encode()
        if command in ("SVO", "MOV"):
            if len(args) != 2:
                return self._fail(1)
            if args[0] != self.AXIS:
                return self._fail(15)
            try:
                value = float(args[1])
            except ValueError:
                return self._fail(1)
            if command == "SVO":
                self.servo = value == 1
                return b""
            return self._move(value)
        if command == "FRF":
            if args and args != [self.AXIS]:
                return self._fail(15)
            if not self.servo:
                return self._fail(5)
            self._move(0.0, referencing=True)
            self.referenced = True
            return b""
        return self._fail(2)

    def _on_target(self) -> int:
        if self.settling < 0:  # stopped by a motion error: never on target
            if self.motion_error_pending:
                self.motion_error_pending = False
                self._fail(self.MOTION_ERROR)
            return 0
        if self.settling:
            self.settling -= 1
            return 0
        return 1

    def _move(self, target_deg: float, referencing: bool = False) -> bytes:
        if not self.servo or not (self.referenced or referencing):
            return self._fail(5)
        lo, hi = self.stage.limits_deg
        if not (lo <= target_deg <= hi and target_deg == target_deg):
            return self._fail(7)
        self.moves += 0 if referencing else 1
        failing = self.moves in self.motion_error_moves and not referencing
        try:
            self.stage.move_to((self.stage.position_deg() + target_deg) / 2.0 if failing else target_deg)
        except OutOfLimits:
            return self._fail(7)
        except InstrumentFault:
            return self._fail(5)
        self.target_deg = target_deg
        if failing:  # found by the controller while the move runs: after the ERR? that follows MOV
            self.servo, self.settling, self.motion_error_pending = False, -1, True
            return b""
        self.settling = 1
        return b""
