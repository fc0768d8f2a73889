"""Oriental AZ (issue 27): a drive that starts its motion 5 ms or 20 ms after the trigger, still
showing the previous IN-POS until then (tests/emulators.AzDriveEmulator, written from Oriental's
samples): `move_to` returns only once the feedback is at the target; the identity is read."""

from __future__ import annotations

import time

import pytest

from drivers.addresses import parse_address
from drivers.errors import InstrumentTimeout
from drivers.modbus_stage import ModbusStage
from tests.emulators import AzDriveEmulator

IN_POS_READY = (1 << 14) | (1 << 5)
REGISTERS = {0x0058: 0, 0x005A: 1, 0x005C: 0, 0x005E: 1000, 0x0060: 1000, 0x0062: 1000, 0x0064: 1000, 0x0066: 0,
             0x007C: 0, 0x007E: IN_POS_READY, 0x0080: 0, 0x00CC: 0}


@pytest.mark.parametrize("latency_s", [0.005, 0.020])
def test_move_to_waits_for_the_motion_to_start_and_reach_the_target(latency_s):
    with AzDriveEmulator(dict(REGISTERS), latency_s=latency_s, motion_s=0.03) as drive:
        stage = ModbusStage(parse_address(f"modbus-tcp://127.0.0.1:{drive.port}?unit=1&steps_per_rev=10000&gear=36"), 1.0)
        try:
            assert stage.identity() == "Oriental Motor AZ drive (Modbus unit 1, direct data operation), READY"
            for angle_deg in (12.345, -3.0, 0.5):
                started = time.monotonic()
                stage.move_to(angle_deg)
                assert time.monotonic() - started >= latency_s + 0.03  # not on the stale IN-POS
                assert drive.motion is None and drive.get32(0x00CC) == round(angle_deg * 1000)
                assert stage.position_deg() == pytest.approx(angle_deg, abs=1e-9)
        finally:
            stage.close()


def test_a_drive_that_never_starts_is_a_timeout():
    with AzDriveEmulator(dict(REGISTERS)) as drive:  # no motion model: the trigger is stored, nothing moves
        stage = ModbusStage(parse_address(f"modbus-tcp://127.0.0.1:{drive.port}?unit=1&steps_per_rev=10000&gear=36"), 0.1)
        try:
            with pytest.raises(InstrumentTimeout, match="never started"):
                stage.move_to(1.0)
        finally:
            stage.close()
