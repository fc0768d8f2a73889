"""A finished run re-evaluated with a reference instrument's new calibration, from its stored readings.

``rtcal catalog reassess`` asks this for each run that used the instrument: the run folder's store
is opened read-only, its procedure and readings are what ``rtcal verify`` recomputes from
(rtcal/run/verify.py), and the method's ``recalibration`` says what the new certificate changes (the
procedure's calibration inputs, the store's record of the polygon's certificate, …). The analysis,
evaluation and verdict then follow as the run itself computed them. Nothing of the run is written.

A run that cannot be re-evaluated is a :class:`Unreachable` with the reason (its folder is gone,
its store or results do not verify, its method takes nothing of that instrument's calibration)."""

from __future__ import annotations

import sqlite3
from collections.abc import Mapping
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rtcal.methods.recalibration import CannotRecalibrate, InstrumentCalibration, Recalibration
from rtcal.results.model import RunResults
from rtcal.store.runstore import RunStore

if TYPE_CHECKING:
    from rtcal.methods.protocol import Method


class Unreachable(Exception):
    """The run's readings cannot be re-evaluated: the message says which and why."""


class _Recalibrated:
    """The run's store as the analysis reads it, with the meta entries a new calibration replaces
    (the readings themselves are the stored ones, unchanged)."""

    def __init__(self, store: RunStore, meta: Mapping[str, str]) -> None:
        self._store, self._meta = store, dict(meta)

    def meta(self) -> dict[str, str]:
        return {**self._store.meta(), **self._meta}

    def __getattr__(self, name: str) -> Any:
        return getattr(self._store, name)


def recalibration_of(method: Method[Any, Any]) -> Recalibration | None:
    """The method's ``recalibration`` (None: it does not say how a new calibration enters its analysis)."""
    found = getattr(method, "recalibration", None)
    return found if isinstance(found, Recalibration) else None


def stored_procedure(run_dir: Path, methods: Mapping[str, Method[Any, Any]]) -> tuple[str, Any, dict[str, str]]:
    """The run's method name, stored procedure and store meta (read-only; ValueError: not readable)."""
    from rtcal.procedure.yamlfile import FileProblems, validate_text
    from rtcal.run.integrity import _read_only

    path = run_dir / RunStore.FILENAME
    if not path.is_file():
        raise ValueError(f"{path}: no store")
    try:
        store = RunStore(_read_only(path), path)
        with closing(store._db):  # noqa: SLF001 — read-only
            meta = store.meta()
    except sqlite3.Error as exc:
        raise ValueError(f"{path}: cannot be read ({exc})") from None
    name = meta.get("method", "")
    if name not in methods:
        raise ValueError(f"{path}: method {name[:40]!r} is not one rtcal knows")
    try:
        proc = validate_text(meta.get("procedure_yaml", ""), methods[name].procedure_model, f"{path} (stored procedure)",
                             context={"large": bool(meta.get("large"))})
    except FileProblems as exc:
        raise ValueError(f"{path}: its stored procedure does not validate ({len(exc.problems)} problems)") from None
    return name, proc, meta


def corrections_applied(run_dir: Path, methods: Mapping[str, Method[Any, Any]]) -> dict[str, str]:
    """Per instrument role, what of its calibration the run's analysis applied, in words ({}: its
    method does not say, or the store cannot be read)."""
    try:
        name, proc, meta = stored_procedure(run_dir, methods)
    except ValueError:
        return {}
    recal = recalibration_of(methods[name])
    return recal.applied(proc, meta) if recal is not None else {}


@dataclass(frozen=True)
class Reevaluation:
    """The run's results as stored and as re-evaluated (both whole, validated)."""

    old: RunResults
    new: RunResults


