"""A simulated AZ-series stepper drive: the register semantics, backed by the bench stage.

Pure Python (no Modbus here): ``read`` and ``write`` take register addresses and values and
return values or a Modbus exception code. :mod:`simulators.servers.modbus_stage` puts it behind
pymodbus servers (TCP and RTU). Motions complete at once in virtual time (the bench clock
advances by their duration).

Injected faults (scenario ``faults``, one draw per motion trigger): drive alarms (stall 0x30,
following error 0x10, limit switch 0x66), an emergency stop: HWTO input detection 0x68 (ALM-RST cannot
clear it while the circuit is open), an
exception reply, and a lost or corrupted reply, which the server adapter applies to the frame
(``reply_fault``) after the drive has acted; a drive that is stuck (accepts, says "in position",
echoes the command as its feedback, and does not turn) or stops short (its feedback shows
where). A read of the feedback position draws the faults of another client moving the table.

A real drive starts a motion some milliseconds after the trigger, and until it does its status
still shows the previous position's IN-POS: ``start_latency_s`` (wall-clock) holds a triggered
motion back that long — it happens at the first register access after it.

``wall_speed_deg_per_s`` makes a triggered motion take wall-clock time, as a real table's does: MOVE
on and IN-POS off while the table turns at that speed (no ramps), the command and feedback positions
between start and target. A STOP input then ends it where the table is (``stopped``: when, where,
and the target it did not reach), as the drive's immediate stop does — what the tests of an abort
or a signal mid-move look at.
"""

from __future__ import annotations

import time

from drivers import az_registers as az
from simulators.faults import ALARM_CODES
from simulators.instruments import SimStage

ILLEGAL_ADDRESS, ILLEGAL_VALUE, DEVICE_FAILURE = 2, 3, 4  # Modbus exception codes


