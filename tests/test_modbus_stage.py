"""The AZ drive: register semantics, the Modbus driver, and independent clients at the documented addresses."""

from __future__ import annotations

import shutil
import subprocess

import pytest
from pymodbus.client import ModbusTcpClient

from drivers import az_registers as az
from drivers.addresses import parse_address
from drivers.errors import InstrumentFault, OutOfLimits
from drivers.modbus_stage import ModbusStage
from simulators.az_drive import DEVICE_FAILURE, ILLEGAL_ADDRESS, ILLEGAL_VALUE, AzDriveModel
from simulators.bench import Bench
from simulators.instruments import SimStage
from simulators.scenario import Scenario, StageScenario
from simulators.servers.hub import SimulatorHub

STEPS_PER_DEG = 1000.0  # 10000 steps/rev × gear 36 / 360°


def _model() -> AzDriveModel:
    bench = Bench(Scenario(stage=StageScenario(soft_limits_deg=(-200.0, 200.0))))
    return AzDriveModel(SimStage(bench), STEPS_PER_DEG)


def test_absolute_move_updates_positions_and_bench():
    m = _model()
    assert m.write(az.OPERATION_TYPE, az.split32(1) + az.split32(30000)) is None
    assert m.write(az.TRIGGER, az.split32(1)) is None
    assert az.join32(*m.read(az.COMMAND_POSITION, 2)) == 30000
    assert az.join32(*m.read(az.FEEDBACK_POSITION, 2)) == 30000
    assert m.stage.position_deg() == pytest.approx(30.0)
    status = az.join32(*m.read(az.OUTPUT_STATUS, 2))
    assert status & az.OUT_READY and status & az.OUT_IN_POS and not status & az.OUT_ALM_A


def test_incremental_move_and_negative_positions():
    m = _model()
    m.write(az.OPERATION_TYPE, az.split32(2) + az.split32(-45500))
    m.write(az.TRIGGER, az.split32(1))
    assert az.join32(*m.read(az.COMMAND_POSITION, 2)) == -45500


@pytest.mark.parametrize("address,values,code", [
    (az.POSITION, [7], ILLEGAL_VALUE),  # half of a 32-bit value
    (az.POSITION + 1, [0, 7], ILLEGAL_VALUE),  # starts in the middle of one
    (az.OUTPUT_STATUS, [0, 1], ILLEGAL_ADDRESS),  # read-only
    (0x0010, [0, 1], ILLEGAL_ADDRESS),  # not a register of this map
    (az.SPEED, az.split32(0), ILLEGAL_VALUE),
    (az.CURRENT, az.split32(2000), ILLEGAL_VALUE),
    (az.OPERATION_TYPE, az.split32(9), ILLEGAL_VALUE),
])
def test_bad_writes_get_modbus_exceptions(address, values, code):
    assert _model().write(address, values) == code


def test_target_beyond_soft_limits_raises_drive_alarm_until_reset():
    m = _model()
    m.write(az.POSITION, az.split32(250000))  # 250° > 200°
    assert m.write(az.TRIGGER, az.split32(1)) is None  # accepted on the wire ...
    status, alarm = az.join32(*m.read(az.OUTPUT_STATUS, 2)), az.join32(*m.read(az.PRESENT_ALARM, 2))
    assert status & az.OUT_ALM_A and not status & az.OUT_READY and alarm == az.ALARM_SOFTWARE_OVERTRAVEL
    m.write(az.POSITION, az.split32(1000))
    assert m.write(az.TRIGGER, az.split32(1)) == DEVICE_FAILURE  # ... and refuses to move while alarmed
    m.write(az.INPUT_COMMAND, az.split32(az.IN_ALM_RST))
    m.write(az.INPUT_COMMAND, az.split32(0))
    assert az.join32(*m.read(az.PRESENT_ALARM, 2)) == az.ALARM_NONE
    assert m.write(az.TRIGGER, az.split32(1)) is None


@pytest.fixture(scope="module")
def hub():
    scenario = Scenario(stage=StageScenario(soft_limits_deg=(-200.0, 200.0)))
    with SimulatorHub(scenario, seed=1) as h:
        yield h


