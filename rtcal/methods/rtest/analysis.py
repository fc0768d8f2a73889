"""The R-test's analysis: the readings that count → the nest calibration (its seven positions) → the kinematic
tests' poses and readings → the adjustment (rtcal.solvers.rtest_fit: the location errors, the sphere's set-up, C's
positioning deviation, each with its budget, the residual test and the identifiability check) → the results."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rtcal import api
from rtcal.methods.rtest.plan import JOINTS, SENSOR, calibration_moves_mm
from rtcal.methods.rtest.procedure import FORMATS, NEST, RTestTrunnion
from rtcal.methods.rtest.results import (LocationError, NestCalibrationResult, RTestAnalysis, RTestEstimates, RTestTruth,
                                         SecondPosition, SpherePath, SphereUsed)
from rtcal.solvers.rtest import LOCATION_SYMBOLS, NestCalibration, calibrate_nest
from rtcal.solvers.rtest_fit import RTestPoses, RTestResult, RTestSetup, solve_rtest

AXIS = {"X0C_um": "C", "Y0C_um": "C", "A0C_arcsec": "C", "B0C_arcsec": "C", "Y0A_um": "A", "Z0A_um": "A",
        "B0A_arcsec": "A", "C0A_arcsec": "A"}


@dataclass(frozen=True)
class RTestData:
    """Per planned reading (plan index order): the joints the control reported (N, 5), the three sensors (N, 3) µm,
    when the joints were read (s); NaN where nothing counts."""

    joints: np.ndarray
    readings_um: np.ndarray
    time_s: np.ndarray


def dataset(store: api.RunReadings, n: int) -> RTestData:
    joints, readings, t = np.full((n, 5), np.nan), np.full((n, 3), np.nan), np.full(n, np.nan)
    for j, field in enumerate(JOINTS):
        for r in store.counted("machine", field, whole_only=True):
            if r.plan_index is not None and r.plan_index < n:
                joints[r.plan_index, j] = r.value
                t[r.plan_index] = r.t_s
    for i, name in enumerate(NEST):
        for r in store.counted(name, SENSOR, whole_only=True):
            if r.plan_index is not None and r.plan_index < n:
                readings[r.plan_index, i] = r.value
    return RTestData(joints, readings, t)


def setup_of(proc: RTestTrunnion) -> RTestSetup:
    """The solver's set-up: one sphere set-up per position, each with its own drift pair."""
    x, y, z = proc.nest.offset_mm
    pairs = proc.drift_pairs()
    return RTestSetup(proc.kinematics.geometry(), np.array(proc.sphere.positions(), float), (x, y, z),
                      pairs[0] if len(pairs) == 1 else None, proc.nest.flat_radius_mm,
                      pairs if len(pairs) > 1 else ())


def nest_calibration(proc: RTestTrunnion, data: RTestData) -> NestCalibration:
    moves = calibration_moves_mm(proc)
    m = data.readings_um[:len(moves)]
    if np.isnan(m).any():
        raise api.DataContradiction("the nest calibration lacks readings: the run did not take its seven positions whole")
    return calibrate_nest(moves, m, proc.stated().reading_sigma_um())


def solve(proc: RTestTrunnion, data: RTestData) -> tuple[NestCalibration, RTestResult]:
    """The nest calibration, then the adjustment of the kinematic tests (every pose must count: the drift pair and
    the model's poses are the plan's)."""
    nest = nest_calibration(proc, data)
    k0 = len(calibration_moves_mm(proc))
    poses = proc.poses()
    J, m, t = data.joints[k0:], data.readings_um[k0:], data.time_s[k0:]
    missing = [i for i in range(len(poses)) if np.isnan(J[i]).any() or np.isnan(m[i]).any()]
    if missing:
        raise api.DataContradiction(f"{len(missing)} poses of the kinematic tests have no whole reading (the first: pose "
                                    f"{missing[0] + 1}): resume the run to take them")
    rp = RTestPoses.of(J, proc.pose_spheres(), [d for _, _, d in poses], [float(v) for v in t])
    return nest, solve_rtest(rp, m, setup_of(proc), nest, proc.stated())


