"""The `linuxcnc` stage driver against a fake linuxcncrsh written from its man page and from what
LinuxCNC 2.9 was seen to answer (docs/protocols/linuxcnc.md): no LinuxCNC needed. The loop with a
real LinuxCNC is tests/test_linuxcnc_loop.py."""

from __future__ import annotations

import json
import re
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from drivers.addresses import AddressError, parse_address
from drivers.errors import InstrumentFault, OutOfLimits
from drivers.factory import open_stage, resolve
from rtcal.cli import main

AXES = "XYZABC"


class FakeRsh:
    """linuxcncrsh as LinuxCNC 2.9's emcrsh serves it: one thread per session, each answering one
    request at a time; hello, echo, verbose, enable (the last session to give the password is the one
    in control: ``get enable`` ON for it alone, ``set`` NAK for the others), wait, estop, machine,
    mode, home, mdi (G0/G1 C…), abort, and the gets the driver asks. As strict as 2.9: the machine
    starts as the operator left it (``estop``, ``machine``, ``homed``, ``program_status``); ``set
    machine on`` is refused in E-stop, MDI needs MDI mode, power and homing; a target beyond the
    joint's limits (±``limit``) is refused with the three messages 2.9 queues. Errors, operator
    displays and texts share one queue (``messages``, (kind, text)): ``get error``, ``get
    operator_display`` and ``get operator_text`` each read the next message into its kind's string,
    then answer their own string, or OK, and clear it (emcrsh ``getError``, shcom.cc
    ``updateError``). ``cut_short_at`` makes the next move stop there with E-stop on, yet answer
    ACK (as LinuxCNC 2.9 does). ``move_s``: a move takes that long, the table turning on meanwhile,
    and its session answers only once it ended — an abort from another session ends it at once.
    ``inifile``: what ``get inifile`` answers. ``max_sessions``: emcrsh's ``-s`` limit, counting every
    session since the start (2.9 never counts a closed one off), the one beyond closed unanswered.
    ``garbled``: request → replies 2.9 gave it when another session's request was parsed at the same
    time (its shared ``strtok``), each answered once in their place, in order, and nothing else done."""

    def __init__(self, joint_type: str = "ANGULAR", stray_after_ack: bool = True, estop: str = "OFF",
                 machine: str = "ON", homed: str = "YES", limit: float = 400.0, inifile: str = "emc.ini",
                 max_sessions: int = -1, password: str = "EMC", enable_password: str = "EMCTOO",
                 units: str = "DEG MM MM MM MM MM"):
        self.joint_type, self.stray_after_ack, self.limit, self.inifile = joint_type, stray_after_ack, limit, inifile
        self.max_sessions, self.password, self.enable_password = max_sessions, password, enable_password
        self.units = units  # every joint's, as `get joint_units` answers
        self.state = {"estop": estop, "machine": machine, "mode": "MANUAL", "homed": homed, "program_status": "IDLE"}
        self.program = "none"
        self.enabled: object = None  # the session in control
        self.sessions = 0
        self.pos = 0.0
        self.move_s = 0.0
        self.moving: tuple[float, float, float] | None = None  # (from, to, started at)
        self.aborted = threading.Event()
        self.cut_short_at: float | None = None
        self.die_on_mdi = False  # the controller is killed while a move is under way: the connection closes
        self.requests: list[str] = []
        self.garbled: dict[str, list[str]] = {}
        self.by_session: dict[int, list[str]] = {}
        self.messages: list[tuple[str, str]] = []
        self.strings = {"ERROR": "", "OPERATOR_DISPLAY": "", "OPERATOR_TEXT": ""}
        self.lock = threading.RLock()
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self.server.accept()
            except OSError:
                return
            self.sessions += 1
            if 0 <= self.max_sessions < self.sessions:
                conn.close()  # emcrsh sockMain: over the limit, closed unanswered
                continue
            threading.Thread(target=self._serve, args=(conn, self.sessions), daemon=True).start()

    def _serve(self, conn: socket.socket, number: int) -> None:
        with conn, conn.makefile("rb") as lines:
            echo = False  # observed: the hello is not echoed, the requests after it are until `set echo off`
            verbose = False
            for raw in lines:
                line = raw.decode().strip()
                with self.lock:
                    self.requests.append(line)
                    self.by_session.setdefault(number, []).append(line)
                if self.die_on_mdi and line.startswith("set mdi"):
                    return
                with self.lock:
                    odd = self.garbled.get(line, [])
                    garbled = odd.pop(0) + "\r\n" if odd else ""
                reply = garbled or (f"ECHO {'ON' if echo else 'OFF'}\r\n" if line == "get echo" else self._answer(line, conn))
                if line.startswith("set echo") and not garbled and verbose:  # emcrsh commandSet: acknowledged once verbose
                    reply = "SET ECHO ACK\n\r"
                verbose = (verbose or line == "set verbose on") and line != "set verbose off"
                if echo:
                    conn.sendall(raw.rstrip(b"\r\n") + b"\r\n")
                if not garbled:  # emcrsh echoes once a hello linked the session, until `set echo off`
                    echo = reply.startswith("HELLO ACK") or (echo and line.lower() != "set echo off")
                if reply:
                    conn.sendall(reply.encode())

    def position(self) -> float:
        """Where the table is: along the move in progress (it turns at a steady speed), else where it stopped."""
        with self.lock:
            if self.moving is None:
                return self.pos
            start, target, t0 = self.moving
            done = min(1.0, (time.monotonic() - t0) / self.move_s) if self.move_s > 0 else 1.0
            return start + done * (target - start)

    def _move(self, target: float) -> None:
        """The move in progress, answered once it ended (its time passed, or an abort)."""
        with self.lock:
            self.aborted.clear()
            self.moving = (self.pos, target, time.monotonic())
        self.aborted.wait(self.move_s)
        with self.lock:
            self.pos, self.moving = self.position(), None

    def _answer(self, line: str, conn: socket.socket) -> str:
        w = line.split()
        if w[0] == "hello":
            return "HELLO ACK EMCNETSVR 1.1\r\n" if w[1] == self.password else "HELLO NAK\r\n"
        if w[:2] == ["set", "echo"]:
            return ""
        if w[0] == "get":
            item = w[1].upper()
            if item in self.strings:
                if self.messages:
                    kind, text = self.messages.pop(0)
                    self.strings[kind] = text
                text, self.strings[item] = self.strings[item] or "OK", ""
                return f"{item} {text}\r\n"
            if item in ("ESTOP", "MACHINE", "MODE", "PROGRAM_STATUS"):
                return f"{item} {self.state[item.lower()]}\r\n"
            if item == "ENABLE":
                return f"ENABLE {'ON' if self.enabled is conn else 'OFF'}\r\n"
            if item == "PROGRAM":
                return f"PROGRAM {self.program}\r\n"
            if item == "INIFILE":
                return f"INIFILE {self.inifile}\r\n"
            if item == "JOINT_TYPE":
                return f"JOINT_TYPE {w[2]}  {self.joint_type}\r\n"
            if item == "JOINT_UNITS":
                return f"JOINT_UNITS {self.units}\r\n"
            if item == "JOINT_HOMED":
                return f"JOINT_HOMED {w[2]} {self.state['homed']}\r\n"
            if item in ("ABS_ACT_POS", "ABS_CMD_POS"):
                return f"{item} {w[2]} {self.position() if w[2] == '5' else 0.0:.6f}\r\n"
            if item == "JOINT_POS":
                return f"JOINT_POS {w[2]} {self.position():.6f}\r\n"
            return f"GET {item} NAK\r\n\r\n"
        item = w[1].upper()
        ok = True
        if item == "ENABLE":
            ok = w[2] == self.enable_password
            self.enabled = conn if ok else self.enabled
        elif item in ("VERBOSE", "CONFIG", "COMM_MODE", "COMM_PROT"):
            pass
        elif self.enabled is not conn:  # emcrsh commandSet: a control function (INIFILE onwards) needs control
            ok = False
        elif item == "WAIT":
            pass
        elif item == "ESTOP":
            self.state["estop"] = w[2].upper()
            self.state["machine"] = "OFF"  # E-stop, pressed or released, leaves the machine off
        elif item == "MACHINE":
            ok = self.state["estop"] == "OFF"
            self.state["machine"] = w[2].upper() if ok else "OFF"
        elif item == "MODE":
            self.state["mode"] = w[2].upper()
        elif item == "HOME":
            ok = self.state["machine"] == "ON"
            self.state["homed"] = "YES" if ok else self.state["homed"]
        elif item == "ABORT":
            self.aborted.set()
        elif item == "MDI":
            ok = self.state["mode"] == "MDI" and self.state["machine"] == "ON" and self.state["homed"] == "YES"
            target = float(w[3][1:])
            if not ok:
                self.messages.append(("ERROR", "Must be in MDI mode to issue MDI command"))
            elif abs(target) > self.limit:
                ok, side = False, "positive" if target > 0 else "negative"
                self.messages += [("ERROR", f"Linear move on line 0 would exceed C's {side} limit"),
                                  ("ERROR", f"Linear move on line 0 would exceed joint 0's {side} limit"),
                                  ("ERROR", "invalid params in linear command")]
            elif self.cut_short_at is not None:
                self.pos, self.cut_short_at = self.cut_short_at, None
                self.state.update(estop="ON", machine="OFF")
            else:
                self._move(target)
        reply = f"SET {item} {'ACK' if ok else 'NAK'}"
        return reply + ("\n\r" if self.stray_after_ack else "\r\n")


