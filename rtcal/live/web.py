"""How rtcal serves a page over HTTP (the live view and the catalogue page share it): the Host
header checked against DNS rebinding, a warning when bound beyond this computer, and a server no
one on the computer can fill so that a control request (abort, pause, confirm) finds no room.

Anyone who can reach the port can open connections; each one holds a descriptor and a place among
:data:`MAX_CONNECTIONS`. What keeps a place open for the operator (issue 40, item 4):

- deadlines on every phase of a request: its headers within :data:`HEADERS_S` of the connection
  (or of the previous answer), its body within :data:`BODY_S` of the headers, its answer within
  :data:`RESPONSE_S` — a connection that sends one byte, or dribbles a body, is closed;
- a full server makes room for a new connection by closing one that has not sent a whole request
  (the one waiting longest, once it has had :data:`GRACE_S`; else one at random) instead of turning
  the newcomer away: a browser's request arrives whole within milliseconds, a held connection never;
- event streams are counted apart (at most :data:`MAX_STREAMS`, beyond: 503) and do not take the
  connections' places; ordinary requests being answered take at most
  ``MAX_CONNECTIONS - CONTROL_SLOTS`` places (beyond: 503), so the last :data:`CONTROL_SLOTS` are
  always free for a request that carries the token (``Authorization: Bearer``).
"""

from __future__ import annotations

import ipaddress
import json
import random
import socket
import sys
import threading
import time
from typing import Any, Awaitable, Callable, Iterable, MutableMapping

import h11
import uvicorn
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from uvicorn.protocols.http.h11_impl import H11Protocol

LOOPBACK = "127.0.0.1"
MAX_CONNECTIONS = 64
"""Connections (event streams apart) open at once: a browser opens about six. The cap keeps the
process far from its descriptor limit (1,024 by default), which the store and instruments need."""
CONTROL_SLOTS = 4  # of them, never taken by requests that carry no token
MAX_STREAMS = 16  # event streams at once (a page keeps one)
HEADERS_S = 10.0  # a request's headers must be complete this long after the connection or the last answer
BODY_S = 10.0  # … and its body this long after its headers (rtcal's requests have none)
RESPONSE_S = 60.0  # an answer other than an event stream written within this (a reader that stops reading)
GRACE_S = 0.5  # a connection this young is not closed to make room while an older idle one can be
TICK_S = 0.25  # how often a connection's deadlines are checked

Scope = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]
Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def host_guard(host: str) -> Middleware:
    """Refuse (400) a request whose Host header names another site than this computer: a page
    elsewhere that rebinds its own name to 127.0.0.1 could otherwise read what is served. Bound
    beyond loopback, any name may reach it (:func:`warn_exposed` says so)."""
    allowed = ["*"] if not is_loopback(host) else sorted({"127.0.0.1", "localhost", "[::1]", "::1", host})
    return Middleware(TrustedHostMiddleware, allowed_hosts=allowed)


def warn_exposed(host: str, what: str, seen: str) -> None:
    """One warning line on stderr when ``host`` is not this computer only: what anyone who reaches
    it sees (``seen``)."""
    if not is_loopback(host):
        print(f"rtcal: warning: the {what} listens on {host}, not only this computer: anyone who reaches it "
              f"sees {seen}", file=sys.stderr, flush=True)


def bind(host: str, port: int) -> socket.socket:
    """A listening socket on ``host`` (a name, IPv4 or IPv6) and ``port`` (0: any free one); OSError if taken."""
    family, _, _, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(address)
        sock.listen(MAX_CONNECTIONS)
    except OSError:
        sock.close()
        raise
    return sock


def url_of(host: str, sock: socket.socket) -> str:
    shown = f"[{host}]" if ":" in host else host
    return f"http://{shown}:{sock.getsockname()[1]}/"


