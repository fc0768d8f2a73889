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

import numpy as np

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from pydantic_core import PydanticCustomError

from rtcal.compensation.registry import format_names
from rtcal.solvers.harmonics import Harmonic
from rtcal.units import arcsec_to_rad, um_to_mm
from simulators.controllers import SINUMERIK

# Bounds a person would accept for a bench (every number is also finite): angles of error up to
# 1°, lengths of error up to 10 mm, positions within 1 km.
Coord_mm = Annotated[float, Field(ge=-1e6, le=1e6)]
Vec3 = tuple[Coord_mm, Coord_mm, Coord_mm]
ErrorAngle_arcsec = Annotated[float, Field(ge=-3600.0, le=3600.0)]
Size_mm = Annotated[float, Field(ge=-1e4, le=1e4)]
Phase_deg = Annotated[float, Field(ge=-360.0, le=360.0)]
Limit_deg = Annotated[float, Field(ge=-36_000.0, le=36_000.0)]


def _noise(default: float, unit: str, what: str, high: float) -> float:
    return Field(default, ge=0.0, le=high, description=f"{what}, {unit} (0: none)")


# What no real bench exceeds (issue 26): a simulated bench beyond them would certify a physics no table
# has. Noise bounds are a hundred times the worst instruments of each kind; an error motion's harmonics
# together stay within what a worn table shows; speeds between a crawl and a direct drive's rapid.
MAX_STAGE_SPEED_DEG_PER_S, MIN_STAGE_SPEED_DEG_PER_S = 3600.0, 1e-3  # 10 turns/s … 3.6°/h
MAX_CMM_SPEED_MM_PER_S, MIN_CMM_SPEED_MM_PER_S = 10_000.0, 0.01
MAX_ANGLE_NOISE_ARCSEC = 360.0  # 1σ of a table's repeatability, an encoder's or autocollimator's noise
MAX_LENGTH_NOISE_UM = 1000.0  # 1σ of a CMM point, a tracer's length, a dial indicator
MAX_LENGTH_NOISE_PPM = 1000.0
MAX_ANGULAR_MOTION_ARCSEC = 3600.0  # Σ|amplitude| of one angular error motion's harmonics (1°)
MAX_LINEAR_MOTION_UM = 1000.0  # Σ|amplitude| of one linear error motion's harmonics (1 mm)


def _bounded_sum(field: str, harmonics: list, unit: str, limit: float) -> None:
    """A harmonic series whose amplitudes together exceed what any table shows (ValueError naming it)."""
    total = sum(abs(h.amplitude_arcsec if isinstance(h, AngularHarmonic) else h.amplitude_um) for h in harmonics)
    if total > limit:
        raise ValueError(f"{field}: its amplitudes add up to {total:g} {unit}; no real bench's error motion exceeds "
                         f"{limit:g} {unit}")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class AngularHarmonic(_Strict):
    """amplitude_arcsec · sin(order·θ + phase)."""

    order: int = Field(ge=0, le=1000, description="cycles per revolution (0: a constant)")
    amplitude_arcsec: ErrorAngle_arcsec = Field(description="amplitude, arcsec (e.g. 2.5)")
    phase_deg: Phase_deg = Field(0.0, description="phase, deg")

    def to_rad(self) -> Harmonic:
        return Harmonic(self.order, arcsec_to_rad(self.amplitude_arcsec), math.radians(self.phase_deg))


class LinearHarmonic(_Strict):
    """amplitude_um · sin(order·θ + phase)."""

    order: int = Field(ge=0, le=1000, description="cycles per revolution (0: a constant)")
    amplitude_um: Annotated[float, Field(ge=-1e4, le=1e4)] = Field(description="amplitude, µm (e.g. 1.5)")
    phase_deg: Phase_deg = Field(0.0, description="phase, deg")

    def to_mm(self) -> Harmonic:
        return Harmonic(self.order, um_to_mm(self.amplitude_um), math.radians(self.phase_deg))


def _format_names_schema(schema: dict[str, Any]) -> None:
    """The JSON schema lists the registered formats (as the Literal it replaces did)."""
    schema["enum"] = list(format_names())


