"""Dying and misbehaving peers, per transport: every driver turns what the wire does into a typed
InstrumentError (never ConnectionResetError, IndexError, termios.error or a hang), and the
simulators keep answering everyone else when one client misbehaves.

The peers here are real sockets and pseudo-terminals, scripted to die or misbehave at a chosen
byte; the end-to-end cases kill a real `rtcal sim serve` under a real `rtcal run`.
"""

from __future__ import annotations

import os
import select
import socket
import sqlite3
import struct
import subprocess
import sys
import threading
import time
import tty
from pathlib import Path

import pytest

from drivers.addresses import AddressError, parse_address
from drivers.errors import InstrumentError, InstrumentFault, InstrumentTimeout
from drivers.ipp_cmm import IppCmm
from drivers.modbus_stage import ModbusStage
from drivers.serial_instruments import ElcomatAutocollimator, LineLaserTracer, QsbEncoder
from rtcal.methods import load_procedure
from rtcal.run.runner import METHODS
from rtcal.engine.operator import OperatorUnavailable, RemoteSimOperator
from simulators.scenario import Scenario
from simulators.servers.hub import SimulatorHub
from tests.polling import stored_plan_indices

TIMEOUT_S = 0.5
REPO = Path(__file__).resolve().parents[1]


# -- scripted peers ------------------------------------------------------------------------------

class TcpPeer:
    """A TCP server thread: ``script(conn)`` runs on each accepted connection."""

    def __init__(self, script, connections: int = 1):
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.script, self.connections = script, connections
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        for _ in range(self.connections):
            try:
                conn, _ = self.listener.accept()
            except OSError:
                return
            with conn:
                try:
                    self.script(conn)
                except OSError:
                    pass
        self.listener.close()

    def close(self) -> None:
        self.listener.close()
        self.thread.join(5)


def reset(conn: socket.socket) -> None:
    """Die abruptly: close with a TCP reset, as a killed process's socket does under load."""
    conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    conn.close()


def read_request_then_reset(conn: socket.socket) -> None:
    conn.recv(4096)
    reset(conn)


def start_session(conn: socket.socket) -> None:
    """Answer what the driver sends when it opens a session: StartSession(), GetDMEVersion(),
    SetCoordSystem(MachineCsy) and IsHomed() (a homed machine)."""
    for data in (b"", b'# DMEVersion("1.4")\r\n', b"", b"# IsHomed(1)\r\n"):
        buffer = b""
        while not buffer.endswith(b"\r\n"):
            buffer += conn.recv(4096)
        tag = buffer[:5]
        conn.sendall(tag + b" &\r\n" + (tag + b" " + data if data else b"") + tag + b" %\r\n")


def ipp_session_then(after_start):
    """Answer the session's start, then hand the connection to ``after_start``."""

    def script(conn: socket.socket) -> None:
        start_session(conn)
        after_start(conn)

    return script


# -- peer dies mid-request: one test per transport --------------------------------------------------

def test_modbus_tcp_peer_reset_mid_request_is_typed():
    peer = TcpPeer(read_request_then_reset)
    stage = ModbusStage(parse_address(f"modbus-tcp://127.0.0.1:{peer.port}"), timeout_s=TIMEOUT_S)
    with pytest.raises(InstrumentError):
        stage.position_deg()
    peer.close()
    with pytest.raises(InstrumentError):  # the drive stays gone: refused, still typed
        stage.position_deg()
    stage.close()


def test_modbus_tcp_short_reply_is_typed():
    """A reply with one register where two were asked (was: IndexError)."""

    def one_register(conn: socket.socket) -> None:
        while request := conn.recv(4096):
            tid, unit, function = request[:2], request[6:7], request[7]
            if function == 0x2B:  # Read Device Identification at connect: an AZ drive answers "illegal function"
                pdu = bytes([0x2B | 0x80, 0x01])
            else:
                pdu = bytes([3, 2, 0x12, 0x34])  # read holding registers: 2 bytes, one register
            conn.sendall(tid + b"\0\0" + struct.pack(">H", len(pdu) + 1) + unit + pdu)
            if function != 0x2B:
                time.sleep(0.5)
                return

    peer = TcpPeer(one_register)
    stage = ModbusStage(parse_address(f"modbus-tcp://127.0.0.1:{peer.port}"), timeout_s=TIMEOUT_S)
    with pytest.raises(InstrumentError, match="register"):
        stage.position_deg()
    stage.close()
    peer.close()


