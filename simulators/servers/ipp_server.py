"""An I++ DME server (asyncio TCP) backed by the simulated CMM, behaving as the standard says a
server does (docs/protocols/ipp_dme.md):

- every transaction ends with ``%``, an error reply included; a malformed line gets ``!`` and ``%``;
- an error of severity 2 or more puts the session in its error state: every later command but
  ``ClearAllErrors()`` (and ``EndSession()``) is answered with error 0514 until it is sent;
- one session at a time: a second client's ``StartSession()`` is refused while another holds
  the session (it waits half a second for a holder that is going away); a second
  ``StartSession()`` on one connection is error 0008 (§6.3.1);
- the machine must be homed before it moves (§6.3.2.1: ``IsHomed()``, ``Home()``; an unhomed
  ``GoTo``/``PtMeas`` gets 0507, as NIST's server answers); it starts homed or not (an option);
- ``SetCoordSystem(MachineCsy | MoveableMachineCsy | MultipleArmCsy | PartCsy)`` (§6.3.3.1) selects
  the system positions are given in, and a new session keeps the previous session's (§6.3.1.1);
  the part system here is the machine's shifted by ``part_origin_mm``;
- it can write warnings (severity 1, which do not end a transaction, §8.1), error lines in the
  specification's form (F3 bare, §8.1) or NIST's (F3 quoted), and an ``E0000`` emergency-stop
  event (§6.2.4.1), after which motions are refused until it is released;
- ``AbortE()`` (an event command, tags ``E0001``…, §6.3.1.5) is answered ``&``, ``%``;
- ``GetDMEVersion()`` identifies the server; ``ChangeTool``/``SetTool`` know the simulated tools;
- ``PtMeas`` probes the one surface the simulated CMM has — its table top, the plane at the
  bottom of the measuring volume — along the given normal, and misses it (error 1006) when the
  surface is farther than the search distance from the nominal point.
"""

from __future__ import annotations

import asyncio
import math

import numpy as np

from drivers import ipp
from drivers.errors import OutOfLimits
from simulators.instruments import SimCmm

MAX_LINE_BYTES = 64 * 1024
DME_VERSION = "1.4 rtcal SIMULATED"  # the version string is the server's only identity: it says it
TOOLS = ("Probe", "CatEye", "RefTool")  # what ChangeTool/SetTool find
SEARCH_MM = 5.0  # PtMeas looks for the surface this far either side of the nominal point
HOLDER_GRACE_S = 0.5  # a StartSession waits this long for a holder whose connection is closing
# a session whose client sends nothing for this long is released and its connection closed, so a client
# that opens a session and falls silent cannot hold the simulated CMM forever (`rtcal sim serve
# --ipp-idle-timeout-s`; docs/faults.md says what that means for a run)
IDLE_TIMEOUT_S = 600.0
COORDINATE_SYSTEMS = ("MachineCsy", "MoveableMachineCsy", "MultipleArmCsy", "PartCsy")
WARNING = ("0512", "No daemons are active")  # a severity-1 entry of the standard's table: harmless to a reading


class IppMachine:
    """What outlives a session: homed or not, the active coordinate system, an emergency stop."""

    def __init__(self, homed: bool = True, coordinate_system: str = "MachineCsy",
                 part_origin_mm: tuple[float, float, float] = (100.0, 0.0, 0.0), warnings: bool = False,
                 bare_cause: bool = False):
        self.homed = homed
        self.coordinate_system = coordinate_system
        self.part_origin_mm = np.asarray(part_origin_mm, float)
        self.warnings = warnings  # every Get and GoTo also answers a severity-1 warning
        self.bare_cause = bare_cause  # error lines in §8.1's form: Error(3, 1008, GoTo, "…")
        self.emergency = False
        self.aborts = 0  # AbortE() received
        self.emergency_at_motion = 0  # > 0: that many motions from now, an emergency stop during the motion
        self.motions = 0
        self._writers: set = set()
        self._loop: asyncio.AbstractEventLoop | None = None

    def offset_mm(self) -> np.ndarray:
        """Machine position − position in the active system."""
        return self.part_origin_mm if self.coordinate_system == "PartCsy" else np.zeros(3)

    def press_emergency_stop(self) -> None:
        """From any thread: the E0000 event goes to every connected client; motions are refused."""
        self.emergency = True
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._broadcast, emergency_event("GoTo", self.bare_cause))

    def release_emergency_stop(self) -> None:
        self.emergency = False

    def _broadcast(self, line: str) -> None:
        for writer in list(self._writers):
            if not writer.is_closing():
                writer.write(line.encode("ascii"))


def emergency_event(cause: str, bare: bool) -> str:
    return ipp.error_line(ipp.EVENT_TAG, ipp.EMERGENCY_STOP, cause, "Emergency stop", quoted=not bare)


class SessionLock:
    """Who holds the server's one session (shared by every connection of one server)."""

    def __init__(self) -> None:
        self.holder: object | None = None
        self.released = asyncio.Event()

    def release(self, session: object) -> None:
        if self.holder is session:
            self.holder = None
            self.released.set()

    async def wait_for(self, session: object, timeout_s: float) -> None:
        """Give a holder whose connection is closing a moment to go (its EOF may be read after the
        newcomer's StartSession)."""
        if self.holder is not None and self.holder is not session:
            self.released.clear()
            try:
                await asyncio.wait_for(self.released.wait(), timeout_s)
            except asyncio.TimeoutError:
                pass


