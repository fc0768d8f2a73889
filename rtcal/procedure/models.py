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
import math
import re
import unicodedata
from typing import Annotated, Any, ClassVar, Literal, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

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
    machine_identity: str = Field("", max_length=300, description="the machine's OPC UA server, opc.tcp://HOST:PORT: its "
                                                                 "OPC 40001-1 identification fills the certificate's item "
                                                                 "at run time, and a serial number other than "
                                                                 "`serial_number` refuses the run")

    @field_validator("machine_identity")
    @classmethod
    def _opc_tcp(cls, text: str) -> str:
        if text and not text.startswith("opc.tcp://"):
            raise ValueError(f"{text[:60]!r} is not an OPC UA address (opc.tcp://HOST:PORT)")
        return _check_text(text)

    _plain = field_validator("customer", "machine", "axis", "serial_number", "location", "operator", "certificate_number",
                             "laboratory", "laboratory_address", "customer_address", "performed_by", "approved_by",
                             "traceability", "condition_on_receipt")(lambda cls, text: _check_text(text))
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

    def check_scheme(self, name: str) -> None:
        """The address is of the kind this instrument speaks (a CMM at a Modbus address would fail
        only when the run opens it)."""
        if self.address is None:
            return
        from drivers.addresses import AddressError
        from drivers.factory import SchemeMismatch, check_address

        try:
            check_address(name, self.address)
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


class MultistationInstruments(_Instruments):
    stage: StageChoice = Field(StageChoice(), description="the rotary table's drive")
    cmm: CmmChoice = Field(CmmChoice(), description="the CMM that carries the tracer's reflector")
    laser_tracer: InstrumentChoice = Field(InstrumentChoice(), description="the laser tracer on the table")
    environment: InstrumentChoice | None = Field(
        None, description="an air and material sensor, read with every length: rtcal corrects each length for the "
                          "refractive index of the air of the moment (e.g. {backend: sim})")


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


class MultistationOnFault(_Strict):
    stage: FaultPolicy = Field(FaultPolicy(), description="when the stage fails")
    cmm: FaultPolicy = Field(FaultPolicy(), description="when the CMM fails")
    laser_tracer: FaultPolicy = Field(FaultPolicy(then="reacquire"), description="when the tracer fails (default: re-acquire)")
    environment: FaultPolicy = Field(FaultPolicy(then="skip"), description="when the environment sensor fails (default: skip)")

    @model_validator(mode="after")
    def _reacquire_is_for_the_tracer(self) -> "MultistationOnFault":
        for name in ("stage", "cmm", "environment"):
            if getattr(self, name).then == "reacquire":
                raise ValueError(f"{name}.then: only the laser_tracer can be re-acquired")
        return self


class AbbeOnFault(_Strict):
    stage: FaultPolicy = Field(FaultPolicy(), description="when the stage fails")
    encoder: FaultPolicy = Field(FaultPolicy(), description="when the encoder counter fails")
    autocollimator: FaultPolicy = Field(FaultPolicy(), description="when the autocollimator fails")
    dial_indicator_1: FaultPolicy = Field(FaultPolicy(), description="when dial indicator 1 fails")
    dial_indicator_2: FaultPolicy = Field(FaultPolicy(), description="when dial indicator 2 fails")
    environment: FaultPolicy = Field(FaultPolicy(then="skip"), description="when the environment sensor fails "
                                     "(default: skip; the visit is kept, its conditions are not recorded)")

    @model_validator(mode="after")
    def _no_reacquire(self) -> "AbbeOnFault":
        for name in type(self).model_fields:
            if getattr(self, name).then == "reacquire":
                raise ValueError(f"{name}.then: reacquire is for a laser tracer")
        return self


class Stations(_Strict):
    """Table stations: first angle, constant step, count (eq. 2 needs m ≥ 4)."""

    first_angle_deg: Angle_deg = Field(-145.0, description="commanded angle of station 1, deg (the paper: -145)")
    step_deg: float = Field(30.0, ge=0.001, lt=180.0, description="angle between adjacent stations, deg (the paper: 30; "
                                                                   "at least 0.001)")
    count: int = Field(11, ge=4, le=720, description="number of stations m (eq. 2 needs m ≥ 4; the paper: 11)")
    approach: Literal["positive", "negative"] = Field(
        "positive", description="direction every station is approached in, and in which the stations follow each other")
    overshoot_deg: float = Field(1.0, ge=0.0, le=90.0, description="pass the target by this much to approach it the set way, deg")

    def angles_deg(self) -> np.ndarray:
        sign = 1.0 if self.approach == "positive" else -1.0
        return self.first_angle_deg + sign * self.step_deg * np.arange(self.count)