def _pty() -> tuple[int, int, str]:
    master, slave = os.openpty()
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


def _die_after_request(master: int, slave: int) -> threading.Thread:
    """The far end of a serial line reads one request and dies: both ends of the pty close."""

    def run() -> None:
        select.select([master], [], [], 5)
        os.read(master, 4096)
        os.close(master)
        os.close(slave)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_modbus_rtu_line_dies_mid_request_is_typed():
    master, slave, path = _pty()
    stage = ModbusStage(parse_address(f"modbus-rtu://{path}?baud=115200&parity=N"), timeout_s=TIMEOUT_S)
    _die_after_request(master, slave).join(0.1)
    for _ in range(2):  # the request in flight, and the next one on the dead line
        with pytest.raises(InstrumentError):
            stage.position_deg()
    stage.close()


def TRACER(path: str) -> LineLaserTracer:
    return LineLaserTracer(parse_address(path), TIMEOUT_S)


@pytest.mark.parametrize("make", [TRACER, lambda path: QsbEncoder(parse_address(path), TIMEOUT_S)], ids=["tracer", "encoder"])
def test_serial_pty_dies_mid_request_is_typed(make):
    """termios.error and EIO from a pseudo-terminal whose other end died become typed errors."""
    master, slave, path = _pty()
    _die_after_request(master, slave)
    try:
        driver = make(path)
    except InstrumentError:  # the counter is configured at open: the line died under its first request
        assert make is not TRACER
        return
    read = driver.read_length if isinstance(driver, LineLaserTracer) else driver.read_angle_deg
    for _ in range(2):
        with pytest.raises(InstrumentError):
            read()
    driver.close()


def test_serial_socket_peer_reset_mid_request_is_typed():
    peer = TcpPeer(read_request_then_reset)
    autocollimator = ElcomatAutocollimator(parse_address(f"socket://127.0.0.1:{peer.port}"), TIMEOUT_S)
    for _ in range(2):
        with pytest.raises(InstrumentError):
            autocollimator.read_arcsec()
    autocollimator.close()
    peer.close()


def test_ipp_peer_reset_mid_command_is_typed_and_the_next_command_reconnects():
    served = []

    def script(conn: socket.socket) -> None:
        start_session(conn)
        served.append(1)
        if len(served) == 1:
            read_request_then_reset(conn)  # the first session dies mid-command
            return
        line = conn.recv(4096)  # the second one answers
        tag = line[:5]
        conn.sendall(tag + b" &\r\n" + tag + b" # X(1.000000), Y(2.000000), Z(3.000000)\r\n" + tag + b" %\r\n")

    peer = TcpPeer(script, connections=2)
    cmm = IppCmm(parse_address(f"ipp://127.0.0.1:{peer.port}"), TIMEOUT_S)
    with pytest.raises(InstrumentFault):
        cmm.position_mm()
    assert list(cmm.position_mm()) == [1.0, 2.0, 3.0]  # a new connection and session
    peer.close()
    with pytest.raises(InstrumentError):  # the CMM is gone: refused, typed
        cmm.position_mm()
    cmm.close()


def test_ipp_server_dribbling_bytes_without_end_meets_the_deadline():
    """A server streaming bytes without CRLF (was: hung 25 s past a 1 s timeout, buffer growing)."""
    stop = threading.Event()

    def dribble(conn: socket.socket) -> None:
        conn.recv(4096)
        while not stop.is_set():
            conn.sendall(b"x" * 100)
            time.sleep(0.01)

    peer = TcpPeer(ipp_session_then(dribble))
    cmm = IppCmm(parse_address(f"ipp://127.0.0.1:{peer.port}"), TIMEOUT_S)
    start = time.monotonic()
    with pytest.raises(InstrumentTimeout):
        cmm.position_mm()
    elapsed = time.monotonic() - start
    stop.set()
    cmm.close()
    peer.close()
    assert elapsed < TIMEOUT_S + 1.0, elapsed  # the deadline, plus scheduling slack
    assert len(cmm._buffer) == 0


def test_ipp_flood_without_line_end_is_bounded():
    def flood(conn: socket.socket) -> None:
        conn.recv(4096)
        conn.sendall(b"y" * 200_000)
        time.sleep(1)

    peer = TcpPeer(ipp_session_then(flood))
    cmm = IppCmm(parse_address(f"ipp://127.0.0.1:{peer.port}"), 5.0)
    with pytest.raises(InstrumentFault, match="longer than 64 KiB"):
        cmm.position_mm()
    cmm.close()
    peer.close()


