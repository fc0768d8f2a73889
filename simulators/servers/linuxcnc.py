"""LinuxCNC, started headless from the configuration rtcal ships (simulators/linuxcnc/), and stopped.

``LinuxCncProcess.start()`` copies the INI, HAL and the bench-feed component into a fresh folder,
sets linuxcncrsh's port, adds ``COMP_FILE``/``COMP_FILE_TYPE`` to the joint when a table is
given (LinuxCNC reads it only at start), and runs ``linuxcnc`` in its own process group, with
the bench feed's address in ``RTCAL_BENCH_FEED``. It returns once linuxcncrsh answers
``hello`` and the simulated operator has brought the machine up at a console of its own (E-stop
released, machine on, joint homed: ``operator()``), which rtcal never does itself. ``stop()`` sends SIGTERM to the group (the ``linuxcnc`` script's trap then runs its
cleanup: displays, tasks, HAL, realtime), waits, and kills what is left; it is idempotent and
registered with atexit, so no LinuxCNC outlives its starter.

As root, ``rtapi_app`` refuses to run without a fallback uid: ``RTAPI_UID`` is set to ``nobody``
and ``RTAPI_FIFO_PATH`` to a file directly under /tmp (../shared/reference/linuxcnc_headless.md).
Only one LinuxCNC can run on a machine (its HAL shared memory and /tmp/linuxcnc.lock are global):
``start()`` holds an exclusive lock on ``MACHINE_LOCK`` until ``stop()``, so a second one is refused
with a message rather than colliding with the first in HAL.
"""

from __future__ import annotations

import atexit
import fcntl
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
import uuid
from pathlib import Path

from typing import TYPE_CHECKING

from simulators.servers.ports import free_port

if TYPE_CHECKING:
    from simulators.scenario import MachineToolScenario

CONFIG = Path(__file__).resolve().parents[1] / "linuxcnc"
INI, HAL, FEED = "rtcal_c.ini", "rtcal_c.hal", "rtcal_bench_feed.py"
# the machines rtcal ships: the rotary table alone (C, joint 0), X Y Z with the table as joint 3, and the
# five-axis machine with a trunnion table (xyzac-trt-kins; its pins in KINS_HAL, written at each start)
MACHINES = {"c": ("rtcal_c.ini", "rtcal_c.hal"), "xyzc": ("rtcal_xyzc.ini", "rtcal_xyzc.hal"),
            "trt": ("rtcal_trt.ini", "rtcal_trt.hal")}
KINS_HAL = "rtcal_trt_kins.hal"
JOINTS = {"c": 1, "xyzc": 4, "trt": 5}
SYSTEM_PYTHON = "/usr/bin/python3"  # LinuxCNC's hal module is built for it alone
NOBODY_UID = 65534
NML_FILE = Path("/usr/share/linuxcnc/linuxcnc.nml")  # the default NML_FILE the linuxcnc script uses
MACHINE_LOCK = Path("/tmp/rtcal-linuxcnc.flock")  # held by the one LinuxCNC rtcal runs on this machine


def available() -> str:
    """"" when LinuxCNC can be started here, else why not (for skips and for `sim serve`'s message)."""
    if shutil.which("linuxcnc") is None or shutil.which("halcmd") is None:
        return "LinuxCNC is not installed (apt-get install -y linuxcnc-uspace)"
    if not Path(SYSTEM_PYTHON).exists():
        return f"{SYSTEM_PYTHON} (the Python LinuxCNC's hal module is built for) is missing"
    return ""