class GridPlan(_Strict):
    """The paper's plan: layers of a serpentine grid in a box (4 × 16 points in 450 × 600 × 450 mm)."""

    kind: Literal["grid"] = Field("grid", description="`grid`: points on a serpentine grid in a box")
    volume_min_mm: Vec3 = Field((700.0, -300.0, 100.0), description="lowest corner of the box, mm, CMM frame")
    volume_size_mm: tuple[Annotated[float, Field(ge=0.0, le=1e5)], Annotated[float, Field(ge=0.0, le=1e5)],
                          Annotated[float, Field(ge=0.0, le=1e5)]] = Field(
        (450.0, 600.0, 450.0), description="edge lengths of the box along X, Y, Z, mm (the paper: 450, 600, 450)")
    layers: int = Field(4, ge=1, le=100, description="planes of points along Z")
    columns: int = Field(4, ge=1, le=100, description="points per row, along X")
    rows: int = Field(4, ge=1, le=100, description="rows per layer, along Y")
    layer_order: Literal["same", "alternate"] = Field(
        "same", description="`same` (the paper's): every layer walked alike, the CMM back to the first corner between "
                            "layers; `alternate`: every other layer walked backwards, the CMM rising straight to the next "
                            "(the shortest path through the grid; `rtcal plan --target-u` proposes it)")

    def points_mm(self) -> np.ndarray:
        lo, size = np.array(self.volume_min_mm), np.array(self.volume_size_mm)
        xs = lo[0] + size[0] * (np.arange(self.columns) / max(self.columns - 1, 1))
        ys = lo[1] + size[1] * (np.arange(self.rows) / max(self.rows - 1, 1))
        zs = lo[2] + size[2] * (np.arange(self.layers) / max(self.layers - 1, 1))
        layer: list[tuple[float, float]] = []
        for r, y in enumerate(ys):
            row = xs if r % 2 == 0 else xs[::-1]
            layer.extend((x, y) for x in row)
        back = self.layer_order == "alternate"
        return np.array([(x, y, z) for k, z in enumerate(zs) for x, y in (layer[::-1] if back and k % 2 else layer)])


class ListPlan(_Strict):
    """An explicit list of CMM points (mm, CMM frame), measured in the order given."""

    kind: Literal["list"] = Field(description="`list`: the points are listed")
    points_mm: list[Vec3] = Field(min_length=1, max_length=100_000,
                                  description="[x, y, z] of each point, mm, CMM frame, in measuring order")

    def points_mm_array(self) -> np.ndarray:
        return np.array(self.points_mm, dtype=float)


class LMSettings(_Strict):
    """The paper's LM parameters (section 4.2.1)."""

    beta: float = Field(0.55, gt=0.0, lt=1.0, description="β of the step-length search, in (0, 1) (the paper: 0.55)")
    sigma: float = Field(0.4, gt=0.0, lt=1.0, description="σ of the sufficient-decrease test, in (0, 1) (the paper: 0.4)")
    epsilon: float = Field(1e-4, gt=0.0, le=1.0, description="stop when the gradient norm falls below this (the paper: 1e-4)")
    mu0: Annotated[float, Field(gt=0.0, le=1e6)] | Literal["residual_norm"] = Field(
        0.75, description="initial damping μ0 (the paper: 0.75), or `residual_norm` to start from ‖f‖")
    max_iterations: int = Field(200, ge=1, le=10_000, description="iterations per station before giving up (e.g. 200)")


PAPER_STATION_1_MM, PAPER_STATION_1_DEG = (-64.9938, -6.6256, 122.5133), -145.0


def _turned_guess(first_angle_deg: float, axis_point_mm: tuple[float, float, float]) -> list[float]:
    """The paper's station 1 turned about the vertical axis through ``axis_point_mm`` to another first angle."""
    a = math.radians(first_angle_deg - PAPER_STATION_1_DEG)
    x, y = PAPER_STATION_1_MM[0] - axis_point_mm[0], PAPER_STATION_1_MM[1] - axis_point_mm[1]
    return [round(math.cos(a) * x - math.sin(a) * y + axis_point_mm[0], 4),
            round(math.sin(a) * x + math.cos(a) * y + axis_point_mm[1], 4), PAPER_STATION_1_MM[2]]


class MultistationSolver(_Strict):
    estimators: list[Literal["paper", "shared_dead_path", "network"]] = Field(
        ["paper", "shared_dead_path", "network"], min_length=1, max_length=3,
        description="which estimators to run: `paper` (as printed), `shared_dead_path`, `network` (one adjustment: "
                    "stations on one circle, CMM points and the CMM's scales and squareness solved); the recommended one "
                    "is chosen among them")
    lm: LMSettings = Field(LMSettings(), description="the paper's LM parameters (section 4.2.1)")
    first_station_guess_mm: Vec3 = Field(PAPER_STATION_1_MM,
                                         description="starting guess of station 1's centre, mm (default: the paper's X0, Y0, Z0 "
                                                     "at −145°, turned about the axis to stations.first_angle_deg); the "
                                                     "lengths are checked against it (verification.tracer_tolerance_mm)")
    axis_point_mm: Vec3 = Field((0.0, 0.0, 0.0), description="a point on the nominal (vertical) axis, mm, for the other stations' guesses")

    @model_validator(mode="after")
    def _each_once(self) -> "MultistationSolver":
        if len(set(self.estimators)) != len(self.estimators):
            raise ValueError("estimators: an estimator is named twice")
        return self


class ErrorMotionBounds(_Strict):
    """Bounds of the table's error motions (ISO 230-7), for the uncertainty budget (Type B).

    One tracer mount cannot tell a sideways shift of the tracer from a rotation, so the error
    motions the table may have enter the uncertainty; give the bounds from its specification
    or an earlier measurement. rtcal models each as an unknown smooth function within ±bound
    (σ = bound/√2 at every angle — a sinusoid that reaches the bound —, harmonic orders
    1..max_order). U (k = 2) then covers about 95 % of the motions within the bounds, not every
    one; a second tracer mount (`second_mount`) measures them instead."""

    radial_um: float = Field(0.0, ge=0.0, le=1000.0, description="bound of the radial error motions EXC, EYC at the tilt centre, µm (e.g. 0.5)")
    axial_um: float = Field(0.0, ge=0.0, le=1000.0, description="bound of the axial error motion EZC, µm (e.g. 0.3)")
    tilt_arcsec: float = Field(0.0, ge=0.0, le=3600.0, description="bound of the tilt error motions EAC, EBC, arcsec (e.g. 1.0)")
    max_order: int = Field(6, ge=1, le=360, description="highest harmonic order (per turn) the error motions may have (e.g. 6)")
    tilt_center_z_mm: float = Field(0.0, ge=-1e4, le=1e4, description="height of the tilt centre in the CMM frame, mm "
                                    "(0: on the table at the CMM origin, as in seed 000)")


