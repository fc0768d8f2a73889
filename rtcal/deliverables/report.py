"""The run's report: report.md, and the calibration certificate report.html and report.pdf.

The certificate carries what ISO/IEC 17025:2017 7.8.2.1 and 7.8.4.1 ask of one (where it
applies): page 1 names the laboratory, the certificate, the customer, the item, the method and
standards with their editions, the dates, the conditions, the result in brief with its U and k,
the conformity verdict with its rule, what the uncertainty leaves out, the traceability, that
the results relate to the item calibrated, and who performed and approved it; then the result per
target and direction, the ISO 230-2 and VDI 3441 parameters, the figures, the budget, the method,
the reference standards and instruments, the conditions, the control of the machine and the
run's events. Every page of the PDF ends with "page N of M". One typed document
(:class:`rtcal.deliverables.certificate.Certificate`, built once from the run's results) feeds the
three renderers here, which only lay it out: report.html, report.pdf, and report.md, the Markdown
frame every run shares around its method's body.
"""

from __future__ import annotations

import base64
import datetime as _dt
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from pydantic import BaseModel

from rtcal.deliverables.departures import departures, parameters_label
from rtcal.deliverables.deviations import PositioningDeviations
from rtcal.deliverables.rounding import u_text, value_text
from rtcal.results.model import EnvironmentSummary, InstrumentRecord, RunResults

if TYPE_CHECKING:
    from rtcal.deliverables.certificate import Certificate

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
    instruments = cast("type[BaseModel]", model.model_fields["instruments"].annotation)  # each method's Instruments model
    for name, field in instruments.model_fields.items():
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


def write_html(certificate: Certificate, path: Path) -> Path:
    """The certificate as one HTML page (printable to A4: the template's @page rules), its figures inlined."""
    from jinja2 import Environment, FileSystemLoader, select_autoescape

    env = Environment(loader=FileSystemLoader(Path(__file__).parent / "templates"), autoescape=select_autoescape(["j2"]))
    figures = [(base64.b64encode(certificate.figure_path(f, path).read_bytes()).decode("ascii"), f.caption) for f in certificate.figures]
    footer_css = "".join(ch for ch in certificate.header.footer if ch not in '"\\<>&\n\r')
    path.write_text(env.get_template("report.html.j2").render(c=certificate, figures=figures, footer_css=footer_css),
                    encoding="utf-8")
    return path


