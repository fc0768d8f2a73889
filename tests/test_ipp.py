"""I++ DME: a raw session over a socket gets the standard's replies; the driver maps errors to types."""

from __future__ import annotations

import socket

import numpy as np
import pytest

from drivers.addresses import parse_address
from drivers.errors import InstrumentFault, OutOfLimits
from drivers.ipp_cmm import IppCmm
from simulators.scenario import CmmScenario, Scenario
from simulators.servers.hub import SimulatorHub


@pytest.fixture(scope="module")
def hub():
    scenario = Scenario(cmm=CmmScenario(volume_min_mm=(0, 0, 0), volume_max_mm=(1000, 800, 600)))
    with SimulatorHub(scenario, seed=1) as h:
        yield h


def _session(hub, lines: list[str]) -> list[str]:
    a = parse_address(hub.addresses["cmm"])
    with socket.create_connection((a.host, a.port), timeout=5) as s:
        f = s.makefile("rwb")
        replies = []
        for line in lines:
            f.write(line.encode() + b"\r\n")
            f.flush()
            tag = line[:5]
            while True:
                reply = f.readline().decode().rstrip("\r\n")
                replies.append(reply)
                if reply.startswith(f"{tag} %") or reply.startswith(f"{tag} !"):
                    break
        return replies


def test_raw_session_start_get_end(hub):
    replies = _session(hub, ["00001 StartSession()", "00002 GoTo(X(100), Y(200), Z(300))", "00003 Get(X(), Y(), Z())",
                             "00004 EndSession()"])
    assert replies[:2] == ["00001 &", "00001 %"]
    assert replies[2:4] == ["00002 &", "00002 %"]
    assert replies[4] == "00003 &"
    assert replies[5] == "00003 # X(100.000000), Y(200.000000), Z(300.000000)"
    assert replies[6:] == ["00003 %", "00004 &", "00004 %"]


@pytest.mark.parametrize("command,code", [
    ("00002 GoTo(X(5000), Y(0), Z(0))", "1008"),
    ("00002 Fly()", "0501"),
    ("00002 GoTo(X(), Y(2), Z(3))", "0502"),
    ("00002 GoTo(X(1), Y(2))", "0509"),
])
def test_errors_carry_the_standard_codes(hub, command, code):
    replies = _session(hub, ["00001 StartSession()", command])
    assert replies[2] == "00002 &"
    assert replies[3].startswith(f"00002 ! Error(2, {code},")


def test_commands_before_start_session_are_refused(hub):
    assert _session(hub, ["00001 Home()"])[1].startswith("00001 ! Error(2, 0008,")


def test_driver(hub):
    cmm = IppCmm(parse_address(hub.addresses["cmm"]))
    try:
        cmm.home()
        cmm.move_to(np.array([10.0, 20.0, 30.0]))
        assert np.allclose(cmm.position_mm(), [10, 20, 30])
        with pytest.raises(OutOfLimits, match="1008"):
            cmm.move_to(np.array([10.0, 2000.0, 30.0]))
        with pytest.raises(InstrumentFault, match="0501"):
            cmm.command("Fly()")
    finally:
        cmm.close()
