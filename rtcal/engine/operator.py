"""Operator steps: what a person must do mid-run (re-seat the polygon, move the tracer). On hardware the
engine pauses with a prompt; on the simulated bench the bench does it itself.

On hardware the person confirms at the run's terminal (Enter) or, with :class:`WaitingOperator`,
also from elsewhere: the live page's Done button or `rtcal control RUN_DIR confirm` reach the
engine's control channel, which hands the confirm to the operator object — the one thing that waits.
"""

from __future__ import annotations

import math
import os
import select
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Protocol, TextIO, runtime_checkable

from drivers.addresses import redact_tokens
from drivers.errors import InstrumentError

if TYPE_CHECKING:
    from simulators.bench import Bench


class OperatorUnavailable(InstrumentError):
    """The run needs a person (or the simulated operator) and none answers: the run stops safely."""

    def __init__(self, message: str):
        super().__init__("operator", message)


class Operator(Protocol):
    def reseat_polygon(self, offset_deg: float, face_pitch_deg: float, resumed: bool = False) -> None: ...

    def move_tracer(self, mount: int, where: str, resumed: bool = False) -> None:
        """Move the laser tracer to mount ``mount`` (0: the first) on the table."""

    def polygon_certificate_arcsec(self) -> list[float] | None:
        """A simulated polygon's certificate (the operator hands it over); None on hardware."""

    def clear_fault(self, message: str) -> None:
        """The run pauses: the operator clears the fault (releases an e-stop, frees the beam)."""


def reseat_instruction(offset_deg: float, face_pitch_deg: float, resumed: bool = False) -> str:
    """What the person is asked before a polygon seating (the console and the live page say the same)."""
    faces = offset_deg / face_pitch_deg
    whole = abs(faces - round(faces)) < 1e-9
    what = (f"{round(faces):d} {'face' if abs(round(faces)) == 1 else 'faces'}" if whole else f"{offset_deg:g}°")
    home = whole and round(faces) == 0  # not "turned by 0 faces": the home seating itself
    seated = "in its home seating" if home else f"seated turned by {what}"
    if resumed:
        return (f"The run resumes with the polygon {seated}. Do not move it; "
                "if it was moved, abort and start the seating again.")
    where = f"{offset_deg:g}° + k·{face_pitch_deg:g}°" if not home else f"k·{face_pitch_deg:g}°"
    return (f"Seat the polygon {'in its home seating' if home else f'turned by {what} from its home seating'} "
            f"(faces in front of the autocollimator at table angles {where}), "
            "and align it to the autocollimator within its range.")


def tracer_instruction(mount: int, where: str, resumed: bool = False) -> str:
    """What the person is asked before the laser tracer's mount ``mount`` (0: the first)."""
    if resumed:
        return f"The run resumes with the laser tracer on mount {mount + 1}. Do not move it."
    return (f"Move the laser tracer to mount {mount + 1} ({where}), at the same height as before, and fix it "
            "(rtcal then re-references the beam).")


def fault_instruction(message: str) -> str:
    """What the person is asked when a fault's policy pauses the run for them."""
    # shown on the console and the page: a driver's message may hold an address with its token
    return f"Clear the fault ({redact_tokens(message)}): release the emergency stop, free the beam; the run then tries again."


class ConsoleOperator:
    """Prints what to do and waits for Enter; refuses to continue without a terminal."""

    def __init__(self, ask: Callable[[str], str] = input):
        self._ask = ask

    def reseat_polygon(self, offset_deg: float, face_pitch_deg: float, resumed: bool = False) -> None:
        message = "\nOperator: " + reseat_instruction(offset_deg, face_pitch_deg, resumed) + " Then press Enter."
        if not sys.stdin.isatty() and self._ask is input:
            raise OperatorUnavailable(NO_TERMINAL_RESEAT)
        self._ask(message + " ")

    def move_tracer(self, mount: int, where: str, resumed: bool = False) -> None:
        message = "\nOperator: " + tracer_instruction(mount, where, resumed) + " Then press Enter."
        if not sys.stdin.isatty() and self._ask is input:
            raise OperatorUnavailable(NO_TERMINAL_TRACER)
        self._ask(message + " ")

    def polygon_certificate_arcsec(self) -> list[float] | None:
        return None

    def clear_fault(self, message: str) -> None:
        if not sys.stdin.isatty() and self._ask is input:
            raise OperatorUnavailable(no_terminal_fault(message))
        self._ask(f"\nOperator: {message}. Clear the fault, then press Enter to try again. ")


