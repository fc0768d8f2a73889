"""The R-test's procedure (procedures/rtest_trunnion.yaml): the machine, the sphere with its certificate, the
nest with its calibration, the ISO 10791-6 kinematic tests, the stated uncertainty and the control's records the
compensation is written into. Validated as every procedure is (file:line:field); docs/rtest.md states the model."""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field, model_validator

from rtcal import api
from rtcal.solvers.rtest import TrunnionGeometry, k_test_sequence
from rtcal.solvers.rtest_fit import StatedUncertainty

NAME = "rtest"
NEST = ("nest_indicator_1", "nest_indicator_2", "nest_indicator_3")
FORMATS = ("linuxcnc-xyzac-trt", "siemens-tc-carr", "fanuc-tcp-table")
Vec3 = tuple[Annotated[float, Field(ge=-1e5, le=1e5)], Annotated[float, Field(ge=-1e5, le=1e5)],
             Annotated[float, Field(ge=-1e5, le=1e5)]]
Angle = Annotated[float, Field(ge=-36_000.0, le=36_000.0)]


class Instruments(api.InstrumentsBase):
    machine: api.InstrumentChoice = Field(description=(
        "the five-axis machine (kind `machine_tool`): `{kind: machine_tool, backend: sim}` or its address, e.g. "
        "`linuxcncrsh://127.0.0.1:5007?take_control=1` from `rtcal sim serve --machine linuxcnc`"))
    nest_indicator_1: api.InstrumentChoice = Field(description="the nest's first sensor (kind `dial_indicator`)")
    nest_indicator_2: api.InstrumentChoice = Field(description="the nest's second sensor (kind `dial_indicator`)")
    nest_indicator_3: api.InstrumentChoice = Field(description="the nest's third sensor (kind `dial_indicator`)")

    @model_validator(mode="after")
    def _kinds(self) -> Instruments:
        if self.machine.kind != "machine_tool":
            raise ValueError("machine.kind: declare the machine's kind, `kind: machine_tool`")
        for name in NEST:
            if getattr(self, name).kind != "dial_indicator":
                raise ValueError(f"{name}.kind: declare the sensor's kind, `kind: dial_indicator` (it reads y_um)")
        return self


class Kinematics(api.StrictModel):
    """The control's kinematics as commissioned: the location errors are relative to these lines."""

    c_point_mm: Vec3 = Field((0.0, 0.0, 0.0), description="a point of C's line at A = C = 0, machine frame, mm (its z: "
                                                           "the height X0C and Y0C are stated at)")
    a_point_mm: Vec3 = Field((0.0, 0.0, 0.0), description="a point of A's line, mm (its x: the plane Y0A and Z0A are "
                                                           "stated at); A along +X, C along +Z")

    def geometry(self) -> TrunnionGeometry:
        return TrunnionGeometry(self.c_point_mm, self.a_point_mm)


class SphereCertificate(api.StrictModel):
    """The calibration sphere's certificate."""

    number: str = Field("", max_length=200, description="the sphere certificate's number (for the certificate's list)")
    radius_mm: float = Field(12.7, gt=0.5, le=100.0, description="its radius as certified, mm")
    form_um: float = Field(0.25, ge=0.0, le=100.0, description="its form deviation as certified (peak to valley), µm")


class Sphere(api.StrictModel):
    position_mm: Vec3 = Field((150.0, 0.0, 80.0), description=(
        "where the sphere's centre is set up on the table, by its machine coordinates at A = C = 0, mm"))
    certificate: SphereCertificate = Field(SphereCertificate(), description="the sphere's certificate")
    second_position_mm: Vec3 | None = Field(None, description=(
        "where the operator moves the sphere (e.g. a second height on a riser) once the tests at `position_mm` are "
        "done, machine coordinates at A = C = 0, mm; the tests are repeated there, each position's first pose "
        "repeated at its end (its own drift). Null: one position. Two heights separate C's tilts (A0C, B0C) from "
        "the set-up better than one"))

    def positions(self) -> list[Vec3]:
        """The sphere's positions in the order they are tested."""
        return [self.position_mm] + ([] if self.second_position_mm is None else [self.second_position_mm])


class NestCalibrationPlan(api.StrictModel):
    move_mm: float = Field(0.5, gt=0.0, le=2.0, description=(
        "the six linear moves ±x, ±y, ±z of the nest around the sphere at the first pose, mm each"))


class Nest(api.StrictModel):
    directions: tuple[Vec3, Vec3, Vec3] = Field(
        ((0.0, 0.0, 0.0),) * 3, description=(
            "each sensor's nominal unit direction (machine frame; all zero: the three at 120° round Z, tilted 35.26° "
            "from it, as the simulated nest) — only the prediction uses them: the calibration measures them"))
    offset_mm: Vec3 = Field((0.0, 0.0, 0.0), description="the nest zero point's offset from the joints (the tool), mm")
    flat_radius_mm: float = Field(3.0, gt=0.0, le=20.0, description="radius of each sensor's flat face, mm")
    calibration: NestCalibrationPlan = Field(NestCalibrationPlan(), description="the nest calibration's moves")


