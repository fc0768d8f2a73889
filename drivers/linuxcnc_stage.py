"""A LinuxCNC controller's rotary axis over linuxcncrsh, its text interface (TCP, default port 5007).

Every command is one of linuxcncrsh(1)'s (docs/protocols/linuxcnc.md cites each). A session opens
with ``hello EMC rtcal 1.0`` (the server's ``HELLO ACK <name> <version>`` is the identity; ``HELLO
NAK`` to this well-formed hello is a wrong connect password), turns echo off and verbose on (so
every ``set`` answers ``SET <CMD> ACK`` or ``NAK``).

Before anything is commanded the driver checks what it is given and what the controller is doing,
and refuses — never changes — what is not its own: the joint must be angular, in degrees, and
(where the INI ``get inifile`` names is on this host) the axis letter's joint in the kinematics'
``coordinates`` (an address error, exit 2: ``axis=Z&joint=3`` moved the Z axis while reporting the
table); a program running in AUTO, or an MDI command executing (``get mode``, ``get
program_status``), is refused naming it; E-stop on (``ESTOP ON``) or the machine off is refused
(release E-stop and switch the machine on at the controller; man: "E-stop "on" means the machine is
in the estop state and won't run"). An unhomed joint is homed (``set mode manual``, ``set home
<joint>``) only when the address says ``home=1``; else refused.

Control: ``set enable EMCTOO`` makes this session the one in control and silently takes control
from any other linuxcncrsh console (an operator's, a cell controller's); linuxcncrsh has no query
that shows another session holds it (``get enable`` answers for the asking session only; emcrsh's
own to-do list: "Get enable to tell peer connections which connection has control"). So a session
that will move the table takes control only when the address says ``take_control=1``; without it,
an address error saying why. `rtcal probe` and `rtcal check` (``may_move=False``) never take
control, change the mode or read LinuxCNC's message queue empty: they only ask.

Stopping: one linuxcncrsh session answers one request at a time, so a ``set abort`` sent on the
session whose ``set mdi`` waits for the move to end is read only after the move ended (seen: Ctrl-C
at 21° of a 0→90° move, the table went on to 90°). A second session, opened at connect and kept for
stopping, sends ``set enable`` and ``set abort`` at once (seen: the table at rest 0.14 s after the
abort); ``wait_stopped`` reads the axis position over that session until it no longer changes. A
linuxcncrsh that refuses the second session (its ``-s/--sessions`` limit closes the connection) is
refused at connect, named so.

A move is one MDI line, ``G0 C<deg>`` (``G1 … F<deg/min>`` with ``speed_deg_per_s``), then ``set
wait done`` (man: "force a wait for the previous command to be received, or done"), which answers
once the motion is done. The driver never sets ``set_wait``: in LinuxCNC 2.9 it is one setting for
every session (emcrsh's ``emcWaitType``), an operator's console's too. linuxcncrsh answers ACK also
for a move that an E-stop or an abort cut short, so every move is checked: E-stop off, machine on,
no error queued (``get error``), the axis's commanded and actual positions at the target. The
approach direction and overshoot are the procedure's (rtcal.engine.motion): the driver goes where
it is told, by the shortest way LinuxCNC takes for a linear (non-wrapped) joint.

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

from drivers.addresses import Address, AddressError, ROTARY_AXES, check_take_control
from drivers.errors import EmergencyStop, InstrumentFault, InstrumentTimeout, OutOfLimits
from drivers.interfaces import RotaryStage, StopSeen, STOP_WATCH_S, watch_still
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
# the joint order of kinematics modules without ``coordinates=`` (man 9 kins): letter i is joint i
DEFAULT_COORDINATES = {"trivkins": "XYZABCUVW", "xyzac-trt-kins": "XYZAC", "xyzbc-trt-kins": "XYZBC"}
SESSION_LIMIT = ("linuxcncrsh closed the connection before answering hello, as it refuses a session beyond its "
                 "-s/--sessions limit (LinuxCNC 2.9 counts every session since it started, closed ones too; rtcal "
                 "needs two, one kept for stopping a move at once): start linuxcncrsh without -s, or restart LinuxCNC")


class Session:
    """One linuxcncrsh connection: a request, then its reply (``what`` names it in messages)."""

    def __init__(self, name: str, address: Address, timeout_s: float, what: str):
        self.name, self.timeout_s, self.what = name, timeout_s, what
        self.stray: list[str] = []
        self._buffer = b""
        self.server = ""
        try:
            self.sock: socket.socket | None = socket.create_connection((address.host, address.port), timeout=timeout_s)
        except OSError as exc:
            raise InstrumentTimeout(name, f"cannot connect to linuxcncrsh at {address.host}:{address.port}: {exc}") from None
        try:
            self._hello()
        except BaseException:
            self.close()
            raise

    def _hello(self) -> None:
        """hello, echo off, verbose on. A connection closed before the hello's reply is linuxcncrsh's
        session limit; ``HELLO NAK`` to this well-formed hello is the connect password (emcrsh commandHello)."""
        self.send(f"hello {CONNECT_PASSWORD} rtcal 1.0")
        try:
            reply = self.line("hello", self.timeout_s).split()
        except InstrumentFault as exc:
            if "closed the connection" in str(exc) or "connection to LinuxCNC lost" in str(exc):
                raise InstrumentFault(self.name, f"{self.what}: {SESSION_LIMIT}") from None
            raise
        if reply[:2] == ["HELLO", "NAK"]:
            raise InstrumentFault(self.name, f"linuxcncrsh refused rtcal's connect password (HELLO NAK): it was started "
                                             f"with a --connectpw other than its documented default {CONNECT_PASSWORD!r}, "
                                             "the one rtcal gives (docs/protocols/linuxcnc.md)")
        if reply[:2] != ["HELLO", "ACK"] or len(reply) < 4:
            raise InstrumentFault(self.name, f"hello refused: {' '.join(reply)[:120]!r} (is this linuxcncrsh?)")
        self.server = f"{reply[2]} {reply[3]}"
        self.send("set echo off")  # acknowledged by the last echo, then nothing more
        self.line("set echo off", self.timeout_s)
        self.send("set verbose on")
        if self.line("set verbose on", self.timeout_s).upper() != "SET VERBOSE ACK":
            raise InstrumentFault(self.name, "set verbose on: not acknowledged")

    def connected(self, what: str) -> socket.socket:
        """The connection (None once closed)."""
        if self.sock is None:
            raise InstrumentFault(self.name, f"{what}: the connection to LinuxCNC is closed")
        return self.sock

    def send(self, line: str) -> None:
        sock = self.connected(repr(line))
        try:
            sock.sendall(line.encode("ascii") + b"\r\n")
        except OSError as exc:
            raise InstrumentFault(self.name, f"{line!r}: connection to LinuxCNC lost ({exc!r})") from None

    def line(self, what: str, timeout_s: float) -> str:
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
            sock = self.connected(what)
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

    def reply(self, line: str, starts: tuple[str, ...], timeout_s: float) -> str:
        """The reply to ``line``: the next line that starts as its reply does. A line that does not is a
        late extra reply to an earlier request (linuxcncrsh 2.9 sometimes sends one) and is skipped, at
        most MAX_STRAY of them; ``stray`` keeps the last few for messages."""
        for _ in range(MAX_STRAY + 1):
            reply = self.line(line, timeout_s)
            if reply.upper().startswith(starts) or reply.upper() in {s.strip() for s in starts}:
                return reply
            self.stray = (self.stray + [reply[:80]])[-MAX_STRAY:]
        raise InstrumentFault(self.name, f"{line!r}: no reply of its kind, only {self.stray!r}")

    def get(self, item: str, *args: object) -> list[str]:
        """``get ITEM [ARGS]`` → the words after the echoed item name (``ABS_ACT_POS 5 30.000000`` → ['5', '30.000000'])."""
        line = " ".join(["get", item, *map(str, args)])
        self.send(line)
        words = self.reply(line, (item.upper(),), self.timeout_s).split()
        if words[1:] == ["NAK"]:
            raise InstrumentFault(self.name, f"{line!r}: refused (NAK)")
        return words[1:]

    def set(self, item: str, *args: object, timeout_s: float | None = None) -> bool:
        """``set ITEM ARGS``: True on ``SET ITEM ACK`` (verbose mode), False on NAK."""
        line = " ".join(["set", item, *map(str, args)])
        self.send(line)
        reply = self.reply(line, (f"SET {item.upper()} ",), timeout_s or self.timeout_s)
        if reply.upper() in (f"SET {item.upper()} ACK", f"SET {item.upper()} NAK"):
            return reply.upper().endswith("ACK")
        raise InstrumentFault(self.name, f"{line!r}: unexpected reply {reply[:120]!r}")

    def position(self, item: str, index: int) -> float:
        """``get ITEM INDEX`` (abs_act_pos, abs_cmd_pos, joint_pos) as degrees."""
        words = self.get(item, index)
        try:
            value = float(words[-1])
        except (ValueError, IndexError):
            value = math.nan
        if len(words) != 2 or words[0] != str(index) or not math.isfinite(value):
            raise InstrumentFault(self.name, f"get {item} {index}: unexpected reply {' '.join(words)[:120]!r}")
        return value

    def close(self) -> None:
        sock, self.sock = self.sock, None
        if sock is not None:
            try:
                sock.close()
            except OSError:
                pass


class LinuxCncStage(RotaryStage):
    """``linuxcncrsh://HOST:PORT?axis=C&joint=0&take_control=1``: the rotary axis letter (A, B or C;
    default C) and its joint number (default 0; checked to be an angular joint in degrees and, where
    the INI is on this host, the letter's joint in the kinematics), ``take_control=1`` (rtcal may take
    control from any other linuxcncrsh console: needed to move), ``speed_deg_per_s`` (G1 at that feed;
    default G0, the joint's rapid), ``move_timeout_s`` (longest wait for one move, default 60) and
    ``home=1`` (rtcal may home an unhomed joint; default: an unhomed joint is refused)."""

    name = "stage"
    framing: Framing | None
    options: dict[str, tuple[float, float, bool]]
    model, kind, schemes, framing, options = "linuxcnc", "stage", ("linuxcncrsh",), None, {}
    step_deg = 1e-6

    def __init__(self, address: Address, timeout_s: float = 2.0, limits_deg: tuple[float, float] = (-360.0, 360.0),
                 may_move: bool = True, **_: object):
        """``may_move=False`` (`rtcal probe`, `rtcal check`): only asks — never takes control, homes or
        changes the mode, whatever the address says."""
        self.address, self.timeout_s, self.limits_deg = address, timeout_s, limits_deg
        self.axis = address.text("axis", "C").upper()
        if self.axis not in ROTARY_AXES:
            raise AddressError(f"option axis={self.axis!r}: a LinuxCNC rotary axis is A, B or C (X Y Z U V W are linear)")
        self.axis_index = AXES.index(self.axis)
        self.joint = int(address.option("joint", 0))
        self.move_timeout_s = address.option("move_timeout_s", 60.0)
        self.feed_deg_per_min = 60.0 * address.option("speed_deg_per_s", 0.0)  # 0: G0, the joint's rapid
        self.may_move = may_move
        self.may_home = may_move and address.option("home", 0) == 1
        if may_move:
            check_take_control(address)
        self.compensation = "not checked"
        self.mapping = f"axis {self.axis}, joint {self.joint}"
        self.stopped = False  # a stop handed control to the stop session: this one moves nothing more
        self.stopper: Session | None = None
        self._ini_read: tuple[Path, str | None] | None = None
        self.rsh = Session(self.name, address, timeout_s, "the session")
        try:
            self._open_session()
        except BaseException:
            self.close()
            raise

    # -- the wire (the moving session)
    def get(self, item: str, *args: object) -> list[str]:
        return self.rsh.get(item, *args)

    def set(self, item: str, *args: object, timeout_s: float | None = None, wait: bool = False) -> None:
        """``set ITEM ARGS``, then (``wait``) ``set wait done``: answered once LinuxCNC has done it, whatever
        ``set_wait`` another console chose; raises with LinuxCNC's reason on NAK."""
        line = " ".join(["set", item, *map(str, args)])
        if not self.rsh.set(item, *args, timeout_s=timeout_s):
            raise InstrumentFault(self.name, f"{line!r} refused: {self._why()}")
        if wait and not self.rsh.set("wait", "done", timeout_s=timeout_s):
            raise InstrumentFault(self.name, f"{line!r} failed: {self._why()}")

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
        """Everything is asked before anything is commanded; control is taken last."""
        self._check_joint()
        self._check_compensation()
        self._check_idle("connect")
        self._check_ready("connect")  # E-stop and power are the operator's: refused, never changed
        homed = self.get("joint_homed", self.joint)[-1:] == ["YES"]
        if not homed and not self.may_home:
            raise InstrumentFault(self.name, f"joint {self.joint} is not homed: home it at the controller"
                                  + (", or add home=1 to the stage's address to let rtcal home it" if self.may_move
                                     else " (a probe never homes)"))
        if not self.may_move:
            return
        self.stopper = Session(self.name, self.address, self.timeout_s, "the session kept for stopping")
        if not self.rsh.set("enable", ENABLE_PASSWORD):
            raise InstrumentFault(self.name, f"linuxcncrsh refused rtcal's enable password (SET ENABLE NAK): it was "
                                             f"started with an --enablepw other than its documented default "
                                             f"{ENABLE_PASSWORD!r}, the one rtcal gives (docs/protocols/linuxcnc.md)")
        self._drain_errors()  # what an earlier session left queued is not this run's
        if not homed:
            self.set("mode", "manual", timeout_s=self.move_timeout_s, wait=True)
            self.set("home", self.joint, timeout_s=self.move_timeout_s, wait=True)
            deadline = time.monotonic() + self.move_timeout_s  # the wait does not wait for homing to finish
            while self.get("joint_homed", self.joint)[-1:] != ["YES"]:
                if time.monotonic() > deadline:
                    raise InstrumentFault(self.name, f"joint {self.joint} did not home: {self._why()}")
                time.sleep(0.05)
        self._mdi_mode("connect")

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
        ini = self._ini()
        if ini is None or ini[1] is None:
            self.mapping = (f"axis {self.axis}, joint {self.joint} (not checked: "
                            + ("LinuxCNC on another host" if ini is None else "INI unreadable") + ")")
            return
        kins, traj = ini_section(ini[1], "KINS"), ini_section(ini[1], "TRAJ")
        words = kins.get("KINEMATICS", "").split()
        module = words[0] if words else ""
        given = [w.split("=", 1)[1] for w in words[1:] if w.lower().startswith("coordinates=")]
        if given:
            letters, source = given[0].upper(), f"{module} coordinates={given[0]}"
        elif module in DEFAULT_COORDINATES:
            letters, source = DEFAULT_COORDINATES[module], f"{module}'s default {DEFAULT_COORDINATES[module]}"
        else:
            letters = "".join(traj.get("COORDINATES", "").split()).upper()
            source = f"[TRAJ] COORDINATES {letters}; {module or 'the kinematics'} gives no coordinates="
        if not letters:
            self.mapping = f"axis {self.axis}, joint {self.joint} (not checked: the INI names no coordinates)"
            return
        joints = [j for j, letter in enumerate(letters) if letter == self.axis]
        if self.joint not in joints:
            mine = letters[self.joint] if self.joint < len(letters) else ""
            hint = (f"axis {self.axis} is joint {' and '.join(map(str, joints))}: give joint={joints[0]}" if joints
                    else f"this machine has no axis {self.axis}" + (f"; joint {self.joint} is {mine}: give axis={mine}"
                                                                      if mine and mine in ROTARY_AXES else ""))
            raise AddressError(f"axis {self.axis} with joint {self.joint}: {hint} ({source}, {ini[0].name})")
        self.mapping = f"axis {self.axis} is joint {self.joint} ({source})"

    def _ini(self) -> tuple[Path, str | None] | None:
        """The INI ``get inifile`` names and its text (None: not readable here); None where LinuxCNC runs
        on another host. Read once."""
        if self.address.host not in LOCAL_HOSTS:
            return None
        if self._ini_read is None:
            path = Path(" ".join(self.get("inifile")))
            try:
                self._ini_read = path, path.read_text(errors="replace") if path.name else None
            except OSError:
                self._ini_read = path, None
        return self._ini_read

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

    def _check_idle(self, what: str) -> None:
        """No program running in AUTO and no MDI command executing (``get program_status`` RUNNING or
        PAUSED): the machine is someone else's now; refused naming what it does (a ``set mode mdi``
        would wait behind the program, and fail long after)."""
        status = self.get("program_status")[:1]
        if status == ["IDLE"]:
            return
        mode = (self.get("mode")[:1] or ["?"])[0]
        program = " ".join(self.get("program")) if mode == "AUTO" else ""
        doing = (f"is running a program in AUTO mode ({program or 'no program named'}, {' '.join(status).lower()})"
                 if mode == "AUTO" else f"is executing a command in {mode} mode ({' '.join(status).lower()})")
        raise InstrumentFault(self.name, f"{what}: LinuxCNC {doing}: rtcal takes no machine from a running program; "
                                         "wait until it ends, or stop it at the controller")

    def _mdi_mode(self, what: str) -> None:
        """MDI mode, entered and confirmed (``get mode``): LinuxCNC may leave it on its own, e.g. as homing ends."""
        deadline = time.monotonic() + self.move_timeout_s
        while self.get("mode")[:1] != ["MDI"]:
            if time.monotonic() > deadline:
                raise InstrumentFault(self.name, f"{what}: LinuxCNC does not enter MDI mode: {self._why()}")
            self.set("mode", "mdi", timeout_s=self.move_timeout_s, wait=True)
            time.sleep(0.02)

    def _check_ready(self, what: str) -> None:
        """E-stop off, machine on, and (a session that moves) this session in control; else a fault saying
        which (emcrsh ``getEStop``: ``ESTOP ON`` while the task is in its ESTOP state)."""
        if self.get("estop")[0].upper() != "OFF":
            raise EmergencyStop(self.name, f"{what}: E-stop is on at the controller (release it there and switch the "
                                           "machine on; rtcal never does)")
        if self.get("machine")[0].upper() != "ON":
            raise InstrumentFault(self.name, f"{what}: the machine is off at the controller (switch it on there; rtcal "
                                             "never does)")
        if self.may_move and self.stopper is not None and self.get("enable")[0].upper() != "ON":
            raise InstrumentFault(self.name, f"{what}: another linuxcncrsh session took control of the machine")

    def _moving_session(self, what: str) -> None:
        if self.stopped:
            raise InstrumentFault(self.name, f"{what}: this session was stopped (control went to the session kept "
                                             "for stopping): connect again")
        if not self.may_move:
            raise InstrumentFault(self.name, f"{what}: a probe never moves the machine")

    # -- the interface
    def identity(self) -> str:
        return f"LinuxCNC linuxcncrsh server {self.rsh.server}; {self.mapping}; {self.compensation}"

    def move_to(self, angle_deg: float) -> None:
        self.check_target(angle_deg)
        what = f"move to {angle_deg:.6f}°"
        self._moving_session(what)
        stale = self._drain_errors()
        if stale:
            raise InstrumentFault(self.name, f"{what}: LinuxCNC reported before the move: {'; '.join(stale)}")
        self._check_idle(what)
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
            commanded = self.rsh.position("abs_cmd_pos", self.axis_index)
            actual = self.rsh.position("abs_act_pos", self.axis_index)
            if abs(commanded - angle_deg) <= POSITION_TOLERANCE_DEG and abs(actual - angle_deg) <= POSITION_TOLERANCE_DEG:
                return
            if time.monotonic() > deadline:
                raise InstrumentFault(self.name, f"{what}: the axis stopped at {actual:.6f}° (commanded {commanded:.6f}°): "
                                                 "the move was cut short (abort, E-stop or a limit)")
            time.sleep(0.01)

    def _mdi(self, word: str, what: str) -> None:
        """``set mdi WORD``, then ``set wait done``; a NAK to either empties LinuxCNC's error queue (the next
        move starts clean) and is OutOfLimits when LinuxCNC names a limit, else a fault with every queued message."""
        if self.rsh.set("mdi", word, timeout_s=self.move_timeout_s) and self.rsh.set("wait", "done",
                                                                                    timeout_s=self.move_timeout_s):
            return
        errors = self._drain_errors()
        if any(LIMIT_ERROR.search(e) for e in errors):
            raise OutOfLimits(self.name, f"{what}: LinuxCNC refused it: {'; '.join(errors)}")
        raise InstrumentFault(self.name, f"{what}: LinuxCNC refused {word!r}: {self._why()}"
                                         + (f"; LinuxCNC: {'; '.join(errors)}" if errors else ""))

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

    def stop(self) -> None:
        """Safe state: ``set abort`` over the session kept for stopping, which first takes control (``set
        enable``) — at once, while the moving session may still wait for its move. If that session is
        gone, the abort goes on the moving session (read there after the move in progress) and the
        stop session's failure is raised. The machine stays on and homed."""
        if self.stopper is None:  # a probe: it commanded nothing
            return
        self.stopped = True
        try:
            if self.stopper.set("enable", ENABLE_PASSWORD) and self.stopper.set("abort"):
                return
            estop, machine = self.stopper.get("estop")[0].upper(), self.stopper.get("machine")[0].upper()
            if estop != "OFF" or machine != "ON":  # emcrsh commandSet refuses it to a machine off: nothing moves
                return
            raise InstrumentFault(self.name, "set abort refused by the session kept for stopping, the machine on")
        except InstrumentFault:
            try:
                self.rsh.send("set abort")
            except InstrumentFault:
                pass
            raise

    def wait_stopped(self, timeout_s: float = STOP_WATCH_S) -> StopSeen:
        """The axis position (``get abs_act_pos``) read over the session kept for stopping until it no
        longer changes: the moving session may still wait for the move's reply."""
        if self.stopper is None:
            return StopSeen(True, f"{self.position_deg():.6f}°")
        stopper = self.stopper
        return watch_still(lambda: stopper.position("abs_act_pos", self.axis_index), lambda deg: f"{deg:.6f}°",
                           self.still_within_deg, timeout_s)

    def reset_alarm(self) -> None:
        """Clear LinuxCNC's queued errors and re-enter MDI; an E-stop or a lost session stays a fault."""
        self._moving_session("recover")
        self._drain_errors()
        self._check_ready("recover")
        self.set("mode", "mdi", wait=True)

    def close(self) -> None:
        for session in (getattr(self, "stopper", None), getattr(self, "rsh", None)):
            if session is not None:
                session.close()


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
