"""All protocol simulators around one bench, served from one asyncio thread.

Every instrument speaks its real protocol on a real endpoint: the stage drive as a Modbus
server (TCP, or RTU on a pseudo-terminal), the CMM as an I++ DME server, the serial ASCII
instruments on pseudo-terminals (or TCP sockets, for pyserial's ``socket://``). One thread runs
every server, so the bench is only ever touched by one thread at a time.

That thread never blocks on a client: a pseudo-terminal is written without blocking, and a
client that does not read its replies loses what the terminal cannot hold, while every other
line and server goes on answering. A request line longer than a protocol
allows is refused and the connection closed.
"""

from __future__ import annotations

import asyncio
import errno
import hmac
import json
import math
import os
import secrets
import threading
import tty
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from drivers.addresses import DEFAULT_GEAR, DEFAULT_STEPS_PER_REV  # a scenario without a stepper serves the driver's default
from drivers.models import BUILTIN
from rtcal.clock import VirtualClock
from simulators.az_drive import AzDriveModel, steps_per_degree
from simulators.bench import Bench
from simulators.instruments import (
    SimAutocollimator,
    SimCmm,
    SimDialIndicator,
    SimEncoder,
    SimEnvironmentSensor,
    SimLaserTracer,
    SimNestIndicator,
    SimStage,
)
from simulators.scenario import NEST_INDICATORS, Scenario
from simulators.servers import modbus_stage
from simulators.servers.joints_feed import FollowingLine, JointsFeed
from simulators.servers.ipp_server import IDLE_TIMEOUT_S as IPP_IDLE_TIMEOUT_S, IppMachine, serve_ipp
from simulators.servers.ports import free_port  # importable from here too (tests)

if TYPE_CHECKING:  # imported when a LinuxCNC hub starts
    from simulators.servers.linuxcnc import LinuxCncProcess
from simulators.servers.serial_protocols import (
    ElcomatHandler,
    EnvironmentNow,
    FaultyLine,
    IthxHandler,
    LineHandler,
    PiGcsHandler,
    QsbHandler,
    SylvacHandler,
    TracerHandler,
    VaisalaHandler,
)

MAX_REQUEST_BYTES = 1024  # the longest request line of the serial protocols
MAX_PENDING_REQUESTS = 16  # requests answered from one read of a line; the rest of a flood is dropped
MAX_OPERATOR_LINE = 1024
# the feeds of the LinuxCNC machine tool's address: a simulated machine has no reason to crawl
MACHINE_SPEED_DEG_PER_S, MACHINE_SPEED_MM_PER_S = 90.0, 200.0
# the product each line emulates, and the framing options a pseudo-terminal line's address carries:
# this machine's kind of pseudo-terminal accepts 8N1 everywhere, other framings only on some kernels
LINE_MODELS = {"laser_tracer": "rtcal-line", "encoder": "qsb", "autocollimator": "elcomat", "dial_indicator_1": "sylvac",
               "dial_indicator_2": "sylvac", "environment": "vaisala-ptu300",
               **{name: "sylvac" for name in NEST_INDICATORS}}
PTY_FRAMING = "bytesize=8&parity=N&stopbits=1"


class PtyWriter:
    """Writes to a pseudo-terminal's master as a serial device transmits: at once, never waiting.

    What the terminal cannot take is lost, as the bytes a device sends to a host that does not
    read them are lost in an overrun. No reply waits in a queue of ours: a client that stopped
    reading leaves at most what the terminal holds, which the next client's open discards
    (pyserial flushes input at open), so a flooder's replies never reach the client after it.
    """

    def __init__(self, fd: int):
        self.fd = fd
        self.dropped_bytes = 0
        os.set_blocking(fd, False)

    def write(self, data: bytes) -> None:
        try:
            written = os.write(self.fd, data)
        except BlockingIOError:
            written = 0
        except OSError as exc:  # the terminal is gone (EIO): nobody to answer
            if exc.errno not in (errno.EIO, errno.EBADF):
                raise
            written = 0
        self.dropped_bytes += len(data) - written


