"""What `rtcal plan` may vary in a laser-tracer multi-station plan (the method's ``planner``): each lever
as a change of the candidate's YAML data, and the combinations the search for a target U tries
(rtcal/planning/levers.py runs the search; the machine time of a candidate is its caller's walk)."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any, Callable

import numpy as np

from rtcal.methods.multistation.procedure import EnvironmentUncertainty, GridPlan, LaserTracerMultistation
from rtcal.api import Candidate


# -- the multi-station method's levers ---------------------------------------------------------------------
def _tracer_polar(data: dict[str, Any], proc: LaserTracerMultistation) -> tuple[np.ndarray, float, float, float]:
    """(axis point, radius, angle, height) of the nominal tracer centre at the first station: as a lever
    already set it in ``data``, else as the procedure has it."""
    axis = np.array(proc.solver.axis_point_mm, float)
    guess = np.array(data.get("solver", {}).get("first_station_guess_mm") or proc.solver.first_station_guess_mm, float)
    rel = guess[:2] - axis[:2]
    return axis, float(np.hypot(*rel)), float(np.arctan2(rel[1], rel[0])), float(guess[2])


def _at(axis: np.ndarray, radius: float, angle: float, height: float) -> list[float]:
    return [round(float(axis[0] + radius * math.cos(angle)), 4), round(float(axis[1] + radius * math.sin(angle)), 4),
            round(height, 4)]


def tracer_radius(plan: Candidate, proc: LaserTracerMultistation, factor: float) -> Candidate:
    """The tracer (and a second mount) ``factor`` times as far from the axis, in the procedure and on the bench."""
    axis, radius, angle, height = _tracer_polar(plan.procedure, proc)
    data, bench = copy.deepcopy(plan.procedure), copy.deepcopy(plan.bench)
    data.setdefault("solver", {})["first_station_guess_mm"] = _at(axis, radius * factor, angle, height)
    tracer = bench["laser_tracer"]
    tracer["mount"] = {**tracer["mount"], "radius_mm": round(tracer["mount"]["radius_mm"] * factor, 3)}
    if data.get("second_mount") and tracer.get("second_mount"):
        g = np.array(data["second_mount"]["first_station_guess_mm"], float)
        data["second_mount"] = {"first_station_guess_mm": [round(float(axis[0] + (g[0] - axis[0]) * factor), 4),
                                                           round(float(axis[1] + (g[1] - axis[1]) * factor), 4), float(g[2])]}
        tracer["second_mount"] = {**tracer["second_mount"], "radius_mm": round(tracer["second_mount"]["radius_mm"] * factor, 3)}
    return Candidate(data, bench, plan.changes + (f"tracer {radius * factor:.0f} mm from the axis (×{factor:.3g})",))


def second_mount(plan: Candidate, proc: LaserTracerMultistation) -> Candidate:
    """A second tracer mount opposite the first (same radius and height, 180° round the table): the plan
    is measured from both, and the network separates the error motions from the rotation. Opposite,
    because a rotation then moves the two mounts in opposite directions while a translation moves them
    alike; the tilt about the line joining them, which two mounts cannot see, moves both alike too."""
    data, bench = copy.deepcopy(plan.procedure), copy.deepcopy(plan.bench)
    axis, radius, angle, height = _tracer_polar(data, proc)
    data["second_mount"] = {"first_station_guess_mm": _at(axis, radius, angle + math.pi, height)}
    tracer = bench["laser_tracer"]
    mount = tracer["mount"]
    tracer["second_mount"] = {"radius_mm": mount["radius_mm"], "azimuth_deg": (mount["azimuth_deg"] + 180.0 + 180.0) % 360.0 - 180.0,
                              "height_mm": mount["height_mm"]}
    return Candidate(data, bench, plan.changes + ("a second tracer mount opposite the first",))


def point_layers(plan: Candidate, layers: int) -> Candidate:
    data = copy.deepcopy(plan.procedure)
    points = data.setdefault("points", {"kind": "grid"})
    old = int(points.get("layers", GridPlan().layers))
    points["layers"] = layers
    n = layers * int(points.get("columns", GridPlan().columns)) * int(points.get("rows", GridPlan().rows))
    return Candidate(data, plan.bench, plan.changes + (f"{n} CMM points ({layers} layers instead of {old})",))


def more_stations(plan: Candidate, proc: LaserTracerMultistation) -> Candidate:
    data = copy.deepcopy(plan.procedure)
    st = proc.stations
    data["stations"] = {**data.get("stations", {}), "step_deg": st.step_deg / 2, "count": 2 * st.count - 1}
    return Candidate(data, plan.bench, plan.changes + (f"{2 * st.count - 1} stations, {st.step_deg / 2:g}° apart (the same span: "
                                                  "every target kept, one between each)",))


def more_samples(plan: Candidate, samples: int, note: str = "") -> Candidate:
    data = copy.deepcopy(plan.procedure)
    data["samples_per_reading"] = samples
    return Candidate(data, plan.bench, plan.changes + (f"{samples} samples per reading{note}",))


def environment_sensor(plan: Candidate, proc: LaserTracerMultistation) -> Candidate:
    """An environment sensor read with every length (on the bench; on real instruments its address is the
    lab's to give, so the proposal never adds one there)."""
    data = copy.deepcopy(plan.procedure)
    data.setdefault("instruments", {})["environment"] = (
        {"backend": "sim"} if proc.instruments.all_sim() else {"address": "socket://ADDRESS-OF-THE-SENSOR:4001?model=vaisala-ptu300"})
    sensor = EnvironmentUncertainty()
    data.setdefault("uncertainty", {})["environment"] = sensor.model_dump()
    return Candidate(data, plan.bench, plan.changes + (
        f"an environment sensor ({sensor.air_temperature_k:g} K, {sensor.air_pressure_pa:g} Pa, {sensor.humidity_pct:g} % RH, "
        "1σ): each length corrected for the air of its moment" + ("" if proc.instruments.all_sim() else " (give its address)"),))


SAMPLE_NOTE = " (each sample the time `durations.tracer_sample_s` states)"


def station_major(plan: Candidate) -> Candidate:
    """For each station the CMM visits every point: the table turns once per station instead of stepping
    through every station and back over its whole span after every point. Each station is then one visit, so the stage's repeatability is no longer
    averaged over the points' visits (the budget says so: its term grows)."""
    data = copy.deepcopy(plan.procedure)
    data["order"] = "station_major"
    return Candidate(data, plan.bench, plan.changes + ("station-major order (for each station, every point)",))


def concurrent_motions(plan: Candidate) -> Candidate:
    """The table and the CMM start together where both move (the engine's ``Parallel``): time only."""
    data = copy.deepcopy(plan.procedure)
    data["concurrent_motions"] = True
    return Candidate(data, plan.bench, plan.changes + ("the table and the CMM moving together",))


def shortest_point_path(plan: Candidate) -> Candidate:
    """Every other grid layer walked backwards: the CMM rises straight to the next layer instead of crossing
    back to the first corner (each move one grid step: the shortest path through the grid). Time only."""
    data = copy.deepcopy(plan.procedure)
    data.setdefault("points", {"kind": "grid"})["layer_order"] = "alternate"
    return Candidate(data, plan.bench, plan.changes + ("the CMM's shortest path through the points (every other layer "
                                                  "backwards)",))


def stated_expansion(plan: Candidate, alpha_ppm_per_k: float) -> Candidate:
    """The table's expansion coefficient stated, so the lengths are corrected for the table's growth about
    the axis with the temperature the sensor reads (its standard uncertainty 10 % of it). The value is the
    bench's: the lab's model of its table, to be checked against the table's own."""
    data = copy.deepcopy(plan.procedure)
    u = data.setdefault("uncertainty", {})
    u["table_expansion_ppm_per_k"] = alpha_ppm_per_k
    u["table_expansion_u_ppm_per_k"] = round(0.1 * alpha_ppm_per_k, 4)
    return Candidate(data, plan.bench, plan.changes + (
        f"the table's expansion stated, {alpha_ppm_per_k:g} ± {0.1 * alpha_ppm_per_k:.3g} ppm/K (the bench's: state "
        "your table's): each length corrected for its growth with the temperature the sensor reads",))


def expansion_to_state(plan: Candidate, proc: LaserTracerMultistation) -> float:
    """The bench's expansion coefficient when the table grows, a sensor reads its temperature and the
    procedure states none (else 0: nothing to state, or no temperature to correct with)."""
    alpha = float(plan.bench.get("stage", {}).get("thermal_expansion_ppm_per_k") or 0.0)
    sensor = proc.instruments.environment is not None or "environment" in plan.procedure.get("instruments", {})
    return alpha if alpha > 0 and sensor and proc.uncertainty.table_expansion_ppm_per_k == 0 else 0.0


def radius_factors(plan: Candidate, proc: LaserTracerMultistation, max_radius_mm: float | None) -> list[float]:
    """How much further from the axis the tracer may go: ×1.5 and ×2 by default, else up to the furthest allowed."""
    _, radius, _, _ = _tracer_polar(plan.procedure, proc)
    if max_radius_mm is None:
        return [1.5, 2.0]
    furthest = max_radius_mm / radius
    return sorted({round(f, 4) for f in (min(1.5, furthest), furthest) if f > 1.0 + 1e-9})


class MultistationPlanner:
    """What `rtcal plan` may vary in a laser-tracer multi-station plan (the method's ``planner``)."""

    def levers(self, plan: Candidate, proc: LaserTracerMultistation, max_radius_mm: float | None) -> list[Candidate]:
        out: list[Candidate] = []
        if proc.second_mount is None:
            out.append(second_mount(plan, proc))
        out += [tracer_radius(plan, proc, f) for f in radius_factors(plan, proc, max_radius_mm)]
        if isinstance(proc.points, GridPlan):
            layers = proc.points.layers
            out += [point_layers(plan, n) for n in sorted({max(layers // 2, 2), 2 * layers}) if n != layers]
        out.append(more_stations(plan, proc))
        out.append(more_samples(plan, 4 * proc.samples_per_reading, SAMPLE_NOTE))
        if proc.instruments.environment is None:
            out.append(environment_sensor(plan, proc))
        if proc.order == "point_major":
            out.append(station_major(plan))
        if not proc.concurrent_motions:
            out.append(concurrent_motions(plan))
        if isinstance(proc.points, GridPlan) and proc.points.layers > 1 and proc.points.layer_order == "same":
            out.append(shortest_point_path(plan))
        alpha = expansion_to_state(plan, proc)
        if alpha > 0:
            out.append(stated_expansion(plan, alpha))
        return out

    def notes(self, proc: LaserTracerMultistation) -> list[str]:
        notes = []
        if proc.second_mount is not None:
            notes.append("second mount: in the plan")
        if proc.instruments.environment is not None:
            notes.append("environment sensor: in the plan")
        if not isinstance(proc.points, GridPlan):
            notes.append("points: the plan lists them (`--optimize` chooses better ones)")
        notes.append("runs: a multi-station plan is one run; its repetition lever is the samples per reading")
        return notes

    def candidates(self, plan: Candidate, proc: LaserTracerMultistation, max_radius_mm: float | None,
                   chains: dict[int, tuple[Candidate, ...]], duration_s: Callable[[Candidate], float]) -> list[tuple[float, Candidate]]:
        return multistation_candidates(plan, proc, max_radius_mm, duration_s, chains)

    def pruning(self, candidate: Candidate) -> tuple[bool, Any]:
        """(whether the candidate has one mount, whose error motions alone may exclude every one-mount plan;
        the configuration whose budget without the tracer's noise may exclude more samples of it)."""
        return not candidate.procedure.get("second_mount"), _config(candidate)

    def points_refusal(self, path: Path, proc: LaserTracerMultistation) -> str | None:
        return None

    def choose_points(self, path: Path, proc: LaserTracerMultistation, scenario: Any, out: Path,
                      simulate: Callable[[Path, Path, Path], None]) -> str:
        """`rtcal plan --optimize`: CMM points that lower the predicted U (rtcal/methods/multistation/design.py);
        ``simulate(procedure, bench, run_dir)`` runs a procedure on a bench into a run directory."""
        from rtcal.methods.multistation.design import optimize_points

        return optimize_points(path, proc, scenario, out, simulate)


# -- the search ----------------------------------------------------------------------------------------------
SAMPLE_FACTORS = (1, 2, 4)  # samples per reading the search tries, × the procedure's


def multistation_candidates(plan: Candidate, proc: LaserTracerMultistation, max_radius_mm: float | None,
                            duration_s: Callable[[Candidate], float],
                            chains: dict[int, tuple[Candidate, ...]] | None = None) -> list[tuple[float, Candidate]]:
    """(walked machine time, plan) for every combination the search tries (see the module docstring),
    shortest first; ``chains`` (if given) gets each plan's intermediate plans, lever by lever (by ``id``)."""
    factor = max([1.0, *radius_factors(plan, proc, max_radius_mm)])
    mounts = [False] + ([True] if proc.second_mount is None else [])
    layers: list[int | None] = [None]
    grid = isinstance(proc.points, GridPlan)
    if isinstance(proc.points, GridPlan):
        L = proc.points.layers
        layers = [*sorted({max(2, round(L * f)) for f in (0.5, 0.75, 1.0, 1.5, 2.0)})]
    from rtcal.methods.multistation.noise import stated_air_ranges

    sensor = proc.instruments.environment is None and bool(stated_air_ranges(proc)) and proc.instruments.all_sim()
    orders = [False] + ([True] if proc.order == "point_major" else [])
    samples = sorted({proc.samples_per_reading * f for f in SAMPLE_FACTORS if proc.samples_per_reading * f <= 1000})
    out = []
    for two in mounts:
        for n_layers in layers:
            for major in orders:
                for n_samples in samples:
                    chain = [plan]

                    def step(lever: Callable[[Candidate], Candidate]) -> None:
                        chain.append(lever(chain[-1]))

                    if two:
                        step(lambda p: second_mount(p, proc))
                    if factor > 1.0:
                        step(lambda p: tracer_radius(p, proc, factor))
                    if n_layers is not None and n_layers != getattr(proc.points, "layers", None):
                        step(lambda p: point_layers(p, n_layers))
                    if major:
                        step(station_major)
                    if not proc.concurrent_motions:
                        step(concurrent_motions)
                    if grid and (n_layers or 0) > 1 and getattr(proc.points, "layer_order", "same") == "same":
                        step(shortest_point_path)
                    if n_samples != proc.samples_per_reading:
                        step(lambda p: more_samples(p, n_samples))
                    if sensor:
                        step(lambda p: environment_sensor(p, proc))
                    alpha = expansion_to_state(chain[-1], proc)
                    if alpha > 0:
                        step(lambda p: stated_expansion(p, alpha))
                    if chains is not None:
                        chains[id(chain[-1])] = tuple(chain)
                    out.append((round(duration_s(chain[-1]), 1), chain[-1]))
    return sorted(out, key=lambda c: c[0])


def _config(plan: Candidate) -> tuple[bool, Any, str]:
    """What fixes a plan's budget apart from its samples per reading: mounts, points, order."""
    d = plan.procedure
    return bool(d.get("second_mount")), d.get("points", {}).get("layers"), str(d.get("order", "point_major"))