class EnvironmentUncertainty(_Strict):
    """The air the tracer's beam runs through (Type B). Its meaning depends on the procedure:

    - with an `environment` instrument: the sensor's standard uncertainties (1σ: its calibration,
      the air the beam runs through against where the sensor sits); each length is corrected with
      the air of its moment;
    - without one: the range the air may take during the run — how far, at most, it may differ at
      any moment from the conditions the tracer's lengths assume (standard air: 20 °C, 1013.25 hPa,
      50 % RH), e.g. `{air_temperature_k: 1.0, air_pressure_pa: 500}` for 20 ± 1 °C and
      1013.25 ± 5 hPa. Only the keys written count (the defaults are a sensor's); a quantity with
      no range is named in the budget's `not_included`."""

    air_temperature_k: float = Field(0.1, ge=0.0, le=10.0, description="air temperature, K: with a sensor its 1σ (e.g. 0.1); "
                                     "without one the range ± the air may take during the run (e.g. 1.0)")
    air_pressure_pa: float = Field(20.0, ge=0.0, le=10000.0, description="air pressure, Pa: with a sensor its 1σ (e.g. 20); "
                                   "without one the range ± the air may take during the run (e.g. 500)")
    humidity_pct: float = Field(5.0, ge=0.0, le=50.0, description="relative humidity, % RH: with a sensor its 1σ (e.g. 5); "
                                "without one the range ± the air may take during the run (e.g. 20)")
    material_temperature_k: float = Field(0.1, ge=0.0, le=20.0, description=(
        "the table's (material) temperature, K: with a sensor reading it, its 1σ (e.g. 0.1); without one the range ± "
        "about 20 °C the table may take during the run (e.g. 0.5); used with uncertainty.table_expansion_ppm_per_k"))
    # With a sensor: its reading-to-reading noise (1σ per reading). Each length is corrected with its own reading,
    # so this enters every length independently, unlike the common errors above (docs/paper000.md derives the defaults).
    air_temperature_noise_k: float = Field(0.01, ge=0.0, le=10.0, description=(
        "with a sensor: its air-temperature noise per reading, K (1σ, e.g. 0.01: the PTU300's last printed digit)"))
    air_pressure_noise_pa: float = Field(3.0, ge=0.0, le=1000.0, description=(
        "with a sensor: its pressure noise per reading, Pa (1σ, e.g. 3: the PTB330 barometer's ±0.03 hPa repeatability)"))
    humidity_noise_pct: float = Field(0.0, ge=0.0, le=50.0, description=(
        "with a sensor: its humidity noise per reading, % RH (1σ; 0: at 0.009 ppm of index per % RH, negligible)"))
    material_temperature_noise_k: float = Field(0.03, ge=0.0, le=10.0, description=(
        "with a sensor reading the table: its noise per reading, K (1σ, e.g. 0.03: a one-decimal thermometer's 0.1/√12)"))


class MultistationUncertainty(_Strict):
    """What the lab knows about its instruments (1σ unless a bound): the uncertainty budget's inputs.

    The sizes of the tracer's and the CMM's random errors are estimated from the readings
    (Type A); the values here give their shape and a reference. The others are Type B."""

    laser_tracer_noise_um: float = Field(0.2, ge=0.0, le=100.0, description="tracer length noise a of a + b·L, µm (1σ per sample, e.g. 0.2)")
    laser_tracer_noise_ppm: float = Field(0.3, ge=0.0, le=100.0, description="tracer length noise b of a + b·L, µm per m (per sample, e.g. 0.3)")
    cmm_point_noise_um: float = Field(0.3, ge=0.0, le=1000.0, description="CMM reading noise per coordinate and visit, µm (1σ, e.g. 0.3)")
    cmm_scale_ppm: float = Field(0.0, ge=0.0, le=1000.0, description="standard uncertainty of each CMM scale, ppm (Type B, e.g. 1.0)")
    cmm_squareness_arcsec: float = Field(0.0, ge=0.0, le=3600.0, description="standard uncertainty of each CMM squareness, arcsec (Type B, e.g. 1.0)")
    stage_repeatability_arcsec: float = Field(0.0, ge=0.0, le=3600.0, description="the stage's positioning repeatability per visit, arcsec (1σ, Type B, e.g. 0.2)")
    error_motions: ErrorMotionBounds = Field(ErrorMotionBounds(), description="bounds of the error motions (Type B)")
    environment: EnvironmentUncertainty = Field(EnvironmentUncertainty(), description="the air: with an environment "
                                                "instrument its sensor's uncertainty (1σ); without one the range the air may "
                                                "take during the run")
    cmm_field_um: float = Field(0.0, ge=0.0, le=1000.0, description=(
        "the CMM's smooth geometric error beyond its three scales and three squarenesses (its error map's residue), "
        "µm: 1σ per coordinate anywhere in the volume (Type B, e.g. 0.5; 0: not stated, named in not_included)"))
    cmm_field_length_mm: float = Field(150.0, gt=0.0, le=100000.0, description=(
        "that field's correlation length, mm: points this far apart share e^-1/2 of it (a wave of length λ: about λ/2π)"))
    table_expansion_ppm_per_k: float = Field(0.0, ge=0.0, le=100.0, description=(
        "how much the table top and the tracer mounted on it grow radially about the axis per K above 20 °C, ppm/K "
        "(e.g. 11.5 for steel; with a sensor reading the table and none stated, steel's 11.5 ± 2 is assumed and the "
        "budget says so; 0: a table that does not grow)"))
    table_expansion_u_ppm_per_k: float = Field(0.0, ge=0.0, le=100.0, description=(
        "standard uncertainty of that coefficient, ppm/K (e.g. 1.0)"))