@pytest.fixture
def rsh():
    fake = FakeRsh()
    yield fake
    fake.server.close()


def test_linuxcncrsh_address_is_a_linuxcnc_stage_without_model():
    parsed, model = resolve("stage", "linuxcncrsh://127.0.0.1?axis=C&joint=3")
    assert model.name == "linuxcnc" and parsed.port == 5007 and parsed.options == {"axis": "C", "joint": "3"}
    assert resolve("stage", "modbus-tcp://127.0.0.1:502")[1].name == "oriental-az"
    with pytest.raises(AddressError, match="axis"):
        parse_address("linuxcncrsh://127.0.0.1:5007?axis=Q")
    with pytest.raises(AddressError, match="joint"):
        parse_address("linuxcncrsh://127.0.0.1:5007?joint=99")


def test_session_moves_by_mdi_and_never_touches_estop_power_or_homing(rsh):
    stage = open_stage(f"linuxcncrsh://127.0.0.1:{rsh.port}?axis=C&joint=0&take_control=1", (-400, 400), 2.0)
    try:
        assert "EMCNETSVR 1.1" in stage.identity()
        stage.move_to(-1.25)
        assert stage.position_deg() == pytest.approx(-1.25, abs=1e-9) and stage.feedback_deg() == pytest.approx(-1.25)
        stage.stop()
    finally:
        stage.close()
    moving, stopping = rsh.by_session[1], rsh.by_session[2]
    assert moving[:4] == stopping[:4] == ["hello EMC rtcal 1.0", "set echo off", "set verbose on", "get echo"]
    assert not [q for q in rsh.requests if q.startswith(("set estop", "set machine", "set home", "set set_wait"))]
    assert moving.index("set enable EMCTOO") > moving.index("get program_status")  # asked before control is taken
    assert moving[moving.index("set mdi G0 C-1.250000") + 1] == "set wait done"
    assert "set abort" not in moving and stopping[4:6] == ["set enable EMCTOO", "set abort"]


