"""No reading is trusted alone: each motion and reading is checked against the command and the
other instruments, and a contradiction is a fault, never a result.

- The stage's feedback position agrees with the command after settling, and does not change
  during a reading (read before and after).
- The CMM's reported position is the commanded point, and does not change during a reading.
Each method's own checks (a tracer length against the geometry, the encoder against the commanded
motion, the autocollimator against the encoder, the indicators) are in its folder:
rtcal/methods/<method>/checks.py.

Tolerances come from the procedure's ``verification`` section. A :class:`Contradiction` is an
instrument fault under that instrument's ``on_fault`` policy; an :class:`UncommandedMotion` — the
table or the probe moved while nothing was commanded — means another client drives the machine,
and the run stops at once (no retry can give rtcal its machine back).
"""

from __future__ import annotations

from functools import partial
from typing import Any, Generator

import numpy as np

from drivers.errors import InstrumentFault
from rtcal.engine.steps import Move, Read, Settle, Step
from rtcal.moved import moved

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


def arrive(checks: MotionChecks, target_deg: float, direction: int, overshoot_deg: float, settle_s: float,
           stage: str = "stage") -> Generator[Step, Any, float]:
    """The stage moves, settles and is checked: approached from ``direction`` (ISO 230-2: past ``overshoot_deg``
    where it would arrive the other way), left ``settle_s`` to settle, its feedback read and checked against the
    command (a Contradiction where it is not there). ``feedback = yield from arrive(...)`` in a plan's attempt."""
    yield Move(stage, target_deg, direction, overshoot_deg, what=f"move to {target_deg:g}°")
    yield Settle(settle_s)
    feedback: float = yield Read(stage, ("feedback_deg",), partial(checks.stage_at, command_deg=target_deg), target_deg,
                                 f"position at {target_deg:g}°")
    return feedback


def stood_still(checks: MotionChecks, target_deg: float, feedback_deg: float, stage: str = "stage") -> Generator[Step, Any, float]:
    """The stage did not move while the readings were taken: its feedback read again (purpose ``after``) and
    checked against the one :func:`arrive` read (an UncommandedMotion where it moved: the run stops)."""
    after: float = yield Read(stage, ("feedback_deg",), partial(checks.stage_still, before_deg=feedback_deg), target_deg,
                              f"position at {target_deg:g}°", "after")
    return after


def combined_sigma(*noise_and_digit: tuple[float, float]) -> float:
    """1σ of a sum or difference of readings: each instrument's noise and its digit (uniform, d/√12)."""
    return float(np.sqrt(sum(n**2 + d**2 / 12.0 for n, d in noise_and_digit)))


__getattr__ = moved(__name__, {"EncoderCheck": "rtcal.methods.abbe.checks"})  # Abbe's, in its folder
