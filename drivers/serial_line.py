"""A request/reply ASCII line over pyserial: a device path or any pyserial URL (socket://...).

Typed errors: no reply or no terminator within the timeout → InstrumentTimeout; a line that
fails (the peer closed the socket, the adapter was unplugged) or a reply that does not parse →
InstrumentFault. pyserial's timeout bounds the whole reply, and a reply is at most ``max_bytes``.
"""

from __future__ import annotations

import serial

try:  # a pseudo-terminal or adapter whose other end died raises termios.error, which is no OSError
    from termios import error as TermiosError
except ImportError:  # Windows has no termios
    class TermiosError(Exception):
        pass

from drivers.errors import InstrumentFault, InstrumentTimeout


def _why(exc: BaseException) -> str:
    """``[Errno 5] Input/output error`` for termios.error(5, ...) as for OSError; pyserial's own text else."""
    if len(exc.args) == 2 and isinstance(exc.args[0], int):
        return f"[Errno {exc.args[0]}] {exc.args[1]}"
    return str(exc) or type(exc).__name__


class SerialLine:
    def __init__(self, name: str, url: str, baudrate: int = 9600, timeout_s: float = 1.0, terminator: bytes = b"\r"):
        self.name = name
        self.terminator = terminator
        try:
            self.port = serial.serial_for_url(url, baudrate=baudrate, timeout=timeout_s, write_timeout=timeout_s)
        except (serial.SerialException, ValueError, OSError, TermiosError) as exc:
            raise InstrumentTimeout(name, f"cannot open {url}: {exc}") from None

    def query(self, request: bytes, max_bytes: int = 256) -> str:
        """Send one request, return the reply line without its terminator."""
        try:
            self.port.reset_input_buffer()
            self.port.write(request)
            self.port.flush()
            reply = self.port.read_until(self.terminator, max_bytes)
        except (serial.SerialException, OSError, TermiosError) as exc:
            raise InstrumentFault(self.name, f"serial line failed: {_why(exc)}") from None
        if not reply:
            raise InstrumentTimeout(self.name, f"no reply to {request!r}")
        if not reply.endswith(self.terminator):
            raise InstrumentTimeout(self.name, f"truncated reply to {request!r}: {reply[:80]!r}")
        try:
            return reply[: -len(self.terminator)].decode("ascii").strip("\r\n")
        except UnicodeDecodeError:
            raise InstrumentFault(self.name, f"reply is not ASCII: {reply[:80]!r}") from None

    def close(self) -> None:
        try:
            self.port.close()
        except (serial.SerialException, OSError, TermiosError):
            pass
