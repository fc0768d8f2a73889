"""Procedure models. Units live in key names; the numeric core converts at the edge.

A procedure names its ``method``; its ``instruments`` section chooses a backend per
instrument; ``bench`` names the scenario that simulated backends observe (a path relative to
the procedure file), which ``rtcal run --scenario`` replaces.

Every number is finite and has bounds a person would accept (the hostile-input corpus in
tests/data/bad/ tries the rest); a plan larger than ``MAX_PLANNED_READINGS`` needs ``--large``.
Each field carries a ``description`` that editors show from ``rtcal schema``.
"""

from __future__ import annotations

import datetime
import difflib
import re
import unicodedata
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Literal

from pydantic import (BaseModel, ConfigDict, Field, SerializerFunctionWrapHandler, field_validator, model_serializer,
                      model_validator)

from rtcal.procedure.standards import LABELS, STANDARDS, standard_named

ANGLE_LIMIT_DEG = 36_000.0  # 100 turns either way: beyond any table's travel
COORD_LIMIT_MM = 1e6  # 1 km: beyond any CMM
Coord_mm = Annotated[float, Field(ge=-COORD_LIMIT_MM, le=COORD_LIMIT_MM)]
Vec3 = tuple[Coord_mm, Coord_mm, Coord_mm]
Angle_deg = Annotated[float, Field(ge=-ANGLE_LIMIT_DEG, le=ANGLE_LIMIT_DEG)]

# Plan sizes (planned readings × samples per reading). The paper's plan has 704; 120 000 took
# 67 s and 0.5 GB on the simulated bench. Beyond the first limit `--large` is needed; beyond the
# second nothing runs. The joint seed-000 solver holds a readings × (3·stations + segments)
# Jacobian: its cells are limited the same way (8 bytes each, several copies).
MAX_PLANNED_READINGS = 100_000
MAX_PLANNED_READINGS_LARGE = 2_000_000
MAX_SOLVER_CELLS = 20_000_000
MAX_SOLVER_CELLS_LARGE = 200_000_000


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class InstrumentRecord(_Strict):
    """An instrument as a certificate names it."""

    id: str = Field("", max_length=200, description="make, model and serial number (e.g. Etalon LaserTRACER 12-0034)")
    calibration_due: str = Field("", max_length=40, description="its calibration due date (e.g. 2027-03-31)")
    certificate_number: str = Field("", max_length=100, description="the number of its own calibration certificate "
                                                                   "(e.g. 0815 DKD-K-06901 2025-03)")
    calibrated_by: str = Field("", max_length=200, description="who issued that certificate: the laboratory and its "
                                                              "accreditation (e.g. PTB, or DAkkS D-K-15033-01-00); the "
                                                              "certificate's traceability statement names it")

    _plain = field_validator("id", "calibration_due", "certificate_number", "calibrated_by")(lambda cls, text: _check_text(text))

    _due = field_validator("calibration_due")(lambda cls, text: _check_date(text))


def _check_date(text: str) -> str:
    """A certificate states its dates as dates (unquoted in YAML a date is read as text)."""
    if not text:
        return text
    try:
        if not re.fullmatch(r"\d{4}-\d{2}-\d{2}", text):
            raise ValueError
        datetime.date.fromisoformat(text)
    except ValueError:
        raise ValueError(f"{text[:40]!r} is not a date: write it as YYYY-MM-DD (e.g. 2027-03-31)") from None
    return text


