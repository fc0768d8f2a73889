"""No reading is trusted alone: each motion and reading is checked against the command and the
other instruments, and a contradiction is a fault, never a result.

- The stage's feedback position agrees with the command after settling, and does not change
  during a reading (read before and after).
- The CMM's reported position is the commanded point, and does not change during a reading.
- The encoder's change since the start's first visit is the commanded change (seed 001).

Each method's own checks (a tracer length against the geometry, the autocollimator against the
encoder, the indicators) are in its folder: rtcal/methods/<method>/checks.py.

Tolerances come from the procedure's ``verification`` section. A :class:`Contradiction` is an
instrument fault under that instrument's ``on_fault`` policy; an :class:`UncommandedMotion` — the
table or the probe moved while nothing was commanded — means another client drives the machine,
and the run stops at once (no retry can give rtcal its machine back).
"""

from __future__ import annotations

import numpy as np

from drivers.errors import InstrumentFault

FLOOR_DEG = 1e-6  # a drive without steps still reports its position in floating point


class Contradiction(InstrumentFault):
    """What an instrument reports contradicts the command or another instrument."""


class UncommandedMotion(Contradiction):
    """The table or the probe moved during a reading while nothing was commanded."""


def _arcsec(deg: float) -> str:
    return f"{deg * 3600:+.1f}″"


class MotionChecks:
    """The stage's and the CMM's positions against their commands and against themselves: relations on
    the values read (the engine reads; these only judge)."""

    def __init__(self, stage_step_deg: float, stage_tolerance_deg: float | None, cmm_tolerance_mm: float | None = None):
        self.stage_tolerance_deg = stage_tolerance_deg or max(2 * stage_step_deg, FLOOR_DEG)
        self.stated = stage_tolerance_deg is not None
        self.cmm_tolerance_mm = cmm_tolerance_mm

    def _stage_tolerance(self) -> str:
        source = "verification.stage_tolerance_deg" if self.stated else "two steps of the drive; verification.stage_tolerance_deg"
        return f"tolerance {self.stage_tolerance_deg * 3600:.3g}″, {source}"

    def stage_at(self, feedback: float, command_deg: float) -> float:
        """The feedback position after settling, or Contradiction when it is not the command."""
        off = feedback - command_deg
        if not abs(off) <= self.stage_tolerance_deg:
            raise Contradiction("stage", f"feedback position {feedback:.6f}° where {command_deg:.6f}° was commanded: "
                                         f"{_arcsec(off)} off ({self._stage_tolerance()})")
        return feedback

    def stage_still(self, feedback: float, before_deg: float) -> float:
        """The feedback position after a reading, or UncommandedMotion when the table turned during it."""
        if not abs(feedback - before_deg) <= self.stage_tolerance_deg:
            raise UncommandedMotion("stage", f"the table turned {_arcsec(feedback - before_deg)} during a reading while "
                                             f"nothing was commanded ({self._stage_tolerance()}): another client or a hand "
                                             "is driving it; rtcal needs the machine to itself")
        return feedback

    def _cmm_tolerance(self) -> float:
        if self.cmm_tolerance_mm is None:
            raise ValueError("these motion checks were made without a CMM tolerance: they check no CMM")
        return self.cmm_tolerance_mm

    def cmm_at(self, position_mm: tuple[float, float, float], point_mm: np.ndarray) -> np.ndarray:
        """The CMM's reported position, or Contradiction when it is not the commanded point."""
        tolerance_mm = self._cmm_tolerance()
        xyz = np.asarray(position_mm, float)
        off = float(np.linalg.norm(xyz - point_mm))
        if not off <= tolerance_mm:
            raise Contradiction("cmm", f"reported position {np.round(xyz, 4).tolist()} mm where "
                                       f"{np.round(point_mm, 4).tolist()} mm was commanded: {off:.4f} mm off "
                                       f"(tolerance {tolerance_mm:g} mm, verification.cmm_tolerance_mm)")
        return xyz

    def cmm_still(self, position_mm: tuple[float, float, float], before_mm: np.ndarray) -> np.ndarray:
        """The reported position after a reading, or UncommandedMotion when the probe moved during it."""
        tolerance_mm = self._cmm_tolerance()
        xyz = np.asarray(position_mm, float)
        moved = float(np.linalg.norm(xyz - before_mm))
        if not moved <= tolerance_mm:
            raise UncommandedMotion("cmm", f"the probe moved {moved:.4f} mm during a reading while nothing was commanded "
                                           f"(tolerance {tolerance_mm:g} mm, verification.cmm_tolerance_mm): another "
                                           "client or a hand is driving it; rtcal needs the machine to itself")
        return xyz


