"""The live view's web server: the page, its state, a stream of server-sent events, control.

Starlette on uvicorn, in a background thread of whatever process serves it: the running engine
(`rtcal run --live`, with its :class:`~rtcal.live.control.Controllable` and token) or another
process reading a run directory (`rtcal view`, read-only). Everything it shows comes from the
run's store, read read-only by :class:`~rtcal.live.storeview.StoreView`; every asset ships in
this package (labs are often offline), and the only files of the run directory it serves are
the report's.

Routes (the contract of issue 24): ``GET /`` the page; ``GET /api/state`` the state JSON;
``GET /api/events`` ``text/event-stream`` (each reading an event whose ``id`` is its store id, so a
browser reconnecting with ``Last-Event-ID`` carries on; ``state`` and ``log`` events carry no id);
``POST /api/pause|resume|abort|confirm`` with ``Authorization: Bearer TOKEN`` → 202, no or a wrong token
→ 401, a read-only view → 409 whatever the token; a confirm (``?step=N``: the wait it answers) when no
operator step (or another one) waits → 409.
"""

from __future__ import annotations

import bisect
import json
import socket
import sqlite3
import sys
import threading
import time
from importlib import resources
from pathlib import Path
from typing import Any, AsyncIterator, Callable

import anyio
import uvicorn
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, Response, StreamingResponse
from starlette.routing import Route

from rtcal.live.control import COMMANDS, Controllable, dispatch, step_of, token_matches
from rtcal.live.storeview import FINAL_STATES, REPORT_FILES, StoreView
from rtcal.live.web import LOOPBACK, Slots, bind, host_guard, serve, url_of, warn_exposed
from rtcal.engine.operator import NothingToConfirm

DEFAULT_PORT = 8765
STATIC_FILES = {"app.js": "text/javascript; charset=utf-8", "style.css": "text/css; charset=utf-8",
                "index.html": "text/html; charset=utf-8"}
SECURITY_HEADERS = {
    "Cache-Control": "no-store",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Content-Security-Policy": ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
                                "connect-src 'self'; frame-ancestors 'none'; base-uri 'none'; form-action 'none'"),
}
# the report is rtcal's own HTML with its inline style and figures as data: URIs; it runs no script
REPORT_HEADERS = {**SECURITY_HEADERS, "Content-Security-Policy": ("default-src 'none'; style-src 'unsafe-inline'; "
                                                                 "img-src data:; frame-ancestors 'none'; base-uri 'none'")}
MAX_LAST_EVENT_ID = 2**63 - 1
FINISHED_LINGER_S = 3.0  # how long a finished run's page is still served so every stream ends with `finished`
EVENTS_PATH = "/api/events"


class LiveSpecError(ValueError):
    """A ``[HOST:]PORT`` the user wrote that is not one (the CLI prints it, exit 2)."""


def parse_live_spec(spec: str) -> tuple[str, int]:
    """``PORT``, ``HOST:PORT`` or ``[IPv6]:PORT`` → (host, port); PORT 0 asks for any free port."""
    text = spec.strip()
    host = LOOPBACK
    if text.startswith("["):
        end = text.find("]")
        if end < 0 or text[end + 1:end + 2] != ":":
            raise LiveSpecError(f"--live {spec!r}: write [IPv6]:PORT, HOST:PORT or PORT")
        host, port_text = text[1:end], text[end + 2:]
    elif ":" in text:
        host, _, port_text = text.rpartition(":")
        if ":" in host:
            raise LiveSpecError(f"--live {spec!r}: an IPv6 address goes in brackets, e.g. [::1]:8765")
    else:
        port_text = text
    if not host or any(c.isspace() or c in "/?#@" for c in host):
        raise LiveSpecError(f"--live {spec!r}: no host name before the port")
    if not (port_text.isascii() and port_text.isdigit()) or len(port_text) > 5 or int(port_text) > 65535:
        raise LiveSpecError(f"--live {spec!r}: the port must be a number 0 … 65535 (0: any free port)")
    return host, int(port_text)


def _json(data: Any, status: int = 200, headers: dict[str, str] | None = None) -> Response:
    return Response(json.dumps(data, allow_nan=False, ensure_ascii=False), status_code=status,
                    media_type="application/json", headers={**SECURITY_HEADERS, **(headers or {})})