class CompensationScenario(_Strict):
    """A compensation table the simulated controller applies (as a CNC would: interpolated between
    entries, per approach direction where the format has two), read from ``file`` (relative to
    the scenario) when the scenario is loaded."""

    format: str = Field(description="the table's format, as `rtcal compensate --format` writes it",
                        json_schema_extra=_format_names_schema)
    file: str | None = Field(None, max_length=4096, description="the table file, relative to the scenario (e.g. c.comp)")
    text: str | None = Field(None, max_length=1_000_000, description="the table itself (filled from `file` when loaded)")
    backlash_deg: float = Field(0.0, ge=-1.0, le=1.0, description=(
        "SINUMERIK (siemens-lec, siemens-cec) only: the axis's backlash compensation MD32450 $MA_BACKLASH, deg; on each "
        "reversal the control adds it to the travel in the new direction (808D Parameter Manual p. 228: positive when "
        "the encoder leads the table); the axis counts as referenced in the positive direction (0: none)"))
    detection_unit_deg: float | None = Field(None, gt=0.0, le=0.01, description=(
        "FANUC (fanuc) only, and needed there: the axis's detection unit, deg — its increment system (0.001 IS-B, 0.0001 "
        "IS-C); the control applies the table's increments in it, whatever unit the table was made for"))
    bidirectional: bool = Field(True, description=(
        "FANUC only: parameter 3605#0 as set on the control (bidirectional pitch error compensation; `rtcal compensate` "
        "writes no 3605 record and asks for #0 = 1); a 3605 record in the table overrides it"))

    @field_validator("format", mode="before")
    @classmethod
    def _registered(cls, value: object) -> object:
        """One of the registry's formats (built-ins and installed plugins: rtcal/compensation/),
        refused as a Literal of them would be."""
        names = format_names()
        if value not in names:
            quoted = [repr(n) for n in names]
            expected = f"{', '.join(quoted[:-1])} or {quoted[-1]}" if len(quoted) > 1 else quoted[0]
            raise PydanticCustomError("literal_error", "Input should be {expected}", {"expected": expected})
        return value

    @model_validator(mode="after")
    def _one_source(self) -> "CompensationScenario":
        if (self.file is None) == (self.text is None):
            raise ValueError("file: give the table's file")
        if self.backlash_deg and self.format not in SINUMERIK:
            raise ValueError(f"backlash_deg: MD32450 is SINUMERIK machine data; a {self.format} control has none")
        fanuc_only = {"detection_unit_deg", "bidirectional"} & self.model_fields_set
        if self.format != "fanuc" and fanuc_only:
            raise ValueError(f"{min(fanuc_only)}: a FANUC axis's parameter; a {self.format} control has none")
        if self.format == "fanuc" and self.detection_unit_deg is None:
            raise ValueError("detection_unit_deg: a FANUC axis's detection unit is needed (0.001 for IS-B, 0.0001 for "
                             "IS-C): the control applies the table's increments in it")
        return self


class StageScenario(_Strict):
    """The rotary table: its axis in the CMM frame and its error motions."""

    axis_point_mm: Vec3 = Field((0.0, 0.0, 0.0), description="where the rotation axis meets the CMM table, mm, CMM frame")
    axis_tilt_x_arcsec: ErrorAngle_arcsec = Field(0.0, description="squareness of the axis to the CMM table, about X, arcsec")
    axis_tilt_y_arcsec: ErrorAngle_arcsec = Field(0.0, description="squareness of the axis to the CMM table, about Y, arcsec")
    positioning_error: list[AngularHarmonic] = Field([], max_length=1000, description="εz(θ): actual − commanded angle, harmonics")
    repeatability_arcsec: float = _noise(0.0, "arcsec", "1σ of the random positioning error per move", MAX_ANGLE_NOISE_ARCSEC)
    reversal_arcsec: ErrorAngle_arcsec = Field(0.0, description="how much lower a negative approach ends than a positive one, arcsec")
    radial_motion_x: list[LinearHarmonic] = Field([], max_length=1000, description="δx(θ) at the tilt centre, harmonics")
    radial_motion_y: list[LinearHarmonic] = Field([], max_length=1000, description="δy(θ) at the tilt centre, harmonics")
    axial_motion: list[LinearHarmonic] = Field([], max_length=1000, description="δz(θ), harmonics")
    tilt_motion_x: list[AngularHarmonic] = Field([], max_length=1000, description="εx(θ), harmonics")
    tilt_motion_y: list[AngularHarmonic] = Field([], max_length=1000, description="εy(θ), harmonics")
    tilt_center_height_mm: Size_mm = Field(0.0, description="tilt centre along the axis above axis_point_mm, mm")
    soft_limits_deg: tuple[Limit_deg, Limit_deg] = Field((-360.0, 360.0), description="[lowest, highest] angle the drive accepts, deg")
    speed_deg_per_s: float = Field(10.0, ge=MIN_STAGE_SPEED_DEG_PER_S, le=MAX_STAGE_SPEED_DEG_PER_S,
                                   description="table speed, deg/s (motions take virtual time; 0.001 … 3600)")
    compensation: CompensationScenario | None = Field(None, description="a compensation table the simulated controller "
                                                                        "applies (calibrate → compensate → verify)")
    thermal_expansion_ppm_per_k: float = Field(0.0, ge=-100.0, le=100.0, description=(
        "the table top and what is mounted on it (the tracer) grow radially about the axis by this much per K of the "
        "material temperature above 20 °C, ppm/K (e.g. 11.5 for steel; 0: none)"))

    @model_validator(mode="after")
    def _ordered_limits(self) -> "StageScenario":
        if self.soft_limits_deg[0] >= self.soft_limits_deg[1]:
            raise ValueError("soft_limits_deg: the lower limit must be below the upper one")
        for name in ("positioning_error", "tilt_motion_x", "tilt_motion_y"):
            _bounded_sum(name, getattr(self, name), "arcsec", MAX_ANGULAR_MOTION_ARCSEC)
        for name in ("radial_motion_x", "radial_motion_y", "axial_motion"):
            _bounded_sum(name, getattr(self, name), "µm", MAX_LINEAR_MOTION_UM)
        return self


