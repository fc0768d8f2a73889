"""``rtcal catalog reassess INSTRUMENT --certificate NEW.yaml``: what a reference instrument's new
calibration means for every certificate it touched (ISO/IEC 17025 7.10; Fluke MET/TEAM's reverse
traceability).

Each current entry that used the instrument (``used-by``) is re-evaluated from its stored readings
with the new calibration (rtcal/run/reassess.py: the method's analysis, evaluation and verdict as the
run computed them); the certificates whose E, U or verdict change as the certificate states them
(E to its U's place, U to two digits rounded up) are listed, old beside new, and an entry measured
on or after the certificate's ``out_of_tolerance_since`` is marked in doubt. A run that cannot be
re-evaluated is named with why. The reassessment is one audit row. With ``--issue`` each changed
certificate gets a superseding one: a new number (the old one with ``-R1``, ``-R2`` …), "replaces N"
on its page, written into a new folder with its results and reassessment.json; filed as a
supersede; the run's folder and its certificate are never touched."""

from __future__ import annotations

import hashlib
import re
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from rtcal.catalog.entry import checked, entry_of
from rtcal.catalog.history import certificate_words, e_text
from rtcal.catalog.store import Catalog
from rtcal.deliverables.conformity import parameter_uncertainties
from rtcal.methods.recalibration import InstrumentCalibration
from rtcal.results.model import RunResults


def load_certificate(path: Path) -> InstrumentCalibration:
    """The new certificate file, validated (FileProblems: one located line per problem)."""
    from rtcal.procedure.yamlfile import read_text, validate_text

    return validate_text(read_text(path), InstrumentCalibration, str(path))


def _figures(results: RunResults) -> dict[str, Any]:
    iso = results.evaluation.iso230_2 if results.evaluation else None
    e = getattr(iso, "E", None)
    u = parameter_uncertainties(results).get("E")
    return {"E_arcsec": e, "E_U_arcsec": u, "verdict": results.conformity.verdict if results.conformity else "none"}


def _shown(f: dict[str, Any]) -> tuple[str, str]:
    return e_text(f), f["verdict"]


def _number(cat: Catalog, old: str) -> str:
    base = re.sub(r"-R\d+$", "", old) or "reissue"
    n = 1
    while cat.by_certificate(f"{base}-R{n}"):
        n += 1
    return f"{base}-R{n}"


def reassess(cat: Catalog, calibration: InstrumentCalibration, since: str | None, who: str, reason: str,
             out: Path | None, issue: bool) -> dict[str, Any]:
    """The reassessment (see the module's docstring) as a document; one audit row, and with ``issue``
    a superseding entry per changed certificate."""
    from rtcal.methods import METHODS
    from rtcal.run.reassess import Unreachable, reevaluate

    rows = cat.used_by(calibration.instrument, since)
    replaced = {r["supersedes"]: r["certificate_number"] for r in cat.machines() if r.get("supersedes")}
    numeric = [c for c in calibration.changes() if not c.startswith("out of tolerance")]
    doc: dict[str, Any] = {"instrument": calibration.instrument, "certificate": calibration.model_dump(mode="json"),
                           "changes": calibration.changes(), "since": since, "reason": reason, "by": who,
                           "runs": [], "unreachable": [], "skipped": []}
    for r in rows:
        name = certificate_words(r)
        if r["run_id"] in replaced:
            doc["skipped"].append({"certificate": name, "why": f"superseded by {replaced[r['run_id']]}"})
            continue
        old = {"E_arcsec": r["E_arcsec"], "E_U_arcsec": r["E_U_arcsec"], "verdict": r["verdict"]}
        suspect = bool(calibration.out_of_tolerance_since) and r["measured_utc"][:10] >= calibration.out_of_tolerance_since
        item: dict[str, Any] = {"run_id": r["run_id"], "certificate_number": r["certificate_number"],
                                "measured_utc": r["measured_utc"], "serial_number": r["serial_number"], "axis": r["axis"],
                                "role": r["role"], "run_dir": r["run_dir"], "old": old, "new": old, "suspect": suspect,
                                "changed": False, "issued": None}
        if numeric:
            if r.get("origin") == "reissue":
                doc["unreachable"].append({"certificate": name, "run_dir": r["run_dir"], "why": (
                    "a reissued certificate: its readings are those of the run it replaces, re-evaluated once already; "
                    "reassess that run with every change at once")})
                continue
            try:
                found = reevaluate(Path(r["run_dir"]), METHODS, r["role"], calibration)
            except Unreachable as exc:
                doc["unreachable"].append({"certificate": name, "run_dir": r["run_dir"], "why": str(exc)})
                continue
            item["new"] = _figures(found.new)
            item["changed"] = _shown(item["new"]) != _shown(old)
            item["_results"] = found.new
        doc["runs"].append(item)
    if issue:
        for item in doc["runs"]:
            if item["changed"]:
                item["issued"] = _issue(cat, item, calibration, who, reason, out)
    for item in doc["runs"]:
        item.pop("_results", None)
    cat.record("reassess", calibration.instrument, who, reason,
               {"certificate_number": calibration.certificate_number, "changes": calibration.changes(), "since": since,
                "runs": [{k: i[k] for k in ("run_id", "certificate_number", "old", "new", "changed", "suspect")}
                         | {"issued": (i["issued"] or {}).get("certificate_number")} for i in doc["runs"]],
                "unreachable": doc["unreachable"]})
    return doc