class _Verification(_Strict):
    """What every motion and reading is checked against: no reading is trusted alone. A
    disagreement is a fault of the instrument named, under its `on_fault` policy; a table or probe
    that moves while nothing was commanded (another client drives it) stops the run at once."""

    stage_tolerance_deg: float | None = Field(
        None, gt=0.0, le=10.0, description="how far the drive's feedback position may sit from the command after settling, "
                                           "and move during a reading, deg (default: two steps of the drive, from its "
                                           "address's steps_per_rev and gear; e.g. 0.002)")


class MultistationVerification(_Verification):
    __doc__ = _Verification.__doc__
    cmm_tolerance_mm: float = Field(0.05, gt=0.0, le=1000.0, description="how far the CMM's reported position may be from the "
                                                                        "commanded point, and move during a reading, mm (e.g. 0.05)")
    tracer_tolerance_mm: float = Field(
        20.0, gt=0.0, le=100_000.0, description="how far a tracer length may be from what the nominal geometry expects "
                                                "(solver.first_station_guess_mm turned to each station), mm; the guess's error "
                                                "must fit inside it (e.g. 20)")
    tracer_drift_um: float = Field(
        2.0, ge=0.0, le=100_000.0, description="how far the tracer's length back at its tracking segment's reference point "
                                               "(measured again at the end of each pass) may differ from its first reading "
                                               "there beyond 5σ of the stated noise, µm (the air between the two, thermal "
                                               "drift; e.g. 2)")


class AbbeVerification(_Verification):
    __doc__ = _Verification.__doc__
    encoder_tolerance_arcsec: float = Field(
        600.0, gt=0.0, le=648_000.0, description="how far the encoder's change since the start's first reading may be from the "
                                                 "commanded change, arcsec (e.g. 600: far more than a table's positioning "
                                                 "deviation, far less than a step)")
    autocollimator_tolerance_arcsec: float = Field(
        600.0, gt=0.0, le=3600.0, description="how far from zero the autocollimator's reading of the face the commanded angle "
                                              "puts in view may be, arcsec (e.g. 600)")
    cross_check_noise_arcsec: float | None = Field(
        None, gt=0.0, le=3600.0, description="1σ of the autocollimator − encoder difference at one visit, arcsec (default: "
                                             "from the uncertainty section's noise and digits of both, 0.3 where it states "
                                             "none; e.g. 0.25)")
    cross_check_drift_arcsec: float = Field(
        0.5, ge=0.0, le=3600.0, description="how far the autocollimator − encoder difference at one target may drift during "
                                            "the run beyond 5σ of its noise (either instrument's thermal drift), arcsec (e.g. 0.5)")
    encoder_error_bound_arcsec: float = Field(
        30.0, ge=0.0, le=3600.0, description="bound of the encoder's error against the table's true angle (the Abbe shift, "
                                             "eccentricity and graduation the method measures), arcsec; the autocollimator − "
                                             "encoder difference changes along a pass by at most twice it (e.g. 30)")
    face_error_bound_arcsec: float = Field(
        5.0, ge=0.0, le=3600.0, description="bound of the polygon's face errors, arcsec (e.g. 5)")
    indicator_range_um: float = Field(
        1000.0, gt=0.0, le=100_000.0, description="how far the dial indicators may read from zero: the shaft's radial and "
                                                  "tilt motion at them, µm (e.g. 1000)")
    indicator_drift_um: float = Field(
        1.0, ge=0.0, le=100_000.0, description="how far a dial indicator's reading at one target may drift during the run "
                                               "beyond 5σ of its stated noise and a digit (thermal drift of its stand), µm "
                                               "(e.g. 1)")


class MultistationDurations(_Strict):
    """What takes time besides the motions and settling: the planned and the simulated clock count it
    (a run on hardware takes what it takes)."""

    tracer_sample_s: float = Field(0.1, ge=0.0, le=600.0, description="time one laser-tracer sample takes (its "
                                                                       "integration and transfer), s")
    reference_tracer_s: float = Field(30.0, ge=0.0, le=3600.0, description="time to (re-)reference the tracer's beam, s")
    move_tracer_s: float = Field(900.0, ge=0.0, le=86400.0, description="time the operator takes to move the tracer to "
                                                                        "another mount and fix it, s")


class AbbeDurations(_Strict):
    """What takes time besides the motions and settling (see MultistationDurations)."""

    reseat_polygon_s: float = Field(600.0, ge=0.0, le=86400.0, description="time the operator takes to seat the polygon "
                                                                           "anew and align it to the autocollimator, s")