class CmmFieldTerm(_Strict):
    """One smooth term of the CMM's error field beyond scales and squarenesses: the probe really stands
    ``amplitude_um``·sin(2π·(direction·p)/wavelength + phase) off along ``axis`` at commanded p."""

    axis: Literal["x", "y", "z"] = Field(description="the coordinate it displaces")
    amplitude_um: Annotated[float, Field(ge=-1e4, le=1e4)] = Field(description="amplitude, µm (e.g. 1.0)")
    wavelength_mm: float = Field(gt=1.0, le=1e6, description="wavelength along `direction`, mm (e.g. 800)")
    direction: Vec3 = Field((1.0, 0.0, 0.0), description="the direction the term varies along (normalised)")
    phase_deg: Phase_deg = Field(0.0, description="phase, deg")


class CmmScenario(_Strict):
    """The CMM: commanded → actual probe position, point noise and measuring volume."""

    scale_error_ppm: tuple[Annotated[float, Field(ge=-1e4, le=1e4)], Annotated[float, Field(ge=-1e4, le=1e4)],
                           Annotated[float, Field(ge=-1e4, le=1e4)]] = Field(
        (0.0, 0.0, 0.0), description="scale errors of the X, Y, Z scales, ppm")
    squareness_xy_arcsec: ErrorAngle_arcsec = Field(0.0, description="squareness error between X and Y, arcsec")
    squareness_xz_arcsec: ErrorAngle_arcsec = Field(0.0, description="squareness error between X and Z, arcsec")
    squareness_yz_arcsec: ErrorAngle_arcsec = Field(0.0, description="squareness error between Y and Z, arcsec")
    point_noise_um: float = _noise(0.0, "µm", "1σ per coordinate of the reported position", MAX_LENGTH_NOISE_UM)
    error_field: list[CmmFieldTerm] = Field([], max_length=100, description="smooth geometric errors beyond the affine "
                                            "model (none: the scales and squarenesses only)")
    volume_min_mm: Vec3 = Field((-300.0, -600.0, -100.0), description="lowest X, Y, Z the CMM reaches, mm")
    volume_max_mm: Vec3 = Field((1200.0, 600.0, 800.0), description="highest X, Y, Z the CMM reaches, mm")
    speed_mm_per_s: float = Field(100.0, ge=MIN_CMM_SPEED_MM_PER_S, le=MAX_CMM_SPEED_MM_PER_S,
                                  description="probe speed, mm/s (motions take virtual time; 0.01 … 10000)")

    @model_validator(mode="after")
    def _ordered_volume(self) -> "CmmScenario":
        if any(lo >= hi for lo, hi in zip(self.volume_min_mm, self.volume_max_mm)):
            raise ValueError("volume_max_mm: each coordinate must exceed volume_min_mm's")
        return self


class TracerMount(_Strict):
    """Where the tracer's reference centre sits in the table frame."""

    radius_mm: float = Field(65.33, gt=0.0, le=1e4, description="distance of the tracer's centre from the axis, mm")
    azimuth_deg: Phase_deg = Field(-29.2, description="its direction at table angle 0, deg (the paper's P1 at −145° lies at about −174°)")
    height_mm: Size_mm = Field(122.5, description="its height above the axis point (the CMM origin), mm")


class SphereLobe(_Strict):
    """One lobe of the reference sphere's form: its radius off by amplitude·cos(order·ψ + phase), ψ the beam's
    azimuth about the sphere's vertical axis in the tracer's base frame (the same at every elevation)."""

    order: int = Field(ge=1, le=100, description="lobes per turn (2: oval, 3: three-lobed)")
    amplitude_um: float = Field(ge=0.0, le=10.0, description="the lobe's amplitude, µm (e.g. 0.03)")
    phase_deg: Phase_deg = Field(0.0, description="its phase, deg")


class LaserTracerScenario(_Strict):
    """Interferometric length noise a + b·L (1σ), the mount, and where the tracer goes when the
    operator moves it to its second mount (a procedure's ``second_mount``)."""

    mount: TracerMount = Field(TracerMount(), description="where the tracer sits on the table")
    second_mount: TracerMount = Field(TracerMount(radius_mm=130.0, azimuth_deg=80.0, height_mm=122.5),
                                      description="where the operator moves it for a procedure's second_mount")
    length_noise_um: float = _noise(0.0, "µm", "1σ of every length, constant part a", MAX_LENGTH_NOISE_UM)
    length_noise_ppm: float = _noise(0.0, "µm per m", "1σ of every length, part b proportional to the length",
                                     MAX_LENGTH_NOISE_PPM)
    sphere_form: list[SphereLobe] = Field([], max_length=32, description=(
        "the form error of the tracer's reference sphere: lobes about its vertical axis, fixed to the tracer's base "
        "(which turns with the table), so each length reads off by the sphere's deviation where its beam touches it"))


