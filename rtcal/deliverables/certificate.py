"""The certificate as ONE typed document, built once from a run's results and metadata.

Every word and number the calibration certificate (report.html, report.pdf) and the run's report
(report.md) show is decided here, once: the renderers in :mod:`rtcal.deliverables.report` only
lay this document out, so a value cannot read one way in the PDF and another in the HTML or the
Markdown. Uncertainties go through :mod:`rtcal.deliverables.rounding` as everywhere else.

A section is a typed model (a field of :class:`Certificate`) and one entry of
:data:`SECTION_BUILDERS`, a function of the run (:class:`Sources`) that returns it, or None where
the run has nothing for it (no acceptance limits: no conformity section). What is particular to a
method comes from its outputs (:func:`rtcal.deliverables.method_outputs.outputs_for`), never from
the results' class. The document is also written as certificate.json beside the report.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr

from rtcal.deliverables.comparison import mean_curve
from rtcal.deliverables.deviations import PositioningDeviations
from rtcal.deliverables.evaluation import UNCONFIRMED
from rtcal.deliverables.method_outputs import MethodOutputs, outputs_for
from rtcal.deliverables.report import (CERTIFICATE_NEEDS, DECISION_STANDARDS, ISO_KEYS, ISO_MEANING, ISO_SYMBOL,
                                       NOTABLE_EVENTS, RELATES_STATEMENT, SIGNING_STATEMENT, STANDARDS,
                                       UNCERTAINTY_STATEMENT, VDI_KEYS, _fmt, conditions, conditions_in_brief, connections,
                                       control_lines, estimate_name, instrument_rows, iso_departures, key_results, largest,
                                       measurement_dates, plural, traceability)
from rtcal.deliverables.rounding import u_text, value_text
from rtcal.results.model import RunResults

SCHEMA_VERSION = "1.0"


class Part(BaseModel):
    """A piece of the certificate: immutable once built, no key beyond those declared."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class Item(Part):
    """One labelled line (a row of a two-column table)."""

    label: str = Field(description="what the line states, in words")
    value: str = Field(description="the statement, as shown")


class Header(Part):
    """The title block of page 1, the footer of every page and the closing line."""

    title: str = Field(description='"Calibration certificate", or "Calibration report" when the metadata cannot make one')
    subtitle: str = Field(description="what was calibrated, in a line")
    laboratory: str = Field(description="the issuing laboratory (ISO/IEC 17025 7.8.2.1 b)")
    laboratory_address: str = Field(description="its address")
    certificate_number: str = Field(description="the certificate's unique identification (empty: not given)")
    not_certificate: str = Field(description="why this is not a certificate (empty: it is one)")
    footer: str = Field(description="the left part of every page's footer")
    closing: str = Field(description="the document's last line")


class Identification(Part):
    """Page 1's table: the ISO/IEC 17025 7.8.2.1 and 7.8.4.1 items, then notes a reviewer must see."""

    items: list[Item] = Field(description="certificate number, dates, customer, item, method, standards, departures, …")
    notes: list[str] = Field(description="estimator failures, an ideal bench, faults and skipped readings (empty: none)")


class KeyResult(Part):
    quantity: str = Field(description="the quantity in words")
    value_arcsec: str = Field(description="its value in arcsec, rounded as its U (with ″)")
    expanded_uncertainty_arcsec: str = Field(description="its U (k = 2) in arcsec, two significant digits rounded up")


class ResultInBrief(Part):
    """The result in brief, the uncertainty statement and what the uncertainty leaves out (7.8.4.1 a)."""

    heading: str = "Result in brief"
    header: list[str] = ["quantity", "value", "U (k = 2)"]
    rows: list[KeyResult]
    uncertainty_statement: str = Field(description="how U was determined (coverage factor, probability, GUM)")
    not_included_heading: str = "The uncertainty stated does not include:"
    not_included: list[str] = Field(description="influences the budget leaves out (empty: none)")


class ConformityRow(Part):
    symbol: str = Field(description="the limited parameter's symbol (E, M, …)")
    parameter: str = Field(description="its meaning, and where it was decided")
    limit_arcsec: str = Field(description="the acceptance limit in arcsec")
    value_arcsec: str = Field(description="the measured value in arcsec, rounded as its U")
    expanded_uncertainty_arcsec: str = Field(description="its U (k = 2) in arcsec")
    guard_band_arcsec: str = Field(description="the guard band in arcsec (0: simple acceptance)")
    verdict: str = Field(description="pass, fail or undecided")


