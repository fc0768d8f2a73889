"""A run end to end: procedure → instruments → sequencer → store → dataset → solvers → results."""

from __future__ import annotations

import datetime as _dt
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from rtcal import __version__
from rtcal.clock import VirtualClock
from rtcal.dataset import multistation_data
from rtcal.instruments import multistation_instruments
from rtcal.procedure.loader import load_procedure, load_scenario
from rtcal.procedure.models import LaserTracerMultistation
from rtcal.report import plot_deviation, write_report
from rtcal.results import paper_estimate_dict, shared_dead_path_dict, write_deviation_csv, write_results
from rtcal.sequencer.multistation import planned_readings, run_multistation
from rtcal.solvers.lm import LMParameters
from rtcal.solvers.paper000 import solve_paper
from rtcal.solvers.shared_dead_path import solve_shared_dead_path
from rtcal.store import RunStore
from simulators.bench import Bench
from simulators.scenario import Scenario
from simulators.truth import station_truth


@dataclass(frozen=True)
class RunOutcome:
    run_dir: Path
    results: dict[str, Any]


def default_run_dir(method: str) -> Path:
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{stamp}-{method}"


def lm_parameters(proc: LaserTracerMultistation) -> LMParameters:
    lm = proc.solver.lm
    return LMParameters(beta=lm.beta, sigma=lm.sigma, epsilon=lm.epsilon,
                        mu0=None if lm.mu0 == "residual_norm" else float(lm.mu0), max_iterations=lm.max_iterations)


def resolve_scenario(procedure_path: Path, proc: LaserTracerMultistation, scenario_path: Path | None) -> tuple[Scenario, str]:
    """The bench: ``--scenario`` if given, else the procedure's ``bench`` (relative to it), else ideal."""
    if scenario_path is None and proc.bench is not None:
        scenario_path = (procedure_path.parent / proc.bench)
    if scenario_path is None:
        return Scenario(), ""
    return load_scenario(scenario_path), Path(scenario_path).read_text(encoding="utf-8")


def run_procedure(
    procedure_path: str | Path,
    scenario_path: str | Path | None = None,
    seed: int | None = None,
    out_dir: str | Path | None = None,
    show_progress: bool | None = None,
) -> RunOutcome:
    """Run a procedure on the simulated bench and write the run directory. Raises FileProblems on bad input."""
    procedure_path = Path(procedure_path)
    proc = load_procedure(procedure_path)
    scenario, scenario_text = resolve_scenario(procedure_path, proc, Path(scenario_path) if scenario_path else None)
    seed = scenario.seed if seed is None else int(seed)
    run_dir = Path(out_dir) if out_dir is not None else default_run_dir(proc.method)
    store = RunStore.create(run_dir, {
        "method": proc.method,
        "procedure_path": str(procedure_path),
        "procedure_yaml": procedure_path.read_text(encoding="utf-8"),
        "scenario_yaml": scenario_text,
        "seed": str(seed),
        "software_version": __version__,
        "started_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(),
        "status": "running",
    })
    clock = VirtualClock()
    bench = Bench(scenario, clock, seed)
    inst = multistation_instruments(proc, bench)
    plan_len = len(planned_readings(proc))
    disable = (not sys.stderr.isatty()) if show_progress is None else not show_progress

    def progress(it):
        return tqdm(it, total=plan_len, desc="readings", unit="rd", disable=disable, file=sys.stderr)

    try:
        run_multistation(proc, inst, store, clock, progress)
    except BaseException as exc:
        store.set_meta({"status": "interrupted", "error": repr(exc)})
        store.close()
        raise
    store.set_meta({"status": "measured", "finished_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(),
                    "virtual_duration_s": f"{clock.now_s():.1f}"})

    angles = proc.stations.angles_deg()
    data = multistation_data(store, angles, len(proc.points_array()))
    guess, axis = np.array(proc.solver.first_station_guess_mm), np.array(proc.solver.axis_point_mm)
    estimate = solve_paper(data.points_mm, data.lengths_mm, np.deg2rad(angles), guess, axis, lm_parameters(proc))
    shared = solve_shared_dead_path(data.points_mm, data.lengths_mm, data.segments, np.deg2rad(angles), guess, axis)
    direction = 1 if proc.stations.approach == "positive" else -1
    results: dict[str, Any] = {
        "rtcal_version": __version__,
        "method": proc.method,
        "procedure": {"name": proc.name, "path": str(procedure_path)},
        "seed": seed,
        "nominal_angles_deg": [float(a) for a in angles],
        "raw_readings": data.raw_readings,
        "virtual_duration_s": round(clock.now_s(), 1),
        "estimates": {"paper": paper_estimate_dict(estimate), "shared_dead_path": shared_dead_path_dict(shared)},
        "truth": station_truth(bench, angles, direction),
        "events": store.events(),
    }
    store.set_meta({"status": "solved"})
    store.close()
    write_results(run_dir, results)
    write_deviation_csv(run_dir, results)
    plot_deviation(run_dir, results)
    write_report(run_dir, results)
    return RunOutcome(run_dir, results)
