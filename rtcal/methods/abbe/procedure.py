"""The encoder Abbe-error procedure's model (seed 001, and the ISO 230-2 test): what its YAML file may
say, on the shared bases of :mod:`rtcal.procedure.models`."""

from __future__ import annotations

import math
from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import Field, ValidationInfo, field_validator, model_validator

from rtcal.api import (FaultPolicy, InstrumentChoice, InstrumentsBase, ProcedureBase, StageChoice, StrictModel,
                       VerificationBase, plan_outside_limits, plan_size_problem)


class AbbeOnFault(StrictModel):
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


class AbbeVerification(VerificationBase):
    __doc__ = VerificationBase.__doc__
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


class AbbeDurations(StrictModel):
    """What takes time besides the motions and settling (see MultistationDurations)."""

    reseat_polygon_s: float = Field(600.0, ge=0.0, le=86400.0, description="time the operator takes to seat the polygon "
                                                                           "anew and align it to the autocollimator, s")


class AbbeInstruments(InstrumentsBase):
    stage: StageChoice = Field(StageChoice(), description="the rotary stage's drive")
    encoder: InstrumentChoice = Field(InstrumentChoice(), description="the counter of the stage's rotary encoder")
    autocollimator: InstrumentChoice = Field(InstrumentChoice(), description="the autocollimator facing the polygon")
    dial_indicator_1: InstrumentChoice = Field(InstrumentChoice(), description="the dial indicator on the shaft at L1")
    dial_indicator_2: InstrumentChoice = Field(InstrumentChoice(), description="the dial indicator on the shaft at L2")
    environment: InstrumentChoice | None = Field(
        None, description="an air and material sensor, read at every visit: the conditions during the measurement, "
                          "summarised in results.json and the certificate (e.g. {backend: sim})")


class AbbeSteps(StrictModel):
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


class PeriodicTest(StrictModel):
    """A fine-step test of the periodic positioning error (ISO 230-2:2014 Annex C): the stage steps by
    ``step_deg`` from ``start_deg`` through ``span_periods`` periods (one and a little more), in each
    direction of ``steps.directions``, ``steps.runs`` times; the encoder is read at every step and the
    autocollimator where a face is in front (the start is a face). The period is one worm revolution
    (360°/worm_ratio) unless ``period_deg`` names another (an encoder's line period, …)."""

    worm_ratio: float = Field(gt=0.0, le=100_000.0, description="worm (motor) turns per table turn, e.g. 90: one "
                                                                "worm revolution turns the table 4°")
    period_deg: float | None = Field(None, gt=0.0, le=90.0, description="the period to test, deg (default: one worm "
                                                                         "revolution, 360°/worm_ratio; must divide 360°)")
    step_deg: float = Field(gt=0.0, le=10.0, description="the fine step, deg: at least 8 steps per period (e.g. 0.1)")
    start_deg: float = Field(0.0, ge=0.0, lt=360.0, description="the first target, deg: a polygon face position, where "
                                                                 "the autocollimator ties the test to the polygon (e.g. 0)")
    span_periods: float = Field(1.25, ge=1.0, le=4.0, description="how far the steps go, in periods: one and a little "
                                                                   "more (e.g. 1.25)")

    @property
    def period(self) -> float:
        return self.period_deg if self.period_deg is not None else 360.0 / self.worm_ratio

    def targets_deg(self) -> np.ndarray:
        """start, start + step, … up to one step past ``span_periods`` periods."""
        n = int(np.ceil(self.span_periods * self.period / self.step_deg - 1e-9))
        return np.round(self.start_deg + self.step_deg * np.arange(n + 1), 9)

    @model_validator(mode="after")
    def _resolvable(self) -> "PeriodicTest":
        period = self.period
        if period > 90.0:
            raise ValueError(f"worm_ratio: a period of {period:g}° is no fine-step test (at most 90°; the ISO test "
                             "covers the turn)")
        if abs(360.0 / period - round(360.0 / period)) > 1e-6:
            raise ValueError(f"period_deg: {period:g}° does not divide the turn (360°/period must be a whole number)")
        if period / self.step_deg < 8:
            raise ValueError(f"step_deg: {period / self.step_deg:.3g} steps per period of {period:g}°; at least 8 are "
                             "needed to see its shape (a smaller step)")
        last = float(self.targets_deg()[-1])
        if last >= 360.0:
            raise ValueError(f"start_deg: the steps would end at {last:g}°, past 360°: start earlier")
        if len(self.targets_deg()) > 2000:
            raise ValueError(f"step_deg: {len(self.targets_deg())} targets per pass (at most 2000)")
        return self


class PolygonSetup(StrictModel):
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


class AbbeGeometry(StrictModel):
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


class AbbeUncertainty(StrictModel):
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
    autocollimator_scale_error_ppm: float = Field(0.0, ge=-1e5, le=1e5, description=(
        "the autocollimator's scale error from its calibration certificate, ppm: each reading is divided by 1 + e before "
        "the analysis (e.g. 120; 0: none stated, nothing corrected)"))


class EncoderAbbeError(ProcedureBase):
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
    periodic: PeriodicTest | None = Field(None, description="a fine-step test of the periodic positioning error through "
                                          "one period and a little more instead of the turn (ISO 230-2:2014 Annex C; "
                                          "procedures/periodic_error.yaml), e.g. {worm_ratio: 90, step_deg: 0.1}")
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
        per_pass = (len(self.periodic.targets_deg()) if self.periodic is not None
                    else self.polygon.faces * self.steps.steps_per_face)
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
        if self.periodic is not None:
            if self.steps.targets_deg is not None:
                raise ValueError("periodic: a fine-step test has its own targets: leave out steps.targets_deg")
            if not self.face_in_front(self.periodic.start_deg, 0.0):
                raise ValueError(f"periodic.start_deg: {self.periodic.start_deg:g}° is not a polygon face position "
                                 f"(multiples of {self.polygon.pitch_deg:g}°): the autocollimator could not read there")
        if self.steps.targets_deg is not None:
            off = [t for t in self.steps.targets_deg if not self.face_in_front(t, 0.0)]
            if off:
                raise ValueError(f"steps.targets_deg: {off[0]:g}° is not a polygon face position (multiples of "
                                 f"{self.polygon.pitch_deg:g}°): the autocollimator could not read there")
        return self

    def pass_angles_deg(self, seating_deg: float) -> np.ndarray:
        """Commanded angles of one positive pass (in [0, 360)) for a seating: the named targets
        (shifted with the seating), or a full turn in steps."""
        if self.periodic is not None:
            return np.sort(np.round(np.mod(seating_deg + self.periodic.targets_deg(), 360.0), 9) % 360.0)
        if self.steps.targets_deg is not None:
            return np.sort(np.round(np.mod(seating_deg + np.array(self.steps.targets_deg), 360.0), 9) % 360.0)
        n = self.polygon.faces * self.steps.steps_per_face
        return np.sort(np.round(np.mod(seating_deg + self.step_deg * np.arange(n), 360.0), 9) % 360.0)

    def face_in_front(self, angle_deg: float, seating_deg: float) -> bool:
        """Whether a polygon face faces the autocollimator at this commanded angle."""
        k = (angle_deg - seating_deg) / self.polygon.pitch_deg
        return abs(k - round(k)) < 1e-6