class Conformity(Part):
    """The statement of conformity with its decision rule (7.8.6)."""

    heading: str = "Conformity"
    verdict: str = Field(description="pass, fail or undecided (over every limit)")
    rule: str = Field(description="the decision rule applied, in words")
    header: list[str] = ["limit", "parameter", "limit / ″", "value / ″", "U / ″", "guard band / ″", "verdict"]
    rows: list[ConformityRow]
    notes: list[str] = Field(default=[], description="how the verdict was reached (report.md)")


class Traceability(Part):
    heading: str = "Traceability"
    statement: str = Field(description="the traceability of the results to the SI (7.8.4.1 c)")
    relates: str = Field(description="the results relate only to the item calibrated (7.8.2.1 l)")


class SignOff(Part):
    """Who performed and approved the calibration, and how it was signed (7.8.2.1 o)."""

    performed_by: str
    approved_by: str
    date_of_issue: str = Field(description="YYYY-MM-DD")
    signing: str = Field(description="how the document was approved for issue")

    def items(self) -> list[Item]:
        return [Item(label="Performed by", value=self.performed_by), Item(label="Approved by", value=self.approved_by),
                Item(label="Date of issue", value=self.date_of_issue)]


class Table(Part):
    """A captioned table: the per-target result, a method's own tables (the axis's location, …)."""

    heading: str
    note: str = ""
    header: list[str]
    rows: list[list[str]]
    numeric_from_column: int = Field(default=0, description="0-based first column set right-aligned as numbers")


class ParameterRow(Part):
    symbol: str
    meaning: str
    value_arcsec: str = Field(description="value in arcsec, rounded as its U")
    expanded_uncertainty_arcsec: str = Field(default="", description="U (k = 2) in arcsec (VDI 3441 parameters: none)")


class Parameters(Part):
    """The ISO 230-2 parameters with U, the VDI/DGQ 3441 ones, and notes on their evaluation."""

    heading: str
    header: list[str] = ["symbol", "meaning", "value / ″", "U (k = 2) / ″"]
    rows: list[ParameterRow]
    vdi_heading: str = "VDI/DGQ 3441 parameters (the guideline's own symbols)"
    vdi_header: list[str] = ["VDI 3441 symbol", "VDI 3441 meaning", "value / ″"]
    vdi_rows: list[ParameterRow] = []
    notes: list[str] = []


class Figure(Part):
    file: str = Field(description="the image's file name, beside the document")
    caption: str = Field(description='"Figure N: …"')


class BudgetRow(Part):
    source: str
    type: str = Field(description="A or B (GUM), empty on the sums")
    input: str = Field(description="the input's standard uncertainty with its unit, or where it came from")
    contribution_arcsec: str = Field(description="its largest contribution over the targets, in arcsec")


class Budget(Part):
    heading: str = "Uncertainty budget"
    note: str = "Largest contribution over the targets."
    header: list[str] = ["source", "type", "input σ", "u / ″"]
    rows: list[BudgetRow]
    not_included: list[str] = []


class Method(Part):
    heading: str = "Method"
    name: str = Field(description="the method in words, never the procedure's `method:` key")
    paragraphs: list[str]


class Instrument(Part):
    instrument: str
    role: str
    id: str
    certificate: str
    calibrated_by: str
    due: str = Field(description="calibration due date, YYYY-MM-DD")


class Standards(Part):
    """The reference standards and instruments used, with their calibrations (7.8.2.1, 7.8.4.1 c)."""

    heading: str = "Reference standards and instruments"
    header: list[str] = ["instrument", "role", "id", "certificate", "calibrated by", "due"]
    rows: list[Instrument]
    connections: str = Field(description="where the instruments were reached")


class Conditions(Part):
    heading: str = "Conditions during the measurement"
    header: list[str] = ["quantity", "min – max over the run (mean)"]
    rows: list[Item] = Field(description="per condition: its label with the unit, min – max (mean)")
    brief: str = Field(description="the conditions in a line (page 1)")


class Control(Part):
    heading: str = "Control of the machine"
    brief: str = Field(description="exclusive control and the checks, in a line (page 1)")
    details: list[str]


