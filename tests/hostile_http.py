"""Hostile clients of an HTTP server on this computer, as anyone logged in could run them (issue 40,
item 4): connections that send one byte and wait, event streams never read, request bodies
dribbled a byte a second, and a flood that reconnects whatever is closed. Used by
tests/test_live_hostile.py and benchmarks/bench_live_abort.py."""

from __future__ import annotations

import resource
import socket
import threading
import time
import urllib.error
import urllib.request
from dataclasses import dataclass, field


def _room_for(count: int) -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < count + 300:
        resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, count + 600), hard))


def _open(host: str, port: int, first: bytes) -> socket.socket | None:
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.settimeout(5)
    try:
        s.connect((host, port))
        s.sendall(first)
    except OSError:  # refused or reset at once: that one holds nothing
        s.close()
        return None
    return s


@dataclass
class Hostile:
    """Open connections of one kind; ``close()`` ends them (and the thread dribbling bodies)."""

    socks: list[socket.socket] = field(default_factory=list)
    stop: threading.Event = field(default_factory=threading.Event)
    threads: list[threading.Thread] = field(default_factory=list)

    def close(self) -> None:
        self.stop.set()
        for t in self.threads:
            t.join(10)
        for s in self.socks:
            s.close()
        self.socks.clear()

    def still_open(self) -> int:
        """How many of them the server has not closed (what it sent is read and dropped; nothing waits)."""
        alive = 0
        for s in self.socks:
            s.setblocking(False)
            try:
                while s.recv(65536):
                    pass
            except BlockingIOError:
                alive += 1  # nothing more to read and no end: still open
            except OSError:
                pass  # reset
            finally:
                s.settimeout(5)
        return alive


def one_byte(host: str, port: int, count: int) -> Hostile:
    """``count`` connections that each send the first byte of a request, and nothing more."""
    _room_for(count)
    return Hostile([s for _ in range(count) if (s := _open(host, port, b"G")) is not None])


def streams(host: str, port: int, count: int) -> Hostile:
    """``count`` event streams (GET /api/events) whose answers are never read."""
    _room_for(count)
    request = f"GET /api/events HTTP/1.1\r\nHost: {host}:{port}\r\n\r\n".encode()
    return Hostile([s for _ in range(count) if (s := _open(host, port, request)) is not None])


def slow_bodies(host: str, port: int, count: int, every_s: float = 1.0) -> Hostile:
    """``count`` POSTs announcing a 100 kB body and sending it a byte every ``every_s``: half to a
    route that takes no body, half to the abort with a wrong token (both answered before the body)."""
    _room_for(count)
    heads = [f"POST /api/state HTTP/1.1\r\nHost: {host}:{port}\r\nContent-Length: 100000\r\n\r\nx".encode(),
             f"POST /api/abort HTTP/1.1\r\nHost: {host}:{port}\r\nAuthorization: Bearer wrong\r\n"
             "Content-Length: 100000\r\n\r\nx".encode()]
    hostile = Hostile([s for k in range(count) if (s := _open(host, port, heads[k % 2])) is not None])

    def dribble() -> None:
        while not hostile.stop.wait(every_s):
            for s in list(hostile.socks):
                try:
                    s.send(b"x")
                except OSError:
                    pass

    t = threading.Thread(target=dribble, daemon=True)
    t.start()
    hostile.threads.append(t)
    return hostile


def flood(host: str, port: int, hold: int, threads: int = 4) -> Hostile:
    """``threads`` loops that keep ``hold`` one-byte connections open between them, opening a new
    one as fast as they can whenever the server closes one (``opened`` counts them)."""
    _room_for(hold + 100)
    hostile = Hostile()
    hostile.opened = 0  # type: ignore[attr-defined]
    per = max(1, hold // threads)

    def loop() -> None:
        mine: list[socket.socket] = []
        while not hostile.stop.is_set():
            kept = []
            for s in mine:
                try:
                    s.setblocking(False)
                    if s.recv(1, socket.MSG_PEEK) == b"":
                        s.close()
                        continue
                except BlockingIOError:
                    pass
                except OSError:
                    s.close()
                    continue
                kept.append(s)
            mine = kept
            while len(mine) < per and not hostile.stop.is_set():
                s = _open(host, port, b"G")
                hostile.opened += 1  # type: ignore[attr-defined]
                if s is not None:
                    mine.append(s)
        for s in mine:
            s.close()

    for _ in range(threads):
        t = threading.Thread(target=loop, daemon=True)
        t.start()
        hostile.threads.append(t)
    return hostile


def timed_post(url: str, command: str, token: str, timeout_s: float = 20.0, tries: int = 1) -> tuple[int | str, float]:
    """POST api/COMMAND with the token: (the HTTP status, or the error's name if none came; seconds).
    ``tries`` > 1: sent again 0.25 s after no answer, as the live page does (rtcal/live/static/app.js)."""
    request = urllib.request.Request(url + f"api/{command}", method="POST", data=b"",
                                     headers={"Authorization": f"Bearer {token}"})
    t0 = time.monotonic()
    for attempt in range(1, tries + 1):
        try:
            with urllib.request.urlopen(request, timeout=timeout_s) as r:
                status: int | str = r.status
        except urllib.error.HTTPError as exc:
            status = exc.code
        except (OSError, urllib.error.URLError) as exc:
            status = type(getattr(exc, "reason", exc)).__name__
            if attempt < tries:
                time.sleep(0.25)
                continue
        break
    return status, time.monotonic() - t0
