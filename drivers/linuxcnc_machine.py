"""A LinuxCNC five-axis machine with a trunnion table (``xyzac-trt-kins``) over linuxcncrsh: the
machine tool the R-test moves (kind ``machine_tool``, model ``linuxcnc-trt``).

What every LinuxCNC driver shares — the sessions, the checks at connect and after every move,
control (``take_control=1``), homing (``home=1``), the session kept for stopping, LinuxCNC's message
queue — is drivers/linuxcncrsh.py (docs/protocols/linuxcnc.md cites each command). This is the
machine's part.

**Kinematics.** LinuxCNC's ``xyzac-trt-kins`` (man 9 kins: a tilting table A carrying a rotary table
C, joints 0:x 1:y 2:z 3:a 4:c by default, remappable with ``coordinates=``) is a switchable module
whose type 0 is the trunnion kinematics: with it, MDI coordinates are where the controlled point
goes on the table (machine coordinates at A = C = 0), and the module's inverse kinematics
(trtfuncs.c ``xyzacKinematicsInverse``, with its pins x/y/z-rot-point, y-offset, z-offset) turns
them into joints every servo period. So the driver moves tool-centre-point targets only
(``MachineTarget.tcp``): one ``G53 G1 X… Y… Z… A… C… F…`` per point (G53: machine coordinates,
whatever work offset the operator set), each followed by ``set wait done``; LinuxCNC interpolates
the point and the angles linearly, so a point held fixed on the table — the sphere — is followed by
the linear axes while the rotary axes turn. ``joint_positions`` reads where the joints went (``get
joint_pos N``), which is what the R-test's model needs; LinuxCNC's kinematic model, not rtcal's,
put them there. Before anything is commanded the driver checks the joints' types and units (X, Y,
Z linear in mm; A, C angular in degrees), that the kinematics is not identity (``get
kinematics_type``: 1 is identity, where a TCP target would move the joints straight and drive the
sphere into the nest), and, where the INI ``get inifile`` names is on this host, that its
``[KINS] KINEMATICS`` is ``xyzac-trt-kins`` without ``sparm=identityfirst`` (which makes type 0
identity) and which joint each letter is. linuxcncrsh cannot show a switch of the module's type
at run time (``motion.switchkins-type``, a HAL pin): the identity says so.

**Feed.** A point that stays on the table while the rotary axes turn is a rotary move for LinuxCNC,
its feed in degrees per minute (``speed_deg_per_s``, default 10); a move of the point is a linear
one, in mm per minute (``speed_mm_per_s``, default 10).

**After every move**: E-stop off, machine on, control still this session's, LinuxCNC's message queue
empty, and the commanded and actual positions of X Y Z A C (``get abs_cmd_pos``, ``get
abs_act_pos``: axes 0, 1, 2, 3 and 5) at the target within two units of the six decimals
linuxcncrsh prints; anything else is a fault (linuxcncrsh answers ACK also for a move an E-stop cut
short).

**Stopping**: ``stop`` aborts over the session kept for it; ``wait_stopped`` reads the five joints
(``get joint_pos``) there until they no longer change.
"""

from __future__ import annotations

import time
from typing import Mapping

from drivers.addresses import Address, AddressError
from drivers.errors import InstrumentFault, OutOfLimits
from drivers.interfaces import MachineTarget, MachineTool, StopSeen, STOP_WATCH_S
from drivers.linuxcncrsh import AXES, LinuxCncControl, Session, ini_section
from drivers.models import Framing

MODULE = "xyzac-trt-kins"
LETTERS = "XYZAC"
IDENTITY_KINEMATICS = "1"  # linuxcncrsh kinematics_type: identity=1 (man: "identity=1, serial=2, parallel=3, custom=4")
POSITION_TOLERANCE = 2e-6  # mm or deg: two units of the six decimals linuxcncrsh prints
MOVED_MM = 1e-6  # a point that moves less than this is held: the move is a rotary one (feed in deg/min)