class SecondMount(_Strict):
    """Measure the whole plan again with the tracer moved to a second place on the table: the
    network estimator then separates the table's error motions from its rotation (one mount
    cannot). Put it at the same height as the first (the tilt about the line joining the mounts
    is invisible, and with mounts at different heights it would leak into the angles)."""

    first_station_guess_mm: Vec3 = Field(description="the tracer's centre at the first station once moved, CMM frame, "
                                                      "mm (nominal, for the solver's start; e.g. [-22.6, 128.0, 122.5])")


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


class _Procedure(_Strict):
    """What every procedure has besides its method: a title, the report's header, its bench."""

    REFERENCE_STANDARDS: ClassVar[tuple[str, ...]] = ()  # artefacts `metadata.instruments` may record besides instruments

    name: str = Field("", max_length=200, description="a title for the report and plots")
    metadata: Metadata = Field(Metadata(), description="customer, machine, axis, operator, instruments: the report's header")
    bench: str | None = Field(None, max_length=4096, description="scenario of the simulated bench, a path relative to this "
                              "file and inside its folder (e.g. `scenarios/abbe_bench.yaml`)")
    acceptance: Acceptance | None = Field(None, description="acceptance limits and decision rule: a conformity verdict "
                                          "(pass, fail, undecided) in results.json, the console and the certificate "
                                          "(docs/conformity.md)")

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


class LaserTracerMultistation(_Procedure):
    """Seed 000: tracer on the table, CMM moves the reflector, table indexes through stations."""

    method: Literal["laser_tracer_multistation"] = Field(description="seed 000's laser-tracer multi-station method")
    instruments: MultistationInstruments = Field(MultistationInstruments(), description="backend of each instrument")
    stations: Stations = Field(Stations(), description="where the table stops")
    points: Union[GridPlan, ListPlan] = Field(GridPlan(), discriminator="kind", description="where the CMM takes the reflector")
    order: Literal["point_major", "station_major"] = Field(
        "point_major", description="point_major (the paper's): for each point every station; station_major: the other way")
    samples_per_reading: int = Field(1, ge=1, le=1000, description="tracer samples averaged per planned reading")
    settle_time_s: float = Field(2.0, ge=0.0, le=3600.0, description="wait after each motion before reading, s")
    concurrent_motions: bool = Field(False, description="start the table and the CMM together where both move to the next "
                                                        "reading (they are independent; `rtcal plan` prints the time it saves)")
    durations: MultistationDurations = Field(MultistationDurations(), description="time the tracer's samples and the "
                                                                                  "operator's steps take")
    on_fault: MultistationOnFault = Field(MultistationOnFault(), description="what to do when an instrument fails (docs/faults.md)")
    verification: MultistationVerification = Field(MultistationVerification(), description="what every motion and reading is "
                                                   "checked against (docs/faults.md)")
    solver: MultistationSolver = Field(MultistationSolver(), description="solver settings")
    uncertainty: MultistationUncertainty = Field(MultistationUncertainty(), description="inputs of the uncertainty budget")
    second_mount: SecondMount | None = Field(None, description="a second tracer mount: the plan is measured again after an "
                                                               "operator step moves the tracer there")

    @model_validator(mode="before")
    @classmethod
    def _guess_follows_first_station(cls, data: Any) -> Any:
        """Without a stated guess, station 1 is the paper's turned to this procedure's first angle
        (a guess at −145° for a plan that starts elsewhere would be far from the tracer)."""
        if not isinstance(data, dict):
            return data
        solver, stations = data.get("solver", {}), data.get("stations", {})
        if not isinstance(solver, dict) or not isinstance(stations, dict) or "first_station_guess_mm" in solver:
            return data
        angle = stations.get("first_angle_deg", PAPER_STATION_1_DEG)
        axis = solver.get("axis_point_mm", (0.0, 0.0, 0.0))

        def number(v: Any) -> bool:
            return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and abs(v) <= 1e6

        if (angle == PAPER_STATION_1_DEG or not number(angle) or not isinstance(axis, (list, tuple)) or len(axis) != 3
                or not all(number(v) for v in axis)):
            return data  # the default as it stands, or a mistake the fields' own validation will name
        return {**data, "solver": {**solver, "first_station_guess_mm": _turned_guess(float(angle), (float(axis[0]), float(axis[1]), float(axis[2])))}}

    @property
    def mounts(self) -> int:
        return 1 if self.second_mount is None else 2

    def approaches(self) -> tuple[set[int], int]:
        """Every station in one direction, once: the table has one run."""
        return {1 if self.stations.approach == "positive" else -1}, 1

    def points_array(self) -> np.ndarray:
        return self.points.points_mm() if isinstance(self.points, GridPlan) else self.points.points_mm_array()

    def plan_size(self, max_cells: int, hint: str) -> tuple[int, str, str, str | None]:
        """Stations × points × samples; the joint solver's Jacobian has readings × (3·stations + 1) cells."""
        m, n = self.stations.count, self.point_count()
        readings = m * n * self.samples_per_reading
        cells = m * n * (3 * m + 1)
        problem = None
        if cells > max_cells:
            problem = (f"stations: {m} stations × {n} points need a solver matrix of {cells:,} cells "
                       f"({cells * 8 / 1e9:.1f} GB each copy); at most {max_cells:,}{hint}")
        return readings, "points", f"{m} stations × {n} points × {self.samples_per_reading} samples", problem

    def planned_stage_deg(self) -> tuple[str, list[float]]:
        d = 1 if self.stations.approach == "positive" else -1
        return "stations", [a for a in self.stations.angles_deg() for a in (a, a - d * self.stations.overshoot_deg)]

    def outside_cmm_volume(self, cmm_min_mm: Any, cmm_max_mm: Any) -> str | None:
        pts = self.points_array()
        outside = ~np.all((pts >= np.array(cmm_min_mm)) & (pts <= np.array(cmm_max_mm)), axis=1)
        if outside.any():
            k = int(np.argmax(outside))
            return (f"points: point {k + 1} at {np.round(pts[k], 3).tolist()} mm lies outside the CMM volume "
                    f"{list(cmm_min_mm)}..{list(cmm_max_mm)} mm")
        return None

    def point_count(self) -> int:
        """Points of the plan, without building them."""
        p = self.points
        return p.layers * p.columns * p.rows if isinstance(p, GridPlan) else len(p.points_mm)

    @model_validator(mode="after")
    def _solvable(self, info: ValidationInfo) -> "LaserTracerMultistation":
        problem = plan_size_problem(self, large=bool((info.context or {}).get("large")))
        if problem:
            raise ValueError(problem)
        pts = self.points_array()
        n, m = len(pts), self.stations.count
        if n < 16:
            raise ValueError(f"points: the plan has {n} points; eq. 2 needs n ≥ 16")
        if m * n < 4 * m + 3 * n:
            raise ValueError(f"points: m·n = {m * n} < 4m + 3n = {4 * m + 3 * n} (eq. 2): too few stations or points")
        centred = pts - pts.mean(axis=0)
        sv = np.linalg.svd(centred, compute_uv=False)
        if sv[-1] < 1e-6 * max(sv[0], 1e-12):
            raise ValueError("points: the CMM points are coplanar or collinear: station height cannot be determined")
        span = abs(self.stations.step_deg) * (self.stations.count - 1)
        if span >= 360.0:
            raise ValueError(f"stations: they span {span}° ≥ 360°: stations would repeat")
        problem = plan_outside_limits(self, self.instruments.stage.soft_limits_deg,
                                      self.instruments.cmm.volume_min_mm, self.instruments.cmm.volume_max_mm)
        if problem:
            raise ValueError(problem)
        return self


