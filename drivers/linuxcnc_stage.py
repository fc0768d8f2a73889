"""A LinuxCNC controller's rotary axis over linuxcncrsh, its text interface (TCP, default port 5007).

What every LinuxCNC driver shares — the sessions, the checks at connect and after every move,
control (``take_control=1``), homing (``home=1``), the session kept for stopping, LinuxCNC's
message queue — is drivers/linuxcncrsh.py (docs/protocols/linuxcnc.md cites each command). This
module is the rotary stage's part.

The joint must be angular, in degrees, and (where the INI ``get inifile`` names is on this host)
the axis letter's joint in the kinematics' ``coordinates`` (an address error, exit 2:
``axis=Z&joint=3`` moved the Z axis while reporting the table).

A move is one MDI line, ``G0 C<deg>`` (``G1 … F<deg/min>`` with ``speed_deg_per_s``), then ``set
wait done``; linuxcncrsh answers ACK also for a move that an E-stop or an abort cut short, so every
move is checked: E-stop off, machine on, no error queued (``get error``), the axis's commanded and
actual positions at the target. The approach direction and overshoot are the procedure's
(rtcal.engine.motion): the driver goes where it is told, by the shortest way LinuxCNC takes for a
linear (non-wrapped) joint.

Compensation type: the table's meaning depends on the INI's ``COMP_FILE_TYPE`` (0: nominal and
measured positions; 1: nominal and trims; usrmotLoadComp, src/emc/motion/usrmotintf.cc), which
linuxcncrsh does not report and which no position it reports shows (below). Where LinuxCNC runs
on this host, the driver reads the INI ``get inifile`` names and the joint's table as LinuxCNC
does; corrections beyond 1° mean a table of the other type (rtcal writes type 0): a fault naming
the type. Elsewhere the identity says the type was not checked.

LinuxCNC's positions (``get abs_act_pos``, ``get joint_pos``) are uncompensated: a joint's
``COMP_FILE`` shows only in HAL (``joint.N.motor-pos-cmd``). The feedback the checks compare is
the joint's actual position; the protocol prints six decimals, hence ``step_deg`` 1e-6. Stopping:
``stop`` aborts over the session kept for it, ``wait_stopped`` reads ``get abs_act_pos`` there
until it no longer changes.
"""

from __future__ import annotations

import math
import time

from drivers.addresses import Address, AddressError, ROTARY_AXES
from drivers.errors import InstrumentFault
from drivers.interfaces import RotaryStage, StopSeen, STOP_WATCH_S
from drivers.linuxcncrsh import AXES, LinuxCncControl, ini_section
from drivers.models import Framing

POSITION_TOLERANCE_DEG = 2e-6  # two units of the six decimals linuxcncrsh prints
MAX_COMP_DEG = 1.0  # a rotary table's correction beyond this is a table read as the wrong COMP_FILE_TYPE


