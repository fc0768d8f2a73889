"""No reading is trusted alone: each motion and reading is checked against the command and the
other instruments, and a contradiction is a fault, never a result.

- The stage's feedback position agrees with the command after settling, and does not change
  during a reading (read before and after).
- The CMM's reported position is the commanded point, and does not change during a reading.
- The encoder's change since the start's first visit is the commanded change (seed 001).
- The autocollimator's reading of the face the commanded angle puts in view is near zero.
- A tracer length is what the nominal geometry expects: the stations are the procedure's first
  station guess turned about the nominal axis, the points the commanded ones (seed 000).

Tolerances come from the procedure's ``verification`` section. A :class:`Contradiction` is an
instrument fault under that instrument's ``on_fault`` policy; an :class:`UncommandedMotion` — the
table or the probe moved while nothing was commanded — means another client drives the machine,
and the run stops at once (no retry can give rtcal its machine back).
"""

from __future__ import annotations

import numpy as np

from drivers.errors import InstrumentFault
from drivers.interfaces import Cmm, RotaryStage

FLOOR_DEG = 1e-6  # a drive without steps still reports its position in floating point


class Contradiction(InstrumentFault):
    """What an instrument reports contradicts the command or another instrument."""


class UncommandedMotion(Contradiction):
    """The table or the probe moved during a reading while nothing was commanded."""


def _arcsec(deg: float) -> str:
    return f"{deg * 3600:+.1f}″"


class MotionChecks:
    """The stage's and the CMM's positions against their commands and against themselves."""

    def __init__(self, stage_step_deg: float, stage_tolerance_deg: float | None, cmm_tolerance_mm: float | None = None):
        self.stage_tolerance_deg = stage_tolerance_deg or max(2 * stage_step_deg, FLOOR_DEG)
        self.stated = stage_tolerance_deg is not None
        self.cmm_tolerance_mm = cmm_tolerance_mm

    def _stage_tolerance(self) -> str:
        source = "verification.stage_tolerance_deg" if self.stated else "two steps of the drive; verification.stage_tolerance_deg"
        return f"tolerance {self.stage_tolerance_deg * 3600:.3g}″, {source}"

    def stage_at(self, stage: RotaryStage, command_deg: float) -> float:
        """The feedback position after settling, or Contradiction when it is not the command."""
        feedback = stage.feedback_deg()
        off = feedback - command_deg
        if not abs(off) <= self.stage_tolerance_deg:
            raise Contradiction("stage", f"feedback position {feedback:.6f}° where {command_deg:.6f}° was commanded: "
                                         f"{_arcsec(off)} off ({self._stage_tolerance()})")
        return feedback

    def stage_still(self, stage: RotaryStage, before_deg: float) -> float:
        """The feedback position after a reading, or UncommandedMotion when the table turned during it."""
        feedback = stage.feedback_deg()
        if not abs(feedback - before_deg) <= self.stage_tolerance_deg:
            raise UncommandedMotion("stage", f"the table turned {_arcsec(feedback - before_deg)} during a reading while "
                                             f"nothing was commanded ({self._stage_tolerance()}): another client or a hand "
                                             "is driving it; rtcal needs the machine to itself")
        return feedback

    def cmm_at(self, cmm: Cmm, point_mm: np.ndarray) -> np.ndarray:
        """The CMM's reported position, or Contradiction when it is not the commanded point."""
        xyz = np.asarray(cmm.position_mm(), float)
        off = float(np.linalg.norm(xyz - point_mm))
        if not off <= self.cmm_tolerance_mm:
            raise Contradiction("cmm", f"reported position {np.round(xyz, 4).tolist()} mm where "
                                       f"{np.round(point_mm, 4).tolist()} mm was commanded: {off:.4f} mm off "
                                       f"(tolerance {self.cmm_tolerance_mm:g} mm, verification.cmm_tolerance_mm)")
        return xyz

    def cmm_still(self, cmm: Cmm, before_mm: np.ndarray) -> np.ndarray:
        """The reported position after a reading, or UncommandedMotion when the probe moved during it."""
        xyz = np.asarray(cmm.position_mm(), float)
        moved = float(np.linalg.norm(xyz - before_mm))
        if not moved <= self.cmm_tolerance_mm:
            raise UncommandedMotion("cmm", f"the probe moved {moved:.4f} mm during a reading while nothing was commanded "
                                           f"(tolerance {self.cmm_tolerance_mm:g} mm, verification.cmm_tolerance_mm): another "
                                           "client or a hand is driving it; rtcal needs the machine to itself")
        return xyz