class SolverIssue(Part):
    estimator: str
    status: str
    message: str


class RunRecord(Part):
    """The run itself: what report.md's frame and the certificate's "Run" section state."""

    heading: str = "Run"
    report_title: str = Field(description="report.md's title")
    method_key: str = Field(description="the procedure's `method:` key (report.md only)")
    software: str
    started_utc: str
    finished_utc: str
    measured: str = Field(description="from the first to the last reading, UTC")
    duration_s: float = Field(description="measurement duration in seconds")
    virtual_clock: bool = Field(description="simulated time: settle times and motions not waited for")
    raw_readings: int
    faults: int
    skipped_readings: int
    run_counts: str = Field(description="readings, skipped and faults in words")
    event_counts: str = Field(description='"kind: n" per kind of event, or "none"')
    notable_events: list[str] = Field(description='"t = …, kind (instrument): message" per fault and action, in order')
    notable_more: int = Field(description="notable events beyond those listed")
    solver_issues: list[SolverIssue]
    bench_note: str = Field(description="an ideal bench, said (empty: not one)")
    instruments: list[Item] = Field(description="instrument → address (empty: simulated)")
    simulated: str = Field(description="simulated instruments, bench and seed (empty: real instruments)")
    recommended: str = Field(description="the recommended estimate's key (empty: none)")


class Certificate(BaseModel):
    """The whole document, section by section in the order of the certificate."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    schema_version: str = SCHEMA_VERSION
    header: Header
    identification: Identification
    result_in_brief: ResultInBrief
    conformity: Conformity | None = Field(description="None: the procedure gives no acceptance limits")
    traceability: Traceability
    sign_off: SignOff
    deviations: Table | None = Field(description="the positioning deviation per target and direction")
    parameters: Parameters | None = Field(description="None: no ISO 230-2 evaluation")
    tables: list[Table] = Field(description="the method's own tables (ISO 230-7 location, error motions)")
    figures: list[Figure]
    budget: Budget | None = Field(description="None: no recommended estimate")
    method: Method
    standards: Standards
    conditions: Conditions
    control: Control
    run: RunRecord
    report_body: list[str] = Field(description="the method's own sections of report.md (Markdown lines)")
    _figures_dir: Path | None = PrivateAttr(default=None)  # where the figures were when it was built (not in the JSON)

    def figure_path(self, figure: Figure, beside: Path) -> Path:
        """The image of ``figure``: in the directory the document was built from, else beside ``beside``."""
        return (self._figures_dir or beside.parent) / figure.file


@dataclasses.dataclass(frozen=True)
class Sources:
    """What every section builder may read: the results, the method's outputs and a few derived facts."""

    results: RunResults
    run_dir: Path
    outputs: MethodOutputs
    figures: list[tuple[str, str]]
    issued: str
    missing: list[str]
    departed: list[str]

    @property
    def doc(self) -> str:
        return "report" if self.missing else "certificate"


def _header(s: Sources) -> Header:
    meta, results = s.results.metadata, s.results
    footer = " · ".join(x for x in (meta.laboratory or results.procedure.name or results.method,
                                    f"Certificate {meta.certificate_number}" if meta.certificate_number else "") if x)
    return Header(title="Calibration certificate" if not s.missing else "Calibration report",
                  subtitle="Angular positioning deviation of a rotary axis",
                  laboratory=meta.laboratory or "Laboratory not stated", laboratory_address=meta.laboratory_address,
                  certificate_number=meta.certificate_number,
                  not_certificate=("Not a calibration certificate: the procedure's metadata does not give "
                                   + ", ".join(s.missing) + "." if s.missing else ""),
                  footer=footer, closing="End of report." if s.missing else "End of certificate.")


