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

from rtcal.methods.planner import Candidate
from rtcal.procedure.models import Procedure

ERROR_MOTION_PREFIX = "error motion"  # the budget's error-motion sources (radial, axial, tilt) start so


@dataclass(frozen=True)
class Outcome:
    """A plan's prediction: the recommended estimator, U (k = 2) at its worst target, the machine time,
    and each source's share of the variance (over the targets)."""

    plan: Candidate
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


def base_plan(procedure_path: Path, scenario) -> Candidate:
    from rtcal.procedure.yamlfile import load_yaml, read_text

    data, _ = load_yaml(read_text(procedure_path), str(procedure_path))
    return Candidate(data, scenario.model_dump(mode="json"))


def shares_of(contributions: dict[str, list[float | None]], combined: list[float | None]) -> dict[str, float]:
    """Each source's share of the combined variance, summed over the targets after the first (the
    reference, 0 ± 0)."""
    total = sum((c or 0.0) ** 2 for c in combined[1:])
    if total <= 0:
        return {}
    return {name: sum((v or 0.0) ** 2 for v in values[1:]) / total for name, values in contributions.items()}


def evaluate(plan: Candidate, workdir: Path | None = None) -> Outcome:
    """Predict ``plan`` (written to a temporary folder: the procedure beside its bench)."""
    from rtcal.planning.predict import predict, simulated
    from rtcal.methods import load_procedure
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


def walked_duration_s(plan: Candidate) -> float:
    """The plan's machine time as the engine's walker counts it on the plan's bench (no simulation, no
    store: the simulated run's clock counts the same), operator steps included; ∞ when it does not validate."""
    from rtcal.engine.walk import Timing, walk
    from rtcal.planning.predict import simulated
    from rtcal.methods import METHODS
    from rtcal.methods import load_procedure
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


def levers(plan: Candidate, proc: Procedure, max_radius_mm: float | None = None) -> list[Candidate]:
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


TRACER_NOISE_SOURCE = "tracer length noise"  # the budget's only term that more samples per reading lower


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


def floor_without_tracer_noise(outcome: Outcome) -> float:
    """U (k = 2) at the worst target without the tracer's length noise: what no number of samples lowers."""
    rest = [np.array(v) for k, v in outcome.contributions.items() if k != TRACER_NOISE_SOURCE]
    return float(2.0 * np.max(np.sqrt(sum(v**2 for v in rest)))) if rest else 0.0


def what_each_buys(chain: tuple[Candidate, ...], final: Outcome, evaluate_plan: Callable[[Candidate], Outcome]) -> list[dict[str, Any]]:
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
    plan = Candidate(outcome.plan.procedure, outcome.plan.bench, tuple(words(r) for r in rows))
    return Outcome(plan, outcome.recommended, outcome.expanded_max_arcsec, outcome.duration_s, outcome.raw_readings,
                   outcome.shares, outcome.contributions, outcome.problem, tuple(rows))


def propose(plan: Candidate, proc: Procedure, target_arcsec: float, max_radius_mm: float | None = None,
            margin: float = DEFAULT_MARGIN, evaluate_plan: Callable[[Candidate], Outcome] | None = None,
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
    chains: dict[int, tuple[Candidate, ...]] = {}
    planner = _planner(proc)
    candidates: list[tuple[float, Candidate]] = (planner.candidates(plan, proc, max_radius_mm, chains, walked_duration_s)
                                                  if planner else [])
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


def write_proposal(procedure_path: Path, base: Candidate, outcome: Outcome, out_path: Path, target_arcsec: float,
                   scenario_given: bool) -> list[Path]:
    """Write the proposed procedure to ``out_path`` (and, when the plan moves the tracer or the prediction ran
    on a ``--scenario``, its bench beside it); returns every file written."""
    from rtcal.outputs import write_output
    from rtcal.methods.planner import bench_file_beside, keep_bench

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
