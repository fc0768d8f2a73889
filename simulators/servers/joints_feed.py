"""The simulated machine tool following a real LinuxCNC: its joints' motor commands, streamed by
rtcal's HAL component (simulators/linuxcnc/rtcal_bench_feed.py, joints form), and the nest's
readings held back until the machine has caught up.

The feed is a process of its own, reading HAL pins LinuxCNC's servo thread writes; on a loaded
host its lines arrive late (seen: a nest read right after a move found the machine 0.4° short of
where LinuxCNC had stopped it). So each line carries the monotonic time its pins were read
(CLOCK_MONOTONIC, one clock for every process of the host) and the feed sends one at least every
HEARTBEAT_S, and a nest reading requested at t is answered only once a line read at or after t has
been applied: the machine is then where LinuxCNC put it when the reading was asked for (a move
rtcal waited for had ended before it asked). A feed silent for CATCH_UP_S leaves the reading
unanswered (the driver's timeout, a fault), never a reading of a machine somewhere else.

The feed is read by a thread of its own, not the hub's event loop, so the loop can wait for it;
the machine model is touched under one lock, by this thread and by the nest's readings.
"""

from __future__ import annotations

import math
import socket
import sys
import threading
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from simulators.bench import Bench
    from simulators.servers.serial_protocols import LineHandler

CATCH_UP_S = 2.0  # the longest a nest reading waits for the machine to catch up with LinuxCNC
MAX_LINE_BYTES = 1024
AXES = ("x", "y", "z", "a", "c")


class JointsFeed:
    """A listening socket for the feed (``address``: HOST:PORT), its reader thread, and the machine it
    moves. ``updates``: lines applied; ``stamp``: the read time of the last."""

    def __init__(self, bench: "Bench", host: str):
        from simulators.machine_tool import machine_of

        self.machine = machine_of(bench)
        self.rng = bench.rng("machine_tool")
        self.lock = threading.Condition()
        self.stamp = -math.inf
        self.updates = 0
        self.warned = False
        self.server = socket.create_server((host, 0))
        self.address = f"{host}:{self.server.getsockname()[1]}"
        self.thread = threading.Thread(target=self._serve, name="rtcal-joints-feed", daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.server.accept()
            except OSError:
                return
            with conn, conn.makefile("rb") as lines:
                try:
                    for line in lines:
                        if len(line) <= MAX_LINE_BYTES:
                            self._apply(line)
                except OSError:
                    pass

    def _apply(self, line: bytes) -> None:
        """``<stamp> <x> <y> <z> <a> <c>``; a line that is not six finite numbers is ignored. A sphere driven
        into the nest is said once on stderr."""
        try:
            values = [float(w) for w in line.split()]
        except ValueError:
            return
        if len(values) != 6 or not all(math.isfinite(v) and abs(v) < 1e9 for v in values):
            return
        with self.lock:
            struck = self.machine.collision
            self.machine.follow_joints(dict(zip(AXES, values[1:])), self.rng)
            self.stamp = max(self.stamp, values[0])
            self.updates += 1
            self.lock.notify_all()
        if self.machine.collision and not struck:
            print(f"rtcal sim serve: WARNING: {self.machine.collision}", file=sys.stderr, flush=True)

    def caught_up(self, asked_s: float, timeout_s: float = CATCH_UP_S) -> bool:
        """Wait until a line read at or after ``asked_s`` (time.monotonic) was applied; False after ``timeout_s``."""
        with self.lock:
            done = self.lock.wait_for(lambda: self.stamp >= asked_s, timeout_s)
        if not done and not self.warned:
            self.warned = True
            print(f"rtcal sim serve: WARNING: LinuxCNC's joints feed fell silent for {timeout_s:g} s: the nest's "
                  "readings go unanswered until it catches up", file=sys.stderr, flush=True)
        return done

    def close(self) -> None:
        try:
            self.server.close()
        except OSError:
            pass


class FollowingLine:
    """A nest indicator's line while LinuxCNC drives the machine: a reading is answered once the machine
    has caught up with LinuxCNC (:meth:`JointsFeed.caught_up`), under the feed's lock; else nothing."""

    def __init__(self, handler: "LineHandler", feed: JointsFeed):
        self.handler, self.feed = handler, feed
        self.terminator, self.reply_terminator = handler.terminator, handler.reply_terminator
        self.instrument = getattr(handler, "instrument", None)  # what the fault injector afflicts

    def counted(self, request: bytes) -> bool:
        return self.handler.counted(request)

    def handle(self, request: bytes) -> bytes:
        if self.handler.counted(request) and not self.feed.caught_up(time.monotonic()):
            return b""
        with self.feed.lock:
            return self.handler.handle(request)
