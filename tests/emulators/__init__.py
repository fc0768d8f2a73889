"""Small emulators of the real products, written from the public references
(../shared/reference/instrument_protocols.md and the sources docs/protocols/ names), sharing no
code with rtcal's drivers or protocol simulators: what `rtcal probe` reads from them is what a
real unit's bytes would give it.

Each serves one TCP connection at a time on loopback (the serial products through pyserial's
``socket://``, as a terminal server would carry them) and records every request it received.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from typing import Callable


class Emulator:
    """A TCP server thread: requests split at ``terminator``; ``answer(request, state) -> bytes``."""

    def __init__(self, answer: Callable[[bytes, dict], bytes], terminator: bytes = b"\r"):
        self.answer, self.terminator = answer, terminator
        self.requests: list[bytes] = []
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def url(self, scheme: str = "socket") -> str:
        return f"{scheme}://127.0.0.1:{self.port}"

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.listener.accept()
            except OSError:
                return
            state: dict = {}
            with conn:
                buffer = b""
                try:
                    while chunk := conn.recv(4096):
                        buffer += chunk
                        buffer = self._feed(conn, buffer, state)
                except OSError:
                    pass

    def _feed(self, conn: socket.socket, buffer: bytes, state: dict) -> bytes:
        while self.terminator in buffer:
            line, buffer = buffer.split(self.terminator, 1)
            line = line.strip(b"\r\n")
            if line:
                self.requests.append(line)
                conn.sendall(self.answer(line, state))
        return buffer

    def close(self) -> None:
        try:
            self.listener.shutdown(socket.SHUT_RDWR)  # wakes the thread's accept(); close() alone does not
        except OSError:
            pass
        self.listener.close()
        self._thread.join(2)

    def __enter__(self) -> "Emulator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# -- Oriental Motor AZ over Modbus TCP: holding registers, 32-bit values upper word first ---------------

class AzDriveEmulator(Emulator):
    """FC03 and FC16 over Modbus TCP (MBAP header: transaction, protocol 0, length, unit).

    With ``latency_s`` it moves as the samples and the reference describe a drive doing: a write of
    1 to the trigger (0x0066) starts the direct-data motion to the position at 0x005C that long
    after the trigger — until then the output status (0x007E) still shows the previous IN-POS
    (bit 14) — then MOVE (bit 13) for ``motion_s``, then IN-POS with the feedback (0x00CC) at the
    target."""

    IN_POS, MOVE, READY = 1 << 14, 1 << 13, 1 << 5

    def __init__(self, registers32: dict[int, int], unit: int = 1, latency_s: float | None = None, motion_s: float = 0.03):
        self.words: dict[int, int] = {}
        for address, value in registers32.items():
            self.set32(address, value)
        self.unit = unit
        self.latency_s, self.motion_s = latency_s, motion_s
        self.motion: tuple[float, int] | None = None  # (trigger time, target)
        super().__init__(lambda *_: b"")

    def set32(self, address: int, value: int) -> None:
        v = value & 0xFFFFFFFF
        self.words[address], self.words[address + 1] = v >> 16, v & 0xFFFF

    def get32(self, address: int) -> int:
        v = (self.words[address] << 16) | self.words[address + 1]
        return v - (1 << 32) if v & 0x80000000 else v

    def _drive(self) -> None:
        """The motion's state now: not started (previous IN-POS), moving, or done at the target."""
        if self.latency_s is None or self.motion is None:
            return
        elapsed = time.monotonic() - self.motion[0]
        if elapsed < self.latency_s:
            return
        if elapsed < self.latency_s + self.motion_s:
            self.set32(0x007E, self.MOVE | self.READY)
            return
        self.set32(0x00CC, self.motion[1])
        self.set32(0x007E, self.IN_POS | self.READY)
        self.motion = None

    def _feed(self, conn: socket.socket, buffer: bytes, state: dict) -> bytes:
        while len(buffer) >= 7 and len(buffer) >= 6 + struct.unpack(">H", buffer[4:6])[0]:
            size = 6 + struct.unpack(">H", buffer[4:6])[0]
            frame, buffer = buffer[:size], buffer[size:]
            self.requests.append(frame)
            tid, unit, pdu = frame[:2], frame[6], frame[7:]
            if unit != self.unit:
                continue  # another drive on the bus: silence
            self._drive()
            if pdu[0] == 3:
                start, count = struct.unpack(">HH", pdu[1:5])
                if any(a not in self.words for a in range(start, start + count)):
                    reply = bytes([0x83, 2])
                else:
                    reply = bytes([3, 2 * count]) + b"".join(struct.pack(">H", self.words[a]) for a in range(start, start + count))
            elif pdu[0] == 16:
                start, count = struct.unpack(">HH", pdu[1:5])
                for k in range(count):
                    self.words[start + k] = struct.unpack(">H", pdu[6 + 2 * k: 8 + 2 * k])[0]
                if self.latency_s is not None and start <= 0x0066 < start + count and self.get32(0x0066) == 1:
                    self.motion = (time.monotonic(), self.get32(0x005C))
                reply = pdu[:5]
            else:
                reply = bytes([pdu[0] | 0x80, 1])
            conn.sendall(tid + b"\0\0" + struct.pack(">H", len(reply) + 1) + bytes([unit]) + reply)
        return buffer