def write_pdf(certificate: Certificate, path: Path) -> Path:
    """A4 pages with reportlab: the same content as the HTML, in the same order; every page ends
    with "page N of M" (drawn last on the page, after the certificate's number)."""
    from reportlab.lib import colors
    from reportlab.lib.pagesizes import A4
    from reportlab.lib.styles import ParagraphStyle, getSampleStyleSheet
    from reportlab.lib.units import mm
    from reportlab.lib.utils import ImageReader
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

    c = certificate
    hd = c.header
    head = Table([[[Paragraph(esc(hd.laboratory), lab), Paragraph(esc(hd.laboratory_address), small)],
                   [Paragraph(esc(hd.title), h1), Paragraph(esc(hd.subtitle), small)]]],
                 colWidths=[width * 0.45, width * 0.55])
    head.setStyle(TableStyle([("VALIGN", (0, 0), (-1, -1), "TOP"), ("LINEBELOW", (0, 0), (-1, 0), 0.8, colors.HexColor("#3a5a80")),
                              ("LEFTPADDING", (0, 0), (-1, -1), 0), ("BOTTOMPADDING", (0, 0), (-1, -1), 4)]))
    story: list[Any] = [head, Spacer(1, 3 * mm)]
    if hd.not_certificate:
        story += [boxed([Paragraph(f"<b>{esc(hd.not_certificate)}</b>", body)], colors.HexColor("#c0392b")), Spacer(1, 2 * mm)]
    story.append(table([(i.label, i.value) for i in c.identification.items], None, [50 * mm, width - 50 * mm],
                       shade_first_column=True))
    for w in c.identification.notes:
        story += [Spacer(1, 1.5 * mm), Paragraph(f"<b>Note:</b> {esc(w)}", body)]
    brief = c.result_in_brief
    story += [Paragraph(esc(brief.heading), h2),
              table([(k.quantity, k.value_arcsec, k.expanded_uncertainty_arcsec) for k in brief.rows], brief.header,
                    [width - 88 * mm, 66 * mm, 22 * mm]),
              Spacer(1, 1.5 * mm), Paragraph(esc(brief.uncertainty_statement), small)]
    if brief.not_included:
        story += [Spacer(1, 2 * mm), boxed([Paragraph(f"<b>{esc(brief.not_included_heading)}</b>", body)]
                                           + [Paragraph("• " + esc(n), small) for n in brief.not_included],
                                           colors.HexColor("#d68910"))]
    if c.conformity:
        v = c.conformity
        story += [Paragraph(f"{esc(v.heading)}: {v.verdict.upper()}", h2), Paragraph(esc(v.rule), small), Spacer(1, 1.5 * mm),
                  table([(r.symbol, r.parameter, r.limit_arcsec, r.value_arcsec, r.expanded_uncertainty_arcsec,
                          r.guard_band_arcsec, r.verdict) for r in v.rows], v.header,
                        [12 * mm, width - 101 * mm, 16 * mm, 17 * mm, 14 * mm, 24 * mm, 18 * mm])]
    story += [Paragraph(esc(c.traceability.heading), h2), Paragraph(esc(c.traceability.statement), body), Spacer(1, 1.5 * mm),
              Paragraph(esc(c.traceability.relates), body)]
    if c.deviations:
        d = c.deviations
        story += [CondPageBreak(60 * mm), Paragraph(esc(d.heading), h2), Paragraph(esc(d.note), small),
                  Spacer(1, 1.5 * mm), table(d.rows, d.header)]
    if c.parameters:
        p = c.parameters
        story += [KeepTogether([Paragraph(esc(p.heading), h2),
                                table([(r.symbol, r.meaning, r.value_arcsec, r.expanded_uncertainty_arcsec) for r in p.rows],
                                      p.header, [18 * mm, width - 62 * mm, 22 * mm, 22 * mm])])]
        if p.vdi_rows:
            story += [KeepTogether([Paragraph(esc(p.vdi_heading), h2),
                                    table([(r.symbol, r.meaning, r.value_arcsec) for r in p.vdi_rows], p.vdi_header,
                                          [26 * mm, width - 48 * mm, 22 * mm])])]
        story += [Paragraph(esc(n), small) for n in p.notes]
    for t in c.tables:
        story += [KeepTogether([Paragraph(esc(t.heading), h2), Paragraph(esc(t.note), small), Spacer(1, 1.5 * mm),
                                table(t.rows, t.header, [18 * mm, width - 74 * mm, 28 * mm, 28 * mm]
                                      if len(t.header) == 4 else None)])]
    for f in c.figures:
        image = certificate.figure_path(f, path)
        iw, ih = ImageReader(str(image)).getSize()
        fw = 0.76 * width if ih / iw < 0.7 else width  # three wide figures fit a page; a tall one takes its width
        story += [KeepTogether([Spacer(1, 2 * mm), Image(str(image), width=fw, height=fw * ih / iw),
                                Paragraph(esc(f.caption), small)])]
    if c.budget:
        b = c.budget
        story += [KeepTogether([Paragraph(esc(b.heading), h2), Paragraph(esc(b.note), small),
                                table([(r.source, r.type, r.input, r.contribution_arcsec) for r in b.rows], b.header,
                                      [70 * mm, 12 * mm, 55 * mm, 28 * mm])])]
        story += [Paragraph(f"Not included: {esc(n)}", small) for n in b.not_included]
    story += [Paragraph(esc(c.method.heading), h2)] + [Paragraph(esc(t), body) for t in c.method.paragraphs]
    s = c.standards
    story += [KeepTogether([Paragraph(esc(s.heading), h2),
              table([(r.instrument, r.role, r.id, r.certificate, r.calibrated_by, r.due) for r in s.rows], s.header,
                    [24 * mm, 32 * mm, width - 132 * mm, 28 * mm, 28 * mm, 20 * mm])]),
              Paragraph("Connections: " + esc(s.connections), small)]
    story += [KeepTogether([Paragraph(esc(c.conditions.heading), h2),
                            table([(i.label, i.value) for i in c.conditions.rows], c.conditions.header,
                                  [55 * mm, width - 55 * mm])])]
    if c.control.details:
        story += [Paragraph(esc(c.control.heading), h2)] + [Paragraph("• " + esc(t), small) for t in c.control.details]
    r = c.run
    story += [Paragraph(esc(r.heading), h2),
              Paragraph(f"Measured {esc(r.measured)}; {esc(r.run_counts)}; events: {esc(r.event_counts)}. Software: "
                        f"{esc(r.software)}.", body),
              Spacer(1, 4 * mm), Paragraph(f"<b>{esc(hd.closing)}</b>", body)]

    footer_left = hd.footer

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

    signatures = table([[f"{i.label}: {i.value}" for i in c.sign_off.items()], [c.sign_off.signing, "", ""]], None,
                       [width / 3] * 3)
    signatures.setStyle(TableStyle([("SPAN", (0, 1), (-1, 1))]))  # how it is signed, under who signed it
    sign_h = signatures.wrap(width, 40 * mm)[1] + 4 * mm

    def sign(canvas, doc):  # page 1's foot: who performed and approved it, whatever the page holds above
        signatures.drawOn(canvas, 15 * mm, 17 * mm)

    first = Frame(15 * mm, 17 * mm + sign_h, width, A4[1] - 13 * mm - 17 * mm - sign_h, id="first", leftPadding=0,
                  rightPadding=0, topPadding=0, bottomPadding=0)
    later = Frame(15 * mm, 17 * mm, width, A4[1] - 30 * mm, id="later", leftPadding=0, rightPadding=0, topPadding=0,
                  bottomPadding=0)
    doc = BaseDocTemplate(str(path), pagesize=A4, title=f"{hd.title} {hd.certificate_number}".strip(), author=hd.laboratory)
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


