"""A CMM over I++ DME (TCP, default port 1294).

A session starts with ``StartSession()``, asks ``GetDMEVersion()`` (the identity) and, when
the procedure names a tool, ``ChangeTool("name")``. An error of severity 2 or more leaves the
server in its error state (every command answered 0514): the driver raises the error, and
clears the state with ``ClearAllErrors()`` before its next command — the retry of the fault
policy, or ``recover()`` — so one refused move does not fail every retry.

Every command has a deadline (the timeout; ten times it for a motion) however the server
dribbles its bytes, a reply line is at most 64 KiB, and coordinates must be finite and within
a kilometre. A connection left unusable (closed by the server, an overlong line) is opened
again, with a new session, by the next command.
"""

from __future__ import annotations

import math
import socket
import time

import numpy as np

from drivers import ipp
from drivers.addresses import Address
from drivers.errors import InstrumentFault, InstrumentTimeout, OutOfLimits
from drivers.interfaces import Cmm

MAX_LINE_BYTES = 64 * 1024
MAX_COORDINATE_MM = 1e6
MOTIONS = ("GoTo", "PtMeas", "Home")


class IppCmm(Cmm):
    name = "cmm"
    model, kind, schemes, options, framing = "ipp", "cmm", ("ipp",), {}, None
    exclusive_access = ("an I++ DME server serves one session at a time, and rtcal held it while measuring (a second "
                        "client's StartSession() is refused; docs/protocols/ipp_dme.md: not confirmed for every real server)")
    _error_state = False  # the server answers 0514 until ClearAllErrors()
    version = ""
    tool: str | None = None

    def __init__(self, address: Address, timeout_s: float = 5.0,
                 volume_min_mm=(-np.inf,) * 3, volume_max_mm=(np.inf,) * 3, tool: str | None = None, **_: object):
        self.volume_min_mm, self.volume_max_mm = tuple(volume_min_mm), tuple(volume_max_mm)
        self.address, self.timeout_s, self.tool = address, timeout_s, tool
        self._tag = 0
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
        self.command("StartSession()")
        try:
            data = self.command("GetDMEVersion()")
            m = ipp.DME_VERSION.search(data[0]) if data else None
            self.version = m.group(1) if m else ""
        except InstrumentFault:  # a server without it is still a CMM; the next command clears the error
            if self.sock is None:  # … but a connection that died is no session
                raise
            self.version = ""
        if self.tool:
            self.command(f'ChangeTool("{self.tool}")')

    def identity(self) -> str:
        return f"I++ DME server, DMEVersion {self.version}" if self.version else "I++ DME server"

    def recover(self) -> None:
        """Leave the error state: ``ClearAllErrors()`` (a new session if the connection died)."""
        if self.sock is None:
            self._connect()
        self.command("ClearAllErrors()")

    def _drop(self, error: Exception | None) -> Exception | None:
        """Close a connection that can no longer be trusted; the next command opens a new one."""
        if self.sock is not None:
            self.sock.close()
            self.sock = None
        self._buffer = b""
        return error

    def _readline(self, deadline: float) -> str:
        while b"\r\n" not in self._buffer:
            if len(self._buffer) > MAX_LINE_BYTES:
                raise self._drop(InstrumentFault(self.name, f"reply line longer than {MAX_LINE_BYTES // 1024} KiB"))
            left = deadline - time.monotonic()
            if left <= 0:
                self._buffer = b""  # a partial line will never complete: start clean next time
                raise InstrumentTimeout(self.name, "no reply within the timeout")
            try:
                self.sock.settimeout(left)
                chunk = self.sock.recv(4096)
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
        if self.sock is None:
            self._connect()
        if self._error_state and not text.startswith(("ClearAllErrors(", "StartSession(")):
            self.command("ClearAllErrors()")
        return self._transaction(text)

    def _transaction(self, text: str) -> list[str]:
        self._tag = self._tag % 99999 + 1
        tag = f"{self._tag:05d}"
        deadline = time.monotonic() + self.timeout_s * (10 if text.startswith(MOTIONS) else 1)
        try:
            self.sock.sendall(f"{tag} {text}\r\n".encode("ascii"))
        except OSError as exc:
            raise self._drop(InstrumentFault(self.name, f"send failed: {exc}")) from None
        data: list[str] = []
        while True:
            line = self._readline(deadline)
            m = ipp.LINE.fullmatch(line)
            if m is None:
                self._buffer = b""
                raise InstrumentFault(self.name, f"malformed reply {line[:80]!r}")
            if m.group(1) != tag:
                continue  # events and other tags are not ours
            kind, rest = m.group(2), m.group(3) or ""
            if kind == ipp.DATA:
                data.append(rest)
            elif kind == ipp.DONE:
                if text.startswith("ClearAllErrors("):
                    self._error_state = False
                return data
            elif kind == ipp.ERROR:
                err = ipp.ERROR_ARGS.search(rest)
                severity, code, message = (int(err.group(1)), err.group(2), err.group(4)) if err else (3, "?", rest[:200])
                if severity >= 2 or code == ipp.USE_CLEAR_ALL_ERRORS:
                    self._error_state = True
                if text.startswith("ClearAllErrors("):
                    self._error_state = False  # it was refused: the next attempt starts a clean session
                    raise self._drop(InstrumentFault(self.name, f"{text}: {message} (I++ error {code})"))
                error = OutOfLimits if code in (ipp.OUT_OF_VOLUME, ipp.MACHINE_LIMIT) else InstrumentFault
                raise error(self.name, f"{text.split('(')[0]}: {message} (I++ error {code}, severity {severity})")

    def home(self) -> None:
        self.command("Home()")

    def move_to(self, xyz_mm) -> None:
        self.check_target(xyz_mm)
        self.command(f"GoTo({ipp.format_axes(*map(float, xyz_mm))})")

    def position_mm(self) -> np.ndarray:
        data = self.command("Get(X(), Y(), Z())")
        values = ipp.axes(data[0]) if data else {}
        if any(values.get(a) is None for a in "XYZ"):
            raise InstrumentFault(self.name, f"Get returned {data[:1]!r:.200}")
        xyz = [values["X"], values["Y"], values["Z"]]
        if not all(math.isfinite(v) and abs(v) <= MAX_COORDINATE_MM for v in xyz):
            raise InstrumentFault(self.name, f"Get returned a position that is no position: {data[0]:.200}")
        return np.array(xyz)

    def stop(self) -> None:
        self.command("ClearAllErrors()")

    def close(self) -> None:
        if self.sock is None:
            return
        try:
            self.command("EndSession()")
        except (InstrumentFault, InstrumentTimeout):
            pass
        if self.sock is not None:
            self.sock.close()
            self.sock = None
