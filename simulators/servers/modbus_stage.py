"""The simulated AZ drive behind pymodbus servers (TCP, and RTU on a serial line).

pymodbus keeps a register image per server; ours is only a window: on every access the action
fills it from, or hands the write to, the one :class:`~simulators.az_drive.AzDriveModel`, so
TCP and RTU clients see the same drive.
"""

from __future__ import annotations

import logging
from typing import Callable

from pymodbus import FramerType, ModbusDeviceIdentification
from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator import DataType, SimData, SimDevice

from drivers import az_registers as az
from simulators.az_drive import AzDriveModel

logging.getLogger("pymodbus").addHandler(logging.NullHandler())  # the console is the run's, not the library's

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


def crc16(frame: bytes) -> bytes:
    """The Modbus RTU CRC of ``frame``, low byte first."""
    crc = 0xFFFF
    for byte in frame:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc.to_bytes(2, "little")


def frame_hook(model: AzDriveModel, rtu: bool, unit: int = 1):
    """pymodbus ``trace_packet`` hook of one connection (its own request state): what a real drive
    does on the wire that pymodbus does not.

    - A request to another unit id, or broadcast (0), gets no reply, as on a bus.
    - An exception reply carries the request's function code | 0x80 (pymodbus sends a bare 0x80
      for a function code it does not know).
    - Lose or corrupt the reply frame the drive model asks for. A corrupted RTU frame fails its
      CRC; Modbus TCP carries no CRC, so there the frame loses its last byte (a broken frame the
      client cannot complete) instead.
    """
    at = 1 if rtu else 7  # where the function code sits: after the unit id (RTU), after the MBAP header (TCP)
    last_code = {"fc": None, "unit": unit}

    def trace(sending: bool, data: bytes) -> bytes:
        if not sending:
            if len(data) >= at + 3 and (rtu or data[2:4] == b"\0\0"):  # a whole request, not a piece of one
                last_code["fc"], last_code["unit"] = data[at], data[at - 1]
            return data
        if last_code["unit"] != unit:
            return b""
        if len(data) > at and data[at] == 0x80 and last_code["fc"] is not None and last_code["fc"] < 0x80:
            data = data[:at] + bytes([last_code["fc"] | 0x80]) + data[at + 1:]
            if rtu:
                data = data[:-2] + crc16(data[:-2])
        if model.reply_fault is None:
            return data
        fault, model.reply_fault = model.reply_fault, None
        if fault == "no_reply":
            return b""
        return data[:-1] + bytes([data[-1] ^ 0xFF]) if rtu else data[:-1]

    return trace


class PerConnectionTcpServer(ModbusTcpServer):
    """A Modbus TCP server that gives each connection its own frame hook: what one client sends
    (a frame for unit 0 or 255, say) decides nothing about another's replies — a real gateway
    answers each connection for itself. (pymodbus hands every connection the server's one hook.)"""

    def __init__(self, *args, hook_factory: Callable[[], Callable[[bool, bytes], bytes]], **kwargs):
        super().__init__(*args, trace_packet=hook_factory(), **kwargs)
        self._hook_factory = hook_factory

    def callback_new_connection(self) -> ServerRequestHandler:
        """pymodbus's hook, called for each accepted connection (``ModbusProtocol.handle_new_connection``):
        the override that gives the connection its own frame hook."""
        return ServerRequestHandler(self, self._hook_factory(), self.trace_pdu, self.trace_connect)


IDENTIFICATION = {"VendorName": "rtcal simulated drives", "ProductCode": "AZ drive SIMULATED", "MajorMinorRevision": "1.0"}
"""What the simulator answers to Modbus Read Device Identification (FC 43 / MEI 14, the basic objects:
Modbus Application Protocol V1.1b3 §6.21). A real AZ drive implements no FC 43 (its manual lists 03h,
06h, 08h, 10h, 17h) and answers it with an exception; the simulator says what it is."""


def identification() -> ModbusDeviceIdentification:
    return ModbusDeviceIdentification(info_name=dict(IDENTIFICATION))


def tcp_server(model: AzDriveModel, host: str, port: int, unit: int = 1) -> ModbusTcpServer:
    return PerConnectionTcpServer(drive_device(model, unit), address=(host, port),
                                  hook_factory=lambda: frame_hook(model, rtu=False, unit=unit), identity=identification(),
                                  ignore_missing_devices=True)  # another unit id: no reply, as on a bus


def rtu_server(model: AzDriveModel, device_path: str, unit: int = 1, baudrate: int = 115200) -> ModbusSerialServer:
    return ModbusSerialServer(drive_device(model, unit), framer=FramerType.RTU, port=device_path, baudrate=baudrate,
                              trace_packet=frame_hook(model, rtu=True, unit=unit), ignore_missing_devices=True,
                              identity=identification())