@pytest.mark.parametrize("state, named", [({"estop": "ON", "machine": "OFF"}, "E-stop is on"),
                                          ({"machine": "OFF"}, "the machine is off")])
def test_probe_refuses_a_controller_in_estop_or_off_and_leaves_it_so(capsys, state, named):
    """Issue 36: connecting released an operator's E-stop and switched the machine on."""
    fake = FakeRsh(**state)
    code = main(["probe", "stage", f"linuxcncrsh://127.0.0.1:{fake.port}?axis=C", "--timeout-s", "2"])
    err = capsys.readouterr().err
    assert code == 1 and named in err and "rtcal never does" in err, err
    assert {k: fake.state[k] for k in state} == state
    assert not [q for q in fake.requests if q.startswith(("set estop", "set machine"))], fake.requests


def test_an_unhomed_joint_is_homed_only_when_the_address_says_home_1():
    fake = FakeRsh(homed="NO")
    with pytest.raises(InstrumentFault, match="not homed.*home=1"):
        open_stage(f"linuxcncrsh://127.0.0.1:{fake.port}?take_control=1", (-400, 400), 2.0)
    assert "set home 0" not in fake.requests and fake.state["homed"] == "NO"
    fake = FakeRsh(homed="NO")
    stage = open_stage(f"linuxcncrsh://127.0.0.1:{fake.port}?home=1&take_control=1", (-400, 400), 2.0)
    stage.close()
    r = fake.requests
    assert fake.state["homed"] == "YES" and r.index("set mode manual") < r.index("set home 0") < r.index("set mode mdi")


