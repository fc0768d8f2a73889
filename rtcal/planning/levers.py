"""`rtcal plan`: what a plan's uncertainty is made of, what each lever of its method would do, and
the shortest plan that reaches a target uncertainty.

A *plan* is a procedure's YAML data with its bench's (the simulated table, tracer and CMM the
prediction runs on). A lever changes both where the physical setup changes (a second tracer mount,
the tracer further from the axis: the bench must have the tracer where the procedure says) and the
procedure alone otherwise (points, stations, samples, runs, an environment sensor). Each plan is
predicted like `rtcal plan` predicts the procedure as written (:func:`rtcal.planning.predict.predict`:
the stated noise on the noise-free bench, the run's simulated clock), so a lever's U and machine time
are those of a procedure that validates and runs.

The search for a target U (:func:`propose`) tries the plans its method offers in order of machine
time and stops at the first group of equally long plans of which one reaches the target; between
plans equally long it takes the smaller U. For the multi-station method the machine time is the
engine's walk of the plan (:func:`walked_duration_s`: motions, settling, every tracer sample and the
operator's steps as `durations:` states them — what the simulated clock counts, without running), and
it combines a second mount, the tracer as far from the axis as allowed, the number of CMM point layers,
the order (point- or station-major), 1, 2 or 4 × the samples per reading, and an environment sensor
(only where the procedure states the air's ranges: a sensor then replaces them); every candidate has
the levers that cost nothing in U (the table and the CMM moving together, the CMM's shortest path
through the grid) and, where the bench's table grows with its temperature and a sensor reads it, the
expansion coefficient stated so that the lengths are corrected. The stations (the certificate's
targets) are left as written. Plans with one mount are skipped once one of them shows that the error
motions alone (a bias no repetition averages) exceed the target at the furthest radius; a
configuration whose U without the tracer's noise exceeds it is not tried with more samples. What each
lever of the proposal buys (seconds and arcseconds, in turn from the procedure as written) is in its
changes and the JSON's ``levers_buy``.
"""

from __future__ import annotations

import copy
import math
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np
import yaml

from rtcal.procedure.models import EncoderAbbeError, EnvironmentUncertainty, GridPlan, LaserTracerMultistation, Procedure

ERROR_MOTION_PREFIX = "error motion"  # the budget's error-motion sources (radial, axial, tilt) start so


@dataclass(frozen=True)
class Plan:
    """A candidate: the procedure's and the bench's YAML data, and what was changed, in words."""

    procedure: dict[str, Any]
    bench: dict[str, Any]
    changes: tuple[str, ...] = ()


@dataclass(frozen=True)
class Outcome:
    """A plan's prediction: the recommended estimator, U (k = 2) at its worst target, the machine time,
    and each source's share of the variance (over the targets)."""

    plan: Plan
    recommended: str | None
    expanded_max_arcsec: float
    duration_s: float
    raw_readings: int
    shares: dict[str, float] = field(default_factory=dict)
    contributions: dict[str, list[float]] = field(default_factory=dict)  # the recommended's budget, 1σ per target
    problem: str = ""  # why the plan could not be predicted (it does not validate, no estimator converged)
    buys: tuple[dict[str, Any], ...] = ()  # a proposal's levers in turn: {lever, seconds, arcsec} each changes

    def summary(self) -> dict[str, Any]:
        """The JSON form of a lever or proposal."""
        changes = [r["lever"] for r in self.buys] if self.buys else list(self.plan.changes)  # the words without the effects
        return {"changes": changes or ["as written"], "recommended": self.recommended,
                "expanded_uncertainty_max_arcsec": _finite(self.expanded_max_arcsec), "duration_s": round(self.duration_s, 1),
                "raw_readings": self.raw_readings,
                "sources_rms_arcsec": {k: round(float(np.sqrt(np.mean(np.square(v[1:])))), 4)
                                       for k, v in self.contributions.items() if len(v) > 1},
                **({"problem": self.problem} if self.problem else {}),
                **({"levers_buy": list(self.buys)} if self.buys else {})}


