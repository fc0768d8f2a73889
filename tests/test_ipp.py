"""I++ DME: a raw session over a socket gets the standard's replies (the error table and severities
of Annex B as pyippdme and NIST's test files give them, the 0514 error state, one session at a
time, PtMeas on a surface); the driver maps errors to types and recovers from the error state."""

from __future__ import annotations

import socket

import numpy as np
import pytest

from drivers.addresses import parse_address
from drivers.errors import InstrumentFault, OutOfLimits
from drivers.ipp_cmm import IppCmm
from simulators.scenario import CmmScenario, Scenario
from simulators.servers.hub import SimulatorHub
from simulators.servers.ipp_server import DME_VERSION


@pytest.fixture(scope="module")
def hub():
    scenario = Scenario(cmm=CmmScenario(volume_min_mm=(0, 0, 0), volume_max_mm=(1000, 800, 600)))
    with SimulatorHub(scenario, seed=1) as h:
        yield h


def _connect(hub) -> socket.socket:
    a = parse_address(hub.addresses["cmm"])
    return socket.create_connection((a.host, a.port), timeout=5)


def _exchange(s: socket.socket, lines: list[str]) -> list[str]:
    """Send each line; collect replies up to that command's ``%``."""
    f = s.makefile("rwb")
    replies = []
    for line in lines:
        f.write(line.encode() + b"\r\n")
        f.flush()
        while True:
            reply = f.readline().decode().rstrip("\r\n")
            replies.append(reply)
            if reply.endswith(" %") or not reply:
                break
    return replies


def _session(hub, lines: list[str]) -> list[str]:
    with _connect(hub) as s:
        return _exchange(s, lines)


def test_raw_session_start_get_end(hub):
    replies = _session(hub, ["00001 StartSession()", "00002 GetDMEVersion()", "00003 GoTo(X(100), Y(200), Z(300))",
                             "00004 Get(X(), Y(), Z())", "00005 EndSession()"])
    assert replies == ["00001 &", "00001 %", "00002 &", f'00002 # DMEVersion("{DME_VERSION}")', "00002 %", "00003 &", "00003 %",
                       "00004 &", "00004 # X(100.000000), Y(200.000000), Z(300.000000)", "00004 %", "00005 &", "00005 %"]


@pytest.mark.parametrize("command,error", [
    ("00002 GoTo(X(5000), Y(0), Z(0))", "3, 1008"),  # target position out of machine volume
    ("00002 Fly()", "3, 0501"),  # unsupported command
    ("00002 GoTo(X(), Y(2), Z(3))", "3, 0509"),  # bad argument
    ("00002 PtMeas(X(1), Y(2))", "3, 0502"),  # incorrect arguments
    ('00002 ChangeTool("Bleep")', "3, 1502"),  # tool not found
])
def test_errors_carry_the_standard_codes_and_end_the_transaction(hub, command, error):
    replies = _session(hub, ["00001 StartSession()", command])
    assert replies[2] == "00002 &"
    assert replies[3].startswith(f"00002 ! Error({error},")
    assert replies[4] == "00002 %"


def test_after_an_error_every_command_gets_0514_until_clear_all_errors(hub):
    replies = _session(hub, ["00001 StartSession()", "00002 GoTo(X(5000), Y(0), Z(0))", "00003 Get(X(), Y(), Z())",
                             "00004 GetDMEVersion()", "00005 ClearAllErrors()", "00006 GetDMEVersion()"])
    assert replies[6] == '00003 ! Error(2, 0514, "Get", "Use ClearAllErrors to continue")'
    assert replies[9].startswith("00004 ! Error(2, 0514,")
    assert replies[11:] == ["00005 &", "00005 %", "00006 &", f'00006 # DMEVersion("{DME_VERSION}")', "00006 %"]


def test_commands_before_start_session_are_refused(hub):
    assert _session(hub, ["00001 Home()"])[1].startswith('00001 ! Error(3, 0507, "Home"')


