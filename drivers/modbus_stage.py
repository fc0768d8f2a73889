"""A rotary stage driven by an AZ-series stepper drive over Modbus (TCP or RTU), with pymodbus.

Degrees ↔ steps: steps per motor revolution × gear (worm) ratio per table revolution. A move
writes the direct-data block (type, position, speed, rates, current, trigger) in one request,
then waits for the motion to **start** (MOVE set, or the feedback position leaving where it was:
a drive starts some milliseconds after the trigger, and until then still shows the previous
IN-POS) and to end in position with the feedback within the tolerance of the target, raising on
alarms and timeouts. The identity is what the drive's own registers say when asked (status and
present alarm): no product-identity register of the AZ is confirmed in public sources.
"""

from __future__ import annotations

import logging
import time

from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusException

from drivers import az_registers as az
from drivers.addresses import DEFAULT_GEAR, DEFAULT_STEPS_PER_REV, Address
from drivers.errors import InstrumentFault, InstrumentTimeout
from drivers.interfaces import RotaryStage
from drivers.models import builtin_framing
from drivers.serial_line import framing_of

# pymodbus logs what it trips over; with no handler Python would print it on the console over the
# progress bar. The typed error carries the news; an application that configures logging still sees these.
logging.getLogger("pymodbus").addHandler(logging.NullHandler())

EXCEPTION_TEXT = {1: "illegal function", 2: "illegal data address", 3: "illegal data value", 4: "server device failure",
                  6: "server device busy"}