def _finite(value: float) -> float | None:
    return round(float(value), 4) if math.isfinite(value) else None


def base_plan(procedure_path: Path, scenario) -> Plan:
    from rtcal.procedure.yamlfile import load_yaml, read_text

    data, _ = load_yaml(read_text(procedure_path), str(procedure_path))
    return Plan(data, scenario.model_dump(mode="json"))


def shares_of(contributions: dict[str, list[float | None]], combined: list[float | None]) -> dict[str, float]:
    """Each source's share of the combined variance, summed over the targets after the first (the
    reference, 0 ± 0)."""
    total = sum((c or 0.0) ** 2 for c in combined[1:])
    if total <= 0:
        return {}
    return {name: sum((v or 0.0) ** 2 for v in values[1:]) / total for name, values in contributions.items()}


def evaluate(plan: Plan, workdir: Path | None = None) -> Outcome:
    """Predict ``plan`` (written to a temporary folder: the procedure beside its bench)."""
    from rtcal.planning.predict import predict, simulated
    from rtcal.procedure.loader import load_procedure
    from rtcal.run.runner import AnalysisFailed
    from rtcal.procedure.yamlfile import FileProblems
    from simulators.scenario import Scenario

    tmp = Path(tempfile.mkdtemp(prefix="lever-", dir=workdir))
    try:
        (tmp / "bench.yaml").write_text(yaml.safe_dump(plan.bench, sort_keys=False), encoding="utf-8")
        path = tmp / "procedure.yaml"
        path.write_text(yaml.safe_dump({**simulated(plan.procedure), "bench": "bench.yaml"}, sort_keys=False,
                                       allow_unicode=True), encoding="utf-8")
        try:
            proc = load_procedure(path)
            scenario = Scenario.model_validate(plan.bench)
            p = predict(path, proc, scenario, tmp)
        except (FileProblems, AnalysisFailed, ValueError) as exc:
            return Outcome(plan, None, math.inf, 0.0, 0, problem=str(exc).splitlines()[0].replace(str(tmp) + "/", ""))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    rec = p["recommended"]
    if rec is None:
        return Outcome(plan, None, math.inf, p["measurement_duration_s"], p["raw_readings"], problem="no estimator converged")
    e = p["estimators"][rec]
    expanded = [v for v in e["predicted_expanded_arcsec"][1:] if v is not None]
    return Outcome(plan, rec, max(expanded) if expanded else math.inf, float(p["measurement_duration_s"]), int(p["raw_readings"]),
                   shares_of(e["budget"], e["predicted_sigma_arcsec"]),
                   {k: [v or 0.0 for v in vals] for k, vals in e["budget"].items()})


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


def tracer_radius(plan: Plan, proc: LaserTracerMultistation, factor: float) -> Plan:
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
    return Plan(data, bench, plan.changes + (f"tracer {radius * factor:.0f} mm from the axis (×{factor:.3g})",))


def second_mount(plan: Plan, proc: LaserTracerMultistation) -> Plan:
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
    return Plan(data, bench, plan.changes + ("a second tracer mount opposite the first",))


def point_layers(plan: Plan, layers: int) -> Plan:
    data = copy.deepcopy(plan.procedure)
    points = data.setdefault("points", {"kind": "grid"})
    old = int(points.get("layers", GridPlan().layers))
    points["layers"] = layers
    n = layers * int(points.get("columns", GridPlan().columns)) * int(points.get("rows", GridPlan().rows))
    return Plan(data, plan.bench, plan.changes + (f"{n} CMM points ({layers} layers instead of {old})",))


def more_stations(plan: Plan, proc: LaserTracerMultistation) -> Plan:
    data = copy.deepcopy(plan.procedure)
    st = proc.stations
    data["stations"] = {**data.get("stations", {}), "step_deg": st.step_deg / 2, "count": 2 * st.count - 1}
    return Plan(data, plan.bench, plan.changes + (f"{2 * st.count - 1} stations, {st.step_deg / 2:g}° apart (the same span: "
                                                  "every target kept, one between each)",))


