"""Every way a process is told to end reaches the engine as Ctrl-C does: an exception in its thread.

A signal whose default action ends the process (SIGHUP when an SSH session closes, SIGQUIT,
SIGTERM, SIGINT, …) would otherwise kill a run mid-move: no STOP to the drive, no AbortE to a
CMM in a GoTo, no message, the status left ``running``. While :func:`routed` is active, each
such signal raises :class:`Interrupted` (a KeyboardInterrupt) in the main thread, which takes
the engine's one safe-state path. A remote abort (`rtcal control`, the live page) arrives the
same way: :func:`interrupt` from the control thread wakes the main thread with WAKE_SIGNAL,
so a blocking call — a drive polled until in position, an I++ GoTo waiting for its ``%`` — is
cut at once, as by Ctrl-C, instead of at the next step.

The first interruption is raised once; what comes after it (a second Ctrl-C, SIGHUP then
SIGTERM) is swallowed until the run has ended, so nothing cuts the stop short. Inside
:func:`held` (the safe stop, a commit to the store) an interruption waits until the section ends.
Only the main thread can take signals: an engine run in another thread is stopped between steps.
A signal someone else handles is left to them, and one ignored at start (``nohup`` ignores
SIGHUP) stays ignored: the user asked the run to outlive it.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from types import FrameType
from typing import Any, Iterator

# asynchronous signals whose default action ends the process (signal(7)); the synchronous ones a
# program raises against itself (SIGSEGV, SIGBUS, SIGFPE, SIGILL, SIGABRT, SIGTRAP, SIGSYS) cannot be
# ridden out in Python, and SIGKILL cannot be caught (`rtcal resume` is the answer to both)
ENDING_NAMES = ("SIGHUP", "SIGINT", "SIGQUIT", "SIGTERM", "SIGUSR1", "SIGUSR2", "SIGALRM", "SIGVTALRM", "SIGPROF",
                "SIGIO", "SIGPWR", "SIGXCPU", "SIGXFSZ", "SIGSTKFLT")
# ignored by default: a stray one wakes nothing, it only carries a pending abort (None: no POSIX signals here)
WAKE_SIGNAL: int | None = getattr(signal, "SIGURG", None) if hasattr(signal, "pthread_kill") else None


def ending_signals() -> dict[int, str]:
    """This platform's ending signals (number → name), real-time ones included."""
    out = {int(getattr(signal, n)): n for n in ENDING_NAMES if hasattr(signal, n)}
    if hasattr(signal, "SIGRTMIN"):
        out.update({n: f"SIGRTMIN+{n - signal.SIGRTMIN}" for n in range(signal.SIGRTMIN, signal.SIGRTMAX + 1)})
    return out


class Interrupted(KeyboardInterrupt):
    """The process was told to end by a signal: the run stops as Ctrl-C stops it (safe state,
    status recorded, exit 130, resumable). ``by`` names the signal."""

    def __init__(self, by: str):
        super().__init__(f"interrupted by {by}")
        self.by = by


class _Router:
    """The process's one router (main thread only): who installed it, what is pending, what was raised."""

    def __init__(self) -> None:
        self.lock = threading.RLock()  # a handler runs in the main thread, maybe inside its own `with lock`
        self.depth = 0
        self.previous: dict[int, Any] = {}
        self.names: dict[int, str] = {}
        self.pending: KeyboardInterrupt | None = None
        self.raised = False
        self.held = 0

    def on_signal(self, signum: int, frame: FrameType | None) -> None:
        if signum != WAKE_SIGNAL:
            name = self.names.get(signum, f"signal {signum}")
            self.request(Interrupted(f"{name} (Ctrl-C)" if name == "SIGINT" else name))
        self.deliver()

    def request(self, exc: KeyboardInterrupt) -> None:
        with self.lock:
            if self.pending is None and not self.raised:
                self.pending = exc

    def deliver(self) -> None:
        """Raise what is pending, once, outside a held section (main thread)."""
        with self.lock:
            if self.pending is None or self.raised or self.held:
                return
            exc, self.pending, self.raised = self.pending, None, True
        raise exc


_ROUTER = _Router()


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextmanager
def routed() -> Iterator[bool]:
    """Route every ending signal (and a remote abort) into the main thread as an exception while
    the block runs; nested uses share one installation. Yields whether it is active (main thread)."""
    if not _in_main_thread():
        yield False
        return
    router = _ROUTER
    if router.depth == 0:
        router.names = ending_signals()
        for signum in [*router.names, *([WAKE_SIGNAL] if WAKE_SIGNAL is not None else [])]:
            try:
                current = signal.getsignal(signum)
            except (OSError, ValueError):
                continue
            ours = current in (signal.SIG_DFL, signal.default_int_handler) or signum == WAKE_SIGNAL
            if not ours:  # ignored (nohup), or handled by someone else (a test's timeout): theirs
                continue
            try:
                router.previous[signum] = signal.signal(signum, router.on_signal)
            except (OSError, ValueError):  # one this kernel will not let us handle
                continue
    router.depth += 1
    try:
        yield True
    finally:
        router.depth -= 1
        if router.depth == 0:
            for signum, handler in router.previous.items():
                signal.signal(signum, handler)
            router.previous.clear()
            with router.lock:
                router.pending, router.raised, router.held = None, False, 0


def interrupt(exc: KeyboardInterrupt, thread: threading.Thread | None = None) -> bool:
    """From any thread: raise ``exc`` in the main thread at once (or when its held section ends).
    False when nothing is routed (the main thread is not in :func:`routed`, or ``thread`` — the one
    to interrupt — is not the main thread): the caller's flag is then all there is."""
    router = _ROUTER
    if router.depth == 0 or (thread is not None and thread is not threading.main_thread()):
        return False
    router.request(exc)
    if _in_main_thread():
        router.deliver()
    else:
        main = threading.main_thread().ident
        if main is not None and WAKE_SIGNAL is not None:
            signal.pthread_kill(main, WAKE_SIGNAL)
    return True


def taken() -> None:
    """The main thread raised the interruption itself (it found the flag first): deliver nothing more."""
    if _in_main_thread() and _ROUTER.depth:
        with _ROUTER.lock:
            _ROUTER.pending, _ROUTER.raised = None, True


@contextmanager
def held() -> Iterator[None]:
    """A section no interruption cuts (the safe stop, a commit): one that arrives meanwhile is
    raised when it ends — unless an exception already leaves it."""
    if not _in_main_thread() or _ROUTER.depth == 0:
        yield
        return
    entered = False  # a signal may come between any two bytecodes: count only what was counted
    try:
        with _ROUTER.lock:
            _ROUTER.held += 1
            entered = True
        yield
    finally:
        if entered:
            with _ROUTER.lock:
                _ROUTER.held -= 1
    _ROUTER.deliver()
