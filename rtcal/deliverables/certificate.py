"""The certificate as ONE typed document, built once from a run's results and metadata.

Every word and number the calibration certificate (report.html, report.pdf) and the run's report
(report.md) show is decided here, once: the renderers in :mod:`rtcal.deliverables.report` only
lay this document out, so a value cannot read one way in the PDF and another in the HTML or the
Markdown. Uncertainties go through :mod:`rtcal.deliverables.rounding` as everywhere else.

A section is a typed model (a field of :class:`Certificate`) and one entry of
:data:`SECTION_BUILDERS`, a function of the run (:class:`Sources`) that returns it, or None where
the run has nothing for it (no acceptance limits: no conformity section). What is particular to a
method comes from the method object the caller passes (its outputs, conditions and roles), never
from the results' class. The document is also written as certificate.json beside the report.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, cast

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr

from rtcal.deliverables.comparison import mean_curve
from rtcal.deliverables.deviations import PositioningDeviations
from rtcal.deliverables.evaluation import UNCONFIRMED
from rtcal.deliverables.departures import departures, parameters_label
from rtcal.deliverables.method_outputs import MethodOutputs
from rtcal.deliverables.rounding import fmt, significant, u_text, value_text
from rtcal.results.model import EnvironmentSummary, InstrumentRecord, QuantityEstimate, RunResults

SCHEMA_VERSION = "1.1"  # 1.1: periodic_error may be null (a method whose result is no positioning deviation)


class CertifiedMethod(Protocol):
    """What the certificate needs of the run's method (:class:`rtcal.methods.protocol.Method` has it):
    its procedure model (which instruments it has), whether its result is a positioning deviation (a
    positioning test's sections apply, or are left out), the conditions and roles it states, its outputs."""

    @property
    def procedure_model(self) -> type[BaseModel]: ...

    @property
    def positioning_deviation(self) -> bool: ...

    def conditions(self, results: RunResults) -> EnvironmentSummary | None: ...

    def instrument_roles(self, results: RunResults) -> dict[str, str]: ...

    def outputs(self, results: RunResults) -> MethodOutputs: ...


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


def __getattr__(name: str) -> object:
    """Deprecated: ``ROLES`` and ``REFERENCE_STANDARDS`` are the methods' (each method's ``instrument_roles``,
    rtcal/methods/<method>/method.py); the old names go in the next release."""
    if name not in ("ROLES", "REFERENCE_STANDARDS"):
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import warnings

    warnings.warn(f"rtcal.deliverables.certificate.{name} moved: a method's instrument_roles() states every role",
                  DeprecationWarning, stacklevel=2)
    return ({"polygon": "reference standard: angle (face errors from its certificate)",
             "autocollimator": "reference standard: angle", "laser_tracer": "reference standard: length",
             "environment": "measuring instrument: conditions", "cmm": "positions the reflector",
             "encoder": "the item's encoder (analysed)", "dial_indicator_1": "measuring instrument: shaft motion",
             "dial_indicator_2": "measuring instrument: shaft motion", "stage": "the item's drive (commanded)"}
            if name == "ROLES" else ("polygon", "autocollimator", "laser_tracer"))


REFERENCE_STANDARD = "reference standard"
"""How a method's role of an instrument begins when the instrument is a reference standard (the
traceability statement cites its certificate)."""


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


def failed_test_notes(results: RunResults) -> list[str]:
    """When the quoted estimate failed its residual test: that its U cannot be quoted as a coverage interval, and
    what the failure means (its budget's not_included entry says which assumptions the readings contradict). The
    recommendation does not move to an estimate whose weaker test passed: that one shares the error."""
    e = results.recommended_estimate()
    test = getattr(e, "residual_test", None)
    if e is None or test is None or test.passed:
        return []
    said = [n for n in e.uncertainty_budget.not_included if "residual test failed" in n]
    passing = [n for n, other in results.estimates.items() if n != results.recommended
               and getattr(getattr(other, "residual_test", None), "passed", False)
               and getattr(results.solver_status.get(n), "status", None) == "converged"]
    others = "another estimate passed its test" if len(passing) == 1 else f"{len(passing)} other estimates passed theirs"
    instead = (f"No other estimate is quoted instead, though {others}: the estimates share "
               "the readings and the budget's assumptions, and a weaker test passes what it cannot see."
               if passing else "No estimate passed its test.")
    return [f"The quoted estimate FAILED its residual test (χ² = {test.chi2:.0f} for {test.dof} degrees of freedom, "
            f"p = {test.p_value:.2g}): the readings contradict the uncertainty budget, so the expanded uncertainties "
            f"stated here are NOT coverage intervals and the result cannot be quoted with them. {instead}"
            + (f" What it means: {said[0].split('; the readings contradict what the budget assumed — ')[-1]}."
               if said and "— one of:" in said[0] else "")]


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


def environment_of(results: RunResults, method: CertifiedMethod) -> EnvironmentSummary | None:
    """The conditions the environment sensor recorded (None: no sensor), as the results' method reads them."""
    return method.conditions(results)


def condition_label(name: str) -> str:
    """A condition's human label with its unit, from the results model's description: "air temperature / °C"."""
    text = EnvironmentSummary.model_fields[name].description or name
    quantity, _, unit = text.rpartition(", ")
    return f"{quantity} / {unit}" if quantity else text


def conditions(results: RunResults, method: CertifiedMethod) -> list[tuple[str, str]]:
    """(label, "min … max (mean …)") per recorded condition; one "not recorded" row without a sensor."""
    env = environment_of(results, method)
    if env is None:
        return [("air and table", "not recorded (the procedure has no environment instrument)")]
    return [(condition_label(name), _range(v.min, v.max) + f" (mean {v.mean:g})") for name, v in env.items()]


def _range(lo: float, hi: float, sep: str = " – ") -> str:
    """A condition's range as min – max, also when it did not change (20 – 20: read, and constant)."""
    return f"{lo:g}{sep}{hi:g}"


def conditions_in_brief(results: RunResults, method: CertifiedMethod) -> str:
    env = environment_of(results, method)
    if env is None:
        return "not recorded (no environment sensor)"
    return "; ".join(f"{condition_label(n).split(' / ')[0]} {_range(v.min, v.max)} {condition_label(n).split(' / ')[-1]}"
                     for n, v in env.items())


def instruments_used(results: RunResults, method: CertifiedMethod) -> list[str]:
    """The procedure's instruments this run used, then its reference standards (from the procedure
    models: one truth of which instruments a method has; the optional sensor when it recorded)."""
    model = method.procedure_model
    names = []
    instruments = cast("type[BaseModel]", model.model_fields["instruments"].annotation)  # each method's Instruments model
    for name, field in instruments.model_fields.items():
        optional = field.default is None
        if not optional or (name == "environment" and environment_of(results, method) is not None) or (
                isinstance(results.instruments, dict) and name in results.instruments):
            names.append(name)
    names += [n for n in getattr(model, "REFERENCE_STANDARDS", ())]
    return names + [n for n in results.metadata.instruments if n not in names]


def instrument_rows(results: RunResults, method: CertifiedMethod) -> list[tuple[str, ...]]:
    """(instrument, role, id, its certificate, calibrated by, due) per instrument and standard."""
    records = results.metadata.instruments
    none = InstrumentRecord(id="", calibration_due="")
    roles = method.instrument_roles(results)  # the method's words, e.g. a polygon separated by closure
    return [(name.replace("_", " "), roles.get(name, ""), records.get(name, none).id or "not recorded",
             records.get(name, none).certificate_number or "–", records.get(name, none).calibrated_by or "–",
             records.get(name, none).calibration_due or "–") for name in instruments_used(results, method)]


def connections(results: RunResults) -> str:
    """Where the instruments were reached."""
    if isinstance(results.instruments, dict):
        return "; ".join(f"{k.replace('_', ' ')}: {v}" for k, v in results.instruments.items())
    return f"every instrument simulated in process (bench {Path(results.bench or '').name or 'ideal'}, random sequence no. {results.seed})"


def traceability(results: RunResults, method: CertifiedMethod) -> str:
    """The metadata's statement, else one made from the reference standards' certificates, else "not stated"."""
    meta = results.metadata
    if meta.traceability:
        return meta.traceability
    used = set(instruments_used(results, method))
    cited = [(n, meta.instruments[n]) for n, role in method.instrument_roles(results).items()
             if role.startswith(REFERENCE_STANDARD) and n in used and n in meta.instruments
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


def estimate_name(outputs: MethodOutputs) -> str:
    """The recommended estimate in words (the method's outputs name it), never its key."""
    return getattr(outputs, "estimate_words", lambda: "the recommended estimate")()


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
    q = results.recommended_result()
    if isinstance(q, QuantityEstimate):  # a result in its own quantity and unit, as the method declares it
        values = [v for v in q.value if v is not None]
        U = largest(q.expanded_uncertainty)
        if values:
            rows.append((f"{q.quantity} (per target and direction)",
                         f"{value_text(min(values), U, '+')} {q.unit} … {value_text(max(values), U, '+')} {q.unit} over "
                         f"{len({round(t, 6) for t in q.target_deg})} targets", f"U ≤ {u_text(U)} {q.unit}"))
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
    p = results.periodic_error
    if p is not None:
        rows.append((f"periodic positioning error over {period_text(p.period_deg, 1.0 if p.worm_ratio else None)} (ISO 230-2:2014 "
                     "Annex C as rtcal reads it)", f"{value_text(p.periodic_error_arcsec, p.expanded_uncertainty_arcsec)}″",
                     "U " + u_text(p.expanded_uncertainty_arcsec) + "″"))
    return rows


def plural(n: int, noun: str) -> str:
    """"1 event", "2 events", "0 events"."""
    return f"{n} {noun}" + ("" if n == 1 else "s")


ITEM_STATES = {"as_found": "as found: as received, before any adjustment or compensation",
               "as_left": "as left: after adjustment or compensation"}
NOTABLE_EVENTS = ("fault", "retry", "reacquire", "skip", "pause", "abort", "resume")


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
    marking: str = Field("", description="SIMULATED / REHEARSED — not a calibration, and why: every page's header and "
                                         "footer carry it (empty: real instruments, not rehearsed)")
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
    electronic_signature: str = Field("", description="who signed the run's digests and with which key (its fingerprint), "
                                                      "or that the run is unsigned")

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


class FigureRow(Part):
    """One figure of another standard, as the page states it."""

    symbol: str = Field(description="the standard's own symbol (e.g. UPR, No. 346, TUR (E))")
    value: str = Field(description="the value with its unit (″), rounded as its U; a ratio without unit")
    expanded_uncertainty: str = Field(description="its U (k = 2) in arcsec, or – where not evaluated for this form")
    edition: str = Field(description="the edition whose definition gives it")
    coverage: str = Field(description="the coverage of the scatter in it (k = 2, 3s, 6s, none)")
    definition: str = Field(description="the definition in words")
    beside: str = Field("", description="what it stands beside (a TUR: the verdict it belongs to)")


class StandardBlock(Part):
    """One standard's figures under its own title, never another's."""

    label: str = Field(description="the label the procedure's evaluation.standards names it by")
    title: str = Field(description="the standard's title and edition, as the figures are headed")
    rows: list[FigureRow]
    rule: str = Field(description="how these figures relate to ISO 230-2:2014's (empty: they are its own)")
    notes: list[str] = Field(description="undefined figures, what is not confirmed")


class OtherStandards(Part):
    """The figures the procedure's ``evaluation.standards`` asks for, from the same readings."""

    heading: str = "Figures to other standards (from the same readings)"
    note: str = Field(description="what the figures are made from")
    header: list[str] = ["symbol", "value", "U (k = 2) / ″", "definition (edition; coverage)"]
    blocks: list[StandardBlock]


class PeriodicErrorSection(Part):
    """ISO 230-2:2014 Annex C's periodic positioning error: the figure and the period's harmonics when
    the run made the fine-step test, "not tested" otherwise."""

    heading: str = "Periodic positioning error (ISO 230-2:2014 Annex C)"
    tested: bool = Field(description="the run made a fine-step test through a period")
    statement: str = Field(description="not tested, or the figure's definition and what it rests on")
    header: list[str] = ["quantity", "value", "U (k = 2)"]
    rows: list[KeyResult] = Field(description="the figure per direction and of the axis (empty: not tested)")
    harmonic_header: list[str] = ["order per turn", "period", "amplitude / ″", "1σ / ″", "significant"]
    harmonic_rows: list[list[str]] = Field(description="the period's harmonics (empty: not tested)")
    notes: list[str] = Field(description="the reference read and what the figure leaves out")


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
    other_standards: OtherStandards | None = Field(description="None: the procedure asks for no other standard's figures")
    periodic_error: PeriodicErrorSection | None = Field(description="ISO 230-2:2014 Annex C: the figure, or not tested; "
                                                                    "None: the method's result is no positioning deviation "
                                                                    "and the run made no such test (e.g. the R-test)")
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
    method: CertifiedMethod
    outputs: MethodOutputs
    figures: list[tuple[str, str]]
    issued: str
    missing: list[str]
    departed: list[str]

    @property
    def doc(self) -> str:
        return "report" if self.missing else "certificate"


def subject(results: RunResults, outputs: MethodOutputs | None = None) -> str:
    """What the certificate is of: what the method's outputs say it measured (their optional ``subject()``), else
    the angular positioning deviation, or the quantity the method's result declares."""
    said = getattr(outputs, "subject", lambda: "")()
    if said:
        return str(said)
    q = results.recommended_result()
    if isinstance(q, QuantityEstimate):
        return f"{q.quantity[:1].upper()}{q.quantity[1:]} ({q.unit})"
    return "Angular positioning deviation of a rotary axis"


def marking(results: RunResults) -> str:
    """What every page says of a run that measured no real item or was rehearsed ("": a calibration):
    results.json's statement, or for a file from before 1.4 its in-process instruments."""
    if results.simulation is not None:
        return results.simulation.statement
    if isinstance(results.instruments, str):
        return "SIMULATED — NOT A CALIBRATION: every instrument and the table were simulated in process on a model bench"
    return ""


def signature_line(results: RunResults) -> str:
    """Who signed the run's digests, with which key; or that it is unsigned."""
    sig = results.signature
    if sig is None:
        return "Unsigned: no laboratory key was configured (its digests show accidents, not forgery)."
    return f"Signed electronically by {sig.signer}, Ed25519 key {sig.key_fingerprint} (signature.json)."


def _header(s: Sources) -> Header:
    meta, results = s.results.metadata, s.results
    footer = " · ".join(x for x in (marking(results).partition(":")[0],  # first: a long name never cuts it off
                                    meta.laboratory or results.procedure.name or results.method,
                                    f"Certificate {meta.certificate_number}" if meta.certificate_number else "") if x)
    return Header(title="Calibration certificate" if not s.missing else "Calibration report",
                  subtitle=subject(results, s.outputs),
                  laboratory=meta.laboratory or "Laboratory not stated", laboratory_address=meta.laboratory_address,
                  certificate_number=meta.certificate_number,
                  not_certificate=("Not a calibration certificate: the procedure's metadata does not give "
                                   + ", ".join(s.missing) + "." if s.missing else ""),
                  marking=marking(results),
                  footer=footer, closing="End of report." if s.missing else "End of certificate.")


def _identification(s: Sources) -> Identification:
    results, meta = s.results, s.results.metadata
    conformity = results.conformity
    evaluated = results.evaluation is not None  # a result of the method's own quantity is evaluated by no positioning standard
    standards = list(STANDARDS if evaluated else STANDARDS[2:]) + ([DECISION_STANDARDS[conformity.decision_rule]] if conformity else [])
    if s.departed:
        standards[0] = "ISO 230-2:2014 (its formulas for E, M, B, R, A applied to a test that departs from its test: see Departures)"
    standards = list(getattr(s.outputs, "standards_applied", lambda: [])()) + standards  # the method's own, e.g. ISO 230-7
    item = ", ".join(x for x in (meta.machine, f"axis {meta.axis}" if meta.axis else "",
                                 f"serial number {meta.serial_number}" if meta.serial_number else "") if x)
    rows = [
        ("Certificate number", meta.certificate_number or "not given"),
        *([("Replaces", f"certificate {meta.replaces}, which this certificate supersedes (that one is withdrawn, "
                        "and kept)")] if meta.replaces else []),
        ("Date of issue", s.issued),
        ("Customer", ", ".join(x for x in (meta.customer, meta.customer_address) if x) or "not given"),
        ("Item calibrated", item or "not given"),
        ("Condition on receipt", getattr(meta, "condition_on_receipt", "") or "not recorded"),
        *([("State of the item", ITEM_STATES[meta.item_state])] if meta.item_state else []),
        ("Place of calibration", meta.location or "not given"),
        ("Date of measurement", measurement_dates(results)),
        ("Method", s.outputs.method_name() or results.method),
        ("Procedure", f"{results.procedure.name or '(untitled)'} ({Path(results.procedure.path).name})"),
        ("Standards applied", "; ".join(standards)),
        ("Departures from the method", ("; ".join(s.departed) + ". The parameters are computed as ISO 230-2 defines them; "
                                        "they are not ISO 230-2 results.") if s.departed else "none"),
        ("Conditions during the measurement", conditions_in_brief(results, s.method)),
        ("Control of the machine", control_lines(results)[0]),
    ]
    if isinstance(results.instruments, str):
        rows.append(("Instruments", "simulated: every instrument and the table are simulated on a model bench "
                                    f"({Path(results.bench or '').name or 'ideal'}, random sequence no. {results.seed}); "
                                    "a demonstration, not a measurement of a real item"))
    if results.simulation is not None and (results.simulation.simulators or results.simulation.rehearsed):
        rows.append(("Simulation", results.simulation.statement))  # what each said: results.json, `simulation`
    notes = [f"Estimator {n} {st.status}: {st.message}" for n, st in results.solver_status.items()
             if st.status != "converged"]
    notes += failed_test_notes(results)
    if results.bench is not None and results.bench.startswith("ideal bench"):
        notes.append(results.bench)
    if results.faults or results.skipped_readings:
        notes.append(f"{plural(results.faults, 'instrument fault')} and {plural(results.skipped_readings, 'skipped reading')} "
                     "during the run (see Run).")
    return Identification(items=[Item(label=k, value=v) for k, v in rows], notes=notes)


def _not_included(s: Sources) -> list[str]:
    e = s.results.recommended_result()
    if isinstance(e, QuantityEstimate):
        return list(e.not_included)
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
    return Traceability(statement=traceability(s.results, s.method), relates=RELATES_STATEMENT.format(doc=s.doc))


def _sign_off(s: Sources) -> SignOff:
    meta = s.results.metadata
    signing = (SIGNING_STATEMENT.format(doc=s.doc, approver=meta.approved_by, date=s.issued) if meta.approved_by else
               f"This {s.doc} has not been approved for issue (the procedure's metadata names no approver).")
    return SignOff(performed_by=meta.performed_by or meta.operator or "not stated",
                   approved_by=meta.approved_by or "not approved", date_of_issue=s.issued, signing=signing,
                   electronic_signature=signature_line(s.results))


def _deviations(s: Sources) -> Table | None:
    results = s.results
    if results.positioning_deviations is None:  # a result of the method's own quantity: its own tables state it
        return None
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
    words = estimate_name(s.outputs)
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


def _other_standards(s: Sources) -> OtherStandards | None:
    from rtcal.deliverables.conformity import parameter_uncertainties
    from rtcal.deliverables.standards import ARCSEC, standard_figures

    results = s.results
    labels = results.procedure.standards or []
    if not labels or results.positioning_deviations is None:
        return None
    table = PositioningDeviations.from_model(results.positioning_deviations)
    u = parameter_uncertainties(results)
    blocks = []
    for label in labels:
        try:
            found = standard_figures(label, table, u, results.conformity)
        except ValueError as exc:  # a TUR without a verdict: said, not skipped
            blocks.append(StandardBlock(label=label, title=label, rows=[], rule="", notes=[str(exc)]))
            continue
        rows = [FigureRow(symbol=f.symbol,
                          value=(value_text(f.value, f.expanded_uncertainty) + "″" if f.unit == ARCSEC and f.value is not None
                                 else "–" if f.value is None else f"{f.value:.1f}"),
                          expanded_uncertainty=u_text(f.expanded_uncertainty), edition=f.edition, coverage=f.coverage,
                          definition=f.definition, beside=f.beside) for f in found.figures]
        notes = [n for n in found.notes if n not in UNCONFIRMED.values()]
        blocks.append(StandardBlock(label=found.label, title=found.title, rows=rows, rule=found.rule, notes=notes))
    prefix = "" if not s.departed else "Computed as each standard defines them from a test that departs from ISO 230-2's (see page 1). "
    return OtherStandards(note=prefix + "Each figure is computed from the same positioning deviations as the ISO 230-2 "
                          "parameters, by its own standard's definition and under its own title; U (k = 2) is given where "
                          "the figure is the same quantity as an ISO 230-2:2014 parameter.", blocks=blocks)


NOT_TESTED = ("Not tested: this run made no fine-step test through a period of the axis (procedures/periodic_error.yaml "
              "makes one).")


def period_text(period_deg: float, worm_revolutions: float | None) -> str:
    """A period in degrees and, where the worm ratio is stated, in worm revolutions."""
    revs = "" if worm_revolutions is None else f" = {worm_revolutions:.4g} worm revolution" + (
        "" if abs(worm_revolutions - 1) < 1e-9 else "s")
    return f"{period_deg:.4g}°{revs}"


def _periodic_error(s: Sources) -> PeriodicErrorSection | None:
    p = s.results.periodic_error
    if p is None and not s.method.positioning_deviation:  # Annex C is a positioning test: not this method's to make
        return None
    if p is None:
        return PeriodicErrorSection(tested=False, statement=NOT_TESTED, rows=[], harmonic_rows=[], notes=[])
    U = p.expanded_uncertainty_arcsec
    over = f"over one period of {period_text(p.period_deg, 1.0 if p.worm_ratio else None)}"
    up, down = p.expanded_uncertainty_up_arcsec, p.expanded_uncertainty_down_arcsec
    rows = [KeyResult(quantity=f"periodic positioning error ↑ {over}", value_arcsec=value_text(p.periodic_error_up_arcsec, up) + "″",
                      expanded_uncertainty_arcsec=u_text(up) + "″"),
            KeyResult(quantity=f"periodic positioning error ↓ {over}",
                      value_arcsec=value_text(p.periodic_error_down_arcsec, down) + "″", expanded_uncertainty_arcsec=u_text(down) + "″"),
            KeyResult(quantity="periodic positioning error of the axis (the larger)",
                      value_arcsec=value_text(p.periodic_error_arcsec, U) + "″", expanded_uncertainty_arcsec=u_text(U) + "″")]
    harmonics = [[str(h.order), period_text(h.period_deg, h.period_worm_revolutions), f"{h.amplitude_arcsec:.2f}",
                  f"{h.amplitude_sigma_arcsec:.2f}", "yes" if h.significant else "no"] for h in p.harmonics]
    return PeriodicErrorSection(
        tested=True, statement=p.definition + f". Steps of {p.step_deg:g}° from {p.start_deg:g}°, "
        f"{p.targets_per_period} targets per period, both directions as the procedure states.", rows=rows,
        harmonic_rows=harmonics, notes=[f"Reference: {p.reference}."] + list(p.notes))


def standards_on_certificate(results: RunResults, positioning: bool = True) -> str:
    """The standards whose positioning-test figures the certificate states, in a sentence (the method section's);
    nothing of a method whose result is no positioning deviation (``positioning`` False) and that made no such test."""
    from rtcal.procedure.standards import STANDARDS as LABELLED

    named = ["ISO 230-2:2014 (E, M, B, R, A)", "VDI/DGQ 3441:1977 (Pa, P, Ps, U)"] if results.evaluation else []
    named += [LABELLED[label].title for label in results.procedure.standards or []]
    if results.periodic_error is not None:
        named.append("the periodic positioning error of ISO 230-2:2014 Annex C (as rtcal reads the annex: see its section)")
    if not named and not positioning:
        return ""
    periodic = "" if results.periodic_error is not None else " The periodic positioning error (ISO 230-2:2014 Annex C) was not tested."
    return ("Figures on this certificate: " + "; ".join(named) + "." if named else
            "No positioning-test figures are on this certificate (no positioning deviations).") + periodic


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
        stated = c.note if "," in c.unit else f"{significant(c.input_sigma)} {c.unit}"  # several inputs: say them
        rows.append(BudgetRow(source=c.source, type=c.type, input=stated + (" (from the data)" if c.estimated_from_data else ""),
                              contribution_arcsec=_fmt(largest(c.contribution_arcsec), 3)))
    comb = largest(b.combined_arcsec)
    rows.append(BudgetRow(source="combined standard uncertainty u", type="", input="", contribution_arcsec=_fmt(comb, 3)))
    rows.append(BudgetRow(source="expanded uncertainty U (k = 2), rounded up to two digits", type="", input="",
                          contribution_arcsec=u_text(None if comb is None else 2 * comb)))
    return Budget(rows=rows, not_included=list(b.not_included))


def _method(s: Sources) -> Method:
    figures = standards_on_certificate(s.results, s.method.positioning_deviation)
    return Method(name=s.outputs.method_name() or s.results.method,
                  paragraphs=list(s.outputs.method_text()) + ([figures] if figures else []))


def _standards(s: Sources) -> Standards:
    return Standards(rows=[Instrument(instrument=r[0], role=r[1], id=r[2], certificate=r[3], calibrated_by=r[4], due=r[5])
                           for r in instrument_rows(s.results, s.method)], connections=connections(s.results))


def _conditions(s: Sources) -> Conditions:
    return Conditions(rows=[Item(label=k, value=v) for k, v in conditions(s.results, s.method)], brief=conditions_in_brief(s.results, s.method))


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
    ("parameters", _parameters), ("other_standards", _other_standards),
    ("periodic_error", _periodic_error), ("tables", _tables), ("figures", _figures), ("budget", _budget), ("method", _method),
    ("standards", _standards), ("conditions", _conditions), ("control", _control), ("run", _run),
    ("report_body", _report_body),
]


def _sources(results: RunResults, run_dir: Path, method: CertifiedMethod,
             figures: list[tuple[str, str]] | None = None) -> Sources:
    outputs = method.outputs(results)
    meta = results.metadata
    return Sources(results=results, run_dir=run_dir, method=method, outputs=outputs,
                   figures=list(outputs.certificate_figures() if figures is None else figures),
                   issued=meta.date_of_issue or _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d"),
                   missing=[what for key, what in CERTIFICATE_NEEDS if not getattr(meta, key)],
                   departed=iso_departures(results))


def build_certificate(results: RunResults, run_dir: Path, method: CertifiedMethod,
                      figures: list[tuple[str, str]] | None = None) -> Certificate:
    """The document, once, from the results, their metadata and the ``method`` they are of; ``figures``
    (file, caption) default to the method's own, shown only when the file is in ``run_dir``."""
    sources = _sources(results, run_dir, method, figures)
    certificate = Certificate(**{name: build(sources) for name, build in SECTION_BUILDERS})
    certificate._figures_dir = run_dir
    return certificate


def certificate_sections(results: RunResults, run_dir: Path, method: CertifiedMethod, names: tuple[str, ...]) -> dict[str, Any]:
    """Some of the certificate's sections (``names``: header, result_in_brief, …), built by the builders
    :func:`build_certificate` uses: what another view of the run (the live page) shows, in the same words
    and rounded numbers."""
    sources = _sources(results, run_dir, method)
    builders = dict(SECTION_BUILDERS)
    return {name: builders[name](sources) for name in names}


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