def more_samples(plan: Plan, samples: int, note: str = "") -> Plan:
    data = copy.deepcopy(plan.procedure)
    data["samples_per_reading"] = samples
    return Plan(data, plan.bench, plan.changes + (f"{samples} samples per reading{note}",))


def environment_sensor(plan: Plan, proc: LaserTracerMultistation) -> Plan:
    """An environment sensor read with every length (on the bench; on real instruments its address is the
    lab's to give, so the proposal never adds one there)."""
    data = copy.deepcopy(plan.procedure)
    data.setdefault("instruments", {})["environment"] = (
        {"backend": "sim"} if proc.instruments.all_sim() else {"address": "socket://ADDRESS-OF-THE-SENSOR:4001?model=vaisala-ptu300"})
    sensor = EnvironmentUncertainty()
    data.setdefault("uncertainty", {})["environment"] = sensor.model_dump()
    return Plan(data, plan.bench, plan.changes + (
        f"an environment sensor ({sensor.air_temperature_k:g} K, {sensor.air_pressure_pa:g} Pa, {sensor.humidity_pct:g} % RH, "
        "1σ): each length corrected for the air of its moment" + ("" if proc.instruments.all_sim() else " (give its address)"),))


def more_runs(plan: Plan, runs: int) -> Plan:
    data = copy.deepcopy(plan.procedure)
    data.setdefault("steps", {})["runs"] = runs
    return Plan(data, plan.bench, plan.changes + (f"{runs} runs",))


SAMPLE_NOTE = " (each sample the time `durations.tracer_sample_s` states)"


def station_major(plan: Plan) -> Plan:
    """For each station the CMM visits every point: the table turns once per station instead of stepping
    through every station and back over its whole span after every point. Each station is then one visit, so the stage's repeatability is no longer
    averaged over the points' visits (the budget says so: its term grows)."""
    data = copy.deepcopy(plan.procedure)
    data["order"] = "station_major"
    return Plan(data, plan.bench, plan.changes + ("station-major order (for each station, every point)",))


def concurrent_motions(plan: Plan) -> Plan:
    """The table and the CMM start together where both move (the engine's ``Parallel``): time only."""
    data = copy.deepcopy(plan.procedure)
    data["concurrent_motions"] = True
    return Plan(data, plan.bench, plan.changes + ("the table and the CMM moving together",))


def shortest_point_path(plan: Plan) -> Plan:
    """Every other grid layer walked backwards: the CMM rises straight to the next layer instead of crossing
    back to the first corner (each move one grid step: the shortest path through the grid). Time only."""
    data = copy.deepcopy(plan.procedure)
    data.setdefault("points", {"kind": "grid"})["layer_order"] = "alternate"
    return Plan(data, plan.bench, plan.changes + ("the CMM's shortest path through the points (every other layer "
                                                  "backwards)",))


def stated_expansion(plan: Plan, alpha_ppm_per_k: float) -> Plan:
    """The table's expansion coefficient stated, so the lengths are corrected for the table's growth about
    the axis with the temperature the sensor reads (its standard uncertainty 10 % of it). The value is the
    bench's: the lab's model of its table, to be checked against the table's own."""
    data = copy.deepcopy(plan.procedure)
    u = data.setdefault("uncertainty", {})
    u["table_expansion_ppm_per_k"] = alpha_ppm_per_k
    u["table_expansion_u_ppm_per_k"] = round(0.1 * alpha_ppm_per_k, 4)
    return Plan(data, plan.bench, plan.changes + (
        f"the table's expansion stated, {alpha_ppm_per_k:g} ± {0.1 * alpha_ppm_per_k:.3g} ppm/K (the bench's: state "
        "your table's): each length corrected for its growth with the temperature the sensor reads",))


