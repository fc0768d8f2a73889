"""The run's report: report.md, and the calibration certificate report.html and report.pdf.

The certificate carries what ISO/IEC 17025:2017 7.8.2.1 and 7.8.4.1 ask of one (where it
applies): page 1 names the laboratory, the certificate, the customer, the item, the method and
standards with their editions, the dates, the conditions, the result in brief with its U and k,
the conformity verdict with its rule, what the uncertainty leaves out, the traceability, that
the results relate to the item calibrated, and who performed and approved it; then the result per
target and direction, the ISO 230-2 and VDI 3441 parameters, the figures, the budget, the method,
the reference standards and instruments, the conditions, the control of the machine and the
run's events. Every page of the PDF ends with "page N of M". One model (:func:`report_model`, a
pure function of the run's results) feeds both renderers. report.md is the Markdown frame every
run shares around its method's body.
"""

from __future__ import annotations

import base64
import datetime as _dt
from pathlib import Path
from typing import Any

from rtcal.deliverables.comparison import mean_curve
from rtcal.deliverables.departures import departures, parameters_label
from rtcal.deliverables.deviations import PositioningDeviations
from rtcal.deliverables.evaluation import UNCONFIRMED
from rtcal.deliverables.rounding import u_text, value_text
from rtcal.results.model import (EnvironmentSummary, Event, InstrumentRecord, RunResults)

ISO_KEYS = (("E_up", "E↑", "unidirectional systematic positional deviation, positive approach"),
            ("E_down", "E↓", "unidirectional systematic positional deviation, negative approach"),
            ("E", "E", "bidirectional systematic positional deviation"),
            ("M", "M", "range of the mean bidirectional positional deviation"),
            ("B", "B", "reversal value (max |B_i|)"), ("B_mean", "B mean", "mean reversal value"),
            ("R_up", "R↑", "unidirectional repeatability, positive"), ("R_down", "R↓", "unidirectional repeatability, negative"),
            ("R", "R", "bidirectional repeatability"), ("A_up", "A↑", "unidirectional accuracy, positive"),
            ("A_down", "A↓", "unidirectional accuracy, negative"), ("A", "A", "bidirectional accuracy"))
ISO_SYMBOL = {key: sym for key, sym, _ in ISO_KEYS} | {"band": "band"}
ISO_MEANING = {key: desc for key, _, desc in ISO_KEYS} | {"band": "every mean deviation x̄↑, x̄↓ within ±limit"}
VDI_KEYS = (("Pa", "Pa", "position deviation"), ("P", "P", "position uncertainty (VDI's term: a span of the data, not "
                                                               "a measurement uncertainty)"),
            ("Ps_max", "Ps max", "positional scatter, max"),
            ("Ps_mean", "Ps mean", "positional scatter, mean"), ("U_max", "U max", "reversal span, max (VDI's U, not an "
                                                                                  "uncertainty)"),
            ("U_mean", "U mean", "reversal span, mean (VDI's U)"))

STANDARDS = (
    "ISO 230-2:2014 (E, M, B, R, A)",
    "VDI/DGQ 3441:1977 (Pa, P, Ps, U)",
    "JCGM 100:2008 (GUM: uncertainty)",
)
DECISION_STANDARDS = {"simple": "ILAC-G8:09/2019 (decision rule: simple acceptance)",
                      "guarded": "ISO 14253-1:2017 (decision rule: guarded acceptance)"}
UNCERTAINTY_STATEMENT = (
    "The expanded uncertainty U is the standard uncertainty u multiplied by the coverage factor k = 2, which for a "
    "normal distribution corresponds to a coverage probability of about 95 %. The standard uncertainty was determined "
    "in accordance with the GUM (JCGM 100:2008) from the budget listed in this {doc}; rtcal's uncertainty "
    "model is validated against the errors of Monte Carlo simulations of the measurement.")
SIGNING_STATEMENT = (
    "This {doc} is issued in electronic form. It was approved for issue electronically by {approver} on {date} in the "
    "laboratory's records; it carries no handwritten signature.")
RELATES_STATEMENT = (
    "The results relate only to the item calibrated, at the time and under the conditions of the measurement stated. "
    "This {doc} shall not be reproduced except in full without the written approval of the issuing laboratory.")
CERTIFICATE_NEEDS = (("laboratory", "the laboratory (metadata.laboratory)"),
                     ("certificate_number", "a certificate number (metadata.certificate_number)"),
                     ("approved_by", "who approved it (metadata.approved_by)"))
ROLES = {"polygon": "reference standard: angle (face errors from its certificate)",
         "autocollimator": "reference standard: angle", "laser_tracer": "reference standard: length",
         "environment": "measuring instrument: conditions", "cmm": "positions the reflector",
         "encoder": "the item's encoder (analysed)", "dial_indicator_1": "measuring instrument: shaft motion",
         "dial_indicator_2": "measuring instrument: shaft motion", "stage": "the item's drive (commanded)"}
REFERENCE_STANDARDS = ("polygon", "autocollimator", "laser_tracer")


def fmt(v: float | None, spec: str) -> str:
    """A value as ``format(v, spec)``; "–" for a missing one."""
    return "–" if v is None else format(v, spec)


def _fmt(v: float | None, digits: int = 2) -> str:
    return fmt(v, f".{digits}f")


