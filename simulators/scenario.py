"""A bench scenario: which error sources exist and how large they are, as a YAML file.

An error source the scenario does not name is absent (ideal instrument, perfect stage).
Geometry defaults to seed 000's setup: the tracer about 65 mm from the axis and 122.5 mm above
the CMM origin, which lies on the table on the rotation axis.

Sign conventions (ISO 230-7 names, functions of the commanded angle θ, CMM frame):
- εz: actual − commanded table angle; positive = the table turned further (counterclockwise
  seen from +Z) than commanded.
- εx, εy: right-handed rotations of the shaft about X and Y through the tilt centre;
  δx, δy, δz: translations of the tilt centre.
- reversal: an approach in the negative direction ends ``reversal_arcsec`` lower than one in
  the positive direction (ISO 230-2's B = ↑ − ↓).
"""

from __future__ import annotations

import math

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from rtcal.harmonics import Harmonic
from rtcal.units import arcsec_to_rad, um_to_mm

Vec3 = tuple[float, float, float]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class AngularHarmonic(_Strict):
    """amplitude_arcsec · sin(order·θ + phase)."""

    order: int = Field(ge=0, le=1000)
    amplitude_arcsec: float
    phase_deg: float = 0.0

    def to_rad(self) -> Harmonic:
        return Harmonic(self.order, arcsec_to_rad(self.amplitude_arcsec), math.radians(self.phase_deg))


class LinearHarmonic(_Strict):
    """amplitude_um · sin(order·θ + phase)."""

    order: int = Field(ge=0, le=1000)
    amplitude_um: float
    phase_deg: float = 0.0

    def to_mm(self) -> Harmonic:
        return Harmonic(self.order, um_to_mm(self.amplitude_um), math.radians(self.phase_deg))


class CompensationScenario(_Strict):
    """A compensation table the simulated controller applies (as a CNC would: interpolated between
    entries, per approach direction where the format has two), read from ``file`` (relative to
    the scenario) when the scenario is loaded."""

    format: Literal["linuxcnc", "siemens-lec", "siemens-cec", "fanuc", "heidenhain"] = Field(
        description="the table's format, as `rtcal compensate --format` writes it")
    file: str | None = Field(None, max_length=4096, description="the table file, relative to the scenario (e.g. c.comp)")
    text: str | None = Field(None, max_length=1_000_000, description="the table itself (filled from `file` when loaded)")

    @model_validator(mode="after")
    def _one_source(self) -> "CompensationScenario":
        if (self.file is None) == (self.text is None):
            raise ValueError("file: give the table's file")
        return self


class StageScenario(_Strict):
    """The rotary table: its axis in the CMM frame and its error motions."""

    axis_point_mm: Vec3 = (0.0, 0.0, 0.0)
    axis_tilt_x_arcsec: float = 0.0  # squareness of the axis to the CMM table, about X
    axis_tilt_y_arcsec: float = 0.0  # ... about Y
    positioning_error: list[AngularHarmonic] = []  # εz(θ)
    repeatability_arcsec: float = Field(0.0, ge=0.0)  # 1σ, random per move
    reversal_arcsec: float = 0.0
    radial_motion_x: list[LinearHarmonic] = []  # δx(θ) at the tilt centre
    radial_motion_y: list[LinearHarmonic] = []  # δy(θ) at the tilt centre
    axial_motion: list[LinearHarmonic] = []  # δz(θ)
    tilt_motion_x: list[AngularHarmonic] = []  # εx(θ)
    tilt_motion_y: list[AngularHarmonic] = []  # εy(θ)
    tilt_center_height_mm: float = 0.0  # along the axis, above axis_point_mm
    soft_limits_deg: tuple[float, float] = (-360.0, 360.0)
    speed_deg_per_s: float = Field(10.0, gt=0.0)
    compensation: CompensationScenario | None = Field(None, description="a compensation table the simulated controller "
                                                                        "applies (calibrate → compensate → verify)")


class CmmScenario(_Strict):
    """The CMM: commanded → actual probe position, point noise and measuring volume."""

    scale_error_ppm: Vec3 = (0.0, 0.0, 0.0)
    squareness_xy_arcsec: float = 0.0
    squareness_xz_arcsec: float = 0.0
    squareness_yz_arcsec: float = 0.0
    point_noise_um: float = Field(0.0, ge=0.0)  # 1σ per coordinate of the reported position
    volume_min_mm: Vec3 = (-300.0, -600.0, -100.0)
    volume_max_mm: Vec3 = (1200.0, 600.0, 800.0)
    speed_mm_per_s: float = Field(100.0, gt=0.0)