def expansion_to_state(plan: Plan, proc: LaserTracerMultistation) -> float:
    """The bench's expansion coefficient when the table grows, a sensor reads its temperature and the
    procedure states none (else 0: nothing to state, or no temperature to correct with)."""
    alpha = float(plan.bench.get("stage", {}).get("thermal_expansion_ppm_per_k") or 0.0)
    sensor = proc.instruments.environment is not None or "environment" in plan.procedure.get("instruments", {})
    return alpha if alpha > 0 and sensor and proc.uncertainty.table_expansion_ppm_per_k == 0 else 0.0


def walked_duration_s(plan: Plan) -> float:
    """The plan's machine time as the engine's walker counts it on the plan's bench (no simulation, no
    store: the simulated run's clock counts the same), operator steps included; ∞ when it does not validate."""
    from rtcal.engine.walk import Timing, walk
    from rtcal.planning.predict import simulated
    from rtcal.methods import METHODS
    from rtcal.procedure.loader import load_procedure
    from rtcal.procedure.yamlfile import FileProblems
    from simulators.scenario import Scenario

    text = yaml.safe_dump({k: v for k, v in simulated(plan.procedure).items() if k != "bench"}, sort_keys=False,
                          allow_unicode=True)
    try:
        proc = load_procedure(Path("plan.yaml"), text=text)
        scenario = Scenario.model_validate(plan.bench)
    except (FileProblems, ValueError):
        return math.inf
    return walk(METHODS[proc.method].plan(proc, set()), Timing.of_scenario(scenario)).duration_s


def radius_factors(plan: Plan, proc: LaserTracerMultistation, max_radius_mm: float | None) -> list[float]:
    """How much further from the axis the tracer may go: ×1.5 and ×2 by default, else up to the furthest allowed."""
    _, radius, _, _ = _tracer_polar(plan.procedure, proc)
    if max_radius_mm is None:
        return [1.5, 2.0]
    furthest = max_radius_mm / radius
    return sorted({round(f, 4) for f in (min(1.5, furthest), furthest) if f > 1.0 + 1e-9})


def levers(plan: Plan, proc: Procedure, max_radius_mm: float | None = None) -> list[Plan]:
    """One plan per lever of the procedure's method, each changing one thing (none: the method has no planner)."""
    planner = _planner(proc)
    return planner.levers(plan, proc, max_radius_mm) if planner is not None else []


def lever_notes(proc: Procedure) -> list[str]:
    """Levers the method has that the table does not vary, and why."""
    planner = _planner(proc)
    return planner.notes(proc) if planner is not None else []


def _planner(proc: Procedure) -> Any:
    """The procedure's method's planner (rtcal.methods.protocol.Method.planner), None: it has none."""
    from rtcal.methods import METHODS

    return METHODS[proc.method].planner


class MultistationPlanner:
    """What `rtcal plan` may vary in a laser-tracer multi-station plan (the method's ``planner``)."""

    def levers(self, plan: Plan, proc: LaserTracerMultistation, max_radius_mm: float | None) -> list[Plan]:
        out: list[Plan] = []
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

    def candidates(self, plan: Plan, proc: LaserTracerMultistation, max_radius_mm: float | None,
                   chains: dict[int, tuple[Plan, ...]]) -> list[tuple[float, Plan]]:
        return multistation_candidates(plan, proc, max_radius_mm, chains)

    def pruning(self, candidate: Plan) -> tuple[bool, Any]:
        """(whether the candidate has one mount, whose error motions alone may exclude every one-mount plan;
        the configuration whose budget without the tracer's noise may exclude more samples of it)."""
        return not candidate.procedure.get("second_mount"), _config(candidate)

    def points_refusal(self, path: Path, proc: LaserTracerMultistation) -> str | None:
        return None

    def choose_points(self, path: Path, proc: LaserTracerMultistation, scenario: Any, out: Path) -> str:
        """`rtcal plan --optimize`: CMM points that lower the predicted U (rtcal/planning/design.py)."""
        from rtcal.planning.design import optimize_points

        return optimize_points(path, proc, scenario, out)