class EncoderCheck:
    """The encoder moves as commanded: its reading minus the command stays within a tolerance of
    what it was at the start's first visit (an incremental counter's zero is arbitrary)."""

    def __init__(self, tolerance_arcsec: float, pitch_deg: float = 0.0, face_still_arcsec: float = 0.0):
        """``pitch_deg``: the polygon's, ``face_still_arcsec``: how far apart two readings of one face by
        an autocollimator that did not move may be (its noise): together they say when a face seen
        square is no evidence that the table turned (item 7 of issue 36)."""
        self.tolerance_arcsec = tolerance_arcsec
        self.pitch_deg, self.face_still_arcsec = pitch_deg, face_still_arcsec
        self.offset_deg: float | None = None
        self.first_command_deg = 0.0
        self.previous: tuple[float, float, float | None] | None = None  # the last request's (encoder, command, face)
        self.suspect: str | None = None  # stale or frozen, found once (issue 26)
        self.came_from: tuple[float, float, float | None] | None = None  # the last request at another command

    def _nothing_turned(self, face_arcsec: float | None, command_deg: float,
                        previous: tuple[float, float, float | None]) -> str:
        """Why the table may not have turned at all ("" if the autocollimator shows it did): the step
        is whole faces — a face square in view whether the table turned or not — and the face reads
        what it read at the previous request, within its noise."""
        step = abs(command_deg - previous[1]) / self.pitch_deg if self.pitch_deg > 0 else 0.5
        x_before = previous[2]
        if face_arcsec is None or x_before is None or abs(step - round(step)) > 1e-6:
            return ""
        if not abs(face_arcsec - x_before) <= self.face_still_arcsec:
            return ""
        return (f"the encoder and the autocollimator both read what they read at {previous[1]:g}°, the target before (the "
                f"face {face_arcsec - x_before:+.2f}″ from it): the table did not turn — a face square to the "
                f"autocollimator cannot tell a {abs(command_deg - previous[1]):g}° turn from none ({self.pitch_deg:g}° "
                "faces). The drive did not move the table (stuck, or not enabled) — or it did, the encoder's count is "
                "frozen or stale, and this face happens to read as the last one")

    def _faces_off(self, apart_deg: float) -> str:
        """The other cause when the encoder is whole faces from the command: a face square to the
        autocollimator cannot tell a table that many faces off (a drive that did not move it) from
        one where it was commanded ("" when the gap is no whole number of faces)."""
        if not self.pitch_deg > 0:
            return ""
        faces = round(apart_deg / self.pitch_deg)
        if faces == 0 or abs(apart_deg - faces * self.pitch_deg) * 3600.0 > self.tolerance_arcsec:
            return ""
        return (f" — or the stage did not turn the table as commanded: the encoder reads {abs(faces)} "
                f"{'face' if abs(faces) == 1 else 'faces'} ({abs(faces) * self.pitch_deg:g}°) from the command, and a face "
                "square to the autocollimator cannot tell a whole face from none (the drive stuck, or not enabled)")

    def check(self, encoder_deg: float, command_deg: float, table_seen: bool = False, face_arcsec: float | None = None) -> None:
        """``table_seen``: the autocollimator saw the face the command puts in view square, so the
        table did turn; an encoder that disagrees is then the encoder's fault, and one that fits
        the previous request (stale) or repeats itself (frozen) stays suspect for the run — unless
        the face reads as it did then too (``face_arcsec``): then nothing turned, and the stage is named."""
        offset = encoder_deg - command_deg
        previous, self.previous = self.previous, (encoder_deg, command_deg, face_arcsec)
        if previous is not None and previous[1] != command_deg:  # a retried visit comes from where the one before came
            self.came_from = previous
        if self.suspect is not None:
            raise Contradiction("encoder", f"at {command_deg:g}°: {self.suspect}")
        if self.offset_deg is None:
            self.offset_deg, self.first_command_deg = offset, command_deg
            return
        apart_deg = (offset - self.offset_deg + 180.0) % 360.0 - 180.0
        if not abs(apart_deg) * 3600.0 <= self.tolerance_arcsec and table_seen and previous is not None:
            lag_deg = (encoder_deg - previous[1] - self.offset_deg + 180.0) % 360.0 - 180.0
            stood = encoder_deg == previous[0] or abs(lag_deg) * 3600.0 <= self.tolerance_arcsec
            # a retried visit's previous request is its own failed attempt: where the table stood before is came_from's
            back = self.came_from
            stayed = back is not None and (encoder_deg == back[0] or abs((encoder_deg - back[1] - self.offset_deg + 180.0)
                                                                         % 360.0 - 180.0) * 3600.0 <= self.tolerance_arcsec)
            why = self._nothing_turned(face_arcsec, command_deg, back) if (stood or stayed) and back else ""
            if why:
                raise Contradiction("stage", f"at {command_deg:g}°: {why}")
            if encoder_deg == previous[0]:
                self.suspect = (f"the encoder repeats {encoder_deg:.6f}° while the table turned (the autocollimator sees the "
                                "commanded face square): a frozen counter or buffer")
            elif abs(lag_deg) * 3600.0 <= self.tolerance_arcsec:
                self.suspect = (f"the encoder reads where the previous request was ({lag_deg * 3600:+.0f}″ from it) while the "
                                "autocollimator sees the commanded face square: its replies are one request behind (stale)")
            if self.suspect is not None:
                raise Contradiction("encoder", f"at {command_deg:g}°: {self.suspect}")
            raise Contradiction("encoder", f"the encoder is {apart_deg * 3600:+.0f}″ from the commanded motion while the "
                                           "autocollimator sees the commanded face square (tolerance "
                                           f"{self.tolerance_arcsec:g}″, verification.encoder_tolerance_arcsec): it misreads"
                                           + self._faces_off(apart_deg))
        if not abs(apart_deg) * 3600.0 <= self.tolerance_arcsec:
            commanded = command_deg - self.first_command_deg
            raise Contradiction("stage", f"the encoder turned {commanded + apart_deg:.4f}° where {commanded:.4f}° was "
                                         f"commanded since the first visit: {apart_deg * 3600:+.0f}″ apart (tolerance "
                                         f"{self.tolerance_arcsec:g}″, verification.encoder_tolerance_arcsec): the table is "
                                         "not where it was commanded, or the encoder misreads")


def combined_sigma(*noise_and_digit: tuple[float, float]) -> float:
    """1σ of a sum or difference of readings: each instrument's noise and its digit (uniform, d/√12)."""
    return float(np.sqrt(sum(n**2 + d**2 / 12.0 for n, d in noise_and_digit)))


