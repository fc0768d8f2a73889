"""An as-found / as-left certificate (ISO/IEC 17025 7.8.4.1 d): two runs of one item, the second
after an adjustment or compensation, side by side, with each change against the combined U.

It is the as-left run's certificate (its laboratory, customer, item, instruments, conformity and
budget) with the results replaced by both runs': per target and direction the deviation as found
and as left, their difference and U_c = 2·√(u_A² + u_B²) (the runs are independent
measurements), and the ISO 230-2 parameters of both with their U. The same renderers as every
certificate write it (:func:`rtcal.deliverables.report.write_pdf`, ``write_html``).

The as-left run is measured after the as-found run has ended (the adjustment lies between): two real
measurements whose periods overlap, or that come in the other order, are no such pair and are refused
(:class:`NotAPair`); on a virtual clock (a simulation: its period is the one it stands for, not when it
ran) the certificate says that the periods overlap.
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path
from typing import Any

from rtcal.deliverables.certificate import (ISO_KEYS, ISO_MEANING, ISO_SYMBOL, Certificate, CertifiedMethod, Item, KeyResult,
                                           ParameterRow, Table, build_certificate, iso_departures, marking,
                                           measurement_dates, signature_line)
from rtcal.deliverables.conformity import parameter_uncertainties
from rtcal.deliverables.rounding import u_text, value_text
from rtcal.results.model import RunResults

BRIEF = ("E", "M", "B", "R", "A")


class NotAPair(ValueError):
    """Two real measurements that cannot be as found and as left: their periods overlap or come in the other order."""


def _utc(stamp: str | None) -> _dt.datetime | None:
    if not stamp:
        return None
    try:
        when = _dt.datetime.fromisoformat(stamp)
    except ValueError:
        return None
    return when if when.tzinfo is not None else when.replace(tzinfo=_dt.timezone.utc)


def periods_overlap(found: RunResults, left: RunResults, labels: tuple[str, str]) -> str:
    """"" when the as-left measurement began after the as-found one ended (or a period is unknown); else
    what is wrong, in a sentence. Two real-clock measurements that are no pair raise :class:`NotAPair`."""
    a0, a1, b0, b1 = (_utc(t) for t in (found.started_utc, found.finished_utc, left.started_utc, left.finished_utc))
    if a0 is None or a1 is None or b0 is None or b1 is None or b0 >= a1:
        return ""
    periods = (f"as found ({labels[0]}) measured {measurement_dates(found)}, as left ({labels[1]}) "
               f"{measurement_dates(left)}")
    order = ("the as-left measurement ended before the as-found one began" if b1 <= a0 else
             "the two measurement periods overlap")
    if found.clock != "virtual" and left.clock != "virtual":
        give = " (give the as-found run first)" if b1 <= a0 else ""
        raise NotAPair(f"{periods}: {order}, so they cannot be an as-found / as-left pair: the as-left run is measured "
                       f"after the as-found run has ended, the adjustment between{give}")
    return (f"The measurement periods are not those of an as-found / as-left pair ({order}: {periods}). A simulated "
            "measurement's period is the one it stands for on its virtual clock, not when it ran: these two runs "
            "show how the certificate reads, not an adjustment between two measurements.")


def _value(v: float | None, u: float | None) -> str:
    return "–" if v is None else value_text(v, u) + "″"


def as_found_as_left_model(found: RunResults, left: RunResults, comparison: dict[str, Any], out_dir: Path,
                           figure: str, labels: tuple[str, str], method: CertifiedMethod) -> Certificate:
    """The certificate: the as-left run's (of ``method``), its results replaced by both runs' side by side."""
    caption = ("mean positioning deviation per target and direction as found (A) and as left (B), each with its U band "
               "(k = 2).")
    overlap = periods_overlap(found, left, labels)  # NotAPair: two real measurements that cannot be one
    cert = build_certificate(left, out_dir, method, [(figure, caption)])
    identification = []
    for item in cert.identification.items:
        if item.label == "Date of measurement":
            identification += [Item(label="As found (before adjustment)", value=f"{measurement_dates(found)}; {labels[0]}"),
                               Item(label="As left (after adjustment)", value=f"{measurement_dates(left)}; {labels[1]}")]
            continue
        if item.label == "Departures from the method":
            both = sorted(set(iso_departures(found)) | set(iso_departures(left)))
            item = Item(label=item.label, value="; ".join(both) + ". The parameters are computed as ISO 230-2 defines them."
                        if both else "none")
        identification.append(item)
    u_found, u_left = parameter_uncertainties(found), parameter_uncertainties(left)
    iso_found = found.evaluation.iso230_2 if found.evaluation else None
    iso_left = left.evaluation.iso230_2 if left.evaluation else None
    brief, table = [], []
    for key, sym, desc in ISO_KEYS:
        a = getattr(iso_found, key) if iso_found else None
        b = getattr(iso_left, key) if iso_left else None
        if a is None and b is None:
            continue
        value, u = (f"{_value(a, u_found.get(key))} → {_value(b, u_left.get(key))}",
                    f"{u_text(u_found.get(key))}″ / {u_text(u_left.get(key))}″")
        table.append(ParameterRow(symbol=sym, meaning=desc, value_arcsec=value, expanded_uncertainty_arcsec=u))
        if key in BRIEF:
            brief.append(KeyResult(quantity=f"{ISO_SYMBOL[key]}: {ISO_MEANING[key]} (as found → as left)", value_arcsec=value,
                                   expanded_uncertainty_arcsec=u))
    changed, compared = comparison["targets_changed"], comparison["targets_compared"]
    rows = [[f"{r['target_deg']:g}", "↑" if r["direction"] > 0 else "↓", f"{r['a_arcsec']:+.2f}", f"{r['b_arcsec']:+.2f}",
             f"{r['change_arcsec']:+.2f}", u_text(r["combined_U_arcsec"]),
             "–" if r["exceeds_U"] is None else "yes" if r["exceeds_U"] else "no"] for r in comparison["per_target"]]
    parameters = cert.parameters.model_copy(update={
        "heading": "ISO 230-2 parameters: as found → as left (U as found / as left, k = 2)", "rows": table, "vdi_rows": []}) \
        if cert.parameters else None
    marks = [m for m in (marking(found), marking(left)) if m]  # either run calibrating nothing makes this no calibration
    signed = (f"Not itself signed: written from two runs. As found: {signature_line(found)} As left: "
              f"{signature_line(left)}")
    return cert.model_copy(update={
        "header": cert.header.model_copy(update={
            "title": "Calibration certificate",
            "subtitle": "Angular positioning deviation of a rotary axis, as found and as left",
            "marking": marks[0] if marks else "",
            "footer": cert.header.footer if cert.header.marking or not marks
            else f"{marks[0].partition(':')[0]} · {cert.header.footer}"}),
        "sign_off": cert.sign_off.model_copy(update={"electronic_signature": signed}),
        "identification": cert.identification.model_copy(update={
            "items": identification, "notes": ([overlap] if overlap else []) + list(cert.identification.notes)}),
        "result_in_brief": cert.result_in_brief.model_copy(update={"rows": [
            KeyResult(quantity="change of the deviation per target and direction (as left − as found)",
                      value_arcsec=f"{changed} of {compared} beyond U_c", expanded_uncertainty_arcsec="U_c: page 2")] + brief}),
        "parameters": parameters,
        "conformity": cert.conformity.model_copy(update={"heading": "Conformity of the item as left"})
        if cert.conformity else None,
        "deviations": Table(
            heading="Result: positioning deviation per target and direction, as found and as left",
            note=("Deviation = actual − commanded angle (arcsec), relative to the first target of the first direction. "
                  "Change = as left − as found; U_c = 2·√(u_found² + u_left²), the expanded uncertainty of the "
                  "change (k = 2, about 95 %; the two measurements are independent)."),
            header=["target / °", "direction", "as found / ″", "as left / ″", "change / ″", "U_c (k = 2) / ″", "beyond U_c"],
            rows=rows)})
