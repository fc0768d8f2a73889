"""What every rtcal driver of a LinuxCNC shares: linuxcncrsh, LinuxCNC's text interface (TCP, default
port 5007), and the rules a driver keeps with the controller (docs/protocols/linuxcnc.md cites each
command). The rotary-stage driver (drivers/linuxcnc_stage.py) and the machine-tool driver
(drivers/linuxcnc_machine.py) are this plus what they move.

A session opens with ``hello EMC rtcal 1.0`` (the server's ``HELLO ACK <name> <version>`` is the
identity; ``HELLO NAK`` to this well-formed hello, every time it is sent, is a wrong connect
password), turns echo off and verbose on (so every ``set`` answers ``SET <CMD> ACK`` or ``NAK``).

Replies are checked for their request's form, never trusted for being next: linuxcncrsh 2.9 serves
each session in a thread of its own and splits every request into words with the C library's
``strtok``, whose place in the line is one for the whole server (emcrsh.cc ``parseCommand`` and
every handler: ``strtok(NULL, delims)``). A request parsed while another session's is may take that
one's words: seen with two sessions asking at once, ``get abs_act_pos 5`` answered ``ABS_ACT_POS
0.000000 … 0.000000`` (the all-axes form: its axis word was gone) or ``GET 5 NAK`` (its item word
taken), ``get joint_pos 0`` answered ``JOINT_POS 5 …`` (the other request's axis). So a ``get`` is
accepted only as ``ITEM [its arguments] value…`` and a ``set`` only as ``SET ITEM ACK|NAK``; a reply
of another form puts the session back in step (``get RTCAL_SYNC_<n>``, an item linuxcncrsh does not
know, answered ``GET RTCAL_SYNC_<n> NAK``: every line before that answer is dropped) and the request
is sent again, at most REASKS times. Every request rtcal sends may be sent twice: gets only read,
and its sets (enable, echo, verbose, mode, home, an absolute G53/G0/G1 target, wait, abort) leave
the controller as once. What no client can undo: a ``get error`` of another session parsed with
this one's words reads a message of LinuxCNC's queue away from it.

Before anything is commanded the driver checks what it is given and what the controller is doing,
and refuses — never changes — what is not its own: the joints and kinematics the driver's kind
needs (its ``_check_configuration``), a program running in AUTO or an MDI command executing (``get
mode``, ``get program_status``), E-stop on (``ESTOP ON``) or the machine off (release E-stop and
switch the machine on at the controller). An unhomed joint is homed (``set mode manual``, ``set
home <joint>``) only when the address says ``home=1``; else refused.

Control: ``set enable EMCTOO`` makes this session the one in control and silently takes control
from any other linuxcncrsh console; linuxcncrsh has no query that shows another session holds it
(``get enable`` answers for the asking session only; emcrsh's own to-do list: "Get enable to tell
peer connections which connection has control"). So a session that will move takes control only
when the address says ``take_control=1``; without it, an address error saying why. `rtcal probe`
and `rtcal check` (``may_move=False``) never take control, change the mode or read LinuxCNC's
message queue empty: they only ask.

Stopping: one linuxcncrsh session answers one request at a time, so a ``set abort`` sent on the
session whose ``set mdi`` waits for the move to end is read only after the move ended. A second
session, opened at connect and kept for stopping, sends ``set enable`` and ``set abort`` at once;
``wait_stopped`` reads positions over that session until they no longer change. A linuxcncrsh that
refuses the second session (its ``-s/--sessions`` limit closes the connection) is refused at
connect, named so.

A move is MDI lines, each followed by ``set wait done`` (man: "force a wait for the previous command
to be received, or done"), which answers once the motion is done. The driver never sets
``set_wait``: in LinuxCNC 2.9 it is one setting for every session (emcrsh's ``emcWaitType``).
linuxcncrsh answers ACK also for a move that an E-stop or an abort cut short, so every move is
checked afterwards by the driver: E-stop off, machine on, control still this session's, no error
queued, the positions at the target.

Errors queue: LinuxCNC's NML error channel (``emcError``) is a queue of errors, operator displays
and texts, and emcrsh's ``getError``/``getOperatorDisplay``/``getOperatorText``
(src/emc/usr_intf/emcrsh.cc) each take its next message, of whatever kind (shcom.cc
``updateError()``), and answer their own kind's or ``OK``. A refused MDI line queues several (2.9,
seen: "Linear move on line 0 would exceed C's positive limit", "… joint 0's positive limit",
"invalid params in linear command"): the driver reads the queue empty after every refusal, so the
next move starts clean; a refusal for a limit is ``OutOfLimits`` (nothing moved), any other a plain
fault.
"""