class StepperScenario(_Strict):
    """Open-loop stepper through a worm: commanded angles are whole (micro)steps."""

    steps_per_revolution: int = Field(0, ge=0, le=10_000_000, description="motor (micro)steps per motor turn; 0: continuous")
    worm_ratio: float = Field(1.0, ge=0.001, le=1e5, description="motor turns per table turn (e.g. 90)")

    @model_validator(mode="after")
    def _fine_enough(self) -> "StepperScenario":
        if self.steps_per_revolution:
            from drivers.addresses import check_step

            check_step(self.steps_per_revolution, self.worm_ratio, ("steps_per_revolution", "worm_ratio"))
        return self


class EncoderScenario(_Strict):
    """The rotary encoder below the tilt centre (seed 001).

    The read head sits at radius rE on +X of the housing; the grating plane lies Zs below the
    tilt centre. A tangential (Y) shift Δt of the grating under the head reads as an extra
    angle Δt/rE: Δt = δy + Zs·εx + e·sin(θ + ψ) for grating eccentricity e at phase ψ.
    """

    radius_mm: float = Field(32.0, gt=0.0, le=1e4, description="rE: radius of the read head, mm")
    grating_offset_mm: Size_mm = Field(0.0, description="Zs: grating plane below the tilt centre, mm")
    eccentricity_um: float = Field(0.0, ge=0.0, le=MAX_LINEAR_MOTION_UM, description="eccentricity of the grating, µm")
    eccentricity_phase_deg: Phase_deg = Field(0.0, description="its phase, deg")
    graduation_error: list[AngularHarmonic] = Field([], max_length=1000, description="errors of the grating angle, harmonics")
    resolution_arcsec: float = _noise(0.0, "arcsec", "one count", 3600.0)
    noise_arcsec: float = _noise(0.0, "arcsec", "1σ of each reading", MAX_ANGLE_NOISE_ARCSEC)

    @model_validator(mode="after")
    def _real_grating(self) -> "EncoderScenario":
        _bounded_sum("graduation_error", self.graduation_error, "arcsec", MAX_ANGULAR_MOTION_ARCSEC)
        return self


class AutocollimatorScenario(_Strict):
    """Reads the polygon face in front of it; ``range_arcsec`` either side of its axis."""

    noise_arcsec: float = _noise(0.0, "arcsec", "1σ of each reading", MAX_ANGLE_NOISE_ARCSEC)
    resolution_arcsec: float = _noise(0.0, "arcsec", "display resolution", MAX_ANGLE_NOISE_ARCSEC)
    range_arcsec: float = Field(150.0, gt=0.0, le=3600.0, description="measuring range either side of the axis, arcsec")
    scale_error_ppm: float = Field(0.0, ge=-1e5, le=1e5, description="its scale error: it reads (1 + this·1e-6) times the "
                                                                    "true deflection, ppm (e.g. 5000 for 0.5 %)")


class PolygonScenario(_Strict):
    """An optical polygon on the table. Face k is in front of the autocollimator at table angle
    k·360°/faces (seated at offset 0). ``face_errors_arcsec``: each face normal's deviation,
    positive counterclockwise; their mean is removed, since a polygon closes (Σ = 0).
    Its certificate is the truth plus noise of ``certificate_uncertainty_arcsec``; each
    re-seating lands within ``seating_error_arcsec`` (1σ) of the nominal offset."""

    faces: int = Field(24, ge=3, le=360, description="faces of the polygon")
    face_errors_arcsec: list[ErrorAngle_arcsec] = Field([], max_length=360, description="each face normal's error, arcsec (none: perfect)")
    certificate_uncertainty_arcsec: float = _noise(0.0, "arcsec", "1σ of the certificate's values", MAX_ANGLE_NOISE_ARCSEC)
    seating_error_arcsec: float = _noise(0.0, "arcsec", "1σ of each re-seating about its nominal offset", 3600.0)

    @model_validator(mode="after")
    def _one_error_per_face(self) -> "PolygonScenario":
        if self.face_errors_arcsec and len(self.face_errors_arcsec) != self.faces:
            raise ValueError(f"face_errors_arcsec: {len(self.face_errors_arcsec)} values for {self.faces} faces")
        return self


class DialIndicatorScenario(_Strict):
    """Two indicators touching the shaft in Y (the grating's tangential direction at the head)."""

    heights_mm: tuple[Size_mm, Size_mm] = Field((50.0, 70.0), description="L1, L2: heights below the tilt centre, mm")
    resolution_um: float = _noise(0.0, "µm", "display resolution", MAX_LENGTH_NOISE_UM)
    noise_um: float = _noise(0.0, "µm", "1σ of each reading", MAX_LENGTH_NOISE_UM)


# -- a five-axis machine tool with a trunnion table (the R-test, docs/rtest.md) ------------------------
ErrorLength_um = Annotated[float, Field(ge=-10_000.0, le=10_000.0)]
# the R-test nest's default: three sensors square to each other, each 54.7° from the spindle axis, at
# azimuths 0°, 120°, 240°; each vector points from the sphere to the sensor (the sphere moving along it
# pushes the plunger in)
_R2, _R3 = math.sqrt(2.0 / 3.0), 1.0 / math.sqrt(3.0)


def _nest_direction(azimuth_deg: float) -> tuple[float, float, float]:
    az = math.radians(azimuth_deg)
    return round(_R2 * math.cos(az), 12), round(_R2 * math.sin(az), 12), round(_R3, 12)


