"""A real LinuxCNC as the R-test's machine tool: Debian's linuxcnc-uspace with its xyzac-trt-kins started
headless (`rtcal sim serve --machine linuxcnc`, simulators/linuxcnc/rtcal_trt.ini), the simulated trunnion
machine's joints following LinuxCNC's motor commands, the nest read as three Sylvac indicators.

What is checked against LinuxCNC itself: its joints are where the module's inverse kinematics (the
formula of trtfuncs.c, written out apart from rtcal in tests/rtest_sim.py) puts them for the pins it
loaded at start; the pins rtcal's LinuxCNC format writes for the machine's true location errors (its
documented signs) make LinuxCNC hold the sphere on the nest, and the same pins with the sign flipped
drive it further off; a stop over the session kept for stopping halts a tool-centre-point move at
once and leaves the machine on. Real time, a minute or so; shares test_linuxcnc_loop's lock (one
LinuxCNC per machine). Skipped where LinuxCNC is not installed.
"""

from __future__ import annotations

import json
import re
import select
import socket
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np
import pytest

from drivers.addresses import AddressError
from drivers.factory import open_dial_indicator, open_machine_tool
from drivers.interfaces import MachineTarget
from rtcal.compensation.kinematics import LocationErrors
from rtcal.compensation.linuxcnc_kins import LinuxCncTrtFormat
from simulators.scenario_file import load_scenario
from simulators.servers.hub import SimulatorHub
from simulators.servers.linuxcnc import LinuxCncProcess, available, console
from tests.rtest_sim import linuxcnc_xyzac_inverse
from tests.test_linuxcnc_loop import one_linuxcnc_at_a_time

pytestmark = pytest.mark.skipif(bool(available()), reason=available() or "LinuxCNC present")
REPO = Path(__file__).resolve().parents[1]
SCENARIO = REPO / "procedures" / "scenarios" / "rtest_trunnion.yaml"
# poses (A, C) of the kinematic tests: C turned at A = 0, A turned at C = 0, C turned at a tilt
POSES = ((0.0, 90.0), (0.0, 180.0), (60.0, 0.0), (-60.0, 0.0), (45.0, 120.0))
JOINT_TOLERANCE = 2e-6  # mm or deg: two units of the six decimals linuxcncrsh prints


@contextmanager
def linuxcnc_machine(kins: str | None = None) -> Iterator[SimulatorHub]:
    """The hub with LinuxCNC as the machine tool (in process: the test sees the simulated machine)."""
    with one_linuxcnc_at_a_time():
        hub = SimulatorHub(load_scenario(SCENARIO), machine="linuxcnc", kins=kins, serial="tcp", sylvac_inch=False)
        hub.start()
        try:
            yield hub
        finally:
            hub.stop()


def pins_of(text: str) -> dict[str, float]:
    return LinuxCncTrtFormat().parse(text)


def at_poses(hub: SimulatorHub, pins: dict[str, float]) -> np.ndarray:
    """Onto the sphere from above, then each pose with the sphere held (TCP); at each, the joints are where
    the module's formula puts them for ``pins`` and where the simulated machine stands. The nest's
    readings (µm) at each pose."""
    machine = open_machine_tool(hub.addresses["machine_tool"], 5.0)
    nest = [open_dial_indicator(hub.addresses[f"nest_indicator_{i}"], f"nest_indicator_{i}", 5.0) for i in (1, 2, 3)]
    sphere = np.array(load_scenario(SCENARIO).machine.sphere.positions_mm[0])  # type: ignore[union-attr]
    at = dict(zip("xyz", (float(v) for v in sphere)))
    readings = []
    try:
        machine.move_to(MachineTarget({**at, "z": at["z"] + 20.0, "a": 0.0, "c": 0.0}, tcp=True))
        machine.move_to(MachineTarget({**at, "a": 0.0, "c": 0.0}, tcp=True))
        for a, c in POSES:
            machine.move_to(MachineTarget({**at, "a": a, "c": c}, tcp=True))
            joints = machine.joint_positions()
            expected = linuxcnc_xyzac_inverse(pins, sphere, a, c)
            assert np.allclose([joints[k] for k in "xyz"], expected, atol=JOINT_TOLERANCE), (a, c, joints, expected)
            assert hub.joints_feed is not None and hub.joints_feed.caught_up(time.monotonic())
            followed = hub.bench.machine.joints
            assert all(abs(followed[k] - joints[k]) <= JOINT_TOLERANCE for k in "xyzac"), (followed, joints)
            readings.append([n.read_um() for n in nest])
        machine.move_to(MachineTarget({**at, "a": 0.0, "c": 0.0}, tcp=True))
        assert not hub.bench.machine.collision
    finally:
        for instrument in (machine, *nest):
            instrument.close()
    return np.array(readings)