class AbbePlanner:
    """What `rtcal plan` may vary in an encoder Abbe-error plan: its runs."""

    def levers(self, plan: Plan, proc: EncoderAbbeError, max_radius_mm: float | None) -> list[Plan]:
        return [more_runs(plan, r) for r in (2 * proc.steps.runs, 5 * proc.steps.runs) if r <= 100]

    def notes(self, proc: EncoderAbbeError) -> list[str]:
        return ["samples per reading: the budget takes each reading's stated noise as it is; runs average it"]

    def candidates(self, plan: Plan, proc: EncoderAbbeError, max_radius_mm: float | None,
                   chains: dict[int, tuple[Plan, ...]]) -> list[tuple[float, Plan]]:
        return [(float(n), p) for n, p in abbe_candidates(plan, proc)]

    def pruning(self, candidate: Plan) -> tuple[bool, Any]:
        return False, None

    def points_refusal(self, path: Path, proc: EncoderAbbeError) -> str | None:
        return f"{path} is a procedure of {proc.method}; choosing CMM points is for laser_tracer_multistation procedures"

    def choose_points(self, path: Path, proc: EncoderAbbeError, scenario: Any, out: Path) -> str:
        raise ValueError(self.points_refusal(path, proc))


# -- the search ----------------------------------------------------------------------------------------------
SAMPLE_FACTORS = (1, 2, 4)  # samples per reading the search tries, × the procedure's
TRACER_NOISE_SOURCE = "tracer length noise"  # the budget's only term that more samples per reading lower


def multistation_candidates(plan: Plan, proc: LaserTracerMultistation, max_radius_mm: float | None,
                            chains: dict[int, tuple[Plan, ...]] | None = None) -> list[tuple[float, Plan]]:
    """(walked machine time, plan) for every combination the search tries (see the module docstring),
    shortest first; ``chains`` (if given) gets each plan's intermediate plans, lever by lever (by ``id``)."""
    factor = max([1.0, *radius_factors(plan, proc, max_radius_mm)])
    mounts = [False] + ([True] if proc.second_mount is None else [])
    layers: list[int | None] = [None]
    grid = isinstance(proc.points, GridPlan)
    if isinstance(proc.points, GridPlan):
        L = proc.points.layers
        layers = [*sorted({max(2, round(L * f)) for f in (0.5, 0.75, 1.0, 1.5, 2.0)})]
    from rtcal.methods.multistation import stated_air_ranges

    sensor = proc.instruments.environment is None and bool(stated_air_ranges(proc)) and proc.instruments.all_sim()
    orders = [False] + ([True] if proc.order == "point_major" else [])
    samples = sorted({proc.samples_per_reading * f for f in SAMPLE_FACTORS if proc.samples_per_reading * f <= 1000})
    out = []
    for two in mounts:
        for n_layers in layers:
            for major in orders:
                for n_samples in samples:
                    chain = [plan]

                    def step(lever: Callable[[Plan], Plan]) -> None:
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
                    out.append((round(walked_duration_s(chain[-1]), 1), chain[-1]))
    return sorted(out, key=lambda c: c[0])


def abbe_candidates(plan: Plan, proc: EncoderAbbeError) -> list[tuple[int, Plan]]:
    runs = sorted({r for r in (proc.steps.runs, 2, 3, 4, 5, 7, 10, 15, 20, 30, 50, 100) if proc.steps.runs <= r <= 100})
    return [(r, plan if r == proc.steps.runs else more_runs(plan, r)) for r in runs]


@dataclass(frozen=True)
class Proposal:
    best: Outcome | None  # the shortest plan that reaches the target (None: none does)
    smallest: Outcome | None  # the smallest U found
    tried: list[Outcome]
    skipped: list[str]


def error_motion_floor(outcome: Outcome) -> float:
    """U (k = 2) the error-motion sources alone give at the worst target."""
    em = [np.array(v) for k, v in outcome.contributions.items() if k.lower().startswith(ERROR_MOTION_PREFIX)]
    if not em:
        return 0.0
    return float(2.0 * np.max(np.sqrt(sum(v**2 for v in em))))


