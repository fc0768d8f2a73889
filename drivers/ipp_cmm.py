"""A CMM over I++ DME (TCP, default port 1294).

A session starts with ``StartSession()``, asks ``GetDMEVersion()`` (the identity), selects the
machine coordinate system with ``SetCoordSystem(MachineCsy)`` (a session re-activates the
previous session's system, §6.3.1.1: a part system left by another program would shift every
position), asks ``IsHomed()`` and, if the machine is not homed, sends ``Home()`` only when the
procedure allows it (``home: true`` in its CMM section, or ``home=1`` in the address) — else it
refuses, naming homing; a probe never homes. When the procedure names a tool it sends
``ChangeTool("name")``.

An error of severity 2 or more leaves the server in its error state (every command answered
0514): the driver raises the error, and clears the state with ``ClearAllErrors()`` before its
next command — the retry of the fault policy, or ``recover()`` — so one refused move does not
fail every retry. A warning (severity 0 or 1) is logged and the reply read on to ``%``. An
``E0000`` error event (the server's emergency stop, §6.2.4.1) latches: every later command
raises :class:`EmergencyStop` without being sent, and nothing clears it automatically.
``stop()`` sends the event command ``AbortE()`` (§6.3.1.5).

Every command has a deadline (the timeout; ten times it for a motion) however the server
dribbles its bytes, a reply line is at most 64 KiB, and coordinates must be finite and within
a kilometre. A connection left unusable (closed by the server, an overlong line) is opened
again, with a new session, by the next command.
"""

from __future__ import annotations

import logging
import math
import select
import socket
import time
from typing import TypeVar

import numpy as np

from drivers import ipp
from drivers.addresses import Address
from drivers.errors import EmergencyStop, InstrumentFault, InstrumentTimeout, OutOfLimits
from drivers.interfaces import Cmm

MAX_LINE_BYTES = 64 * 1024
MAX_COORDINATE_MM = 1e6
MOTIONS = ("GoTo", "PtMeas", "Home")
_Error = TypeVar("_Error", bound=Exception | None)  # what _drop passes on
COORDINATE_SYSTEM = "MachineCsy"  # §6.3.3.1: the machine's own axes, whatever a previous session left active
log = logging.getLogger(__name__)


