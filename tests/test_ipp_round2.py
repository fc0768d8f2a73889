"""I++ DME as the specification 1.4.3 says (issue 27): `rtcal probe cmm` against an emulator written
from the specification (tests/emulators) — unhomed, homed, left in a part coordinate system, errors
in §8.1's form, warnings — and the driver against the simulator: homing only when allowed, E0000
emergency stops that latch, AbortE()."""

from __future__ import annotations

import json

import numpy as np
import pytest

from drivers.addresses import parse_address
from drivers.errors import EmergencyStop, InstrumentFault, OutOfLimits
from drivers.ipp_cmm import IppCmm
from rtcal.cli import main
from simulators.scenario import CmmScenario, Scenario
from simulators.servers.hub import SimulatorHub
from tests import emulators as emu
from tests.emulators import Emulator


def _probe(capsys, address: str) -> tuple[int, dict | None, str]:
    code = main(["probe", "cmm", address, "--json", "--timeout-s", "1"])
    out, err = capsys.readouterr()
    return code, (json.loads(out) if code == 0 else None), err


def _commands(device: Emulator) -> list[str]:
    return [line[6:].decode() for line in device.requests]


def test_probe_refuses_an_unhomed_cmm_and_never_homes_it(capsys):
    """A probe never moves a machine, even with home=1 in the address."""
    answer = emu.ipp_answer(first_get_fails=False, homed=False)
    with Emulator(answer, b"\r\n") as cmm:
        code, _, err = _probe(capsys, cmm.url("ipp") + "?home=1")
    assert code == 1
    assert err.count("\n") == 1 and "not homed" in err and "probe never moves" in err
    assert "Home()" not in _commands(cmm) and answer.machine["homed"] is False


@pytest.mark.parametrize("csy", ["MachineCsy", "PartCsy"])
def test_probe_reads_machine_coordinates_whatever_system_the_last_session_left(capsys, csy):
    answer = emu.ipp_answer(first_get_fails=False, coordinate_system=csy, part_origin_mm=(100.0, -50.0, 7.0))
    with Emulator(answer, b"\r\n") as cmm:
        code, r, err = _probe(capsys, cmm.url("ipp"))
    assert code == 0, err
    assert r["reading"] == {"x_mm": 1.0, "y_mm": 2.0, "z_mm": 3.0}  # machine coordinates, not 100 mm off
    assert "coordinate system MachineCsy" in r["identity"]
    assert _commands(cmm).index("SetCoordSystem(MachineCsy)") < _commands(cmm).index("Get(X(), Y(), Z())")


@pytest.mark.parametrize("bare", [False, True])
def test_probe_reads_through_warnings_and_errors_of_either_form(capsys, bare):
    """Severity-1 warnings before `%` are no failure; the severity-2 error (F3 bare or quoted) is
    cleared and read again."""
    with Emulator(emu.ipp_answer(first_get_fails=True, bare_cause=bare, warnings=True), b"\r\n") as cmm:
        code, r, err = _probe(capsys, cmm.url("ipp"))
    assert code == 0, err
    assert r["reading"] == {"x_mm": 1.0, "y_mm": 2.0, "z_mm": 3.0}
    assert "ClearAllErrors()" in _commands(cmm)


@pytest.mark.parametrize("bare", [False, True])
def test_driver_keeps_the_code_of_an_error_in_the_specifications_form(bare):
    """§8.1: `Error(3, 2500, GoTo, "…")` — a machine limit is OutOfLimits, not a generic fault."""
    with Emulator(emu.ipp_answer(first_get_fails=False, bare_cause=bare), b"\r\n") as device:
        cmm = IppCmm(parse_address(device.url("ipp")), 1.0)
        try:
            with pytest.raises(OutOfLimits, match="2500"):
                cmm.move_to(np.array([9000.0, 0.0, 0.0]))
            cmm.move_to(np.array([4.0, 5.0, 6.0]))  # the error state was cleared first
            assert np.allclose(cmm.position_mm(), [4, 5, 6])
        finally:
            cmm.close()
    assert "ClearAllErrors()" in _commands(device)


def test_driver_logs_warnings_and_goes_on():
    with Emulator(emu.ipp_answer(first_get_fails=False, warnings=True, bare_cause=True), b"\r\n") as device:
        cmm = IppCmm(parse_address(device.url("ipp")), 1.0)
        try:
            cmm.move_to(np.array([4.0, 5.0, 6.0]))
            assert np.allclose(cmm.position_mm(), [4, 5, 6])
            assert len(cmm.warnings) == 2 and "0504" in cmm.warnings[0]
        finally:
            cmm.close()
    assert "ClearAllErrors()" not in _commands(device)