def _identification(s: Sources) -> Identification:
    results, meta = s.results, s.results.metadata
    conformity = results.conformity
    standards = list(STANDARDS) + ([DECISION_STANDARDS[conformity.decision_rule]] if conformity else [])
    if s.departed:
        standards[0] = "ISO 230-2:2014 (its formulas for E, M, B, R, A applied to a test that departs from its test: see Departures)"
    item = ", ".join(x for x in (meta.machine, f"axis {meta.axis}" if meta.axis else "",
                                 f"serial number {meta.serial_number}" if meta.serial_number else "") if x)
    rows = [
        ("Certificate number", meta.certificate_number or "not given"),
        ("Date of issue", s.issued),
        ("Customer", ", ".join(x for x in (meta.customer, meta.customer_address) if x) or "not given"),
        ("Item calibrated", item or "not given"),
        ("Condition on receipt", getattr(meta, "condition_on_receipt", "") or "not recorded"),
        ("Place of calibration", meta.location or "not given"),
        ("Date of measurement", measurement_dates(results)),
        ("Method", s.outputs.method_name() or results.method),
        ("Procedure", f"{results.procedure.name or '(untitled)'} ({Path(results.procedure.path).name})"),
        ("Standards applied", "; ".join(standards)),
        ("Departures from the method", ("; ".join(s.departed) + ". The parameters are computed as ISO 230-2 defines them; "
                                        "they are not ISO 230-2 results.") if s.departed else "none"),
        ("Conditions during the measurement", conditions_in_brief(results)),
        ("Control of the machine", control_lines(results)[0]),
    ]
    if isinstance(results.instruments, str):
        rows.append(("Instruments", "simulated: every instrument and the table are simulated on a model bench "
                                    f"({Path(results.bench or '').name or 'ideal'}, random sequence no. {results.seed}); "
                                    "a demonstration, not a measurement of a real item"))
    notes = [f"Estimator {n} {st.status}: {st.message}" for n, st in results.solver_status.items()
             if st.status != "converged"]
    if results.bench is not None and results.bench.startswith("ideal bench"):
        notes.append(results.bench)
    if results.faults or results.skipped_readings:
        notes.append(f"{plural(results.faults, 'instrument fault')} and {plural(results.skipped_readings, 'skipped reading')} "
                     "during the run (see Run).")
    return Identification(items=[Item(label=k, value=v) for k, v in rows], notes=notes)


def _not_included(s: Sources) -> list[str]:
    e = s.results.recommended_estimate()
    return list(e.uncertainty_budget.not_included) if e is not None else []


def _result_in_brief(s: Sources) -> ResultInBrief:
    from rtcal.deliverables.conformity import parameter_uncertainties

    rows = key_results(s.results, parameter_uncertainties(s.results))
    return ResultInBrief(rows=[KeyResult(quantity=q, value_arcsec=v, expanded_uncertainty_arcsec=u) for q, v, u in rows],
                         uncertainty_statement=UNCERTAINTY_STATEMENT.format(doc=s.doc), not_included=_not_included(s))


def _conformity(s: Sources) -> Conformity | None:
    c = s.results.conformity
    if c is None:
        return None
    rows = [ConformityRow(symbol=ISO_SYMBOL[k], parameter=ISO_MEANING[k] + (
                f" (decided at {v.target_deg:g}° {'↑' if v.direction == 1 else '↓'})"
                if v.target_deg is not None and v.direction is not None else ""),
            limit_arcsec=f"{v.limit_arcsec:g}", value_arcsec=value_text(v.value_arcsec, v.expanded_uncertainty_arcsec),
            expanded_uncertainty_arcsec=u_text(v.expanded_uncertainty_arcsec),
            guard_band_arcsec=u_text(v.guard_band_arcsec) if v.guard_band_arcsec else "0", verdict=v.verdict)
            for k, v in c.per_limit.items()]
    return Conformity(verdict=c.verdict, rule=c.rule, rows=rows, notes=list(c.notes))


def _traceability(s: Sources) -> Traceability:
    return Traceability(statement=traceability(s.results), relates=RELATES_STATEMENT.format(doc=s.doc))


def _sign_off(s: Sources) -> SignOff:
    meta = s.results.metadata
    signing = (SIGNING_STATEMENT.format(doc=s.doc, approver=meta.approved_by, date=s.issued) if meta.approved_by else
               f"This {s.doc} has not been approved for issue (the procedure's metadata names no approver).")
    return SignOff(performed_by=meta.performed_by or meta.operator or "not stated",
                   approved_by=meta.approved_by or "not approved", date_of_issue=s.issued, signing=signing)


