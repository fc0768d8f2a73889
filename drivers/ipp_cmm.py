"""A CMM over I++ DME (TCP, default port 1294)."""

from __future__ import annotations

import socket

import numpy as np

from drivers import ipp
from drivers.addresses import Address
from drivers.errors import InstrumentFault, InstrumentTimeout, OutOfLimits
from drivers.interfaces import Cmm


class IppCmm(Cmm):
    name = "cmm"

    def __init__(self, address: Address, timeout_s: float = 5.0,
                 volume_min_mm=(-np.inf,) * 3, volume_max_mm=(np.inf,) * 3):
        self.volume_min_mm, self.volume_max_mm = tuple(volume_min_mm), tuple(volume_max_mm)
        self._tag = 0
        self._buffer = b""
        try:
            self.sock = socket.create_connection((address.host, address.port), timeout=timeout_s)
        except OSError as exc:
            raise InstrumentTimeout(self.name, f"cannot connect to {address.host}:{address.port}: {exc}") from None
        self.command("StartSession()")

    def _readline(self) -> str:
        while b"\r\n" not in self._buffer:
            try:
                chunk = self.sock.recv(4096)
            except socket.timeout:
                self._buffer = b""  # a partial line will never complete: start clean next time
                raise InstrumentTimeout(self.name, "no reply within the timeout") from None
            except OSError as exc:
                raise InstrumentFault(self.name, f"connection failed: {exc}") from None
            if not chunk:
                raise InstrumentFault(self.name, "the CMM closed the connection")
            self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\r\n", 1)
        return line.decode("ascii", errors="replace")

    def command(self, text: str) -> list[str]:
        """Send one command; return its data lines; raise on an error reply."""
        self._tag = self._tag % 99999 + 1
        tag = f"{self._tag:05d}"
        try:
            self.sock.sendall(f"{tag} {text}\r\n".encode("ascii"))
        except OSError as exc:
            raise InstrumentFault(self.name, f"send failed: {exc}") from None
        data: list[str] = []
        while True:
            line = self._readline()
            m = ipp.LINE.fullmatch(line)
            if m is None:
                self._buffer = b""
                raise InstrumentFault(self.name, f"malformed reply {line!r}")
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
            raise InstrumentFault(self.name, f"Get returned {data!r}")
        return np.array([values["X"], values["Y"], values["Z"]])

    def stop(self) -> None:
        self.command("ClearAllErrors()")

    def close(self) -> None:
        try:
            self.command("EndSession()")
        except (InstrumentFault, InstrumentTimeout):
            pass
        self.sock.close()