# -- I++ DME: tagged lines, & # % !, the error state ----------------------------------------------------

def ipp_answer(first_get_fails: bool = True, homed: bool = True, coordinate_system: str = "MachineCsy",
               part_origin_mm: tuple[float, float, float] = (100.0, 0.0, 0.0), bare_cause: bool = False,
               warnings: bool = False, emergency_at_goto: bool = False) -> Callable[[bytes, dict], bytes]:
    """An I++ DME server from the specification 1.4.3 and NIST's server: StartSession (0008 if the
    session is already started, §6.3.1), GetDMEVersion, SetCoordSystem (the active system outlives the
    session, §6.3.1.1; PartCsy is the machine's shifted by ``part_origin_mm``), IsHomed / Home (an
    unhomed GoTo is 0507, §6.3.2.1), GoTo, Get, ClearAllErrors, EndSession, AbortE (E-tagged,
    §6.3.1.5). The first Get may be answered with a severity-2 error, every command after it with
    0514 until ClearAllErrors(). Error lines with F3 quoted (NIST) or bare (§8.1); severity-1
    warnings before ``%`` (§8.1); an emergency stop during a GoTo as an ``E0000`` event (§6.2.4.1).
    ``machine`` (the returned function's attribute) is what outlives a connection."""
    machine = {"homed": homed, "csy": coordinate_system, "xyz": [1.0, 2.0, 3.0], "emergency": False}

    def error(tag: str, severity: int, code: str, method: str, text: str) -> str:
        cause = method if bare_cause else f'"{method}"'
        return f'{tag} ! Error({severity}, {code}, {cause}, "{text}")\r\n'

    def answer(line: bytes, state: dict) -> bytes:
        text = line.decode()
        tag, command = text[:5], text[6:]
        name, _, args = command.partition("(")
        args = args.rstrip(")")
        ack, done = f"{tag} &\r\n", f"{tag} %\r\n"
        offset = part_origin_mm if machine["csy"] == "PartCsy" else (0.0, 0.0, 0.0)
        if tag.startswith("E"):
            return (ack + done).encode()
        if name == "StartSession":
            if state.get("session"):
                return (ack + error(tag, 3, "0008", name, "Protocol error") + done).encode()
            state["session"] = True
            return (ack + done).encode()
        if name == "ClearAllErrors":
            state["error"] = False
            return (ack + done).encode()
        if state.get("error"):
            return (ack + error(tag, 2, "0514", name, "Use ClearAllErrors to continue") + done).encode()
        if name == "Get" and first_get_fails and not state.get("failed_once"):
            state["failed_once"] = state["error"] = True
            return (ack + error(tag, 2, "2001", name, "Head error excessive force") + done).encode()
        warning = error(tag, 1, "0504", name, "Argument out of range") if warnings else ""
        if name == "SetCoordSystem":
            machine["csy"] = args
        elif name == "IsHomed":
            return (ack + f"{tag} # IsHomed({int(machine['homed'])})\r\n" + done).encode()
        elif name == "Home":
            machine["homed"] = True
        elif name == "GoTo":
            if not machine["homed"]:
                state["error"] = True
                return (ack + error(tag, 3, "0507", name, "Illegal command") + done).encode()
            values = [float(v.split("(")[1]) for v in args.replace(" ", "").split("),") if "(" in v]
            if abs(values[0] - offset[0]) > 5000:
                state["error"] = True
                return (ack + error(tag, 3, "2500", name, "Machine limit encountered [Move Out Of Limits]") + done).encode()
            if emergency_at_goto:
                machine["emergency"] = state["error"] = True
                event = f'E0000 ! Error(3, 0500, {"GoTo" if bare_cause else chr(34) + "GoTo" + chr(34)}, "Emergency stop")\r\n'
                return (ack + event + error(tag, 2, "0006", name, "Transaction aborted") + done).encode()
            machine["xyz"] = [v + o for v, o in zip(values, offset)]
            return (ack + warning + done).encode()
        elif name == "Get":
            x, y, z = (v - o for v, o in zip(machine["xyz"], offset))
            return (ack + warning + f"{tag} # X({x:g}), Y({y:g}), Z({z:g})\r\n" + done).encode()
        elif name == "EndSession":
            state["session"] = False
        data = {"GetDMEVersion": 'DMEVersion("1.4")'}.get(name)
        return (ack + (f"{tag} # {data}\r\n" if data else "") + done).encode()

    answer.machine = machine  # type: ignore[attr-defined]
    return answer


