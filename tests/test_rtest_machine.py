"""The simulated trunnion machine as instruments: the machine_tool kind (drivers/interfaces.py), its
in-process backend, and the nest read as three Sylvac indicators, in process and over the wire."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from drivers.errors import InstrumentFault, OutOfLimits
from drivers.factory import open_dial_indicator
from drivers.fence import fenced
from drivers.interfaces import MachineTarget, MachineTool
from drivers.kinds import KINDS, describe_kind
from rtcal.solvers.rtest import TrunnionGeometry, joint_targets
from simulators.bench import Bench
from simulators.instruments import SimMachineTool, SimNestIndicator
from simulators.scenario import Scenario
from simulators.servers.serial_protocols import SylvacHandler

SCENARIO = {"machine": {"location_errors": {"X0C_um": 15.0, "B0A_arcsec": -20.0},
                        "sphere": {"setup_offsets_um": [[20.0, -10.0, 5.0]]},
                        "nest": {"resolution_um": 0.1}}}


def _at_sphere(tool: SimMachineTool) -> dict[str, float]:
    spec = tool.machine.spec
    start = joint_targets(TrunnionGeometry(spec.kinematics.c_point_mm, spec.kinematics.a_point_mm),
                          spec.sphere.positions_mm[0], [0.0], [0.0])[0]
    here = dict(zip("xyzac", (float(v) for v in start)))
    tool.move_to(MachineTarget({**here, "z": here["z"] + 20.0}))
    tool.move_to(MachineTarget(here))
    return here


def test_the_machine_tool_kind_describes_its_joints():
    assert KINDS["machine_tool"].interface is MachineTool
    fields = describe_kind("machine_tool")
    assert list(fields) == ["position_x_mm", "position_y_mm", "position_z_mm", "position_a_deg", "position_b_deg",
                            "position_c_deg"]
    tool = SimMachineTool(Bench(Scenario.model_validate(SCENARIO)))
    here = _at_sphere(tool)
    values = tool.read_values()
    assert values["position_x_mm"].value == pytest.approx(here["x"]) and values["position_c_deg"].value == 0.0
    assert math.isnan(values["position_b_deg"].value)  # an xyzac machine has no B
    fenced_tool = fenced("machine_tool", "sim", "", lambda: tool)
    assert isinstance(fenced_tool, MachineTool)
    assert fenced_tool.read_values(["position_z_mm"])["position_z_mm"].value == pytest.approx(here["z"])


def test_a_target_beyond_the_limits_or_with_other_axes_is_refused_before_anything_moves():
    tool = SimMachineTool(Bench(Scenario.model_validate(SCENARIO)))
    with pytest.raises(OutOfLimits, match="A 130 ° outside its limits"):
        tool.move_to(MachineTarget({"x": 0, "y": 0, "z": 0, "a": 130.0, "c": 0}))
    with pytest.raises(OutOfLimits, match="names axes"):
        tool.move_to(MachineTarget({"x": 0, "y": 0, "z": 0, "b": 10.0, "c": 0}))
    with pytest.raises(OutOfLimits, match="X nan"):
        tool.move_to(MachineTarget({"x": 0, "y": 0, "z": 0, "a": 0, "c": 0}, via=({"x": math.nan, "y": 0, "z": 0, "a": 0,
                                                                                     "c": 0},)))
    assert tool.joint_positions() == {"x": 0.0, "y": 0.0, "z": 0.0, "a": 0.0, "c": 0.0}


def test_the_nest_reads_as_three_sylvac_indicators_in_process_and_on_the_wire():
    bench = Bench(Scenario.model_validate(SCENARIO))
    tool = SimMachineTool(bench, inject=False)
    _at_sphere(tool)
    nest = [SimNestIndicator(bench, i, inject=False) for i in range(3)]
    assert [n.name for n in nest] == ["nest_indicator_1", "nest_indicator_2", "nest_indicator_3"]
    plungers_um = np.array([tool.machine.sensor_mm(i) * 1e3 for i in range(3)])
    assert np.max(np.abs(plungers_um)) > 5.0  # the set-up offset shows
    assert np.allclose([n.read_um() for n in nest], plungers_um, atol=0.05)  # the display's 0.1 µm digit
    handler = SylvacHandler(nest[0], inch=True)
    handler.handle(b"MM\r")
    reply = handler.handle(b"?\r")
    assert float(reply.decode().strip()) * 1e3 == pytest.approx(plungers_um[0], abs=0.05)


def test_the_hub_serves_the_nest_to_the_sylvac_driver():
    from simulators.servers.hub import SimulatorHub

    with SimulatorHub(Scenario.model_validate(SCENARIO), seed=1, serial="tcp") as hub:
        assert "model=sylvac" in hub.addresses["nest_indicator_3"]
        indicator = open_dial_indicator(hub.addresses["nest_indicator_3"], "nest_indicator_3", 2.0)
        try:
            value = indicator.read_um()
        finally:
            indicator.close()
    assert abs(value) <= 2000.0  # its plunger, within the stroke (no sphere there: fully out)


def test_the_scenario_states_exactly_the_eight_location_errors():
    with pytest.raises(ValidationError, match="X0A_um"):
        Scenario.model_validate({"machine": {"location_errors": {"X0A_um": 3.0}}})
    with pytest.raises(ValidationError, match="directions"):
        Scenario.model_validate({"machine": {"nest": {"directions": [[1, 0, 0], [0, 1, 0], [1, 1, 0]]}}})
    quiet = Scenario.model_validate({"machine": {"nest": {"noise_um": 0.5}, "linear_axes": {"repeatability_um": 1.0}}})
    assert quiet.without_noise().machine is not None and quiet.without_noise().machine.nest.noise_um == 0.0
    assert Scenario().machine is None


# -- tool-centre-point targets (MachineTarget.tcp) and the mover's stop contract

def test_a_tcp_target_puts_the_joints_where_the_controls_inverse_kinematics_does_and_holds_the_sphere():
    """In process, the control's model is the scenario's nominal kinematics: a C turn about the held sphere
    puts the joints where LinuxCNC's xyzacKinematicsInverse would (its formula, written from the C source in
    tests/rtest_sim.py), and a machine without location errors keeps the sphere on the nest's zero all the
    way (a straight joint move would strike the nest: the next test)."""
    from tests.rtest_sim import linuxcnc_xyzac_inverse

    bench = Bench(Scenario.model_validate({"machine": {"kinematics": {"c_point_mm": [5.0, -3.0, 10.0],
                                                                      "a_point_mm": [5.0, 20.0, -40.0]}}}))
    tool = SimMachineTool(bench, inject=False)
    sphere = tool.machine.spec.sphere.positions_mm[0]
    pins = {"x-rot-point": 5.0, "y-rot-point": -3.0, "z-rot-point": 10.0, "y-offset": 23.0, "z-offset": -50.0}
    at = dict(zip("xyz", sphere))
    tool.move_to(MachineTarget({**at, "z": at["z"] + 20.0, "a": 0.0, "c": 0.0}, tcp=True))
    tool.move_to(MachineTarget({**at, "a": 0.0, "c": 0.0}, tcp=True))
    for a, c in ((0.0, 90.0), (30.0, 90.0), (-60.0, 200.0)):
        tool.move_to(MachineTarget({**at, "a": a, "c": c}, tcp=True))
        joints = tool.joint_positions()
        expected = linuxcnc_xyzac_inverse(pins, np.array(sphere), a, c)
        assert np.allclose([joints["x"], joints["y"], joints["z"]], expected, atol=1e-9), (a, c)
        assert (joints["a"], joints["c"]) == (a, c)
        assert np.linalg.norm(tool.machine.displacement_mm()) < 1e-9


def test_a_joint_move_between_the_same_poses_strikes_the_nest_and_a_tcp_backend_is_needed_for_tcp():
    bench = Bench(Scenario.model_validate({"machine": {}}))
    tool = SimMachineTool(bench, inject=False)
    at = dict(zip("xyz", tool.machine.spec.sphere.positions_mm[0]))
    tool.move_to(MachineTarget({**at, "z": at["z"] + 20.0, "a": 0.0, "c": 0.0}, tcp=True))
    tool.move_to(MachineTarget({**at, "a": 0.0, "c": 0.0}, tcp=True))
    target = MachineTarget({**at, "a": 0.0, "c": 90.0}, tcp=True)
    tool.move_to(target)
    there = tool.joint_positions()
    tool.move_to(MachineTarget({**at, "a": 0.0, "c": 0.0}, tcp=True))
    with pytest.raises(InstrumentFault, match="struck the nest"):
        tool.move_to(MachineTarget(there))  # the same end, straight in joint space

    class JointsOnly(SimMachineTool):
        tcp = False

    with pytest.raises(OutOfLimits, match="tool-centre-point target"):
        JointsOnly(Bench(Scenario.model_validate({"machine": {}})), inject=False).move_to(target)


def test_a_tcp_move_that_would_take_a_joint_beyond_its_limits_is_refused_before_anything_moves():
    bench = Bench(Scenario.model_validate({"machine": {"limits_mm": [[-200, -100, -200], [200, 100, 200]]}}))
    tool = SimMachineTool(bench, inject=False)
    at = dict(zip("xyz", tool.machine.spec.sphere.positions_mm[0]))
    with pytest.raises(OutOfLimits, match="joint Y outside its limits"):
        tool.move_to(MachineTarget({**at, "a": 0.0, "c": 90.0}, tcp=True))  # the sphere swings to Y 150
    assert tool.joint_positions() == {"x": 0.0, "y": 0.0, "z": 0.0, "a": 0.0, "c": 0.0}


def test_the_machine_tool_is_a_mover_with_a_fence_that_checks_its_joints():
    """stop() sends, wait_stopped() says where it was seen still: the engine's one safe-state path."""
    from drivers.interfaces import StopSeen

    tool = SimMachineTool(Bench(Scenario.model_validate({"machine": {}})), inject=False)
    fenced_tool = fenced("machine_tool", "sim", "", lambda: tool)
    fenced_tool.stop()
    seen = fenced_tool.wait_stopped()
    assert isinstance(seen, StopSeen) and seen.still and seen.where.startswith("X 0.000000 mm")

    class Broken(SimMachineTool):
        def joint_positions(self) -> dict[str, float]:
            return {"x": math.inf, "y": 0.0, "z": 0.0, "a": 0.0, "c": 0.0}

    broken = fenced("machine_tool", "sim", "", lambda: Broken(Bench(Scenario.model_validate({"machine": {}})), inject=False))
    with pytest.raises(InstrumentFault, match="joint X"):
        broken.joint_positions()


