"""A LinuxCNC controller's rotary axis over linuxcncrsh, its text interface (TCP, default port 5007).

Every command is one of linuxcncrsh(1)'s (docs/protocols/linuxcnc.md cites each): the session
opens with ``hello EMC rtcal 1.0`` (the server's ``HELLO ACK <name> <version>`` is the
identity), turns echo off and verbose on (so every ``set`` answers ``SET <CMD> ACK`` or ``NAK``),
takes control with ``set enable EMCTOO``, makes every ``set`` wait until LinuxCNC has done it
(``set set_wait done``). It never changes the E-stop or the machine's power: a controller in
E-stop (``get estop`` → ``ESTOP ON``) or switched off (``get machine`` → ``MACHINE OFF``) is
refused with a fault naming it (release E-stop and switch the machine on at the controller; man:
"E-stop "on" means the machine is in the estop state and won't run"). An unhomed joint is homed
(``set mode manual``, ``set home <joint>``) only when the address says ``home=1``; else refused.
Then ``set mode mdi``.

A move is one MDI line, ``G0 C<deg>`` (``G1 … F<deg/min>`` with ``speed_deg_per_s``), answered
once the motion is done. linuxcncrsh answers ACK also for a move that an E-stop or an abort cut
short, so every move is checked: E-stop off, machine on, no error queued (``get error``), the
axis's commanded and actual positions at the target. The approach direction and overshoot are
the procedure's (rtcal.engine.motion): the driver goes where it is told, by the shortest
way LinuxCNC takes for a linear (non-wrapped) joint.

Errors queue: LinuxCNC's NML error channel (``emcError``) is a queue of errors, operator
displays and texts, and emcrsh's ``getError``/``getOperatorDisplay``/``getOperatorText``
(src/emc/usr_intf/emcrsh.cc) each take its next message, of whatever kind (shcom.cc
``updateError()``), and answer their own kind's or ``OK``. A refused MDI line queues several (2.9, seen: "Linear
move on line 0 would exceed C's positive limit", "… joint 0's positive limit", "invalid params in
linear command"): the driver reads the queue empty after every refusal, so the next move starts
clean; a refusal for a limit is ``OutOfLimits`` (nothing moved), any other a plain fault.

Compensation type: the table's meaning depends on the INI's ``COMP_FILE_TYPE`` (0: nominal and
measured positions; 1: nominal and trims; usrmotLoadComp, src/emc/motion/usrmotintf.cc), which
linuxcncrsh does not report and which no position it reports shows (below). Where LinuxCNC runs
on this host, the driver reads the INI ``get inifile`` names and the joint's table as LinuxCNC
does; corrections beyond 1° mean a table of the other type (rtcal writes type 0): a fault naming
the type. Elsewhere the identity says the type was not checked.

LinuxCNC's positions (``get abs_act_pos``, ``get joint_pos``) are uncompensated: a joint's
``COMP_FILE`` shows only in HAL (``joint.N.motor-pos-cmd``). The feedback the checks compare is
the joint's actual position; the protocol prints six decimals, hence ``step_deg`` 1e-6.
"""

from __future__ import annotations

import math
import re
import socket
import time
from pathlib import Path

from drivers.addresses import Address, AddressError
from drivers.errors import EmergencyStop, InstrumentFault, InstrumentTimeout, OutOfLimits
from drivers.interfaces import RotaryStage
from drivers.models import Framing

AXES = "XYZABCUVW"  # linuxcncrsh numbers a position's axes in this order (abs_act_pos 5 is C)
CONNECT_PASSWORD, ENABLE_PASSWORD = "EMC", "EMCTOO"  # linuxcncrsh's documented defaults (no secret: see its man page)
MAX_LINE_BYTES = 4096
POSITION_TOLERANCE_DEG = 2e-6  # two units of the six decimals linuxcncrsh prints
MAX_STRAY = 4  # late extra reply lines skipped before a request's own reply
MAX_QUEUED = 64  # rounds of reading LinuxCNC's message queue; a longer queue is a controller in trouble
LIMIT_ERROR = re.compile(r"exceed .*limit", re.IGNORECASE)  # 2.9: "Linear move on line 0 would exceed C's positive limit"
MAX_COMP_DEG = 1.0  # a rotary table's correction beyond this is a table read as the wrong COMP_FILE_TYPE
LOCAL_HOSTS = {"127.0.0.1", "localhost", "::1"}