class ModbusStage(RotaryStage):
    """Oriental Motor AZ: Modbus TCP, or RTU with 8E1 framing unless the address says otherwise
    (the drive's own setting; ``baud``, ``parity``, ``stopbits`` options)."""

    name = "stage"
    options: dict[str, tuple[float, float, bool]]
    model, kind, schemes, options = "oriental-az", "stage", ("modbus-tcp", "modbus-rtu"), {}
    framing = builtin_framing("oriental-az")

    SETTLE_S = 0.3  # after IN-POS: how long the feedback may take to come within tolerance of the target
    tolerance_steps = 2.0  # how far the feedback may end from the target (set from tolerance_deg at open)

    def __init__(self, address: Address, timeout_s: float = 2.0, limits_deg: tuple[float, float] = (-360.0, 360.0),
                 tolerance_deg: float | None = None, **_: object):
        """``tolerance_deg``: how far the feedback may end from the target (the procedure's
        verification.stage_tolerance_deg; default two steps, as the verification's default)."""
        self.unit = int(address.option("unit", 1))
        self.steps_per_deg = address.option("steps_per_rev", DEFAULT_STEPS_PER_REV) * address.option("gear", DEFAULT_GEAR) / 360.0
        self.step_deg = 1.0 / self.steps_per_deg
        self.tolerance_steps = max((tolerance_deg or 2 * self.step_deg) * self.steps_per_deg, 1.0)
        self.speed_hz = max(1, round(address.option("speed_deg_per_s", 10.0) * self.steps_per_deg))
        self.limits_deg = limits_deg
        self.timeout_s = timeout_s
        self.client: ModbusTcpClient | ModbusSerialClient
        if address.scheme == "modbus-tcp":
            self.client = ModbusTcpClient(address.host, port=address.port, timeout=timeout_s, retries=0)
            where = f"{address.host}:{address.port}"
        else:
            f = framing_of(address, self.framing)
            self.client = ModbusSerialClient(address.path, framer=FramerType.RTU, baudrate=f.baud, bytesize=f.bytesize,
                                             parity=f.parity, stopbits=f.stopbits, timeout=timeout_s, retries=0)
            where = f"{address.path} at {f}"
        try:
            connected = self.client.connect()
        except Exception as exc:  # noqa: BLE001 — a device path that is no serial port (termios.error), …
            raise InstrumentTimeout(self.name, f"cannot connect to the drive at {where}: {exc!r}") from None
        if not connected:
            raise InstrumentTimeout(self.name, f"cannot connect to the drive at {where}")
        self.device_identification = self._device_identification()

    def _device_identification(self) -> str:
        """Modbus Read Device Identification (FC 43 / MEI 14, basic objects: VendorName, ProductCode,
        MajorMinorRevision; Modbus Application Protocol V1.1b3 §6.21), asked once at connect. An AZ drive
        does not implement it (exception: illegal function), which leaves it empty; rtcal's simulator
        answers it, and says SIMULATED."""
        try:
            reply = self.client.read_device_information(read_code=1, object_id=0, device_id=self.unit)
        except (ModbusException, OSError, ValueError):
            return ""
        if reply.isError():
            return ""
        info = getattr(reply, "information", {}) or {}
        words = []
        for key in (0, 1, 2):
            value = info.get(key)
            if isinstance(value, bytes):
                words.append("".join(c if c.isprintable() else "?" for c in value.decode("ascii", "replace"))[:100])
        return " ".join(words)

    def identity(self) -> str:
        """What the drive's registers say now (status, present alarm) and its device identification where it
        answers one: no identity register of the AZ is confirmed."""
        status, alarm = self._read32(az.OUTPUT_STATUS, 2)
        state = f"alarm 0x{alarm:02X}" if status & az.OUT_ALM_A else "READY" if status & az.OUT_READY else "not ready"
        said = f"; device identification: {self.device_identification}" if self.device_identification else ""
        return f"Oriental Motor AZ drive (Modbus unit {self.unit}, direct data operation), {state}{said}"

    # -- register access with typed errors: nothing but an InstrumentError leaves this driver
    def _call(self, what: str, fn, *args, **kwargs):
        try:
            response = fn(*args, device_id=self.unit, **kwargs)
        except ModbusException as exc:
            raise InstrumentTimeout(self.name, f"{what}: no valid reply ({exc})") from None
        except OSError as exc:  # the drive, its gateway or the serial adapter went away mid-request
            raise InstrumentFault(self.name, f"{what}: connection to the drive failed ({exc!r})") from None
        except Exception as exc:  # noqa: BLE001 — pymodbus or pyserial tripping over what came back (termios.error, …)
            raise InstrumentFault(self.name, f"{what}: the Modbus client failed ({exc!r})") from None
        if response.isError():
            code = getattr(response, "exception_code", 0)
            raise InstrumentFault(self.name, f"{what}: Modbus exception {code} ({EXCEPTION_TEXT.get(code, 'unknown')})")
        return response

    def _read32(self, register: int, count: int = 1) -> list[int]:
        regs = self._call(f"read 0x{register:04X}", self.client.read_holding_registers, register, count=2 * count).registers
        if len(regs) != 2 * count:
            raise InstrumentFault(self.name, f"read 0x{register:04X}: {len(regs)} registers in the reply, {2 * count} asked")
        return [az.join32(regs[2 * k], regs[2 * k + 1]) for k in range(count)]

    def _write32(self, register: int, values: list[int]) -> None:
        words = [w for v in values for w in az.split32(v)]
        self._call(f"write 0x{register:04X}", self.client.write_registers, register, words)

    def _input_pulse(self, bit: int) -> None:
        self._write32(az.INPUT_COMMAND, [bit])
        self._write32(az.INPUT_COMMAND, [0])

    def _wait_in_position(self, what: str, target_steps: int | None = None, before_steps: int | None = None) -> None:
        """Poll until the motion started and ended in position (and, for a move, the feedback reached
        the target within the tolerance or stopped settling); alarms raise at once."""
        deadline = time.monotonic() + max(self.timeout_s, 1.0) * 10
        start_deadline = time.monotonic() + max(self.timeout_s, 0.5)  # a drive starts within milliseconds
        started = before_steps is None
        settle_until = None
        while True:
            status, alarm = self._read32(az.OUTPUT_STATUS, 2)
            if status & az.OUT_ALM_A:
                raise InstrumentFault(self.name, f"{what}: drive alarm 0x{alarm:02X} ({az.ALARM_TEXT.get(alarm, 'see the drive manual')})")
            feedback = None
            if status & az.OUT_MOVE:
                started = True
            elif not started and before_steps is not None and target_steps is not None:  # IN-POS of the previous position until the drive starts: look at the feedback
                feedback = self._read32(az.FEEDBACK_POSITION)[0]
                started = feedback != before_steps or abs(feedback - target_steps) <= self.tolerance_steps
            if started and status & az.OUT_IN_POS and not status & az.OUT_MOVE:
                if target_steps is None:
                    return
                if feedback is None:
                    feedback = self._read32(az.FEEDBACK_POSITION)[0]
                if abs(feedback - target_steps) <= self.tolerance_steps:
                    return
                settle_until = settle_until or time.monotonic() + self.SETTLE_S
                if time.monotonic() > settle_until:
                    return  # in position somewhere else: the motion checks name it, with the feedback
            if time.monotonic() > (deadline if started else start_deadline):
                if not started and before_steps is not None:
                    raise InstrumentTimeout(self.name, f"{what}: the drive never started the motion (feedback still "
                                                       f"{before_steps / self.steps_per_deg:.6f}°)")
                raise InstrumentTimeout(self.name, f"{what}: not in position in time")
            time.sleep(0.005)

    # -- the interface
    def move_to(self, angle_deg: float) -> None:
        self.check_target(angle_deg)
        steps = round(angle_deg * self.steps_per_deg)
        before = self._read32(az.FEEDBACK_POSITION)[0]
        # operation type, position, speed, acceleration, deceleration, current, trigger: one request
        self._write32(az.OPERATION_TYPE, [1, steps, self.speed_hz, self.speed_hz, self.speed_hz, 1000, 1])
        self._wait_in_position(f"move to {angle_deg:.6f}°", steps, before)

    def home(self) -> None:
        self._input_pulse(az.IN_ZHOME)
        self._wait_in_position("homing")

    def stop(self) -> None:
        self._input_pulse(az.IN_STOP)

    def reset_alarm(self) -> None:
        self._input_pulse(az.IN_ALM_RST)

    def position_deg(self) -> float:
        """The drive's feedback (detection) position: the one monitor the vendor's sample reads."""
        steps = self._read32(az.FEEDBACK_POSITION)[0]
        if steps == -(1 << 31):  # INT_MIN: the register's "no value", not a position the table can be at
            raise InstrumentFault(self.name, "the drive's feedback position register holds −2³¹ (INT_MIN): no position")
        return steps / self.steps_per_deg

    feedback_deg = position_deg

    def close(self) -> None:
        try:
            self.client.close()
        except Exception:  # noqa: BLE001, S110 — closing a line that already died: nothing left to release
            pass