class KTests(api.StrictModel):
    """The ISO 10791-6 kinematic tests of a trunnion table."""

    c_angles_deg: list[Angle] = Field(list(range(0, 360, 30)), min_length=3, max_length=720,
                                      description="C's angles, turned at A = 0 and at the tilt, deg")
    a_angles_deg: list[Angle] = Field([-90, -60, -30, 0, 30, 60, 90], min_length=0, max_length=720,
                                      description="A's angles, turned at C = 0 (empty: no A test), deg")
    tilt_deg: float | None = Field(45.0, ge=-180.0, le=180.0, description="A's tilt for the second C test (null: none)")
    both_directions: bool = Field(True, description="each test there and back (C approached from both sides)")
    overshoot_deg: float = Field(2.0, ge=0.0, le=30.0, description="how far C passes a target to arrive from its side")


class Uncertainty(api.StrictModel):
    """What the readings and the machine may be off by (1σ unless said): the GUM budget's inputs."""

    sensor_noise_um: float = Field(0.1, ge=0.0, le=100.0, description="each sensor reading's noise, µm")
    sensor_resolution_um: float = Field(0.1, ge=0.0, le=100.0, description="each sensor's digit, µm")
    nest_zero_um: float = Field(1.0, ge=0.0, le=1000.0, description="the nest zero point's position on the spindle, µm")
    linear_scale_ppm: float = Field(3.0, ge=0.0, le=1000.0, description="the linear axes' scale errors, ppm")
    linear_squareness_arcsec: float = Field(2.0, ge=0.0, le=1000.0, description="their squareness errors, arcsec")
    linear_repeatability_um: float = Field(0.3, ge=0.0, le=100.0, description="their positioning repeatability, µm")
    drift_nonlinearity: float = Field(0.25, ge=0.0, le=1.0, description=(
        "the share of the drift measured by the repeated first pose that its linear correction may miss"))
    expected_drift_um: float = Field(2.0, ge=0.0, le=1000.0, description="the drift `rtcal plan` assumes, µm per axis")


class OnFault(api.StrictModel):
    machine: api.FaultPolicy = Field(api.FaultPolicy(), description="when the machine fails")
    nest: api.FaultPolicy = Field(api.FaultPolicy(), description="when a nest sensor fails")


class Compensation(api.StrictModel):
    """The control's records as commissioned, per format (absent: derived from `kinematics`)."""

    records: dict[Literal["linuxcnc-xyzac-trt", "siemens-tc-carr", "fanuc-tcp-table"], dict[str, float]] = Field(
        {}, description="format → its record (e.g. `linuxcnc-xyzac-trt: {x-rot-point: 0, …}`)")


class Durations(api.StrictModel):
    mount_s: float = Field(600.0, ge=0.0, le=86_400.0, description="what mounting the sphere and the nest takes, s")