def test_linuxcnc_puts_the_joints_by_its_kinematics_and_the_pins_it_loads_hold_the_sphere_as_the_format_says(tmp_path):
    scenario = load_scenario(SCENARIO)
    assert scenario.machine is not None
    truth = scenario.machine.location_errors.model_dump()
    nominal = {"x-rot-point": 0.0, "y-rot-point": 0.0, "z-rot-point": 0.0, "y-offset": 0.0, "z-offset": -50.0}
    with linuxcnc_machine() as hub:
        before = at_poses(hub, nominal)
        stop_mid_move(hub)
    fmt = LinuxCncTrtFormat()
    corrected = fmt.write(nominal, LocationErrors.of(truth))
    assert set(corrected.absorbed) == {"X0C_um", "Y0C_um", "Y0A_um", "Z0A_um"}
    (tmp_path / "right.hal").write_text(corrected.text)
    flipped = fmt.write(nominal, LocationErrors.of({k: -v for k, v in truth.items()}))
    (tmp_path / "flipped.hal").write_text(flipped.text)
    with linuxcnc_machine(str(tmp_path / "right.hal")) as hub:
        after = at_poses(hub, pins_of(corrected.text))
    with linuxcnc_machine(str(tmp_path / "flipped.hal")) as hub:
        wrong = at_poses(hub, pins_of(flipped.text))
    worst = {name: float(np.max(np.linalg.norm(r, axis=1))) for name, r in
             (("before", before), ("after", after), ("flipped", wrong))}
    print(f"largest nest reading at the poses, µm: {worst}")
    assert worst["before"] > 40.0, worst  # tens of µm off the nominal lines
    assert worst["after"] * 5 <= worst["before"], worst  # what is left: the tilts and C's positioning error
    assert worst["flipped"] >= 1.5 * worst["before"], worst


def stop_mid_move(hub: SimulatorHub) -> None:
    """A long C turn about the held sphere (0 → 300° at 90 °/s), stopped 1 s in over the session kept for
    stopping: at rest within a second, far short of 300°, where the joints say; the machine left on."""
    address = hub.addresses["machine_tool"]
    machine = open_machine_tool(address, 5.0)
    sphere = load_scenario(SCENARIO).machine.sphere.positions_mm[0]  # type: ignore[union-attr]
    at = dict(zip("xyz", sphere))
    errors: list[BaseException] = []

    def move() -> None:
        try:
            machine.move_to(MachineTarget({**at, "a": 0.0, "c": 300.0}, tcp=True))
        except BaseException as exc:  # noqa: BLE001 — the cut-short move's fault is expected
            errors.append(exc)

    try:
        machine.move_to(MachineTarget({**at, "a": 0.0, "c": 0.0}, tcp=True))
        mover = threading.Thread(target=move)
        mover.start()
        time.sleep(1.0)
        asked = time.monotonic()
        machine.stop()
        seen = machine.wait_stopped()
        took_s = time.monotonic() - asked
        mover.join(30)
        print(f"stop: at rest {took_s:.2f} s after stop() at {seen.where}; the move said: {errors[0] if errors else '-'}")
        assert seen.still and took_s < 1.5, (seen, took_s)
        c_deg = float(re.search(r"C (-?[\d.]+)°", seen.where).group(1))
        assert 30.0 < c_deg < 200.0, seen.where
        assert errors, "the move cut short by the stop was reported done"
        host, port = re.match(r"linuxcncrsh://([^:]+):(\d+)", address).groups()
        assert console(host, int(port), "get estop", "get machine") == ["ESTOP OFF", "MACHINE ON"]
    finally:
        machine.close()


def test_a_linuxcnc_without_the_trunnion_kinematics_is_refused_before_anything_moves():
    """The four-axis trivkins machine (identity kinematics): a tool-centre-point target would move its joints
    straight, so the machine tool refuses it at connect, naming why."""
    with one_linuxcnc_at_a_time():
        process = LinuxCncProcess(machine="xyzc")
        port = process.start()
        try:
            with pytest.raises(AddressError, match="identity kinematics"):
                open_machine_tool(f"linuxcncrsh://127.0.0.1:{port}?take_control=1", 5.0)
        finally:
            process.stop()


@pytest.mark.campaign  # LinuxCNC brought up and down by sim serve; CI keeps the machine's kinematics test
def test_sim_serve_machine_linuxcnc_prints_the_machine_tools_address_and_shuts_linuxcnc_down(tmp_path):
    bad = tmp_path / "bad.hal"
    bad.write_text("setp xyzac-trt-kins.x-rot-point twelve\n")
    code = subprocess.run([sys.executable, "-m", "rtcal.cli", "sim", "serve", "--machine", "linuxcnc", "--scenario",
                           str(SCENARIO), "--kins", str(bad)], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert code.returncode == 2 and "--kins" in code.stderr and "not a number" in code.stderr, code.stderr
    with one_linuxcnc_at_a_time():
        proc = subprocess.Popen([sys.executable, "-m", "rtcal.cli", "sim", "serve", "--machine", "linuxcnc", "--scenario",
                                 str(SCENARIO)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
        try:
            ready, _, _ = select.select([proc.stdout], [], [], 90)
            assert ready, "rtcal sim serve --machine linuxcnc printed nothing in 90 s"
            addresses = json.loads(proc.stdout.readline())
            assert addresses["machine_tool"].startswith("linuxcncrsh://127.0.0.1:")
            assert "take_control=1" in addresses["machine_tool"] and "nest_indicator_3" in addresses
            probed = subprocess.run([sys.executable, "-m", "rtcal.cli", "probe", "machine_tool", addresses["machine_tool"],
                                     "--timeout-s", "5"], capture_output=True, text=True, cwd=REPO, timeout=60)
            assert probed.returncode == 0 and "xyzac-trt-kins, joints X0 Y1 Z2 A3 C4" in probed.stdout, probed
        finally:
            proc.terminate()
            proc.wait(60)
        assert proc.returncode == 0, proc.stderr.read()
        port = int(re.search(r":(\d+)\?", addresses["machine_tool"]).group(1))
        with socket.socket() as s:
            assert s.connect_ex(("127.0.0.1", port)) != 0, "LinuxCNC still answers after `sim serve` ended"
