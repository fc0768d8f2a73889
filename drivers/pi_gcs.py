"""A rotary stage on a PI (Physik Instrumente) controller, through its GCS ASCII commands.

Commands as PI's open-source Python library pipython sends them (pidevice/common/gcsbasecommands.py,
gcsmessages.py; docs/protocols/pi_gcs.md): one line ended by LF, the axis then the value
separated by spaces (``MOV 1 12.5``); a query answers ``<axis>=<value>`` and LF (a line ending in
space + LF announces another line). A command that is not a query answers nothing: its success is
asked with ``ERR?`` (``0``: no error), as pipython does after every command.

At open: ``*IDN?`` (the identity) and ``ERR?`` (an error left from before is logged, and so
cleared). A driver that may move the stage switches the servo on (``SVO 1 1``) and checks the
axis is referenced (``FRF? 1``); an unreferenced axis is referenced (``FRF 1``, a motion to the
reference switch) only when the address allows it (``home=1``), else refused naming referencing.
A probe does neither: it asks ``POS? 1`` only.

``move_to``: ``POS?`` and ``VEL?`` (the closed-loop velocity, physical units per second: PI's
C-863.12 manual MS249E, "VEL? (Get Closed-Loop Velocity)"), ``MOV``, ``ERR?`` (7: outside the
controller's travel range; 5: servo off or not referenced), then ``ONT?`` and ``ERR?`` in turn
until the axis is on target. The deadline is the move's own: twice distance / velocity, plus ten
times the timeout for the start and the settling — a 350° turn at 10°/s is given 80 s, a step
of 1° 10 s. ``ERR?`` while waiting is what tells a move that failed from one still going: error
1024, "motion error: position error too large, servo is switched off automatically" (MS249E
§8.7 "Error Codes"; pipython gcserror.py ``PI_CNTR_MOTION_ERROR``), leaves ``ONT?`` at 0 for
ever, and is raised at once naming it. ``stop``: ``HLT`` of the axis (a smooth halt; the
controller sets error 10, which the driver reads off).
"""

from __future__ import annotations

import logging
import math
import re
import time

from drivers.addresses import Address, AddressError
from drivers.errors import InstrumentError, InstrumentFault, InstrumentTimeout, OutOfLimits
from drivers.interfaces import RotaryStage
from drivers.models import Framing, builtin_framing
from drivers.serial_line import SerialLine

log = logging.getLogger(__name__)

# GCS error codes rtcal meets (pipython pidevice/gcserror.py)
ERRORS = {1: "parameter syntax error", 2: "unknown command", 5: "move without reference or servo off",
          7: "position out of limits", 10: "controller was stopped by command", 15: "invalid axis identifier",
          1024: "motion error: position error too large, servo is switched off automatically"}
STOPPED = 10
SETTLE_TIMEOUTS = 10.0  # timeouts allowed beyond the travel time for a move's start and settling
TRAVEL_MARGIN = 2.0  # the travel time allowed, in units of distance / velocity (acceleration, a slower stage)
MAX_POSITION_DEG = 1e6  # a rotation stage's position beyond this is no position