class IppSession:
    """One client's connection: turns request lines into reply lines."""

    def __init__(self, cmm: SimCmm, faults=None, lock: SessionLock | None = None, machine: IppMachine | None = None):
        self.cmm = cmm
        self.faults = faults  # the bench's injector: one draw per motion command
        self.lock = lock or SessionLock()
        self.machine = machine or IppMachine()
        self.started = False
        self.error_state = False
        self.tool = "Probe"

    def _error(self, tag: str, code: str, cause: str, text: str = "", ack: bool = True) -> str:
        if ipp.ERRORS.get(code, (3, ""))[0] >= 2:
            self.error_state = True
        line = ipp.error_line(tag, code, cause, text, quoted=not self.machine.bare_cause)
        return (f"{tag} &\r\n" if ack else "") + line + f"{tag} %\r\n"

    def _warning(self, tag: str, cause: str) -> str:
        if not self.machine.warnings:
            return ""
        return ipp.error_line(tag, WARNING[0], cause, WARNING[1], quoted=not self.machine.bare_cause, severity=1)

    def handle(self, line: str) -> str:
        m = ipp.COMMAND.fullmatch(line.strip())
        if m is None:
            tag = line[:5] if line[:5].isdigit() and line[:5] != "00000" else "00000"
            code = "0001" if tag == "00000" else "0002" if line[5:6] != " " else ipp.PROTOCOL_ERROR
            return self._error(tag, code, "", ack=False)
        tag, name, args = m.groups()
        if tag.startswith("E"):  # an event command: answered at once, in or out of the error state
            if name != "AbortE":
                return self._error(tag, ipp.UNSUPPORTED_COMMAND, name)
            self.machine.aborts += 1  # counted: the tests check that every way a run ends aborts the CMM
            return f"{tag} &\r\n{tag} %\r\n"  # nothing runs between two lines of this server: nothing to abort
        if name == "StartSession":
            return self._start(tag)
        if not self.started:
            return self._error(tag, ipp.ILLEGAL_COMMAND, name, "No session: send StartSession() first")
        if name == "ClearAllErrors":
            self.error_state = False
            return f"{tag} &\r\n{tag} %\r\n"
        if name == "EndSession":
            self.end()
            return f"{tag} &\r\n{tag} %\r\n"
        if self.error_state:
            return self._error(tag, ipp.USE_CLEAR_ALL_ERRORS, name)
        return self._command(tag, name, args)

    def _start(self, tag: str) -> str:
        if self.started:
            return self._error(tag, ipp.PROTOCOL_ERROR, "StartSession", "Session already started")
        if self.lock.holder is not None and self.lock.holder is not self:
            return self._error(tag, ipp.ILLEGAL_COMMAND, "StartSession", "Another client holds the session")
        self.lock.holder = self
        self.started, self.error_state = True, False
        return f"{tag} &\r\n{tag} %\r\n"

    def end(self) -> None:
        self.started = False
        self.lock.release(self)

    def _command(self, tag: str, name: str, args: str) -> str:
        ack, done = f"{tag} &\r\n", f"{tag} %\r\n"
        if name == "GetDMEVersion":
            return ack + f'{tag} # DMEVersion("{DME_VERSION}")\r\n' + done
        if name == "Home":
            if self.machine.emergency:
                return self._error(tag, ipp.EMERGENCY_STOP, name)
            self.cmm.home()
            self.machine.homed = True
            return ack + done
        if name == "IsHomed":
            return ack + f"{tag} # IsHomed({int(self.machine.homed)})\r\n" + done
        if name == "SetCoordSystem":
            if args.strip() not in COORDINATE_SYSTEMS:
                return self._error(tag, ipp.BAD_ARGUMENT, name)
            self.machine.coordinate_system = args.strip()
            return ack + done
        if name == "GetCoordSystem":
            return ack + f"{tag} # CoordSystem({self.machine.coordinate_system})\r\n" + done
        if name in ("ChangeTool", "SetTool"):
            m = ipp.STRING_ARG.fullmatch(args)
            if m is None:
                return self._error(tag, ipp.INCORRECT_ARGUMENTS, name)
            if m.group(1) not in TOOLS:
                return self._error(tag, ipp.TOOL_NOT_FOUND, name)
            self.tool = m.group(1)
            return ack + done
        if name in ("GoTo", "PtMeas"):
            if self.machine.emergency:
                return self._error(tag, ipp.EMERGENCY_STOP, name)
            if not self.machine.homed:
                return self._error(tag, ipp.ILLEGAL_COMMAND, name, "Machine not homed: Home() first")
            self.machine.motions += 1
            if self.machine.emergency_at_motion and self.machine.motions >= self.machine.emergency_at_motion:
                self.machine.emergency_at_motion, self.machine.emergency = 0, True
                self.error_state = True
                return (ack + emergency_event(name, self.machine.bare_cause)
                        + ipp.error_line(tag, ipp.TRANSACTION_ABORTED, name, quoted=not self.machine.bare_cause) + done)
            fault = self.faults.draw("cmm") if self.faults else None
            if fault is not None and fault.kind == "no_reply":
                return ""
            if fault is not None and fault.kind == "garbled":
                return "\x15#?% garbage\r\n"
            if fault is not None and fault.kind == "truncated":
                return f"{tag} "
            return self._motion(tag, name, args)
        if name == "Get":
            wanted = ipp.axes(args)
            if not wanted or set(wanted) - {"X", "Y", "Z"}:
                return self._error(tag, ipp.BAD_ARGUMENT, name, "Get supports X(), Y(), Z()")
            pos = dict(zip("XYZ", self.cmm.position_mm() - self.machine.offset_mm()))
            body = ", ".join(f"{a}({pos[a]:.6f})" for a in "XYZ" if a in wanted)
            return ack + self._warning(tag, name) + f"{tag} # {body}\r\n" + done
        return self._error(tag, ipp.UNSUPPORTED_COMMAND, name)

    def _motion(self, tag: str, name: str, args: str) -> str:
        values = ipp.axes(args)
        if any(v is None or not math.isfinite(v) for v in values.values()):
            return self._error(tag, ipp.BAD_ARGUMENT, name)
        if not values or (name == "PtMeas" and set(values) != {"X", "Y", "Z"}):
            return self._error(tag, ipp.INCORRECT_ARGUMENTS, name, "Needs X(), Y() and Z()")
        offset = self.machine.offset_mm()
        here = dict(zip("XYZ", self.cmm.bench.probe_target_mm - offset))
        target = np.array([values.get(a, here[a]) for a in "XYZ"], float) + offset  # the machine's coordinates
        if name == "PtMeas":
            touched = self._probe(target, args)
            if touched is None:
                return self._error(tag, ipp.SURFACE_NOT_FOUND, name)
            target = touched
        try:
            self.cmm.move_to(target)
        except OutOfLimits:
            return self._error(tag, ipp.OUT_OF_VOLUME, name)
        if name == "PtMeas":
            return f"{tag} &\r\n{tag} # {ipp.format_axes(*(self.cmm.position_mm() - offset))}\r\n{tag} %\r\n"
        return f"{tag} &\r\n" + self._warning(tag, name) + f"{tag} %\r\n"

    def _probe(self, nominal: np.ndarray, args: str) -> np.ndarray | None:
        """Where the probe, moving along −IJK through the nominal point, meets the table top; None if
        it does not within ±SEARCH_MM (no IJK: straight down)."""
        m = ipp.IJK.search(args)
        try:
            normal = np.array([float(v) for v in m.groups()]) if m else np.array([0.0, 0.0, 1.0])
        except ValueError:
            return None
        norm = float(np.linalg.norm(normal))
        surface_z = self.cmm.volume_min_mm[2]
        if not (norm > 0 and math.isfinite(norm) and math.isfinite(surface_z)) or normal[2] == 0:
            return None
        normal = normal / norm
        t = (nominal[2] - surface_z) / normal[2]  # nominal − t·normal lies on the surface
        return nominal - t * normal if abs(t) <= SEARCH_MM else None