# -- PI GCS: one axis, LF-ended lines, queries answer "1=<value>", ERR? after commands --------------

def pi_gcs(position_deg: float = 0.0, referenced: bool = True, travel_deg: float = 180.0,
           velocity_deg_per_s: float | None = None, motion_error_after_s: float | None = None,
           clock: Callable[[], float] = time.monotonic) -> Callable[[bytes, dict], bytes]:
    """A PI controller with rotation axis 1 as pipython talks to it (gcsbasecommands.py, gcsmessages.py,
    gcserror.py): ``*IDN?``; ``SVO 1 1``; ``FRF 1`` / ``FRF? 1``; ``MOV 1 <deg>`` (error 5 without servo
    or reference, 7 outside the travel range); ``POS? 1``, ``ONT? 1`` (0 for two polls after a move);
    ``VEL? 1``; ``ERR?`` answers the error code and clears it; ``HLT 1`` / ``STP`` set error 10.
    Commands answer nothing. ``velocity_deg_per_s``: a move takes distance / velocity on ``clock``
    (``POS?`` on the way, ``ONT?`` 0 until it arrives; else a move is done at once);
    ``motion_error_after_s``: each timed move stops that long after it starts with the servo off and
    error 1024 (MS249E §8.7: position error too large, servo switched off), never on target. ``state``
    (the returned function's attribute) outlives a connection."""
    state = {"pos": position_deg, "servo": False, "referenced": referenced, "error": 0, "settle": 0, "ont_polls": 0,
             "move": None}

    def fail(code: int) -> bytes:
        state["error"] = state["error"] or code
        return b""

    def advance() -> None:
        """Where a timed move has got to (and a motion error, once its time has come)."""
        if state["move"] is None:
            return
        start_s, start_deg, target_deg = state["move"]
        elapsed_s = clock() - start_s
        if motion_error_after_s is not None and elapsed_s >= motion_error_after_s:
            elapsed_s = motion_error_after_s
            state["servo"], state["move"], state["settle"] = False, None, -1  # -1: never on target
            fail(1024)
        travel_deg = target_deg - start_deg
        done = min(1.0, elapsed_s * velocity_deg_per_s / abs(travel_deg)) if travel_deg else 1.0
        state["pos"] = start_deg + done * travel_deg
        if done >= 1.0:
            state["move"] = None

    def answer(line: bytes, _: dict) -> bytes:
        words = line.decode().split()
        cmd, args = words[0], words[1:]
        advance()
        if cmd == "*IDN?":
            return b"(c)2019 Physik Instrumente (PI) GmbH & Co. KG, C-884.4DC, 119012345, 2.0.1\n"
        if cmd == "ERR?":
            code, state["error"] = state["error"], 0
            return f"{code}\n".encode()
        if cmd in ("HLT", "STP"):
            state["move"] = None
            return fail(10)
        if cmd == "SVO" and args[:1] == ["1"]:
            state["servo"] = args[1] == "1"
            return b""
        if cmd == "FRF" and args[:1] == ["1"]:
            if not state["servo"]:
                return fail(5)
            state["pos"], state["referenced"], state["settle"] = 0.0, True, 2
            return b""
        if cmd == "MOV" and args[:1] == ["1"]:
            if not (state["servo"] and state["referenced"]):
                return fail(5)
            target = float(args[1])
            if abs(target) > travel_deg:
                return fail(7)
            if velocity_deg_per_s is None:
                state["pos"] = target
            else:
                state["move"] = (clock(), state["pos"], target)
            state["settle"] = 2
            return b""
        if cmd.endswith("?") and args == ["1"]:
            if cmd == "ONT?":
                state["ont_polls"] += 1
                on = state["settle"] == 0 and state["move"] is None
                if state["settle"] > 0:
                    state["settle"] -= 1
                return f"1={int(on)}\n".encode()
            value = {"POS?": f"{state['pos']:.6f}", "FRF?": str(int(state["referenced"])), "SVO?": str(int(state["servo"])),
                     "VEL?": f"{velocity_deg_per_s or 10.0:.6f}"}.get(cmd)
            if value is not None:
                return f"1={value.rstrip('0').rstrip('.') if '.' in value else value}\n".encode()
        return fail(2)

    answer.state = state  # type: ignore[attr-defined]
    return answer