NEST_DIRECTIONS = (_nest_direction(0.0), _nest_direction(120.0), _nest_direction(240.0))


class LocationErrorsScenario(_Strict):
    """The machine's true ISO 230-7 location errors (docs/rtest.md: frames and signs), exactly these keys."""

    X0C_um: ErrorLength_um = Field(0.0, description="C's line in X at the height of the C point, µm")
    Y0C_um: ErrorLength_um = Field(0.0, description="C's line in Y relative to A's line, µm")
    A0C_arcsec: ErrorAngle_arcsec = Field(0.0, description="C's tilt about X (right-hand), arcsec")
    B0C_arcsec: ErrorAngle_arcsec = Field(0.0, description="C's squareness to A about Y (right-hand), arcsec")
    Y0A_um: ErrorLength_um = Field(0.0, description="A's line in Y at the A point's X, µm")
    Z0A_um: ErrorLength_um = Field(0.0, description="A's line in Z at the A point's X, µm")
    B0A_arcsec: ErrorAngle_arcsec = Field(0.0, description="A's tilt about Y (right-hand), arcsec")
    C0A_arcsec: ErrorAngle_arcsec = Field(0.0, description="A's tilt about Z (right-hand), arcsec")


class TrunnionScenario(_Strict):
    """The nominal kinematics the controller holds: a point of C's line at A = C = 0 and a point of A's line,
    machine frame (LinuxCNC xyzac-trt-kins: C through the rot point, A through rot point + (0, y-offset, z-offset))."""

    c_point_mm: Vec3 = Field((0.0, 0.0, 0.0), description="a point of C's line, mm (its z: where X0C, Y0C are stated)")
    a_point_mm: Vec3 = Field((0.0, 0.0, -50.0), description="a point of A's line, mm (its x: where Y0A, Z0A are stated)")


class LinearAxesScenario(_Strict):
    """The linear axes' geometry: the nest stands at M·J for commanded joints J, M = [[1+sx, 0, 0],
    [xy, 1+sy, 0], [xz, yz, 1+sz]] (as the CMM's), plus a random error per move."""

    scale_error_ppm: tuple[Annotated[float, Field(ge=-1e3, le=1e3)], Annotated[float, Field(ge=-1e3, le=1e3)],
                           Annotated[float, Field(ge=-1e3, le=1e3)]] = Field((0.0, 0.0, 0.0), description="X, Y, Z scale errors, ppm")
    squareness_xy_arcsec: ErrorAngle_arcsec = Field(0.0, description="squareness between X and Y, arcsec")
    squareness_xz_arcsec: ErrorAngle_arcsec = Field(0.0, description="squareness between X and Z, arcsec")
    squareness_yz_arcsec: ErrorAngle_arcsec = Field(0.0, description="squareness between Y and Z, arcsec")
    repeatability_um: float = _noise(0.0, "µm", "1σ per axis of each move's random positioning error", MAX_LENGTH_NOISE_UM)


class SphereSetupScenario(_Strict):
    """The calibration sphere: its certificate and where it is mounted on the table."""

    radius_mm: float = Field(12.7, gt=0.5, le=100.0, description="radius, mm (e.g. 12.7: a 1-inch ball)")
    form_um: float = Field(0.0, ge=0.0, le=100.0, description="its form deviation, peak to valley, µm (a smooth field "
                                                              "of spherical degrees 2–6; 0: perfect)")
    positions_mm: list[Vec3] = Field([(150.0, 0.0, 80.0)], min_length=1, max_length=10, description=(
        "where each set-up's sphere centre is assumed on the table (table coordinates: machine frame at A = C = 0), mm"))
    setup_offsets_um: list[tuple[ErrorLength_um, ErrorLength_um, ErrorLength_um]] = Field([], max_length=10, description=(
        "where each sphere really sits less where assumed, µm (none: drawn with setup_sigma_um)"))
    setup_sigma_um: float = Field(0.0, ge=0.0, le=1000.0, description="1σ per axis of the set-up offsets drawn when none "
                                                                    "are given, µm")

    @model_validator(mode="after")
    def _one_offset_per_position(self) -> "SphereSetupScenario":
        if self.setup_offsets_um and len(self.setup_offsets_um) != len(self.positions_mm):
            raise ValueError(f"setup_offsets_um: {len(self.setup_offsets_um)} for {len(self.positions_mm)} positions")
        return self


