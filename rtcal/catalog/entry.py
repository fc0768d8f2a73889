"""A finished run as a catalogue entry: verified first (rtcal/run/verify.py), then the columns a
history needs taken from its results.json."""

from __future__ import annotations

import hashlib
import json
import sqlite3
from pathlib import Path
from typing import Any

from rtcal.catalog.schema import PARAMETERS, VDI
from rtcal.catalog.store import dumps, now_utc


class RunRefused(Exception):
    """A run the catalogue will not take: ``code`` 2 (not a finished run) or 1 (does not verify)."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


def run_id(results: dict[str, Any]) -> str:
    """The run's id: its digests (procedure, readings, events) and start time, hashed. The same run
    copied elsewhere keeps it; any other run differs in one of them."""
    key = dumps({"digests": results.get("digests"), "started_utc": results.get("started_utc")})
    return hashlib.sha256(key.encode()).hexdigest()[:32]


def verified_results(run_dir: Path) -> dict[str, Any]:
    """results.json of a run that ``rtcal verify`` finds agreeing with its readings and digests."""
    from rtcal.procedure.yamlfile import FileProblems
    from rtcal.results import ResultsError
    from rtcal.run.rundir import RunDirError
    from rtcal.run.verify import verify

    if not run_dir.is_dir():
        raise RunRefused(f"{run_dir}: not a run directory", 2)
    try:
        found = verify(run_dir)
    except (ResultsError, RunDirError) as exc:
        raise RunRefused(" ".join(str(exc).split()), 2) from None
    except FileProblems as exc:
        raise RunRefused(f"{run_dir}: its stored procedure does not validate ({len(exc.problems)} problems)", 2) from None
    except sqlite3.DatabaseError as exc:
        raise RunRefused(f"{run_dir / 'run.sqlite'}: cannot be read whole ({exc})", 2) from None
    except ValueError as exc:
        raise RunRefused(f"{run_dir}: its results cannot be recomputed from its readings ({str(exc)[:200]})", 1) from None
    if not found.agrees:
        what = found.integrity[0] if found.integrity else f"{len(found.differences)} values differ from its readings"
        raise RunRefused(f"{run_dir}: does not verify (`rtcal verify {run_dir}`): {' '.join(what.split())[:300]}", 1)
    return json.loads((run_dir / "results.json").read_text(encoding="utf-8"))  # type: ignore[no-any-return]


def _location_errors(estimates: dict[str, Any]) -> dict[str, Any]:
    """Every estimate of an axis location error with its U (names carrying 'location' or 'offset')."""
    out: dict[str, Any] = {}
    for solver, est in (estimates or {}).items():
        if not isinstance(est, dict):
            continue
        for key, value in est.items():
            if any(w in key for w in ("location", "offset", "tilt", "eccentric")) and not isinstance(value, list):
                out[f"{solver}.{key}"] = value
    return out


def _uncertainties(run_dir: Path) -> dict[str, float | None]:
    """U (k = 2) of each ISO 230-2 parameter, as the certificate states it (with or without limits)."""
    from rtcal.deliverables.conformity import parameter_uncertainties
    from rtcal.results import read_results

    return parameter_uncertainties(read_results(run_dir))


def entry_of(run_dir: Path, results: dict[str, Any]) -> dict[str, Any]:
    """The catalogue row of a verified run."""
    meta = results.get("metadata") or {}
    evaluation = results.get("evaluation") or {}
    iso = evaluation.get("iso230_2") or {}
    vdi = evaluation.get("vdi3441") or {}
    conformity = results.get("conformity") or {}
    limits = conformity.get("per_limit") or {}
    row: dict[str, Any] = {
        "run_id": run_id(results),
        "serial_number": str(meta.get("serial_number") or ""),
        "axis": str(meta.get("axis") or ""),
        "machine": str(meta.get("machine") or ""),
        "customer": str(meta.get("customer") or ""),
        "method": str(results.get("method") or ""),
        "measured_utc": str(results.get("started_utc") or ""),
        "finished_utc": str(results.get("finished_utc") or ""),
        "certificate_number": str(results.get("certificate_number") or meta.get("certificate_number") or ""),
        "verdict": str(conformity.get("verdict") or "none"),
        "location_errors": dumps(_location_errors(results.get("estimates") or {})),
        "digests": dumps(results.get("digests") or {}),
        "run_dir": str(run_dir.resolve()),
        "added_utc": now_utc(),
        "results": dumps(results),
    }
    uncertainties = _uncertainties(run_dir)
    for p in PARAMETERS:
        row[f"{p}_arcsec"] = iso.get(p)
        row[f"{p}_U_arcsec"] = uncertainties.get(p)
        row[f"{p}_limit_arcsec"] = (limits.get(p) or {}).get("limit_arcsec")
    for p in VDI:
        row[f"vdi_{p}_arcsec"] = vdi.get(p)
    return row