def reevaluate(run_dir: Path, methods: Mapping[str, Method[Any, Any]], role: str,
               calibration: InstrumentCalibration) -> Reevaluation:
    """The run recomputed from its store with ``calibration`` for its instrument ``role``
    (Unreachable: why it cannot be)."""
    from rtcal.procedure.yamlfile import FileProblems
    from rtcal.results import ResultsError
    from rtcal.run.integrity import IntegrityError, check_run
    from rtcal.run.rundir import RunDirError
    from rtcal.run.verify import recompute

    if not run_dir.is_dir():
        raise Unreachable(f"{run_dir}: the run folder is not there (moved, deleted, or on a disk not mounted)")
    if not (run_dir / RunStore.FILENAME).is_file():
        raise Unreachable(f"{run_dir / RunStore.FILENAME}: not there: the readings are gone")

    def adjust(method: Method[Any, Any], proc: Any, store: RunStore) -> tuple[Any, RunStore]:
        recal = recalibration_of(method)
        if recal is None:
            raise CannotRecalibrate(f"its method {method.name} does not say how a new calibration enters its analysis")
        new_proc, meta = recal.recalibrated(proc, store.meta(), role, calibration)
        return new_proc, (_Recalibrated(store, meta) if meta else store)  # type: ignore[return-value]

    try:
        old, recomputed, _ = recompute(run_dir, methods, adjust)
        check_run(run_dir, old)  # the readings are the ones the results were computed from
    except CannotRecalibrate as exc:
        raise Unreachable(f"{run_dir}: cannot be re-evaluated: {exc}") from None
    except IntegrityError as exc:
        raise Unreachable(f"{run_dir}: its store and results.json do not verify: {' '.join(str(exc).split())[:200]}") from None
    except (ResultsError, RunDirError) as exc:
        raise Unreachable(f"{run_dir}: {' '.join(str(exc).split())[:200]}") from None
    except FileProblems as exc:
        raise Unreachable(f"{run_dir}: its stored procedure does not validate ({len(exc.problems)} problems)") from None
    except sqlite3.DatabaseError as exc:
        raise Unreachable(f"{run_dir / RunStore.FILENAME}: cannot be read whole ({exc})") from None
    except ValueError as exc:
        raise Unreachable(f"{run_dir}: the solvers could not recompute it ({' '.join(str(exc).split())[:200]})") from None
    new = type(old).model_validate({**old.model_dump(mode="json"), **recomputed})
    return Reevaluation(old, new)


def reissued(new: RunResults, number: str, issued_on: str, role: str, calibration: InstrumentCalibration) -> RunResults:
    """The superseding certificate's results: the re-evaluated ones under a new ``number``, saying which
    certificate they replace (the run's own), issued on ``issued_on``, the instrument in ``role`` named
    with its new certificate (the traceability statement cites it); the digests of the readings stay
    the run's."""
    instruments = dict(new.metadata.instruments)
    if role in instruments:
        old = instruments[role]
        instruments[role] = old.model_copy(update={"certificate_number": calibration.certificate_number,
                                                   "calibrated_by": calibration.calibrated_by or old.calibrated_by,
                                                   "calibration_due": calibration.calibration_due or old.calibration_due})
    meta = new.metadata.model_copy(update={"certificate_number": number, "replaces": new.metadata.certificate_number,
                                           "date_of_issue": issued_on, "instruments": instruments})
    return type(new).model_validate({**new.model_dump(mode="json"), "metadata": meta.model_dump(mode="json")})


def write_reissue(folder: Path, results: RunResults, method: Method[Any, Any], note: dict[str, Any]) -> RunResults:
    """A new folder holding the superseding certificate (certificate.json, report.md/.html/.pdf, the
    table, figures and results.json, as a run writes them) and ``reassessment.json`` (``note``: the
    instrument's new certificate, the reason, the run folder whose readings it rests on). The run's
    own folder is not touched. RunDirError: ``folder`` exists and is not empty."""
    import json

    from rtcal.deliverables.certificate import build_certificate, write_certificate_json
    from rtcal.deliverables.deviations import PositioningDeviations
    from rtcal.deliverables.report import write_html, write_markdown, write_pdf
    from rtcal.outputs import staged_outputs, write_output
    from rtcal.results import write_results
    from rtcal.run.integrity import deliverable_digests
    from rtcal.run.rundir import RunDirError
    from rtcal.run.runner import with_deliverable_digests

    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise RunDirError(f"{folder}: exists and is not an empty folder: a reissued certificate goes into a new one")
    folder.mkdir(parents=True, exist_ok=True)
    with staged_outputs(folder) as out:
        if results.positioning_deviations is not None:
            PositioningDeviations.from_model(results.positioning_deviations).write_csv(out / "positioning_deviations.csv")
        method.outputs(results).write_files(out)
        certificate = build_certificate(results, out, method)
        write_markdown(certificate, out / "report.md")
        write_html(certificate, out / "report.html")
        write_pdf(certificate, out / "report.pdf")
        write_certificate_json(certificate, out / "certificate.json")
        write_output(out / "reassessment.json", json.dumps(note, indent=1, ensure_ascii=False) + "\n")
        results = with_deliverable_digests(results, deliverable_digests(out))
        write_results(out, results)
    return results
