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

from pydantic import BaseModel, ConfigDict, Field

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
    """Interferometric length noise a + b·L (1σ) and the mount."""

    mount: TracerMount = TracerMount()
    length_noise_um: float = Field(0.0, ge=0.0)
    length_noise_ppm: float = Field(0.0, ge=0.0)  # µm per m of length


class EncoderScenario(_Strict):
    """The rotary encoder (completed by the seed-001 work): read-head radius and resolution."""

    radius_mm: float = Field(32.0, gt=0.0)
    grating_offset_mm: float = 0.0  # Zs, grating plane below the tilt centre
    resolution_arcsec: float = Field(0.0, ge=0.0)


class AutocollimatorScenario(_Strict):
    noise_arcsec: float = Field(0.0, ge=0.0)
    range_arcsec: float = Field(150.0, gt=0.0)


class PolygonScenario(_Strict):
    faces: int = Field(24, ge=3)


class DialIndicatorScenario(_Strict):
    heights_mm: tuple[float, float] = (50.0, 70.0)  # L1, L2 below the tilt centre
    resolution_um: float = Field(0.0, ge=0.0)


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