class AbbeInstruments(_Instruments):
    stage: StageChoice = Field(StageChoice(), description="the rotary stage's drive")
    encoder: InstrumentChoice = Field(InstrumentChoice(), description="the counter of the stage's rotary encoder")
    autocollimator: InstrumentChoice = Field(InstrumentChoice(), description="the autocollimator facing the polygon")
    dial_indicator_1: InstrumentChoice = Field(InstrumentChoice(), description="the dial indicator on the shaft at L1")
    dial_indicator_2: InstrumentChoice = Field(InstrumentChoice(), description="the dial indicator on the shaft at L2")
    environment: InstrumentChoice | None = Field(
        None, description="an air and material sensor, read at every visit: the conditions during the measurement, "
                          "summarised in results.json and the certificate (e.g. {backend: sim})")


class AbbeSteps(_Strict):
    """The targets and how they are approached.

    By default a full turn per pass: ``faces × steps_per_face`` steps from the seating's offset.
    ``targets_deg`` names the targets instead (an ISO 230-2 test: irregularly spaced, each where a
    polygon face is in front). ``cycle``: ``linear`` (ISO 230-2's standard test cycle: each run
    goes through every target in one direction, then back through every target in the other, each
    target approached past an overrun so that every approach is from its own side) or ``pilgrim``
    (the step cycle of its annex: each target approached ``runs`` times from each side before the
    next)."""

    steps_per_face: int = Field(1, ge=1, le=100, description="steps per polygon face (finer than the polygon: the "
                                                             "autocollimator reads at faces only), e.g. 2")
    targets_deg: list[float] | None = Field(None, min_length=2, max_length=360,
                                            description="explicit targets, deg in [0, 360), each a polygon face position "
                                                        "(e.g. [0, 15, 45, 90, 120, 180, 225, 270, 300, 330])")
    directions: list[Literal["positive", "negative"]] = Field(["positive"], min_length=1, max_length=2,
                                                              description="approach directions, e.g. [positive, negative]")
    runs: int = Field(1, ge=1, le=100, description="runs (approaches per target and direction), e.g. 5 for ISO 230-2")
    overshoot_deg: float = Field(1.0, ge=0.0, le=90.0, description="overrun past each target to approach it from its "
                                                                   "own side, deg (e.g. 1)")
    cycle: Literal["linear", "pilgrim"] = Field("linear", description="linear (ISO 230-2 standard cycle) or pilgrim (step cycle)")

    @model_validator(mode="after")
    def _targets(self) -> "AbbeSteps":
        if self.targets_deg is not None:
            if any(not (0.0 <= t < 360.0) for t in self.targets_deg):
                raise ValueError("targets_deg: targets lie in [0, 360) degrees")
            if len(set(round(t, 9) for t in self.targets_deg)) != len(self.targets_deg):
                raise ValueError("targets_deg: targets repeat")
        if len(set(self.directions)) != len(self.directions):
            raise ValueError("directions: a direction repeats (for more approaches raise `runs`)")
        return self


