"""``rtcal verify RUN_DIR``: the results recomputed from the store, set beside results.json.

The store holds the procedure, the bench and the seed a run was made with and every reading:
the method's ``analyse`` (what the run itself called) gives the estimates again, the runner's
evaluation and verdict follow from them, and each number is compared to the digits results.json
stores. The digests (rtcal/run/integrity.py) are checked too: a run whose numbers were edited
back into agreement but whose file differs from what the run wrote is still found, and so is
every deliverable (certificate, reports, CSV, figures) whose bytes are not those the run wrote.
"""

from __future__ import annotations

import json
import math
from contextlib import closing
from dataclasses import dataclass, field
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rtcal.results.io import read_results
from rtcal.results.model import RunResults
from rtcal.run.integrity import (IntegrityError, SignatureStatus, _read_only, check_deliverables, check_run, check_signature,
                                 missing_digests)
from rtcal.store.runstore import RunStore

if TYPE_CHECKING:
    from rtcal.methods.protocol import Method

# what a run's results hold that its store determines (paths, times and versions apart)
# (``truth`` is what a simulated bench had, not what its readings give: it is not recomputed)
RECOMPUTED = ("nominal_angles_deg", "raw_readings", "recommended", "solver_status", "estimates", "positioning_deviations",
              "environment", "evaluation", "conformity", "skipped_readings", "faults", "events")
REL_TOLERANCE = 1e-9  # a full-precision float recomputed on another machine's BLAS
ALTERED = {"EDITED": "changed after the run wrote it: its SHA-256 is not the one results.json records for it",
           "missing": "results.json records it as written by the run, and it is gone",
           "not a regular file": "a link or a folder stands where the run wrote this file"}
"""What each status of a deliverable (Verification.files) means, as `rtcal verify` and `catalog add` say it."""


@dataclass
class Verification:
    """What ``rtcal verify`` found: digest problems, and the numbers that differ (path, stored, recomputed)."""

    compared: int = 0
    readings: int = 0
    integrity: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    differences: list[tuple[str, Any, Any]] = field(default_factory=list)
    files: list[tuple[str, str]] = field(default_factory=list)
    """Each deliverable results.json records a digest of, and its status (integrity.check_deliverables)."""
    signature: SignatureStatus | None = None
    """The run's signature against the lab's keys (integrity.check_signature); None: not checked."""
    results: RunResults | None = None
    """results.json as read (its simulation and signature marks)."""

    @property
    def altered_files(self) -> list[tuple[str, str]]:
        return [(name, status) for name, status in self.files if status != "as written"]

    @property
    def agrees(self) -> bool:
        return not self.integrity and not self.differences and not self.altered_files


def _decimals(value: float) -> int:
    """The digits after the point that results.json stores for ``value`` (its JSON text)."""
    text = json.dumps(value)
    if "e" in text or "E" in text:
        mantissa, _, exponent = text.lower().partition("e")
        return max(0, len(mantissa.partition(".")[2]) - int(exponent))
    return len(text.partition(".")[2])


def _same_number(stored: float, recomputed: float) -> bool:
    if stored == recomputed:
        return True
    half_digit = 0.5 * 10.0 ** -_decimals(stored)
    return abs(recomputed - stored) <= half_digit * (1 + 1e-9) or math.isclose(stored, recomputed, rel_tol=REL_TOLERANCE)


def compare(stored: Any, recomputed: Any, path: str, out: Verification) -> None:
    """Walk both documents; every number compared to the digits stored, every text and key exactly."""
    if isinstance(stored, dict) and isinstance(recomputed, dict):
        for key in sorted(set(stored) | set(recomputed)):
            where = f"{path}.{key}" if path else str(key)
            if key not in stored or key not in recomputed:
                out.differences.append((where, stored.get(key, "(absent)"), recomputed.get(key, "(absent)")))
            else:
                compare(stored[key], recomputed[key], where, out)
        return
    if isinstance(stored, list) and isinstance(recomputed, list):
        if len(stored) != len(recomputed):
            out.differences.append((path, f"{len(stored)} values", f"{len(recomputed)} values"))
            return
        for i, (a, b) in enumerate(zip(stored, recomputed)):
            compare(a, b, f"{path}.{i}", out)
        return
    numbers = (int, float)
    if isinstance(stored, numbers) and isinstance(recomputed, numbers) and not isinstance(stored, bool) \
            and not isinstance(recomputed, bool):
        out.compared += 1
        if not _same_number(float(stored), float(recomputed)):
            out.differences.append((path, stored, recomputed))
        return
    out.compared += 1
    if stored != recomputed:
        out.differences.append((path, stored, recomputed))