def _round(x: float, digits: int = 4) -> float:
    return round(float(x), digits)


def analyse(proc: RTestTrunnion, store: api.RunReadings, truth: dict[str, float] | None,
            true_ecc: list[float] | None) -> RTestAnalysis:
    n = len(calibration_moves_mm(proc)) + len(proc.poses())
    data = dataset(store, n)
    nest, result = solve(proc, data)
    location = {s: LocationError(axis=AXIS[s], value=_round(p.value), standard_uncertainty=_round(p.u),
                                 expanded_uncertainty=_round(p.U), budget={k: _round(v) for k, v in p.budget.items()})
                for s, p in result.location.items()}
    ident = result.identifiability
    not_determined = {**{s: why for s, why in ident.refused.items()}, **{s: why for s, why in ident.structural.items()}}
    keys = sorted(result.ecc)
    ecc = [result.ecc[k] for k in keys]
    sources = [api.QuantitySource(src, "B", 0.0, "arcsec", [p.budget.get(src, 0.0) for p in ecc])
               for src in sorted({s for p in ecc for s in p.budget})]
    estimate = api.quantity_estimate("angular positioning deviation of C", "″", [c for c, _ in keys], [d for _, d in keys],
                                     [p.value for p in ecc], sources,
                                     ["C's angular zero (its constant): not separable from the sphere's azimuth"],
                                     api.with_residual_test("Gauss–Newton on the exact rotations", result.residual_test))
    found, status = api.run_estimators({"rtest": lambda: estimate})
    poses = proc.poses()
    rows = result.fitted_poses if len(result.fitted_poses) else np.arange(len(poses))

    def norm(a: np.ndarray) -> list[float]:
        return [_round(v, 3) for v in np.linalg.norm(np.asarray(a), axis=1)]
    path = SpherePath(a_deg=[poses[int(i)][0] for i in rows], c_deg=[poses[int(i)][1] for i in rows],
                      before_um=norm(result.before_um), after_um=norm(result.after_um), residual_um=norm(result.residual_um))
    sx, sy, sz = result.setup_offsets[0]
    second = None
    if proc.sphere.second_position_mm is not None:
        s2 = result.setup_offsets[1]
        second = SecondPosition(position_mm=list(proc.sphere.second_position_mm),
                                setup_um=[_round(p.value) for p in s2], setup_u_um=[_round(p.u) for p in s2],
                                drift_um=[_round(v) for v in result.drifts_um[1]])
    rtruth = None
    if truth is not None:
        rtruth = RTestTruth(location_errors={s: _round(truth[s], 6) for s in LOCATION_SYMBOLS},
                            cumulative_deviation_arcsec=[_round(v, 6) for v in (true_ecc or [])])
    return RTestAnalysis(
        nominal_angles_deg=[float(c) for c in proc.tests.c_angles_deg], raw_readings=len(store.done_plan_indices()),
        recommended=api.choose_recommended(found, status), solver_status=status, estimates=RTestEstimates(**found),
        truth=rtruth, location_errors=location, not_determined=not_determined,
        nest_calibration=NestCalibrationResult(
            matrix=[[_round(v, 6) for v in row] for row in nest.matrix],
            direction_u_deg=[_round(v, 6) for v in nest.direction_u_deg()],
            residual_rms_um=_round(float(np.sqrt(np.mean(nest.residual_um**2))), 5), move_mm=proc.nest.calibration.move_mm),
        drift_um=[_round(v) for v in result.drift_um], sphere_setup_um=[_round(p.value) for p in (sx, sy, sz)],
        sphere_setup_u_um=[_round(p.u) for p in (sx, sy, sz)], sphere_path=path,
        residual_test=api.residual_test(result.residual_test), linearisation_um=_round(result.linearisation_um, 6),
        sphere=SphereUsed(radius_mm=proc.sphere.certificate.radius_mm, form_um=proc.sphere.certificate.form_um,
                          certificate=proc.sphere.certificate.number, position_mm=list(proc.sphere.position_mm),
                          second=second),
        control_records={fmt: proc.control_record(fmt) for fmt in FORMATS})