def test_a_probe_never_homes_even_with_home_1(capsys):
    fake = FakeRsh(homed="NO")
    code = main(["probe", "stage", f"linuxcncrsh://127.0.0.1:{fake.port}?home=1", "--timeout-s", "2"])
    err = capsys.readouterr().err
    assert code == 1 and "not homed" in err and "a probe never homes" in err, err
    assert not [q for q in fake.requests if q.startswith(("set home", "set mode"))], fake.requests


def test_after_refused_moves_the_next_legal_one_succeeds(rsh):
    """Issue 36: LinuxCNC queues three messages for a refused MDI line; the driver read one, and the next
    legal move failed ("reported before the move"). A refusal for a limit is OutOfLimits."""
    stage = open_stage(f"linuxcncrsh://127.0.0.1:{rsh.port}?take_control=1", (-1000, 1000), 2.0)
    try:
        for target in (500.0, -450.0):
            with pytest.raises(OutOfLimits, match="exceed .* limit.*invalid params"):
                stage.move_to(target)
        stage.move_to(30.0)
        assert stage.position_deg() == pytest.approx(30.0) and rsh.messages == []
    finally:
        stage.close()


def test_an_error_queued_behind_an_operator_display_is_read(rsh):
    """Errors and operator messages share LinuxCNC's queue: `get error` that reads a display answers
    ERROR OK though an error waits behind it; the driver reads on until every kind says OK."""
    stage = open_stage(f"linuxcncrsh://127.0.0.1:{rsh.port}?take_control=1", (-400, 400), 2.0)
    try:
        rsh.messages += [("OPERATOR_DISPLAY", "check the clamp"), ("ERROR", "joint 0 following error")]
        with pytest.raises(InstrumentFault, match="before the move: operator display: check the clamp; joint 0 following"):
            stage.move_to(10.0)
        stage.move_to(10.0)  # the fault was reported; the queue is empty
        assert rsh.messages == [] and all(not text for text in rsh.strings.values())
    finally:
        stage.close()


def _linuxcnc_ini(tmp_path: Path, table_text: str, comp_type: int) -> Path:
    (tmp_path / "c.comp").write_text(table_text)
    ini = tmp_path / "machine.ini"
    ini.write_text(f"[JOINT_1]\nCOMP_FILE = other.comp\n[JOINT_0]\nTYPE = ANGULAR\n# a comment\n"
                   f"COMP_FILE = c.comp\nCOMP_FILE_TYPE = {comp_type}\n")
    return ini