from __future__ import annotations

import math
import re
import socket
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from drivers.addresses import Address, check_take_control
from drivers.errors import EmergencyStop, InstrumentFault, InstrumentTimeout, OutOfLimits
from drivers.interfaces import StopSeen, watch_still

AXES = "XYZABCUVW"  # linuxcncrsh numbers a position's axes in this order (abs_act_pos 5 is C)
CONNECT_PASSWORD, ENABLE_PASSWORD = "EMC", "EMCTOO"  # linuxcncrsh's documented defaults (no secret: see its man page)
MAX_LINE_BYTES = 4096
MAX_STRAY = 4  # replies of another form kept for messages
REASKS = 4  # a request answered in another form is sent again at most this many times
SYNC_ITEM = "RTCAL_SYNC_"  # + a number: an item linuxcncrsh does not know, its NAK puts a session back in step
MAX_QUEUED = 64  # rounds of reading LinuxCNC's message queue; a longer queue is a controller in trouble
LIMIT_ERROR = re.compile(r"exceed .*limit", re.IGNORECASE)  # 2.9: "Linear move on line 0 would exceed C's positive limit"
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
        self._syncs = 0
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
        session limit; ``HELLO NAK`` to this well-formed hello is the connect password (emcrsh
        commandHello), unless another session's request took its words: sent again, REASKS times."""
        for _ in range(REASKS + 1):
            self.send(f"hello {CONNECT_PASSWORD} rtcal 1.0")
            try:
                reply = self.line("hello", self.timeout_s).split()
            except InstrumentFault as exc:
                if "closed the connection" in str(exc) or "connection to LinuxCNC lost" in str(exc):
                    raise InstrumentFault(self.name, f"{self.what}: {SESSION_LIMIT}") from None
                raise
            if reply[:2] != ["HELLO", "NAK"]:
                break
        else:
            raise InstrumentFault(self.name, f"linuxcncrsh refused rtcal's connect password (HELLO NAK): it was started "
                                             f"with a --connectpw other than its documented default {CONNECT_PASSWORD!r}, "
                                             "the one rtcal gives (docs/protocols/linuxcnc.md)")
        if reply[:2] != ["HELLO", "ACK"] or len(reply) < 4:
            raise InstrumentFault(self.name, f"hello refused: {' '.join(reply)[:120]!r} (is this linuxcncrsh?)")
        self.server = f"{reply[2]} {reply[3]}"
        self.send("set echo off")  # echoed (the echo is written before the request is parsed); no reply, verbose off
        self.line("set echo off", self.timeout_s)
        if not self.set("verbose", "on"):
            raise InstrumentFault(self.name, "set verbose on: not acknowledged")
        for _ in range(REASKS + 1):  # a `set echo off` parsed with another session's words left echo on
            if self.get("echo") == ["OFF"]:
                return
            self.set("echo", "off")
        raise InstrumentFault(self.name, "set echo off: linuxcncrsh still echoes every request")

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

    def ask(self, line: str, fits: Callable[[list[str]], bool], timeout_s: float) -> list[str]:
        """``line`` sent, its reply's words: the next line, not the echo of ``line``, that ``fits`` the
        request's form. A reply of another form (the request parsed with another session's words, or a
        late reply to an earlier request) is not trusted: the session is put back in step and the
        request sent again, at most REASKS times; ``stray`` keeps the last few for messages."""
        for attempt in range(REASKS + 1):
            if attempt:
                self.resync(line)
            self.send(line)
            reply = self.line(line, timeout_s)
            while reply == line:  # echo still on: the request itself comes back first
                reply = self.line(line, timeout_s)
            if fits(words := reply.split()):
                return words
            self.stray = (self.stray + [reply[:80]])[-MAX_STRAY:]
        raise InstrumentFault(self.name, f"{line!r}: no reply of its form in {REASKS + 1} tries, only {self.stray!r}")

    def resync(self, what: str) -> None:
        """Back in step: ``get RTCAL_SYNC_<n>`` until its own ``GET RTCAL_SYNC_<n> NAK`` (emcrsh
        commandGet: ``GET <item> NAK`` for an item it does not know), every line before it dropped."""
        for _ in range(REASKS + 1):
            self._syncs += 1
            answer = f"GET {SYNC_ITEM}{self._syncs} NAK"
            self.send(f"get {SYNC_ITEM}{self._syncs}")
            deadline = time.monotonic() + self.timeout_s
            try:
                while self.line(what, max(deadline - time.monotonic(), 1e-3)).upper() != answer:
                    pass
                return
            except InstrumentTimeout:
                continue  # the marker itself taken by another session's words: another one
        raise InstrumentFault(self.name, f"{what}: linuxcncrsh does not answer in step ({REASKS + 1} markers unanswered)")

    def get(self, item: str, *args: object) -> list[str]:
        """``get ITEM [ARGS]`` → the words after the echoed item name (``ABS_ACT_POS 5 30.000000`` → ['5', '30.000000']):
        a reply that names the item and, in order, the arguments asked, with at least one word more;
        ``GET ITEM NAK`` every time it is asked is a refusal."""
        line = " ".join(["get", item, *map(str, args)])
        head, nak = [item.upper(), *map(str, args)], ["GET", item.upper(), "NAK"]
        for _ in range(REASKS + 1):  # a NAK naming the item may be the request parsed with another session's words
            words = self.ask(line, lambda w: w[:len(head)] == head and len(w) > len(head) or w == nak, self.timeout_s)
            if words != nak:
                return words[1:]
        raise InstrumentFault(self.name, f"{line!r}: refused (GET {item.upper()} NAK)")

    def set(self, item: str, *args: object, timeout_s: float | None = None) -> bool:
        """``set ITEM ARGS``: True on ``SET ITEM ACK`` (verbose mode), False on ``SET ITEM NAK``."""
        line = " ".join(["set", item, *map(str, args)])
        words = self.ask(line, lambda w: w[:2] == ["SET", item.upper()] and w[2:] in (["ACK"], ["NAK"]),
                         timeout_s or self.timeout_s)
        return words[2] == "ACK"

    def position(self, item: str, index: int) -> float:
        """``get ITEM INDEX`` (abs_act_pos, abs_cmd_pos, joint_pos) as a number (degrees or mm)."""
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