def write_markdown(certificate: Certificate, path: Path) -> Path:
    """report.md: the frame every run shares (from the document's run record), the conformity
    table, the method's body, the run's events."""
    c, r = certificate, certificate.run
    lines = [f"# {r.report_title}", ""]
    for issue in r.solver_issues:
        lines.append(f"> **Estimator `{issue.estimator}` {issue.status}**: {issue.message}")
        lines.append(">")
    if r.bench_note:
        lines += [f"> **Note:** {r.bench_note}.", ""]
    lines += [f"- method: {c.method.name} (`{r.method_key}`)" if c.method.name != r.method_key else f"- method: `{r.method_key}`",
              f"- software: {r.software}",
              f"- started: {r.started_utc} (UTC); measured until {r.finished_utc}; "
              f"report written {_dt.datetime.now(_dt.timezone.utc).isoformat(timespec='seconds')}",
              f"- measurement duration: {r.duration_s} s"
              + (" of simulated time (virtual clock: settle times and motions were not waited for)" if r.virtual_clock else ""),
              f"- raw readings: {r.raw_readings}; faults: {r.faults}; skipped: {r.skipped_readings}",
              f"- conditions: {c.conditions.brief}",
              f"- control of the machine: {c.control.brief}"]
    if r.instruments:
        lines += ["- instruments:"] + [f"  - {i.label}: `{i.value}`" for i in r.instruments]
    else:
        lines += [f"- instruments: {r.simulated}"]
    if r.recommended:
        lines.append(f"- recommended estimate: `{r.recommended}` (converged, smallest uncertainty)")
    lines.append("")
    if c.conformity:
        v = c.conformity
        lines += [f"## {v.heading}: {v.verdict}", "", v.rule, "",
                  "| limit | value / ″ | limit / ″ | U (k = 2) / ″ | guard band / ″ | verdict |", "|---|---|---|---|---|---|"]
        lines += [f"| {x.symbol} | {x.value_arcsec} | {x.limit_arcsec} | {x.expanded_uncertainty_arcsec} | "
                  f"{x.guard_band_arcsec} | {x.verdict} |" for x in v.rows]
        lines += [""] + [f"- {n}" for n in v.notes] + [""]
    lines += c.report_body
    if r.event_counts != "none":
        lines += ["## Events", "", r.event_counts, ""] + [f"- {e}" for e in r.notable_events]
        if r.notable_more:
            lines.append(f"- … {r.notable_more} more in results.json and run.sqlite")
        lines.append("")
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


NOTABLE_EVENTS = ("fault", "retry", "reacquire", "skip", "pause", "abort", "resume")