def test_driver_moves_and_reads_back(hub):
    stage = ModbusStage(parse_address(hub.addresses["stage"]), limits_deg=(-360.0, 360.0))
    try:
        stage.move_to(-145.0)
        assert stage.position_deg() == pytest.approx(-145.0)
        assert hub.bench.commanded_rad == pytest.approx(-2.530727415391778)
        with pytest.raises(InstrumentFault, match="software overtravel"):
            stage.move_to(250.0)  # inside rtcal's limits, outside the drive's
        stage.reset_alarm()
        stage.move_to(10.0)
    finally:
        stage.close()


def test_soft_limits_stop_a_command_before_the_wire(hub):
    stage = ModbusStage(parse_address(hub.addresses["stage"]), limits_deg=(-90.0, 90.0))
    try:
        stage.move_to(20.0)
        with pytest.raises(OutOfLimits):
            stage.move_to(120.0)
        assert stage.position_deg() == pytest.approx(20.0)
    finally:
        stage.close()


def _tcp(hub) -> tuple[str, int]:
    a = parse_address(hub.addresses["stage"])
    return a.host, a.port


def test_pymodbus_client_reads_documented_addresses(hub):
    stage = ModbusStage(parse_address(hub.addresses["stage"]))
    stage.move_to(12.5)
    stage.close()
    host, port = _tcp(hub)
    client = ModbusTcpClient(host, port=port)
    assert client.connect()
    try:
        feedback = client.read_holding_registers(az.FEEDBACK_POSITION, count=2, device_id=1).registers
        assert az.join32(*feedback) == 12500
        status = client.read_holding_registers(az.OUTPUT_STATUS, count=2, device_id=1).registers
        assert az.join32(*status) & az.OUT_READY
        half = client.write_register(az.POSITION, 5, device_id=1)
        assert half.isError() and half.exception_code == 3
    finally:
        client.close()


@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll (Debian package) not installed")
def test_mbpoll_reads_feedback_position_and_status(hub):
    stage = ModbusStage(parse_address(hub.addresses["stage"]))
    stage.move_to(-7.25)
    stage.close()
    host, port = _tcp(hub)
    # mbpoll counts references from 1; -B: 32-bit values upper word first
    out = subprocess.run(["mbpoll", "-m", "tcp", "-p", str(port), "-a", "1", "-t", "4:int", "-B", "-1",
                          "-r", str(az.FEEDBACK_POSITION + 1), "-c", "1", host], capture_output=True, text=True, timeout=20)
    assert out.returncode == 0, out.stderr
    assert f"[{az.FEEDBACK_POSITION + 1}]: \t-7250" in out.stdout
    out = subprocess.run(["mbpoll", "-m", "tcp", "-p", str(port), "-a", "1", "-t", "4:hex", "-1",
                          "-r", str(az.OUTPUT_STATUS + 2), "-c", "1", host], capture_output=True, text=True, timeout=20)
    assert out.returncode == 0, out.stderr
    value = int(out.stdout.split(f"[{az.OUTPUT_STATUS + 2}]:")[1].split()[0], 16)
    assert value & az.OUT_READY and value & az.OUT_IN_POS


def test_each_connection_has_its_own_frame_hook():
    """pymodbus asks the server for each accepted connection's handler (``callback_new_connection``,
    overridden): what one client asks decides nothing about another's replies. Client A asks unit 5
    (no such drive: no reply), client B unit 1; A's reply is still dropped and B's still sent."""
    import asyncio

    from simulators.servers import modbus_stage

    def request(unit: int) -> bytes:  # MBAP (transaction 1, protocol 0, 6 bytes follow), read 2 holding registers
        return bytes([0, 1, 0, 0, 0, 6, unit, 3, 0, 0, 0, 2])

    reply = bytes([0, 1, 0, 0, 0, 7, 1, 3, 4, 0, 0, 0, 0])

    async def connections() -> tuple[bytes, bytes]:
        server = modbus_stage.tcp_server(_model(), "127.0.0.1", 0)
        a, b = server.handle_new_connection(), server.handle_new_connection()
        a.trace_packet(False, request(5))
        b.trace_packet(False, request(1))
        return a.trace_packet(True, reply), b.trace_packet(True, reply)

    assert asyncio.run(connections()) == (b"", reply)