class Metadata(_Strict):
    """Who and what the calibration is for: the report's and certificate's header."""

    customer: str = Field("", max_length=200, description="the customer (e.g. Acme Machine Tools GmbH)")
    machine: str = Field("", max_length=200, description="the machine (e.g. 5-axis machining centre DMU 65)")
    axis: str = Field("", max_length=50, description="the axis calibrated (e.g. C)")
    serial_number: str = Field("", max_length=100, description="the machine's or table's serial number")
    location: str = Field("", max_length=200, description="where it was calibrated")
    operator: str = Field("", max_length=200, description="who calibrated it")
    certificate_number: str = Field("", max_length=100, description="the certificate's number")
    instruments: dict[str, InstrumentRecord] = Field({}, description="per instrument of the procedure (stage, cmm, "
                                                                     "laser_tracer, …) and reference standard (polygon): "
                                                                     "its id, calibration due date and certificate")
    laboratory: str = Field("", max_length=200, description="the calibration laboratory issuing the certificate, with its "
                                                           "accreditation (e.g. Example Metrology Lab GmbH, DAkkS D-K-99999-01-00)")
    laboratory_address: str = Field("", max_length=300, description="the laboratory's address (e.g. Messweg 1, 12345 "
                                                                   "Musterstadt, Germany)")
    customer_address: str = Field("", max_length=300, description="the customer's address")
    date_of_issue: str = Field("", max_length=10, description="the certificate's date of issue, YYYY-MM-DD (empty: the "
                                                             "day the report is written)")
    performed_by: str = Field("", max_length=200, description="who performed the calibration, as the certificate names "
                                                             "them (name, function; empty: the `operator`)")
    approved_by: str = Field("", max_length=200, description="who authorised the certificate for issue (name, function), "
                                                            "ISO/IEC 17025 7.8.2.1 o)")
    traceability: str = Field("", max_length=2000, description="the certificate's traceability statement (empty: made from "
                                                              "the reference standards' certificates listed under "
                                                              "`instruments`)")
    condition_on_receipt: str = Field("", max_length=500, description="the item's condition on receipt (ISO/IEC 17025 "
                                                                     "7.8.2.1 j; e.g. clean, no visible damage, table "
                                                                     "at room temperature overnight)")
    machine_identity: str = Field("", max_length=300, description="the machine's OPC UA server, opc.tcp://HOST:PORT, or "
                                                                 "its MTConnect agent, http://HOST:PORT/DEVICE: its "
                                                                 "identification (OPC 40001-1; MTConnect's Device and "
                                                                 "Description) fills the certificate's item at run time, "
                                                                 "and a serial number other than `serial_number` refuses "
                                                                 "the run")
    item_state: Literal["", "as_found", "as_left"] = Field("", description=(
        "what the run measured: `as_found` (the item as received, before any adjustment or compensation) or `as_left` "
        "(after it); empty: not said (`rtcal run --as-found` / `--as-left` set it)"))
    replaces: str = Field("", max_length=100, description=(
        "the number of the certificate this one replaces (empty: none); the certificate says so, and `rtcal catalog "
        "add --reason` files it as superseding that one"))

    @field_validator("machine_identity")
    @classmethod
    def _opc_tcp(cls, text: str) -> str:
        if text and not text.startswith(("opc.tcp://", "http://", "https://")):
            raise ValueError(f"{text[:60]!r} is not an OPC UA address (opc.tcp://HOST:PORT) or an MTConnect agent's "
                             "(http://HOST:PORT/DEVICE)")
        return _check_text(text)

    _plain = field_validator("customer", "machine", "axis", "serial_number", "location", "operator", "certificate_number",
                             "laboratory", "laboratory_address", "customer_address", "performed_by", "approved_by",
                             "traceability", "condition_on_receipt", "replaces")(lambda cls, text: _check_text(text))
    _issued = field_validator("date_of_issue")(lambda cls, text: _check_date(text))