def _rtcal_type0_table() -> str:
    from rtcal.compensation import write_table
    from rtcal.compensation.table import CompensationTable

    positions = np.arange(0.0, 361.0, 30.0)
    trims = 5e-3 * np.sin(np.radians(positions))
    return write_table("linuxcnc", CompensationTable(positions, trims, trims + 1e-3))


def test_a_type_0_table_loaded_as_type_1_is_a_fault_naming_the_type(tmp_path):
    """Issue 36: rtcal's type-0 table loaded with COMP_FILE_TYPE = 1 moved the motor to 55.3° for 30°,
    unseen by every position linuxcncrsh reports."""
    fake = FakeRsh(inifile=str(_linuxcnc_ini(tmp_path, _rtcal_type0_table(), 1)))
    with pytest.raises(InstrumentFault, match="COMP_FILE_TYPE = 1 corrects by up to .*°.*type 0"):
        open_stage(f"linuxcncrsh://127.0.0.1:{fake.port}?take_control=1", (-400, 400), 2.0)
    fake = FakeRsh(inifile=str(_linuxcnc_ini(tmp_path, _rtcal_type0_table(), 0)))
    stage = open_stage(f"linuxcncrsh://127.0.0.1:{fake.port}?take_control=1", (-400, 400), 2.0)
    try:
        assert "COMP_FILE c.comp, COMP_FILE_TYPE = 0, corrections up to 21.60″" in stage.identity()
    finally:
        stage.close()


def test_an_unreadable_ini_says_the_type_was_not_checked(rsh):
    stage = open_stage(f"linuxcncrsh://127.0.0.1:{rsh.port}?take_control=1", (-400, 400), 2.0)
    try:
        assert "COMP_FILE_TYPE not checked (INI emc.ini not readable here)" in stage.identity()
    finally:
        stage.close()


def test_a_move_an_estop_cut_short_is_a_fault_though_linuxcncrsh_said_ack(rsh):
    stage = open_stage(f"linuxcncrsh://127.0.0.1:{rsh.port}?take_control=1", (-400, 400), 2.0)
    try:
        rsh.cut_short_at = 48.6
        with pytest.raises(InstrumentFault, match="E-stop"):
            stage.move_to(300.0)
        with pytest.raises(InstrumentFault, match="E-stop"):  # the retry's recover() never releases it
            stage.reset_alarm()
    finally:
        stage.close()
    assert "set estop off" not in rsh.requests[rsh.requests.index("set mdi G0 C300.000000"):]


def test_a_linear_joint_is_refused(capsys):
    fake = FakeRsh(joint_type="LINEAR")
    code = main(["probe", "stage", f"linuxcncrsh://127.0.0.1:{fake.port}?axis=C", "--timeout-s", "2"])
    err = capsys.readouterr().err
    assert code == 2 and "not an angular joint" in err and len(err.strip().splitlines()) == 1


