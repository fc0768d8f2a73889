"""A CMM over I++ DME (TCP, default port 1294).

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

    def __init__(self, address: Address, timeout_s: float = 5.0,
                 volume_min_mm=(-np.inf,) * 3, volume_max_mm=(np.inf,) * 3):
        self.volume_min_mm, self.volume_max_mm = tuple(volume_min_mm), tuple(volume_max_mm)
        self.address, self.timeout_s = address, timeout_s
        self._tag = 0
        self._buffer = b""
        self.sock: socket.socket | None = None
        self._connect()

    def _connect(self) -> None:
        a = self.address
        try:
            self.sock = socket.create_connection((a.host, a.port), timeout=self.timeout_s)
        except OSError as exc:
            raise InstrumentTimeout(self.name, f"cannot connect to {a.host}:{a.port}: {exc}") from None
        self._buffer = b""
        self.command("StartSession()")

    def _drop(self, error: Exception) -> Exception:
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
                return data
            elif kind == ipp.ERROR:
                err = ipp.ERROR_ARGS.search(rest)
                code, message = (err.group(2), err.group(4)) if err else ("?", rest)
                if code == ipp.OUT_OF_VOLUME:
                    raise OutOfLimits(self.name, f"{text}: {message} (I++ error {code})")
                raise InstrumentFault(self.name, f"{text}: {message} (I++ error {code})")

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