class TracerMount(_Strict):
    """Where the tracer's reference centre sits in the table frame."""

    radius_mm: float = Field(65.33, gt=0.0)
    azimuth_deg: float = -29.2  # at table angle 0; the paper's P1 at −145° lies at about −174°
    height_mm: float = 122.5  # above the axis point (the CMM origin)


class LaserTracerScenario(_Strict):
    """Interferometric length noise a + b·L (1σ), the mount, and where the tracer goes when the
    operator moves it to its second mount (a procedure's ``second_mount``)."""

    mount: TracerMount = TracerMount()
    second_mount: TracerMount = TracerMount(radius_mm=130.0, azimuth_deg=80.0, height_mm=122.5)
    length_noise_um: float = Field(0.0, ge=0.0)
    length_noise_ppm: float = Field(0.0, ge=0.0)  # µm per m of length


class StepperScenario(_Strict):
    """Open-loop stepper through a worm: commanded angles are whole (micro)steps."""

    steps_per_revolution: int = Field(0, ge=0)  # motor (micro)steps per motor turn; 0 = continuous
    worm_ratio: float = Field(1.0, gt=0.0)  # motor turns per table turn


class EncoderScenario(_Strict):
    """The rotary encoder below the tilt centre (seed 001).

    The read head sits at radius rE on +X of the housing; the grating plane lies Zs below the
    tilt centre. A tangential (Y) shift Δt of the grating under the head reads as an extra
    angle Δt/rE: Δt = δy + Zs·εx + e·sin(θ + ψ) for grating eccentricity e at phase ψ.
    """

    radius_mm: float = Field(32.0, gt=0.0)  # rE
    grating_offset_mm: float = 0.0  # Zs, grating plane below the tilt centre
    eccentricity_um: float = Field(0.0, ge=0.0)
    eccentricity_phase_deg: float = 0.0
    graduation_error: list[AngularHarmonic] = []  # of the grating angle
    resolution_arcsec: float = Field(0.0, ge=0.0)
    noise_arcsec: float = Field(0.0, ge=0.0)


class AutocollimatorScenario(_Strict):
    """Reads the polygon face in front of it; ``range_arcsec`` either side of its axis."""

    noise_arcsec: float = Field(0.0, ge=0.0)
    resolution_arcsec: float = Field(0.0, ge=0.0)
    range_arcsec: float = Field(150.0, gt=0.0)


class PolygonScenario(_Strict):
    """An optical polygon on the table. Face k is in front of the autocollimator at table angle
    k·360°/faces (seated at offset 0). ``face_errors_arcsec``: each face normal's deviation,
    positive counterclockwise; their mean is removed, since a polygon closes (Σ = 0).
    Its certificate is the truth plus noise of ``certificate_uncertainty_arcsec``; each
    re-seating lands within ``seating_error_arcsec`` (1σ) of the nominal offset."""

    faces: int = Field(24, ge=3, le=360)
    face_errors_arcsec: list[float] = []
    certificate_uncertainty_arcsec: float = Field(0.0, ge=0.0)
    seating_error_arcsec: float = Field(0.0, ge=0.0)

    @model_validator(mode="after")
    def _one_error_per_face(self) -> "PolygonScenario":
        if self.face_errors_arcsec and len(self.face_errors_arcsec) != self.faces:
            raise ValueError(f"face_errors_arcsec: {len(self.face_errors_arcsec)} values for {self.faces} faces")
        return self


class DialIndicatorScenario(_Strict):
    """Two indicators touching the shaft in Y (the grating's tangential direction at the head)."""

    heights_mm: tuple[float, float] = (50.0, 70.0)  # L1, L2 below the tilt centre
    resolution_um: float = Field(0.0, ge=0.0)
    noise_um: float = Field(0.0, ge=0.0)


class EnvironmentScenario(_Strict):
    """The air around the bench and the table's temperature, drifting linearly with the run's time
    (the clock starts at 0), and the environment sensor's noise. Unnamed: standard air (20 °C,
    1013.25 hPa, 50 % RH), steady — the simulated tracer then reads as if in vacuum-corrected air."""

    air_temperature_c: float = Field(20.0, ge=-10.0, le=50.0, description="air temperature at the start, °C (e.g. 20.3)")
    air_temperature_drift_k_per_h: float = Field(0.0, ge=-20.0, le=20.0, description="its drift, K per hour (e.g. 0.5)")
    air_pressure_pa: float = Field(101325.0, ge=60000.0, le=120000.0, description="air pressure at the start, Pa (e.g. 100800)")
    air_pressure_drift_pa_per_h: float = Field(0.0, ge=-5000.0, le=5000.0, description="its drift, Pa per hour (e.g. 300)")
    humidity_pct: float = Field(50.0, ge=0.0, le=100.0, description="relative humidity at the start, % (e.g. 45)")
    humidity_drift_pct_per_h: float = Field(0.0, ge=-100.0, le=100.0, description="its drift, % per hour")
    material_temperature_c: float = Field(20.0, ge=-10.0, le=60.0, description="the table's temperature at the start, °C")
    material_temperature_drift_k_per_h: float = Field(0.0, ge=-20.0, le=20.0, description="its drift, K per hour")
    temperature_noise_k: float = Field(0.0, ge=0.0, le=10.0, description="the sensor's temperature noise, K (1σ, e.g. 0.01)")
    pressure_noise_pa: float = Field(0.0, ge=0.0, le=1000.0, description="the sensor's pressure noise, Pa (1σ, e.g. 2)")
    humidity_noise_pct: float = Field(0.0, ge=0.0, le=50.0, description="the sensor's humidity noise, % (1σ, e.g. 0.5)")


