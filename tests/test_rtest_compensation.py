"""Location-error compensation (rtcal/compensation/kinematics.py and its formats) against the simulated
machine's true lines and LinuxCNC's own kinematics formula: the corrected record puts the control's
axes where the machine's are, with the sign each manual gives."""

from __future__ import annotations

import numpy as np
import pytest

from rtcal.compensation.kinematics import LocationErrors
from rtcal.compensation.kinematics_registry import kinematics_format
from rtcal.compensation.table import CompensationError
from simulators.bench import Bench
from simulators.machine_tool import machine_of
from simulators.scenario import Scenario
from tests.rtest_sim import linuxcnc_xyzac_inverse

PINS = {"x-rot-point": 3.0, "y-rot-point": -2.0, "z-rot-point": 0.0, "y-offset": 20.0, "z-offset": -40.0}
OFFSETS = {"X0C_um": 35.0, "Y0C_um": -22.0, "Y0A_um": 18.0, "Z0A_um": -27.0}
ANGLES = {"A0C_arcsec": 25.0, "B0C_arcsec": -15.0, "B0A_arcsec": 10.0, "C0A_arcsec": -12.0}
SPHERE = np.array([140.0, 30.0, 60.0])
POSES = [(0.0, 0.0), (0.0, 90.0), (30.0, 200.0), (-60.0, 45.0), (90.0, -120.0)]


def machine(errors: dict[str, float]):
    """The simulated machine whose nominal kinematics are LinuxCNC's pins above, with these true errors."""
    geometry = kinematics_format("linuxcnc-xyzac-trt").geometry(PINS)
    bench = Bench(Scenario.model_validate({"machine": {
        "kinematics": {"c_point_mm": list(geometry.c_point_mm), "a_point_mm": list(geometry.a_point_mm)},
        "location_errors": errors, "sphere": {"positions_mm": [SPHERE.tolist()], "setup_offsets_um": [[0, 0, 0]]}}}))
    return machine_of(bench)


def tcp_deviation_um(model, pins: dict[str, float]) -> float:
    """LinuxCNC with these pins, in TCP, commanded to the sphere's workpiece position at each pose: how far
    (µm) the tool's point is from where the true machine carried the sphere."""
    worst = 0.0
    for a, c in POSES:
        joints = linuxcnc_xyzac_inverse(pins, SPHERE, a, c)
        true = model.sphere_centre_mm({"x": 0.0, "y": 0.0, "z": 0.0, "a": a, "c": c}, 1)
        worst = max(worst, float(np.max(np.abs(true - joints))) * 1e3)
    return worst


def test_linuxcnc_pins_put_the_controls_axes_where_the_machine_has_them():
    model = machine(OFFSETS)
    fmt = kinematics_format("linuxcnc-xyzac-trt")
    out = fmt.write(PINS, LocationErrors.of(OFFSETS))
    assert tcp_deviation_um(model, PINS) > 20.0  # before: the control's model misses by the location errors
    assert tcp_deviation_um(model, out.record) < 1e-6  # after: exactly where the sphere is
    assert fmt.parse(out.text) == pytest.approx(out.record, abs=1e-6)  # the file holds what was computed
    flipped = {k: 2 * PINS[k] - v for k, v in out.record.items()}  # a wrong sign: twice as far off
    assert tcp_deviation_um(model, flipped) > 1.5 * tcp_deviation_um(model, PINS)
    assert set(out.absorbed) == set(OFFSETS) and not out.not_absorbed


def test_linuxcnc_leaves_the_tilts_and_says_so():
    model = machine({**OFFSETS, **ANGLES})
    out = kinematics_format("linuxcnc-xyzac-trt").write(PINS, LocationErrors.of({**OFFSETS, **ANGLES}))
    assert set(out.not_absorbed) == set(ANGLES)
    assert all(f"NOT absorbed: {s}" in out.text for s in ANGLES)
    before, after = tcp_deviation_um(model, PINS), tcp_deviation_um(model, out.record)
    assert after < before / 2 and after > 1.0  # the offsets are gone, the tilts' share (µm at 200 mm) stays


