"""A simulated R-test driven directly on the simulated machine and nest (no engine, no store): what
the truth tests and benchmarks/bench_rtest.py run. The method's plan (a later folder) does the same
through the engine; this helper states the physics' side of the contract: the sphere path between
poses, C approached from the stated direction, the nest calibrated from six moves at the first pose."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from drivers.interfaces import MachineTarget
from rtcal.solvers.rtest import (NestCalibration, TrunnionGeometry, calibrate_nest, joint_targets, k_test_sequence,
                                 path_between)
from rtcal.solvers.rtest_fit import RTestPoses, RTestSetup, StatedUncertainty
from simulators.bench import Bench
from simulators.instruments import SimMachineTool, SimNestIndicator
from simulators.scenario import Scenario

AXES = ("x", "y", "z", "a", "c")
NEST_MOVE_MM = 0.5
OVERSHOOT_DEG = 2.0


@dataclass
class SimulatedRTest:
    poses: RTestPoses
    readings_um: np.ndarray
    nest: NestCalibration
    setup: RTestSetup
    truth: dict[str, float]
    truth_setup_um: np.ndarray
    bench: Bench


def linuxcnc_xyzac_inverse(pins: dict[str, float], p: np.ndarray, a_deg: float, c_deg: float) -> np.ndarray:
    """LinuxCNC's xyzacKinematicsInverse (src/emc/kinematics/trtfuncs.c) term by term, tool-offset 0: the
    joints X, Y, Z that put the tool on workpiece point ``p`` at A, C — written from the C source, apart
    from rtcal's model, for the tests that check the kinematics and its compensation against it."""
    xr, yr, zr, dy, dz = (pins[k] for k in ("x-rot-point", "y-rot-point", "z-rot-point", "y-offset", "z-offset"))
    a, c = math.radians(a_deg), math.radians(c_deg)
    x, y, z = p
    return np.array([
        math.cos(c) * (x - xr) - math.sin(c) * (y - yr) + xr,
        math.sin(c) * math.cos(a) * (x - xr) + math.cos(c) * math.cos(a) * (y - yr) - math.sin(a) * (z - zr)
        - math.cos(a) * dy + math.sin(a) * dz + dy + yr,
        math.sin(c) * math.sin(a) * (x - xr) + math.cos(c) * math.sin(a) * (y - yr) + math.cos(a) * (z - zr)
        - math.sin(a) * dy - math.cos(a) * dz + dz + zr])


def _joints(row: np.ndarray) -> dict[str, float]:
    return {a: float(v) for a, v in zip(AXES, row)}


def stated_for(scenario: Scenario, **overrides: float) -> StatedUncertainty:
    """What a procedure would state for this machine: the scenario's noise and certificate values, and
    the bounds its truth lies within (the defaults of StatedUncertainty where the scenario is silent)."""
    m = scenario.machine
    assert m is not None
    values = {"sensor_noise_um": m.nest.noise_um, "sensor_resolution_um": m.nest.resolution_um,
              "sphere_form_um": m.sphere.form_um, "linear_repeatability_um": m.linear_axes.repeatability_um}
    values.update(overrides)
    return StatedUncertainty(**values)