class PacedSender:
    """Hands reply bytes on at a serial line's speed: one character every (start + data + parity +
    stop bits) / baud seconds, so a client sees a 15-line listing take the second it takes on the
    product's line. Bytes queue in order; ``send`` is called from the server's loop only."""

    CHUNK = 8  # characters handed on together (8 characters at 4800 baud: 17 ms)

    def __init__(self, send, framing, loop: asyncio.AbstractEventLoop):
        bits = 1 + framing.bytesize + (framing.parity != "N") + framing.stopbits
        self.char_s = bits / framing.baud
        self.send, self.loop = send, loop
        self.queue = bytearray()
        self.busy = False

    def __call__(self, data: bytes) -> None:
        self.queue += data
        if not self.busy:
            self.busy = True
            self.loop.call_later(self.char_s * min(self.CHUNK, len(self.queue)), self._tick)

    def _tick(self) -> None:
        chunk, self.queue = bytes(self.queue[:self.CHUNK]), self.queue[self.CHUNK:]
        try:
            self.send(chunk)
        except (ConnectionError, RuntimeError, OSError):
            self.queue.clear()
        if self.queue:
            self.loop.call_later(self.char_s * min(self.CHUNK, len(self.queue)), self._tick)
        else:
            self.busy = False


def raw_pty() -> tuple[int, int, str]:
    """A pseudo-terminal in raw mode: (master fd, slave fd, slave path)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


@dataclass
class SimulatorHub:
    scenario: Scenario
    seed: int | None = None
    host: str = "127.0.0.1"
    serial: Literal["pty", "tcp"] = "pty"
    modbus: Literal["tcp", "rtu"] = "tcp"
    environment: Literal["vaisala-ptu300", "vaisala-ptb330"] = "vaisala-ptu300"
    # a second iTHX, its probe 2 on the tracer's mount (the environment's mount_thermometer=); off by default, so that
    # the environment's readings are those of the in-process run of a procedure without the probe, draw for draw
    mount_thermometer: bool = False
    stage_model: Literal["oriental-az", "pi-gcs"] = "oriental-az"  # the stage's protocol: Modbus drive or PI GCS line
    cmm_homed: bool = True  # the I++ server starts homed (a run against an unhomed one needs `home: true`)
    pace_serial: bool = False  # serial replies at the product's baud rate (4800 baud: ~2 ms a character)
    echo: bool = True  # serial products that echo commands do (the Vaisala from the factory, a Sylvac on UniCal)
    stage_start_latency_s: float = 0.005  # the drive starts a motion this long after the trigger
    stage_wall_speed_deg_per_s: float | None = None  # the drive's motions take wall time at this speed (None: at once)
    sylvac_inch: bool = True  # the indicators start with an inch display: the driver must switch them to mm
    addresses: dict[str, str] = field(default_factory=dict)
    ipp_idle_timeout_s: float = IPP_IDLE_TIMEOUT_S  # an I++ session silent this long is released
    # "linuxcnc": the stage is a real LinuxCNC started headless (simulators/servers/linuxcnc.py), the
    # bench's table following its compensated motor command; ``comp``: its COMP_FILE (type 0)
    stage: Literal["modbus", "linuxcnc"] = "modbus"
    comp: str | None = None
    # "linuxcnc": the scenario's machine tool is a real LinuxCNC with xyzac-trt-kins started headless, the
    # simulated machine's joints following its motor commands; ``kins``: the pins it loads (a .hal file of
    # setp lines), else the scenario's nominal kinematics
    machine: Literal["sim", "linuxcnc"] = "sim"
    kins: str | None = None

    def __post_init__(self) -> None:
        self.bench = Bench(self.scenario, VirtualClock(), self.seed)
        b = self.bench
        stepper = self.scenario.stepper
        self.steps_per_rev = stepper.steps_per_revolution or DEFAULT_STEPS_PER_REV
        self.gear = stepper.worm_ratio if stepper.steps_per_revolution else DEFAULT_GEAR
        # the instruments inject no faults themselves: the protocol ends do, on the wire
        self.drive = AzDriveModel(SimStage(b, inject=False), steps_per_degree(self.steps_per_rev, self.gear),
                                  self.stage_start_latency_s, self.stage_wall_speed_deg_per_s)
        self.cmm = SimCmm(b, inject=False)
        self.ipp_machine = IppMachine(homed=self.cmm_homed)
        res = self.scenario.encoder.resolution_arcsec
        self.counts_per_rev = round(1296000 / res) if res > 0 else 2**30
        lines: dict[str, LineHandler] = {
            "laser_tracer": TracerHandler(SimLaserTracer(b, inject=False)),
            "encoder": QsbHandler(SimEncoder(b, inject=False), self.counts_per_rev),
            "autocollimator": ElcomatHandler(SimAutocollimator(b, inject=False)),
            "dial_indicator_1": SylvacHandler(SimDialIndicator(b, 0, inject=False), echo=self.echo, inch=self.sylvac_inch),
            "dial_indicator_2": SylvacHandler(SimDialIndicator(b, 1, inject=False), echo=self.echo, inch=self.sylvac_inch),
        }
        # a LinuxCNC machine tool: the simulated machine follows its joints' feed (a thread of its own)
        self.joints_feed = JointsFeed(b, self.host) if self.machine == "linuxcnc" else None
        if self.scenario.machine is not None:  # the R-test's nest: three Sylvac indicators around the sphere
            for i, name in enumerate(NEST_INDICATORS):
                nest = SylvacHandler(SimNestIndicator(b, i, inject=False), echo=self.echo, inch=self.sylvac_inch)
                lines[name] = nest if self.joints_feed is None else FollowingLine(nest, self.joints_feed)
        # referenced, as a lab leaves its controller (an extra reference move would draw the table's noise anew)
        self.pi_gcs = PiGcsHandler(SimStage(b, inject=False), referenced=True) if self.stage_model == "pi-gcs" else None
        self.environment_now = EnvironmentNow(SimEnvironmentSensor(b, inject=False, mount_probe=self.mount_thermometer))
        lines["environment"] = VaisalaHandler(self.environment_now, self.environment.removeprefix("vaisala-").upper(),
                                              echo=self.echo)
        self.handlers: dict[str, LineHandler] = {name: FaultyLine(h, name, b) for name, h in lines.items()}
        self.operator_token = secrets.token_urlsafe(18)  # only the run given the operator's address may use it
        self._fds: list[int] = []
        self._pty_writers: list[PtyWriter] = []
        self._line_masters: dict[str, int] = {}  # serial line name → its pseudo-terminal's master
        self._loop = asyncio.new_event_loop()
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._servers: list = []
        self.linuxcnc: LinuxCncProcess | None = None  # the LinuxCncProcess of a `stage="linuxcnc"` hub
        self.feed_updates = 0  # motor positions the LinuxCNC bench feed delivered
        self._feed_address = ""
        if self.machine == "linuxcnc" and self.stage == "linuxcnc":
            raise ValueError("one LinuxCNC per machine: the stage or the machine tool, not both")
        if self.machine == "linuxcnc" and self.scenario.machine is None:
            raise ValueError("a LinuxCNC machine tool drives the scenario's `machine:`, and it has none")

    # -- life cycle
    def start(self, timeout_s: float = 10.0) -> dict[str, str]:
        """Start every server; return the address of each instrument once all listen."""
        self._thread = threading.Thread(target=self._run, name="rtcal-sim", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s) or self._error:
            self.stop()
            raise RuntimeError(f"simulators did not start: {self._error!r}")
        if self.stage == "linuxcnc":
            from simulators.servers.linuxcnc import LinuxCncProcess

            self.linuxcnc = LinuxCncProcess(self.host, feed=self._feed_address,
                                            comp_file=Path(self.comp) if self.comp else None)
            try:
                port = self.linuxcnc.start()
            except BaseException:
                self.stop()
                raise
            self.addresses["stage"] = f"linuxcncrsh://{self.host}:{port}?axis=C&joint=0&take_control=1"
        if self.machine == "linuxcnc":
            from simulators.servers.linuxcnc import LinuxCncProcess, kins_hal

            assert self.scenario.machine is not None
            assert self.joints_feed is not None
            self.linuxcnc = LinuxCncProcess(self.host, feed=self.joints_feed.address, machine="trt",
                                            kins_hal=kins_hal(self.scenario.machine, self.kins))
            try:
                port = self.linuxcnc.start()
            except BaseException:
                self.stop()
                raise
            self.addresses["machine_tool"] = (f"linuxcncrsh://{self.host}:{port}?take_control=1&"
                                              f"speed_deg_per_s={MACHINE_SPEED_DEG_PER_S:g}&"
                                              f"speed_mm_per_s={MACHINE_SPEED_MM_PER_S:g}")
        return dict(self.addresses)

    def stop(self) -> None:
        if self.linuxcnc is not None:
            self.linuxcnc.stop()  # first: its bench feed must not outlive the bench
        if self.joints_feed is not None:
            self.joints_feed.close()
        if self._thread and self._thread.is_alive():
            asyncio.run_coroutine_threadsafe(self._shutdown(), self._loop)
            self._thread.join(5)
        for fd in self._fds:
            try:
                os.close(fd)
            except OSError:
                pass
        self._fds.clear()

    def dropped_reply_bytes(self) -> int:
        """Reply bytes dropped because a pseudo-terminal's client did not read them."""
        return sum(w.dropped_bytes for w in self._pty_writers)

    def wait_line_idle(self, name: str, timeout_s: float = 5.0, quiet_s: float = 0.1) -> bool:
        """Wait until the serial line ``name`` has answered every request written to it.

        Idle means: nothing waits to be read at the master, seen from the server thread itself
        (so no request is between being read and answered), and that stayed so for ``quiet_s``
        (a terminal hands written bytes to its master through the kernel's work queue, which
        takes microseconds). A client opened after this reads no reply meant for another."""
        import fcntl
        import struct
        import termios
        import time

        master = self._line_masters[name]

        async def waiting_bytes() -> int:
            return struct.unpack("i", fcntl.ioctl(master, termios.FIONREAD, b"\0\0\0\0"))[0]

        deadline = time.monotonic() + timeout_s
        quiet_since = None
        while time.monotonic() < deadline:
            if asyncio.run_coroutine_threadsafe(waiting_bytes(), self._loop).result(timeout_s):
                quiet_since = None
            elif quiet_since is None:
                quiet_since = time.monotonic()
            elif time.monotonic() - quiet_since >= quiet_s:
                return True
            time.sleep(0.01)
        return False

    def __enter__(self) -> "SimulatorHub":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._start_all())
        except BaseException as exc:  # reported by start()
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        self._loop.run_forever()
        self._loop.close()

    async def _shutdown(self) -> None:
        """Close every server and connection, then stop the loop."""
        for fd in self._fds:
            try:
                self._loop.remove_reader(fd)
                self._loop.remove_writer(fd)
            except (ValueError, OSError):
                pass
        for server in self._servers:
            if isinstance(server, asyncio.base_events.Server):
                server.close()
        tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        self._loop.stop()

    async def _start_all(self) -> None:
        h = self.host
        stage_query = f"unit=1&steps_per_rev={self.steps_per_rev}&gear={self.gear:g}"
        if self.stage == "linuxcnc":
            feed = await asyncio.start_server(self._motor_feed, h, 0, limit=MAX_REQUEST_BYTES)
            self._servers.append(feed)
            self._feed_address = f"{h}:{feed.sockets[0].getsockname()[1]}"
        elif self.pi_gcs is not None:
            where = await self._serve_line("stage", self.pi_gcs, model="pi-gcs")
            self.addresses["stage"] = f"{where}?model=pi-gcs&axis=1" + (
                "" if where.startswith("socket://") else f"&{PTY_FRAMING}")
        elif self.modbus == "tcp":
            port = free_port(h)
            server = modbus_stage.tcp_server(self.drive, h, port)
            self._servers.append(asyncio.ensure_future(server.serve_forever()))
            await self._wait_listening(h, port)
            self.addresses["stage"] = f"modbus-tcp://{h}:{port}?{stage_query}"
        else:
            client_path = await self._start_rtu()
            self.addresses["stage"] = f"modbus-rtu://{client_path}?{stage_query}&baud=115200&parity=N"  # a pty line: 8N1
        cmm_server = await serve_ipp(self.cmm, h, 0, self.bench.faults, self.ipp_machine, self.ipp_idle_timeout_s)
        self._servers.append(cmm_server)
        self.addresses["cmm"] = f"ipp://{h}:{cmm_server.sockets[0].getsockname()[1]}"
        for name, handler in self.handlers.items():
            model = self.environment if name == "environment" else LINE_MODELS[name]
            where = await self._serve_line(name, handler, model=model)
            self.addresses[name] = f"{where}?model={model}" + ("" if where.startswith("socket://") else f"&{PTY_FRAMING}")
        self.addresses["encoder"] += f"&counts_per_rev={self.counts_per_rev}"
        thermometer = await self._serve_line("thermometer", IthxHandler(self.environment_now), tcp=True)  # an iServer
        self.addresses["environment"] += f"&thermometer={thermometer}"
        if self.mount_thermometer:  # its own iServer, answering from the same moment as the others
            mount = await self._serve_line("mount_thermometer", IthxHandler(self.environment_now, on_mount=True), tcp=True)
            self.addresses["environment"] += f"&mount_thermometer={mount}"
        op = await asyncio.start_server(self._operator_client, h, 0, limit=MAX_OPERATOR_LINE)
        self._servers.append(op)
        self.addresses["operator"] = f"sim-operator://{h}:{op.sockets[0].getsockname()[1]}?token={self.operator_token}"

    async def _motor_feed(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """LinuxCNC's bench feed (simulators/linuxcnc/rtcal_bench_feed.py): lines ``<motor_deg> <command_deg>``,
        the joint's compensated motor command and its command; the bench's table follows the motor.
        A line that is not two finite numbers is ignored."""
        try:
            while line := await reader.readline():
                try:
                    motor_deg, command_deg = (float(w) for w in line.split())
                except ValueError:
                    continue
                if math.isfinite(motor_deg) and math.isfinite(command_deg) and abs(motor_deg) < 1e6:
                    self.bench.follow_motor(motor_deg, command_deg)
                    self.feed_updates += 1
        except (ConnectionError, ValueError, asyncio.CancelledError):
            pass
        finally:
            writer.close()

    async def _wait_listening(self, host: str, port: int) -> None:
        for _ in range(200):
            try:
                _, writer = await asyncio.open_connection(host, port)
                writer.close()
                return
            except OSError:
                await asyncio.sleep(0.02)
        raise RuntimeError(f"Modbus server did not listen on {host}:{port}")

    async def _start_rtu(self) -> str:
        """A null-modem pair of pseudo-terminals: the drive on one end, the client on the other."""
        m1, s1, p1 = raw_pty()
        m2, s2, p2 = raw_pty()
        self._fds += [m1, s1, m2, s2]

        writers = {m1: PtyWriter(m1), m2: PtyWriter(m2)}
        self._pty_writers += writers.values()

        def forward(src: int, dst: int) -> None:
            try:
                data = os.read(src, 4096)
            except (BlockingIOError, OSError):
                return
            writers[dst].write(data)

        self._loop.add_reader(m1, forward, m1, m2)
        self._loop.add_reader(m2, forward, m2, m1)
        server = modbus_stage.rtu_server(self.drive, p1)
        self._servers.append(asyncio.ensure_future(server.serve_forever()))
        await asyncio.sleep(0.2)
        return p2

    def _paced(self, send, model: str):
        """``send``, at the model's baud rate when the hub paces its serial lines."""
        framing = BUILTIN[model].framing if model in BUILTIN else None
        if not self.pace_serial or framing is None:
            return send
        return PacedSender(send, framing, self._loop)

    async def _serve_line(self, name: str, handler: LineHandler, tcp: bool = False, model: str = "") -> str:
        if self.serial == "tcp" or tcp:
            async def client(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
                buffer = b""
                send = self._paced(writer.write, model)
                try:
                    while chunk := await reader.read(4096):
                        buffer = self._answer(handler, buffer + chunk, send)
                        await writer.drain()
                except (ConnectionError, asyncio.CancelledError):
                    pass
                finally:
                    writer.close()

            server = await asyncio.start_server(client, self.host, 0)
            self._servers.append(server)
            return f"socket://{self.host}:{server.sockets[0].getsockname()[1]}"
        master, slave, path = raw_pty()
        self._fds += [master, slave]  # holding the slave open keeps the master readable between clients
        self._line_masters[name] = master
        state = {"buffer": b""}
        writer = PtyWriter(master)
        self._pty_writers.append(writer)
        send = self._paced(writer.write, model)

        def readable() -> None:
            try:
                data = os.read(master, 4096)
            except (BlockingIOError, OSError):
                return
            state["buffer"] = self._answer(handler, state["buffer"] + data, send)

        self._loop.add_reader(master, readable)
        return path

    @staticmethod
    def _answer(handler: LineHandler, buffer: bytes, send) -> bytes:
        """Answer the complete requests in the buffer; return what is left.

        An instrument answers one request at a time: more than MAX_PENDING_REQUESTS arriving at
        once is a flood, and the rest is dropped, as an instrument's input buffer overflows —
        so a flooding client costs the one thread a bounded moment per read, never the others'
        timeouts."""
        answered = 0
        while handler.terminator in buffer:
            line, buffer = buffer.split(handler.terminator, 1)
            if answered == MAX_PENDING_REQUESTS:
                return b""
            if line.strip():
                answered += 1
                reply = handler.handle(line)
                if reply:  # an injected no_reply answers nothing
                    send(reply)
        if len(buffer) > MAX_REQUEST_BYTES:
            buffer = b""  # a line this long is garbage; drop it
        return buffer

    def _operator_action(self, name: str, rest: list[str]) -> bytes:
        """``DO <name> <JSON list of arguments>``: one of the bench's OPERATOR_ACTIONS (a method's operator step,
        e.g. ``DO mount_artefact ["test_ball", [0, 0, 40]]``), answered ``OK <JSON result>``; anything else ``ERR``."""
        if name not in Bench.OPERATOR_ACTIONS:
            return b"ERR CMD\n"
        try:
            args = json.loads(rest[0]) if rest else []
            if not isinstance(args, list):
                raise ValueError("not a list of arguments")
            result = getattr(self.bench, name)(*args)
            if name == "release_emergency_stop":
                self.ipp_machine.release_emergency_stop()
            return f"OK {json.dumps(result, allow_nan=False)}\n".encode()
        except (ValueError, TypeError, RecursionError):
            return b"ERR ARG\n"

    async def _operator_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """The simulated operator, for the run given its address: every line is ``AUTH <token> <command>``
        (the token of the address ``rtcal sim serve`` printed); without it, ``ERR AUTH`` and nothing
        done. ``DO <action> <JSON arguments>`` does one of the bench's OPERATOR_ACTIONS (what a method's
        operator step asks of the simulated operator) and answers ``OK <JSON result>``; ``PING`` answers ``OK``.
        The older lines still work: ``RESEAT <deg>`` re-seats the polygon on the bench; ``MOUNT <0|1>`` moves the
        laser tracer to its first or second mount; ``CERT?`` hands over the polygon's calibration certificate
        (face errors, arcsec); ``CLEAR`` releases an emergency stop (the drive's and the CMM's)."""
        try:
            while line := await reader.readline():
                words = line.decode(errors="replace").split()
                if len(words) < 3 or words[0] != "AUTH" or not hmac.compare_digest(words[1].encode(),
                                                                                    self.operator_token.encode()):
                    writer.write(b"ERR AUTH\n")
                    await writer.drain()
                    continue
                words = words[2:]
                if len(words) == 2 and words[0] == "RESEAT":
                    try:
                        offset_deg = float(words[1])
                    except ValueError:
                        offset_deg = math.nan
                    if math.isfinite(offset_deg) and abs(offset_deg) <= 360.0:
                        self.bench.reseat_polygon(offset_deg)
                        writer.write(b"OK\n")
                    else:
                        writer.write(b"ERR ARG\n")
                elif len(words) == 2 and words[0] == "MOUNT" and words[1] in ("0", "1"):
                    self.bench.mount_tracer(int(words[1]))
                    writer.write(b"OK\n")
                elif words == ["CLEAR"]:
                    self.bench.emergency_stop = False
                    self.ipp_machine.release_emergency_stop()
                    writer.write(b"OK\n")
                elif words == ["CERT?"]:
                    values = " ".join(f"{v:.6f}" for v in self.bench.face_certificate_arcsec)
                    writer.write(f"CERT {values}\n".encode())
                elif words == ["PING"]:
                    writer.write(b"OK\n")
                elif len(words) >= 2 and words[0] == "DO":
                    writer.write(self._operator_action(words[1], line.decode(errors="replace").split(None, 4)[4:]))
                else:
                    writer.write(b"ERR CMD\n")
                await writer.drain()
        except ValueError:  # a line beyond the limit: refused, and this client let go
            writer.write(b"ERR LINE\n")
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            writer.close()
