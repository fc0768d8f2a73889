"""`rtcal plan`: the uncertainty and duration of a procedure before anything moves.

The procedure is run on its bench with every random error removed (its geometry and systematic
errors kept), and each estimator's budget is formed from the noise the procedure states instead
of the noise the readings show: the linearised uncertainty of the plan — for the least-squares
estimators their Cramér–Rao bound under the stated noise. The simulated run's clock gives the
duration (motions, settling, the tracer's samples, and the operator's steps as the procedure's `durations:` states them).
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rtcal.procedure.models import Procedure


def simulated(data: dict[str, Any]) -> dict[str, Any]:
    """A procedure's YAML data with every instrument on the simulated bench (``backend: sim``, no address):
    a plan of real instruments is predicted on the bench as it is written, and nothing is connected to."""
    instruments = data.get("instruments")
    if not isinstance(instruments, dict):
        return data
    sim = {name: {**{k: v for k, v in (choice or {}).items() if k != "address"}, "backend": "sim"}
           for name, choice in instruments.items() if choice is not None}
    return {**data, "instruments": sim}


def predict(procedure_path: Path, proc: Procedure, scenario, workdir: Path | None = None) -> dict[str, Any]:
    """Predicted 1σ per target for every estimator, the recommended one, and the run's duration."""
    from rtcal.procedure.yamlfile import load_yaml, read_text
    from rtcal.results.model import Estimate
    from rtcal.run.runner import run_procedure

    tmp = Path(tempfile.mkdtemp(prefix="plan-", dir=workdir))
    try:
        bench = tmp / "bench.yaml"
        bench.write_text(yaml.safe_dump(scenario.without_noise().model_dump(mode="json"), sort_keys=False), encoding="utf-8")
        run_path = procedure_path
        if not proc.instruments.all_sim():  # predicted on the simulated bench, never on the instruments themselves
            data, _ = load_yaml(read_text(procedure_path), str(procedure_path))
            run_path = tmp / "procedure.yaml"
            run_path.write_text(yaml.safe_dump({k: v for k, v in simulated(data).items() if k != "bench"}, sort_keys=False,
                                               allow_unicode=True), encoding="utf-8")
        outcome = run_procedure(run_path, bench, out_dir=tmp / "run", show_progress=False, outputs=False,
                                estimate_noise=False)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    r = outcome.results
    return {
        "procedure": str(procedure_path),
        "targets": r.target_labels(),
        "measurement_duration_s": r.measurement_duration_s,
        "raw_readings": r.raw_readings,
        "recommended": r.recommended,
        "estimators": {name: {"predicted_sigma_arcsec": est.cumulative_uncertainty_arcsec,
                              "predicted_expanded_arcsec": est.cumulative_expanded_uncertainty_arcsec,
                              "rms_predicted_sigma_arcsec": round(float(np.sqrt(np.mean(np.square(
                                  [v for v in est.cumulative_uncertainty_arcsec[1:] if v is not None])))), 4),
                              "budget": {c.source: c.contribution_arcsec for c in est.uncertainty_budget.components}}
                       for name, est in r.estimates.items()
                       if isinstance(est, Estimate)},  # a quantity of its own: its method's planner notes say it
    }