class PolygonSetup(_Strict):
    """The polygon as the user knows it.

    ``certificate_arcsec``: face errors from its calibration certificate (one per face), or
    ``bench`` to take the simulated polygon's certificate, or ``none`` to trust nothing and
    separate face and table errors by closure (needs ≥ 2 whole-face seatings).
    ``seatings_deg``: offsets at which the operator seats the polygon in turn; whole multiples of
    the face pitch for closure, fractions of it to sample the table between faces.
    """

    faces: int = Field(24, ge=3, le=360, description="faces of the polygon (seed 001: 24)")
    certificate_arcsec: list[Annotated[float, Field(ge=-3600.0, le=3600.0)]] | Literal["bench", "none"] = Field(
        "bench", description="face errors from the certificate, arcsec, one per face; `bench`: the simulated polygon's; "
                             "`none`: separate by closure")
    certificate_uncertainty_arcsec: float = Field(0.0, ge=0.0, le=3600.0, description="1σ of each certificate value, arcsec")
    seatings_deg: list[Annotated[float, Field(ge=-360.0, le=360.0)]] = Field(
        [0.0], min_length=1, max_length=360, description="offsets at which the polygon is seated in turn, deg (e.g. [0, 15, 45])")

    @property
    def pitch_deg(self) -> float:
        return 360.0 / self.faces

    @model_validator(mode="after")
    def _consistent(self) -> "PolygonSetup":
        if isinstance(self.certificate_arcsec, list) and len(self.certificate_arcsec) != self.faces:
            raise ValueError(f"certificate_arcsec: {len(self.certificate_arcsec)} values for {self.faces} faces")
        whole = {round(s / self.pitch_deg) % self.faces for s in self.seatings_deg
                 if abs(s / self.pitch_deg - round(s / self.pitch_deg)) < 1e-9}
        if self.certificate_arcsec == "none" and len(whole) < 2:
            raise ValueError("seatings_deg: closure (certificate_arcsec: none) needs at least two seatings "
                             "a whole number of faces apart")
        if len({round(s % 360.0, 9) % 360.0 for s in self.seatings_deg}) != len(self.seatings_deg):
            raise ValueError("seatings_deg: offsets repeat (offsets a whole turn apart are the same seating)")
        if self.certificate_arcsec == "none":
            offsets = sorted(whole)
            common = math.gcd(self.faces, *[k - offsets[0] for k in offsets[1:]])
            if common > 1:
                raise ValueError(f"seatings_deg: closure cannot separate table and polygon errors: the whole-face offsets "
                                 f"{offsets} differ by multiples of {common}, which divides the {self.faces} faces, so "
                                 f"the readings split into {common} unconnected sets; use offsets whose differences "
                                 f"share no factor with {self.faces} (e.g. include an offset of 1 face)")
        return self


MIN_ENCODER_RADIUS_MM = 1.0  # the smallest rotary encoder discs are a few mm across


class AbbeGeometry(_Strict):
    """Design sizes of the stage the solver uses (from drawings or measurement), mm."""

    encoder_radius_mm: float = Field(32.0, gt=0.0, le=1e4, description="rE: radius of the encoder's read head, mm (seed 001: 32)")
    grating_offset_mm: float = Field(60.0, ge=-1e4, le=1e4, description="Zs: grating plane below the tilt centre, mm (seed 001: 60)")
    indicator_heights_mm: tuple[Annotated[float, Field(ge=-1e4, le=1e4)], Annotated[float, Field(ge=-1e4, le=1e4)]] = Field(
        (50.0, 70.0), description="L1, L2: the dial indicators below the tilt centre, mm")

    @field_validator("encoder_radius_mm")
    @classmethod
    def _real_encoder(cls, radius_mm: float) -> float:
        """A read head under 1 mm from the axis is no rotary encoder: a unit slip (m typed as mm)."""
        if radius_mm < MIN_ENCODER_RADIUS_MM:
            raise ValueError(f"{radius_mm:g} mm is no encoder's read-head radius (at least {MIN_ENCODER_RADIUS_MM:g} mm; "
                             f"seed 001's is 32 mm): metres typed as mm? ({radius_mm * 1000:g} mm)")
        return radius_mm

    @model_validator(mode="after")
    def _separated(self) -> "AbbeGeometry":
        if abs(self.indicator_heights_mm[1] - self.indicator_heights_mm[0]) < 1.0:
            raise ValueError("indicator_heights_mm: the indicators must be at least 1 mm apart to separate tilt from radial motion")
        return self


class AbbeUncertainty(_Strict):
    """The instruments' stated noise and resolution (1σ), for the uncertainty budget.

    With one run they are the budget's Type B inputs; with two or more runs (or closure) the
    random parts are estimated from the readings instead (Type A). The polygon certificate's
    uncertainty is ``polygon.certificate_uncertainty_arcsec``."""

    autocollimator_noise_arcsec: float = Field(0.0, ge=0.0, le=3600.0, description="autocollimator noise per reading, arcsec (1σ, e.g. 0.2)")
    autocollimator_resolution_arcsec: float = Field(0.0, ge=0.0, le=3600.0, description="autocollimator display digit, arcsec (e.g. 0.1)")
    stage_repeatability_arcsec: float = Field(0.0, ge=0.0, le=3600.0, description="stage positioning repeatability per visit, arcsec (1σ, e.g. 0.3)")
    encoder_noise_arcsec: float = Field(0.0, ge=0.0, le=3600.0, description="encoder noise per reading, arcsec (1σ, e.g. 0.05)")
    encoder_resolution_arcsec: float = Field(0.0, ge=0.0, le=3600.0, description="encoder resolution, arcsec (e.g. 0.05)")
    indicator_noise_um: float = Field(0.0, ge=0.0, le=1000.0, description="dial indicator noise per reading, µm (1σ, e.g. 0.2)")
    indicator_resolution_um: float = Field(0.0, ge=0.0, le=1000.0, description="dial indicator digit, µm (e.g. 1.0)")
    autocollimator_scale_u_ppm: float = Field(0.0, ge=0.0, le=1e5, description=(
        "standard uncertainty of the autocollimator's scale, from its calibration certificate, ppm (Type B, e.g. 2500 "
        "for U = 0.5 % at k = 2; 0: not stated, named in not_included)"))
    autocollimator_calibration_u_arcsec: float = Field(0.0, ge=0.0, le=3600.0, description=(
        "expanded uncertainty (k = 2) of an indication from the autocollimator's calibration certificate, arcsec (e.g. 0.1)"))
    indicator_scale_u_ppm: float = Field(0.0, ge=0.0, le=1e5, description=(
        "standard uncertainty of each dial indicator's scale, from its calibration certificate, ppm (e.g. 5000)"))