def largest(values: list[float | None]) -> float | None:
    """The largest of the values present (None: none is)."""
    present = [v for v in values if v is not None]
    return max(present) if present else None


def smallest(values: list[float | None]) -> float | None:
    """The smallest of the values present (None: none is)."""
    present = [v for v in values if v is not None]
    return min(present) if present else None


def status_lines(results: RunResults) -> list[str]:
    """One line per estimator that did not converge or could not run (empty when all is well)."""
    return [f"estimator {name} {st.status}: {st.message}" for name, st in results.solver_status.items()
            if st.status != "converged"]


def _when(stamp: str | None) -> str:
    """An ISO 8601 UTC time as ``YYYY-MM-DD HH:MM`` ("?" when unknown)."""
    if not stamp:
        return "?"
    try:
        return _dt.datetime.fromisoformat(stamp).astimezone(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M")
    except ValueError:
        return stamp[:40]


def measurement_dates(results: RunResults) -> str:
    """From the first to the last reading, UTC (one day written once)."""
    start, end = _when(results.started_utc), _when(results.finished_utc)
    simulated = " (simulated measurement: virtual clock)" if results.clock == "virtual" else ""
    if start[:10] == end[:10] and start != "?":
        return f"{start} – {end[11:]} UTC{simulated}"
    return f"{start} – {end} UTC{simulated}"


def environment_of(results: RunResults) -> EnvironmentSummary | None:
    """The conditions the environment sensor recorded (None: no sensor), as the results' method reads them."""
    from rtcal.methods import METHODS

    return METHODS[results.method].conditions(results)


def condition_label(name: str) -> str:
    """A condition's human label with its unit, from the results model's description: "air temperature / °C"."""
    text = EnvironmentSummary.model_fields[name].description or name
    quantity, _, unit = text.rpartition(", ")
    return f"{quantity} / {unit}" if quantity else text


def conditions(results: RunResults) -> list[tuple[str, str]]:
    """(label, "min … max (mean …)") per recorded condition; one "not recorded" row without a sensor."""
    env = environment_of(results)
    if env is None:
        return [("air and table", "not recorded (the procedure has no environment instrument)")]
    return [(condition_label(name), _range(v.min, v.max) + f" (mean {v.mean:g})") for name, v in env.items()]


def _range(lo: float, hi: float, sep: str = " – ") -> str:
    """A condition's range as min – max, also when it did not change (20 – 20: read, and constant)."""
    return f"{lo:g}{sep}{hi:g}"


def conditions_in_brief(results: RunResults) -> str:
    env = environment_of(results)
    if env is None:
        return "not recorded (no environment sensor)"
    return "; ".join(f"{condition_label(n).split(' / ')[0]} {_range(v.min, v.max)} {condition_label(n).split(' / ')[-1]}"
                     for n, v in env.items())


def instruments_used(results: RunResults) -> list[str]:
    """The procedure's instruments this run used, then its reference standards (from the procedure
    models: one truth of which instruments a method has; the optional sensor when it recorded)."""
    from rtcal.methods import METHODS

    model = METHODS[results.method].procedure_model
    names = []
    for name, field in model.model_fields["instruments"].annotation.model_fields.items():
        optional = field.default is None
        if not optional or (name == "environment" and environment_of(results) is not None) or (
                isinstance(results.instruments, dict) and name in results.instruments):
            names.append(name)
    names += [n for n in getattr(model, "REFERENCE_STANDARDS", ())]
    return names + [n for n in results.metadata.instruments if n not in names]


def instrument_rows(results: RunResults) -> list[tuple[str, ...]]:
    """(instrument, role, id, its certificate, calibrated by, due) per instrument and standard."""
    records = results.metadata.instruments
    none = InstrumentRecord(id="", calibration_due="")
    roles = dict(ROLES)
    from rtcal.methods import METHODS

    roles.update(METHODS[results.method].instrument_roles(results))  # a method's own, e.g. a polygon separated by closure
    return [(name.replace("_", " "), roles.get(name, ""), records.get(name, none).id or "not recorded",
             records.get(name, none).certificate_number or "–", records.get(name, none).calibrated_by or "–",
             records.get(name, none).calibration_due or "–") for name in instruments_used(results)]


def connections(results: RunResults) -> str:
    """Where the instruments were reached."""
    if isinstance(results.instruments, dict):
        return "; ".join(f"{k.replace('_', ' ')}: {v}" for k, v in results.instruments.items())
    return f"every instrument simulated in process (bench {Path(results.bench or '').name or 'ideal'}, random sequence no. {results.seed})"


def traceability(results: RunResults) -> str:
    """The metadata's statement, else one made from the reference standards' certificates, else "not stated"."""
    meta = results.metadata
    if meta.traceability:
        return meta.traceability
    used = set(instruments_used(results))
    cited = [(n, meta.instruments[n]) for n in REFERENCE_STANDARDS if n in used and n in meta.instruments
             and meta.instruments[n].certificate_number]
    if not cited:
        return ("Not stated: the procedure's metadata gives no traceability statement and no certificate of a reference "
                "standard (metadata.traceability, metadata.instruments.<name>.certificate_number).")
    refs = "; ".join(f"{n.replace('_', ' ')} {r.id or ''} (certificate {r.certificate_number}"
                     + (f", {r.calibrated_by}" if r.calibrated_by else "") + ")" for n, r in cited)
    return (f"The results are traceable to the SI through the reference standards used: {refs}. Their "
            "certificates state their own traceability to national standards.")


def control_lines(results: RunResults) -> tuple[str, list[str]]:
    """(one line for page 1, the details) of the run's control of the machine and its checks."""
    c = results.control
    if c is None:
        return "not recorded (results written before schema 1.1)", []
    how = "; ".join(f"{k.replace('_', ' ')}: {v.split(':')[0]}" for k, v in c.instruments.items())
    brief = (f"{'exclusive' if c.exclusive else 'exclusive control not known from every protocol'} ({how}); every "
             f"motion and reading checked against the commands: "
             + (f"{plural(c.rejected_attempts, 'reading')} contradicted them, rejected and taken again" if c.rejected_attempts
                else "none contradicted them"))
    details = [f"{k}: {v}" for k, v in c.instruments.items()] + [f"check — {t}" for t in c.checks]
    return brief, details


def iso_departures(results: RunResults) -> list[str]:
    """How the run's positioning test departs from ISO 230-2's (empty: it follows it, or there is none)."""
    if results.positioning_deviations is None:
        return []
    return departures(PositioningDeviations.from_model(results.positioning_deviations))


def estimate_name(results: RunResults) -> str:
    """The recommended estimate in words (the method's outputs name it), never its key."""
    from rtcal.deliverables.method_outputs import outputs_for

    return getattr(outputs_for(results), "estimate_words", lambda: "the recommended estimate")()


def key_results(results: RunResults, uncertainties: dict[str, float | None]) -> list[tuple[str, str, str]]:
    """The result in brief: the deviation's range and U, and the main ISO 230-2 parameters with U
    (labelled as ISO 230-2's only when the test follows it)."""
    rows = []
    e = results.recommended_estimate()
    if e is not None:
        cum = e.cumulative_deviation_arcsec
        pd = results.positioning_deviations
        targets = len({round(t, 6) for t in pd.target_deg}) if pd else len(cum)
        dirs = len(set(pd.direction)) if pd else 1
        U = largest(e.cumulative_expanded_uncertainty_arcsec)
        rows.append(("positioning deviation ECC (mean per target and direction)",
                     f"{value_text(smallest(cum), U, '+')}″ … {value_text(largest(cum), U, '+')}″ over {targets} targets"
                     + (" in both directions" if dirs == 2 else " in one direction"), f"U ≤ {u_text(U)}″"))
    iso = results.evaluation.iso230_2 if results.evaluation else None
    if iso is not None:
        label = parameters_label(iso_departures(results))
        prefix = "" if label.startswith("ISO") else "as ISO 230-2 defines it, not an ISO 230-2 result (see Departures): "
        for key in ("E", "M", "B", "R", "A", "E_up", "E_down"):
            value = getattr(iso, key)
            if value is None or (key in ("E_up", "E_down") and iso.E is not None):
                continue
            u = uncertainties.get(key)
            rows.append((f"{ISO_SYMBOL[key]}: {prefix}{ISO_MEANING[key]}", f"{value_text(value, u)}″", "U " + u_text(u) + "″"))
    return rows


def report_model(results: RunResults, run_dir: Path, figures: list[tuple[str, str]], method_text: list[str],
                 method_name: str = "") -> dict[str, Any]:
    """Everything the certificate shows, as strings and rows, from the run's results."""
    from rtcal.deliverables.conformity import parameter_uncertainties
    from rtcal.deliverables.method_outputs import outputs_for

    meta = results.metadata
    missing = [what for key, what in CERTIFICATE_NEEDS if not getattr(meta, key)]
    issued = meta.date_of_issue or _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d")
    uncertainties = parameter_uncertainties(results)
    conformity = results.conformity
    departed = iso_departures(results)
    standards = list(STANDARDS) + ([DECISION_STANDARDS[conformity.decision_rule]] if conformity else [])
    if departed:
        standards[0] = "ISO 230-2:2014 (its formulas for E, M, B, R, A applied to a test that departs from its test: see Departures)"
    item = ", ".join(x for x in (meta.machine, f"axis {meta.axis}" if meta.axis else "",
                                 f"serial number {meta.serial_number}" if meta.serial_number else "") if x)
    control_brief, control_details = control_lines(results)
    identification = [
        ("Certificate number", meta.certificate_number or "not given"),
        ("Date of issue", issued),
        ("Customer", ", ".join(x for x in (meta.customer, meta.customer_address) if x) or "not given"),
        ("Item calibrated", item or "not given"),
        ("Condition on receipt", getattr(meta, "condition_on_receipt", "") or "not recorded"),
        ("Place of calibration", meta.location or "not given"),
        ("Date of measurement", measurement_dates(results)),
        ("Method", method_name or results.method),
        ("Procedure", f"{results.procedure.name or '(untitled)'} ({Path(results.procedure.path).name})"),
        ("Standards applied", "; ".join(standards)),
        ("Departures from the method", ("; ".join(departed) + ". The parameters are computed as ISO 230-2 defines them; "
                                        "they are not ISO 230-2 results.") if departed else "none"),
        ("Conditions during the measurement", conditions_in_brief(results)),
        ("Control of the machine", control_brief),
    ]
    if isinstance(results.instruments, str):
        identification.append(("Instruments", "simulated: every instrument and the table are simulated on a model bench "
                                              f"({Path(results.bench or '').name or 'ideal'}, random sequence no. {results.seed}); "
                                              "a demonstration, not a measurement of a real item"))
    warnings = [f"Estimator {n} {st.status}: {st.message}" for n, st in results.solver_status.items()
                if st.status != "converged"]
    if results.bench is not None and results.bench.startswith("ideal bench"):
        warnings.append(results.bench)
    if results.faults or results.skipped_readings:
        warnings.append(f"{plural(results.faults, 'instrument fault')} and {plural(results.skipped_readings, 'skipped reading')} during "
                        "the run (see Run).")
    rows = []
    if results.positioning_deviations is not None:
        table = PositioningDeviations.from_model(results.positioning_deviations)
        curve = mean_curve(table, results, wrap=False)
        counts: dict[tuple[float, int], int] = {}
        for t, d in zip(table.target_deg, table.direction):
            counts[(round(float(t), 6), int(d))] = counts.get((round(float(t), 6), int(d)), 0) + 1
        for key in curve:  # in the measurement's order
            x, u = curve[key]
            rows.append((f"{key[0]:g}", "↑" if key[1] > 0 else "↓", value_text(x, 2 * u, "+"), u_text(u), u_text(2 * u),
                         str(counts.get(key, ""))))
    iso = results.evaluation.iso230_2 if results.evaluation else None
    vdi = results.evaluation.vdi3441 if results.evaluation else None
    budget_rows = []
    not_included: list[str] = []
    e = results.recommended_estimate()
    if e is not None:
        b = e.uncertainty_budget
        for c in b.components:
            stated = c.note if "," in c.unit else f"{c.input_sigma:.3g} {c.unit}"  # several inputs: say them
            budget_rows.append((c.source, c.type, stated + (" (from the data)" if c.estimated_from_data else ""),
                                _fmt(largest(c.contribution_arcsec), 3)))
        comb = largest(b.combined_arcsec)
        budget_rows.append(("combined standard uncertainty u", "", "", _fmt(comb, 3)))
        budget_rows.append(("expanded uncertainty U (k = 2), rounded up to two digits", "", "", u_text(None if comb is None else 2 * comb)))
        not_included = b.not_included
    events: dict[str, int] = {}
    for ev in results.events:
        events[ev.kind] = events.get(ev.kind, 0) + 1
    iso_notes = iso.notes if iso else []
    verdict = None
    if conformity is not None:
        verdict = {
            "verdict": conformity.verdict, "rule": conformity.rule,
            "rows": [(ISO_SYMBOL[k], ISO_MEANING[k] + (f" (decided at {c.target_deg:g}° {'↑' if c.direction == 1 else '↓'})"
                                                       if c.target_deg is not None and c.direction is not None else ""),
                      f"{c.limit_arcsec:g}", value_text(c.value_arcsec, c.expanded_uncertainty_arcsec),
                      u_text(c.expanded_uncertainty_arcsec), u_text(c.guard_band_arcsec) if c.guard_band_arcsec else "0",
                      c.verdict) for k, c in conformity.per_limit.items()],
        }
    performed = meta.performed_by or meta.operator
    doc = "report" if missing else "certificate"
    footer = " · ".join(x for x in (meta.laboratory or results.procedure.name or results.method,
                                    f"Certificate {meta.certificate_number}" if meta.certificate_number else "") if x)
    return {
        "title": "Calibration certificate" if not missing else "Calibration report",
        "subtitle": "Angular positioning deviation of a rotary axis",
        "procedure_name": results.procedure.name or results.method,
        "laboratory": meta.laboratory or "Laboratory not stated", "laboratory_address": meta.laboratory_address,
        "certificate_number": meta.certificate_number,
        "not_certificate": ("Not a calibration certificate: the procedure's metadata does not give " + ", ".join(missing) + "."
                            if missing else ""),
        "identification": identification, "warnings": warnings,
        "key_results": key_results(results, uncertainties),
        "uncertainty_statement": UNCERTAINTY_STATEMENT.format(doc=doc), "not_included": not_included,
        "conformity": verdict, "traceability": traceability(results), "statement": RELATES_STATEMENT.format(doc=doc),
        "signing": SIGNING_STATEMENT.format(doc=doc, approver=meta.approved_by, date=issued) if meta.approved_by else
        f"This {doc} has not been approved for issue (the procedure's metadata names no approver).",
        "signatures": [("Performed by", performed or "not stated"), ("Approved by", meta.approved_by or "not approved"),
                       ("Date of issue", issued)],
        "instruments": instrument_rows(results), "connections": connections(results),
        "rows": rows, "recommended": estimate_name(results),
        "rows_title": "Result: positioning deviation per target and direction",
        "rows_header": ["target / °", "direction", "deviation / ″", "u / ″", "U (k = 2) / ″", "runs"],
        "rows_note": ("Deviation = actual − commanded angle (arcsec), relative to the first target of the first direction; "
                      "u standard uncertainty, U = 2u expanded uncertainty (k = 2, about 95 %). Estimate: "
                      f"{estimate_name(results)}."),
        "iso_title": ("ISO 230-2:2014 parameters" if not departed else
                      "Positioning parameters computed as ISO 230-2 defines them (not ISO 230-2 results: the test departs "
                      "from it, see page 1)"),
        "iso": [(sym, desc, value_text(getattr(iso, key), uncertainties.get(key)), u_text(uncertainties.get(key)))
                for key, sym, desc in ISO_KEYS if getattr(iso, key) is not None] if iso else [],
        "vdi": [(sym, desc, _fmt(getattr(vdi, key))) for key, sym, desc in VDI_KEYS] if vdi else [],
        "evaluation_notes": [n for n in iso_notes + [n for n in (vdi.notes if vdi else []) if n not in iso_notes]
                             if n not in UNCONFIRMED.values()],  # what is not confirmed: docs/evaluation.md, not the customer's
        "figures": [(run_dir / f, f"Figure {n}: {caption}") for n, (f, caption) in
                    enumerate([(f, c) for f, c in figures if (run_dir / f).exists()], start=1)],
        "budget": budget_rows,
        "tables": outputs_for(results).certificate_tables(),  # the method's own, e.g. the axis's location errors (ISO 230-7)
        "method": method_text, "environment": conditions(results), "control": control_details,
        "events": ", ".join(f"{k}: {n}" for k, n in events.items()) or "none",
        "raw_readings": results.raw_readings, "skipped": results.skipped_readings, "faults": results.faults,
        "run_counts": f"{plural(results.raw_readings, 'planned reading')} taken, {results.skipped_readings} skipped, "
                      f"{plural(results.faults, 'instrument fault')}",
        "software": f"rtcal {results.rtcal_version}", "measured": measurement_dates(results),
        "footer": footer, "footer_css": "".join(ch for ch in footer if ch not in '"\\<>&\n\r'),
    }


def write_html(model: dict[str, Any], path: Path) -> Path:
    from jinja2 import Environment, FileSystemLoader, select_autoescape

    env = Environment(loader=FileSystemLoader(Path(__file__).parent / "templates"), autoescape=select_autoescape(["j2"]))
    figures = [(base64.b64encode(p.read_bytes()).decode("ascii"), caption) for p, caption in model["figures"]]
    path.write_text(env.get_template("report.html.j2").render(m=model, figures=figures), encoding="utf-8")
    return path


def write_pdf(model: dict[str, Any], path: Path) -> Path:
    """A4 pages with reportlab: the same content as the HTML, in the same order; every page ends
    with "page N of M" (drawn last on the page, after the certificate's number)."""
    from reportlab.lib import colors
    from reportlab.lib.pagesizes import A4
    from reportlab.lib.styles import ParagraphStyle, getSampleStyleSheet
    from reportlab.lib.units import mm
    from reportlab.pdfbase import pdfmetrics
    from reportlab.pdfbase.ttfonts import TTFont
    from reportlab.pdfgen.canvas import Canvas
    from reportlab.platypus import (BaseDocTemplate, CondPageBreak, Frame, Image, KeepTogether, PageTemplate, Paragraph, Spacer,
                                    Table, TableStyle)

    font, bold = _fonts(pdfmetrics, TTFont)
    styles = getSampleStyleSheet()
    body = ParagraphStyle("body", parent=styles["BodyText"], fontName=font, fontSize=8.5, leading=11)
    small = ParagraphStyle("small", parent=body, fontSize=7.5, leading=8.8)
    h1 = ParagraphStyle("h1", parent=styles["Heading1"], fontName=bold, fontSize=16, spaceAfter=2, spaceBefore=0)
    h2 = ParagraphStyle("h2", parent=styles["Heading2"], fontName=bold, fontSize=11, spaceBefore=4, spaceAfter=2, keepWithNext=1)
    lab = ParagraphStyle("lab", parent=body, fontName=bold, fontSize=10, leading=12)
    width = A4[0] - 30 * mm

    def esc(text: str) -> str:
        return str(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")

    def table(rows, header, col_widths=None, font_size=8, shade_first_column=False):
        head = [[Paragraph(f"<b>{esc(h)}</b>", small) for h in header]] if header else []
        data = head + [[Paragraph(esc(c), small) for c in r] for r in rows]
        t = Table(data, colWidths=col_widths, repeatRows=1 if header else 0)
        style = [("GRID", (0, 0), (-1, -1), 0.3, colors.grey), ("VALIGN", (0, 0), (-1, -1), "TOP"),
                 ("FONTSIZE", (0, 0), (-1, -1), font_size), ("TOPPADDING", (0, 0), (-1, -1), 1),
                 ("BOTTOMPADDING", (0, 0), (-1, -1), 1.2)]
        if header:
            style.append(("BACKGROUND", (0, 0), (-1, 0), colors.HexColor("#e8eef5")))
        if shade_first_column:
            style.append(("BACKGROUND", (0, 0), (0, -1), colors.HexColor("#e8eef5")))
        t.setStyle(TableStyle(style))
        return t

    def boxed(paragraphs, colour):
        t = Table([[paragraphs]], colWidths=[width])
        t.setStyle(TableStyle([("BOX", (0, 0), (-1, -1), 0.8, colour), ("BACKGROUND", (0, 0), (-1, -1), colors.HexColor("#fff8e1")),
                               ("TOPPADDING", (0, 0), (-1, -1), 3), ("BOTTOMPADDING", (0, 0), (-1, -1), 3)]))
        return t

    m = model
    head = Table([[[Paragraph(esc(m["laboratory"]), lab), Paragraph(esc(m["laboratory_address"]), small)],
                   [Paragraph(esc(m["title"]), h1), Paragraph(esc(m["subtitle"]), small)]]],
                 colWidths=[width * 0.45, width * 0.55])
    head.setStyle(TableStyle([("VALIGN", (0, 0), (-1, -1), "TOP"), ("LINEBELOW", (0, 0), (-1, 0), 0.8, colors.HexColor("#3a5a80")),
                              ("LEFTPADDING", (0, 0), (-1, -1), 0), ("BOTTOMPADDING", (0, 0), (-1, -1), 4)]))
    story: list[Any] = [head, Spacer(1, 3 * mm)]
    if m["not_certificate"]:
        story += [boxed([Paragraph(f"<b>{esc(m['not_certificate'])}</b>", body)], colors.HexColor("#c0392b")), Spacer(1, 2 * mm)]
    story.append(table(m["identification"], None, [50 * mm, width - 50 * mm], shade_first_column=True))
    for w in m["warnings"]:
        story += [Spacer(1, 1.5 * mm), Paragraph(f"<b>Note:</b> {esc(w)}", body)]
    story += [Paragraph("Result in brief", h2), table(m["key_results"], ["quantity", "value", "U (k = 2)"],
                                                       [width - 88 * mm, 66 * mm, 22 * mm]),
              Spacer(1, 1.5 * mm), Paragraph(esc(m["uncertainty_statement"]), small)]
    if m["not_included"]:
        story += [Spacer(1, 2 * mm), boxed([Paragraph("<b>The uncertainty stated does not include:</b>", body)]
                                           + [Paragraph("• " + esc(n), small) for n in m["not_included"]],
                                           colors.HexColor("#d68910"))]
    if m["conformity"]:
        c = m["conformity"]
        story += [Paragraph(f"{esc(c.get('title', 'Conformity'))}: {c['verdict'].upper()}", h2), Paragraph(esc(c["rule"]), small), Spacer(1, 1.5 * mm),
                  table(c["rows"], ["limit", "parameter", "limit / ″", "value / ″", "U / ″", "guard band / ″", "verdict"],
                        [12 * mm, width - 101 * mm, 16 * mm, 17 * mm, 14 * mm, 24 * mm, 18 * mm])]
    story += [Paragraph("Traceability", h2), Paragraph(esc(m["traceability"]), body), Spacer(1, 1.5 * mm),
              Paragraph(esc(m["statement"]), body)]

    story += [CondPageBreak(60 * mm), Paragraph(esc(m["rows_title"]), h2), Paragraph(esc(m["rows_note"]), small),
              Spacer(1, 1.5 * mm), table(m["rows"], m["rows_header"])]
    if m["iso"]:
        story += [KeepTogether([Paragraph(esc(m["iso_title"]), h2),
                                table(m["iso"], ["symbol", "meaning", "value / ″", "U (k = 2) / ″"],
                                      [18 * mm, width - 62 * mm, 22 * mm, 22 * mm])])]
        if m["vdi"]:
            story += [KeepTogether([Paragraph("VDI/DGQ 3441 parameters (the guideline's own symbols)", h2),
                                    table(m["vdi"], ["VDI 3441 symbol", "VDI 3441 meaning", "value / ″"],
                                          [26 * mm, width - 48 * mm, 22 * mm])])]
        story += [Paragraph(esc(n), small) for n in m["evaluation_notes"]]
    for t in m.get("tables", []):
        story += [KeepTogether([Paragraph(esc(t["heading"]), h2), Paragraph(esc(t["note"]), small), Spacer(1, 1.5 * mm),
                                table(t["rows"], t["header"], [18 * mm, width - 74 * mm, 28 * mm, 28 * mm]
                                      if len(t["header"]) == 4 else None)])]
    for p, caption in m["figures"]:
        from reportlab.lib.utils import ImageReader

        iw, ih = ImageReader(str(p)).getSize()
        fw = 0.76 * width if ih / iw < 0.7 else width  # three wide figures fit a page; a tall one takes its width
        story += [KeepTogether([Spacer(1, 2 * mm), Image(str(p), width=fw, height=fw * ih / iw), Paragraph(esc(caption), small)])]
    if m["budget"]:
        story += [KeepTogether([Paragraph("Uncertainty budget (largest contribution over the targets)", h2),
                                table(m["budget"], ["source", "type", "input σ", "u / ″"], [70 * mm, 12 * mm, 55 * mm, 28 * mm])])]
        story += [Paragraph(f"Not included: {esc(n)}", small) for n in m["not_included"]]
    story += [Paragraph("Method", h2)] + [Paragraph(esc(t), body) for t in m["method"]]
    story += [KeepTogether([Paragraph("Reference standards and instruments", h2),
              table(m["instruments"], ["instrument", "role", "id", "certificate", "calibrated by", "due"],
                    [24 * mm, 32 * mm, width - 132 * mm, 28 * mm, 28 * mm, 20 * mm])]),
              Paragraph("Connections: " + esc(m["connections"]), small)]
    story += [KeepTogether([Paragraph("Conditions during the measurement", h2),
                            table(m["environment"], ["quantity", "min – max over the run (mean)"], [55 * mm, width - 55 * mm])])]
    if m["control"]:
        story += [Paragraph("Control of the machine", h2)] + [Paragraph("• " + esc(t), small) for t in m["control"]]
    story += [Paragraph("Run", h2),
              Paragraph(f"Measured {esc(m['measured'])}; {esc(m['run_counts'])}; events: {esc(m['events'])}. Software: "
                        f"{esc(m['software'])}.", body),
              Spacer(1, 4 * mm), Paragraph("<b>End of certificate.</b>" if not m["not_certificate"] else "<b>End of report.</b>", body)]

    footer_left = m["footer"]

    class NumberedCanvas(Canvas):
        """Keeps each page until the count is known, then draws its footer last: "page N of M"."""

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self._pages: list[dict] = []

        def showPage(self):
            self._pages.append(dict(self.__dict__))
            self._startPage()

        def save(self):
            total = len(self._pages)
            for state in self._pages:
                self.__dict__.update(state)
                self.setFont(font, 7)
                self.setStrokeColor(colors.HexColor("#3a5a80"))
                self.line(15 * mm, 13 * mm, A4[0] - 15 * mm, 13 * mm)
                self.drawString(15 * mm, 9 * mm, footer_left[:120])
                self.drawRightString(A4[0] - 15 * mm, 9 * mm, f"page {self._pageNumber} of {total}")
                super().showPage()
            super().save()

    signatures = table([[f"{k}: {v}" for k, v in m["signatures"]], [m["signing"], "", ""]], None, [width / 3] * 3)
    signatures.setStyle(TableStyle([("SPAN", (0, 1), (-1, 1))]))  # how it is signed, under who signed it
    sign_h = signatures.wrap(width, 40 * mm)[1] + 4 * mm

    def sign(canvas, doc):  # page 1's foot: who performed and approved it, whatever the page holds above
        signatures.drawOn(canvas, 15 * mm, 17 * mm)

    first = Frame(15 * mm, 17 * mm + sign_h, width, A4[1] - 13 * mm - 17 * mm - sign_h, id="first", leftPadding=0,
                  rightPadding=0, topPadding=0, bottomPadding=0)
    later = Frame(15 * mm, 17 * mm, width, A4[1] - 30 * mm, id="later", leftPadding=0, rightPadding=0, topPadding=0,
                  bottomPadding=0)
    doc = BaseDocTemplate(str(path), pagesize=A4, title=f"{m['title']} {m['certificate_number']}".strip(), author=m["laboratory"])
    doc.addPageTemplates([PageTemplate("first", [first], onPage=sign, autoNextPageTemplate="later"),
                          PageTemplate("later", [later])])
    doc.build(story, canvasmaker=NumberedCanvas)
    return path


def _fonts(pdfmetrics, TTFont) -> tuple[str, str]:
    """DejaVu Sans from matplotlib (it has ″, ↑, σ, ±, –); Helvetica if it cannot be found."""
    try:
        import matplotlib

        base = Path(matplotlib.get_data_path()) / "fonts" / "ttf"
        pdfmetrics.registerFont(TTFont("DejaVuSans", str(base / "DejaVuSans.ttf")))
        pdfmetrics.registerFont(TTFont("DejaVuSans-Bold", str(base / "DejaVuSans-Bold.ttf")))
        pdfmetrics.registerFontFamily("DejaVuSans", normal="DejaVuSans", bold="DejaVuSans-Bold")
        return "DejaVuSans", "DejaVuSans-Bold"
    except Exception:  # noqa: BLE001 — any font problem: fall back to a built-in font
        return "Helvetica", "Helvetica-Bold"


def write_report(run_dir: Path, results: RunResults, body: list[str], method_name: str = "") -> Path:
    """The Markdown report: a header every run shares, the method's body, the run's events."""
    lines = [f"# rtcal run — {results.procedure.name or results.method}", ""]
    for name, st in results.solver_status.items():
        if st.status != "converged":
            lines.append(f"> **Estimator `{name}` {st.status}**: {st.message}")
            lines.append(">")
    if results.bench and results.bench.startswith("ideal bench"):
        lines += [f"> **Note:** {results.bench}.", ""]
    lines += [f"- method: {method_name} (`{results.method}`)" if method_name else f"- method: `{results.method}`",
              f"- software: rtcal {results.rtcal_version}",
              f"- started: {results.started_utc or '?'} (UTC); measured until {results.finished_utc or '?'}; "
              f"report written {_dt.datetime.now(_dt.timezone.utc).isoformat(timespec='seconds')}",
              f"- measurement duration: {results.measurement_duration_s} s"
              + (" of simulated time (virtual clock: settle times and motions were not waited for)"
                 if results.clock == "virtual" else ""),
              f"- raw readings: {results.raw_readings}; faults: {results.faults}; skipped: {results.skipped_readings}",
              f"- conditions: {conditions_in_brief(results)}",
              f"- control of the machine: {control_lines(results)[0]}"]
    if isinstance(results.instruments, dict):
        lines += ["- instruments:"] + [f"  - {k}: `{v}`" for k, v in results.instruments.items()]
    else:
        lines += [f"- instruments: {results.instruments}, bench `{results.bench}`, seed {results.seed}"]
    if results.recommended:
        lines.append(f"- recommended estimate: `{results.recommended}` (converged, smallest uncertainty)")
    lines.append("")
    lines += conformity_section(results)
    lines += body
    lines += events_section(results.events)
    path = run_dir / "report.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def console_lines(results: RunResults) -> list[str]:
    """What every run prints after its method's summary: the ISO 230-2 parameters with U, the
    conformity verdict per limit with the rule, and the faults and skipped readings."""
    from rtcal.deliverables.conformity import parameter_uncertainties

    lines = []
    iso = results.evaluation.iso230_2 if results.evaluation else None
    if iso is not None:
        u = parameter_uncertainties(results)
        shown = [f"{ISO_SYMBOL[k]} {value_text(getattr(iso, k), u.get(k))}″ (U {u_text(u.get(k))}″)"
                 for k in ("E", "M", "B", "R", "A", "E_up", "E_down", "R_up", "R_down") if getattr(iso, k) is not None]
        if shown:
            lines.append(parameters_label(iso_departures(results)) + ": " + ", ".join(shown))
    c = results.conformity
    if c is not None:
        lines.append(f"conformity ({c.decision_rule} acceptance, "
                     f"{'ISO 14253-1' if c.decision_rule == 'guarded' else 'ILAC-G8'}): {c.verdict.upper()}")
        for k, v in c.per_limit.items():
            at = f" at {v.target_deg:g}°{'↑' if v.direction == 1 else '↓'}" if v.target_deg is not None else ""
            lines.append(f"  {ISO_SYMBOL[k]}: {value_text(v.value_arcsec, v.expanded_uncertainty_arcsec)}″{at} against "
                         f"{v.limit_arcsec:g}″"
                         + (f" ± U {u_text(v.expanded_uncertainty_arcsec)}″" if c.decision_rule == "guarded" else "")
                         + f": {v.verdict}")
    lines += fault_lines(results)
    return lines


def plural(n: int, noun: str) -> str:
    """"1 event", "2 events", "0 events"."""
    return f"{n} {noun}" + ("" if n == 1 else "s")


def fault_lines(results: RunResults) -> list[str]:
    """The run's faults by instrument, the readings skipped and rejected (one line when there were none)."""
    by: dict[str, int] = {}
    for ev in results.events:
        if ev.kind == "fault":
            by[ev.instrument or "run"] = by.get(ev.instrument or "run", 0) + 1
    rejected = results.control.rejected_attempts if results.control else 0
    if not by and not results.skipped_readings and not rejected:
        return ["no instrument fault, no reading skipped or rejected"]
    lines = [plural(results.faults, "instrument fault") + (" (" + ", ".join(f"{k} {n}" for k, n in by.items()) + ")" if by else "")
             + f"; {plural(results.skipped_readings, 'planned reading')} skipped and not retaken; "
               f"{plural(rejected, 'reading')} rejected by the checks (kept, not used)"]
    actions = {k: n for k, n in ((kind, sum(1 for ev in results.events if ev.kind == kind))
                                 for kind in ("retry", "reacquire", "skip", "pause", "resume")) if n}
    if actions:
        lines.append("  actions taken: " + ", ".join(f"{k} {n}" for k, n in actions.items()) + " (report.md: Events)")
    return lines


def conformity_section(results: RunResults) -> list[str]:
    """The verdict against the acceptance limits, with the rule (empty without limits)."""
    c = results.conformity
    if c is None:
        return []
    lines = [f"## Conformity: {c.verdict}", "", c.rule, "",
             "| limit | value / ″ | limit / ″ | U (k = 2) / ″ | guard band / ″ | verdict |", "|---|---|---|---|---|---|"]
    for k, v in c.per_limit.items():
        lines.append(f"| {ISO_SYMBOL[k]} | {_fmt(v.value_arcsec)} | {v.limit_arcsec:g} | {_fmt(v.expanded_uncertainty_arcsec)} | "
                     f"{_fmt(v.guard_band_arcsec)} | {v.verdict} |")
    return lines + [""] + [f"- {n}" for n in c.notes] + [""]


NOTABLE_EVENTS = ("fault", "retry", "reacquire", "skip", "pause", "abort", "resume")


def events_section(events: list[Event], limit: int = 60) -> list[str]:
    """Counts of every kind of event, then the faults and the actions taken, in order."""
    if not events:
        return []
    counts: dict[str, int] = {}
    for ev in events:
        counts[ev.kind] = counts.get(ev.kind, 0) + 1
    lines = ["## Events", "", ", ".join(f"{k}: {n}" for k, n in counts.items()), ""]
    notable = [ev for ev in events if ev.kind in NOTABLE_EVENTS]
    for ev in notable[:limit]:
        who = f" ({ev.instrument})" if ev.instrument else ""
        lines.append(f"- t = {ev.t_s:.1f} s, {ev.kind}{who}: {ev.message}")
    if len(notable) > limit:
        lines.append(f"- … {len(notable) - limit} more in results.json and run.sqlite")
    return lines + [""]