class InstrumentChoice(_Strict):
    """Which backend serves an instrument: ``backend: sim`` (in-process, on the simulated bench)
    or an ``address`` of a real transport (see drivers/addresses.py): a Modbus drive, an I++
    CMM, a serial device path or ``socket://`` URL."""

    backend: Literal["sim"] | None = Field(None, description="`sim`: the in-process simulated instrument on the bench")
    address: str | None = Field(None, max_length=1000, description="where a real instrument is, e.g. "
                                "`modbus-tcp://192.168.0.20:502?unit=1`, `ipp://cmm:1294`, `/dev/ttyUSB0`, `socket://host:4001`")
    timeout_s: float = Field(2.0, ge=0.01, le=600.0, description="deadline of one request to the instrument, s (e.g. 2; "
                                                               "at least 0.01)")
    kind: str | None = Field(None, min_length=1, max_length=64, pattern=r"^[a-z][a-z0-9_]*$", description=(
        "the instrument's kind (e.g. `dial_indicator`, `inclinometer`): what it reads and which drivers speak to it; "
        "default: by its name (`stage`, `dial_indicator_1`, … or an installed kind's name)"))

    @model_validator(mode="after")
    def _one_backend(self) -> "InstrumentChoice":
        if self.backend is not None and self.address is not None:
            raise ValueError("give either `backend: sim` or an `address`, not both")
        if self.address is not None:
            from drivers.addresses import AddressError, parse_address

            try:
                parse_address(self.address)
            except AddressError as exc:
                raise ValueError(f"address: {exc}") from None
        return self

    @model_serializer(mode="wrap")
    def _kind_when_declared(self, handler: SerializerFunctionWrapHandler) -> Any:
        """``kind`` only where the procedure declared it: an instrument section stored with a run (whose digest
        covers it) is what it was before instruments had a kind."""
        data = handler(self)
        if isinstance(data, dict) and data.get("kind", "") is None:
            del data["kind"]
        return data

    def kind_of(self, name: str) -> str:
        """This instrument's kind: declared (``kind:``), else by its ``name`` (ValueError naming the known kinds)."""
        from drivers.addresses import AddressError
        from drivers.factory import kind_of

        try:
            return kind_of(name, self.kind)
        except AddressError as exc:
            raise ValueError(f"{name}.kind: {exc}" if self.kind is not None else f"{name}: {exc}") from None

    def check_scheme(self, name: str) -> None:
        """The address is of the kind this instrument speaks (a CMM at a Modbus address would fail
        only when the run opens it)."""
        if self.kind is not None:
            self.kind_of(name)  # a declared kind is one rtcal knows, whatever the backend
        if self.address is None:
            return
        from drivers.addresses import AddressError
        from drivers.factory import SchemeMismatch, check_address

        try:
            check_address(name, self.address, self.kind)
        except SchemeMismatch as exc:
            raise ValueError(f"{name}.address: a {exc.scheme} address; the {name.replace('_', ' ')} speaks "
                             f"{' or '.join(exc.schemes)} (see drivers/addresses.py)") from None
        except AddressError as exc:  # a model of another kind of instrument
            raise ValueError(f"{name}.address: {exc}") from None

    @property
    def is_sim(self) -> bool:
        return self.address is None


class StageChoice(InstrumentChoice):
    """The stage, with soft limits rtcal enforces before any command reaches a transport."""

    soft_limits_deg: tuple[Angle_deg, Angle_deg] = Field(
        (-360.0, 360.0), description="[lowest, highest] angle rtcal may command, deg; checked before anything is sent")

    @model_validator(mode="after")
    def _ordered_limits(self) -> "StageChoice":
        if self.soft_limits_deg[0] >= self.soft_limits_deg[1]:
            raise ValueError("soft_limits_deg: the lower limit must be below the upper one")
        if self.address is not None:  # a run moves its stage: taking a LinuxCNC's control is said in its address
            from drivers.addresses import AddressError, check_take_control, parse_address

            try:
                check_take_control(parse_address(self.address))
            except AddressError as exc:
                raise ValueError(f"address: {exc}") from None
        return self


class CmmChoice(InstrumentChoice):
    """The CMM, with an optional measuring volume rtcal enforces before any command is sent."""

    volume_min_mm: Vec3 = Field((-1e6, -1e6, -1e6), description="lowest X, Y, Z the CMM may be sent to, mm (CMM frame)")
    volume_max_mm: Vec3 = Field((1e6, 1e6, 1e6), description="highest X, Y, Z the CMM may be sent to, mm (CMM frame)")
    tool: str | None = Field(None, min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.\-]+$",
                             description="the CMM tool that carries the reflector, selected at session start "
                                         "(I++ ChangeTool), e.g. CatEye; none: the CMM's active tool")
    home: bool = Field(False, description="true: a run may home an unhomed CMM at session start (I++ Home()); "
                                          "false: an unhomed CMM is refused and a person homes it")

    @model_validator(mode="after")
    def _ordered_volume(self) -> "CmmChoice":
        if any(lo >= hi for lo, hi in zip(self.volume_min_mm, self.volume_max_mm)):
            raise ValueError("volume_max_mm: each coordinate must exceed volume_min_mm's")
        return self


class _Instruments(_Strict):
    def present(self) -> list[str]:
        """The instruments the procedure uses (an optional one left out is None)."""
        return [f for f in type(self).model_fields if getattr(self, f) is not None]

    def all_sim(self) -> bool:
        return all(getattr(self, f).is_sim for f in self.present())

    @model_validator(mode="after")
    def _addresses_of_their_kind(self) -> "_Instruments":
        for name in self.present():
            getattr(self, name).check_scheme(name)
        return self

    @model_validator(mode="after")
    def _one_bench(self) -> "_Instruments":
        kinds = {getattr(self, f).is_sim for f in self.present()}
        if len(kinds) > 1:
            raise ValueError("mixing `backend: sim` with addresses would put instruments on two different benches; "
                             "use addresses for all (e.g. from `rtcal sim serve`) or sim for all")
        return self