# -- serial products -----------------------------------------------------------------------------------

def elcomat(line: bytes, state: dict) -> bytes:
    """dls-controls/elcomat3000: ``d`` → ``8 <serial> <day> <month> <year> <focal length>``."""
    return {b"a": b"4 003 12.34 -5.67\r", b"r": b"2 103 0.50 0.25\r", b"d": b"8 30123 15 01 2026 300\r"}.get(line, b"")


def elcomat_one_axis(valid_digit: str) -> Callable[[bytes, dict], bytes]:
    """An absolute reading whose status says only X (1) or only Y (2) is valid (dls-controls/elcomat3000)."""
    return lambda line, state: f"4 00{valid_digit} 12.34 -5.67\r".encode() if line == b"a" else elcomat(line, state)


def sylvac(line: bytes, state: dict) -> bytes:
    return sylvac_opto_rs()(line, state)


def sylvac_opto_rs(inch: bool = False, echo: bool = False, accepts_mm: bool = True,
                   displacement_mm: float = -0.0123) -> Callable[[bytes, dict], bytes]:
    """A Sylvac indicator as the OPTO-RS cable manual describes it: the value as ``[sign or
    space][digits].[decimals]`` and CR with **no unit** (the display's unit: inches show 5
    decimals), ``MM`` / ``IN`` set the unit, ``UNI?`` answers it, ``ERRn`` an error; ``echo``: the
    command comes back first (UniCal manual). The unit outlives a connection."""
    unit = {"inch": inch}

    def answer(line: bytes, state: dict) -> bytes:
        out = line + b"\r" if echo else b""
        if line in (b"MM", b"IN"):
            unit["inch"] = line == b"IN" or not accepts_mm
            return out
        if line == b"UNI?":
            return out + (b"IN\r" if unit["inch"] else b"MM\r")
        if line == b"BAT?":
            return out + b"BAT1\r"
        if line in (b"?", b"PRI?"):
            value = displacement_mm / 25.4 if unit["inch"] else displacement_mm
            text = f"{value:.5f}" if unit["inch"] else f"{value:.4f}"
            return out + (text if text.startswith("-") else " " + text).encode() + b"\r"
        return out + b"ERR1\r"

    return answer


def qsb(line: bytes, state: dict) -> bytes:
    """Lower-case response letter, register, 8 hex digits, "!", CR LF (EOR 3)."""
    text = line.decode().upper()
    if text == "R0E":
        return b"r0E0001F4A2!\r\n"  # the reference's example: count 128162
    if text == "R14":
        return b"r1400020304!\r\n"
    if text.startswith("W") and len(text) >= 4:
        return f"w{text[1:3]}{int(text[3:], 16):08X}!\r\n".encode()
    return b"e00000000!\r\n"


def vaisala(model: str) -> Callable[[bytes, dict], bytes]:
    """``?`` → model / version and Key : value lines; FORM is acknowledged; SEND keeps the unit's own
    labelled layout (the PTU300 line quoted in open code), whatever FORM asked. No echo (see
    :class:`VaisalaEmulator` for the factory defaults)."""

    def answer(line: bytes, state: dict) -> bytes:
        text = line.decode()
        if text == "?":
            return f"{model} / 1.12\r\nSerial number  : P4040154\r\nBatch number   : 4030010\r\n".encode()
        if text.startswith("FORM"):
            return b"OK\r\n"
        if text == "SEND":
            if model == "PTB330":
                return b"P=  1003.8 hPa\r\n"
            return b"P=  1003.8 hPa   T= 17.7 'C RH= 40.9 %RH TD=  4.3 'C\r\n"
        if text in ("S", "ECHO OFF"):
            return b""
        return b"Unknown command\r\n"

    return answer