def test_seed_000s_four_location_errors_feed_the_same_writers():
    errors = LocationErrors.of({"X0C_um": (12.0, 0.8), "Y0C_um": (-7.0, 0.8), "A0C_arcsec": (3.0, 0.5),
                                "B0C_arcsec": (-2.0, 0.5)}, frame="CMM frame (docs/paper000.md)")
    out = kinematics_format("linuxcnc-xyzac-trt").write(PINS, errors)
    assert out.record["x-rot-point"] == pytest.approx(PINS["x-rot-point"] + 0.012)
    assert out.record["y-rot-point"] == pytest.approx(PINS["y-rot-point"] - 0.007)
    assert out.record["y-offset"] == pytest.approx(PINS["y-offset"] + 0.007)  # A stays: only C moved
    assert set(out.not_absorbed) == {"A0C_arcsec", "B0C_arcsec"}
    with pytest.raises(CompensationError, match="not a location error's symbol"):
        LocationErrors.of({"X0Q_um": 1.0})
    with pytest.raises(CompensationError, match="belong to no axis of a trunnion"):
        kinematics_format("fanuc-tcp-table").write(
            {"table_position_x": 0, "table_position_y": 0, "table_position_z": 0, "19703": 0, "19704": 0, "19705": 0},
            LocationErrors.of({"X0B_um": 3.0}))


def test_linuxcncs_own_example_config_is_read_and_its_net_fed_offsets_refused():
    """LinuxCNC configs/sim/axis/vismach/5axis/table-rotary-tilting/xyzac-trt.ini sets the rot point with setp
    and feeds y-offset and z-offset from signals (net … sets :y-offset 20): the rot point reads 0; the
    signal-fed pins are refused, not read as 0."""
    example = ("HALCMD = net  :y-offset     xyzac-trt-kins.y-offset    xyzac-trt-gui.y-offset\n"
               "HALCMD = sets :y-offset     20\n"
               "HALCMD = setp xyzac-trt-kins.x-rot-point 0\n"
               "HALCMD = setp xyzac-trt-kins.y-rot-point 0\n"
               "HALCMD = setp xyzac-trt-kins.z-rot-point 0\n")
    fmt = kinematics_format("linuxcnc-xyzac-trt")
    with pytest.raises(CompensationError, match=r":1: xyzac-trt-kins.y-offset is fed by a signal"):
        fmt.parse(example, "xyzac-trt.ini")
    assert fmt.parse(example.split("\n", 2)[2], "xyzac-trt.ini") == {p: 0.0 for p in PINS}
    ini = fmt.write(PINS, LocationErrors.of(OFFSETS), form="ini")
    assert all(line.startswith(("#", "HALCMD = setp ")) for line in ini.text.splitlines())


CARR = {"I2x": 3.0, "I2y": 18.0, "I2z": -40.0, "I3x": 0.0, "I3y": -20.0, "I3z": 40.0,
        "V1x": 1.0, "V1y": 0.0, "V1z": 0.0, "V2x": 0.0, "V2y": 0.0, "V2z": 1.0}


def _distance_to_line(point: np.ndarray, line_point: np.ndarray, direction: np.ndarray) -> float:
    v = point - line_point
    return float(np.linalg.norm(v - (v @ direction) * direction))


