"""Remote control of a running engine: an owner-only Unix-domain socket in the run directory.

The engine (a :class:`Controllable`) serves ``RUN_DIR/.rtcal-control.sock`` through a
:class:`ControlServer`; `rtcal control` and the live view's buttons reach it with the run's
control token. A socket file rather than a TCP port: it needs no free port, it is found from the
run directory alone, and the file mode (0600) keeps other users out before the token is even
read. The token itself is compared in constant time and never written to any file or log.
A run without ``--live`` has no token (none is printed: nothing but the socket can reach it): its
server admits a request only from a process of its own user (the peer's credentials, SO_PEERCRED,
where the system gives them; elsewhere the 0600 socket alone), and any token sent is ignored.

Protocol: one JSON line per connection, ``{"token": "...", "command": "pause"|"resume"|"abort"|"confirm"}``,
answered by one JSON line, ``{"ok": true}`` or ``{"ok": false, "error": "token"|"command"|"request"|"nothing"|"failed"}``
("nothing": a confirm when no operator step waits; nothing changed; "failed" comes with the engine's
``message``, e.g. an abort once the run has finished measuring).
"""

from __future__ import annotations

import hmac
import json
import os
import secrets
import socket
import stat
import struct
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Protocol, runtime_checkable

from rtcal.engine.operator import NothingToConfirm

SOCKET_NAME = ".rtcal-control.sock"
COMMANDS = ("pause", "resume", "abort", "confirm")
MAX_LINE_BYTES = 4096  # a request is ~100 bytes; anything longer is refused unread
CONNECTION_TIMEOUT_S = 2.0  # a client that sends nothing cannot hold the server
TOKEN_ENV = "RTCAL_CONTROL_TOKEN"
BY_CONTROL = "`rtcal control`"  # who sent a request through the socket (the live page's are its own)
_SUN_PATH_MAX = 100  # sockaddr_un holds 108 bytes with its NUL; longer paths go through /proc/self/fd


def new_token() -> str:
    """A control token: 192 random bits, URL-safe (printed once by the run, written nowhere). It never
    starts with "-", which `rtcal control --token` would take for an option."""
    while True:
        token = secrets.token_urlsafe(24)
        if not token.startswith("-"):
            return token


@runtime_checkable
class Controllable(Protocol):
    """What the engine offers to remote control; each request takes effect at its next checkpoint."""

    def request_pause(self) -> None: ...

    def request_resume(self) -> None: ...

    def request_abort(self, by: str = "a remote request") -> None:
        """Stop the run at once, as Ctrl-C does; ``by`` (the live page, `rtcal control`) is recorded."""

    def request_confirm(self, step: int | None = None) -> None:
        """Confirm the operator step that waits (only wait ``step`` when given); NothingToConfirm if none does."""


class NoEngine(Exception):
    """No engine serves this run directory (no socket, connection refused, a stale socket): exit 1."""


class ControlRefused(Exception):
    """The engine answered but refused: ``reason`` is "token", "command", "request" or "failed"."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


def socket_path(run_dir: Path) -> Path:
    return Path(run_dir) / SOCKET_NAME


def token_matches(given: object, token: str) -> bool:
    """Constant-time comparison; anything but a string is a mismatch."""
    return isinstance(given, str) and hmac.compare_digest(given.encode("utf-8", "surrogatepass"), token.encode("utf-8"))


def dispatch(target: Controllable, command: str, step: int | None = None, by: str = "the live page") -> None:
    """Hand ``command`` (one of COMMANDS) to the engine; a confirm names the wait it answers (``step``),
    an abort who sent it (``by``: the live page, or `rtcal control` through the socket)."""
    if command not in COMMANDS:
        raise ValueError(f"unknown command {command!r}")
    if command == "confirm":
        target.request_confirm(step)
    elif command == "abort":
        target.request_abort(by)
    else:
        getattr(target, f"request_{command}")()


def step_of(value: object) -> int | None:
    """A confirm's operator step: None (whichever waits) or a positive int; ValueError otherwise."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"an operator step is a number from 1, not {str(value)[:20]!r}")
    return value