NO_TERMINAL_RESEAT = ("the procedure needs an operator to re-seat the polygon but there is no terminal; "
                      "run it from a terminal")
NO_TERMINAL_TRACER = ("the procedure needs an operator to move the laser tracer but there is no terminal; "
                      "run it from a terminal")


def no_terminal_fault(message: str) -> str:
    return f"the run paused for the operator ({message}) but there is no terminal"


class OperatorCancelled(KeyboardInterrupt):
    """A remote abort while the run waited for the operator: the run stops as Ctrl-C stops it
    (the safe state, the status recorded, exit 130, resumable)."""


class NothingToConfirm(RuntimeError):
    """A confirm sent when no operator step waits: refused, and nothing changes."""


Asked = Callable[[str | None, str], None]
"""``asked(instruction, answer)``: the instruction while the operator is asked (answer ""), then
``asked(None, answer)`` once it is over (answer: "at the terminal", "remotely", or "" if it was not
answered: an abort, Ctrl-C)."""


@runtime_checkable
class Confirmable(Protocol):
    """An operator whose steps can be confirmed from another thread (the engine's control channel)."""

    def confirm(self, step: int | None = None) -> bool:
        """Confirm what the operator is asked now (``step``: only if it is that wait): True; False if
        nothing (or another wait) waits — nothing changes."""

    def cancel(self) -> None:
        """A remote abort: what waits (or will wait) raises OperatorCancelled."""

    def listen(self, asked: Asked) -> None:
        """Tell ``asked`` what the person is asked and when it is over (in the waiting thread)."""


def stdin_terminal() -> int | None:
    """The descriptor of this process's terminal, None without one (nohup, a service, a pipe)."""
    try:
        return sys.stdin.fileno() if sys.stdin is not None and sys.stdin.isatty() else None
    except (ValueError, OSError):  # stdin closed or replaced by something without a descriptor
        return None