def test_ipp_position_that_is_no_number_is_refused():
    def infinite(conn: socket.socket) -> None:
        tag = conn.recv(4096)[:5]
        conn.sendall(tag + b" &\r\n" + tag + b" # X(1e999), Y(0), Z(0)\r\n" + tag + b" %\r\n")
        time.sleep(0.5)

    peer = TcpPeer(ipp_session_then(infinite))
    cmm = IppCmm(parse_address(f"ipp://127.0.0.1:{peer.port}"), TIMEOUT_S)
    with pytest.raises(InstrumentFault, match="no position"):
        cmm.position_mm()
    cmm.close()
    peer.close()


def test_unreachable_simulated_operator_is_typed():
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    operator = RemoteSimOperator(f"sim-operator://127.0.0.1:{port}", timeout_s=TIMEOUT_S)
    with pytest.raises(OperatorUnavailable, match="does not answer"):
        operator.clear_fault("e-stop")
    assert issubclass(OperatorUnavailable, InstrumentError)  # the fault policies handle it


@pytest.mark.parametrize("address,text", [
    ("modbus-tcp://127.0.0.1:502?steps_per_rev=0", "steps_per_rev='0': must be a whole number from 1"),
    ("modbus-tcp://127.0.0.1:502?gear=nan", "gear='nan': must be a number from"),
    ("modbus-tcp://127.0.0.1:502?gear=1e308", "gear='1e308'"),
    ("modbus-tcp://127.0.0.1:502?unit=300", "unit='300'"),
    ("modbus-tcp://127.0.0.1:502?speed=3", "unknown option 'speed'"),
    ("/dev/ttyUSB0?baud=-1", "baud='-1'"),
    ("socket://127.0.0.1:5?counts_per_rev=" + "9" * 5000, "counts_per_rev="),
    ("modbus-tcp://127.0.0.1:502?steps_per_rev=4&gear=1", "one motor step would turn the table 90°"),
    ("modbus-tcp://127.0.0.1:0", "port 0 is no port"),  # it was read as the default port 502
    ("ipp://127.0.0.1:0", "port 0 is no port"),
])
def test_address_options_are_checked_when_parsed(address, text):
    with pytest.raises(AddressError, match=text.replace("?", r"\?")):
        parse_address(address)


# -- the simulators' servers: one misbehaving client never harms the others -------------------------

@pytest.fixture(scope="module")
def hub():
    with SimulatorHub(Scenario(), seed=1) as h:
        yield h


def _host_port(address: str) -> tuple[str, int]:
    host, port = address.split("//")[1].split("?")[0].split(":")
    return host, int(port)


def _ask(address: str, data: bytes, timeout_s: float = TIMEOUT_S) -> bytes:
    with socket.create_connection(_host_port(address), timeout=timeout_s) as s:
        s.sendall(data)
        reply = b""
        try:
            while not reply.endswith(b"\n"):
                chunk = s.recv(4096)
                if not chunk:
                    break
                reply += chunk
        except TimeoutError:
            pass
        return reply


def _auth(hub) -> bytes:
    return f"AUTH {parse_address(hub.addresses['operator']).text('token')} ".encode()


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "1e400", "720", "x"])
def test_operator_refuses_a_seating_that_is_no_angle(hub, value):
    assert _ask(hub.addresses["operator"], _auth(hub) + f"RESEAT {value}\n".encode()) == b"ERR ARG\n"
    assert _ask(hub.addresses["operator"], _auth(hub) + b"RESEAT 45\n") == b"OK\n"


@pytest.mark.parametrize("line", [b"RESEAT 45\n", b"MOUNT 1\n", b"CLEAR\n", b"AUTH wrong-token-123 RESEAT 45\n",
                                  b"AUTH  RESEAT 45\n"])
def test_operator_refuses_a_stranger(hub, line):
    """Only the run given the operator's address (with its token) may re-seat, move or clear."""
    hub.bench.reseat_polygon(0.0)
    before = (hub.bench.polygon_rotation_rad, hub.bench.tracer_mount)
    assert _ask(hub.addresses["operator"], line) == b"ERR AUTH\n"
    assert (hub.bench.polygon_rotation_rad, hub.bench.tracer_mount) == before


