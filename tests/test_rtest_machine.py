"""The simulated trunnion machine as instruments: the machine_tool kind (drivers/interfaces.py), its
in-process backend, and the nest read as three Sylvac indicators, in process and over the wire."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from drivers.errors import OutOfLimits
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