DEFAULT_MARGIN = 0.1


TIME_ONLY = ("the table and the CMM moving together", "the CMM's shortest path")  # levers that change no reading


def _config(plan: Plan) -> tuple[bool, Any, str]:
    """What fixes a plan's budget apart from its samples per reading: mounts, points, order."""
    d = plan.procedure
    return bool(d.get("second_mount")), d.get("points", {}).get("layers"), str(d.get("order", "point_major"))


def floor_without_tracer_noise(outcome: Outcome) -> float:
    """U (k = 2) at the worst target without the tracer's length noise: what no number of samples lowers."""
    rest = [np.array(v) for k, v in outcome.contributions.items() if k != TRACER_NOISE_SOURCE]
    return float(2.0 * np.max(np.sqrt(sum(v**2 for v in rest)))) if rest else 0.0


def what_each_buys(chain: tuple[Plan, ...], final: Outcome, evaluate_plan: Callable[[Plan], Outcome]) -> list[dict[str, Any]]:
    """Each lever of a plan applied in turn from the procedure as written: the machine time (walked) and the
    U (k = 2, worst target; predicted, except for the time-only levers, which change no reading) it changes."""
    rows: list[dict[str, Any]] = []
    u_before = evaluate_plan(chain[0]).expanded_max_arcsec
    t_before = walked_duration_s(chain[0])
    for k, p in enumerate(chain[1:], 1):
        change = p.changes[-1]
        last = k == len(chain) - 1
        u = final.expanded_max_arcsec if last else (
            u_before if change.startswith(TIME_ONLY) else evaluate_plan(p).expanded_max_arcsec)
        t = final.duration_s if last else walked_duration_s(p)
        rows.append({"lever": change, "seconds": round(t - t_before, 1),
                     "arcsec": round(u - u_before, 4) if math.isfinite(u) and math.isfinite(u_before) else None})
        u_before, t_before = u, t
    return rows


def with_buys(outcome: Outcome, rows: list[dict[str, Any]]) -> Outcome:
    """The outcome with each change's effect in its words (the console and the written plan's header show
    the changes) and in ``buys`` (the JSON)."""
    def words(r: dict[str, Any]) -> str:
        u = "" if r["arcsec"] is None else f", {r['arcsec']:+.2f}″"
        return f"{r['lever']} [{r['seconds']:+.0f} s{u}]"
    plan = Plan(outcome.plan.procedure, outcome.plan.bench, tuple(words(r) for r in rows))
    return Outcome(plan, outcome.recommended, outcome.expanded_max_arcsec, outcome.duration_s, outcome.raw_readings,
                   outcome.shares, outcome.contributions, outcome.problem, tuple(rows))