def recompute(run_dir: Path, methods: Mapping[str, Method[Any, Any]],
              adjust: Callable[[Method[Any, Any], Any, RunStore], tuple[Any, RunStore]] | None = None,
              ) -> tuple[RunResults, dict[str, Any], int]:
    """results.json as read, the parts of it the store determines recomputed, and the readings used
    (``methods``: the known methods, by name: the store names the run's; ``adjust``: the procedure and
    store the analysis takes instead of the stored ones — a reference instrument's new calibration,
    rtcal/run/reassess.py)."""
    from rtcal.procedure.yamlfile import validate_text
    from rtcal.results.model import Event
    from rtcal.run.rundir import RunDirError
    from rtcal.run.runner import conformity_of, evaluation_of

    results = read_results(run_dir, {name: m.results_model for name, m in methods.items()})
    path = run_dir / RunStore.FILENAME
    if not path.is_file():
        raise RunDirError(f"{run_dir}: no {RunStore.FILENAME}: nothing to recompute the results from")
    store = RunStore(_read_only(path), path)
    with closing(store._db):  # noqa: SLF001 — read-only: verify changes no byte of the run
        meta = store.meta()
        where = f"{path} (stored procedure)"
        method = meta.get("method", "")
        if method not in methods:
            raise RunDirError(f"{path}: its `method` is {method[:40]!r}, not one rtcal knows: the store was edited")
        proc: Any = validate_text(meta.get("procedure_yaml", ""), methods[method].procedure_model, where,
                             context={"large": bool(meta.get("large"))})
        try:
            proc = proc.model_copy(update={"instruments": type(proc.instruments).model_validate_json(meta.get("instruments", ""))})
        except ValueError:
            raise RunDirError(f"{path}: its `instruments` is not the procedure's instrument section: the store was edited") from None
        source = store
        if adjust is not None:
            proc, source = adjust(methods[proc.method], proc, store)
        analysis = methods[proc.method].analyse(proc, source, None, True)  # no bench: truth is the simulator's, not the readings'

        evaluation = evaluation_of(analysis) if methods[proc.method].positioning_deviation else None
        events = [Event(**e) for e in store.events()]
        recomputed = {
            **analysis.model_dump(mode="json"),
            "evaluation": evaluation.model_dump(mode="json") if evaluation else None,
            "conformity": (c.model_dump(mode="json") if (c := conformity_of(proc, analysis, evaluation)) else None),
            "skipped_readings": len(store.skipped_plan_indices()),
            "faults": sum(1 for e in events if e.kind == "fault"),
            "events": [e.model_dump(mode="json") for e in events],
        }
        readings = store.instrument_readings()
    return results, recomputed, readings


def verify(run_dir: str | Path, methods: Mapping[str, Method[Any, Any]]) -> Verification:
    """Digests checked, results recomputed from the store and compared (ResultsError, RunDirError,
    FileProblems: a run directory that cannot be verified at all); ``methods``: the known methods."""
    run_dir = Path(run_dir)
    results, recomputed, readings = recompute(run_dir, methods)
    if missing_digests(results, run_dir / "results.json"):  # exit 2: not a results.json rtcal wrote
        raise IntegrityError(missing_digests(results, run_dir / "results.json"))
    out = Verification(readings=readings, results=results)
    try:
        out.warnings += check_run(run_dir, results)
    except IntegrityError as exc:
        out.integrity.append(str(exc))
    try:
        out.signature = check_signature(run_dir, results)
    except IntegrityError as exc:  # a forgery: named once, whichever check found it first
        out.signature = SignatureStatus("REFUSED", str(exc))
        if str(exc) not in out.integrity:
            out.integrity.append(str(exc))
    out.files = check_deliverables(run_dir, results)
    if results.digests is not None and results.digests.deliverables_sha256 is None and not out.integrity:
        out.warnings.append(f"{run_dir / 'results.json'} (schema {results.schema_version}) records no digests of the "
                            "certificate, reports and CSV (rtcal writes them since schema 1.3): those files are not checked")
    stored = results.model_dump(mode="json")
    for key in RECOMPUTED:
        compare(stored.get(key), recomputed.get(key), key, out)
    return out