def run(scenario: Scenario, c_angles_deg: Sequence[float] = tuple(range(0, 360, 30)), tilt_deg: float | None = 45.0,
        a_angles_deg: Sequence[float] = (-90, -60, -30, 0, 30, 60, 90), seed: int = 0, both_directions: bool = True,
        sphere: int = 0) -> SimulatedRTest:
    bench = Bench(scenario, seed=seed)
    machine = SimMachineTool(bench, inject=False)
    nest = [SimNestIndicator(bench, i, inject=False) for i in range(3)]
    spec = scenario.machine
    assert spec is not None
    machine.machine.mounted = sphere
    geometry = TrunnionGeometry(spec.kinematics.c_point_mm, spec.kinematics.a_point_mm)
    sph = np.array(spec.sphere.positions_mm[sphere], float)
    offset = tuple(spec.nest.offset_mm)
    start = joint_targets(geometry, sph, [0.0], [0.0], offset)[0]
    above = start.copy()
    above[2] += 20.0
    machine.move_to(MachineTarget(_joints(above)))
    machine.move_to(MachineTarget(_joints(start)))

    def read() -> np.ndarray:
        return np.array([n.read_um() for n in nest])

    moves = np.array([[0, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float) * NEST_MOVE_MM
    cal = []
    for mv in moves:
        machine.move_to(MachineTarget(_joints(start + np.concatenate([mv, [0, 0]]))))
        cal.append(read())
    nest_cal = calibrate_nest(moves, np.array(cal), float(np.hypot(spec.nest.noise_um, spec.nest.resolution_um / 12**0.5)))
    machine.move_to(MachineTarget(_joints(start)))
    joints, dirs, times, readings = [], [], [], []
    a_here, c_here = 0.0, 0.0
    for a, c, d in k_test_sequence(c_angles_deg, tilt_deg, a_angles_deg, both_directions):
        legs = []
        if c != c_here and (1 if c > c_here else -1) != d or (c == c_here and d != machine.machine.c_direction):
            legs.append((a_here, c - d * OVERSHOOT_DEG))
        legs.append((a, c))
        via: list[dict[str, float]] = []
        at = (a_here, c_here)
        for leg in legs:
            via += [_joints(r) for r in path_between(geometry, sph, at, leg, offset, max_step_deg=0.5)]
            at = leg
        target = via.pop()
        machine.move_to(MachineTarget(target, tuple(via)))
        a_here, c_here = a, c
        joints.append([target[k] for k in AXES])
        dirs.append(machine.machine.c_direction)
        times.append(bench.clock.now_s())
        readings.append(read())
    n = len(joints)
    poses = RTestPoses.of(np.array(joints), [0] * n, dirs, times)
    setup = RTestSetup(geometry, sph[None, :], offset, (0, n - 1), spec.nest.flat_radius_mm)
    return SimulatedRTest(poses, np.array(readings), nest_cal, setup, machine.machine.truth_location_errors(),
                          machine.machine.truth_setup_offsets_um()[sphere], bench)


# -- hidden benches: random truths of realistic size, the stated uncertainty as the procedure would give it
STATED = StatedUncertainty(sensor_noise_um=0.1, sensor_resolution_um=0.1, sphere_form_um=0.25, nest_zero_um=1.0,
                           linear_scale_ppm=3.0, linear_squareness_arcsec=2.0, linear_repeatability_um=0.2,
                           drift_nonlinearity=0.25)


SYSTEMATICS = 9  # the stated systematic inputs a bench draws: 3 scales, 3 squarenesses, the nest zero's 3


def hidden_bench(rng: np.random.Generator, stated: StatedUncertainty = STATED, systematics: np.ndarray | None = None) -> Scenario:
    """A machine with location errors of tens of µm and tens of arcsec (1σ 20 each), C's positioning
    deviation (harmonics 1–3, up to 10″) and a reversal up to 6″, its linear axes and nest zero as the
    statement says they may be (``systematics``: 9 standard normal deviates — X, Y, Z scales, XY, XZ, YZ
    squarenesses, the nest zero's x, y, z — drawn here if not given), a sphere of the stated form set up
    within ±50 µm, nest directions off by 1° (and faces tilted 0.5°) that the calibration must find, a
    warming drift of a few µm."""
    z = rng.standard_normal(SYSTEMATICS) if systematics is None else np.asarray(systematics, float)
    loc = {"X0C_um": 20, "Y0C_um": 20, "Y0A_um": 20, "Z0A_um": 20, "A0C_arcsec": 20, "B0C_arcsec": 20,
           "B0A_arcsec": 20, "C0A_arcsec": 20}
    return Scenario.model_validate({"machine": {
        "location_errors": {k: float(s * rng.standard_normal()) for k, s in loc.items()},
        "c_positioning_error": [{"order": o, "amplitude_arcsec": float(rng.uniform(-10, 10) / o),
                                 "phase_deg": float(rng.uniform(0, 360))} for o in (1, 2, 3)],
        "c_reversal_arcsec": float(rng.uniform(0, 6)),
        "linear_axes": {"scale_error_ppm": [float(v) for v in stated.linear_scale_ppm * z[:3]],
                        "squareness_xy_arcsec": float(stated.linear_squareness_arcsec * z[3]),
                        "squareness_xz_arcsec": float(stated.linear_squareness_arcsec * z[4]),
                        "squareness_yz_arcsec": float(stated.linear_squareness_arcsec * z[5]),
                        "repeatability_um": stated.linear_repeatability_um},
        "sphere": {"form_um": stated.sphere_form_um,
                   "setup_offsets_um": [[float(v) for v in rng.uniform(-50, 50, 3)]]},
        "nest": {"direction_error_deg": 1.0, "face_tilt_deg": 0.5, "noise_um": stated.sensor_noise_um,
                 "resolution_um": stated.sensor_resolution_um,
                 "zero_error_um": [float(v) for v in stated.nest_zero_um * z[6:9]]},
        "drift": {"amplitude_um": [float(v) for v in rng.normal(0, 3, 3)], "time_constant_s": float(rng.uniform(600, 3600))},
    }, "seed": int(rng.integers(2**31))})


def monte_carlo(trials: int, seed: int = 2026, stated: StatedUncertainty = STATED,
                balanced: bool = False) -> dict[str, dict[str, np.ndarray]]:
    """Per location error: the errors (estimate − truth) and the reported u of each trial. ``balanced``: the
    stated systematic inputs drawn in moment-matched antithetic pairs (rtcal.planning.montecarlo's
    balanced_normals, as `rtcal uncertainty --balanced`), so that they add no sampling noise to the RMS of
    the errors (an even number of trials, at least 18)."""
    from rtcal.planning.montecarlo import balanced_normals
    from rtcal.solvers.rtest import LOCATION_SYMBOLS
    from rtcal.solvers.rtest_fit import solve_rtest

    rng = np.random.default_rng(seed)
    draws = balanced_normals(trials // 2, SYSTEMATICS, rng) if balanced else [None] * trials
    errors: dict[str, list[float]] = {s: [] for s in LOCATION_SYMBOLS}
    us: dict[str, list[float]] = {s: [] for s in LOCATION_SYMBOLS}
    for k in range(trials):
        scenario = hidden_bench(rng, stated, draws[k])
        sim = run(scenario, seed=scenario.seed)
        result = solve_rtest(sim.poses, sim.readings_um, sim.setup, sim.nest, stated)
        for s in LOCATION_SYMBOLS:
            errors[s].append(result.location[s].value - sim.truth[s])
            us[s].append(result.location[s].u)
    return {s: {"error": np.array(errors[s]), "u": np.array(us[s])} for s in LOCATION_SYMBOLS}
