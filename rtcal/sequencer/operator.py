"""Operator steps: what a person must do mid-run (re-seat the polygon). On hardware the
sequencer pauses with a prompt; on the simulated bench the bench does it itself."""

from __future__ import annotations

import sys
from typing import Callable, Protocol


class Operator(Protocol):
    def reseat_polygon(self, offset_deg: float, face_pitch_deg: float) -> None: ...


class ConsoleOperator:
    """Prints what to do and waits for Enter; refuses to continue without a terminal."""

    def __init__(self, ask: Callable[[str], str] = input):
        self._ask = ask

    def reseat_polygon(self, offset_deg: float, face_pitch_deg: float) -> None:
        faces = offset_deg / face_pitch_deg
        what = f"{faces:g} face(s)" if abs(faces - round(faces)) < 1e-9 else f"{offset_deg:g}°"
        message = (f"\nOperator: seat the polygon turned by {what} from its home seating "
                   f"(faces in front of the autocollimator at table angles {offset_deg:g}° + k·{face_pitch_deg:g}°), "
                   "align it to the autocollimator within its range, then press Enter.")
        if not sys.stdin.isatty() and self._ask is input:
            raise RuntimeError("the procedure needs an operator (polygon re-seating) but there is no terminal")
        self._ask(message + " ")


class BenchOperator:
    """The simulated bench re-seats its own polygon."""

    def __init__(self, bench) -> None:
        self.bench = bench

    def reseat_polygon(self, offset_deg: float, face_pitch_deg: float) -> None:
        self.bench.reseat_polygon(offset_deg)
