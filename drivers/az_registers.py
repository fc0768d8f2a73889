"""Register map of an Oriental Motor AZ-series drive, "direct data operation" (Modbus).

32-bit values span two registers, upper word first (the vendor's default word order).
The feedback position is read at 0x00CC, as Oriental Motor's own published sample reads it
(om_modbus_master sample/python/AZ/sample3.py: address 204, "FeedbackPosition"); the command
position at 0x00C6 is from a second-generation register map (docs/protocols/modbus_stage.md gives each source).
Everything address-shaped lives here, so a correction is one line.
"""

from __future__ import annotations

OPERATION_DATA_NUMBER = 0x0058
OPERATION_TYPE = 0x005A  # 1 absolute positioning, 2 incremental (from the command position)
POSITION = 0x005C  # steps, signed
SPEED = 0x005E  # Hz (steps/s), > 0
ACCELERATION = 0x0060  # starting/changing rate
DECELERATION = 0x0062  # stopping deceleration
CURRENT = 0x0064  # 0.1 % units, 0..1000
TRIGGER = 0x0066  # write 1: start with all direct data
INPUT_COMMAND = 0x007C  # driver input command (NET-IN), lower word holds the bits
OUTPUT_STATUS = 0x007E  # driver output status (NET-OUT), read-only
PRESENT_ALARM = 0x0080  # read-only
COMMAND_POSITION = 0x00C6  # steps, read-only (an Oriental CVD register map in open code; the driver does not read it)
FEEDBACK_POSITION = 0x00CC  # steps, read-only: the detection position, confirmed by the vendor's sample

WRITABLE_32 = (OPERATION_DATA_NUMBER, OPERATION_TYPE, POSITION, SPEED, ACCELERATION, DECELERATION, CURRENT, TRIGGER, INPUT_COMMAND)
READONLY_32 = (OUTPUT_STATUS, PRESENT_ALARM, COMMAND_POSITION, FEEDBACK_POSITION)

# driver input command bits (defaults of NET-IN0..15)
IN_START, IN_ZHOME, IN_STOP, IN_FREE, IN_ALM_RST = 1 << 3, 1 << 4, 1 << 5, 1 << 6, 1 << 7
# driver output status bits (defaults of NET-OUT0..15)
OUT_HOME_END, OUT_READY, OUT_ALM_A, OUT_SYS_BSY, OUT_MOVE, OUT_IN_POS = 1 << 4, 1 << 5, 1 << 7, 1 << 8, 1 << 13, 1 << 14

# present-alarm codes (docs/protocols/modbus_stage.md: which are confirmed by open code, which are not)
ALARM_NONE = 0x00
ALARM_EXCESSIVE_POSITION_DEVIATION = 0x10  # following error
ALARM_OVERLOAD = 0x30  # stall (AZD alarm tables in independent open code)
ALARM_HARDWARE_OVERTRAVEL = 0x66  # limit switch (same)
ALARM_SOFTWARE_OVERTRAVEL = 0x67  # target beyond the drive's soft limits (same)
ALARM_HWTO = 0x68  # HWTO input detection: the safe-torque-off input opened (an emergency-stop circuit)

ALARM_TEXT = {
    ALARM_EXCESSIVE_POSITION_DEVIATION: "excessive position deviation (following error)",
    0x20: "overcurrent",
    0x21: "main circuit overheat",
    0x22: "overvoltage",
    0x25: "undervoltage",
    0x26: "motor overheat",
    0x28: "sensor error",
    ALARM_OVERLOAD: "overload (stall)",
    ALARM_HARDWARE_OVERTRAVEL: "hardware overtravel (limit switch)",
    ALARM_SOFTWARE_OVERTRAVEL: "software overtravel (target beyond the drive's soft limits)",
    ALARM_HWTO: "HWTO input detection (the safe-torque-off input opened, e.g. by an emergency-stop circuit); "
                "close the circuit, then reset the alarm",
}


def split32(value: int) -> list[int]:
    """Signed 32-bit → [upper, lower] registers."""
    v = int(value) & 0xFFFFFFFF
    return [v >> 16, v & 0xFFFF]


def join32(upper: int, lower: int) -> int:
    """[upper, lower] registers → signed 32-bit."""
    v = ((upper & 0xFFFF) << 16) | (lower & 0xFFFF)
    return v - (1 << 32) if v & 0x80000000 else v