def test_operator_and_ipp_refuse_an_overlong_line_and_go_on(hub):
    assert _ask(hub.addresses["operator"], b"A" * 100_000 + b"\n", 2.0) == b"ERR LINE\n"
    assert _ask(hub.addresses["cmm"], b"B" * 100_000 + b"\r\n", 2.0).endswith(b'"Line too long")\r\n')
    assert _ask(hub.addresses["operator"], _auth(hub) + b"CLEAR\n") == b"OK\n"
    assert _ask(hub.addresses["cmm"], b"00001 StartSession()\r\n", 2.0).startswith(b"00001 &")


def _modbus_raw(address: str, unit: int, pdu: bytes) -> bytes:
    with socket.create_connection(_host_port(address), timeout=TIMEOUT_S) as s:
        s.sendall(struct.pack(">HHHB", 7, 0, len(pdu) + 1, unit) + pdu)
        try:
            return s.recv(256)
        except TimeoutError:
            return b""


def test_modbus_simulator_answers_as_a_drive_does(hub):
    stage = hub.addresses["stage"]
    assert _modbus_raw(stage, 9, b"\x03\x00\x00\x00\x02") == b""  # another unit id: silence, as on a bus
    assert _modbus_raw(stage, 0, b"\x03\x00\x00\x00\x02") == b""  # broadcast: no reply
    reply = _modbus_raw(stage, 1, b"\x41\x00\x00")  # an unknown function code
    assert reply[7:] == b"\xc1\x01", reply  # code | 0x80, illegal function (was a bare 0x80)
    with pytest.raises(InstrumentTimeout):  # the driver at a wrong unit id times out, typed
        ModbusStage(parse_address(stage.split("?")[0] + "?unit=2"), timeout_s=TIMEOUT_S).position_deg()


def test_a_pty_client_that_never_reads_freezes_nothing(hub):
    """Floods one serial line with requests and never reads a reply (was: the hub's one thread
    blocked in os.write; Modbus and I++ froze and stayed frozen). Modbus, I++ and the other serial
    lines must answer within their timeouts throughout and after."""
    stage = ModbusStage(parse_address(hub.addresses["stage"]), timeout_s=TIMEOUT_S)
    cmm = IppCmm(parse_address(hub.addresses["cmm"]), TIMEOUT_S)
    autocollimator = ElcomatAutocollimator(parse_address(hub.addresses["autocollimator"]), TIMEOUT_S)
    flood = os.open(hub.addresses["encoder"].split("?")[0], os.O_RDWR | os.O_NOCTTY)
    tty.setraw(flood)
    os.set_blocking(flood, False)
    worst_s = 0.0

    def ask_the_others() -> None:
        nonlocal worst_s
        for request in (stage.position_deg, cmm.position_mm, autocollimator.read_arcsec):
            t = time.perf_counter()
            request()
            worst_s = max(worst_s, time.perf_counter() - t)

    try:
        sent = 0
        for _ in range(50):  # bursts: 2000 requests at once, more than any instrument queues
            try:
                sent += os.write(flood, b"R0E\r" * 2000)
            except BlockingIOError:
                pass
            ask_the_others()
        assert sent > 100_000, sent
        for k in range(1500):  # a steady stream, every request answered: 290 kB of replies nobody reads
            try:
                os.write(flood, b"R0E\r" * 16)
            except BlockingIOError:
                pass
            time.sleep(0.0005)
            if k % 100 == 0:
                ask_the_others()
        deadline = time.monotonic() + 5
        while hub.dropped_reply_bytes() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert hub.dropped_reply_bytes() > 0  # the replies beyond what the terminal holds were let go
    finally:
        os.close(flood)
    # the flooder's last requests are answered into the terminal it left; a client that opens the
    # line after they were is given a clean line (the open discards them), one that opens before
    # would read their replies as its own — on a real line too, so wait as a technician would
    assert hub.wait_line_idle("encoder"), "the flooded line went on answering for 5 s"
    ask_the_others()
    print(f"flood: {sent} request bytes in bursts, {hub.dropped_reply_bytes()} reply bytes dropped; "
          f"worst Modbus/I++/serial round trip meanwhile {worst_s * 1e3:.1f} ms (timeout {TIMEOUT_S} s)")
    encoder = QsbEncoder(parse_address(hub.addresses["encoder"]), TIMEOUT_S)  # the flooded line itself recovers
    encoder.read_angle_deg()
    for driver in (stage, cmm, autocollimator, encoder):
        driver.close()