class EncoderAbbeError(_Procedure):
    """Seed 001: encoder error from tilt and radial motion, against an autocollimator and polygon."""

    method: Literal["encoder_abbe_error"] = Field(description="seed 001's encoder Abbe-error method")
    instruments: AbbeInstruments = Field(AbbeInstruments(), description="backend of each instrument")
    steps: AbbeSteps = Field(AbbeSteps(), description="how the stage steps through a turn")
    polygon: PolygonSetup = Field(PolygonSetup(), description="the optical polygon and its seatings")
    geometry: AbbeGeometry = Field(AbbeGeometry(), description="design sizes of the stage, mm")
    samples_per_reading: int = Field(1, ge=1, le=1000, description="samples of every instrument per step")
    settle_time_s: float = Field(1.0, ge=0.0, le=3600.0, description="wait after each motion before reading, s")
    durations: AbbeDurations = Field(AbbeDurations(), description="time the operator's steps take")
    on_fault: AbbeOnFault = Field(AbbeOnFault(), description="what to do when an instrument fails (docs/faults.md)")
    verification: AbbeVerification = Field(AbbeVerification(), description="what every motion and reading is checked against "
                                           "(docs/faults.md)")
    max_harmonic_order: int = Field(24, ge=1, le=360, description="highest harmonic order fitted per revolution")
    uncertainty: AbbeUncertainty = Field(AbbeUncertainty(), description="inputs of the uncertainty budget")

    REFERENCE_STANDARDS: ClassVar[tuple[str, ...]] = ("polygon",)

    @property
    def step_deg(self) -> float:
        return self.polygon.pitch_deg / self.steps.steps_per_face

    def approaches(self) -> tuple[set[int], int]:
        return {1 if d == "positive" else -1 for d in self.steps.directions}, self.steps.runs

    def visit_count(self) -> int:
        """Planned stage visits, without building them."""
        per_pass = self.polygon.faces * self.steps.steps_per_face
        return len(self.polygon.seatings_deg) * self.steps.runs * len(self.steps.directions) * per_pass

    def plan_size(self, max_cells: int, hint: str) -> tuple[int, str, str, str | None]:
        """Stage visits × samples (its solvers are linear per visit: no limit of their own)."""
        return (self.visit_count() * self.samples_per_reading, "steps",
                f"{self.visit_count()} stage visits × {self.samples_per_reading} samples", None)

    def planned_stage_deg(self) -> tuple[str, list[float]]:
        dirs = [1 if d == "positive" else -1 for d in self.steps.directions]
        base = [a for s in self.polygon.seatings_deg for a in self.pass_angles_deg(s)]
        return "steps", base + [a - d * self.steps.overshoot_deg for a in base for d in dirs]

    @model_validator(mode="after")
    def _within_limits(self, info: ValidationInfo) -> "EncoderAbbeError":
        problem = plan_size_problem(self, large=bool((info.context or {}).get("large")))
        if problem:
            raise ValueError(problem)
        problem = plan_outside_limits(self, self.instruments.stage.soft_limits_deg)
        if problem:
            raise ValueError(problem)
        if self.steps.targets_deg is not None:
            off = [t for t in self.steps.targets_deg if not self.face_in_front(t, 0.0)]
            if off:
                raise ValueError(f"steps.targets_deg: {off[0]:g}° is not a polygon face position (multiples of "
                                 f"{self.polygon.pitch_deg:g}°): the autocollimator could not read there")
        return self

    def pass_angles_deg(self, seating_deg: float) -> np.ndarray:
        """Commanded angles of one positive pass (in [0, 360)) for a seating: the named targets
        (shifted with the seating), or a full turn in steps."""
        if self.steps.targets_deg is not None:
            return np.sort(np.round(np.mod(seating_deg + np.array(self.steps.targets_deg), 360.0), 9) % 360.0)
        n = self.polygon.faces * self.steps.steps_per_face
        return np.sort(np.round(np.mod(seating_deg + self.step_deg * np.arange(n), 360.0), 9) % 360.0)

    def face_in_front(self, angle_deg: float, seating_deg: float) -> bool:
        """Whether a polygon face faces the autocollimator at this commanded angle."""
        k = (angle_deg - seating_deg) / self.polygon.pitch_deg
        return abs(k - round(k)) < 1e-6


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


Procedure = Union[LaserTracerMultistation, EncoderAbbeError]
"""The built-in methods' procedures (for the type checker); every method's model is its ``procedure_model``
in :data:`rtcal.methods.METHODS`, where the loader finds it by ``method:``."""

# The bases a method's own procedure model builds on (a plugin's too: docs/architecture.md, "Adding a method")
StrictModel = _Strict
InstrumentsBase = _Instruments
VerificationBase = _Verification
ProcedureBase = _Procedure