def _deviations(s: Sources) -> Table | None:
    results = s.results
    rows = []
    if results.positioning_deviations is not None:
        table = PositioningDeviations.from_model(results.positioning_deviations)
        curve = mean_curve(table, results, wrap=False)
        counts: dict[tuple[float, int], int] = {}
        for t, d in zip(table.target_deg, table.direction):
            counts[(round(float(t), 6), int(d))] = counts.get((round(float(t), 6), int(d)), 0) + 1
        for key in curve:  # in the measurement's order
            x, u = curve[key]
            rows.append([f"{key[0]:g}", "↑" if key[1] > 0 else "↓", value_text(x, 2 * u, "+"), u_text(u), u_text(2 * u),
                         str(counts.get(key, ""))])
    words = estimate_name(results)
    return Table(heading="Result: positioning deviation per target and direction",
                 note=("Deviation = actual − commanded angle (arcsec), relative to the first target of the first direction; "
                       "u standard uncertainty, U = 2u expanded uncertainty (k = 2, about 95 %). Estimate: "
                       f"{words}."),
                 header=["target / °", "direction", "deviation / ″", "u / ″", "U (k = 2) / ″", "runs"], rows=rows)


def _parameters(s: Sources) -> Parameters | None:
    from rtcal.deliverables.conformity import parameter_uncertainties

    results = s.results
    iso = results.evaluation.iso230_2 if results.evaluation else None
    if iso is None:
        return None
    vdi = results.evaluation.vdi3441 if results.evaluation else None
    u = parameter_uncertainties(results)
    notes = [n for n in iso.notes + [n for n in (vdi.notes if vdi else []) if n not in iso.notes]
             if n not in UNCONFIRMED.values()]  # what is not confirmed: docs/evaluation.md, not the customer's
    return Parameters(
        heading=("ISO 230-2:2014 parameters" if not s.departed else
                 "Positioning parameters computed as ISO 230-2 defines them (not ISO 230-2 results: the test departs "
                 "from it, see page 1)"),
        rows=[ParameterRow(symbol=sym, meaning=desc, value_arcsec=value_text(getattr(iso, key), u.get(key)),
                           expanded_uncertainty_arcsec=u_text(u.get(key)))
              for key, sym, desc in ISO_KEYS if getattr(iso, key) is not None],
        vdi_rows=[ParameterRow(symbol=sym, meaning=desc, value_arcsec=_fmt(getattr(vdi, key))) for key, sym, desc in VDI_KEYS]
        if vdi else [], notes=notes)


def _tables(s: Sources) -> list[Table]:
    return [Table(heading=t["heading"], note=t["note"], header=list(t["header"]), rows=[list(r) for r in t["rows"]],
                  numeric_from_column=1) for t in s.outputs.certificate_tables()]  # the method's own, e.g. ISO 230-7's


def _figures(s: Sources) -> list[Figure]:
    present = [(f, c) for f, c in s.figures if (s.run_dir / f).exists()]
    return [Figure(file=f, caption=f"Figure {n}: {caption}") for n, (f, caption) in enumerate(present, start=1)]


def _budget(s: Sources) -> Budget | None:
    e = s.results.recommended_estimate()
    if e is None:
        return None
    b = e.uncertainty_budget
    rows = []
    for c in b.components:
        stated = c.note if "," in c.unit else f"{c.input_sigma:.3g} {c.unit}"  # several inputs: say them
        rows.append(BudgetRow(source=c.source, type=c.type, input=stated + (" (from the data)" if c.estimated_from_data else ""),
                              contribution_arcsec=_fmt(largest(c.contribution_arcsec), 3)))
    comb = largest(b.combined_arcsec)
    rows.append(BudgetRow(source="combined standard uncertainty u", type="", input="", contribution_arcsec=_fmt(comb, 3)))
    rows.append(BudgetRow(source="expanded uncertainty U (k = 2), rounded up to two digits", type="", input="",
                          contribution_arcsec=u_text(None if comb is None else 2 * comb)))
    return Budget(rows=rows, not_included=list(b.not_included))


def _method(s: Sources) -> Method:
    return Method(name=s.outputs.method_name() or s.results.method, paragraphs=list(s.outputs.method_text()))


def _standards(s: Sources) -> Standards:
    return Standards(rows=[Instrument(instrument=r[0], role=r[1], id=r[2], certificate=r[3], calibrated_by=r[4], due=r[5])
                           for r in instrument_rows(s.results)], connections=connections(s.results))


def _conditions(s: Sources) -> Conditions:
    return Conditions(rows=[Item(label=k, value=v) for k, v in conditions(s.results)], brief=conditions_in_brief(s.results))