def test_one_session_at_a_time(hub):
    """A second client cannot start a session (and so cannot move the CMM) while the first holds it."""
    with _connect(hub) as first, _connect(hub) as second:
        assert _exchange(first, ["00001 StartSession()"]) == ["00001 &", "00001 %"]
        refused = _exchange(second, ["00001 StartSession()", "00002 GoTo(X(1), Y(1), Z(1))"])
        assert refused[1].startswith('00001 ! Error(3, 0507, "StartSession", "Another client holds the session")')
        assert refused[4].startswith('00002 ! Error(3, 0507, "GoTo"')
        assert _exchange(first, ["00002 EndSession()"]) == ["00002 &", "00002 %"]
        assert _exchange(second, ["00003 StartSession()"]) == ["00003 &", "00003 %"]  # released: the second goes on


@pytest.mark.parametrize("command,reply", [
    ("00002 PtMeas(X(10), Y(20), Z(3), IJK(0, 0, 1))", "00002 # X(10.000000), Y(20.000000), Z(0.000000)"),  # 3 mm above
    ("00002 PtMeas(X(10), Y(20), Z(-2), IJK(0, 0, 1))", "00002 # X(10.000000), Y(20.000000), Z(0.000000)"),  # 2 mm in
    ("00002 PtMeas(X(10), Y(20), Z(9), IJK(0, 0, 1))", '00002 ! Error(2, 1006, "PtMeas", "Surface not found")'),
    ("00002 PtMeas(X(10), Y(20), Z(3), IJK(1, 0, 0))", '00002 ! Error(2, 1006, "PtMeas", "Surface not found")'),
])
def test_ptmeas_probes_the_table_top_and_can_miss_it(hub, command, reply):
    """The simulated CMM's one surface is its table top at Z = 0 (the volume's floor); PtMeas
    searches ±5 mm along the normal through the nominal point."""
    assert _session(hub, ["00001 StartSession()", command])[3] == reply


def test_driver(hub):
    cmm = IppCmm(parse_address(hub.addresses["cmm"]), tool="CatEye")
    try:
        assert cmm.identity() == f"I++ DME server, DMEVersion {DME_VERSION}, coordinate system MachineCsy"
        cmm.home()
        cmm.move_to(np.array([10.0, 20.0, 30.0]))
        assert np.allclose(cmm.position_mm(), [10, 20, 30])
        with pytest.raises(OutOfLimits, match="1008"):
            cmm.move_to(np.array([10.0, 2000.0, 30.0]))
        assert np.allclose(cmm.position_mm(), [10, 20, 30])  # the driver cleared the error state first
        with pytest.raises(InstrumentFault, match="0501"):
            cmm.command("Fly()")
        cmm.recover()  # what a fault policy's retry does
        assert cmm.command("GetDMEVersion()") == [f'DMEVersion("{DME_VERSION}")']
    finally:
        cmm.close()


def test_a_second_client_is_told_the_cmm_is_busy(hub):
    """Issue 46: a second rtcal (or `rtcal probe cmm`) beside a run got the server's bare refusal, or —
    from a server that leaves it unanswered, as NIST's reference server does — a timeout. Both now say
    the CMM is busy and what to do."""
    import threading

    from drivers.errors import InstrumentTimeout

    first = IppCmm(parse_address(hub.addresses["cmm"]), tool="CatEye")
    try:
        with pytest.raises(InstrumentFault, match="the CMM is busy: another client holds its I\\+\\+ session .*close the "
                                                  "other client"):
            IppCmm(parse_address(hub.addresses["cmm"]), tool="CatEye")
    finally:
        first.close()
    silent = socket.create_server(("127.0.0.1", 0))  # accepts, never answers: a server busy with another client
    held: list[socket.socket] = []
    threading.Thread(target=lambda: held.append(silent.accept()[0]), daemon=True).start()
    try:
        with pytest.raises(InstrumentTimeout, match=r"no reply to StartSession\(\) within 0.3 s: the CMM may be busy"):
            IppCmm(parse_address(f"ipp://127.0.0.1:{silent.getsockname()[1]}"), timeout_s=0.3)
    finally:
        for s in held:
            s.close()
        silent.close()


def test_driver_refuses_an_unknown_tool(hub):
    with pytest.raises(InstrumentFault, match="Tool not found"):
        IppCmm(parse_address(hub.addresses["cmm"]), 1.0, tool="NoSuchTool")