class IppCmm(Cmm):
    name = "cmm"
    model, kind, schemes, framing = "ipp", "cmm", ("ipp",), None
    options: dict[str, tuple[float, float, bool]] = {}  # home=1 (drivers/addresses.py): the run may home an unhomed machine
    exclusive_access = ("an I++ DME server serves one session at a time, and rtcal held it while measuring (NIST's "
                        "reference server stops serving a second connection; docs/protocols/ipp_dme.md: not confirmed "
                        "for every real server)")
    _error_state = False  # the server answers 0514 until ClearAllErrors()
    version = ""
    tool: str | None = None
    emergency = ""  # the E0000 event's text once the server reported an emergency stop
    warnings: tuple[str, ...] = ()  # severity 0–1 replies, as the server worded them
    _event_tag = 0

    def __init__(self, address: Address, timeout_s: float = 5.0,
                 volume_min_mm=(-np.inf,) * 3, volume_max_mm=(np.inf,) * 3, tool: str | None = None,
                 home: bool = False, may_move: bool = True, **_: object):
        """``home``: the procedure allows homing an unhomed machine (as ``home=1`` in the address does);
        ``may_move=False`` (a probe) never homes, whatever the address says."""
        self.volume_min_mm, self.volume_max_mm = tuple(volume_min_mm), tuple(volume_max_mm)
        self.address, self.timeout_s, self.tool = address, timeout_s, tool
        self.may_home = may_move and (bool(home) or address.option("home", 0) == 1)
        self.may_move = may_move
        self.emergency = ""
        self.warnings = ()
        self.homed_by_rtcal = False
        self._tag = 0
        self._event_tag = 0
        self._buffer = b""
        self._error_state = False  # the server answers 0514 until ClearAllErrors()
        self.version = ""
        self.sock: socket.socket | None = None
        try:
            self._connect()
        except BaseException:
            self._drop(None)  # a session that could not be set up holds nothing
            raise

    def _connect(self) -> None:
        a = self.address
        try:
            self.sock = socket.create_connection((a.host, a.port), timeout=self.timeout_s)
        except OSError as exc:
            raise InstrumentTimeout(self.name, f"cannot connect to {a.host}:{a.port}: {exc}") from None
        self._buffer = b""
        self._error_state = False  # a new session starts clean
        self._start_session()
        try:
            data = self.command("GetDMEVersion()")
            m = ipp.DME_VERSION.search(data[0]) if data else None
            self.version = m.group(1) if m else ""
        except InstrumentFault:  # a server without it is still a CMM; the next command clears the error
            if self.sock is None:  # … but a connection that died is no session
                raise
            self.version = ""
        self.command(f"SetCoordSystem({COORDINATE_SYSTEM})")
        self._ensure_homed()
        if self.tool:
            self.command(f'ChangeTool("{self.tool}")')

    def _start_session(self) -> None:
        """``StartSession()``; a refusal or no answer says the CMM may be busy: a server serves one
        client at a time (§6.3.1), and one whose session is held may refuse a second (rtcal's
        simulator: 0507 "Another client holds the session") or leave it unanswered (NIST's
        reference server)."""
        busy = ("close the other client (another rtcal, the CMM's own software) or wait for its run to end, then try "
                "again")
        try:
            self.command("StartSession()")
        except InstrumentTimeout:
            raise self._drop(InstrumentTimeout(self.name, f"no reply to StartSession() within {self.timeout_s:g} s: the "
                                                          "CMM may be busy — it serves one client at a time, and a server "
                                                          f"whose session another client holds may not answer: {busy}")) from None
        except InstrumentFault as exc:
            said = str(exc).removeprefix(f"{self.name}: ")
            if "another client" in said.lower() or f"error {ipp.ILLEGAL_COMMAND}" in said:
                raise self._drop(InstrumentFault(self.name, f"the CMM is busy: another client holds its I++ session "
                                                            f"({said}): {busy}")) from None
            raise

    def _ensure_homed(self) -> None:
        """``IsHomed()``; an unhomed machine is homed only when allowed (§6.3.2.1: it refuses motion until homed)."""
        data = self.command("IsHomed()")
        m = ipp.IS_HOMED.search(data[0]) if data else None
        if m is None:
            raise InstrumentFault(self.name, f"IsHomed() gave {data[:1]!r:.200}, not IsHomed(0) or IsHomed(1)")
        if m.group(1) == "1":
            return
        if not self.may_home:
            why = ("a probe never moves a machine" if not self.may_move else
                   "rtcal homes it only when the procedure allows it (cmm: home: true, or home=1 in the address)")
            raise InstrumentFault(self.name, f"the CMM is not homed (IsHomed() = 0): home it at the machine first; {why}")
        log.info("%s: not homed; sending Home() as the procedure allows", self.name)
        self.command("Home()")
        self.homed_by_rtcal = True

    def identity(self) -> str:
        text = f"I++ DME server, DMEVersion {self.version}" if self.version else "I++ DME server"
        return f"{text}, coordinate system {COORDINATE_SYSTEM}" + (", homed by rtcal" if self.homed_by_rtcal else "")

    def recover(self) -> None:
        """Leave the error state: ``ClearAllErrors()`` (a new session if the connection died); never an
        emergency stop, which a person releases at the machine."""
        self._check_emergency()
        if self.sock is None:
            self._connect()
        self.command("ClearAllErrors()")

    def _check_emergency(self) -> None:
        if self.emergency:
            raise EmergencyStop(self.name, f"emergency stop reported by the CMM ({self.emergency}); nothing is sent "
                                           "until it is released at the machine and the run is started again")

    def _drop(self, error: _Error) -> _Error:
        """Close a connection that can no longer be trusted; the next command opens a new one."""
        if self.sock is not None:
            self.sock.close()
            self.sock = None
        self._buffer = b""
        return error

    def _connected(self) -> socket.socket:
        """The open connection (a command opens one first; one that failed was dropped with an error)."""
        if self.sock is None:
            raise InstrumentFault(self.name, "not connected")
        return self.sock

    def _readline(self, deadline: float) -> str:
        while b"\r\n" not in self._buffer:
            if len(self._buffer) > MAX_LINE_BYTES:
                raise self._drop(InstrumentFault(self.name, f"reply line longer than {MAX_LINE_BYTES // 1024} KiB"))
            left = deadline - time.monotonic()
            if left <= 0:
                self._buffer = b""  # a partial line will never complete: start clean next time
                raise InstrumentTimeout(self.name, "no reply within the timeout")
            sock = self._connected()
            try:
                sock.settimeout(left)
                chunk = sock.recv(4096)
            except socket.timeout:
                self._buffer = b""
                raise InstrumentTimeout(self.name, "no reply within the timeout") from None
            except OSError as exc:
                raise self._drop(InstrumentFault(self.name, f"connection failed: {exc}")) from None
            if not chunk:
                raise self._drop(InstrumentFault(self.name, "the CMM closed the connection"))
            self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\r\n", 1)
        if len(line) > MAX_LINE_BYTES:
            raise self._drop(InstrumentFault(self.name, f"reply line longer than {MAX_LINE_BYTES // 1024} KiB"))
        return line.decode("ascii", errors="replace")

    def command(self, text: str) -> list[str]:
        """Send one command; return its data lines; raise on an error reply."""
        self._check_emergency()
        if self.sock is None:
            self._connect()
        if self._error_state and not text.startswith(("ClearAllErrors(", "StartSession(")):
            self.command("ClearAllErrors()")
        return self._transaction(text)

    def _read_unsolicited(self) -> None:
        """Lines that arrived while no command ran: an ``E0000`` event (an emergency stop pressed
        between commands) latches before the next command is sent; other stale lines are dropped."""
        sock = self.sock
        if sock is None:
            return  # nothing can have arrived
        try:
            while select.select([sock], [], [], 0)[0]:
                chunk = sock.recv(4096)
                if not chunk:
                    return  # closed: the send or the read that follows reports it
                self._buffer += chunk
                if len(self._buffer) > MAX_LINE_BYTES:
                    break
        except (OSError, ValueError, TypeError):  # TypeError: a transport without a descriptor (a test's fake)
            return
        *lines, self._buffer = self._buffer.split(b"\r\n")
        for raw in lines:
            m = ipp.LINE.fullmatch(raw.decode("ascii", errors="replace"))
            if m is not None and m.group(1) == ipp.EVENT_TAG:
                self._server_event(m.group(2), m.group(3) or "")

    def _transaction(self, text: str, event: bool = False) -> list[str]:
        self._read_unsolicited()
        if not event:
            self._check_emergency()
        if event:  # an event command (AbortE): tags E0001…E9999, served ahead of the queue (§6.2.4)
            self._event_tag = self._event_tag % 9999 + 1
            tag = f"E{self._event_tag:04d}"
        else:
            self._tag = self._tag % 99999 + 1
            tag = f"{self._tag:05d}"
        deadline = time.monotonic() + self.timeout_s * (10 if text.startswith(MOTIONS) else 1)
        try:
            self._connected().sendall(f"{tag} {text}\r\n".encode("ascii"))
        except OSError as exc:
            raise self._drop(InstrumentFault(self.name, f"send failed: {exc}")) from None
        data: list[str] = []
        failure: Exception | None = None
        method = text.split("(")[0]
        while True:
            line = self._readline(deadline)
            m = ipp.LINE.fullmatch(line)
            if m is None:
                self._buffer = b""
                raise InstrumentFault(self.name, f"malformed reply {line[:80]!r}")
            kind, rest = m.group(2), m.group(3) or ""
            if m.group(1) == ipp.EVENT_TAG:
                self._server_event(kind, rest)
                continue
            if m.group(1) != tag:
                continue  # other tags are not ours
            if kind == ipp.DATA:
                data.append(rest)
            elif kind == ipp.DONE:
                if failure is None and text.startswith("ClearAllErrors("):
                    self._error_state = False
                if not event:
                    self._check_emergency()  # an emergency stop during the command fails it, whatever else it says
                if failure is not None:
                    raise failure
                return data
            elif kind == ipp.ERROR:
                err = ipp.parse_error(rest)
                severity, code, message = (err[0], err[1], err[3]) if err else (3, "?", rest[:200])
                if severity <= ipp.WARNING_SEVERITY and code != ipp.USE_CLEAR_ALL_ERRORS:
                    warning = f"{method}: {message} (I++ warning {code}, severity {severity})"
                    self.warnings = (*self.warnings[-99:], warning)
                    log.warning("%s: %s", self.name, warning)
                    continue  # §8.1: a warning does not end the transaction
                self._error_state = True
                if text.startswith("ClearAllErrors("):
                    self._error_state = False  # it was refused: the next attempt starts a clean session
                    raise self._drop(InstrumentFault(self.name, f"{text}: {message} (I++ error {code})"))
                error = OutOfLimits if code in (ipp.OUT_OF_VOLUME, ipp.MACHINE_LIMIT) else InstrumentFault
                if failure is None:  # the first error names the cause; read on to % so the next reply is not this one's
                    failure = error(self.name, f"{method}: {message} (I++ error {code}, severity {severity})")

    def _server_event(self, kind: str, rest: str) -> None:
        """An ``E0000`` line: an error event of severity 2 or more (an emergency stop) latches."""
        if kind != ipp.ERROR:
            return
        err = ipp.parse_error(rest)
        severity, code, message = (err[0], err[1], err[3]) if err else (3, "?", rest[:200])
        if severity <= ipp.WARNING_SEVERITY and code != ipp.EMERGENCY_STOP:
            self.warnings = (*self.warnings[-99:], f"event: {message} (I++ warning {code})")
            log.warning("%s: event %s (I++ warning %s)", self.name, message, code)
            return
        self.emergency = f"I++ event {ipp.EVENT_TAG} error {code}: {message}"[:200]
        log.error("%s: %s", self.name, self.emergency)

    def home(self) -> None:
        self.command("Home()")

    def move_to(self, xyz_mm) -> None:
        self.check_target(xyz_mm)
        self.command(f"GoTo({ipp.format_axes(*map(float, xyz_mm))})")

    def position_mm(self) -> np.ndarray:
        data = self.command("Get(X(), Y(), Z())")
        values = ipp.axes(data[0]) if data else {}
        xyz = [v for v in (values.get(a) for a in "XYZ") if v is not None]
        if len(xyz) < 3:
            raise InstrumentFault(self.name, f"Get returned {data[:1]!r:.200}")
        if not all(math.isfinite(v) and abs(v) <= MAX_COORDINATE_MM for v in xyz):
            raise InstrumentFault(self.name, f"Get returned a position that is no position: {data[0]:.200}")
        return np.array(xyz)

    def stop(self) -> None:
        """``AbortE()`` (§6.3.1.5): the server aborts whatever it executes. It is an event command, so
        it is sent even in the error state, and after an emergency stop too (stopping is always safe)."""
        if self.sock is None:
            return
        try:
            self._transaction("AbortE()", event=True)
        except InstrumentFault:
            if self.sock is None or self.emergency:
                return
            raise

    def close(self) -> None:
        if self.sock is None:
            return
        try:
            if not self.emergency:
                self.command("EndSession()")
        except (InstrumentFault, InstrumentTimeout):
            pass
        if self.sock is not None:
            self.sock.close()
            self.sock = None