class FaultPolicy(_Strict):
    """What the sequencer does when an instrument fails: retry with doubling backoff, then act.

    abort: stop the stage and CMM, close sessions, keep every reading; `rtcal resume` goes on.
    skip: mark the planned reading as skipped and go on (solvers use what was measured).
    pause: ask the operator to clear the fault, then try once more before aborting.
    reacquire (laser tracer): re-reference the tracer and go on in a new tracking segment.
    """

    retries: int = Field(2, ge=0, le=20, description="attempts after the first before `then` applies (e.g. 2)")
    backoff_s: float = Field(0.5, ge=0.0, le=600.0, description="wait before the first retry, s; doubles on each retry")
    then: Literal["abort", "skip", "pause", "reacquire"] = Field(
        "abort", description="when the retries are spent: abort (safe stop, resumable), skip the reading, "
                             "pause for the operator, or reacquire (laser tracer)")
    max_skips_in_a_row: int = Field(
        5, ge=1, le=100_000, description="with `then: skip`: this many planned readings skipped in a row mean the fault "
                                         "persists (an emergency stop, a lost beam): stop safely instead; resume retakes them")


class _Verification(_Strict):
    """What every motion and reading is checked against: no reading is trusted alone. A
    disagreement is a fault of the instrument named, under its `on_fault` policy; a table or probe
    that moves while nothing was commanded (another client drives it) stops the run at once."""

    stage_tolerance_deg: float | None = Field(
        None, gt=0.0, le=10.0, description="how far the drive's feedback position may sit from the command after settling, "
                                           "and move during a reading, deg (default: two steps of the drive, from its "
                                           "address's steps_per_rev and gear; e.g. 0.002)")


Limit_arcsec = Annotated[float, Field(gt=0.0, le=1e6)]


class AcceptanceLimits(_Strict):
    """Upper limits of ISO 230-2 parameters of the axis, arcsec (any subset; docs/conformity.md)."""

    E: Limit_arcsec | None = Field(None, description="bidirectional systematic positional deviation E, arcsec (e.g. 60)")
    E_up: Limit_arcsec | None = Field(None, description="unidirectional systematic positional deviation E↑, arcsec")
    E_down: Limit_arcsec | None = Field(None, description="unidirectional systematic positional deviation E↓, arcsec")
    M: Limit_arcsec | None = Field(None, description="range of the mean bidirectional positional deviation M, arcsec")
    B: Limit_arcsec | None = Field(None, description="reversal value B (max |B_i|), arcsec (e.g. 12)")
    R: Limit_arcsec | None = Field(None, description="bidirectional repeatability R, arcsec (needs two runs or more)")
    R_up: Limit_arcsec | None = Field(None, description="unidirectional repeatability R↑, arcsec (needs two runs or more)")
    R_down: Limit_arcsec | None = Field(None, description="unidirectional repeatability R↓, arcsec (needs two runs or more)")
    A: Limit_arcsec | None = Field(None, description="bidirectional accuracy A, arcsec (needs two runs or more)")
    A_up: Limit_arcsec | None = Field(None, description="unidirectional accuracy A↑, arcsec (needs two runs or more)")
    A_down: Limit_arcsec | None = Field(None, description="unidirectional accuracy A↓, arcsec (needs two runs or more)")

    def items(self) -> list[tuple[str, float]]:
        """The limits given, in the order above."""
        return [(k, getattr(self, k)) for k in type(self).model_fields if getattr(self, k) is not None]


class Acceptance(_Strict):
    """Acceptance limits and the decision rule that turns the measured parameters into a verdict
    (docs/conformity.md). ``simple`` (ILAC-G8:09/2019, simple acceptance): pass when the value is
    at most the limit. ``guarded`` (ISO 14253-1:2017): pass when the value is at most the limit
    less its expanded uncertainty U (k = 2), fail when it exceeds the limit plus U, undecided
    between."""

    decision_rule: Literal["simple", "guarded"] = Field(
        description="`simple` (ILAC-G8: pass if value ≤ limit) or `guarded` (ISO 14253-1: pass if value ≤ limit − U, "
                    "fail if value > limit + U, else undecided)")
    limits_arcsec: AcceptanceLimits = Field(AcceptanceLimits(), description="upper limits of ISO 230-2 parameters, "
                                            "arcsec, e.g. {E: 60, B: 12}")
    band_arcsec: Limit_arcsec | None = Field(
        None, description="tolerance band on the positioning deviation: every mean deviation x̄↑, x̄↓ per target (relative "
                          "to the first target, as the result table gives them) within ±band_arcsec (e.g. 30)")

    @model_validator(mode="after")
    def _something_to_decide(self) -> "Acceptance":
        if not self.limits_arcsec.items() and self.band_arcsec is None:
            raise ValueError("limits_arcsec: give at least one limit (E, E_up, E_down, M, B, R, R_up, R_down, A, A_up, "
                             "A_down) or a band_arcsec")
        return self