class AzDriveModel:
    """Registers and state of one drive; ``steps_per_deg`` converts for the bench stage."""

    def __init__(self, stage: SimStage, steps_per_deg: float, start_latency_s: float = 0.0,
                 wall_speed_deg_per_s: float | None = None):
        self.stage = stage
        self.steps_per_deg = steps_per_deg
        self.start_latency_s = start_latency_s
        self.wall_speed_deg_per_s = wall_speed_deg_per_s
        self._moving: tuple[float, int, int] | None = None  # (wall start, from, to steps) of a motion under way
        self.stopped: list[tuple[float, float, float]] = []  # (time.monotonic(), where °, target °) of each STOP mid-motion
        self._pending: tuple[float, int] | None = None  # (when, target steps) of a triggered motion not started yet
        self.direct = {az.OPERATION_DATA_NUMBER: 0, az.OPERATION_TYPE: 1, az.POSITION: 0, az.SPEED: 1000,
                       az.ACCELERATION: 1000, az.DECELERATION: 1000, az.CURRENT: 1000, az.TRIGGER: 0}
        self.input_command = 0
        self.alarm = az.ALARM_NONE
        self.free = False
        self.homed = False
        self.stops = 0  # STOP inputs received
        self.command_steps = round(stage.position_deg() * steps_per_deg)
        self.feedback_steps = self.command_steps
        self.reply_fault: str | None = None  # "no_reply" or "crc_error" for the next reply frame

    @property
    def moving_to_deg(self) -> float | None:
        """The target of the motion in wall time under way (None: at rest)."""
        return None if self._moving is None else self._moving[2] / self.steps_per_deg

    # -- what the registers show
    def status(self) -> int:
        if self._moving is not None:
            return az.OUT_MOVE | (az.OUT_HOME_END if self.homed else 0)
        bits = az.OUT_IN_POS
        if self.alarm:
            bits |= az.OUT_ALM_A
        elif not self.free:
            bits |= az.OUT_READY
        if self.homed:
            bits |= az.OUT_HOME_END
        return bits

    def value32(self, address: int) -> int:
        if address in self.direct:
            return self.direct[address]
        return {az.INPUT_COMMAND: self.input_command, az.OUTPUT_STATUS: self.status(), az.PRESENT_ALARM: self.alarm,
                az.COMMAND_POSITION: self.command_steps, az.FEEDBACK_POSITION: self.feedback_steps}[address]

    def _another_client(self) -> None:
        """A scheduled fault `moved`: another client turns the table by an incremental move now."""
        fault = self.stage.bench.faults.draw("stage", position_read=True)
        if fault is not None and fault.kind == "moved":
            self._move_to_steps(self.command_steps + round(fault.offset_deg * self.steps_per_deg))

    def _advance(self) -> None:
        """Start (and, in virtual time, finish) a triggered motion whose latency has passed; a motion
        in wall time goes on, or ends at its target."""
        if self._pending is not None and time.monotonic() >= self._pending[0]:
            target = self._pending[1]
            self._pending = None
            self._start(target)
        if self._moving is not None:
            start_s, origin, target = self._moving
            if self._wall_steps(start_s, origin, target) == target:
                self._moving = None
                self._move_to_steps(target)
            else:
                self.command_steps = self.feedback_steps = self._wall_steps(start_s, origin, target)

    def _wall_steps(self, start_s: float, origin: int, target: int) -> int:
        """Where a motion in wall time has the table now (steps)."""
        assert self.wall_speed_deg_per_s is not None
        done = (time.monotonic() - start_s) * self.wall_speed_deg_per_s * self.steps_per_deg
        return target if done >= abs(target - origin) else origin + round(done) * (1 if target > origin else -1)

    def _start(self, target: int) -> int | None:
        """A motion begins: at once in virtual time, or turning in wall time."""
        if self.wall_speed_deg_per_s is None or self.alarm or target == self.feedback_steps:
            return self._move_to_steps(target)
        lo, hi = self.stage.limits_deg
        if not lo <= target / self.steps_per_deg <= hi:
            return self._move_to_steps(target)  # the drive alarms
        self.free = False
        self._moving = (time.monotonic(), self.feedback_steps, int(target))
        return None

    def read(self, address: int, count: int) -> list[int] | int:
        """Registers [address, address + count) or an exception code."""
        self._advance()
        if address <= az.FEEDBACK_POSITION < address + count:  # one position read, however many registers
            self._another_client()
        out = []
        for reg in range(address, address + count):
            base = reg - ((reg - az.OPERATION_DATA_NUMBER) % 2) if reg >= az.OPERATION_DATA_NUMBER else reg
            if base not in az.WRITABLE_32 + az.READONLY_32:
                return ILLEGAL_ADDRESS
            out.append(az.split32(self.value32(base))[reg - base])
        return out

    # -- writes
    def write(self, address: int, values: list[int]) -> int | None:
        """Apply a write of whole 32-bit values; None or an exception code."""
        self._advance()
        if (address - az.OPERATION_DATA_NUMBER) % 2 or len(values) % 2:
            return ILLEGAL_VALUE  # half of a 32-bit value
        for k in range(0, len(values), 2):
            reg = address + k
            if reg in az.READONLY_32:
                return ILLEGAL_ADDRESS
            if reg not in az.WRITABLE_32:
                return ILLEGAL_ADDRESS
        for k in range(0, len(values), 2):
            reg, value = address + k, az.join32(values[k], values[k + 1])
            code = self._write32(reg, value)
            if code:
                return code
        return None

    def _write32(self, reg: int, value: int) -> int | None:
        if reg == az.INPUT_COMMAND:
            rising = value & ~self.input_command
            self.input_command = value & 0xFFFF
            return self._inputs(rising)
        if reg == az.OPERATION_TYPE and value not in (1, 2):
            return ILLEGAL_VALUE
        if reg in (az.SPEED, az.ACCELERATION, az.DECELERATION) and value <= 0:
            return ILLEGAL_VALUE
        if reg == az.CURRENT and not 0 <= value <= 1000:
            return ILLEGAL_VALUE
        if reg == az.TRIGGER:
            return self._trigger() if value == 1 else None
        self.direct[reg] = value
        return None

    def _inputs(self, rising: int) -> int | None:
        if rising & az.IN_ALM_RST and not self.stage.bench.emergency_stop:
            self.alarm = az.ALARM_NONE
        if rising & az.IN_FREE:
            self.free = True
        if rising & az.IN_STOP:
            self.stops += 1  # counted: the tests check that every way a run ends stops the drive
            self._pending = None
            if self._moving is not None:  # stopped where it is: the table is there
                target = self._moving[2]
                self._moving = None
                self.stopped.append((time.monotonic(), self.feedback_steps / self.steps_per_deg, target / self.steps_per_deg))
                self._move_to_steps(self.feedback_steps)
            return None
        if rising & az.IN_ZHOME:
            return self._move_to_steps(0, homing=True)
        if rising & az.IN_START:
            return self._trigger()
        return None

    def _trigger(self) -> int | None:
        target = self.direct[az.POSITION]
        if self.direct[az.OPERATION_TYPE] == 2:
            target += self.command_steps
        if self.alarm:
            return DEVICE_FAILURE  # the drive refuses to move while an alarm is present
        fault = self.stage.bench.faults.draw("stage")
        if fault is not None and fault.kind == "alarm":
            self.alarm = ALARM_CODES[fault.alarm]
        elif fault is not None and fault.kind == "emergency_stop":
            self.stage.bench.emergency_stop = True
        elif fault is not None and fault.kind == "modbus_exception":
            return DEVICE_FAILURE
        if self.stage.bench.emergency_stop:
            self.alarm = az.ALARM_HWTO
        if self.alarm:
            return None  # accepted on the wire; the drive shows its alarm
        if fault is not None and fault.kind == "stuck":  # "in position", the command echoed, the table where it was
            self.command_steps = self.feedback_steps = int(target)
            return None
        if fault is not None and fault.kind == "short":  # short of the target, from where the table is
            way = 1 if target > self.feedback_steps else -1
            short = min(round(fault.shortfall_deg * self.steps_per_deg), abs(target - self.feedback_steps))
            code = self._move_to_steps(target - way * short)
            self.command_steps = int(target)  # the drive was told the target; its feedback says where it stopped
            return code
        if self.start_latency_s > 0 and not self.alarm:
            self._pending = (time.monotonic() + self.start_latency_s, int(target))  # IN-POS of where it was, for now
            code = None
        else:
            code = self._start(int(target))
        if fault is not None and fault.kind in ("no_reply", "crc_error"):
            self.reply_fault = fault.kind
        return code

    def _move_to_steps(self, target: int, homing: bool = False) -> int | None:
        if self.alarm:
            return DEVICE_FAILURE  # the drive refuses to move while an alarm is present
        lo, hi = self.stage.limits_deg
        deg = target / self.steps_per_deg
        if not lo <= deg <= hi:
            self.alarm = az.ALARM_SOFTWARE_OVERTRAVEL
            return None  # accepted on the wire; the drive alarms
        self.free = False
        self.stage.move_to(deg)
        self.command_steps = self.feedback_steps = int(target)
        self.homed = self.homed or homing
        return None


def steps_per_degree(steps_per_revolution: int, gear_ratio: float) -> float:
    """Motor steps per degree of table rotation."""
    return steps_per_revolution * gear_ratio / 360.0