# -- end to end: the simulator dies under a run, the run stops safely and resumes ---------------------

def _sim_serve(*options: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([sys.executable, "-m", "rtcal.cli", "sim", "serve", "--seed", "5", *options],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 30)
    assert ready, "rtcal sim serve printed nothing in 30 s"
    return proc, proc.stdout.readline()


def _done_once(db: Path) -> list[int]:
    """How many done attempts each planned reading has (each must have exactly one)."""
    with sqlite3.connect(db) as c:
        rows = c.execute(
            "SELECT plan_index, COUNT(DISTINCT attempt) FROM readings r WHERE plan_index IS NOT NULL AND quantity <> "
            "'skipped' AND NOT EXISTS (SELECT 1 FROM readings s WHERE s.plan_index = r.plan_index AND s.attempt IS "
            "r.attempt AND s.quantity = 'skipped') GROUP BY plan_index ORDER BY plan_index").fetchall()
    return [n for _, n in rows]


KILLS = [
    ("tests/data/small_multistation.yaml", ("--serial", "pty", "--modbus", "tcp")),
    ("procedures/encoder_abbe_error.yaml", ("--serial", "tcp", "--modbus", "rtu")),
]


@pytest.mark.parametrize("procedure,options", KILLS, ids=["ptys-modbus-tcp-ipp", "sockets-modbus-rtu"])
def test_simulator_killed_mid_run_stops_safely_and_resumes(tmp_path, procedure, options):
    """kill -9 of `rtcal sim serve` under `rtcal run`: exit 1 with a typed instrument error and the
    resume command, no traceback; a restarted simulator and `rtcal resume --instruments` finish the
    run with every planned reading done exactly once."""
    out, db = tmp_path / "run", tmp_path / "run" / "run.sqlite"
    sim, addresses = _sim_serve(*options)
    (tmp_path / "a.json").write_text(addresses)
    run = subprocess.Popen([sys.executable, "-m", "rtcal.cli", "run", str(REPO / procedure), "--instruments",
                            str(tmp_path / "a.json"), "--virtual-clock", "--out", str(out)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while stored_plan_indices(db) < 5 and run.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    sim.kill()
    sim.wait()
    _, err = run.communicate(timeout=120)
    assert run.returncode == 1, err
    assert "instrument error" in err and "run aborted" in err and f"rtcal resume {out}" in err, err  # the safe stop
    assert "Traceback" not in err, err
    assert all(line.startswith(("rtcal:", "control token: ")) for line in err.splitlines() if line.strip()), err  # no library's log lines
    sim, addresses = _sim_serve(*options)
    try:
        (tmp_path / "b.json").write_text(addresses)
        resumed = subprocess.run([sys.executable, "-m", "rtcal.cli", "resume", str(out), "--instruments",
                                  str(tmp_path / "b.json"), "--virtual-clock"], capture_output=True, text=True, timeout=300)
    finally:
        sim.terminate()
        sim.wait(10)
    assert resumed.returncode == 0, resumed.stderr
    proc = load_procedure(REPO / procedure)
    assert _done_once(db) == [1] * METHODS[proc.method].plan_length(proc), "a planned reading lost or stored twice"


def test_no_terminal_for_the_operator_is_a_safe_stop_not_a_traceback(tmp_path, hub):
    """A wired polygon closure needs an operator; with neither a terminal nor the simulated
    operator (was: RuntimeError traceback) the run stops with exit 1, says why and how to go on,
    and pymodbus prints nothing of its own."""
    import json

    addresses = {k: v for k, v in hub.addresses.items() if k != "operator"}
    run = subprocess.run([sys.executable, "-m", "rtcal.cli", "run", str(REPO / "procedures" / "polygon_closure.yaml"),
                          "--instruments", json.dumps(addresses), "--virtual-clock", "--out", str(tmp_path / "run")],
                         stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120)
    assert run.returncode == 1, run.stderr
    assert "operator: the procedure needs an operator to re-seat the polygon but there is no terminal" in run.stderr
    assert f"rtcal resume {tmp_path / 'run'}" in run.stderr
    assert all(line.startswith(("rtcal:", "control token: ")) for line in run.stderr.splitlines() if line.strip()), run.stderr