def _control(s: Sources) -> Control:
    brief, details = control_lines(s.results)
    return Control(brief=brief, details=details)


EVENTS_LISTED = 60  # report.md lists this many faults and actions; the rest are in results.json and run.sqlite


def _run(s: Sources) -> RunRecord:
    r = s.results
    counts: dict[str, int] = {}
    for ev in r.events:
        counts[ev.kind] = counts.get(ev.kind, 0) + 1
    notable = [ev for ev in r.events if ev.kind in NOTABLE_EVENTS]
    return RunRecord(
        report_title=f"rtcal run — {r.procedure.name or r.method}", method_key=r.method,
        software=f"rtcal {r.rtcal_version}", started_utc=r.started_utc or "?", finished_utc=r.finished_utc or "?",
        measured=measurement_dates(r), duration_s=r.measurement_duration_s, virtual_clock=r.clock == "virtual",
        raw_readings=r.raw_readings, faults=r.faults, skipped_readings=r.skipped_readings,
        run_counts=f"{plural(r.raw_readings, 'planned reading')} taken, {r.skipped_readings} skipped, "
                   f"{plural(r.faults, 'instrument fault')}",
        event_counts=", ".join(f"{k}: {n}" for k, n in counts.items()) or "none",
        notable_events=[f"t = {ev.t_s:.1f} s, {ev.kind}{f' ({ev.instrument})' if ev.instrument else ''}: {ev.message}"
                        for ev in notable[:EVENTS_LISTED]],
        notable_more=max(0, len(notable) - EVENTS_LISTED),
        solver_issues=[SolverIssue(estimator=n, status=st.status, message=st.message)
                       for n, st in r.solver_status.items() if st.status != "converged"],
        bench_note=r.bench if r.bench and r.bench.startswith("ideal bench") else "",
        instruments=[Item(label=k, value=v) for k, v in r.instruments.items()] if isinstance(r.instruments, dict) else [],
        simulated="" if isinstance(r.instruments, dict) else f"{r.instruments}, bench `{r.bench}`, seed {r.seed}",
        recommended=r.recommended or "")


def _report_body(s: Sources) -> list[str]:
    return list(s.outputs.report_body())


# The certificate's sections, each from one builder: a new section is a field of Certificate and a line here.
SECTION_BUILDERS: list[tuple[str, Callable[[Sources], Any]]] = [
    ("header", _header), ("identification", _identification), ("result_in_brief", _result_in_brief),
    ("conformity", _conformity), ("traceability", _traceability), ("sign_off", _sign_off), ("deviations", _deviations),
    ("parameters", _parameters), ("tables", _tables), ("figures", _figures), ("budget", _budget), ("method", _method),
    ("standards", _standards), ("conditions", _conditions), ("control", _control), ("run", _run),
    ("report_body", _report_body),
]


def build_certificate(results: RunResults, run_dir: Path, outputs: MethodOutputs | None = None,
                      figures: list[tuple[str, str]] | None = None) -> Certificate:
    """The document, once, from the results and their metadata; ``figures`` (file, caption) default
    to the method's own, shown only when the file is in ``run_dir``."""
    outputs = outputs or outputs_for(results)
    meta = results.metadata
    sources = Sources(results=results, run_dir=run_dir, outputs=outputs,
                      figures=list(outputs.certificate_figures() if figures is None else figures),
                      issued=meta.date_of_issue or _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d"),
                      missing=[what for key, what in CERTIFICATE_NEEDS if not getattr(meta, key)],
                      departed=iso_departures(results))
    certificate = Certificate(**{name: build(sources) for name, build in SECTION_BUILDERS})
    certificate._figures_dir = run_dir
    return certificate


def write_certificate_json(certificate: Certificate, path: Path) -> Path:
    """The document as JSON (certificate.json), for a laboratory's own systems."""
    path.write_text(certificate.model_dump_json(indent=1) + "\n", encoding="utf-8")
    return path


def certificate_schema() -> str:
    """JSON Schema (draft 2020-12) of certificate.json, every field described: what ``rtcal schema
    --certificate`` prints."""
    schema = Certificate.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "rtcal certificate.json"
    schema["description"] = ("The calibration certificate of one rtcal run as one document: every word and number "
                             "report.html, report.pdf and report.md show, section by section.")
    return json.dumps(schema, indent=2)