def test_sinumerik_swivel_record_holds_all_eight_on_the_true_lines():
    fmt = kinematics_format("siemens-tc-carr")
    geometry = fmt.geometry(CARR)
    everything = {**OFFSETS, **ANGLES}
    bench = Bench(Scenario.model_validate({"machine": {
        "kinematics": {"c_point_mm": list(geometry.c_point_mm), "a_point_mm": list(geometry.a_point_mm)},
        "location_errors": everything}}))
    model = machine_of(bench)
    out = fmt.write(CARR, LocationErrors.of(everything), carrier=2)
    rec = out.record
    a_pt = np.array([rec["I2x"], rec["I2y"], rec["I2z"]])
    c_pt = a_pt + np.array([rec["I3x"], rec["I3y"], rec["I3z"]])
    v1, v2 = (np.array([rec[f"{v}{a}"] for a in "xyz"]) for v in ("V1", "V2"))
    assert _distance_to_line(a_pt, model.a_point, model.a_dir) < 1e-9
    assert _distance_to_line(c_pt, model.c_point, model.c_dir) < 1e-9
    assert np.allclose(v1, model.a_dir, atol=1e-12) and np.allclose(v2, model.c_dir, atol=1e-12)
    assert np.allclose([rec["I4x"], rec["I4y"], rec["I4z"]], -(a_pt + np.array([rec["I3x"], rec["I3y"], rec["I3z"]])))
    assert set(out.absorbed) == set(everything) and not out.not_absorbed
    back = fmt.parse(out.text, carrier=2)
    assert back == pytest.approx({k: rec[k] for k in back}, abs=1e-4)
    assert "$TC_CARR23[2]=\"P\"" in out.text and out.text.rstrip().endswith("M30")


def test_sinumerik_keeps_the_commissioned_sense_and_refuses_another_machine():
    fmt = kinematics_format("siemens-tc-carr")
    reversed_table = {**CARR, "V1x": -1.0, "V2z": -1.0}  # "for a table the axis direction is reversed"
    out = fmt.write(reversed_table, LocationErrors.of(ANGLES))
    assert out.record["V1x"] < 0 and out.record["V2z"] < 0
    with pytest.raises(CompensationError, match="is not along X"):
        fmt.write({**CARR, "V1x": 0.0, "V1y": 1.0}, LocationErrors.of(ANGLES))
    broken = "\n".join("$TC_CARR18[1]=5.0" if line.startswith("$TC_CARR18[1]=") else line for line in out.text.splitlines())
    with pytest.raises(CompensationError, match="does not close the chain"):
        fmt.parse(broken)


FANUC = {"table_position_x": 3.0, "table_position_y": 18.0, "table_position_z": -40.0, "19703": 0.0, "19704": -20.0,
         "19705": 40.0}


def test_fanuc_table_position_and_intersection_vector_on_the_true_lines():
    fmt = kinematics_format("fanuc-tcp-table")
    geometry = fmt.geometry(FANUC)
    bench = Bench(Scenario.model_validate({"machine": {
        "kinematics": {"c_point_mm": list(geometry.c_point_mm), "a_point_mm": list(geometry.a_point_mm)},
        "location_errors": OFFSETS}}))
    model = machine_of(bench)
    out = fmt.write(FANUC, LocationErrors.of({**OFFSETS, **ANGLES}), increment_system="is-c", position_parameter=19700)
    rec = out.record
    a_pt = np.array([rec["table_position_x"], rec["table_position_y"], rec["table_position_z"]])
    b_pt = a_pt + np.array([rec["19703"], rec["19704"], rec["19705"]])
    assert _distance_to_line(a_pt, model.a_point, model.a_dir) < 1e-9
    assert _distance_to_line(b_pt, model.c_point, model.c_dir) < 1e-9
    assert set(out.not_absorbed) == set(ANGLES)
    assert "19700 = 3.0000" in out.text and "19704 = " in out.text
    assert fmt.parse(out.text) == pytest.approx(rec, abs=1e-4)
    unnumbered = fmt.write(FANUC, LocationErrors.of(OFFSETS))
    assert "ROTARY TABLE POSITION X = 3.000" in unnumbered.text and fmt.parse(unnumbered.text)["19703"] == pytest.approx(
        unnumbered.record["19703"], abs=1e-3)
    with pytest.raises(CompensationError, match="increment system"):
        fmt.write(FANUC, LocationErrors.of(OFFSETS), increment_system="is-a")
