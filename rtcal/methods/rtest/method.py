"""The R-test as rtcal's third method, written against ``rtcal.api`` alone (and ``rtcal.solvers`` for its
mathematics): the location errors of a trunnion table's two rotary axes (ISO 230-7) from a sphere and a nest of
three sensors, the machine moving through the ISO 10791-6 kinematic tests by its own kinematics. docs/rtest.md."""

from __future__ import annotations

from typing import Any

import numpy as np

from rtcal import api
from rtcal.methods.rtest import analysis
from rtcal.methods.rtest.outputs import RTestOutputs
from rtcal.methods.rtest.plan import CONTEXT, ROTARY_TOLERANCE_DEG, RTestPlan, calibration_moves_mm
from rtcal.methods.rtest.procedure import NAME, NEST, RTestTrunnion
from rtcal.methods.rtest.results import RTestAnalysis, RTestResults
from rtcal.solvers.rtest import joint_targets
from rtcal.solvers.rtest_fit import RTestPoses, RTestPrediction, nominal_nest, predict_rtest

# the simulated nest's nominal directions when the procedure leaves them zero: three at 120° round Z, 35.26° from it
_TILT = np.arctan(np.sqrt(2.0))


def nominal_directions(proc: RTestTrunnion) -> np.ndarray:
    d = np.array(proc.nest.directions, float)
    if np.any(np.linalg.norm(d, axis=1) == 0):
        az = np.radians([0.0, 120.0, 240.0])
        d = np.column_stack([np.sin(_TILT) * np.cos(az), np.sin(_TILT) * np.sin(az), -np.cos(_TILT) * np.ones(3)])
    return d


def predict(proc: RTestTrunnion) -> RTestPrediction:
    """Before anything moves: each location error's U (k = 2) and what the plan cannot determine."""
    poses, spheres = proc.poses(), proc.pose_spheres()
    positions = proc.sphere.positions()
    J = np.zeros((len(poses), 5))
    for j, where in enumerate(positions):
        mine = np.array(spheres) == j
        J[mine] = joint_targets(proc.kinematics.geometry(), where, np.array([a for a, _, _ in poses])[mine],
                                np.array([c for _, c, _ in poses])[mine], proc.nest.offset_mm)
    rp = RTestPoses.of(J, spheres, [d for _, _, d in poses], [10.0 * k for k in range(len(poses))])
    stated = proc.stated()
    nest = nominal_nest(nominal_directions(proc), calibration_moves_mm(proc), stated.reading_sigma_um())
    return predict_rtest(rp, analysis.setup_of(proc), nest, stated)


class RTestPlanner:
    """What `rtcal plan` says of an R-test: no lever to vary (yet); its notes are the prediction."""

    def levers(self, plan: Any, proc: RTestTrunnion, max_radius_mm: float | None = None) -> list[Any]:
        return []

    def candidates(self, *args: Any, **kwargs: Any) -> list[Any]:
        return []

    def notes(self, proc: RTestTrunnion) -> list[str]:
        p = predict(proc)
        lines = ["predicted U (k = 2) of each location error: " + ", ".join(
            f"{s.split('_')[0]} {u:.2f} {'µm' if s.endswith('_um') else '″'}" for s, u in p.U.items())]
        for s, why in {**p.identifiability.refused, **p.identifiability.structural}.items():
            lines.append(f"not determined with this set-up: {s.split('_')[0]}: {why}")
        return lines


class RTestMethod(api.MethodBase):
    name = NAME
    procedure_model = RTestTrunnion
    results_model = RTestResults
    estimators = ("rtest",)
    positioning_deviation = False  # location errors (µm, ″) and C's deviation as a quantity of its own
    operator_steps = True  # the sphere and the nest
    context_columns = CONTEXT
    planner = RTestPlanner()

    def plan(self, proc: RTestTrunnion, done: set[int], generation: int = 0, stage_step_deg: float = 0.0) -> RTestPlan:
        return RTestPlan(proc, done, generation)

    def sim_instruments(self, proc: RTestTrunnion, bench: api.SimBench) -> api.Instruments:
        return api.Instruments({"machine": api.simulated_instrument(bench, "machine_tool"),
                                **{name: api.simulated_nest_indicator(bench, i) for i, name in enumerate(NEST)}})

    def scenario_problem(self, proc: RTestTrunnion, scenario: api.Scenario) -> tuple[tuple[str, ...], str] | None:
        if scenario.machine is None:
            return ("bench",), "the bench's scenario has no `machine:` (the trunnion machine, its sphere and nest)"
        n = len(proc.sphere.positions())
        if len(scenario.machine.sphere.positions_mm) < n:
            return (("sphere", "second_position_mm"), f"the bench's scenario sets the sphere up at "
                    f"{len(scenario.machine.sphere.positions_mm)} position(s) (machine.sphere.positions_mm), the "
                    f"procedure tests {n}: give the scenario the second position")
        return None

    def analyse(self, proc: RTestTrunnion, store: api.RunReadings, bench: api.SimBench | None,
                estimate_noise: bool = True) -> RTestAnalysis:
        truth = ecc = None
        if bench is not None:
            truth = api.true_location_errors(bench)
            keys = sorted({(float(c), int(d)) for _, c, d in proc.poses()})
            first = api.true_c_deviation_arcsec(bench, *keys[0])
            ecc = [api.true_c_deviation_arcsec(bench, c, d) - first for c, d in keys]
        return analysis.analyse(proc, store, truth, ecc)

    def checks_text(self, proc: RTestTrunnion) -> list[str]:
        return [f"the control reported A and C within {ROTARY_TOLERANCE_DEG:g}° of each command before the sensors were "
                "read; the nest calibration's residuals and the adjustment's χ² test against the stated noise"]

    def instrument_roles(self, results: api.RunResults) -> dict[str, str]:
        return {"machine": "the item: the machine's rotary axes, moved by its control's kinematics",
                **{n: "measuring instrument: a sensor of the R-test's nest" for n in NEST}}

    def outputs(self, results: api.RunResults) -> RTestOutputs:
        if not isinstance(results, RTestResults):
            raise TypeError(f"R-test outputs need its results, not {type(results).__name__}")
        return RTestOutputs(results)