class LinuxCncControl:
    """A driver's side of one LinuxCNC: the moving session (``rsh``), the session kept for stopping
    (``stopper``, a run only), the checks at connect and after every move, homing, the message queue.
    A driver class sets ``name`` and what it needs, calls :meth:`_connect`, and supplies
    ``_check_configuration`` (its joints and kinematics, asked before anything is commanded) and
    ``homing_joints`` (the joints it needs homed)."""

    name: str
    what_address: str  # "stage", "machine tool": whose address a message names
    rsh: Session
    stopper: Session | None

    def _connect(self, address: Address, timeout_s: float, may_move: bool) -> None:
        """Read the shared options, open the moving session and do every check; close all on failure."""
        self.address, self.timeout_s = address, timeout_s
        self.move_timeout_s = address.option("move_timeout_s", 60.0)
        self.may_move = may_move
        self.may_home = may_move and address.option("home", 0) == 1
        if may_move:
            check_take_control(address)
        self.stopped = False  # a stop handed control to the stop session: this one moves nothing more
        self.stopper = None
        self._ini_read: tuple[Path, str | None] | None = None
        self.rsh = Session(self.name, address, timeout_s, "the session")
        try:
            self._open_session()
        except BaseException:
            self.close()
            raise

    def _check_configuration(self) -> None:
        """The joints and kinematics this driver needs (an address error when the address names others)."""

    def homing_joints(self) -> Sequence[int]:
        """The joints that must be homed before anything moves."""
        return ()

    # -- the wire (the moving session)
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
        self._check_configuration()
        self._check_idle("connect")
        self._check_ready("connect")  # E-stop and power are the operator's: refused, never changed
        unhomed = [j for j in self.homing_joints() if self.get("joint_homed", j)[-1:] != ["YES"]]
        if unhomed and not self.may_home:
            which = (f"joint {unhomed[0]} is" if len(unhomed) == 1 else f"joints {', '.join(map(str, unhomed))} are")
            raise InstrumentFault(self.name, f"{which} not homed: home {'it' if len(unhomed) == 1 else 'them'} at the "
                                  "controller" + (f", or add home=1 to the {self.what_address}'s address to let rtcal home "
                                                  f"{'it' if len(unhomed) == 1 else 'them'}" if self.may_move
                                                  else " (a probe never homes)"))
        if not self.may_move:
            return
        self.stopper = Session(self.name, self.address, self.timeout_s, "the session kept for stopping")
        if not any(self.rsh.set("enable", ENABLE_PASSWORD) for _ in range(REASKS + 1)):  # NAK each time: the password
            raise InstrumentFault(self.name, f"linuxcncrsh refused rtcal's enable password (SET ENABLE NAK): it was "
                                             f"started with an --enablepw other than its documented default "
                                             f"{ENABLE_PASSWORD!r}, the one rtcal gives (docs/protocols/linuxcnc.md)")
        self._drain_errors()  # what an earlier session left queued is not this run's
        if unhomed:
            self.set("mode", "manual", timeout_s=self.move_timeout_s, wait=True)
            for joint in unhomed:
                self.set("home", joint, timeout_s=self.move_timeout_s, wait=True)
            deadline = time.monotonic() + self.move_timeout_s  # the wait does not wait for homing to finish
            while any(self.get("joint_homed", j)[-1:] != ["YES"] for j in unhomed):
                if time.monotonic() > deadline:
                    raise InstrumentFault(self.name, f"joints {unhomed} did not home: {self._why()}")
                time.sleep(0.05)
        self._mdi_mode("connect")

    def _kinematics(self) -> tuple[str, str, str, str] | str:
        """(module, its joints' letters in joint order, where they come from, the INI's name) from the INI ``get inifile``
        names (``coordinates=`` of the module; without it the module's default, else ``[TRAJ]
        COORDINATES``), or why that was not checked."""
        ini = self._ini()
        if ini is None or ini[1] is None:
            return "LinuxCNC on another host" if ini is None else "INI unreadable"
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
            return "the INI names no coordinates"
        return module, letters, source, ini[0].name

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
    def _before_move(self, what: str) -> None:
        """A session that may move, nothing queued from before, no program running, MDI mode."""
        self._moving_session(what)
        stale = self._drain_errors()
        if stale:
            raise InstrumentFault(self.name, f"{what}: LinuxCNC reported before the move: {'; '.join(stale)}")
        self._check_idle(what)
        self._mdi_mode(what)

    def _after_mdi(self, what: str) -> None:
        """What an ACK does not say (a move an E-stop cut short is ACKed too): E-stop, power, control, nothing queued."""
        self._check_ready(what)
        errors = self._drain_errors()
        if errors:
            raise InstrumentFault(self.name, f"{what}: LinuxCNC: {'; '.join(errors)}")

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

    def stop(self) -> None:
        """Safe state: ``set abort`` over the session kept for stopping, which first takes control (``set
        enable``) — at once, while the moving session may still wait for its move. If that session is
        gone, the abort goes on the moving session (read there after the move in progress) and the
        stop session's failure is raised. The machine stays on and homed."""
        if self.stopper is None:  # a probe: it commanded nothing
            return
        self.stopped = True
        try:
            if any(self.stopper.set("enable", ENABLE_PASSWORD) for _ in range(REASKS + 1)) and self.stopper.set("abort"):
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

    def _watch_stopped(self, read: Callable[[Session], Any], show: Callable[[Any], str], tolerance: float,
                       timeout_s: float) -> StopSeen:
        """After :meth:`stop`: ``read`` over the session kept for stopping until it no longer changes and
        ``get program_status`` says IDLE (the moving session may still wait for the move's reply); a
        probe's session is read once. Seen on a loaded host: linuxcncrsh repeated one position for 0.3 s
        while the table turned on 3° (its status, written by LinuxCNC's task process, not refreshed), but
        that status said RUNNING, as it does while an MDI move executes, until the abort."""
        if self.stopper is None:
            return StopSeen(True, show(read(self.rsh)))
        stopper = self.stopper
        return watch_still(lambda: read(stopper), show, tolerance, timeout_s,
                           busy=lambda: stopper.get("program_status")[:1] != ["IDLE"])

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


