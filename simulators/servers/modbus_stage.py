"""The simulated AZ drive behind pymodbus servers (TCP, and RTU on a serial line).

pymodbus keeps a register image per server; ours is only a window: on every access the action
fills it from, or hands the write to, the one :class:`~simulators.az_drive.AzDriveModel`, so
TCP and RTU clients see the same drive.
"""

from __future__ import annotations

from pymodbus import FramerType
from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from drivers import az_registers as az
from simulators.az_drive import AzDriveModel

READ_CODES = (3, 4)


def drive_device(model: AzDriveModel, unit: int = 1) -> SimDevice:
    """A pymodbus device whose every register access goes through the drive model."""

    async def action(function_code, start, address, count, registers, values):
        if values is None:
            if function_code in READ_CODES:
                result = model.read(address, count)
                if isinstance(result, int):
                    return ExcCodes(result)
                registers[address - start : address - start + count] = result
            return None
        code = model.write(address, [int(v) for v in values])
        return ExcCodes(code) if code else None

    return SimDevice(id=unit, simdata=[SimData(0, count=az.FEEDBACK_POSITION + 2, values=0, datatype=DataType.REGISTERS)], action=action)


def frame_faults(model: AzDriveModel, rtu: bool):
    """pymodbus ``trace_packet`` hook: lose or corrupt the reply frame the drive model asks for.

    A corrupted RTU frame fails its CRC; Modbus TCP carries no CRC, so there the frame loses
    its last byte (a broken frame the client cannot complete) instead.
    """

    def trace(sending: bool, data: bytes) -> bytes:
        if not sending or model.reply_fault is None:
            return data
        fault, model.reply_fault = model.reply_fault, None
        if fault == "no_reply":
            return b""
        return data[:-1] + bytes([data[-1] ^ 0xFF]) if rtu else data[:-1]

    return trace


def tcp_server(model: AzDriveModel, host: str, port: int, unit: int = 1) -> ModbusTcpServer:
    return ModbusTcpServer(drive_device(model, unit), address=(host, port), trace_packet=frame_faults(model, rtu=False))


def rtu_server(model: AzDriveModel, device_path: str, unit: int = 1, baudrate: int = 115200) -> ModbusSerialServer:
    return ModbusSerialServer(drive_device(model, unit), framer=FramerType.RTU, port=device_path, baudrate=baudrate,
                              trace_packet=frame_faults(model, rtu=True))