class NestScenario(_Strict):
    """Three flat-ended indicators on the spindle around the sphere (read as Sylvac indicators)."""

    directions: tuple[Vec3, Vec3, Vec3] = Field(NEST_DIRECTIONS, description=(
        "each sensor's nominal direction from the sphere to the sensor (normalised)"))
    direction_error_deg: float = Field(0.0, ge=0.0, le=10.0, description="1σ of each sensor's real axis about its "
                                                                        "nominal direction, deg (drawn once per nest)")
    face_tilt_deg: float = Field(0.0, ge=0.0, le=5.0, description="1σ of each flat face's tilt to its plunger, deg")
    flat_radius_mm: float = Field(3.0, gt=0.0, le=20.0, description="radius of each flat face, mm")
    stroke_mm: float = Field(2.0, gt=0.0, le=25.0, description="each plunger's travel either side of its zero, mm")
    capture_mm: float = Field(1.0, gt=0.0, le=10.0, description="how far the sphere may stray from the nest's zero "
                                                               "point before it strikes the nest, mm")
    offset_mm: Vec3 = Field((0.0, 0.0, 0.0), description="the nest zero point's stated offset from the joints, mm")
    zero_error_um: tuple[ErrorLength_um, ErrorLength_um, ErrorLength_um] = Field(
        (0.0, 0.0, 0.0), description="where the zero point really is less the stated offset, µm")
    noise_um: float = _noise(0.0, "µm", "1σ of each reading", MAX_LENGTH_NOISE_UM)
    resolution_um: float = Field(0.1, ge=0.0, le=10.0, description="display resolution, µm (a Sylvac's 0.0001 mm)")

    @model_validator(mode="after")
    def _square_enough(self) -> "NestScenario":
        d = np.array(self.directions, float)
        n = np.linalg.norm(d, axis=1)
        if np.any(n < 1e-6) or abs(np.linalg.det(d / n[:, None])) < 0.1:
            raise ValueError("directions: three directions that span space (a nest whose sensors lie in one plane "
                             "cannot see the sphere move across it)")
        return self


class DriftScenario(_Strict):
    """The sphere's drift relative to the nest (spindle and table warming): amplitude·(1 − e^(−t/τ)) from
    the run's first reading."""

    amplitude_um: tuple[ErrorLength_um, ErrorLength_um, ErrorLength_um] = Field((0.0, 0.0, 0.0), description="X, Y, Z, µm")
    time_constant_s: float = Field(3600.0, gt=0.0, le=1e7, description="τ, s")


class MachineToolScenario(_Strict):
    """A five-axis machine with a trunnion table (A about X carrying C), as LinuxCNC's xyzac-trt-kins
    describes it, and the truth the R-test measures (docs/rtest.md)."""

    kinematics: TrunnionScenario = Field(TrunnionScenario(), description="the nominal kinematics")
    location_errors: LocationErrorsScenario = Field(LocationErrorsScenario(), description="the true location errors")
    c_positioning_error: list[AngularHarmonic] = Field([], max_length=1000, description="ECC(c): C's actual − commanded "
                                                                                       "angle, harmonics")
    c_reversal_arcsec: ErrorAngle_arcsec = Field(0.0, description="how much lower C ends approached negative, arcsec")
    linear_axes: LinearAxesScenario = Field(LinearAxesScenario(), description="the linear axes' errors")
    sphere: SphereSetupScenario = Field(SphereSetupScenario(), description="the calibration sphere")
    nest: NestScenario = Field(NestScenario(), description="the three-sensor nest")
    drift: DriftScenario = Field(DriftScenario(), description="thermal drift of the sphere relative to the nest")
    limits_mm: tuple[Vec3, Vec3] = Field(((-500.0, -500.0, -500.0), (500.0, 500.0, 500.0)),
                                         description="[lowest X, Y, Z], [highest X, Y, Z] the joints accept, mm")
    a_limits_deg: tuple[Limit_deg, Limit_deg] = Field((-120.0, 120.0), description="A's limits, deg")
    c_limits_deg: tuple[Limit_deg, Limit_deg] = Field((-36_000.0, 36_000.0), description="C's limits, deg")
    linear_speed_mm_per_s: float = Field(50.0, ge=0.01, le=10_000.0, description="linear speed, mm/s")
    rotary_speed_deg_per_s: float = Field(20.0, ge=MIN_STAGE_SPEED_DEG_PER_S, le=MAX_STAGE_SPEED_DEG_PER_S,
                                          description="rotary speed, deg/s")

    @model_validator(mode="after")
    def _bounded(self) -> "MachineToolScenario":
        _bounded_sum("c_positioning_error", self.c_positioning_error, "arcsec", MAX_ANGULAR_MOTION_ARCSEC)
        if any(lo >= hi for lo, hi in zip(*self.limits_mm)) or self.a_limits_deg[0] >= self.a_limits_deg[1] \
                or self.c_limits_deg[0] >= self.c_limits_deg[1]:
            raise ValueError("limits: each lower limit must be below its upper one")
        return self


Profile = list[tuple[Annotated[float, Field(ge=0.0, le=1e7)], Annotated[float, Field(ge=-1e5, le=1e5)]]]


def _profile(what: str, unit: str) -> Profile:
    return Field([], max_length=10_000, description=(
        f"{what}: [[t_s, offset {unit}], …] added to the start value and the drift, piecewise linear in seconds from the "
        "run's first reading; the first offset holds before the first point, the last after the last (e.g. a step: "
        "[[3000, 0], [3060, 1.8]])"))


