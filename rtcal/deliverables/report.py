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
from typing import TYPE_CHECKING, Any

from rtcal.deliverables.certificate import ISO_SYMBOL, iso_departures, plural
from rtcal.deliverables.departures import parameters_label
from rtcal.deliverables.rounding import u_text, value_text
from rtcal.results.model import RunResults

if TYPE_CHECKING:
    from rtcal.deliverables.certificate import Certificate

def write_html(certificate: Certificate, path: Path) -> Path:
    """The certificate as one HTML page (printable to A4: the template's @page rules), its figures inlined."""
    from jinja2 import Environment, FileSystemLoader, select_autoescape

    env = Environment(loader=FileSystemLoader(Path(__file__).parent / "templates"), autoescape=select_autoescape(["j2"]))
    figures = [(base64.b64encode(certificate.figure_path(f, path).read_bytes()).decode("ascii"), f.caption) for f in certificate.figures]
    footer_css = "".join(ch for ch in certificate.header.footer if ch not in '"\\<>&\n\r')
    marking_css = "".join(ch for ch in certificate.header.marking if ch not in '"\\<>&\n\r')
    path.write_text(env.get_template("report.html.j2").render(c=certificate, figures=figures, footer_css=footer_css,
                                                              marking_css=marking_css), encoding="utf-8")
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
    if c.other_standards:
        o = c.other_standards
        story += [Paragraph(esc(o.heading), h2), Paragraph(esc(o.note), small)]
        title = ParagraphStyle("block", parent=body, keepWithNext=1, spaceBefore=3)
        for blk in o.blocks:  # a long table splits over pages (its header repeated); its title stays with it
            story += [Paragraph(f"<b>{esc(blk.title)}</b>", title)]
            if blk.rows:
                story.append(table([(r.symbol, r.value, r.expanded_uncertainty, figure_definition(r)) for r in blk.rows],
                                   o.header, [20 * mm, 24 * mm, 20 * mm, width - 64 * mm]))
            story += [Paragraph(esc(t), small) for t in [blk.rule] + blk.notes if t] + [Spacer(1, 1.5 * mm)]
    pe = c.periodic_error
    if pe is not None:
        story += [Paragraph(esc(pe.heading), h2), Paragraph(esc(pe.statement), small)]
    if pe is not None and pe.tested:
        story += [Spacer(1, 1.5 * mm), table([(k.quantity, k.value_arcsec, k.expanded_uncertainty_arcsec) for k in pe.rows],
                                              pe.header, [width - 60 * mm, 36 * mm, 24 * mm]),
                  Spacer(1, 1.5 * mm), table(pe.harmonic_rows, pe.harmonic_header,
                                             [26 * mm, width - 104 * mm, 26 * mm, 26 * mm, 26 * mm])]
        story += [Paragraph(esc(n), small) for n in pe.notes]
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
    marking = hd.marking

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
                if marking:  # every page's head: a page taken alone still says it is no calibration
                    self.setFont(bold, 7)
                    self.setFillColor(colors.HexColor("#c0392b"))
                    self.drawCentredString(A4[0] / 2, A4[1] - 8 * mm, marking[:150])
                    self.setFillColor(colors.black)
                self.setFont(font, 7)
                self.setStrokeColor(colors.HexColor("#3a5a80"))
                self.line(15 * mm, 13 * mm, A4[0] - 15 * mm, 13 * mm)
                page = f"page {self._pageNumber} of {total}"
                room = width - pdfmetrics.stringWidth(page, font, 7) - 6 * mm
                self.drawString(15 * mm, 9 * mm, fit_footer(footer_left, lambda t: pdfmetrics.stringWidth(t, font, 7), room))
                self.drawRightString(A4[0] - 15 * mm, 9 * mm, page)
                super().showPage()
            super().save()

    signatures = table([[f"{i.label}: {i.value}" for i in c.sign_off.items()],
                        [f"{c.sign_off.signing} {c.sign_off.electronic_signature}".strip(), "", ""]], None, [width / 3] * 3)
    signatures.setStyle(TableStyle([("SPAN", (0, 1), (-1, 1))]))  # how it is signed and by which key, under who
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


def fit_footer(text: str, width_of: Any, room: float) -> str:
    """The footer's parts (" · "-joined: marking, laboratory, certificate number) within ``room``: the longest part
    is shortened with "…" until the whole fits, so the certificate's number is never cut off by the page count."""
    parts = text.split(" · ")
    while width_of(" · ".join(parts)) > room:
        longest = max(range(len(parts)), key=lambda i: len(parts[i]))
        if len(parts[longest]) <= 8:
            return " · ".join(parts)
        parts[longest] = parts[longest][:-2].rstrip(" …") + "…"
    return " · ".join(parts)


def figure_definition(row: Any) -> str:
    """A figure's definition with its edition and coverage (and the verdict a TUR stands beside), in one cell."""
    text = f"{row.definition} ({row.edition}; coverage: {row.coverage})"
    return f"{text}. {row.beside}" if row.beside else text


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
    if c.header.marking:
        lines += [f"> **{c.header.marking}**", ""]
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
    lines.append(f"- signature: {c.sign_off.electronic_signature}")
    lines.append("")
    if c.conformity:
        v = c.conformity
        lines += [f"## {v.heading}: {v.verdict}", "", v.rule, "",
                  "| limit | value / ″ | limit / ″ | U (k = 2) / ″ | guard band / ″ | verdict |", "|---|---|---|---|---|---|"]
        lines += [f"| {x.symbol} | {x.value_arcsec} | {x.limit_arcsec} | {x.expanded_uncertainty_arcsec} | "
                  f"{x.guard_band_arcsec} | {x.verdict} |" for x in v.rows]
        lines += [""] + [f"- {n}" for n in v.notes] + [""]
    pe = c.periodic_error
    if pe is not None:
        lines += [f"## {pe.heading}", "", pe.statement, ""]
    if pe is not None and pe.tested:
        lines += ["| " + " | ".join(pe.header) + " |", "|---|---|---|"]
        lines += [f"| {k.quantity} | {k.value_arcsec} | {k.expanded_uncertainty_arcsec} |" for k in pe.rows]
        lines += ["", "| " + " | ".join(pe.harmonic_header) + " |", "|---|---|---|---|---|"]
        lines += ["| " + " | ".join(r) + " |" for r in pe.harmonic_rows] + [""] + [f"- {n}" for n in pe.notes] + [""]
    if c.other_standards:
        o = c.other_standards
        lines += [f"## {o.heading}", "", o.note, ""]
        for blk in o.blocks:
            lines += [f"### {blk.title}", ""]
            if blk.rows:
                lines += ["| " + " | ".join(o.header) + " |", "|---|---|---|---|"]
                lines += [f"| {r.symbol} | {r.value} | {r.expanded_uncertainty} | {figure_definition(r)} |" for r in blk.rows]
                lines.append("")
            lines += [f"- {t}" for t in [blk.rule] + blk.notes if t] + [""]
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