def acceptance_problem(acceptance: Acceptance, directions: set[int], runs: int) -> str | None:
    """``field: message`` when a limit names a parameter the plan cannot define (one direction, one run)."""
    for key, _ in acceptance.limits_arcsec.items():
        needs = {1} if key.endswith("_up") else {-1} if key.endswith("_down") else {1, -1}
        if not needs <= directions:
            side = {1: "positive", -1: "negative"}
            return (f"limits_arcsec.{key}: {key} needs the {' and '.join(side[d] for d in sorted(needs, reverse=True))} "
                    f"approach{'es' if len(needs) > 1 else ''}; this procedure measures "
                    f"{' and '.join(side[d] for d in sorted(directions, reverse=True))} only")
        if key[0] in "RA" and runs < 2:
            return f"limits_arcsec.{key}: {key} needs the scatter of at least two runs per direction; this procedure has {runs}"
    return None


class EvaluationChoice(_Strict):
    """The standards whose figures the certificate carries besides ISO 230-2:2014's parameters and
    VDI/DGQ 3441's (labels: `rtcal evaluate --help`, docs/evaluation.md)."""

    standards: list[str] = Field(
        [], max_length=len(LABELS), json_schema_extra={"items": {"enum": list(LABELS)}},
        description="labels of the standards whose figures the certificate states, each under its own title, e.g. "
                    "[upr, iso230-2:1988-vs-2014, jis-b6190-2] (one of: " + ", ".join(LABELS) + ")")

    @field_validator("standards")
    @classmethod
    def _known(cls, labels: list[str]) -> list[str]:
        """Each a known label (an edition alias of ISO 230-2 is its label), none twice."""
        names = [standard_named(label).label for label in labels]  # ValueError naming the labels
        twice = next((n for n in names if names.count(n) > 1), None)
        if twice is not None:
            raise ValueError(f"{twice} is named twice")
        return names


class _Procedure(_Strict):
    """What every procedure has besides its method: a title, the report's header, its bench."""

    REFERENCE_STANDARDS: ClassVar[tuple[str, ...]] = ()  # artefacts `metadata.instruments` may record besides instruments
    if TYPE_CHECKING:  # every method's model declares these, with its own types; shared code reads them so
        method: str
        instruments: _Instruments
        verification: _Verification

    name: str = Field("", max_length=200, description="a title for the report and plots")
    metadata: Metadata = Field(Metadata(), description="customer, machine, axis, operator, instruments: the report's header")
    bench: str | None = Field(None, max_length=4096, description="scenario of the simulated bench, a path relative to this "
                              "file and inside its folder (e.g. `scenarios/abbe_bench.yaml`)")
    acceptance: Acceptance | None = Field(None, description="acceptance limits and decision rule: a conformity verdict "
                                          "(pass, fail, undecided) in results.json, the console and the certificate "
                                          "(docs/conformity.md)")
    evaluation: EvaluationChoice | None = Field(None, description="which other standards' figures the certificate "
                                                "states from the same readings (docs/evaluation.md), e.g. "
                                                "{standards: [upr, jis-b6190-2]}")

    _plain_name = field_validator("name")(lambda cls, name: _check_name(name))

    def approaches(self) -> tuple[set[int], int]:
        """The directions (+1, −1) the positioning-deviation table will have, and its runs per direction."""
        raise NotImplementedError

    def plan_size(self, max_cells: int, hint: str) -> tuple[int, str, str, str | None]:
        """The plan's planned readings (× samples), the field that sets them, the product in words, and a
        problem of this method's own size limit (None: within ``max_cells``): :func:`plan_size_problem`."""
        raise NotImplementedError

    def planned_stage_deg(self) -> tuple[str, list[float]]:
        """The field that sets the stage's targets, and every angle the stage is commanded to (approaches
        included): :func:`plan_outside_limits`."""
        raise NotImplementedError

    def outside_cmm_volume(self, cmm_min_mm: Any, cmm_max_mm: Any) -> str | None:
        """``field: message`` for a planned CMM point outside the volume (None: none, or no CMM)."""
        return None

    @model_validator(mode="after")
    def _acceptance_defined(self) -> "_Procedure":
        if self.acceptance is not None:
            problem = acceptance_problem(self.acceptance, *self.approaches())
            if problem:
                raise ValueError(f"acceptance.{problem}")
        return self

    @model_validator(mode="after")
    def _standards_decidable(self) -> "_Procedure":
        """A standard whose figures need the verdicts (ASME B5.64's TUR) needs acceptance limits."""
        for label in self.evaluation.standards if self.evaluation is not None else []:
            if STANDARDS[label].needs_limits and self.acceptance is None:
                raise ValueError(f"evaluation.standards: {label} states the test uncertainty ratio of each acceptance "
                                 "limit: give `acceptance:` limits (docs/conformity.md), or leave it out")
        return self

    @model_validator(mode="after")
    def _records_of_instruments(self) -> "_Procedure":
        """A certificate lists the instruments the procedure uses: a misspelt key would print an
        instrument that took no part."""
        known = list(type(getattr(self, "instruments")).model_fields) + list(self.REFERENCE_STANDARDS)
        for key in self.metadata.instruments:
            if key not in known:
                close = difflib.get_close_matches(key, known, n=1)
                hint = f"did you mean `{close[0]}`?" if close else f"one of: {', '.join(known)}"
                where = f"metadata.instruments.{key}" if re.fullmatch(r"[A-Za-z_]\w*", key) else "metadata.instruments"
                raise ValueError(f"{where}: not an instrument of this procedure; {hint}")
        return self