def kins_hal(machine: "MachineToolScenario", kins_file: str | None = None) -> str:
    """The text of KINS_HAL: ``setp`` lines of xyzac-trt-kins' five pins — those ``kins_file`` sets (a .hal
    file or INI [HAL] lines, what `rtcal compensate --format linuxcnc-xyzac-trt` writes; a pin it does not
    set is 0, as in LinuxCNC), else the scenario's nominal kinematics (C's line through the rot point, A's
    through rot point + (0, y-offset, z-offset): trtfuncs.c). Only these pins are written, whatever else
    the file holds. ValueError (with the file's line) for a file LinuxCNC would read otherwise."""
    from rtcal.compensation.linuxcnc_kins import PINS, PREFIX, LinuxCncTrtFormat
    from rtcal.compensation.table import CompensationError

    if kins_file is not None:
        try:
            pins = LinuxCncTrtFormat().parse(Path(kins_file).read_text(), kins_file)
        except CompensationError as exc:
            raise ValueError(str(exc)) from None
    else:
        c, a = machine.kinematics.c_point_mm, machine.kinematics.a_point_mm
        pins = {"x-rot-point": c[0], "y-rot-point": c[1], "z-rot-point": c[2], "y-offset": a[1] - c[1],
                "z-offset": a[2] - c[2]}
    source = kins_file or "the scenario's nominal kinematics"
    return f"# rtcal sim serve: xyzac-trt-kins' pins from {source}\n" + "".join(
        f"setp {PREFIX}.{pin} {pins[pin]!r}\n" for pin in PINS)


def with_comp(ini_text: str, comp_file: Path, comp_type: int = 0, joint: int = 0) -> str:
    """The INI with ``COMP_FILE`` and ``COMP_FILE_TYPE`` in ``[JOINT_<joint>]``."""
    head = f"[JOINT_{joint}]\n"
    if head not in ini_text:
        raise ValueError(f"the INI has no {head.strip()}")
    return ini_text.replace(head, f"{head}COMP_FILE = {comp_file}\nCOMP_FILE_TYPE = {comp_type}\n", 1)


def console(host: str, port: int, *requests: str, timeout_s: float = 30.0, joints: int = 1) -> list[str]:
    """An operator at a linuxcncrsh console of their own: ``requests`` (e.g. ``set estop off``, ``set
    machine on``, ``set home 0``, ``get estop``), each answered before the next (``set_wait done``);
    their replies. A refused ``set`` is tried again (seen: ``set machine on`` or ``set mode manual``
    refused just after the step before it), RuntimeError if it is still refused after ``timeout_s``;
    after ``set home`` it waits until the joint is homed (``set home -1``: each of the ``joints``)."""
    replies = []
    with socket.create_connection((host, port), timeout=timeout_s) as s, s.makefile("rb") as lines:
        def ask(line: str) -> str:
            s.sendall(line.encode() + b"\r\n")
            while True:
                reply = lines.readline().decode(errors="replace").strip()
                if reply:
                    return reply
        for line in ("hello EMC rtcal-operator 1.0", "set echo off"):
            ask(line)
        for line in ("set verbose on", "set enable EMCTOO", "set set_wait done", *requests):
            deadline = time.monotonic() + timeout_s
            reply = ask(line)
            while line.startswith("set") and reply.upper().endswith("NAK"):
                if time.monotonic() > deadline:
                    raise RuntimeError(f"LinuxCNC refused the operator's {line!r}: {ask('get error')}")
                time.sleep(0.1)
                reply = ask(line)
            replies.append(reply)
            # `set home -1` homes every joint: each must say YES (2.9's all-joints reply has one word too many)
            homing = range(joints) if line.strip() == "set home -1" else [int(line.split()[-1])] if line.startswith("set home") else []
            while any(not ask(f"get joint_homed {j}").upper().endswith("YES") for j in homing):
                if time.monotonic() > deadline:
                    raise RuntimeError(f"LinuxCNC's joints {list(homing)} did not home")
                time.sleep(0.05)
    return replies[3:]


SERVER_NAME = "rtcal-SIMULATED"
"""The simulated machine's linuxcncrsh server name: its HELLO ACK, and so the stage's identity, says SIMULATED."""