class WaitingOperator:
    """The console operator whose every step can also be confirmed remotely: Enter at the terminal
    or a remote :meth:`confirm` (the live page's Done, `rtcal control RUN_DIR confirm`), whichever
    comes first, continues the run. Without a terminal it waits for a remote confirm when the run
    can be reached (``remote``: it serves its live page), and otherwise refuses as
    :class:`ConsoleOperator` does (OperatorUnavailable, the same message). :meth:`cancel` (a remote
    abort) ends the wait with OperatorCancelled. The terminal is read by ``select`` on its
    descriptor in the waiting thread itself, so no reader is left blocked on stdin afterwards."""

    def __init__(self, remote: bool = False, run_dir: Path | str | None = None,
                 terminal: Callable[[], int | None] = stdin_terminal, out: TextIO | None = None,
                 log: TextIO | None = None, poll_s: float = 0.2):
        self.remote = remote
        self.run_dir = run_dir
        self._terminal = terminal
        self._out = out
        self._log = log
        self.poll_s = poll_s
        self._lock = threading.Lock()
        self._waiting: threading.Event | None = None
        self._cancelled = threading.Event()
        self._listeners: list[Asked] = []
        self.asking: str | None = None
        """The instruction the person is asked now (None: nothing waits)."""
        self.step = 0
        """The number of the current (or last) wait, from 1: a confirm naming another one is refused."""

    # ---- from other threads ------------------------------------------------------------------
    def confirm(self, step: int | None = None) -> bool:
        """Confirm the wait ``step`` (None: whichever waits now); False if it does not wait (nothing
        changes): a late Done meant for a step already confirmed at the terminal never releases the next."""
        with self._lock:
            if self._waiting is None or self._waiting.is_set() or (step is not None and step != self.step):
                return False
            self._waiting.set()
            return True

    def cancel(self) -> None:
        self._cancelled.set()
        with self._lock:
            if self._waiting is not None:
                self._waiting.set()  # wake it: it finds the cancel before it counts a confirm

    def listen(self, asked: Asked) -> None:
        self._listeners.append(asked)

    # ---- the operator's steps (the engine's thread) -------------------------------------------
    def reseat_polygon(self, offset_deg: float, face_pitch_deg: float, resumed: bool = False) -> None:
        self._wait(reseat_instruction(offset_deg, face_pitch_deg, resumed), NO_TERMINAL_RESEAT)

    def move_tracer(self, mount: int, where: str, resumed: bool = False) -> None:
        self._wait(tracer_instruction(mount, where, resumed), NO_TERMINAL_TRACER)

    def polygon_certificate_arcsec(self) -> list[float] | None:
        return None

    def clear_fault(self, message: str) -> None:
        self._wait(fault_instruction(message), no_terminal_fault(message))

    def _wait(self, instruction: str, unavailable: str) -> None:
        fd = self._terminal()
        if fd is None and not self.remote:
            raise OperatorUnavailable(unavailable)
        if self._cancelled.is_set():
            raise OperatorCancelled("aborted by a remote request")
        confirmed = threading.Event()
        with self._lock:
            self.step += 1
            self._waiting = confirmed
        self.asking = instruction
        answer = ""
        try:
            self._tell(instruction, "")
            remote_hint = self._remote_hint()
            if fd is not None:
                _drain(fd)  # an Enter pressed before the instruction was shown confirms nothing
                out = self._out if self._out is not None else sys.stdout
                out.write(f"\nOperator: {instruction} Then press Enter" + (f" (or {remote_hint})" if remote_hint else "")
                          + ". ")
                out.flush()
            else:
                log = self._log if self._log is not None else sys.stderr
                log.write(f"rtcal: operator: {instruction} Waiting for {remote_hint}.\n")
                log.flush()
            answer = self._until_confirmed(confirmed, fd, unavailable)
        finally:
            with self._lock:
                self._waiting = None
            self.asking = None
            self._tell(None, answer)

    def _remote_hint(self) -> str:
        where = f"`rtcal control {self.run_dir if self.run_dir is not None else 'RUN_DIR'} confirm --step {self.step}`"
        return ("Done on the live page, or " + where + " with the run's control token" if self.remote
                else where + " (from your user: without --live the run has no token)")

    def _until_confirmed(self, confirmed: threading.Event, fd: int | None, unavailable: str) -> str:
        while True:
            if self._cancelled.is_set():
                raise OperatorCancelled("aborted by a remote request while the operator was asked")
            if confirmed.is_set():
                return "remotely"
            if fd is None:
                confirmed.wait(self.poll_s)
                continue
            ready, _, _ = select.select([fd], [], [], self.poll_s)
            if not ready:
                continue
            data = os.read(fd, 4096)
            if not data:  # the terminal went away (a closed ssh session)
                fd = None
                if not self.remote:
                    raise OperatorUnavailable(unavailable.replace("there is no terminal", "the terminal closed"))
                continue
            if b"\n" in data or b"\r" in data:
                with self._lock:
                    if confirmed.is_set():  # a remote confirm came first
                        continue
                    confirmed.set()
                if self._cancelled.is_set():
                    continue
                return "at the terminal"

    def _tell(self, instruction: str | None, answer: str) -> None:
        for asked in self._listeners:
            asked(instruction, answer)


def _drain(fd: int) -> None:
    """Discard what was typed before the prompt."""
    while select.select([fd], [], [], 0)[0]:
        if not os.read(fd, 4096):
            return


