"""A request/reply ASCII line over pyserial: a device path or any pyserial URL (socket://...).

Typed errors: no reply or no terminator within the timeout → InstrumentTimeout; a reply that
does not parse → InstrumentFault (raised by the instrument classes).
"""

from __future__ import annotations

import serial

from drivers.errors import InstrumentFault, InstrumentTimeout


class SerialLine:
    def __init__(self, name: str, url: str, baudrate: int = 9600, timeout_s: float = 1.0, terminator: bytes = b"\r"):
        self.name = name
        self.terminator = terminator
        try:
            self.port = serial.serial_for_url(url, baudrate=baudrate, timeout=timeout_s, write_timeout=timeout_s)
        except (serial.SerialException, ValueError, OSError) as exc:
            raise InstrumentTimeout(name, f"cannot open {url}: {exc}") from None

    def query(self, request: bytes, max_bytes: int = 256) -> str:
        """Send one request, return the reply line without its terminator."""
        try:
            self.port.reset_input_buffer()
            self.port.write(request)
            self.port.flush()
            reply = self.port.read_until(self.terminator, max_bytes)
        except (serial.SerialException, OSError) as exc:
            raise InstrumentFault(self.name, f"serial line failed: {exc}") from None
        if not reply:
            raise InstrumentTimeout(self.name, f"no reply to {request!r}")
        if not reply.endswith(self.terminator):
            raise InstrumentTimeout(self.name, f"truncated reply to {request!r}: {reply!r}")
        try:
            return reply[: -len(self.terminator)].decode("ascii").strip("\r\n")
        except UnicodeDecodeError:
            raise InstrumentFault(self.name, f"reply is not ASCII: {reply!r}") from None

    def close(self) -> None:
        self.port.close()