def test_the_linuxcnc_machine_address_takes_control_only_when_told_and_names_no_axis():
    from drivers.addresses import AddressError
    from drivers.factory import open_machine_tool, resolve

    assert resolve("machine_tool", "linuxcncrsh://127.0.0.1:5007?take_control=1")[1].name == "linuxcnc-trt"
    with pytest.raises(AddressError, match="take_control=1"):
        open_machine_tool("linuxcncrsh://127.0.0.1:9?speed_deg_per_s=5", 0.5)  # refused before any connection
    with pytest.raises(AddressError, match="no axis= or joint="):
        open_machine_tool("linuxcncrsh://127.0.0.1:9?axis=C&take_control=1", 0.5)


def test_the_kinematics_linuxcnc_loads_are_the_scenarios_nominal_or_a_files_pins_only(tmp_path):
    from rtcal.compensation.linuxcnc_kins import LinuxCncTrtFormat
    from simulators.servers.linuxcnc import kins_hal

    machine = Scenario.model_validate({"machine": {"kinematics": {"c_point_mm": [1.0, 2.0, 3.0],
                                                                  "a_point_mm": [1.0, 12.0, -47.0]}}}).machine
    assert machine is not None
    nominal = LinuxCncTrtFormat().parse(kins_hal(machine))
    assert nominal == {"x-rot-point": 1.0, "y-rot-point": 2.0, "z-rot-point": 3.0, "y-offset": 10.0, "z-offset": -50.0}
    given = tmp_path / "kins.hal"
    given.write_text("loadusr -W halshow\nsetp xyzac-trt-kins.x-rot-point 0.04\nsetp xyzac-trt-kins.z-offset -49.965\n")
    text = kins_hal(machine, str(given))
    assert "halshow" not in text and LinuxCncTrtFormat().parse(text)["x-rot-point"] == 0.04
    given.write_text("net off xyzac-trt-kins.y-offset\n")
    with pytest.raises(ValueError, match="fed by a signal"):
        kins_hal(machine, str(given))
