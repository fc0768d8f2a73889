"""The run's report: report.md, and the certificate-grade report.html and report.pdf.

The certificate leads with what a reader signs off: who and what (metadata), the result per
target and direction with its expanded uncertainty U (k = 2), the ISO 230-2 and VDI 3441
parameters and the figures; then the uncertainty budget, the method, the conditions and the
run's events. One model (:func:`report_model`, a pure function of the run's results) feeds both
renderers. report.md is the Markdown frame every run shares around its method's body.
"""

from __future__ import annotations

import base64
import datetime as _dt
from pathlib import Path
from typing import Any

from rtcal.deliverables.comparison import mean_curve
from rtcal.deliverables.deviations import PositioningDeviations
from rtcal.results.model import Event, InstrumentRecord, MultistationResults, RunResults

ISO_KEYS = (("E_up", "E↑", "unidirectional systematic positional deviation, positive approach"),
            ("E_down", "E↓", "unidirectional systematic positional deviation, negative approach"),
            ("E", "E", "bidirectional systematic positional deviation"),
            ("M", "M", "range of the mean bidirectional positional deviation"),
            ("B", "B", "reversal value (max |B_i|)"), ("B_mean", "B mean", "mean reversal value"),
            ("R_up", "R↑", "unidirectional repeatability, positive"), ("R_down", "R↓", "unidirectional repeatability, negative"),
            ("R", "R", "bidirectional repeatability"), ("A_up", "A↑", "unidirectional accuracy, positive"),
            ("A_down", "A↓", "unidirectional accuracy, negative"), ("A", "A", "bidirectional accuracy"))
VDI_KEYS = (("Pa", "Pa", "position deviation"), ("P", "P", "position uncertainty"), ("Ps_max", "Ps max", "positional scatter, max"),
            ("Ps_mean", "Ps mean", "positional scatter, mean"), ("U_max", "U max", "reversal span, max"),
            ("U_mean", "U mean", "reversal span, mean"))
METADATA_KEYS = (("certificate_number", "Certificate"), ("customer", "Customer"), ("machine", "Machine"), ("axis", "Axis"),
                 ("serial_number", "Serial number"), ("location", "Location"), ("operator", "Operator"))


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


