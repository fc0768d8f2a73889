"""A run end to end: procedure → instruments → sequencer → store → dataset → solvers → results.

The method modules (:mod:`rtcal.methods`) hold what differs between methods; this module holds
what every run shares: the run directory, the store's metadata, the bench, the progress bar.
"""

from __future__ import annotations

import datetime as _dt
import sys
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

from tqdm import tqdm

from rtcal import __version__
from rtcal.clock import VirtualClock
from rtcal.methods import abbe, multistation
from rtcal.procedure.loader import load_procedure, load_scenario
from rtcal.procedure.models import Procedure
from rtcal.report import write_report, write_results
from rtcal.store import RunStore
from rtcal.yamlfile import read_text
from simulators.bench import Bench
from simulators.scenario import Scenario

METHODS: dict[str, ModuleType] = {"laser_tracer_multistation": multistation, "encoder_abbe_error": abbe}


@dataclass(frozen=True)
class RunOutcome:
    run_dir: Path
    results: dict[str, Any]


def default_run_dir(method: str) -> Path:
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{stamp}-{method}"


def resolve_scenario(procedure_path: Path, proc: Procedure, scenario_path: Path | None) -> tuple[Scenario, str]:
    """The bench: ``--scenario`` if given, else the procedure's ``bench`` (relative to it), else ideal."""
    if scenario_path is None and proc.bench is not None:
        scenario_path = procedure_path.parent / proc.bench
    if scenario_path is None:
        return Scenario(), ""
    return load_scenario(scenario_path), read_text(scenario_path)


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat()


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
    method = METHODS[proc.method]
    scenario, scenario_text = resolve_scenario(procedure_path, proc, Path(scenario_path) if scenario_path else None)
    seed = scenario.seed if seed is None else int(seed)
    run_dir = Path(out_dir) if out_dir is not None else default_run_dir(proc.method)
    store = RunStore.create(run_dir, {
        "method": proc.method, "procedure_path": str(procedure_path), "procedure_yaml": read_text(procedure_path),
        "scenario_yaml": scenario_text, "seed": str(seed), "software_version": __version__,
        "started_utc": _now(), "status": "running",
    })
    bench = Bench(scenario, VirtualClock(), seed)
    disable = (not sys.stderr.isatty()) if show_progress is None else not show_progress

    def progress(it):
        return tqdm(it, total=method.plan_length(proc), desc="readings", unit="rd", disable=disable, file=sys.stderr)

    try:
        method.measure(proc, bench, store, progress)
    except BaseException as exc:
        store.set_meta({"status": "interrupted", "error": repr(exc)})
        store.close()
        raise
    store.set_meta({"status": "measured", "finished_utc": _now(), "virtual_duration_s": f"{bench.clock.now_s():.1f}"})

    results: dict[str, Any] = {
        "rtcal_version": __version__,
        "method": proc.method,
        "procedure": {"name": proc.name, "path": str(procedure_path)},
        "seed": seed,
        "virtual_duration_s": round(bench.clock.now_s(), 1),
        **method.analyse(proc, store, bench),
        "events": store.events(),
    }
    store.set_meta({"status": "solved"})
    store.close()
    write_results(run_dir, results)
    method.write_files(run_dir, results)
    write_report(run_dir, results, method.report_body(results))
    return RunOutcome(run_dir, results)