class LinuxCncStage(RotaryStage):
    """``linuxcncrsh://HOST:PORT?axis=C&joint=0``: axis letter (default C), its joint number (default
    0; checked to be an angular joint in degrees), ``speed_deg_per_s`` (G1 at that feed; default G0,
    the joint's rapid), ``move_timeout_s`` (longest wait for one move, default 60) and ``home=1``
    (rtcal may home an unhomed joint; default: an unhomed joint is refused)."""

    name = "stage"
    framing: Framing | None
    options: dict[str, tuple[float, float, bool]]
    model, kind, schemes, framing, options = "linuxcnc", "stage", ("linuxcncrsh",), None, {}
    step_deg = 1e-6

    def __init__(self, address: Address, timeout_s: float = 2.0, limits_deg: tuple[float, float] = (-360.0, 360.0),
                 may_move: bool = True, **_: object):
        """``may_move=False`` (`rtcal probe`, `rtcal check`): never homes or changes the mode, whatever the address says."""
        self.address, self.timeout_s, self.limits_deg = address, timeout_s, limits_deg
        self.axis = address.text("axis", "C").upper()
        if self.axis not in AXES:
            raise AddressError(f"option axis={self.axis!r}: a LinuxCNC axis is a letter ({' '.join(AXES)}), e.g. axis=C")
        self.axis_index = AXES.index(self.axis)
        self.joint = int(address.option("joint", 0))
        self.move_timeout_s = address.option("move_timeout_s", 60.0)
        self.feed_deg_per_min = 60.0 * address.option("speed_deg_per_s", 0.0)  # 0: G0, the joint's rapid
        self.may_move = may_move
        self.may_home = may_move and address.option("home", 0) == 1
        self.server = ""
        self.compensation = "not checked"
        self.stray: list[str] = []
        self._buffer = b""
        try:
            self.sock: socket.socket | None = socket.create_connection((address.host, address.port), timeout=timeout_s)
        except OSError as exc:
            raise InstrumentTimeout(self.name, f"cannot connect to linuxcncrsh at {address.host}:{address.port}: {exc}") from None
        try:
            self._open_session()
        except BaseException:
            self.close()
            raise

    # -- the wire
    def _connected(self, what: str) -> socket.socket:
        """The connection (None once closed)."""
        if self.sock is None:
            raise InstrumentFault(self.name, f"{what}: the connection to LinuxCNC is closed")
        return self.sock

    def _send(self, line: str) -> None:
        sock = self._connected(repr(line))
        try:
            sock.sendall(line.encode("ascii") + b"\r\n")
        except OSError as exc:
            raise InstrumentFault(self.name, f"{line!r}: connection to LinuxCNC lost ({exc!r})") from None

    def _line(self, what: str, timeout_s: float) -> str:
        """The next non-empty reply line (linuxcncrsh ends replies with \\r\\n; stray empty lines are skipped)."""
        deadline = time.monotonic() + timeout_s
        while True:
            while b"\n" in self._buffer:
                raw, self._buffer = self._buffer.split(b"\n", 1)
                text = raw.decode("ascii", errors="replace").strip()
                if text:
                    return text
            if len(self._buffer) > MAX_LINE_BYTES:
                raise InstrumentFault(self.name, f"{what}: a reply line longer than {MAX_LINE_BYTES} bytes")
            left = deadline - time.monotonic()
            if left <= 0:
                raise InstrumentTimeout(self.name, f"{what}: no reply in {timeout_s:g} s")
            sock = self._connected(what)
            try:
                sock.settimeout(left)
                chunk = sock.recv(4096)
            except socket.timeout:
                raise InstrumentTimeout(self.name, f"{what}: no reply in {timeout_s:g} s") from None
            except OSError as exc:
                raise InstrumentFault(self.name, f"{what}: connection to LinuxCNC lost ({exc!r})") from None
            if not chunk:
                raise InstrumentFault(self.name, f"{what}: LinuxCNC closed the connection (controller shut down or killed)")
            self._buffer += chunk

    def _reply(self, line: str, starts: tuple[str, ...], timeout_s: float) -> str:
        """The reply to ``line``: the next line that starts as its reply does. A line that does not is a
        late extra reply to an earlier request (linuxcncrsh 2.9 sometimes sends one) and is skipped, at
        most MAX_STRAY of them; ``stray`` keeps the last few for messages."""
        for _ in range(MAX_STRAY + 1):
            reply = self._line(line, timeout_s)
            if reply.upper().startswith(starts) or reply.upper() in {s.strip() for s in starts}:
                return reply
            self.stray = (self.stray + [reply[:80]])[-MAX_STRAY:]
        raise InstrumentFault(self.name, f"{line!r}: no reply of its kind, only {self.stray!r}")

    def get(self, item: str, *args: object) -> list[str]:
        """``get ITEM [ARGS]`` → the words after the echoed item name (``ABS_ACT_POS 5 30.000000`` → ['5', '30.000000'])."""
        line = " ".join(["get", item, *map(str, args)])
        self._send(line)
        words = self._reply(line, (item.upper(),), self.timeout_s).split()
        if words[1:] == ["NAK"]:
            raise InstrumentFault(self.name, f"{line!r}: refused (NAK)")
        return words[1:]

    def set(self, item: str, *args: object, timeout_s: float | None = None) -> None:
        """``set ITEM ARGS``; waits for ``SET ITEM ACK`` (verbose mode), raises with LinuxCNC's reason on NAK."""
        line = " ".join(["set", item, *map(str, args)])
        self._send(line)
        reply = self._reply(line, (f"SET {item.upper()} ",), timeout_s or self.timeout_s)
        if reply.upper() == f"SET {item.upper()} ACK":
            return
        if reply.upper() == f"SET {item.upper()} NAK":
            raise InstrumentFault(self.name, f"{line!r} refused: {self._why()}")
        raise InstrumentFault(self.name, f"{line!r}: unexpected reply {reply[:120]!r}")

    def _why(self) -> str:
        """What the controller says about a refusal: its queued error, E-stop, machine power, control."""
        try:
            facts = [f"E-stop {self.get('estop')[0].lower()}", f"machine {self.get('machine')[0].lower()}",
                     f"this session's control {self.get('enable')[0].lower()}"]
            errors = self._drain_errors()
        except InstrumentFault as exc:
            return f"(and asking why failed: {exc})"
        return "; ".join(([f"LinuxCNC: {'; '.join(errors)}"] if errors else []) + facts)

    def _message(self, item: str) -> str:
        """``get error``/``operator_display``/``operator_text``: the text, or "" for ``<ITEM> OK``."""
        words = self.get(item)
        return "" if [w.upper() for w in words] == ["OK"] else " ".join(words)

    def _drain_errors(self) -> list[str]:
        """Every queued message, until a round of ``get error``, ``get operator_display`` and ``get
        operator_text`` says OK: errors, operator displays and texts share one NML queue, and each of
        these requests reads its next message whatever its kind (shcom.cc ``updateError``), so an
        ``ERROR OK`` alone may hide an error queued behind a display message."""
        messages: list[str] = []
        for _ in range(MAX_QUEUED):
            heard = [(item, self._message(item)) for item in ("error", "operator_display", "operator_text")]
            if not any(text for _, text in heard):
                return messages
            messages += [text if item == "error" else f"{item.replace('_', ' ')}: {text}" for item, text in heard if text]
        raise InstrumentFault(self.name, f"LinuxCNC's message queue does not empty ({len(messages)} messages, the last: "
                                         f"{messages[-1]!r})")

    # -- session and machine state
    def _open_session(self) -> None:
        self._send(f"hello {CONNECT_PASSWORD} rtcal 1.0")
        reply = self._line("hello", self.timeout_s).split()
        if reply[:2] != ["HELLO", "ACK"] or len(reply) < 4:
            raise InstrumentFault(self.name, f"hello refused: {' '.join(reply)[:120]!r} (is this linuxcncrsh?)")
        self.server = f"{reply[2]} {reply[3]}"
        self._send("set echo off")  # acknowledged by the last echo, then nothing more
        self._line("set echo off", self.timeout_s)
        self._send("set verbose on")
        if self._line("set verbose on", self.timeout_s).upper() != "SET VERBOSE ACK":
            raise InstrumentFault(self.name, "set verbose on: not acknowledged")
        self.set("enable", ENABLE_PASSWORD)
        self.set("set_wait", "done")
        kind = self.get("joint_type", self.joint)[-1:]
        units = self.get("joint_units")  # every joint's: 2.9 answers the one-joint form with its type
        unit = units[self.joint:self.joint + 1]
        if kind != ["ANGULAR"] or unit != ["DEG"]:
            raise InstrumentFault(self.name, f"joint {self.joint} is {' '.join(kind).lower() or '?'} in "
                                             f"{' '.join(unit).lower() or '?'}, not an angular joint in degrees: "
                                             "give joint= the rotary axis's joint")
        self._drain_errors()  # what an earlier session left queued is not this run's
        self._check_ready("connect")  # E-stop and power are the operator's: refused, never changed
        self._check_compensation()
        if self.get("joint_homed", self.joint)[-1:] != ["YES"]:
            if not self.may_home:
                raise InstrumentFault(self.name, f"joint {self.joint} is not homed: home it at the controller"
                                      + (", or add home=1 to the stage's address to let rtcal home it" if self.may_move
                                         else " (a probe never homes)"))
            self.set("mode", "manual", timeout_s=self.move_timeout_s)
            self.set("home", self.joint, timeout_s=self.move_timeout_s)
            deadline = time.monotonic() + self.move_timeout_s  # set_wait done does not wait for homing to finish
            while self.get("joint_homed", self.joint)[-1:] != ["YES"]:
                if time.monotonic() > deadline:
                    raise InstrumentFault(self.name, f"joint {self.joint} did not home: {self._why()}")
                time.sleep(0.05)
        if self.may_move:
            self.set("mode", "mdi", timeout_s=self.move_timeout_s)

    def _check_compensation(self) -> None:
        """The joint's COMP_FILE read as LinuxCNC reads it with its COMP_FILE_TYPE, where the INI
        ``get inifile`` names is this host's (linuxcncrsh reports neither the type nor any compensated
        position): corrections beyond MAX_COMP_DEG are a fault naming the type."""
        if self.address.host not in LOCAL_HOSTS:
            self.compensation = "COMP_FILE_TYPE not checked (LinuxCNC runs on another host)"
            return
        words = self.get("inifile")
        ini = Path(" ".join(words)) if words else None
        try:
            values = ini_section(ini.read_text(errors="replace"), f"JOINT_{self.joint}") if ini else None
        except OSError:
            values = None
        if ini is None or values is None:
            self.compensation = f"COMP_FILE_TYPE not checked (INI {ini} not readable here)"
            return
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

    def _mdi_mode(self, what: str) -> None:
        """MDI mode, entered and confirmed (``get mode``): LinuxCNC may leave it on its own, e.g. as homing ends."""
        deadline = time.monotonic() + self.move_timeout_s
        while self.get("mode")[:1] != ["MDI"]:
            if time.monotonic() > deadline:
                raise InstrumentFault(self.name, f"{what}: LinuxCNC does not enter MDI mode: {self._why()}")
            self.set("mode", "mdi", timeout_s=self.move_timeout_s)
            time.sleep(0.02)

    def _check_ready(self, what: str) -> None:
        """E-stop off, machine on, this session in control; else a fault saying which (emcrsh ``getEStop``:
        ``ESTOP ON`` while the task is in its ESTOP state)."""
        if self.get("estop")[0].upper() != "OFF":
            raise EmergencyStop(self.name, f"{what}: E-stop is on at the controller (release it there and switch the "
                                           "machine on; rtcal never does)")
        if self.get("machine")[0].upper() != "ON":
            raise InstrumentFault(self.name, f"{what}: the machine is off at the controller (switch it on there; rtcal "
                                             "never does)")
        if self.get("enable")[0].upper() != "ON":
            raise InstrumentFault(self.name, f"{what}: another linuxcncrsh session took control of the machine")

    # -- the interface
    def identity(self) -> str:
        return f"LinuxCNC linuxcncrsh server {self.server}; axis {self.axis}, joint {self.joint}; {self.compensation}"

    def move_to(self, angle_deg: float) -> None:
        self.check_target(angle_deg)
        what = f"move to {angle_deg:.6f}°"
        stale = self._drain_errors()
        if stale:
            raise InstrumentFault(self.name, f"{what}: LinuxCNC reported before the move: {'; '.join(stale)}")
        self._mdi_mode(what)
        word = f"G1 {self.axis}{angle_deg:.6f} F{self.feed_deg_per_min:.3f}" if self.feed_deg_per_min else f"G0 {self.axis}{angle_deg:.6f}"
        self._mdi(word, what)
        self._check_ready(what)
        errors = self._drain_errors()
        if errors:
            raise InstrumentFault(self.name, f"{what}: LinuxCNC: {'; '.join(errors)}")
        # "done" is the MDI command's; the status LinuxCNC reports may lag a servo cycle or two behind
        # (seen: 0.00005° short of the target right after the ACK, there a moment later), so the
        # position is polled until it is the target, for at most the driver's timeout
        deadline = time.monotonic() + self.timeout_s
        while True:
            commanded = self._position("abs_cmd_pos")
            actual = self._position("abs_act_pos")
            if abs(commanded - angle_deg) <= POSITION_TOLERANCE_DEG and abs(actual - angle_deg) <= POSITION_TOLERANCE_DEG:
                return
            if time.monotonic() > deadline:
                raise InstrumentFault(self.name, f"{what}: the axis stopped at {actual:.6f}° (commanded {commanded:.6f}°): "
                                                 "the move was cut short (abort, E-stop or a limit)")
            time.sleep(0.01)

    def _mdi(self, word: str, what: str) -> None:
        """``set mdi WORD``; a NAK empties LinuxCNC's error queue (the next move starts clean) and is
        OutOfLimits when LinuxCNC names a limit, else a fault with every queued message."""
        line = f"set mdi {word}"
        self._send(line)
        reply = self._reply(line, ("SET MDI ",), self.move_timeout_s).upper()
        if reply == "SET MDI ACK":
            return
        if reply != "SET MDI NAK":
            raise InstrumentFault(self.name, f"{line!r}: unexpected reply {reply[:120]!r}")
        errors = self._drain_errors()
        if any(LIMIT_ERROR.search(e) for e in errors):
            raise OutOfLimits(self.name, f"{what}: LinuxCNC refused it: {'; '.join(errors)}")
        raise InstrumentFault(self.name, f"{what}: LinuxCNC refused {word!r}: {self._why()}"
                                         + (f"; LinuxCNC: {'; '.join(errors)}" if errors else ""))

    def home(self) -> None:
        """The joint is homed in place when the session opens; homing here returns to the datum, 0°."""
        self.move_to(0.0)

    def _position(self, item: str) -> float:
        words = self.get(item, self.axis_index)
        try:
            value = float(words[-1])
        except (ValueError, IndexError):
            value = math.nan
        if len(words) != 2 or words[0] != str(self.axis_index) or not math.isfinite(value):
            raise InstrumentFault(self.name, f"get {item} {self.axis_index}: unexpected reply {' '.join(words)[:120]!r}")
        return value

    def position_deg(self) -> float:
        """The axis's actual position (``get abs_act_pos``), uncompensated as LinuxCNC reports it."""
        return self._position("abs_act_pos")

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

    def stop(self) -> None:
        """Safe state: abort the MDI move (``set abort``); the machine stays on and homed."""
        self.set("abort")

    def reset_alarm(self) -> None:
        """Clear LinuxCNC's queued errors and re-enter MDI; an E-stop or a lost session stays a fault."""
        self._drain_errors()
        self._check_ready("recover")
        self.set("mode", "mdi")

    def close(self) -> None:
        sock, self.sock = getattr(self, "sock", None), None
        if sock is not None:
            try:
                sock.close()
            except OSError:
                pass


def ini_section(text: str, section: str) -> dict[str, str]:
    """``KEY = value`` of one INI section as LinuxCNC's IniFile reads it (``#`` and ``;`` start comments;
    the first of a repeated key counts)."""
    values: dict[str, str] = {}
    current = ""
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("[") and "]" in line:
            current = line[1:line.index("]")].strip()
        elif current == section and "=" in line:
            key, value = line.split("=", 1)
            values.setdefault(key.strip(), value.strip())
    return values


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