class LinuxCncMachine(LinuxCncControl, MachineTool):
    """``linuxcncrsh://HOST:PORT?take_control=1`` (kind ``machine_tool``): ``take_control=1`` (rtcal may
    take control from any other linuxcncrsh console: needed to move), ``speed_deg_per_s`` (the feed of a
    move that turns the table about a held point, default 10), ``speed_mm_per_s`` (the feed of a move of
    the point, default 10), ``move_timeout_s`` (longest wait for one move, default 60), ``home=1``
    (rtcal may home unhomed joints; default: refused)."""

    name = "machine_tool"
    what_address = "machine tool"
    framing: Framing | None
    options: dict[str, tuple[float, float, bool]]
    model, kind, schemes, framing, options = "linuxcnc-trt", "machine_tool", ("linuxcncrsh",), None, {}
    tcp = True

    def __init__(self, address: Address, timeout_s: float = 2.0, may_move: bool = True, **_: object):
        """``may_move=False`` (`rtcal probe`, `rtcal check`): only asks — never takes control, homes or
        changes the mode, whatever the address says."""
        if "axis" in address.options or "joint" in address.options:
            raise AddressError("a LinuxCNC machine tool's address names no axis= or joint=: the kinematics' coordinates "
                               "say which joint each of X Y Z A C is")
        self.feed_deg_per_min = 60.0 * address.option("speed_deg_per_s", 10.0)
        self.feed_mm_per_min = 60.0 * address.option("speed_mm_per_s", 10.0)
        self.joints = {a: i for i, a in enumerate(self.axes)}  # the module's default coordinates, XYZAC
        self.mapping = "kinematics not checked"
        self._connect(address, timeout_s, may_move)

    # -- at connect
    def _check_configuration(self) -> None:
        """The kinematics (not identity; where the INI is here: xyzac-trt-kins, not identity first, each
        letter's joint), then each joint's type and unit."""
        kinds = self.get("kinematics_type")
        if kinds[-1:] == [IDENTITY_KINEMATICS]:
            raise AddressError("this LinuxCNC runs identity kinematics (kinematics_type 1): the machine tool moves "
                               "tool-centre-point targets through xyzac-trt-kins, a trunnion table's kinematics")
        found = self._kinematics()
        if isinstance(found, str):
            self.mapping = f"{MODULE} assumed, joints X0 Y1 Z2 A3 C4 (not checked: {found}); kinematics_type {' '.join(kinds)}"
        else:
            module, letters, source, ini_name = found
            words = self._kins_words()
            if module != MODULE:
                raise AddressError(f"this LinuxCNC's kinematics are {module or 'not named'} ({ini_name} [KINS] "
                                   f"KINEMATICS): the machine tool needs {MODULE}, a trunnion table A carrying C")
            if any(w.lower().startswith("sparm=") and "identityfirst" in w.lower() for w in words):
                raise AddressError(f"{ini_name} loads {MODULE} with sparm=identityfirst: its startup type is identity, "
                                   "where a tool-centre-point move drives the joints straight; remove it")
            missing = [a for a in LETTERS if a not in letters]
            if missing:
                raise AddressError(f"this LinuxCNC has no axis {' '.join(missing)} ({source}, {ini_name})")
            self.joints = {a.lower(): letters.index(a) for a in LETTERS}
            self.mapping = (f"{MODULE}, joints " + " ".join(f"{a}{self.joints[a.lower()]}" for a in LETTERS)
                            + f" ({source}); its type switch (motion.switchkins-type) not visible over linuxcncrsh")
        units = self.get("joint_units")  # every joint's (2.9 answers the one-joint form with its type)
        for axis, joint in self.joints.items():
            kind = self.get("joint_type", joint)[-1:]
            unit = units[joint:joint + 1]
            want = (["LINEAR"], ["MM"]) if axis in "xyz" else (["ANGULAR"], ["DEG"])
            if (kind, unit) != want:
                raise AddressError(f"joint {joint} ({axis.upper()}) of this LinuxCNC is {' '.join(kind).lower() or '?'} in "
                                   f"{' '.join(unit).lower() or '?'}; the machine tool needs X Y Z linear in mm and A C "
                                   "angular in degrees")

    def _kins_words(self) -> list[str]:
        ini = self._ini()
        return ini_section(ini[1], "KINS").get("KINEMATICS", "").split() if ini and ini[1] else []

    def homing_joints(self) -> list[int]:
        return sorted(self.joints.values())

    # -- the interface
    def identity(self) -> str:
        return f"LinuxCNC linuxcncrsh server {self.rsh.server}; {self.mapping}"

    def home(self) -> None:
        """The joints were found homed, or homed with ``home=1``, as the session opened: nothing moves."""
        unhomed = [j for j in self.homing_joints() if self.get("joint_homed", j)[-1:] != ["YES"]]
        if unhomed:
            raise InstrumentFault(self.name, f"joints {unhomed} are no longer homed: home them at the controller")

    def move_to(self, target: MachineTarget) -> None:
        self.check_target(target)
        if not target.tcp:
            raise OutOfLimits(self.name, "a joint target: LinuxCNC under xyzac-trt-kins moves tool-centre-point targets "
                                         "only (its kinematics turn them into joints)")
        what = "move to " + self._shown(target.joints)
        self._before_move(what)
        here = [self.rsh.position("abs_cmd_pos", AXES.index(a)) for a in "XYZ"]
        for point in target.points():
            there = [point[a] for a in "xyz"]
            moved = max(abs(b - a) for a, b in zip(here, there)) > MOVED_MM
            feed = self.feed_mm_per_min if moved else self.feed_deg_per_min
            word = ("G53 G1 " + " ".join(f"{a.upper()}{point[a]:.6f}" for a in self.axes) + f" F{feed:.3f}")
            self._mdi(word, what)
            self._after_mdi(what)
            self._arrived(point, what)
            here = there

    def _arrived(self, point: Mapping[str, float], what: str) -> None:
        """The commanded and actual positions of X Y Z A C at ``point`` (LinuxCNC's status may lag a servo
        cycle or two behind the MDI's done: polled for at most the driver's timeout)."""
        deadline = time.monotonic() + self.timeout_s
        while True:
            off = {}
            for a in self.axes:
                index = AXES.index(a.upper())
                commanded, actual = self.rsh.position("abs_cmd_pos", index), self.rsh.position("abs_act_pos", index)
                if max(abs(commanded - point[a]), abs(actual - point[a])) > POSITION_TOLERANCE:
                    off[a] = actual
            if not off:
                return
            if time.monotonic() > deadline:
                raise InstrumentFault(self.name, f"{what}: stopped short at " + self._shown(off)
                                      + ": the move was cut short (abort, E-stop or a limit)")
            time.sleep(0.01)

    def joint_positions(self) -> dict[str, float]:
        """Each joint's actual position (``get joint_pos N``), where LinuxCNC's kinematics put it."""
        return self._joints_over(self.rsh)

    def _joints_over(self, session: Session) -> dict[str, float]:
        return {axis: session.position("joint_pos", joint) for axis, joint in self.joints.items()}

    def wait_stopped(self, timeout_s: float = STOP_WATCH_S) -> StopSeen:
        """The five joints (``get joint_pos``) read over the session kept for stopping until they no longer
        change: the moving session may still wait for the move's reply."""
        return self._watch_stopped(lambda rsh: [self._joints_over(rsh)[a] for a in self.axes], self.show_joints,
                                   self.still_within, timeout_s)

    @staticmethod
    def _shown(point: Mapping[str, float]) -> str:
        return " ".join(f"{a.upper()} {v:.6f}" for a, v in point.items())