class LinuxCncProcess:
    """One headless LinuxCNC: ``start()`` → linuxcncrsh's port; ``stop()`` shuts it down."""

    def __init__(self, host: str = "127.0.0.1", feed: str = "", comp_file: Path | None = None, comp_type: int = 0,
                 machine: str = "c", rsh_options: str = "", kins_hal: str = ""):
        """``machine``: one of MACHINES; ``rsh_options``: more linuxcncrsh options (e.g. ``-s 2``, its session limit);
        ``kins_hal`` (machine "trt"): the text of KINS_HAL, the kinematics' ``setp`` lines LinuxCNC loads at start."""
        self.host, self.feed, self.comp_file, self.comp_type = host, feed, comp_file, comp_type
        self.machine = machine
        self.ini_name, self.hal_name = MACHINES[machine]
        if machine == "trt" and not kins_hal.strip():
            raise ValueError("the trunnion machine needs its kinematics' pins (kins_hal)")
        self.kins_hal = kins_hal
        self.rsh_options = rsh_options
        self.proc: subprocess.Popen | None = None
        self.marker = uuid.uuid4().hex
        self.env: dict[str, str] = dict(os.environ)
        self.folder: Path | None = None
        self.fifo = Path(f"/tmp/rtcal-rtapi-{uuid.uuid4().hex[:12]}")
        self.port = 0
        self.log: Path | None = None
        self._machine_lock: int | None = None

    def _take_machine(self) -> None:
        """The machine's one LinuxCNC: an exclusive lock, or RuntimeError naming why not."""
        fd = os.open(MACHINE_LOCK, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise RuntimeError("another LinuxCNC started by rtcal is running on this machine (only one can: its HAL "
                               f"shared memory is global; {MACHINE_LOCK} is locked); stop it first") from None
        self._machine_lock = fd

    def _release_machine(self) -> None:
        fd, self._machine_lock = self._machine_lock, None
        if fd is not None:
            os.close(fd)  # closing the descriptor releases the lock

    def _write_config(self) -> Path:
        folder = Path(tempfile.mkdtemp(prefix="rtcal-linuxcnc-"))
        folder.chmod(0o755)  # rtapi_app runs as the fallback uid
        # --name: the server name linuxcncrsh gives in HELLO ACK (linuxcncrsh(1)); it says the machine is simulated
        ini = (CONFIG / self.ini_name).read_text().replace(
            "linuxcncrsh --port 5007",
            " ".join(["linuxcncrsh", "--port", str(self.port), "--name", SERVER_NAME, *self.rsh_options.split()]))
        if self.comp_file is not None:
            table = folder / "c.comp"
            shutil.copyfile(self.comp_file, table)
            ini = with_comp(ini, table, self.comp_type)
        (folder / self.ini_name).write_text(ini)
        for name in (self.hal_name, FEED):
            shutil.copyfile(CONFIG / name, folder / name)
        if self.machine == "trt":
            (folder / KINS_HAL).write_text(self.kins_hal)
        (folder / "rtcal_c.var").write_text("")  # every shipped INI names these two
        (folder / "rtcal_c.tbl").write_text("T1 P1 D0 Z0 ;rtcal: no tools\n")
        for p in folder.iterdir():
            p.chmod(0o644)
        self.folder = folder
        return folder

    def start(self, timeout_s: float = 60.0) -> int:
        """Start LinuxCNC; linuxcncrsh's port once it answers ``hello``. RuntimeError (with LinuxCNC's
        last output) if it does not come up in time."""
        why = available()
        if why:
            raise RuntimeError(why)
        self._take_machine()
        self.port = free_port(self.host)
        folder = self._write_config()
        self.env = env = dict(os.environ, RUNTESTS="1", RTCAL_BENCH_FEED=self.feed, RTCAL_LINUXCNC_ID=self.marker)
        env.pop("DISPLAY", None)  # headless: never an X display (the script would ask it about a stale lock)
        if os.geteuid() == 0:
            env.update(RTAPI_UID=str(NOBODY_UID), RTAPI_FIFO_PATH=str(self.fifo))
        self.log = folder / "linuxcnc.log"
        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen(["linuxcnc", str(folder / self.ini_name)], cwd=folder, env=env, stdin=subprocess.DEVNULL,
                                         stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        atexit.register(self.stop)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            code = self.proc.poll()
            if code is not None:
                tail = self.tail()
                self.stop()
                raise RuntimeError(f"LinuxCNC exited at start ({code}): {tail}")
            if self._hello():
                steps = ("set estop off", "set machine on", "set mode manual",
                         "set home 0" if self.ini_name == INI else "set home -1")
                try:
                    self.operator(*steps)
                except (RuntimeError, OSError):
                    # seen on a loaded host: "USRMOT: ERROR: command timeout" as the machine came on, after
                    # which it stays off and every mode change is refused; the operator starts over once
                    try:
                        self.operator("set estop on", *steps)
                    except (RuntimeError, OSError) as exc:
                        raise RuntimeError(f"{exc}; LinuxCNC's log: {self.tail(20)}") from None
                return self.port
            time.sleep(0.2)
        tail = self.tail()
        self.stop()
        raise RuntimeError(f"linuxcncrsh did not answer on port {self.port} in {timeout_s:g} s: {tail}")

    def _hello(self) -> bool:
        try:
            with socket.create_connection((self.host, self.port), timeout=1.0) as s:
                s.sendall(b"hello EMC rtcal-sim 1.0\r\n")
                return s.recv(64).startswith(b"HELLO ACK")
        except OSError:
            return False

    def operator(self, *requests: str, timeout_s: float = 30.0) -> list[str]:
        """The operator at a console of their own (``console``) on this LinuxCNC."""
        return console(self.host, self.port, *requests, timeout_s=timeout_s, joints=JOINTS[self.machine])

    def tail(self, lines: int = 8) -> str:
        try:
            text = self.log.read_text(errors="replace") if self.log else ""
        except OSError:
            text = ""
        return " | ".join(text.strip().splitlines()[-lines:])

    def kill(self) -> None:
        """Kill LinuxCNC at once (SIGKILL to its process group): a controller that dies mid-run."""
        if self.proc is not None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass

    def _clean_up_after_crash(self) -> None:
        """What the ``linuxcnc`` script's cleanup does, for a LinuxCNC killed before it could: unload
        HAL (``halrun -U``), remove NML's shared memory (the ``B … SHMEM`` keys of its NML file),
        remove the lock file. Without it the next LinuxCNC starts but never leaves E-stop."""
        subprocess.run(["halrun", "-U"], env=self.env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL, timeout=30, check=False)
        try:
            lines = NML_FILE.read_text().splitlines()
        except OSError:
            lines = []
        for line in lines:
            words = line.split()
            if len(words) >= 10 and words[0] == "B" and words[2] == "SHMEM":
                subprocess.run(["ipcrm", "-M", words[9]], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
        Path("/tmp/linuxcnc.lock").unlink(missing_ok=True)

    def _session(self) -> list[int]:
        """Every process of this LinuxCNC, found by the marker in its environment (rtapi_app and
        linuxcncsvr start sessions of their own, so no process group holds them all)."""
        marker, pids = f"RTCAL_LINUXCNC_ID={self.marker}".encode(), []
        for entry in Path("/proc").iterdir():
            if entry.name.isdigit() and int(entry.name) != os.getpid():
                try:
                    if marker in (entry / "environ").read_bytes().split(b"\0"):
                        pids.append(int(entry.name))
                except OSError:
                    continue
        return pids

    def stop(self, timeout_s: float = 20.0) -> None:
        """Shut LinuxCNC down (SIGTERM to its group: the script's cleanup), then kill what is left of
        its session and unload what a killed LinuxCNC left in HAL."""
        proc, self.proc = self.proc, None
        if proc is not None:
            crashed = proc.poll() is not None
            try:
                os.killpg(proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            try:
                proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                pass
            deadline = time.monotonic() + 10.0  # the script may exit before the processes it told to
            while self._session() and time.monotonic() < deadline:
                time.sleep(0.1)
            left = self._session()
            for pid in left:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                pass
            if crashed or left:  # no cleanup ran: HAL, NML's shared memory and the lock are still there
                self._clean_up_after_crash()
        try:
            self.fifo.unlink()
        except OSError:
            pass
        if self.folder is not None and not os.environ.get("RTCAL_KEEP_LINUXCNC_FOLDER"):
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder = None
        self._release_machine()
        atexit.unregister(self.stop)
