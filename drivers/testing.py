"""A test helper for driver authors: a fake serial transport that replays an expected exchange.

    from drivers.testing import replay

    with replay([(b"a\\r\\n", b"4 003 12.34 -5.67\\r")]) as line:
        autocollimator = open_instrument("autocollimator", "socket://device:1?model=elcomat", 1.0)
        assert autocollimator.read_arcsec() == (12.34, -5.67)
    line.assert_done()

Inside ``replay`` every :class:`drivers.serial_line.SerialLine` (what serial drivers use) is
opened on the script instead of a device: each byte the driver writes is compared with the
next expected byte, and the first that differs raises :class:`ExchangeMismatch` naming the
request, the byte's position, what was expected and what came, and what was sent so far.
Once a request is complete its reply is what the driver reads (``None``: silence, so the
driver times out). ``line.framing`` holds what the driver opened the line with.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

from drivers import serial_line


class ExchangeMismatch(AssertionError):
    """The driver sent a byte the exchange did not expect."""


def _show(byte: int | None) -> str:
    return "nothing more" if byte is None else f"{bytes([byte])!r} (0x{byte:02X})"


class ReplayLine:
    """Stands in for a pyserial port: write, flush, read_until, reset_input_buffer, close."""

    def __init__(self, exchange: list[tuple[bytes, bytes | None]]):
        self.exchange = list(exchange)
        self.step = 0  # the request being written
        self.sent = b""  # of that request, so far
        self.pending = b""  # reply bytes not yet read
        self.framing: dict = {}
        self.is_open = True

    # -- pyserial's port, as SerialLine uses it
    def write(self, data: bytes) -> int:
        for byte in data:
            if self.step >= len(self.exchange):
                raise ExchangeMismatch(f"request {self.step + 1}: the exchange has ended, but the driver sent "
                                       f"{_show(byte)} after {self.sent!r}")
            expected = self.exchange[self.step][0]
            position = len(self.sent)
            if position >= len(expected) or expected[position] != byte:
                want = expected[position] if position < len(expected) else None
                raise ExchangeMismatch(f"request {self.step + 1}, byte {position + 1}: expected {_show(want)}, got "
                                       f"{_show(byte)}; sent so far {self.sent!r}, expected {expected!r}")
            self.sent += bytes([byte])
            if self.sent == expected:
                self.pending += self.exchange[self.step][1] or b""
                self.step, self.sent = self.step + 1, b""
        return len(data)

    def flush(self) -> None:
        pass

    def reset_input_buffer(self) -> None:
        pass  # a scripted reply is never stale

    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes:
        end = self.pending.find(expected)
        stop = len(self.pending) if end < 0 else end + len(expected)
        if size is not None:
            stop = min(stop, size)
        data, self.pending = self.pending[:stop], self.pending[stop:]
        return data

    def close(self) -> None:
        self.is_open = False

    # -- for the test
    def assert_done(self) -> None:
        """Every request of the exchange was sent (and nothing more, which write() already refused)."""
        if self.step < len(self.exchange):
            raise ExchangeMismatch(f"the driver stopped after request {self.step} of {len(self.exchange)}; "
                                   f"request {self.step + 1} ({self.exchange[self.step][0]!r}) never came"
                                   + (f" (sent of it: {self.sent!r})" if self.sent else ""))


@contextmanager
def replay(exchange: list[tuple[bytes, bytes | None]]) -> Iterator[ReplayLine]:
    """Serial lines opened inside the block replay ``exchange`` (request, reply) pairs in order."""
    line = ReplayLine(exchange)

    def open_port(url: str, **settings) -> ReplayLine:
        line.framing = dict(settings, url=url)
        return line

    saved, serial_line.open_port = serial_line.open_port, open_port
    try:
        yield line
    finally:
        serial_line.open_port = saved