class RTestTrunnion(api.ProcedureBase):
    """The R-test of a trunnion table (A about X carrying C): the eight ISO 230-7 location errors."""

    method: Literal["rtest"] = Field(description="the R-test of a five-axis machine's rotary axes")
    instruments: Instruments = Field(description="the machine and the nest's three sensors")
    kinematics: Kinematics = Field(Kinematics(), description="the control's nominal kinematics")
    sphere: Sphere = Field(Sphere(), description="the sphere and its certificate")
    nest: Nest = Field(Nest(), description="the nest of three sensors")
    tests: KTests = Field(KTests(), description="the kinematic tests")
    settle_time_s: float = Field(0.5, ge=0.0, le=600.0, description="wait after each move before reading, s")
    uncertainty: Uncertainty = Field(Uncertainty(), description="inputs of the uncertainty budget")
    on_fault: OnFault = Field(OnFault(), description="what to do when an instrument fails")
    verification: api.VerificationBase = Field(api.VerificationBase(), description="what every motion is checked against")
    compensation: Compensation = Field(Compensation(), description="the control's records the compensation is written into")
    durations: Durations = Field(Durations(), description="what the operator's step takes")

    def poses(self) -> list[tuple[float, float, int]]:
        """(A, C, C's approach direction) of each K-test reading, in order: the tests at each sphere position in
        turn, each position's first pose repeated at its end."""
        t = self.tests
        one = k_test_sequence(t.c_angles_deg, t.tilt_deg, t.a_angles_deg, t.both_directions)
        return one * len(self.sphere.positions())

    def pose_spheres(self) -> list[int]:
        """The sphere position (index into ``sphere.positions()``) of each pose of ``poses()``."""
        n = len(self.poses()) // len(self.sphere.positions())
        return [j for j in range(len(self.sphere.positions())) for _ in range(n)]

    def drift_pairs(self) -> tuple[tuple[int, int], ...]:
        """Per sphere position, (its first pose, its repeat) as indices of ``poses()``: the drift of each."""
        n = len(self.poses()) // len(self.sphere.positions())
        return tuple((j * n, j * n + n - 1) for j in range(len(self.sphere.positions())))

    def approaches(self) -> tuple[set[int], int]:
        return ({1, -1} if self.tests.both_directions else {1}), 1

    def plan_size(self, max_cells: int, hint: str) -> tuple[int, str, str, str | None]:
        n = 7 + len(self.poses())
        return n, "tests", f"7 nest calibration moves + {n - 7} poses", None

    def planned_stage_deg(self) -> tuple[str, list[float]]:
        return "tests", []  # no rotary stage: the machine's own limits check its joints

    def stated(self) -> StatedUncertainty:
        u = self.uncertainty
        return StatedUncertainty(
            sensor_noise_um=u.sensor_noise_um, sensor_resolution_um=u.sensor_resolution_um,
            sphere_form_um=self.sphere.certificate.form_um, nest_zero_um=u.nest_zero_um,
            linear_scale_ppm=u.linear_scale_ppm, linear_squareness_arcsec=u.linear_squareness_arcsec,
            linear_repeatability_um=u.linear_repeatability_um, drift_nonlinearity=u.drift_nonlinearity,
            expected_drift_um=u.expected_drift_um)

    def control_record(self, fmt: str) -> dict[str, float]:
        """The control's record of ``fmt`` that holds ``kinematics`` (the procedure's, else as commissioned from it):
        LinuxCNC's pins (trtfuncs.c: C through the rot point, A through it + the offsets), SINUMERIK's I2 (machine
        zero to A's point) and I3 (A's point to C's), V1 = +X, V2 = +Z, FANUC's table position (A's point) and
        19703–19705 (A's point to C's)."""
        given = self.compensation.records.get(fmt)  # type: ignore[call-overload]
        if given is not None:
            return dict(given)
        c, a = self.kinematics.c_point_mm, self.kinematics.a_point_mm
        if fmt == "linuxcnc-xyzac-trt":
            return {"x-rot-point": c[0], "y-rot-point": c[1], "z-rot-point": c[2], "y-offset": a[1] - c[1],
                    "z-offset": a[2] - c[2]}
        if fmt == "siemens-tc-carr":
            vec = {"I2": a, "I3": tuple(ci - ai for ci, ai in zip(c, a)), "V1": (1.0, 0.0, 0.0), "V2": (0.0, 0.0, 1.0)}
            return {f"{k}{axis}": float(v) for k, xyz in vec.items() for axis, v in zip("xyz", xyz)}
        return {"table_position_x": a[0], "table_position_y": a[1], "table_position_z": a[2], "19703": c[0] - a[0],
                "19704": c[1] - a[1], "19705": c[2] - a[2]}

    @model_validator(mode="after")
    def _plan(self) -> RTestTrunnion:
        problem = api.plan_size_problem(self)
        if problem:
            raise ValueError(problem)
        t = self.tests
        if len(set(t.c_angles_deg)) != len(t.c_angles_deg) or len(set(t.a_angles_deg)) != len(t.a_angles_deg):
            raise ValueError("tests: each angle once in c_angles_deg and in a_angles_deg")
        for i, d in enumerate(self.nest.directions):
            n = math.sqrt(sum(x * x for x in d))
            if n != 0.0 and abs(n - 1.0) > 1e-3:
                raise ValueError(f"nest.directions[{i}]: {list(d)} is not a unit vector")
        return self

    @model_validator(mode="after")
    def _records_match_the_kinematics(self) -> RTestTrunnion:
        """A record given is the control's: its lines must be the `kinematics` the errors are stated against."""
        for name, record in self.compensation.records.items():
            try:
                g = api.kinematics_format(name).geometry(record)
            except api.CompensationError as exc:
                raise ValueError(f"compensation.records.{name}: {exc}") from None
            nominal = self.kinematics.geometry()
            # C's line where it crosses the commissioned height, A's where it crosses the commissioned plane
            off = max(abs(g.c_point_mm[0] - nominal.c_point_mm[0]), abs(g.c_point_mm[1] - nominal.c_point_mm[1]),
                      abs(g.a_point_mm[1] - nominal.a_point_mm[1]), abs(g.a_point_mm[2] - nominal.a_point_mm[2]))
            if off > 1e-3:
                raise ValueError(f"compensation.records.{name}: its lines are {off * 1e3:.1f} µm from `kinematics` (the "
                                 "location errors are relative to the kinematics the control held): give the same")
        return self