def test_probe_reads_the_axis_position(rsh, capsys):
    rsh.pos = 12.5
    code = main(["probe", "stage", f"linuxcncrsh://127.0.0.1:{rsh.port}?axis=C", "--json", "--timeout-s", "2"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["model"] == "linuxcnc" and out["reading"] == {"position_deg": 12.5}
    assert "get abs_act_pos 5" in rsh.requests


def test_sim_serve_comp_needs_the_linuxcnc_stage(capsys, tmp_path):
    table = tmp_path / "c.comp"
    table.write_text("0 0 0\n360 360 360\n")
    assert main(["sim", "serve", "--comp", str(table)]) == 2
    assert "--stage linuxcnc" in capsys.readouterr().err


def test_a_controller_that_dies_mid_move_is_a_fault(rsh):
    stage = open_stage(f"linuxcncrsh://127.0.0.1:{rsh.port}?take_control=1", (-400, 400), 2.0)
    try:
        rsh.die_on_mdi = True
        with pytest.raises(InstrumentFault, match="closed the connection"):
            stage.move_to(10.0)
    finally:
        stage.close()


def test_a_run_with_a_linuxcnc_stage_refuses_the_virtual_clock(capsys, tmp_path):
    instruments = json.dumps({"stage": "linuxcncrsh://127.0.0.1:5007?axis=C"})
    procedure = Path(__file__).resolve().parents[1] / "procedures" / "iso230_2_polygon.yaml"
    code = main(["run", str(procedure), "--instruments", instruments, "--virtual-clock",
                 "--out", str(tmp_path / "run")])
    assert code == 2 and "real time" in capsys.readouterr().err and not (tmp_path / "run").exists()


def _stopped_at_20_deg(fake: FakeRsh, garbled: dict[str, list[str]] | None = None):
    """A move 0 → 90° at 10 °/s, stopped from another thread once the table passed 20° (``garbled``
    given to the fake then): what wait_stopped saw, and how long after the stop was asked."""
    fake.move_s = 9.0
    stage = open_stage(f"linuxcncrsh://127.0.0.1:{fake.port}?take_control=1", (-400, 400), 2.0)
    moving = threading.Thread(target=lambda: pytest.raises(InstrumentFault, stage.move_to, 90.0), daemon=True)
    try:
        moving.start()
        while fake.position() < 20.0:
            time.sleep(0.01)
        fake.garbled = garbled or {}
        asked_s = time.monotonic()
        stage.stop()
        seen = stage.wait_stopped()
        return seen, time.monotonic() - asked_s
    finally:
        moving.join(15)
        stage.close()


def test_a_stop_reaches_linuxcnc_while_the_moving_session_waits_for_its_move():
    """Issue 40: `set abort` went on the session whose `set mdi` waited for the move, and was read only
    after the move ended (the table went on from 21° to 90°). The stop goes over the session kept for
    stopping, at once, and the position is seen at rest far short of the target."""
    fake = FakeRsh()
    seen, took_s = _stopped_at_20_deg(fake)
    assert seen.still and 20.0 <= float(seen.where.rstrip("°")) < 25.0, seen
    assert took_s < 1.0 and fake.position() < 25.0
    assert fake.by_session[2][4:6] == ["set enable EMCTOO", "set abort"]


ALL_AXES = "ABS_ACT_POS 0.000000 0.000000 0.000000 0.000000 0.000000 0.000000"  # 2.9's all-axes form


def test_replies_of_another_form_are_asked_again_never_trusted(rsh):
    """linuxcncrsh 2.9 splits every session's request with one ``strtok`` for the whole server: a request
    parsed while another session's is takes that one's words (seen on LinuxCNC: `get abs_act_pos 5` →
    the all-axes form or `GET 5 NAK`; `get joint_pos 0` → `JOINT_POS 5 …`). Such a reply, or a late one
    before the reply, is asked again once the session is back in step: never an error, never its value."""
    rsh.garbled = {
        "hello EMC rtcal 1.0": ["HELLO NAK"],  # its password word taken
        "set echo off": ["SET NAK"],  # parsed without its words: echo stays on
        "set enable EMCTOO": ["SET ENABLE NAK"],  # its password word taken
        "get mode": ["SET MODE ACK\r\nMODE MANUAL"],  # a late reply, then a reply of before
        "set mdi G0 C-1.250000": ["SET ABS_ACT_POS NAK"],
        "get abs_act_pos 5": [ALL_AXES, "GET 5 NAK", "ABS_ACT_POS 0 0.000000", "ABS_CMD_POS 5 0.000000"],
        "get joint_pos 0": ["JOINT_POS 5 0.000000"],
    }
    stage = open_stage(f"linuxcncrsh://127.0.0.1:{rsh.port}?axis=C&joint=0&take_control=1", (-400, 400), 2.0)
    try:
        stage.move_to(-1.25)
        assert stage.position_deg() == -1.25 and stage.feedback_deg() == -1.25
    finally:
        stage.close()
    assert not any(rsh.garbled.values())  # every odd reply was given, and none was taken
    moving = rsh.by_session[1]
    assert moving.count("hello EMC rtcal 1.0") == 2 and moving.count("set mdi G0 C-1.250000") == 2
    assert moving[moving.index("get echo") + 1] == "set echo off"  # echo still on: turned off again
    assert [q for q in moving if q.startswith("get RTCAL_SYNC_")] == [f"get RTCAL_SYNC_{n}" for n in range(1, 9)]


def test_a_reply_of_another_form_every_time_is_a_fault_not_a_value(rsh):
    stage = open_stage(f"linuxcncrsh://127.0.0.1:{rsh.port}?axis=C&joint=0&take_control=1", (-400, 400), 2.0)
    try:
        rsh.garbled = {"get abs_act_pos 5": ["ABS_ACT_POS 0 12.000000"] * 5, "get joint_pos 0": ["GET JOINT_POS NAK"] * 25}
        with pytest.raises(InstrumentFault, match=r"no reply of its form in 5 tries, only .*'ABS_ACT_POS 0 12.000000'"):
            stage.position_deg()
        with pytest.raises(InstrumentFault, match=re.escape("'get joint_pos 0': refused (GET JOINT_POS NAK)")):
            stage.feedback_deg()
    finally:
        stage.close()


def test_a_stop_is_seen_at_rest_through_replies_of_another_form():
    """The stop watch reads the position over the session kept for stopping while another session asks:
    a reply of another form there is asked again, not a machine that could not be seen to stop."""
    fake = FakeRsh()
    seen, _ = _stopped_at_20_deg(fake, {"get abs_act_pos 5": [ALL_AXES, "GET 5 NAK", ALL_AXES], "set abort": ["SET NAK"]})
    assert seen.still and 20.0 <= float(seen.where.rstrip("°")) < 25.0, seen
    assert not any(fake.garbled.values()) and fake.by_session[2].count("set abort") == 2


def test_the_moving_session_moves_nothing_after_a_stop(rsh):
    stage = open_stage(f"linuxcncrsh://127.0.0.1:{rsh.port}?take_control=1", (-400, 400), 2.0)
    try:
        stage.stop()
        with pytest.raises(InstrumentFault, match="was stopped"):
            stage.move_to(5.0)
    finally:
        stage.close()
    assert "set mdi G0 C5.000000" not in rsh.requests


def test_a_session_refused_by_linuxcncrsh_s_limit_is_named_so_not_a_dead_controller(capsys):
    """Issue 46: a linuxcncrsh started with -s closes a session beyond it; that is no controller shut down."""
    fake = FakeRsh(max_sessions=1)  # the moving session fits, the one kept for stopping does not
    with pytest.raises(InstrumentFault, match=r"session kept for stopping: .*-s/--sessions limit") as refused:
        open_stage(f"linuxcncrsh://127.0.0.1:{fake.port}?take_control=1", (-400, 400), 2.0)
    assert "shut down or killed" not in str(refused.value)
    assert "set enable EMCTOO" not in fake.requests  # refused before control was taken
    code = main(["probe", "stage", f"linuxcncrsh://127.0.0.1:{fake.port}", "--timeout-s", "2"])  # the 3rd session
    err = capsys.readouterr().err
    assert code == 1 and "sessions limit" in err and "shut down or killed" not in err, err


@pytest.mark.parametrize("which, named", [({"password": "secret1"}, "connect password (HELLO NAK)"),
                                          ({"enable_password": "secret2"}, "enable password (SET ENABLE NAK)")])
def test_a_wrong_linuxcnc_password_is_named(which, named):
    fake = FakeRsh(**which)
    with pytest.raises(InstrumentFault, match=re.escape(named)) as refused:
        open_stage(f"linuxcncrsh://127.0.0.1:{fake.port}?take_control=1", (-400, 400), 2.0)
    assert "secret" not in str(refused.value)


def test_moving_needs_take_control_1_and_a_probe_never_takes_control(capsys, tmp_path):
    """Issue 40: rtcal took control from an operator's console silently; linuxcncrsh cannot tell that one
    holds it, so taking it is said in the address — refused otherwise, before anything is sent."""
    fake = FakeRsh()
    with pytest.raises(AddressError, match="take_control=1.*cannot tell"):
        open_stage(f"linuxcncrsh://127.0.0.1:{fake.port}", (-400, 400), 2.0)
    assert fake.requests == []
    procedure = Path(__file__).resolve().parents[1] / "procedures" / "iso230_2_polygon.yaml"
    instruments = json.dumps({"stage": f"linuxcncrsh://127.0.0.1:{fake.port}?axis=C"})
    code = main(["run", str(procedure), "--instruments", instruments, "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and "take_control=1" in err and len(err.strip().splitlines()) == 1, err
    assert fake.requests == []
    fake.messages.append(("ERROR", "the operator's own message"))
    assert main(["probe", "stage", f"linuxcncrsh://127.0.0.1:{fake.port}", "--timeout-s", "2"]) == 0
    assert not [q for q in fake.requests if q.startswith("set") and q not in ("set echo off", "set verbose on")]
    assert fake.messages, "a probe read the operator's message queue"


def test_a_program_running_in_auto_is_refused_at_once_naming_it():
    """Issue 40: connecting while a program ran in AUTO waited ~17 s and failed at the first move."""
    fake = FakeRsh()
    fake.state.update(mode="AUTO", program_status="RUNNING")
    fake.program = "/home/op/part.ngc"
    started = time.monotonic()
    with pytest.raises(InstrumentFault, match=r"running a program in AUTO mode \(/home/op/part.ngc, running\)"):
        open_stage(f"linuxcncrsh://127.0.0.1:{fake.port}?take_control=1", (-400, 400), 2.0)
    assert time.monotonic() - started < 1.0
    assert not [q for q in fake.requests if q.startswith("set") and q not in ("set echo off", "set verbose on")]


def test_a_linear_axis_letter_is_refused_where_the_address_is_read(capsys, tmp_path):
    """Issue 40: `axis=Z&joint=3` moved the Z axis 30 mm while rtcal reported the table at 30°."""
    with pytest.raises(AddressError, match="rotary axis is A, B or C"):
        parse_address("linuxcncrsh://127.0.0.1:5007?axis=Z&joint=3&take_control=1")
    assert main(["probe", "stage", "linuxcncrsh://127.0.0.1:9?axis=Z&joint=3"]) == 2
    assert "rotary axis is A, B or C" in capsys.readouterr().err


def test_the_axis_letter_must_be_the_kinematics_coordinate_of_the_joint(tmp_path, capsys):
    ini = tmp_path / "xyzc.ini"
    ini.write_text("[KINS]\nKINEMATICS = trivkins coordinates=XYZC\nJOINTS = 4\n[TRAJ]\nCOORDINATES = X Y Z C\n")
    fake = FakeRsh(inifile=str(ini), units="DEG MM MM DEG MM MM")  # joint 0 angular too: the INI tells them apart
    code = main(["probe", "stage", f"linuxcncrsh://127.0.0.1:{fake.port}?axis=C&joint=0", "--timeout-s", "2"])
    err = capsys.readouterr().err
    assert code == 2 and "axis C is joint 3: give joint=3" in err and "coordinates=XYZC" in err, err
    code = main(["probe", "stage", f"linuxcncrsh://127.0.0.1:{fake.port}?axis=A&joint=3", "--timeout-s", "2"])
    err = capsys.readouterr().err
    assert code == 2 and "no axis A; joint 3 is C: give axis=C" in err, err
    stage = open_stage(f"linuxcncrsh://127.0.0.1:{fake.port}?axis=C&joint=3&take_control=1", (-400, 400), 2.0)
    try:
        assert "axis C is joint 3 (trivkins coordinates=XYZC)" in stage.identity()
    finally:
        stage.close()