def propose(plan: Plan, proc: Procedure, target_arcsec: float, max_radius_mm: float | None = None,
            margin: float = DEFAULT_MARGIN, evaluate_plan: Callable[[Plan], Outcome] | None = None,
            explain: bool = True) -> Proposal:
    """The shortest plan whose predicted U (k = 2, recommended estimator, worst target) is ≤ the target
    less ``margin`` (a fraction of it). The prediction is linear about the noise-free bench with the noise
    as stated; the margin leaves room for what it does not hold — the noise a run finds in its readings,
    and the sampling of the Monte Carlo (`rtcal uncertainty`) that verifies the proposal, whose RMS error
    per target is known to ±1/√(2N) and whose worst target is the largest of several such estimates.
    Candidates are tried shortest first (the walked machine time); a configuration (mounts, points, order)
    whose U without the tracer's noise already exceeds the goal is not tried with more samples. ``explain``:
    what each of the proposal's levers buys, in turn (a prediction per lever that changes the readings)."""
    goal = target_arcsec * (1.0 - margin)
    evaluate_plan = evaluate_plan or evaluate
    chains: dict[int, tuple[Plan, ...]] = {}
    planner = _planner(proc)
    candidates: list[tuple[float, Plan]] = planner.candidates(plan, proc, max_radius_mm, chains) if planner else []
    tried: list[Outcome] = []
    skipped: list[str] = []
    one_mount_out = False
    floors_out: set[Any] = set()
    group: list[Outcome] = []
    for k, (size, candidate) in enumerate(candidates):
        is_one_mount, config = planner.pruning(candidate)
        if (is_one_mount and one_mount_out) or (config is not None and config in floors_out):
            skipped.append(", ".join(candidate.changes) or "as written")
            continue
        outcome = evaluate_plan(candidate)
        tried.append(outcome)
        if is_one_mount and error_motion_floor(outcome) > goal:
            one_mount_out = True
        if config is not None and floor_without_tracer_noise(outcome) > goal:
            floors_out.add(config)
        if outcome.expanded_max_arcsec <= goal:
            group.append(outcome)
        last_of_size = k + 1 == len(candidates) or candidates[k + 1][0] != size
        if group and last_of_size:
            break
    reached = min(group, key=lambda o: (o.duration_s, o.expanded_max_arcsec)) if group else None
    if explain and reached is not None and id(reached.plan) in chains and len(chains[id(reached.plan)]) > 1:
        reached = with_buys(reached, what_each_buys(chains[id(reached.plan)], reached, evaluate_plan))
    finite = [o for o in tried if math.isfinite(o.expanded_max_arcsec)]
    smallest = min(finite, key=lambda o: o.expanded_max_arcsec) if finite else None
    return Proposal(reached, smallest, tried, skipped)


def format_hours(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 3600 else f"{seconds / 60:.0f} min"


def table_lines(rows: Iterable[tuple[str, Outcome]]) -> list[str]:
    lines = [f"  {'U max (k = 2)':>13}  {'machine time':>12}  lever"]
    for label, o in rows:
        u = f"{o.expanded_max_arcsec:.2f}″" if math.isfinite(o.expanded_max_arcsec) else "—"
        lines.append(f"  {u:>13}  {format_hours(o.duration_s):>12}  {label}" + (f" ({o.problem})" if o.problem else ""))
    return lines


def write_proposal(procedure_path: Path, base: Plan, outcome: Outcome, out_path: Path, target_arcsec: float,
                   scenario_given: bool) -> list[Path]:
    """Write the proposed procedure to ``out_path`` (and, when the plan moves the tracer or the prediction ran
    on a ``--scenario``, its bench beside it); returns every file written."""
    from rtcal.outputs import write_output
    from rtcal.planning.design import bench_file_beside, keep_bench

    data = copy.deepcopy(outcome.plan.procedure)
    written = []
    if outcome.plan.bench != base.bench or scenario_given:
        bench = bench_file_beside(out_path)
        moved = "; ".join(c for c in outcome.plan.changes if "tracer" in c)
        header = f"# Written by `rtcal plan --target-u`: the simulated bench of the proposed plan ({moved or 'as predicted'})\n"
        written.append(write_output(bench, header + yaml.safe_dump(outcome.plan.bench, sort_keys=False, allow_unicode=True)))
        data["bench"] = bench.name
    else:
        copied = keep_bench(procedure_path, data, out_path)
        written += [copied] if copied is not None else []
    data["name"] = f"{data.get('name') or procedure_path.stem}"[:160] + f" — proposed by rtcal plan for U ≤ {target_arcsec:g}″"
    lines = [f"# Written by `rtcal plan --target-u {target_arcsec:g}` from {procedure_path.name}: predicted U (k = 2) "
             f"{outcome.expanded_max_arcsec:.3f}″ at the worst target ({outcome.recommended}), "
             f"{format_hours(outcome.duration_s)} of machine time. Changed:"]
    lines += [f"#   - {c}" for c in outcome.plan.changes] or ["#   - nothing"]
    written.insert(0, write_output(out_path, "\n".join(lines) + "\n" + yaml.safe_dump(
        data, sort_keys=False, allow_unicode=True, default_flow_style=None, width=200)))
    return written