class VaisalaEmulator(Emulator):
    """A PTU300 / PTB330 as its manuals describe it from the factory (PTB330 M210855EN, PTU300
    M210796EN, PTB200/PTU200/HMT310 on ECHO): replies paced at 4800 baud 7E1 (10 bits a character),
    ECHO ON (the command comes back, a ``>`` prompt follows each answer), the full ``?`` listing
    ending with the module lines (msl-equipment reads to "Module 2" / "Module 4"), CR in and CR LF
    out, optionally in RUN mode (a reading every ``interval_s`` until ``S``)."""

    LISTING = {
        "PTU300": ["PTU300 / 1.12", "Serial number  : P4040154", "Batch number   : 4030010", "Adjust. date   : 2024-03-11",
                   "Adjust. info   : VAISALA/HEL", "Date           : 2026-11-27", "Time           : 12:00:00",
                   "Serial mode    : {mode}", "Baud P D S     : 4800 E 7 1", "Output interval: 1 s",
                   "Serial delay   : 0", "Address        : 0", "Echo           : {echo}", "Module 1       : BARO-1",
                   "Module 2       : EMPTY"],
        "PTB330": ["PTB330 / 1.12", "Serial number  : G1234567", "Batch number   : G1230010", "Output format  : \\P \\U #r#n",
                   "Adjust. date   : 2024-03-11", "Adjust. info   : VAISALA/HEL", "Date           : 2026-11-27",
                   "Time           : 12:00:00", "Start mode     : {mode}", "Pressure unit  : hPa", "Serial mode    : {mode}",
                   "Baud P D S     : 4800 E 7 1", "Output interval: 1 s", "Echo           : {echo}", "Address        : 0",
                   "Module 1       : BARO-1", "Module 2       : EMPTY", "Module 3       : EMPTY", "Module 4       : EMPTY"],
    }
    READING = {"PTU300": b"P=  1003.8 hPa   T= 17.7 'C RH= 40.9 %RH TD=  4.3 'C\r\n", "PTB330": b"P=  1003.8 hPa\r\n"}

    def __init__(self, model: str, echo: bool = True, run: bool = False, baud: int = 4800, interval_s: float = 0.3):
        self.model, self.echo, self.run = model, echo, run
        self.char_s = 10.0 / baud if baud else 0.0
        self.interval_s = interval_s
        super().__init__(lambda *_: b"")

    def _send(self, conn: socket.socket, data: bytes) -> None:
        for i in range(0, len(data), 4):
            conn.sendall(data[i:i + 4])
            if self.char_s:
                time.sleep(4 * self.char_s)

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.listener.accept()
            except OSError:
                return
            with conn:
                conn.settimeout(self.interval_s)
                buffer = b""
                while True:
                    try:
                        chunk = conn.recv(4096)
                    except socket.timeout:
                        if self.run:
                            self._send(conn, self.READING[self.model])
                        continue
                    except OSError:
                        break
                    if not chunk:
                        break
                    buffer += chunk
                    while b"\r" in buffer:
                        line, buffer = buffer.split(b"\r", 1)
                        line = line.strip(b"\n")
                        if line:
                            self.requests.append(line)
                            self._send(conn, self._answer(line.decode()))

    def _answer(self, text: str) -> bytes:
        echo = (text + "\r\n").encode() if self.echo else b""
        command = text.split(" ")[0].upper()
        if command == "S":
            self.run = False
            reply = b""
        elif command == "ECHO":
            self.echo = text.upper().endswith("ON")
            reply = f"Echo           : {'ON' if self.echo else 'OFF'}\r\n".encode()
        elif command == "?":
            mode, echo_text = ("RUN" if self.run else "STOP"), ("ON" if self.echo else "OFF")
            reply = "".join(line.format(mode=mode, echo=echo_text) + "\r\n" for line in self.LISTING[self.model]).encode()
        elif command == "FORM":
            reply = b"OK\r\n"
        elif command == "SEND":
            reply = self.READING[self.model]
        else:
            reply = b"Unknown command\r\n"
        return echo + reply + (b">" if self.echo else b"")


def ithx(line: bytes, state: dict) -> bytes:
    """msl-equipment's test exchange: CR-terminated requests and replies, one decimal."""
    return {b"*SRTC": b"19.3\r", b"*SRTC2": b"25.1\r", b"*SRH": b"42.5\r", b"*SRH2": b"44.4\r"}.get(line, b"Serial Time Out\r")


def tracer(line: bytes, state: dict) -> bytes:
    return {b"REF": b"OK REF 3\r\n", b"LEN?": b"LEN 1234567.125 3\r\n"}.get(line, b"ERR CMD\r\n")
