"""A request/reply ASCII line over pyserial: a device path or any pyserial URL (socket://...).

Typed errors: no reply or no terminator within the timeout → InstrumentTimeout; a line that
fails (the peer closed the socket, the adapter was unplugged) or a reply that does not parse →
InstrumentFault. pyserial's timeout bounds the whole reply, and a reply is at most ``max_bytes``.

The framing (baud, data bits, parity, stop bits) is the address's, else the model's defaults.
A ``socket://`` line carries bytes only, so there the framing is the far end's business (a
terminal server's port settings); pyserial still holds the values for inspection.
"""

from __future__ import annotations

import sys
from typing import Callable

import serial

if sys.platform != "win32":  # a pseudo-terminal or adapter whose other end died raises termios.error, which is no OSError
    from termios import error as TermiosError
else:  # Windows has no termios
    class TermiosError(Exception):
        pass

from drivers.addresses import Address
from drivers.errors import InstrumentFault, InstrumentTimeout
from drivers.models import Framing

# how a line is opened: pyserial's, replaced by drivers.testing.replay for byte-level tests
open_port: Callable[..., serial.SerialBase] = serial.serial_for_url


def _why(exc: BaseException) -> str:
    """``[Errno 5] Input/output error`` for termios.error(5, ...) as for OSError; pyserial's own text else."""
    if len(exc.args) == 2 and isinstance(exc.args[0], int):
        return f"[Errno {exc.args[0]}] {exc.args[1]}"
    return str(exc) or type(exc).__name__


def framing_of(address: Address, default: Framing) -> Framing:
    """The address's framing options over the model's defaults."""
    return Framing(int(address.option("baud", default.baud)), int(address.option("bytesize", default.bytesize)),
                   address.text("parity", default.parity), int(address.option("stopbits", default.stopbits)))


class SerialLine:
    def __init__(self, name: str, address: Address | str, framing: Framing = Framing(), timeout_s: float = 1.0,
                 terminator: bytes = b"\r"):
        self.name = name
        self.terminator = terminator
        url = address if isinstance(address, str) else address.path
        self.framing = framing if isinstance(address, str) else framing_of(address, framing)
        f = self.framing
        try:
            self.port = open_port(url, baudrate=f.baud, bytesize=f.bytesize, parity=f.parity, stopbits=f.stopbits,
                                  timeout=timeout_s, write_timeout=timeout_s)
        except (serial.SerialException, ValueError, OSError, TermiosError) as exc:
            raise InstrumentTimeout(name, f"cannot open {url} at {f}: {_why(exc)}") from None

    def write(self, request: bytes) -> None:
        try:
            self.port.reset_input_buffer()
            self.port.write(request)
            self.port.flush()
        except (serial.SerialException, OSError, TermiosError) as exc:
            raise InstrumentFault(self.name, f"serial line failed: {_why(exc)}") from None

    def read_line(self, what: bytes, max_bytes: int = 256) -> str:
        """One reply line without its terminator (and without a CR or LF left before it)."""
        try:
            reply = self.port.read_until(self.terminator, max_bytes)
        except (serial.SerialException, OSError, TermiosError) as exc:
            raise InstrumentFault(self.name, f"serial line failed: {_why(exc)}") from None
        if not reply:
            raise InstrumentTimeout(self.name, f"no reply to {what!r}")
        if not reply.endswith(self.terminator):
            raise InstrumentTimeout(self.name, f"truncated reply to {what!r}: {reply[:80]!r}")
        try:
            return reply[: -len(self.terminator)].decode("ascii").strip("\r\n")
        except UnicodeDecodeError:
            raise InstrumentFault(self.name, f"reply is not ASCII: {reply[:80]!r}") from None

    def query(self, request: bytes, max_bytes: int = 256) -> str:
        """Send one request, return the reply line without its terminator."""
        self.write(request)
        return self.read_line(request, max_bytes)

    def close(self) -> None:
        try:
            self.port.close()
        except (serial.SerialException, OSError, TermiosError):
            pass