class BenchOperator:
    """The simulated bench re-seats its own polygon."""

    def __init__(self, bench: Bench) -> None:
        self.bench = bench

    def reseat_polygon(self, offset_deg: float, face_pitch_deg: float, resumed: bool = False) -> None:
        self.bench.reseat_polygon(offset_deg)  # deterministic per seating: a resume finds it as it was

    def move_tracer(self, mount: int, where: str, resumed: bool = False) -> None:
        self.bench.mount_tracer(mount)

    def polygon_certificate_arcsec(self) -> list[float] | None:
        return [float(v) for v in self.bench.face_certificate_arcsec]

    def clear_fault(self, message: str) -> None:
        self.bench.emergency_stop = False


class RemoteSimOperator:
    """The simulated operator of a protocol-simulator hub (``sim-operator://HOST:PORT?token=…``):
    each request carries the token the hub printed, so only the run it serves is let in."""

    def __init__(self, address: str, timeout_s: float = 5.0):
        from drivers.addresses import parse_address

        a = parse_address(address)
        self.where = (a.host, a.port)
        self.token = a.text("token")
        self.timeout_s = timeout_s

    def _ask(self, line: str) -> str:
        import socket

        try:
            with socket.create_connection(self.where, timeout=self.timeout_s) as s:
                s.sendall(f"AUTH {self.token or '-'} {line}\n".encode())
                return s.makefile("rb").readline(64 * 1024).decode(errors="replace").strip()
        except OSError as exc:
            raise OperatorUnavailable(f"the simulated operator at {self.where[0]}:{self.where[1]} does not answer "
                                      f"({exc}); is `rtcal sim serve` still running?") from None

    def reseat_polygon(self, offset_deg: float, face_pitch_deg: float, resumed: bool = False) -> None:
        reply = self._ask(f"RESEAT {offset_deg!r}")
        if reply != "OK":
            raise OperatorUnavailable(f"the simulated operator refused to re-seat the polygon: {reply[:80]!r}")

    def move_tracer(self, mount: int, where: str, resumed: bool = False) -> None:
        reply = self._ask(f"MOUNT {int(mount)}")
        if reply != "OK":
            raise OperatorUnavailable(f"the simulated operator refused to move the tracer: {reply[:80]!r}")

    def clear_fault(self, message: str) -> None:
        if self._ask("CLEAR") != "OK":
            raise OperatorUnavailable("the simulated operator could not clear the fault")

    def polygon_certificate_arcsec(self) -> list[float] | None:
        words = self._ask("CERT?").split()
        try:
            if not words or words[0] != "CERT":
                raise ValueError
            values = [float(w) for w in words[1:]]
        except ValueError:
            raise OperatorUnavailable(f"the simulated operator has no certificate: {' '.join(words)[:80]!r}") from None
        if not all(math.isfinite(v) and abs(v) <= 3600 for v in values):
            raise OperatorUnavailable("the simulated operator's certificate holds values that are no face errors")
        return values


class RehearsalOperator(WaitingOperator):
    """A rehearsal of a run's operator steps on `rtcal sim serve`: each step waits for a person as on
    hardware (Enter, the live page's Done, `rtcal control … confirm`), and once confirmed the
    simulated operator carries it out on the simulated bench (there is no polygon to seat by hand);
    the simulated polygon's certificate comes from it too."""

    def __init__(self, simulated: "RemoteSimOperator | BenchOperator", **waiting: Any):
        super().__init__(**waiting)
        self.simulated = simulated

    def reseat_polygon(self, offset_deg: float, face_pitch_deg: float, resumed: bool = False) -> None:
        super().reseat_polygon(offset_deg, face_pitch_deg, resumed)
        self.simulated.reseat_polygon(offset_deg, face_pitch_deg, resumed)

    def move_tracer(self, mount: int, where: str, resumed: bool = False) -> None:
        super().move_tracer(mount, where, resumed)
        self.simulated.move_tracer(mount, where, resumed)

    def clear_fault(self, message: str) -> None:
        super().clear_fault(message)
        self.simulated.clear_fault(message)

    def polygon_certificate_arcsec(self) -> list[float] | None:
        return self.simulated.polygon_certificate_arcsec()
