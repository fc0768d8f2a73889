"""A scripted serial device on a pseudo-terminal: the protocol-level test adapter for drivers.

The driver opens a real device path; the device checks each request byte for byte and answers
with the scripted reply — or with nothing (silence) when the reply is None.
"""

from __future__ import annotations

import os
import select
import threading
import tty


class ScriptedDevice:
    def __init__(self, script: list[tuple[bytes, bytes | None]]):
        self.script = list(script)
        self.received: list[bytes] = []
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        buffer = b""
        while not self._stop.is_set() and self.script:
            ready, _, _ = select.select([self.master], [], [], 0.05)
            if not ready:
                continue
            try:
                buffer += os.read(self.master, 1024)
            except OSError:
                return
            expected, reply = self.script[0]
            if len(buffer) >= len(expected):
                self.received.append(buffer[: len(expected)])
                buffer = buffer[len(expected):]
                self.script.pop(0)
                if reply is not None:
                    os.write(self.master, reply)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1)
        for fd in (self.master, self.slave):
            os.close(fd)

    def __enter__(self) -> "ScriptedDevice":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