InstrumentName = Literal["stage", "cmm", "laser_tracer", "encoder", "autocollimator", "dial_indicator_1", "dial_indicator_2",
                         "environment"]
FaultKind = Literal["beam_break", "no_reply", "garbled", "truncated", "modbus_exception", "crc_error", "alarm", "emergency_stop"]
STAGE_ONLY = {"modbus_exception", "crc_error", "alarm", "emergency_stop"}


class FaultSpec(_Strict):
    """A fault to inject: on an instrument's k-th request (``at_request``, counting from 1; a
    request is a motion command or a reading) and/or at random with ``probability`` per request.

    beam_break (laser tracer): tracking is lost until the tracer is re-referenced.
    no_reply, garbled, truncated: the reply never comes, is noise, or stops half-way.
    modbus_exception, crc_error (stage): an exception reply, or a reply with a corrupted frame.
    alarm (stage: stall, following_error, limit_switch) and emergency_stop: the drive alarms.
    """

    instrument: InstrumentName
    kind: FaultKind
    alarm: Literal["stall", "following_error", "limit_switch"] = "stall"
    probability: float = Field(0.0, ge=0.0, le=1.0)
    at_request: list[int] = []

    @model_validator(mode="after")
    def _fits_instrument(self) -> "FaultSpec":
        if self.kind == "beam_break" and self.instrument != "laser_tracer":
            raise ValueError("kind: beam_break happens to the laser_tracer only")
        if self.kind in STAGE_ONLY and self.instrument != "stage":
            raise ValueError(f"kind: {self.kind} happens to the stage drive only")
        if self.instrument == "stage" and self.kind in ("garbled", "truncated"):
            raise ValueError("kind: a Modbus reply cannot be garbled or truncated undetected; use crc_error")
        if not self.probability and not self.at_request:
            raise ValueError("probability: give a probability or at_request, or the fault never happens")
        if any(k < 1 for k in self.at_request):
            raise ValueError("at_request: requests count from 1")
        return self


class Scenario(_Strict):
    """A whole bench. ``seed`` makes every random draw of a run reproducible."""

    seed: int = 0
    stage: StageScenario = StageScenario()
    cmm: CmmScenario = CmmScenario()
    laser_tracer: LaserTracerScenario = LaserTracerScenario()
    encoder: EncoderScenario = EncoderScenario()
    autocollimator: AutocollimatorScenario = AutocollimatorScenario()
    polygon: PolygonScenario = PolygonScenario()
    dial_indicators: DialIndicatorScenario = DialIndicatorScenario()
    stepper: StepperScenario = StepperScenario()
    environment: EnvironmentScenario = EnvironmentScenario()
    faults: list[FaultSpec] = []

    def without_noise(self) -> "Scenario":
        """The same bench with every random error and fault removed: its systematic errors and
        geometry only (what `rtcal plan` measures to predict the uncertainty of a plan)."""
        return self.model_copy(update={
            "stage": self.stage.model_copy(update={"repeatability_arcsec": 0.0}),
            "cmm": self.cmm.model_copy(update={"point_noise_um": 0.0}),
            "laser_tracer": self.laser_tracer.model_copy(update={"length_noise_um": 0.0, "length_noise_ppm": 0.0}),
            "encoder": self.encoder.model_copy(update={"noise_arcsec": 0.0, "resolution_arcsec": 0.0}),
            "autocollimator": self.autocollimator.model_copy(update={"noise_arcsec": 0.0, "resolution_arcsec": 0.0}),
            "polygon": self.polygon.model_copy(update={"certificate_uncertainty_arcsec": 0.0, "seating_error_arcsec": 0.0}),
            "dial_indicators": self.dial_indicators.model_copy(update={"noise_um": 0.0, "resolution_um": 0.0}),
            "environment": self.environment.model_copy(update={"temperature_noise_k": 0.0, "pressure_noise_pa": 0.0,
                                                               "humidity_noise_pct": 0.0}),
            "faults": [],
        })