def _sse(event: str, data: Any, event_id: int | None = None) -> str:
    head = f"event: {event}\n" + (f"id: {event_id}\n" if event_id is not None else "")
    return head + f"data: {json.dumps(data, allow_nan=False, ensure_ascii=False)}\n\n"


def _asset(name: str) -> bytes:
    return resources.files("rtcal.live").joinpath("static").joinpath(name).read_bytes()


def _last_event_id(request: Request) -> int:
    """Where a reconnecting browser was (``Last-Event-ID``), or ``?after=`` for a first
    connection; anything not a whole number ≥ 0 counts as nothing seen."""
    text = request.headers.get("last-event-id") or request.query_params.get("after") or "0"
    text = text.strip()
    if text.isascii() and text.isdigit() and len(text) <= 19 and int(text) <= MAX_LAST_EVENT_ID:
        return int(text)
    return 0


CATCH_UP_BATCH = 2000  # readings per read of a viewer behind the feed
FEED_WINDOW = 20000  # encoded readings the feed keeps for every viewer (a few MB)


class _Feed:
    """What every event stream sends, read from the store once per poll for all viewers and
    encoded once: the newest FEED_WINDOW readings, the events, the state."""

    def __init__(self, view: StoreView, poll_s: float, control: Callable[[], bool]):
        self.view = view
        self.poll_s = poll_s
        self.control = control
        self._lock = threading.Lock()
        self._ids: list[int] = []
        self._texts: list[str] = []
        self._events: list[tuple[int, str]] = []
        self.last_id: int | None = None  # None: not yet placed at the store's end
        self.state_text: str | None = None
        self.final = False  # the state read last is a run's end (finished, failed, aborted)
        self._at = -1e9

    def refresh(self, now: bool = False) -> None:
        """Read what the store added since the last refresh (at most once per poll, whoever asks;
        ``now``: whenever asked)."""
        with self._lock:
            if not now and time.monotonic() - self._at < 0.8 * self.poll_s:
                return
            try:
                self._read()
            except sqlite3.Error:  # a store being created or checkpointed: the next poll reads it
                pass
            self._at = time.monotonic()

    def _read(self) -> None:
        """Called with the lock held: the new readings and events, encoded, and the state."""
        state = self.view.state()
        if self.last_id is None:  # a long run's older readings are read by each viewer that wants them
            self.last_id = max(0, int(state.get("last_reading_id") or 0) - FEED_WINDOW)
        while True:
            rows = self.view.readings_after(self.last_id, CATCH_UP_BATCH)
            for r in rows:
                self._ids.append(r["id"])
                self._texts.append(_sse("reading", r, r["id"]))
            if rows:
                self.last_id = rows[-1]["id"]
            if len(rows) < CATCH_UP_BATCH:
                break
        if len(self._ids) > 2 * FEED_WINDOW:
            del self._ids[:-FEED_WINDOW], self._texts[:-FEED_WINDOW]
        after = self._events[-1][0] if self._events else 0
        self._events += [(e["id"], _sse("log", e)) for e in self.view.events_after(after)]
        self.state_text = json.dumps({**state, "control": self.control()}, allow_nan=False, ensure_ascii=False)
        self.final = state.get("state") in FINAL_STATES

    def readings_since(self, after: int) -> list[tuple[int, str]] | None:
        """The encoded readings after ``after``; None if they begin before the feed's window."""
        with self._lock:
            first = self._ids[0] if self._ids else (self.last_id or 0) + 1
            if after + 1 < first and after < (self.last_id or 0):
                return None
            k = bisect.bisect_right(self._ids, after)
            return list(zip(self._ids[k:], self._texts[k:]))

    def events_since(self, after: int) -> list[tuple[int, str]]:
        with self._lock:
            k = bisect.bisect_right([i for i, _ in self._events], after)
            return self._events[k:]


