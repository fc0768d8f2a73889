"""Operator steps: what a person must do mid-run (re-seat the polygon, move the tracer). On hardware the
sequencer pauses with a prompt; on the simulated bench the bench does it itself."""

from __future__ import annotations

import math
import sys
from typing import Callable, Protocol

from drivers.errors import InstrumentError


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


class ConsoleOperator:
    """Prints what to do and waits for Enter; refuses to continue without a terminal."""

    def __init__(self, ask: Callable[[str], str] = input):
        self._ask = ask

    def reseat_polygon(self, offset_deg: float, face_pitch_deg: float, resumed: bool = False) -> None:
        faces = offset_deg / face_pitch_deg
        what = f"{faces:g} face(s)" if abs(faces - round(faces)) < 1e-9 else f"{offset_deg:g}°"
        if resumed:
            message = (f"\nOperator: the run resumes with the polygon seated turned by {what}. Do not move it; "
                       "if it was moved, abort and start the seating again. Press Enter to continue.")
        else:
            message = (f"\nOperator: seat the polygon turned by {what} from its home seating "
                       f"(faces in front of the autocollimator at table angles {offset_deg:g}° + k·{face_pitch_deg:g}°), "
                       "align it to the autocollimator within its range, then press Enter.")
        if not sys.stdin.isatty() and self._ask is input:
            raise OperatorUnavailable("the procedure needs an operator to re-seat the polygon but there is no terminal; "
                                      "run it from a terminal")
        self._ask(message + " ")

    def move_tracer(self, mount: int, where: str, resumed: bool = False) -> None:
        if resumed:
            message = f"\nOperator: the run resumes with the laser tracer on mount {mount + 1}. Do not move it. Press Enter."
        else:
            message = (f"\nOperator: move the laser tracer to mount {mount + 1} ({where}), at the same height as before; "
                       "fix it, then press Enter (rtcal re-references the beam).")
        if not sys.stdin.isatty() and self._ask is input:
            raise OperatorUnavailable("the procedure needs an operator to move the laser tracer but there is no terminal; "
                                      "run it from a terminal")
        self._ask(message + " ")

    def polygon_certificate_arcsec(self) -> list[float] | None:
        return None

    def clear_fault(self, message: str) -> None:
        if not sys.stdin.isatty() and self._ask is input:
            raise OperatorUnavailable(f"the run paused for the operator ({message}) but there is no terminal")
        self._ask(f"\nOperator: {message}. Clear the fault, then press Enter to try again. ")


class BenchOperator:
    """The simulated bench re-seats its own polygon."""

    def __init__(self, bench) -> None:
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