class GuardedH11(H11Protocol):
    """uvicorn's HTTP/1.1 with the deadlines and the making room of this module's docstring."""

    cap = MAX_CONNECTIONS
    headers_s = HEADERS_S
    body_s = BODY_S
    response_s = RESPONSE_S
    grace_s = GRACE_S
    stream_paths: frozenset[str] = frozenset()

    def connection_made(self, transport: Any) -> None:  # type: ignore[override]
        now = time.monotonic()
        self._gone = False  # refused, closed to make room, or past a deadline
        self._timer: Any = None
        self._waiting_since = now  # when it began waiting for a request's headers
        self._request_at = now  # when the current request's headers were complete
        self._seen: Any = None  # the request cycle the times above belong to
        if self._held() >= self.cap:
            victim = self._victim(now)
            if victim is None:  # every place is being answered: closed at once, the descriptor comes back
                self._gone = True
                transport.abort()
                return
            victim._close()
        super().connection_made(transport)
        self._timer = self.loop.call_later(TICK_S, self._tick)

    # -- what a connection is doing -----------------------------------------------------------
    def _phase(self) -> str:
        """"waiting" (for a request's headers), "body" (for the rest of a request), "serving" an
        answer, or "stream" (an event stream being served)."""
        cycle = self.cycle
        if cycle is not None and self.conn.their_state is h11.SEND_BODY:
            return "body"
        if cycle is None or cycle.response_complete:
            return "waiting"
        return "stream" if self.scope["path"] in self.stream_paths else "serving"

    def _phase_since(self) -> float:
        return self._waiting_since if self._phase() == "waiting" else self._request_at

    def _held(self) -> int:
        return sum(1 for c in self.connections if isinstance(c, GuardedH11) and not c._gone and c._phase() != "stream")

    def _victim(self, now: float) -> GuardedH11 | None:
        """The connection to close for a newcomer: one without a whole request, the longest waiting
        once past its grace, else any at random (a flood of new connections cannot keep the
        newest safe); None when every place is answering a request."""
        idle = [c for c in self.connections if isinstance(c, GuardedH11) and not c._gone
                and c._phase() in ("waiting", "body")]
        if not idle:
            return None
        oldest = min(idle, key=lambda c: c._phase_since())
        return oldest if now - oldest._phase_since() >= self.grace_s else random.choice(idle)

    # -- deadlines ---------------------------------------------------------------------------
    def _tick(self) -> None:
        self._timer = None
        if self._gone:
            return
        phase = self._phase()
        limit = {"waiting": self.headers_s, "body": self.body_s, "serving": self.response_s}.get(phase)
        if limit is not None and time.monotonic() - self._phase_since() > limit:
            self._close()
            return
        self._timer = self.loop.call_later(TICK_S, self._tick)

    def _close(self) -> None:
        self._gone = True
        self.transport.abort()  # at once, no lingering: the descriptor comes back now

    # -- uvicorn's hooks ---------------------------------------------------------------------
    def handle_events(self) -> None:
        super().handle_events()
        if self.cycle is not self._seen:  # a new request's headers are complete
            self._seen = self.cycle
            self._request_at = time.monotonic()

    def on_response_complete(self) -> None:
        self._waiting_since = time.monotonic()
        super().on_response_complete()

    def connection_lost(self, exc: Exception | None) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self.transport is None:  # refused in connection_made: uvicorn never knew it
            return
        self._gone = True
        super().connection_lost(exc)


class Slots:
    """An ASGI wrapper that counts what is being answered: event streams (``stream_paths``) at
    most :data:`MAX_STREAMS`, requests carrying no token at most ``MAX_CONNECTIONS -
    CONTROL_SLOTS``; one more is answered 503 at once. A POST with ``Authorization: Bearer`` is
    never held back (the app checks its token; a wrong one is a 401 in a millisecond)."""

    def __init__(self, app: ASGIApp, stream_paths: Iterable[str] = (), max_streams: int = MAX_STREAMS,
                 max_ordinary: int = MAX_CONNECTIONS - CONTROL_SLOTS) -> None:
        self.app = app
        self.stream_paths = frozenset(stream_paths)
        self.limits = {"stream": max_streams, "ordinary": max_ordinary}
        self.busy = {"stream": 0, "ordinary": 0}
        self.lock = threading.Lock()  # the counts are read from other threads (a server waiting for streams to end)

    @staticmethod
    def carries_token(scope: Scope) -> bool:
        return scope["method"] == "POST" and any(
            name == b"authorization" and value[:7].lower() == b"bearer " for name, value in scope["headers"])

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or self.carries_token(scope):
            await self.app(scope, receive, send)
            return
        kind = "stream" if scope["path"] in self.stream_paths else "ordinary"
        with self.lock:
            full = self.busy[kind] >= self.limits[kind]
            if not full:
                self.busy[kind] += 1
        if full:
            await _busy(send, kind)
            return
        try:
            await self.app(scope, receive, send)
        finally:
            with self.lock:
                self.busy[kind] -= 1


async def _busy(send: Send, kind: str) -> None:
    what = "event streams" if kind == "stream" else "requests"
    body = json.dumps({"error": f"too many {what} at once; try again"}).encode()
    await send({"type": "http.response.start", "status": 503, "headers": [
        (b"content-type", b"application/json"), (b"retry-after", b"2"), (b"connection", b"close"),
        (b"cache-control", b"no-store"), (b"content-length", str(len(body)).encode())]})
    await send({"type": "http.response.body", "body": body})


def serve(app: ASGIApp, sock: socket.socket, name: str, stream_paths: Iterable[str] = ()) -> tuple[uvicorn.Server,
                                                                                                   threading.Thread]:
    """Serve ``app`` on ``sock`` in a background thread with :class:`GuardedH11`; returns once it
    serves (or its thread ended)."""
    protocol = type("GuardedH11", (GuardedH11,), {"stream_paths": frozenset(stream_paths)})
    config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="off", http=protocol,
                            timeout_graceful_shutdown=2, server_header=False,
                            backlog=MAX_CONNECTIONS)  # asyncio accepts up to `backlog` at a time before any is served
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, name=name, daemon=True)
    thread.start()
    deadline = time.monotonic() + 10
    while not server.started and thread.is_alive() and time.monotonic() < deadline:
        time.sleep(0.02)
    return server, thread