class PiGcsStage(RotaryStage):
    name = "stage"
    model, kind, schemes = "pi-gcs", "stage", ("serial",)
    options: dict[str, tuple[float, float, bool]] = {}  # axis= and home= are general address options (drivers/addresses.py)
    framing: Framing = builtin_framing("pi-gcs")
    POLL_S = 0.01

    def __init__(self, address: Address, timeout_s: float = 2.0, limits_deg: tuple[float, float] = (-360.0, 360.0),
                 may_move: bool = True, **_: object):
        axis = address.text("axis", "1")  # a letter or a number (drivers/addresses.py); GCS names axes by number here
        if not axis.isdigit():
            raise AddressError(f"option axis={axis!r}: a PI GCS axis is a number, e.g. axis=1")
        self.axis = axis
        self.limits_deg = limits_deg
        self.timeout_s = timeout_s
        self.may_move = may_move
        self.step_deg = 0.0
        self.line = SerialLine(self.name, address, self.framing, timeout_s, b"\n")
        try:
            self._identity = self._query("*IDN?").strip()
            stale = self._error_code()
            if stale:
                log.warning("%s: the controller held GCS error %d (%s) from before; read and cleared", self.name, stale,
                            ERRORS.get(stale, "see the controller manual"))
            if not may_move and not self._referenced():  # a query: nothing moves; what a run would refuse is said now
                self._identity += (f" — axis {self.axis} NOT referenced (FRF? {self.axis} = 0): a run refuses it until it "
                                   "is referenced at the controller, or with home=1 in the address")
            if may_move:
                self._command(f"SVO {self.axis} 1")
                if not self._referenced():
                    if address.option("home", 0) != 1:
                        raise InstrumentFault(self.name, f"axis {self.axis} is not referenced (FRF? {self.axis} = 0): "
                                                         "reference it at the controller, or allow rtcal to with home=1 "
                                                         "in the address (FRF moves the stage to its reference switch)")
                    self.home()
        except BaseException:
            self.line.close()
            raise

    # -- the wire
    def _query(self, command: str) -> str:
        """One answer, all its lines (a line ending in space + LF announces another)."""
        self.line.write(command.encode("ascii") + b"\n")
        lines = [self.line.read_line(command.encode("ascii"))]
        while lines[-1].endswith(" ") and len(lines) < 64:
            lines.append(self.line.port.read_until(b"\n", 256).decode("ascii", errors="replace").rstrip("\n"))
        return "\n".join(line.rstrip() for line in lines)

    def _axis_value(self, command: str) -> str:
        """``<axis>=<value>`` of our axis in the answer to ``command``."""
        answer = self._query(command)
        for line in answer.splitlines():
            key, equals, value = line.partition("=")
            if equals and key.strip() == self.axis:
                return value.strip()
        raise InstrumentFault(self.name, f"{command}: answer {answer[:80]!r} has no value for axis {self.axis}")

    def _error_code(self) -> int:
        answer = self._query("ERR?").strip()
        if not re.fullmatch(r"-?\d{1,6}", answer):
            raise InstrumentFault(self.name, f"ERR?: unexpected answer {answer[:40]!r}")
        return int(answer)

    def _command(self, command: str) -> None:
        """A command without an answer, then ``ERR?``: a non-zero code raises (7 as OutOfLimits)."""
        self.line.write(command.encode("ascii") + b"\n")
        code = self._error_code()
        if code:
            error = OutOfLimits if code == 7 else InstrumentFault
            raise error(self.name, f"{command}: GCS error {code} ({ERRORS.get(code, 'see the controller manual')})")

    def _referenced(self) -> bool:
        return self._axis_value(f"FRF? {self.axis}") == "1"

    def _velocity_deg_per_s(self) -> float:
        """``VEL?`` of the axis: the closed-loop velocity the move will run at."""
        text = self._axis_value(f"VEL? {self.axis}")
        try:
            value = float(text)
        except ValueError:
            raise InstrumentFault(self.name, f"VEL?: {text[:40]!r} is no number") from None
        if not (math.isfinite(value) and value > 0.0):
            raise InstrumentFault(self.name, f"VEL?: {text[:40]!r} is no velocity a move can be timed by")
        return value

    def _wait(self, what: str, done, travel_s: float = 0.0) -> None:
        """Until ``done()``, reading ``ERR?`` between polls: a motion error is raised when it happens,
        not as a timeout; the deadline is the travel time given plus the settling allowance."""
        allowed_s = TRAVEL_MARGIN * travel_s + max(self.timeout_s, 1.0) * SETTLE_TIMEOUTS
        deadline = time.monotonic() + allowed_s
        while not done():
            code = self._error_code()
            if code:
                raise InstrumentFault(self.name, f"{what}: GCS error {code} ({ERRORS.get(code, 'see the controller manual')})"
                                                 f" at {self.position_deg():.6f}°")
            if time.monotonic() > deadline:
                raise InstrumentTimeout(self.name, f"{what}: not on target within {allowed_s:.0f} s")
            time.sleep(self.POLL_S)

    # -- the interface
    def identity(self) -> str:
        return self._identity

    def home(self) -> None:
        """``FRF`` (a reference move to the switch, at most a turn at ``VEL?``), then wait for ``FRF?`` = 1 and ``ONT?`` = 1."""
        travel_s = 360.0 / self._velocity_deg_per_s()  # the switch is at most a turn away
        self._command(f"FRF {self.axis}")
        self._wait("reference move", lambda: self._referenced() and self._axis_value(f"ONT? {self.axis}") == "1", travel_s)

    def move_to(self, angle_deg: float) -> None:
        self.check_target(angle_deg)
        travel_s = abs(angle_deg - self.position_deg()) / self._velocity_deg_per_s()
        self._command(f"MOV {self.axis} {angle_deg:.12g}")
        self._wait(f"move to {angle_deg:.6f}°", lambda: self._axis_value(f"ONT? {self.axis}") == "1", travel_s)

    def position_deg(self) -> float:
        text = self._axis_value(f"POS? {self.axis}")
        try:
            value = float(text)
        except ValueError:
            raise InstrumentFault(self.name, f"POS?: {text[:40]!r} is no number") from None
        if not (math.isfinite(value) and abs(value) <= MAX_POSITION_DEG):
            raise InstrumentFault(self.name, f"POS?: {text[:40]!r} is no position")
        return value

    def stop(self) -> None:
        """``HLT`` of the axis; the error 10 it sets is read off."""
        self.line.write(f"HLT {self.axis}\n".encode("ascii"))
        code = self._error_code()
        if code not in (0, STOPPED):
            raise InstrumentFault(self.name, f"HLT: GCS error {code} ({ERRORS.get(code, 'see the controller manual')})")

    def reset_alarm(self) -> None:
        """Read the error off (``ERR?`` clears it) and switch the servo on again."""
        self._error_code()
        if self.may_move:
            self._command(f"SVO {self.axis} 1")

    def close(self) -> None:
        try:
            self.line.close()
        except InstrumentError:
            pass