class EnvironmentScenario(_Strict):
    """The air around the bench and the table's temperature: a start value, a linear drift with the
    clock (it starts at 0) and a piecewise-linear profile in the time since the run's first reading
    (a step, a cycle), and the environment sensor's noise. Unnamed: standard air (20 °C, 1013.25 hPa,
    50 % RH), steady — the simulated tracer then reads as if in vacuum-corrected air."""

    air_temperature_c: float = Field(20.0, ge=-10.0, le=50.0, description="air temperature at the start, °C (e.g. 20.3)")
    air_temperature_drift_k_per_h: float = Field(0.0, ge=-20.0, le=20.0, description="its drift, K per hour (e.g. 0.5)")
    air_pressure_pa: float = Field(101325.0, ge=60000.0, le=120000.0, description="air pressure at the start, Pa (e.g. 100800)")
    air_pressure_drift_pa_per_h: float = Field(0.0, ge=-5000.0, le=5000.0, description="its drift, Pa per hour (e.g. 300)")
    humidity_pct: float = Field(50.0, ge=0.0, le=100.0, description="relative humidity at the start, % (e.g. 45)")
    humidity_drift_pct_per_h: float = Field(0.0, ge=-100.0, le=100.0, description="its drift, % per hour")
    material_temperature_c: float = Field(20.0, ge=-10.0, le=60.0, description="the table's temperature at the start, °C")
    material_temperature_drift_k_per_h: float = Field(0.0, ge=-20.0, le=20.0, description="its drift, K per hour")
    mount_temperature_drift_k_per_h: float | None = Field(None, ge=-20.0, le=20.0, description=(
        "the drift of the table region that carries the tracer, K per hour, from the table's start temperature (a "
        "gradient: a motor under the table warms the mount faster than the rim the sensor reads; None: the table's)"))
    temperature_noise_k: float = Field(0.0, ge=0.0, le=10.0, description="the sensor's temperature noise, K (1σ, e.g. 0.01)")
    pressure_noise_pa: float = Field(0.0, ge=0.0, le=1000.0, description="the sensor's pressure noise, Pa (1σ, e.g. 2)")
    humidity_noise_pct: float = Field(0.0, ge=0.0, le=50.0, description="the sensor's humidity noise, % (1σ, e.g. 0.5)")
    air_temperature_profile: Profile = _profile("the air temperature's course", "K")
    air_pressure_profile: Profile = _profile("the air pressure's course", "Pa")
    humidity_profile: Profile = _profile("the humidity's course", "% RH")
    material_temperature_profile: Profile = _profile("the table's temperature's course", "K")

    @model_validator(mode="after")
    def _profiles_in_time_order(self) -> "EnvironmentScenario":
        for name in ("air_temperature_profile", "air_pressure_profile", "humidity_profile", "material_temperature_profile"):
            times = [t for t, _ in getattr(self, name)]
            if any(b < a for a, b in zip(times, times[1:])):
                raise ValueError(f"{name}: the times must not decrease")
        return self

    def offsets(self, since_first_reading_s: float | None) -> tuple[float, float, float, float]:
        """The profiles' offsets (air K, air Pa, % RH, material K) at a time since the run's first
        reading (None: before it, the first offsets)."""
        out = []
        for profile in (self.air_temperature_profile, self.air_pressure_profile, self.humidity_profile,
                        self.material_temperature_profile):
            if not profile:
                out.append(0.0)
                continue
            t, v = zip(*profile)
            out.append(float(np.interp(-math.inf if since_first_reading_s is None else since_first_reading_s, t, v)))
        return out[0], out[1], out[2], out[3]


InstrumentName = Literal["stage", "cmm", "laser_tracer", "encoder", "autocollimator", "dial_indicator_1", "dial_indicator_2",
                         "environment", "machine_tool", "nest_indicator_1", "nest_indicator_2", "nest_indicator_3"]
FaultKind = Literal["beam_break", "no_reply", "garbled", "truncated", "modbus_exception", "crc_error", "alarm", "emergency_stop",
                    "stuck", "short", "moved", "stale", "frozen", "creep", "inch"]
STAGE_ONLY = {"modbus_exception", "crc_error", "alarm", "emergency_stop", "stuck", "short"}
POSITION_READ_KINDS = {"moved"}  # counted on the instrument's position reads, not on its other requests
# what goes wrong inside an instrument and stays wrong: from the request it is drawn at, every reading after
NEST_INDICATORS = ("nest_indicator_1", "nest_indicator_2", "nest_indicator_3")
STATE_KINDS = {"stale": ("autocollimator", "encoder"), "frozen": ("autocollimator", "encoder"),
               "creep": ("laser_tracer", "dial_indicator_1", "dial_indicator_2", *NEST_INDICATORS),
               "inch": ("dial_indicator_1", "dial_indicator_2", *NEST_INDICATORS)}