def test_emergency_stop_event_latches_and_is_never_cleared_automatically():
    with Emulator(emu.ipp_answer(first_get_fails=False, emergency_at_goto=True, bare_cause=True), b"\r\n") as device:
        cmm = IppCmm(parse_address(device.url("ipp")), 1.0)
        try:
            with pytest.raises(EmergencyStop, match="0500"):
                cmm.move_to(np.array([4.0, 5.0, 6.0]))
            sent = len(device.requests)
            for attempt in (lambda: cmm.recover(), lambda: cmm.position_mm(), lambda: cmm.move_to(np.zeros(3))):
                with pytest.raises(EmergencyStop):
                    attempt()
            assert len(device.requests) == sent  # nothing sent, ClearAllErrors() least of all
            cmm.stop()  # stopping is always allowed: AbortE()
            assert device.requests[-1].decode() == "E0001 AbortE()"
        finally:
            cmm.close()


# -- against the simulator ----------------------------------------------------------------------------

@pytest.fixture()
def hub():
    scenario = Scenario(cmm=CmmScenario(volume_min_mm=(0, 0, 0), volume_max_mm=(1000, 800, 600)))
    with SimulatorHub(scenario, seed=1, cmm_homed=False) as h:
        yield h


def test_simulator_homes_only_when_allowed_and_keeps_the_coordinate_system(hub):
    address = parse_address(hub.addresses["cmm"])
    with pytest.raises(InstrumentFault, match="not homed.*home: true"):
        IppCmm(address, 1.0)
    hub.ipp_machine.coordinate_system = "PartCsy"  # what another program's session left
    cmm = IppCmm(address, 1.0, home=True)
    try:
        assert hub.ipp_machine.homed and "homed by rtcal" in cmm.identity()
        assert hub.ipp_machine.coordinate_system == "MachineCsy"
        cmm.move_to(np.array([10.0, 20.0, 30.0]))
        assert np.allclose(cmm.position_mm(), [10, 20, 30])
        assert np.allclose(hub.cmm.bench.probe_target_mm, [10, 20, 30])
        cmm.stop()  # AbortE() answered
        assert np.allclose(cmm.position_mm(), [10, 20, 30])
    finally:
        cmm.close()


def test_simulator_part_system_and_emergency_stop(hub):
    hub.ipp_machine.homed = True
    cmm = IppCmm(parse_address(hub.addresses["cmm"] + "?home=1"), 1.0)
    try:
        assert cmm.command("SetCoordSystem(PartCsy)") == []
        assert np.allclose(cmm.position_mm(), hub.cmm.bench.probe_target_mm - hub.ipp_machine.part_origin_mm)
        cmm.command("SetCoordSystem(MachineCsy)")
        hub.ipp_machine.emergency_at_motion = 1
        with pytest.raises(EmergencyStop):
            cmm.move_to(np.array([10.0, 20.0, 30.0]))
        with pytest.raises(EmergencyStop):
            cmm.recover()
    finally:
        cmm.close()
    hub.ipp_machine.release_emergency_stop()


def test_simulator_second_start_session_is_a_protocol_error(hub):
    import socket

    a = parse_address(hub.addresses["cmm"])
    with socket.create_connection((a.host, a.port), timeout=2) as s:
        f = s.makefile("rwb")
        f.write(b"00001 StartSession()\r\n00002 StartSession()\r\n")
        f.flush()
        replies = [f.readline().decode().strip() for _ in range(5)]
    assert replies[:2] == ["00001 &", "00001 %"]
    assert replies[3].startswith('00002 ! Error(3, 0008, "StartSession"')


def test_a_run_opens_the_cmm_with_the_procedures_home_option(hub):
    """`cmm: {home: true}` in a procedure reaches the driver through the factory; false refuses."""
    from drivers import factory
    from rtcal.procedure.models import CmmChoice

    assert CmmChoice.model_validate({"address": hub.addresses["cmm"], "home": True}).home is True
    assert CmmChoice.model_validate({"address": hub.addresses["cmm"]}).home is False
    with pytest.raises(InstrumentFault, match="not homed"):
        factory.open_cmm(hub.addresses["cmm"], (0, 0, 0), (1000, 800, 600), 1.0)
    cmm = factory.open_cmm(hub.addresses["cmm"], (0, 0, 0), (1000, 800, 600), 1.0, home=True)
    try:
        assert hub.ipp_machine.homed and "homed by rtcal" in cmm.identity()
    finally:
        cmm.close()


def test_an_emergency_stop_pressed_between_commands_stops_the_next_one_before_it_is_sent(hub):
    hub.ipp_machine.homed = True
    cmm = IppCmm(parse_address(hub.addresses["cmm"]), 1.0)
    try:
        cmm.move_to(np.array([10.0, 20.0, 30.0]))
        hub.ipp_machine.press_emergency_stop()  # the server's unsolicited E0000 line
        import time

        time.sleep(0.2)
        with pytest.raises(EmergencyStop, match="0500"):
            cmm.move_to(np.array([50.0, 60.0, 70.0]))
        assert np.allclose(hub.cmm.bench.probe_target_mm, [10, 20, 30])
        assert hub.ipp_machine.motions == 1  # the second GoTo never reached the server
    finally:
        cmm.close()
        hub.ipp_machine.release_emergency_stop()