class LinuxCncStage(LinuxCncControl, RotaryStage):
    """``linuxcncrsh://HOST:PORT?axis=C&joint=0&take_control=1``: the rotary axis letter (A, B or C;
    default C) and its joint number (default 0; checked to be an angular joint in degrees and, where
    the INI is on this host, the letter's joint in the kinematics), ``take_control=1`` (rtcal may take
    control from any other linuxcncrsh console: needed to move), ``speed_deg_per_s`` (G1 at that feed;
    default G0, the joint's rapid), ``move_timeout_s`` (longest wait for one move, default 60) and
    ``home=1`` (rtcal may home an unhomed joint; default: an unhomed joint is refused)."""

    name = "stage"
    what_address = "stage"
    framing: Framing | None
    options: dict[str, tuple[float, float, bool]]
    model, kind, schemes, framing, options = "linuxcnc", "stage", ("linuxcncrsh",), None, {}
    step_deg = 1e-6

    def __init__(self, address: Address, timeout_s: float = 2.0, limits_deg: tuple[float, float] = (-360.0, 360.0),
                 may_move: bool = True, **_: object):
        """``may_move=False`` (`rtcal probe`, `rtcal check`): only asks — never takes control, homes or
        changes the mode, whatever the address says."""
        self.limits_deg = limits_deg
        self.axis = address.text("axis", "C").upper()
        if self.axis not in ROTARY_AXES:
            raise AddressError(f"option axis={self.axis!r}: a LinuxCNC rotary axis is A, B or C (X Y Z U V W are linear)")
        self.axis_index = AXES.index(self.axis)
        self.joint = int(address.option("joint", 0))
        self.feed_deg_per_min = 60.0 * address.option("speed_deg_per_s", 0.0)  # 0: G0, the joint's rapid
        self.compensation = "not checked"
        self.mapping = f"axis {self.axis}, joint {self.joint}"
        self._connect(address, timeout_s, may_move)

    def _check_configuration(self) -> None:
        self._check_joint()
        self._check_compensation()

    def homing_joints(self) -> list[int]:
        return [self.joint]

    def _check_joint(self) -> None:
        """The joint is angular, in degrees, and (INI on this host) the axis letter's joint in the
        kinematics; else an address error (the address names the wrong joint or letter)."""
        kind = self.get("joint_type", self.joint)[-1:]
        units = self.get("joint_units")  # every joint's: 2.9 answers the one-joint form with its type
        unit = units[self.joint:self.joint + 1]
        if kind != ["ANGULAR"] or unit != ["DEG"]:
            raise AddressError(f"joint {self.joint} of this LinuxCNC is {' '.join(kind).lower() or '?'} in "
                               f"{' '.join(unit).lower() or '?'}, not an angular joint in degrees: give joint= the "
                               f"rotary axis {self.axis}'s joint")
        found = self._kinematics()
        if isinstance(found, str):
            self.mapping = f"axis {self.axis}, joint {self.joint} (not checked: {found})"
            return
        _, letters, source, ini_name = found
        joints = [j for j, letter in enumerate(letters) if letter == self.axis]
        if self.joint not in joints:
            mine = letters[self.joint] if self.joint < len(letters) else ""
            hint = (f"axis {self.axis} is joint {' and '.join(map(str, joints))}: give joint={joints[0]}" if joints
                    else f"this machine has no axis {self.axis}" + (f"; joint {self.joint} is {mine}: give axis={mine}"
                                                                      if mine and mine in ROTARY_AXES else ""))
            raise AddressError(f"axis {self.axis} with joint {self.joint}: {hint} ({source}, {ini_name})")
        self.mapping = f"axis {self.axis} is joint {self.joint} ({source})"

    def _check_compensation(self) -> None:
        """The joint's COMP_FILE read as LinuxCNC reads it with its COMP_FILE_TYPE, where the INI
        ``get inifile`` names is this host's (linuxcncrsh reports neither the type nor any compensated
        position): corrections beyond MAX_COMP_DEG are a fault naming the type."""
        found = self._ini()
        if found is None:
            self.compensation = "COMP_FILE_TYPE not checked (LinuxCNC runs on another host)"
            return
        ini, text = found
        if text is None:
            self.compensation = f"COMP_FILE_TYPE not checked (INI {ini} not readable here)"
            return
        values = ini_section(text, f"JOINT_{self.joint}")
        if "COMP_FILE" not in values:
            self.compensation = "no COMP_FILE"
            return
        table = ini.parent / values["COMP_FILE"]
        kind = values.get("COMP_FILE_TYPE", "0").strip()
        try:
            rows = comp_rows(table.read_text(errors="replace"))
        except OSError as exc:
            raise InstrumentFault(self.name, f"joint {self.joint}'s COMP_FILE {table} cannot be read ({exc.strerror})") from None
        corrections = [abs(c) for nominal, fwd, rev in rows
                       for c in ((nominal - fwd, nominal - rev) if kind == "0" else (fwd, rev))]
        worst = max(corrections, default=0.0)
        if worst > MAX_COMP_DEG:
            meant = "1 (nominal, forward trim, reverse trim)" if kind == "0" else "0 (nominal, measured forward, measured reverse)"
            raise InstrumentFault(self.name, f"joint {self.joint}'s COMP_FILE {table.name} read as COMP_FILE_TYPE = {kind} "
                                             f"corrects by up to {worst:.4f}°: a table of type {meant} (rtcal compensate "
                                             "writes type 0); set COMP_FILE_TYPE in the INI and restart LinuxCNC")
        self.compensation = f"COMP_FILE {table.name}, COMP_FILE_TYPE = {kind}, corrections up to {worst * 3600:.2f}″"

    # -- the interface
    # -- the interface
    def identity(self) -> str:
        return f"LinuxCNC linuxcncrsh server {self.rsh.server}; {self.mapping}; {self.compensation}"

    def move_to(self, angle_deg: float) -> None:
        self.check_target(angle_deg)
        what = f"move to {angle_deg:.6f}°"
        self._before_move(what)
        word = f"G1 {self.axis}{angle_deg:.6f} F{self.feed_deg_per_min:.3f}" if self.feed_deg_per_min else f"G0 {self.axis}{angle_deg:.6f}"
        self._mdi(word, what)
        self._after_mdi(what)
        # "done" is the MDI command's; the status LinuxCNC reports may lag a servo cycle or two behind
        # (seen: 0.00005° short of the target right after the ACK, there a moment later), so the
        # position is polled until it is the target, for at most the driver's timeout
        deadline = time.monotonic() + self.timeout_s
        while True:
            commanded = self.rsh.position("abs_cmd_pos", self.axis_index)
            actual = self.rsh.position("abs_act_pos", self.axis_index)
            if abs(commanded - angle_deg) <= POSITION_TOLERANCE_DEG and abs(actual - angle_deg) <= POSITION_TOLERANCE_DEG:
                return
            if time.monotonic() > deadline:
                raise InstrumentFault(self.name, f"{what}: the axis stopped at {actual:.6f}° (commanded {commanded:.6f}°): "
                                                 "the move was cut short (abort, E-stop or a limit)")
            time.sleep(0.01)

    def home(self) -> None:
        """The joint is homed in place when the session opens; homing here returns to the datum, 0°."""
        self.move_to(0.0)

    def position_deg(self) -> float:
        """The axis's actual position (``get abs_act_pos``), uncompensated as LinuxCNC reports it."""
        return self.rsh.position("abs_act_pos", self.axis_index)

    def feedback_deg(self) -> float:
        """The joint's actual position (``get joint_pos``): what the motor feedback says, compensation removed."""
        words = self.get("joint_pos", self.joint)
        try:
            value = float(words[-1])
        except (ValueError, IndexError):
            value = math.nan
        if len(words) != 2 or not math.isfinite(value):
            raise InstrumentFault(self.name, f"get joint_pos {self.joint}: unexpected reply {' '.join(words)[:120]!r}")
        return value

    def wait_stopped(self, timeout_s: float = STOP_WATCH_S) -> StopSeen:
        """The axis position (``get abs_act_pos``) read over the session kept for stopping until it no
        longer changes: the moving session may still wait for the move's reply."""
        return self._watch_stopped(lambda rsh: rsh.position("abs_act_pos", self.axis_index), lambda deg: f"{deg:.6f}°",
                                   self.still_within_deg, timeout_s)


def comp_rows(text: str) -> list[tuple[float, float, float]]:
    """A COMP_FILE's triplets as usrmotLoadComp reads them: three numbers a line, up to the first line that is not."""
    rows = []
    for line in text.splitlines():
        try:
            nominal, fwd, rev = (float(w) for w in line.split()[:3])
        except ValueError:
            break
        rows.append((nominal, fwd, rev))
    return rows
