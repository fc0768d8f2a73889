"""An I++ DME server (asyncio TCP) backed by the simulated CMM."""

from __future__ import annotations

import asyncio
import math

import numpy as np

from drivers import ipp
from drivers.errors import OutOfLimits
from simulators.instruments import SimCmm

MAX_LINE_BYTES = 64 * 1024


class IppSession:
    """One client's session: turns request lines into reply lines."""

    def __init__(self, cmm: SimCmm, faults=None):
        self.cmm = cmm
        self.faults = faults  # the bench's injector: one draw per motion command
        self.started = False
        self.homed = False
        self.tool = "Probe"

    def handle(self, line: str) -> str:
        m = ipp.COMMAND.fullmatch(line.strip())
        if m is None:
            tag = line[:5] if line[:5].isdigit() else "00000"
            return ipp.error_line(tag, 2, ipp.PROTOCOL_ERROR, "", "Protocol error: expected TTTTT Command(...)")
        tag, name, args = m.groups()
        ack = f"{tag} &\r\n"
        done = f"{tag} %\r\n"
        if name != "StartSession" and not self.started:
            return ack + ipp.error_line(tag, 2, ipp.PROTOCOL_ERROR, name, "No session: send StartSession() first")
        if name == "StartSession":
            self.started = True
            return ack + done
        if name == "EndSession":
            self.started = False
            return ack + done
        if name == "ClearAllErrors":
            return ack + done
        if name == "Home":
            self.cmm.home()
            self.homed = True
            return ack + done
        if name == "IsHomed":
            return ack + f"{tag} # IsHomed({int(self.homed)})\r\n" + done
        if name == "SetTool":
            self.tool = args.strip().strip('"') or self.tool
            return ack + done
        if name in ("GoTo", "PtMeas"):
            fault = self.faults.draw("cmm") if self.faults else None
            if fault is not None and fault.kind == "no_reply":
                return ""
            if fault is not None and fault.kind == "garbled":
                return "\x15#?% garbage\r\n"
            if fault is not None and fault.kind == "truncated":
                return f"{tag} "
            values = ipp.axes(args)
            if set(values) != {"X", "Y", "Z"}:
                return ack + ipp.error_line(tag, 2, ipp.BAD_ARGUMENT_COUNT, name, "Needs X(), Y() and Z()")
            if any(v is None or not math.isfinite(v) for v in values.values()):
                return ack + ipp.error_line(tag, 2, ipp.BAD_ARGUMENT, name, "Bad argument")
            target = np.array([values["X"], values["Y"], values["Z"]])
            try:
                self.cmm.move_to(target)
            except OutOfLimits:
                return ack + ipp.error_line(tag, 2, ipp.OUT_OF_VOLUME, name, "Target position out of machine volume")
            if name == "PtMeas":
                return ack + f"{tag} # {ipp.format_axes(*self.cmm.position_mm())}\r\n" + done
            return ack + done
        if name == "Get":
            wanted = ipp.axes(args)
            if not wanted or set(wanted) - {"X", "Y", "Z"}:
                return ack + ipp.error_line(tag, 2, ipp.BAD_ARGUMENT, name, "Get supports X(), Y(), Z()")
            pos = dict(zip("XYZ", self.cmm.position_mm()))
            body = ", ".join(f"{a}({pos[a]:.6f})" for a in "XYZ" if a in wanted)
            return ack + f"{tag} # {body}\r\n" + done
        return ack + ipp.error_line(tag, 2, ipp.UNSUPPORTED_COMMAND, name, "Unsupported command")


async def serve_ipp(cmm: SimCmm, host: str, port: int, faults=None) -> asyncio.base_events.Server:
    """Start an I++ server; one session per connection."""

    async def client(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        session = IppSession(cmm, faults)
        try:
            while line := await reader.readline():
                writer.write(session.handle(line.decode("ascii", errors="replace")).encode("ascii", errors="replace"))
                await writer.drain()
        except ValueError:  # a line beyond MAX_LINE_BYTES: answered with a protocol error, the client let go
            writer.write(ipp.error_line("00000", 3, ipp.PROTOCOL_ERROR, "", "Line too long").encode("ascii"))
        except (ConnectionError, asyncio.IncompleteReadError, asyncio.CancelledError):
            pass
        finally:
            writer.close()

    return await asyncio.start_server(client, host, port, limit=MAX_LINE_BYTES)
