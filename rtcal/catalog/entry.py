"""A finished run as a catalogue entry: verified first (rtcal/run/verify.py), then the columns a
history needs taken from its results.json."""

from __future__ import annotations

import hashlib
import json
import math
import re
import sqlite3
import unicodedata
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from rtcal.catalog.schema import NAMES, PARAMETERS, STATES, VDI, VERDICTS, calibrations, instruments, normal_text
from rtcal.catalog.store import dumps, now_utc
from rtcal.methods import read_results
from rtcal.results.io import finite
from rtcal.results.model import RunResults


class RunRefused(Exception):
    """A run the catalogue will not take: ``code`` 2 (not a finished run) or 1 (does not verify)."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


def run_id(results: RunResults) -> str:
    """The run's id: its digests (procedure, readings, events) and start time, hashed. The same run
    copied elsewhere keeps it; any other run differs in one of them."""
    digests = results.digests.model_dump(mode="json") if results.digests else None
    key = dumps({"digests": digests, "started_utc": results.started_utc})
    return hashlib.sha256(key.encode()).hexdigest()[:32]


def verified(run_dir: Path) -> tuple[RunResults, str]:
    """results.json of a run that ``rtcal verify`` finds agreeing with its readings, digests and signature
    (a forgery refused: RunRefused, code 1), and its signature as the catalogue marks it."""
    from rtcal.procedure.yamlfile import FileProblems
    from rtcal.results import ResultsError
    from rtcal.run.rundir import RunDirError
    from rtcal.methods import METHODS
    from rtcal.run.verify import verify

    if not run_dir.is_dir():
        raise RunRefused(f"{run_dir}: not a run directory", 2)
    try:
        found = verify(run_dir, METHODS)
    except (ResultsError, RunDirError) as exc:
        raise RunRefused(" ".join(str(exc).split()), 2) from None
    except FileProblems as exc:
        raise RunRefused(f"{run_dir}: its stored procedure does not validate ({len(exc.problems)} problems)", 2) from None
    except sqlite3.DatabaseError as exc:
        raise RunRefused(f"{run_dir / 'run.sqlite'}: cannot be read whole ({exc})", 2) from None
    except ValueError as exc:
        raise RunRefused(f"{run_dir}: its results cannot be recomputed from its readings ({str(exc)[:200]})", 1) from None
    if not found.agrees:
        raise RunRefused(f"{run_dir}: does not verify (`rtcal verify {run_dir}`): {' '.join(_why(run_dir, found).split())[:700]}", 1)
    status = found.signature
    mark = "unsigned" if status is None or status.state == "unsigned" else \
        f"{'checked' if status.state == 'valid' else 'not checked'}: {status.signer} {status.fingerprint}"
    return read_results(run_dir), mark


def refuse_simulated(run_dir: Path, results: RunResults) -> None:
    """A run that calibrated nothing (simulated, or rehearsed) is no entry of a machine's history unless
    ``catalog add --allow-simulated`` (RunRefused, code 2, naming why)."""
    from rtcal.deliverables.certificate import marking

    if marking(results):
        raise RunRefused(f"{run_dir}: {marking(results)}; the catalogue files calibrations (add it anyway with "
                         "--allow-simulated: every listing then marks it SIMULATED)", 2)


def marks(row: dict[str, Any]) -> str:
    """What a listing says of an entry beside its verdict: SIMULATED, unsigned, signature not checked ("": none)."""
    out = ["SIMULATED" if "REHEARSED" not in (row.get("simulated") or "") else "SIMULATED/REHEARSED"] \
        if row.get("simulated") else []
    signature = row.get("signature") or "unsigned"
    if signature == "unsigned":
        out.append("unsigned")
    elif signature.startswith("not checked"):
        out.append("signature not checked")
    return ", ".join(out)


def _why(run_dir: Path, found: Any) -> str:
    """What ``rtcal verify`` would say first: a digest that does not match, an edited file named, or
    a value that differs from its readings."""
    from rtcal.run.verify import ALTERED

    if found.integrity:
        return str(found.integrity[0])
    if found.altered_files:
        name, status = found.altered_files[0]
        more = f" (and {len(found.altered_files) - 1} more files)" if len(found.altered_files) > 1 else ""
        return f"{run_dir / name}: {status} — {ALTERED[status]}{more}"
    where, stored, recomputed = found.differences[0]
    return (f"{run_dir / 'results.json'}: {where}: stored {str(stored)[:40]}, recomputed from the readings "
            f"{str(recomputed)[:40]} ({len(found.differences)} values differ)")


def _location_errors(results: RunResults) -> dict[str, Any]:
    """Every estimate of an axis location error with its U (names carrying location, offset, tilt, eccentric)."""
    out: dict[str, Any] = {}
    for solver, est in results.estimates.model_dump(mode="json").items():
        for key, value in (est or {}).items() if isinstance(est, dict) else ():
            if any(w in key for w in ("location", "offset", "tilt", "eccentric")) and not isinstance(value, list):
                out[f"{solver}.{key}"] = value
    return out


def location_error_rows(doc: Any) -> list[dict[str, Any]]:
    """The run's ISO 230-7 location errors (``location_errors`` of its results.json ``doc``, the R-test's) as the
    catalogue's rows: symbol as results.json keys it (its unit in it), axis, value, U and k; none for a method
    without them. (Migration 0005 holds a copy: keep the two alike.)"""
    found = doc.get("location_errors") if isinstance(doc, dict) else None
    out = []
    for symbol, e in (found.items() if isinstance(found, dict) else ()):
        if not isinstance(e, dict):
            continue
        numbers = [e.get("value"), e.get("expanded_uncertainty"), e.get("coverage_factor", 2.0)]
        if not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in numbers):
            continue
        value, U, k = (float(x) for x in numbers)  # type: ignore[arg-type]  # (checked above)
        out.append({"symbol": str(symbol)[:40], "axis": str(e.get("axis", ""))[:10], "value": value,
                    "expanded_uncertainty": U, "coverage_factor": k})
    return out


def instruments_of(run_dir: Path, results: RunResults) -> list[dict[str, Any]]:
    """The instruments and reference standards the run names (metadata.instruments), each with what of
    its calibration the run's analysis applied (its method's words; rtcal/run/reassess.py)."""
    from rtcal.methods import METHODS
    from rtcal.run.reassess import corrections_applied

    applied = corrections_applied(run_dir, METHODS)
    return [{"role": role, "instrument_id": rec.id, "kind": re.sub(r"_\d+$", "", role),
             "certificate_number": rec.certificate_number, "issuer": rec.calibrated_by, "due": rec.calibration_due,
             "correction": applied.get(role, "not stated by its method" if applied else
                                       f"not stated: its method {results.method} does not say")}
            for role, rec in results.metadata.instruments.items() if rec.id]


def entry_of(run_dir: Path, results: RunResults, signature: str = "unsigned", check: bool = True) -> dict[str, Any]:
    """The catalogue row of a verified run (``signature``: as :func:`verified` marks it), every field
    :func:`checked` (``check`` False: as it comes, as older rtcal versions added it — tests make such
    catalogues)."""
    from rtcal.deliverables.certificate import marking
    from rtcal.deliverables.conformity import parameter_uncertainties

    meta = results.metadata
    iso = results.evaluation.iso230_2 if results.evaluation else None
    vdi = results.evaluation.vdi3441 if results.evaluation else None
    conformity = results.conformity
    limits = conformity.per_limit if conformity else {}
    row: dict[str, Any] = {
        "run_id": run_id(results),
        "serial_number": meta.serial_number, "axis": meta.axis, "machine": meta.machine, "customer": meta.customer,
        "method": results.method,
        "measured_utc": results.started_utc or "", "finished_utc": results.finished_utc or "",
        "certificate_number": meta.certificate_number,
        "verdict": conformity.verdict if conformity else "none",
        "location_errors": dumps(finite(_location_errors(results))),
        "digests": dumps(results.digests.model_dump(mode="json") if results.digests else {}),
        "run_dir": str(run_dir.resolve()),
        "added_utc": now_utc(),
        "results": (text := (run_dir / "results.json").read_text(encoding="utf-8")),  # the file as written, byte for byte
        "simulated": marking(results), "signature": signature,
        "results_sha256": hashlib.sha256(text.encode()).hexdigest(),
        "test": results.procedure.name or results.method,
        "state": meta.item_state, "replaces": meta.replaces, "origin": "run",
        "instruments": instruments_of(run_dir, results),
        "location_error_rows": location_error_rows(json.loads(text)),
    }
    uncertainties = parameter_uncertainties(results)
    for p in PARAMETERS:
        row[f"{p}_arcsec"] = getattr(iso, p, None)
        row[f"{p}_U_arcsec"] = uncertainties.get(p)
        row[f"{p}_limit_arcsec"] = limits[p].limit_arcsec if p in limits else None
    for p in VDI:
        row[f"vdi_{p}_arcsec"] = getattr(vdi, p, None)
    return checked(row, run_dir) if check else row


CLOCK_SKEW = timedelta(days=1)  # a run may seem to start this far in the future (another computer's clock)


def _refused(run_dir: Path, field: str, why: str) -> RunRefused:
    return RunRefused(f"{run_dir}: its {field} cannot go into the catalogue: {why}", 2)


def _utc(run_dir: Path, field: str, text: str, required: bool) -> str:
    """An ISO 8601 time as UTC ISO 8601 (one form, so entries sort and compare as times)."""
    if not text and not required:
        return ""
    try:
        t = datetime.fromisoformat(text)
    except (ValueError, TypeError):
        raise _refused(run_dir, field, f"{str(text)[:40]!r} is not an ISO 8601 time") from None
    t = (t if t.tzinfo else t.replace(tzinfo=timezone.utc)).astimezone(timezone.utc)
    if not datetime(1970, 1, 1, tzinfo=timezone.utc) <= t <= datetime.now(timezone.utc) + CLOCK_SKEW:
        raise _refused(run_dir, field, f"{text[:40]} is before 1970 or in the future")
    return t.isoformat()


def _name(run_dir: Path, name: str, text: Any, limit: int | None) -> str:
    """A name as the catalogue keeps it (normal_text), or RunRefused naming the field."""
    if not isinstance(text, str):
        raise _refused(run_dir, name, "not text")
    bad = next((c for c in text if unicodedata.category(c) in ("Cc", "Cf", "Cs", "Co")), None)
    if bad is not None:
        raise _refused(run_dir, name, f"it holds a control or invisible character (U+{ord(bad):04X})")
    text = normal_text(text)
    if limit is not None and len(text) > limit:
        raise _refused(run_dir, name, f"longer than {limit} characters")
    return text


def checked(row: dict[str, Any], run_dir: Path) -> dict[str, Any]:
    """The row with every field checked (RunRefused, code 2, naming the first that is not one the
    catalogue can keep) and its names and times in the one form lists compare: an entry added
    is one no list, history or page fails on."""
    for name in (*NAMES, "method", "verdict"):
        row[name] = _name(run_dir, name, row[name], getattr(calibrations.c[name].type, "length", None))
    if not row["serial_number"]:
        raise _refused(run_dir, "serial number", "none (metadata.serial_number): a history is a machine's")
    if row["verdict"] not in VERDICTS:
        raise _refused(run_dir, "verdict", f"{row['verdict'][:20]!r} is not one of {', '.join(VERDICTS)}")
    if row.get("state", "") not in STATES:
        raise _refused(run_dir, "item state", f"{str(row['state'])[:20]!r} is not as_found, as_left or empty")
    for name in ("test", "replaces", "site", "rig", "added_by"):
        if name in row:
            row[name] = _name(run_dir, name, row[name], getattr(calibrations.c[name].type, "length", None))
    for i in row.get("instruments", []):
        for name in ("role", "instrument_id", "kind", "certificate_number", "issuer", "due"):
            i[name] = _name(run_dir, f"instrument {i.get('role', '')[:20]} {name}", i[name],
                            getattr(instruments.c[name].type, "length", None))
    if row["replaces"] and row["replaces"] == row["certificate_number"]:
        raise _refused(run_dir, "metadata.replaces", "it names the certificate's own number")
    row["certificate_key"] = row["certificate_number"] or None  # unique in the catalogue
    row["measured_utc"] = _utc(run_dir, "start time (started_utc)", row["measured_utc"], True)
    row["finished_utc"] = _utc(run_dir, "end time (finished_utc)", row["finished_utc"], False)
    for key in [f"{p}_{kind}arcsec" for p in PARAMETERS for kind in ("", "U_", "limit_")] + [f"vdi_{p}_arcsec" for p in VDI]:
        value = row[key]
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise _refused(run_dir, key, f"{str(value)[:20]} is not a finite number")
        if ("_U_" in key or "_limit_" in key) and value < 0:
            raise _refused(run_dir, key, f"{value} is negative")
    return row