def _valid_step(value: object) -> bool:
    try:
        step_of(value)
    except ValueError:
        return False
    return True


@contextmanager
def _bindable(path: Path) -> Iterator[str]:
    """An address for ``path`` short enough for sockaddr_un: the path itself, or (Linux) the path
    through an open descriptor of its directory, so a deep run directory still gets its socket."""
    if len(os.fsencode(str(path))) <= _SUN_PATH_MAX:
        yield str(path)
        return
    fd = os.open(path.parent, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        yield f"/proc/self/fd/{fd}/{path.name}"
    finally:
        os.close(fd)


def _connect(path: Path, timeout_s: float) -> socket.socket:
    """A connection to the engine's socket, or NoEngine saying why there is none."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        raise NoEngine(f"no engine runs for {path.parent} (no control socket)") from None
    if not stat.S_ISSOCK(st.st_mode):
        raise NoEngine(f"no engine runs for {path.parent} ({path.name} is not a socket)")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(timeout_s)
    try:
        with _bindable(path) as address:
            sock.connect(address)
    except (ConnectionRefusedError, FileNotFoundError):
        sock.close()
        raise NoEngine(f"no engine runs for {path.parent} (a stale control socket: the run has ended)") from None
    except OSError as exc:
        sock.close()
        raise NoEngine(f"no engine runs for {path.parent} (cannot connect to its control socket: "
                       f"{exc.strerror or exc})") from None
    return sock


def _read_line(sock: socket.socket) -> bytes | None:
    """One line of at most MAX_LINE_BYTES (without its newline); None if longer or cut short."""
    data = b""
    while b"\n" not in data:
        chunk = sock.recv(MAX_LINE_BYTES + 1 - len(data))
        if not chunk:
            return None
        data += chunk
        if len(data) > MAX_LINE_BYTES and b"\n" not in data:
            return None
    return data.split(b"\n", 1)[0]


def send_control(run_dir: Path, token: str, command: str, timeout_s: float = 5, step: int | None = None) -> None:
    """Ask the engine of ``run_dir`` to pause, resume, abort or confirm. Returns when it accepted; raises
    ValueError for an unknown command, NoEngine when no engine runs for the directory (or it did
    not answer), ControlRefused when it refused (a wrong token, above all)."""
    if command not in COMMANDS:
        raise ValueError(f"unknown command {command!r}: one of {', '.join(COMMANDS)}")
    with _connect(socket_path(Path(run_dir)), timeout_s) as sock:
        try:
            request = {"token": token, "command": command, **({"step": step} if step is not None else {})}
            sock.sendall(json.dumps(request).encode() + b"\n")
            line = _read_line(sock)
        except (socket.timeout, ConnectionError) as exc:
            raise NoEngine(f"the engine of {run_dir} did not answer ({exc.__class__.__name__})") from None
    if line is None:
        raise NoEngine(f"the engine of {run_dir} closed the connection without an answer")
    try:
        reply = json.loads(line)
    except ValueError:
        raise NoEngine(f"the control socket of {run_dir} answered something that is not rtcal's") from None
    if not isinstance(reply, dict) or reply.get("ok") is not True:
        reason = str(reply.get("error", "request")) if isinstance(reply, dict) else "request"
        messages = {"token": "the engine refused the control token", "command": f"the engine does not know `{command}`",
                    "nothing": "nothing to confirm: " + ("no operator step waits now" if step is None else
                                                         f"operator step {step} does not wait now") + " (nothing was changed)",
                    "failed": f"the engine could not {command}" + (f": {reply['message']}" if isinstance(reply, dict)
                                                                   and isinstance(reply.get("message"), str) else "")}
        raise ControlRefused(reason, messages.get(reason, "the engine refused the request"))


def _peer_is_owner(conn: socket.socket) -> bool:
    """A tokenless server's check: the connecting process runs as this one's user (Linux's
    SO_PEERCRED; where the system has no such option, the socket's 0600 mode already ensured it)."""
    option = getattr(socket, "SO_PEERCRED", None)
    if option is None:
        return True
    _pid, uid, _gid = struct.unpack("3i", conn.getsockopt(socket.SOL_SOCKET, option, struct.calcsize("3i")))
    return uid == os.geteuid()


class ControlServer:
    """Serves the engine's control socket in a thread: one request per connection, checked
    against the token, handed to ``target``. :meth:`close` stops it and removes the socket."""

    def __init__(self, run_dir: Path, token: str | None, target: Controllable):
        if token is not None and len(token) < 16:
            raise ValueError("a control token needs at least 128 random bits (use new_token())")
        self.run_dir = Path(run_dir)
        self.path = socket_path(self.run_dir)
        self._token = token
        self._target = target
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._inode: tuple[int, int] | None = None

    def start(self) -> None:
        """Bind the socket owner-only (0600) and serve it. A stale socket left by a killed run is
        replaced; a live one (another engine on this directory) is a RuntimeError."""
        self._clear_stale()
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o177)  # created 0600: no moment when another user could connect
        try:
            with _bindable(self.path) as address:
                sock.bind(address)
        except BaseException:
            sock.close()
            raise
        finally:
            os.umask(old)
        st = os.lstat(self.path)
        if stat.S_IMODE(st.st_mode) & 0o077:  # a filesystem that ignored the umask
            os.chmod(self.path, 0o600)
        self._inode = (st.st_dev, st.st_ino)
        sock.listen(8)
        sock.settimeout(0.2)  # the accept loop looks at the stop flag five times a second
        self._sock = sock
        self._thread = threading.Thread(target=self._serve, name="rtcal-control", daemon=True)
        self._thread.start()

    def _clear_stale(self) -> None:
        try:
            st = os.lstat(self.path)
        except FileNotFoundError:
            return
        if not stat.S_ISSOCK(st.st_mode):
            raise RuntimeError(f"{self.path} exists and is not a socket; rtcal leaves it as it is: move it away")
        try:
            _connect(self.path, 1.0).close()
        except NoEngine:
            os.unlink(self.path)
            return
        raise RuntimeError(f"another engine serves {self.path}")

    def _serve(self) -> None:
        assert self._sock is not None
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except socket.timeout:
                continue
            except OSError:
                break  # closed
            with conn:
                try:
                    self._answer(conn)
                except OSError:
                    pass  # the client went away: nothing to answer

    def _answer(self, conn: socket.socket) -> None:
        conn.settimeout(CONNECTION_TIMEOUT_S)
        try:
            line = _read_line(conn)
        except socket.timeout:
            line = None
        reply: dict[str, object]
        try:
            request = json.loads(line) if line is not None else None
        except ValueError:
            request = None
        if not isinstance(request, dict):
            reply = {"ok": False, "error": "request"}
        elif not (token_matches(request.get("token"), self._token) if self._token is not None else _peer_is_owner(conn)):
            reply = {"ok": False, "error": "token"}
        elif request.get("command") not in COMMANDS:
            reply = {"ok": False, "error": "command"}
        elif not _valid_step(request.get("step")):
            reply = {"ok": False, "error": "request"}
        else:
            try:
                dispatch(self._target, str(request["command"]), step_of(request.get("step")), by=BY_CONTROL)
                reply = {"ok": True}
            except NothingToConfirm:
                reply = {"ok": False, "error": "nothing"}
            except Exception as exc:  # the engine refused (e.g. finished measuring): the run goes on as it was
                reply = {"ok": False, "error": "failed", "message": str(exc)[:200]}
        conn.sendall(json.dumps(reply).encode() + b"\n")

    def close(self) -> None:
        """Stop serving and remove the socket (only the one this server bound)."""
        self._stop.set()
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        try:
            st = os.lstat(self.path)
            if self._inode == (st.st_dev, st.st_ino):
                os.unlink(self.path)
        except FileNotFoundError:
            pass
        self._inode = None

    def __enter__(self) -> "ControlServer":
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