class FaultSpec(_Strict):
    """A fault to inject: on an instrument's k-th request (``at_request``, counting from 1; a
    request is a motion command or a reading) and/or at random with ``probability`` per request.

    beam_break (laser tracer): tracking is lost until the tracer is re-referenced.
    no_reply, garbled, truncated: the reply never comes, is noise, or stops half-way.
    modbus_exception, crc_error (stage): an exception reply, or a reply with a corrupted frame.
    alarm (stage: stall, following_error, limit_switch) and emergency_stop: the drive alarms.
    stuck (stage): the drive accepts the move, reports "in position" and echoes the command as its
    feedback, but the table does not turn (only another instrument can tell).
    short (stage): the table stops ``shortfall_deg`` short of the target, and the drive's
    feedback position shows where it stopped.
    moved (stage, cmm): another client moves it — the table by ``offset_deg``, the probe by
    ``offset_mm`` — at its k-th position read (position reads are counted on their own).
    stale, frozen, creep, inch: from the request drawn on, for the rest of the run (a restart of the
    instrument — a resume — clears it). stale (autocollimator, encoder): each reply is the reading
    taken at the previous request (a buffer one step behind); frozen: every reply repeats the last
    reply before it (a frozen display); creep (laser_tracer, dial indicators): each length or
    displacement reads ``creep_um_per_reading`` more than the one before (a slowly creeping count,
    an indicator slipping on its stand); inch (dial
    indicator): the display shows inches — over the wire the Sylvac reply says ``in``; in process
    the simulated instrument stands for a reply without a unit, read as mm (25.4× too small).
    """

    instrument: InstrumentName = Field(description="which instrument suffers it")
    kind: FaultKind = Field(description="what happens (see above)")
    alarm: Literal["stall", "following_error", "limit_switch"] = Field("stall", description="which drive alarm, for kind `alarm`")
    shortfall_deg: float = Field(0.01, gt=0.0, le=90.0, description="for kind `short`: how far short the table stops, deg")
    offset_deg: float = Field(0.003, ge=-90.0, le=90.0, description="for kind `moved` on the stage: how far the other client "
                                                                   "turns the table, deg (e.g. 0.003: three steps)")
    offset_mm: Vec3 = Field((0.5, 0.0, 0.0), description="for kind `moved` on the CMM: how far the other client moves the probe, mm")
    creep_um_per_reading: float = Field(0.5, gt=0.0, le=1000.0, description="for kind `creep`: how much each tracer length "
                                                                         "or indicator reading adds to the one before, µm (e.g. 0.5)")
    probability: float = Field(0.0, ge=0.0, le=1.0, description="chance per request, 0..1 (e.g. 0.02)")
    at_request: list[Annotated[int, Field(le=1_000_000_000)]] = Field(
        [], max_length=10_000, description="the instrument's requests that fail, counted from 1 over the whole run (resumes go on counting)")

    @model_validator(mode="after")
    def _fits_instrument(self) -> "FaultSpec":
        if self.kind == "beam_break" and self.instrument != "laser_tracer":
            raise ValueError("kind: beam_break happens to the laser_tracer only")
        if self.kind in STAGE_ONLY and self.instrument != "stage":
            raise ValueError(f"kind: {self.kind} happens to the stage drive only")
        if self.kind == "moved" and self.instrument not in ("stage", "cmm"):
            raise ValueError("kind: only the stage or the CMM can be moved by another client")
        if self.kind in STATE_KINDS and self.instrument not in STATE_KINDS[self.kind]:
            raise ValueError(f"kind: {self.kind} happens to the {' or the '.join(STATE_KINDS[self.kind])} only")
        if self.instrument == "stage" and self.kind in ("garbled", "truncated"):
            raise ValueError("kind: a Modbus reply cannot be garbled or truncated undetected; use crc_error")
        if not self.probability and not self.at_request:
            raise ValueError("probability: give a probability or at_request, or the fault never happens")
        if any(k < 1 for k in self.at_request):
            raise ValueError("at_request: requests count from 1")
        return self


class Scenario(_Strict):
    """A whole bench. ``seed`` makes every random draw of a run reproducible."""

    seed: int = Field(0, ge=0, le=2**63 - 1, description="seed of the run's random generator (`rtcal run --seed` replaces it)")
    stage: StageScenario = Field(StageScenario(), description="the rotary table")
    cmm: CmmScenario = Field(CmmScenario(), description="the CMM")
    laser_tracer: LaserTracerScenario = Field(LaserTracerScenario(), description="the laser tracer")
    encoder: EncoderScenario = Field(EncoderScenario(), description="the rotary encoder (seed 001)")
    autocollimator: AutocollimatorScenario = Field(AutocollimatorScenario(), description="the autocollimator (seed 001)")
    polygon: PolygonScenario = Field(PolygonScenario(), description="the optical polygon (seed 001)")
    dial_indicators: DialIndicatorScenario = Field(DialIndicatorScenario(), description="the two dial indicators (seed 001)")
    stepper: StepperScenario = Field(StepperScenario(), description="an open-loop stepper drive, if any")
    environment: EnvironmentScenario = Field(EnvironmentScenario(), description="the air around the beam and its sensor")
    faults: list[FaultSpec] = Field([], max_length=1000, description="faults to inject (docs/faults.md)")
    machine: MachineToolScenario | None = Field(None, description="a five-axis machine tool with a trunnion table and "
                                                                  "the R-test's sphere and nest (docs/rtest.md)")

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
            "machine": None if self.machine is None else self.machine.model_copy(update={
                "linear_axes": self.machine.linear_axes.model_copy(update={"repeatability_um": 0.0}),
                "nest": self.machine.nest.model_copy(update={"noise_um": 0.0, "resolution_um": 0.0})}),
        })