def report_model(results: RunResults, run_dir: Path, figures: list[tuple[str, str]], method_text: list[str]) -> dict[str, Any]:
    """Everything the report shows, as strings and rows, from the run's results."""
    meta = results.metadata
    header = [(label, getattr(meta, key)) for key, label in METADATA_KEYS if getattr(meta, key)]
    header += [("Procedure", results.procedure.name or results.procedure.path),
               ("Calibration method", results.method),
               ("Measured", f"{results.started_utc or '?'} – {results.finished_utc or '?'} (UTC)"),
               ("Report", _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")),
               ("Software", f"rtcal {results.rtcal_version}")]
    if isinstance(results.instruments, dict):
        instruments = [(name, address) for name, address in results.instruments.items()]
    else:
        instruments = [("all", f"simulated in process; bench {results.bench}; seed {results.seed}")]
    records = meta.instruments
    none = InstrumentRecord(id="", calibration_due="")
    instrument_rows = [(name, where, records.get(name, none).id, records.get(name, none).calibration_due)
                       for name, where in instruments]
    warnings = [f"Estimator {n} {st.status}: {st.message}" for n, st in results.solver_status.items()
                if st.status != "converged"]
    if results.bench is not None and results.bench.startswith("ideal bench"):
        warnings.append(results.bench)
    rows = []
    if results.positioning_deviations is not None:
        table = PositioningDeviations.from_model(results.positioning_deviations)
        curve = mean_curve(table, results, wrap=False)
        counts: dict[tuple[float, int], int] = {}
        for t, d in zip(table.target_deg, table.direction):
            counts[(round(float(t), 6), int(d))] = counts.get((round(float(t), 6), int(d)), 0) + 1
        for key in curve:  # in the measurement's order
            x, u = curve[key]
            rows.append((f"{key[0]:g}", "↑" if key[1] > 0 else "↓", f"{x:+.2f}", _fmt(u), _fmt(2 * u), str(counts.get(key, ""))))
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
        budget_rows.append(("expanded uncertainty U (k = 2)", "", "", _fmt(None if comb is None else 2 * comb, 3)))
        not_included = b.not_included
    environment = []
    if isinstance(results, MultistationResults) and results.environment is not None:
        for name, v in results.environment.items():
            environment.append((name.replace("_", " "), f"{v.min:g} … {v.max:g} (mean {v.mean:g})"))
    events: dict[str, int] = {}
    for ev in results.events:
        events[ev.kind] = events.get(ev.kind, 0) + 1
    iso_notes = iso.notes if iso else []
    return {
        "title": results.procedure.name or "rtcal calibration",
        "header": header, "instruments": instrument_rows, "warnings": warnings,
        "rows": rows, "recommended": results.recommended,
        "iso": [(sym, desc, _fmt(getattr(iso, key))) for key, sym, desc in ISO_KEYS] if iso else [],
        "vdi": [(sym, desc, _fmt(getattr(vdi, key))) for key, sym, desc in VDI_KEYS] if vdi else [],
        "evaluation_notes": iso_notes + [n for n in (vdi.notes if vdi else []) if n not in iso_notes],
        "figures": [(run_dir / f, caption) for f, caption in figures if (run_dir / f).exists()],
        "budget": budget_rows, "not_included": not_included,
        "method": method_text, "environment": environment,
        "events": ", ".join(f"{k}: {n}" for k, n in events.items()),
        "raw_readings": results.raw_readings, "skipped": results.skipped_readings,
    }


def write_html(model: dict[str, Any], path: Path) -> Path:
    from jinja2 import Environment, FileSystemLoader, select_autoescape

    env = Environment(loader=FileSystemLoader(Path(__file__).parent / "templates"), autoescape=select_autoescape(["j2"]))
    figures = [(base64.b64encode(p.read_bytes()).decode("ascii"), caption) for p, caption in model["figures"]]
    path.write_text(env.get_template("report.html.j2").render(m=model, figures=figures), encoding="utf-8")
    return path


def write_pdf(model: dict[str, Any], path: Path) -> Path:
    """A4 pages with reportlab: the same content as the HTML, in the same order."""
    from reportlab.lib import colors
    from reportlab.lib.pagesizes import A4
    from reportlab.lib.styles import ParagraphStyle, getSampleStyleSheet
    from reportlab.lib.units import mm
    from reportlab.pdfbase import pdfmetrics
    from reportlab.pdfbase.ttfonts import TTFont
    from reportlab.platypus import Image, KeepTogether, Paragraph, SimpleDocTemplate, Spacer, Table, TableStyle

    font, bold = _fonts(pdfmetrics, TTFont)
    styles = getSampleStyleSheet()
    body = ParagraphStyle("body", parent=styles["BodyText"], fontName=font, fontSize=8.5, leading=11)
    small = ParagraphStyle("small", parent=body, fontSize=7.5, leading=9.5)
    h1 = ParagraphStyle("h1", parent=styles["Heading1"], fontName=bold, fontSize=15, spaceAfter=4)
    h2 = ParagraphStyle("h2", parent=styles["Heading2"], fontName=bold, fontSize=11, spaceBefore=8, spaceAfter=4)
    width = A4[0] - 30 * mm

    def esc(text: str) -> str:
        return str(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")

    def table(rows, header, col_widths=None, font_size=8):
        head = [[Paragraph(f"<b>{esc(h)}</b>", small) for h in header]] if header else []
        data = head + [[Paragraph(esc(c), small) for c in r] for r in rows]
        t = Table(data, colWidths=col_widths, repeatRows=1 if header else 0)
        t.setStyle(TableStyle([("GRID", (0, 0), (-1, -1), 0.3, colors.grey),
                               ("BACKGROUND", (0, 0), (-1 if header else 0, 0 if header else -1), colors.HexColor("#e8eef5")),
                               ("VALIGN", (0, 0), (-1, -1), "TOP"), ("FONTSIZE", (0, 0), (-1, -1), font_size),
                               ("TOPPADDING", (0, 0), (-1, -1), 1.5), ("BOTTOMPADDING", (0, 0), (-1, -1), 1.5)]))
        return t

    story = [Paragraph(esc(model["title"]), h1), Paragraph("Calibration of the angular positioning deviation of a rotary axis", body),
             Spacer(1, 4 * mm), table(model["header"], None, [45 * mm, width - 45 * mm])]
    for w in model["warnings"]:
        story += [Spacer(1, 2 * mm), Paragraph(f"<b>Note:</b> {esc(w)}", body)]
    story += [Paragraph("Result: positioning deviation per target and direction", h2),
              Paragraph(f"Deviation = actual − commanded angle (arcsec), relative to the first target of the first direction; "
                        f"u standard uncertainty, U = 2u expanded uncertainty (k = 2, about 95 %). Estimate: {esc(model['recommended'])}.",
                        small), Spacer(1, 2 * mm),
              table(model["rows"], ["target / °", "direction", "deviation / ″", "u / ″", "U (k = 2) / ″", "runs"])]
    if model["iso"]:
        params = [(a[0], a[1], a[2]) for a in model["iso"]] + [(b[0], f"VDI 3441: {b[1]}", b[2]) for b in model["vdi"]]
        story += [KeepTogether([Paragraph("ISO 230-2 and VDI/DGQ 3441 parameters (arcsec)", h2),
                                table(params, ["symbol", "meaning", "value / ″"], [22 * mm, width - 50 * mm, 28 * mm])])]
        story += [Paragraph(esc(n), small) for n in model["evaluation_notes"]]
    for p, caption in model["figures"]:
        from reportlab.lib.utils import ImageReader

        iw, ih = ImageReader(str(p)).getSize()
        story += [KeepTogether([Spacer(1, 3 * mm), Image(str(p), width=width, height=width * ih / iw), Paragraph(esc(caption), small)])]
    if model["budget"]:
        story += [KeepTogether([Paragraph("Uncertainty budget (largest contribution over the targets)", h2),
                                table(model["budget"], ["source", "type", "input σ", "u / ″"], [70 * mm, 12 * mm, 55 * mm, 28 * mm])])]
        story += [Paragraph(f"Not included: {esc(n)}", small) for n in model["not_included"]]
    story += [Paragraph("Method", h2)] + [Paragraph(esc(t), body) for t in model["method"]]
    story += [Paragraph("Instruments", h2), table(model["instruments"], ["instrument", "connection", "id", "calibration due"])]
    if model["environment"]:
        story += [Paragraph("Conditions", h2), table(model["environment"], ["quantity", "range"])]
    story += [Paragraph("Run", h2), Paragraph(f"{model['raw_readings']} readings, {model['skipped']} skipped; events: {esc(model['events'])}", body)]

    def footer(canvas, doc):
        canvas.saveState()
        canvas.setFont(font, 7)
        canvas.drawString(15 * mm, 10 * mm, f"{model['title']} — page {doc.page}")
        canvas.restoreState()

    SimpleDocTemplate(str(path), pagesize=A4, leftMargin=15 * mm, rightMargin=15 * mm, topMargin=15 * mm, bottomMargin=15 * mm,
                      title=model["title"], author="rtcal").build(story, onFirstPage=footer, onLaterPages=footer)
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


def write_report(run_dir: Path, results: RunResults, body: list[str]) -> Path:
    """The Markdown report: a header every run shares, the method's body, the run's events."""
    lines = [f"# rtcal run — {results.procedure.name or results.method}", ""]
    for name, st in results.solver_status.items():
        if st.status != "converged":
            lines.append(f"> **Estimator `{name}` {st.status}**: {st.message}")
            lines.append(">")
    if results.bench and results.bench.startswith("ideal bench"):
        lines += [f"> **Note:** {results.bench}.", ""]
    lines += [f"- method: `{results.method}`", f"- software: rtcal {results.rtcal_version}",
              f"- started: {results.started_utc or '?'} (UTC); measured until {results.finished_utc or '?'}; "
              f"report written {_dt.datetime.now(_dt.timezone.utc).isoformat(timespec='seconds')}",
              f"- measurement duration: {results.measurement_duration_s} s"
              + (" of simulated time (virtual clock: settle times and motions were not waited for)"
                 if results.clock == "virtual" else ""),
              f"- raw readings: {results.raw_readings}"]
    if isinstance(results.instruments, dict):
        lines += ["- instruments:"] + [f"  - {k}: `{v}`" for k, v in results.instruments.items()]
    else:
        lines += [f"- instruments: {results.instruments}, bench `{results.bench}`, seed {results.seed}"]
    if results.recommended:
        lines.append(f"- recommended estimate: `{results.recommended}` (converged, smallest uncertainty)")
    lines.append("")
    lines += body
    lines += events_section(results.events)
    path = run_dir / "report.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


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