def _check_text(text: str) -> str:
    """Text for a report or certificate: no control or format characters — a right-to-left override
    (U+202E) or a zero-width character would make a certificate read other than it says."""
    bad = next((c for c in text if unicodedata.category(c) in ("Cc", "Cf", "Cs", "Co")), None)
    if bad is not None:
        raise ValueError(f"no control or invisible formatting characters (found U+{ord(bad):04X})")
    return text


def _check_name(name: str) -> str:
    """A name goes into plot titles, where matplotlib reads `$` as mathematics, and into reports."""
    if "$" in name:
        raise ValueError("no `$` (plot titles would read it as mathematics)")
    return _check_text(name)


def plan_size_problem(proc: "_Procedure", large: bool = False) -> str | None:
    """``field: message`` when the plan is larger than rtcal runs without ``--large`` (or at all): its
    planned readings, then the method's own limit (:meth:`_Procedure.plan_size`)."""
    max_readings = MAX_PLANNED_READINGS_LARGE if large else MAX_PLANNED_READINGS
    max_cells = MAX_SOLVER_CELLS_LARGE if large else MAX_SOLVER_CELLS
    hint = "" if large else " (`--large` raises the limits if you mean it)"
    readings, where, what, own = proc.plan_size(max_cells, hint)
    if readings <= max_readings and own is not None:
        return own
    if readings > max_readings:
        return f"{where}: {what} = {readings:,} planned readings; at most {max_readings:,}{hint}"
    return None


def plan_outside_limits(proc: "_Procedure", stage_limits_deg, cmm_min_mm=None, cmm_max_mm=None) -> str | None:
    """``field.path: message`` for the first planned target outside the given limits, else None."""
    lo, hi = stage_limits_deg
    where, angles = proc.planned_stage_deg()
    bad = [a for a in angles if not lo <= a <= hi]
    if bad:
        return f"{where}: the stage would go to {bad[0]:g}° (approach included), outside its soft limits [{lo:g}, {hi:g}]°"
    if cmm_min_mm is not None:
        return proc.outside_cmm_volume(cmm_min_mm, cmm_max_mm)
    return None


Procedure = _Procedure
"""Any method's procedure (for the type checker): every method's model is its ``procedure_model``, on
this base; the command line passes the models to the loader (:func:`rtcal.procedure.loader.load_procedure`)."""

# The bases a method's own procedure model builds on (a plugin's too, through rtcal.api: docs/architecture.md,
# "Writing a method")
StrictModel = _Strict
InstrumentsBase = _Instruments
VerificationBase = _Verification
ProcedureBase = _Procedure