class EncoderCheck:
    """The encoder moves as commanded: its reading minus the command stays within a tolerance of
    what it was at the start's first visit (an incremental counter's zero is arbitrary)."""

    def __init__(self, tolerance_arcsec: float):
        self.tolerance_arcsec = tolerance_arcsec
        self.offset_deg: float | None = None
        self.first_command_deg = 0.0

    def check(self, encoder_deg: float, command_deg: float) -> None:
        offset = encoder_deg - command_deg
        if self.offset_deg is None:
            self.offset_deg, self.first_command_deg = offset, command_deg
            return
        apart_deg = (offset - self.offset_deg + 180.0) % 360.0 - 180.0
        if not abs(apart_deg) * 3600.0 <= self.tolerance_arcsec:
            commanded = command_deg - self.first_command_deg
            raise Contradiction("stage", f"the encoder turned {commanded + apart_deg:.4f}° where {commanded:.4f}° was "
                                         f"commanded since the first visit: {apart_deg * 3600:+.0f}″ apart (tolerance "
                                         f"{self.tolerance_arcsec:g}″, verification.encoder_tolerance_arcsec): the table is "
                                         "not where it was commanded, or the encoder misreads")


def check_face(x_arcsec: float, tolerance_arcsec: float, command_deg: float) -> None:
    """The face the commanded angle puts in view is seen square (within the tolerance)."""
    if not abs(x_arcsec) <= tolerance_arcsec:
        raise Contradiction("autocollimator", f"the face at {command_deg:g}° is seen {x_arcsec:+.1f}″ from square (tolerance "
                                              f"{tolerance_arcsec:g}″, verification.autocollimator_tolerance_arcsec): the "
                                              "table is not where it was commanded, or the polygon is not seated as stated")


class TracerCheck:
    """Tracer lengths against the nominal geometry: the change since the tracer's reference is the
    change of the distance from the nominal station centre to the commanded point."""

    def __init__(self, first_guesses_mm: list[np.ndarray], axis_point_mm: np.ndarray, angles_deg: np.ndarray,
                 points_mm: np.ndarray, tolerance_mm: float):
        delta = np.radians(np.asarray(angles_deg, float) - angles_deg[0])
        c, s = np.cos(delta), np.sin(delta)
        axis = np.asarray(axis_point_mm, float)
        self.distance_mm = []  # per mount: (points × stations) nominal distances
        for first in first_guesses_mm:
            rel = np.asarray(first, float)[:2] - axis[:2]
            centres = np.column_stack([c * rel[0] - s * rel[1] + axis[0], s * rel[0] + c * rel[1] + axis[1],
                                       np.full(len(delta), float(first[2]))])
            self.distance_mm.append(np.linalg.norm(np.asarray(points_mm)[:, None, :] - centres[None, :, :], axis=2))
        self.tolerance_mm = tolerance_mm
        self.reference: tuple[int, int, int] | None = None

    def referenced(self, mount: int, point: int, station: int) -> None:
        self.reference = (mount, point, station)

    def check(self, length_mm: float, mount: int, point: int, station: int) -> None:
        if self.reference is None:
            return
        k, i, j = self.reference
        expected = self.distance_mm[mount][point, station] - self.distance_mm[k][i, j]
        if not abs(length_mm - expected) <= self.tolerance_mm:
            raise Contradiction("stage", f"the laser tracer's length at point {point + 1}, station {station + 1} is "
                                         f"{length_mm:.3f} mm where the nominal geometry expects {expected:.3f} mm: "
                                         f"{length_mm - expected:+.3f} mm apart (tolerance {self.tolerance_mm:g} mm, "
                                         "verification.tracer_tolerance_mm): the table or the CMM is not where it was "
                                         "commanded, or solver.first_station_guess_mm does not describe this set-up")