async def serve_ipp(cmm: SimCmm, host: str, port: int, faults=None,
                    machine: IppMachine | None = None, idle_timeout_s: float = IDLE_TIMEOUT_S) -> asyncio.base_events.Server:
    """Start an I++ server: one session at a time, held until EndSession, the connection closes, or
    its client stays silent for ``idle_timeout_s`` (then the session is released and the
    connection closed). ``machine`` is what outlives a session (homing, coordinate system, e-stop)."""
    lock = SessionLock()
    machine = machine or IppMachine()
    machine._loop = asyncio.get_running_loop()

    async def next_line(reader: asyncio.StreamReader, session: IppSession) -> bytes:
        while True:
            try:
                return await asyncio.wait_for(reader.readline(), idle_timeout_s)
            except asyncio.TimeoutError:
                if lock.holder is session:
                    return b""  # idle while holding the session: let it go
                # no session held: an idle connection costs nobody anything

    async def client(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        session = IppSession(cmm, faults, lock, machine)
        machine._writers.add(writer)
        try:
            while line := await next_line(reader, session):
                text = line.decode("ascii", errors="replace")
                if text[6:].startswith("StartSession("):
                    await lock.wait_for(session, HOLDER_GRACE_S)
                reply = session.handle(text)
                writer.write(reply.encode("ascii", errors="replace"))
                await writer.drain()
        except ValueError:  # a line beyond MAX_LINE_BYTES: answered with a protocol error, the client let go
            writer.write(ipp.error_line("00000", ipp.PROTOCOL_ERROR, "", "Line too long").encode("ascii"))
        except (ConnectionError, asyncio.IncompleteReadError, asyncio.CancelledError):
            pass
        finally:
            machine._writers.discard(writer)
            session.end()
            writer.close()

    return await asyncio.start_server(client, host, port, limit=MAX_LINE_BYTES)