class LiveServer:
    """The live view of one run directory, served by uvicorn in a background thread.

    ``control`` None (`rtcal view`) makes the view read-only: its control endpoints answer 409.
    """

    def __init__(self, run_dir: Path, host: str = LOOPBACK, port: int = DEFAULT_PORT,
                 control: Controllable | None = None, token: str | None = None, poll_s: float = 0.5):
        if control is not None and not token:
            raise ValueError("a live view with control needs the run's control token")
        self.run_dir = Path(run_dir)
        self.host = host
        self.port = port
        self.control = control
        self._token = token
        self.poll_s = poll_s
        self.view = StoreView(self.run_dir)
        self._feed = _Feed(self.view, poll_s, lambda: self.control is not None)
        self._server: uvicorn.Server | None = None
        self._thread: threading.Thread | None = None
        self._sock: socket.socket | None = None
        self._stopping = threading.Event()
        self._finishing = threading.Event()  # the run has ended: each stream ends once it has sent the final state
        self._slots: Slots | None = None  # counts the event streams being served
        self._control_limiter: anyio.CapacityLimiter | None = None
        self.url: str | None = None

    # -- the application ----------------------------------------------------------------------
    def app(self) -> Slots:
        """The page's routes behind the Host check, counted by :class:`~rtcal.live.web.Slots`
        (event streams apart; a request with the token never waits behind others)."""
        routes = [
            Route("/", self._index),
            Route("/static/{name}", self._static),
            Route("/api/state", self._state),
            Route(EVENTS_PATH, self._events),
            Route("/api/{command}", self._control, methods=["POST"]),
            Route("/files/{name}", self._file),
        ]
        self._slots = Slots(Starlette(routes=routes, middleware=[host_guard(self.host)]), stream_paths=[EVENTS_PATH])
        return self._slots

    def _streams(self) -> int:
        if self._slots is None:
            return 0
        with self._slots.lock:
            return self._slots.busy["stream"]

    async def _index(self, request: Request) -> Response:
        return Response(_asset("index.html"), media_type=STATIC_FILES["index.html"], headers=SECURITY_HEADERS)

    async def _static(self, request: Request) -> Response:
        name = request.path_params["name"]
        if name not in STATIC_FILES or name == "index.html":
            return _json({"error": "not found"}, 404)
        return Response(_asset(name), media_type=STATIC_FILES[name], headers=SECURITY_HEADERS)

    def _state_now(self) -> dict[str, Any]:
        return {**self.view.state(), "control": self.control is not None}

    async def _state(self, request: Request) -> Response:
        return _json(await anyio.to_thread.run_sync(self._state_now))

    async def _events(self, request: Request) -> Response:
        after = _last_event_id(request)
        return StreamingResponse(self._stream(request, after), media_type="text/event-stream",
                                 headers={**SECURITY_HEADERS, "X-Accel-Buffering": "no"})

    async def _stream(self, request: Request, after: int) -> AsyncIterator[str]:
        """Readings after ``after`` (each with its store id), the events table, and the state
        whenever it changes; a comment every 15 s keeps proxies from closing a quiet stream.
        Every viewer takes the same encoded events from one shared :class:`_Feed`; one that is
        further behind than the feed keeps reads its own way up from the store first. Once the run
        has ended (:meth:`stop` with a linger) the stream ends with the run's final state."""
        yield "retry: 2000\n\n"
        feed = self._feed
        last_event = 0
        last_state: str | None = None
        quiet_since = time.monotonic()
        while not self._stopping.is_set():
            await anyio.to_thread.run_sync(feed.refresh)
            parts = feed.readings_since(after)
            if parts is None:  # behind the feed's window: catch up from the store in batches
                rows = await anyio.to_thread.run_sync(self.view.readings_after, after, CATCH_UP_BATCH)
                parts = [(r["id"], _sse("reading", r, r["id"])) for r in rows]
            if parts:
                after = parts[-1][0]
            events = feed.events_since(last_event)
            if events:
                last_event = events[-1][0]
            chunk = "".join(text for _, text in parts) + "".join(text for _, text in events)
            with feed._lock:
                state, final = feed.state_text, feed.final
            if state is not None and state != last_state:
                chunk += f"event: state\ndata: {state}\n\n"
                last_state = state
            if chunk:
                quiet_since = time.monotonic()
                yield chunk
            elif time.monotonic() - quiet_since > 15:
                quiet_since = time.monotonic()
                yield ": still here\n\n"
            if self._finishing.is_set() and final and len(parts) < CATCH_UP_BATCH:
                return  # the run's end was sent: the page keeps it, nothing follows
            if len(parts) < CATCH_UP_BATCH:
                await anyio.sleep(self.poll_s)

    async def _control(self, request: Request) -> Response:
        command = request.path_params["command"]
        if command not in COMMANDS:
            return _json({"error": f"no such command: one of {', '.join(COMMANDS)}"}, 404)
        if self.control is None:
            return _json({"error": "read-only view: `rtcal view` serves no control; use the run's own --live page "
                                   "or `rtcal control`"}, 409)
        scheme, _, given = request.headers.get("authorization", "").partition(" ")
        if scheme.lower() != "bearer" or not token_matches(given.strip(), self._token or ""):
            return _json({"error": "the run's control token is needed (Authorization: Bearer TOKEN)"}, 401,
                         {"WWW-Authenticate": 'Bearer realm="rtcal"'})
        try:  # a confirm names the wait it answers (?step=N, the page sends the one it shows)
            step = step_of(int(request.query_params["step"])) if "step" in request.query_params else None
        except ValueError:
            return _json({"error": "step: an operator step is a number from 1"}, 400)
        if self._control_limiter is None:  # threads of its own: never queued behind the streams' reads
            self._control_limiter = anyio.CapacityLimiter(2)
        try:
            await anyio.to_thread.run_sync(dispatch, self.control, command, step, limiter=self._control_limiter)
        except NothingToConfirm as exc:  # pressed twice, a second tablet's, or a step answered already: nothing changed
            return _json({"error": f"{exc} (nothing was changed)"}, 409)
        except Exception as exc:  # the engine refused (e.g. already finished): nothing changed
            return _json({"error": f"the engine could not {command}: {exc}"[:300]}, 409)
        return _json({"accepted": command}, 202)

    async def _file(self, request: Request) -> Response:
        name = request.path_params["name"]
        path = self.run_dir / name
        if name not in REPORT_FILES or path.is_symlink() or not path.is_file():
            return _json({"error": "not found"}, 404)
        return FileResponse(path, headers=REPORT_HEADERS)

    # -- serving ----------------------------------------------------------------------------
    def start(self) -> str:
        """Bind (OSError if the port is taken), serve in a background thread and return the URL
        with the real port. A host other than loopback gets a warning on stderr."""
        warn_exposed(self.host, "live view", "the run (control still needs the token, sent unencrypted)")
        sock = bind(self.host, self.port)
        self._server, self._thread = serve(self.app(), sock, "rtcal-live", stream_paths=[EVENTS_PATH])
        self._sock = sock
        threading.Thread(target=self.view.state, name="rtcal-live-warm", daemon=True).start()  # first reads import the methods
        self.port = sock.getsockname()[1]
        self.url = url_of(self.host, sock)
        return self.url

    def stop(self, linger_s: float = 0.0) -> None:
        """End every stream and shut the server down (within a few seconds). ``linger_s``: the run
        has ended; serve its final state (and the result) that long at most, until every open
        stream has sent it, so no page is left showing a run still running."""
        if linger_s > 0 and self._thread is not None and self._thread.is_alive():
            self.view.finish()
            self._feed.refresh(now=True)
            self._finishing.set()
            deadline = time.monotonic() + linger_s
            while time.monotonic() < deadline and self._streams() > 0:
                time.sleep(0.05)
        self._stopping.set()
        if self._server is not None:
            self._server.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        self._server = None

    def __enter__(self) -> "LiveServer":
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def serve_view(run_dir: Path, host: str = LOOPBACK, port: int | None = None) -> int:
    """`rtcal view`: serve a run directory read-only until interrupted; returns the exit code.
    ``port`` None: 8765, or any free port if that one is taken."""
    server = LiveServer(run_dir, host, DEFAULT_PORT if port is None else port)
    try:
        url = server.start()
    except OSError:
        if port is not None:
            raise
        server = LiveServer(run_dir, host, 0)
        url = server.start()
    print(f"live view: {url}", file=sys.stderr, flush=True)
    try:
        while server._thread is not None and server._thread.is_alive():
            time.sleep(0.5)
    except KeyboardInterrupt:
        return 0
    finally:
        server.stop()
    return 1  # the server ended by itself