def _issue(cat: Catalog, item: dict[str, Any], calibration: InstrumentCalibration, who: str, reason: str,
           out: Path | None) -> dict[str, str]:
    """The superseding certificate of one changed run: written into a new folder and filed."""
    from rtcal.methods import METHODS
    from rtcal.run.reassess import reissued, write_reissue

    old_entry = cat.entry(item["run_id"])
    assert old_entry is not None
    number = _number(cat, item["certificate_number"])
    run_dir = Path(item["run_dir"])
    folder = (out or run_dir.parent) / f"{run_dir.name}-{re.sub(r'[^A-Za-z0-9._-]+', '_', number)}"
    now = datetime.now(timezone.utc)
    results = reissued(item["_results"], number, now.date().isoformat(), item["role"], calibration)
    note = {"replaces": item["certificate_number"], "reason": reason, "by": who, "at_utc": now.isoformat(),
            "run_dir": str(run_dir), "readings_sha256": (results.digests.readings_sha256 if results.digests else None),
            "instrument": calibration.instrument, "role": item["role"],
            "new_calibration": calibration.model_dump(mode="json"), "old": item["old"], "new": item["new"]}
    results = write_reissue(folder, results, METHODS[results.method], note)
    entry = checked(entry_of(folder, results, check=False), folder)
    entry.update(run_id=hashlib.sha256(f"{item['run_id']}/{number}".encode()).hexdigest()[:32], origin="reissue",
                 supersedes=item["run_id"], replaces=item["certificate_number"], site=old_entry.get("site", ""),
                 rig=old_entry.get("rig", ""), added_by=who, state=old_entry.get("state", ""))
    entry["instruments"] = [
        {**{k: i[k] for k in ("role", "instrument_id", "kind", "certificate_number", "issuer", "due", "correction")},
         **({"certificate_number": calibration.certificate_number, "issuer": calibration.calibrated_by or i["issuer"],
             "due": calibration.calibration_due or i["due"],
             "correction": f"reassessed with its certificate {calibration.certificate_number}: "
                           f"{'; '.join(calibration.changes())}"} if i["role"] == item["role"] else {})}
        for i in cat.instruments_of([item["run_id"]])]
    cat.add(entry, who=who, reason=reason)
    return {"certificate_number": number, "folder": str(folder)}


def report_lines(doc: dict[str, Any]) -> list[str]:
    """The reassessment as the console prints it."""
    runs = doc["runs"]
    out = [f"{doc['instrument']}: new certificate {doc['certificate']['certificate_number']} "
           f"({'; '.join(doc['changes']) or 'no change of scale, corrections or U'}); "
           f"{len(runs) + len(doc['unreachable']) + len(doc['skipped'])} calibrations used it"
           f"{' since ' + doc['since'] if doc['since'] else ''}"]
    if runs:
        out.append(f"{'certificate (measured)':30} {'serial number':16} {'axis':5} {'E ± U (″) before → after':34} "
                   "verdict before → after")
    for i in runs:
        (e_old, v_old), (e_new, v_new) = _shown(i["old"]), _shown(i["new"])
        mark = "CHANGED" if i["changed"] else "unchanged"
        if i["suspect"]:
            mark += f"; IN DOUBT: the instrument was out of tolerance since {doc['certificate']['out_of_tolerance_since']}"
        out.append(f"{certificate_words(i):30} {i['serial_number'][:16]:16} {i['axis'][:5]:5} "
                   f"{e_old + ' → ' + e_new:34} {v_old} → {v_new}  {mark}")
        if i["issued"]:
            out.append(f"  issued {i['issued']['certificate_number']} (replaces {i['certificate_number']}) in "
                       f"{i['issued']['folder']}")
    for u in doc["unreachable"]:
        out.append(f"cannot be re-evaluated: {u['certificate']}: {u['why']}")
    for s in doc["skipped"]:
        out.append(f"left out: {s['certificate']}: {s['why']}")
    changed = sum(i["changed"] for i in runs)
    out.append(f"{changed} changed, {len(runs) - changed} unchanged, {sum(i['suspect'] for i in runs)} in doubt, "
               f"{len(doc['unreachable'])} cannot be re-evaluated")
    return out
