"""The laser-tracer multi-station procedure's model (seed 000): what its YAML file may say, on the
shared bases of :mod:`rtcal.procedure.models` (metadata, instruments, fault policies, acceptance)."""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import Field, ValidationInfo, model_validator

from rtcal.api import (Angle_deg, CmmChoice, FaultPolicy, InstrumentChoice, InstrumentsBase, ProcedureBase, StageChoice,
                       StrictModel, Vec3, VerificationBase, plan_outside_limits, plan_size_problem)
PAPER_STATION_1_MM, PAPER_STATION_1_DEG = (-64.9938, -6.6256, 122.5133), -145.0


class MultistationInstruments(InstrumentsBase):
    stage: StageChoice = Field(StageChoice(), description="the rotary table's drive")
    cmm: CmmChoice = Field(CmmChoice(), description="the CMM that carries the tracer's reflector")
    laser_tracer: InstrumentChoice = Field(InstrumentChoice(), description="the laser tracer on the table")
    environment: InstrumentChoice | None = Field(
        None, description="an air and material sensor, read with every length: rtcal corrects each length for the "
                          "refractive index of the air of the moment (e.g. {backend: sim})")


class MultistationOnFault(StrictModel):
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


class Stations(StrictModel):
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


class GridPlan(StrictModel):
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


class ListPlan(StrictModel):
    """An explicit list of CMM points (mm, CMM frame), measured in the order given."""

    kind: Literal["list"] = Field(description="`list`: the points are listed")
    points_mm: list[Vec3] = Field(min_length=1, max_length=100_000,
                                  description="[x, y, z] of each point, mm, CMM frame, in measuring order")

    def points_mm_array(self) -> np.ndarray:
        return np.array(self.points_mm, dtype=float)


class LMSettings(StrictModel):
    """The paper's LM parameters (section 4.2.1)."""

    beta: float = Field(0.55, gt=0.0, lt=1.0, description="β of the step-length search, in (0, 1) (the paper: 0.55)")
    sigma: float = Field(0.4, gt=0.0, lt=1.0, description="σ of the sufficient-decrease test, in (0, 1) (the paper: 0.4)")
    epsilon: float = Field(1e-4, gt=0.0, le=1.0, description="stop when the gradient norm falls below this (the paper: 1e-4)")
    mu0: Annotated[float, Field(gt=0.0, le=1e6)] | Literal["residual_norm"] = Field(
        0.75, description="initial damping μ0 (the paper: 0.75), or `residual_norm` to start from ‖f‖")
    max_iterations: int = Field(200, ge=1, le=10_000, description="iterations per station before giving up (e.g. 200)")


def _turned_guess(first_angle_deg: float, axis_point_mm: tuple[float, float, float]) -> list[float]:
    """The paper's station 1 turned about the vertical axis through ``axis_point_mm`` to another first angle."""
    a = math.radians(first_angle_deg - PAPER_STATION_1_DEG)
    x, y = PAPER_STATION_1_MM[0] - axis_point_mm[0], PAPER_STATION_1_MM[1] - axis_point_mm[1]
    return [round(math.cos(a) * x - math.sin(a) * y + axis_point_mm[0], 4),
            round(math.sin(a) * x + math.cos(a) * y + axis_point_mm[1], 4), PAPER_STATION_1_MM[2]]


class MultistationSolver(StrictModel):
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


class ErrorMotionBounds(StrictModel):
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


class EnvironmentUncertainty(StrictModel):
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
    mount_gradient_share: float = Field(0.5, ge=0.0, le=10.0, description=(
        "with a sensor reading the table: how far the temperature change of the region that carries the tracer may "
        "differ from the sensor's, as a share of the sensor's change over the run (1σ, e.g. 0.2; a motor under the "
        "table warms the mount faster than a sensor on the rim). Not stated: 0.5 is assumed and the budget says so; "
        "0: the sensor sits at the tracer's mount"))
    mount_temperature_k: float | None = Field(None, ge=0.0, le=20.0, description=(
        "with a second material probe on the tracer's mount (the environment's address's mount_thermometer=: a "
        "second iTHX, its probe 2; in simulation the bench's mount region): its 1σ, K (e.g. 0.1; its noise per reading "
        "is material_temperature_noise_k). Stated, the lengths are corrected with the mount's temperature, not the "
        "table's, so a gradient between the two is measured, not budgeted: no gradient line unless "
        "mount_gradient_share is stated (then against the mount probe's change)"))


class SphereMap(StrictModel):
    """The tracer's reference sphere as its certificate measured it: the polar trace of its radius about the
    tracer's vertical (a roundness certificate's table), which the lengths are corrected by; the budget then carries
    only the map's own uncertainty."""

    deviation_um: list[tuple[float, float]] = Field(min_length=8, max_length=3600, description=(
        "rows [azimuth_deg, deviation_um]: the sphere's radius less its mean at each azimuth, µm (a bump toward the "
        "beam positive: the tracer reads that direction short by it). Azimuth about the table's axis, counterclockwise "
        "seen from above, 0° pointing from the axis out through the tracer's centre (the base turns with the table, "
        "so this holds at every station); 0 ≤ azimuth < 360, increasing, no gap over 30° (linear between rows)"))
    expanded_uncertainty_um: float = Field(gt=0.0, le=10.0, description=(
        "the certificate's expanded uncertainty (k = 2) of those deviations, µm (e.g. 0.01)"))
    certificate: str = Field("", max_length=200, description="the certificate's number, for the budget's note")

    @model_validator(mode="after")
    def _trace(self) -> "SphereMap":
        az = [row[0] for row in self.deviation_um]
        for k, (a, d) in enumerate(self.deviation_um):
            if not (0.0 <= a < 360.0 and math.isfinite(d)) or abs(d) > 10.0:
                raise ValueError(f"deviation_um row {k + 1} [{a:g}, {d:g}]: the azimuth must lie in 0 ≤ a < 360 and the "
                                 "deviation within ±10 µm")
            if k and a <= az[k - 1]:
                raise ValueError(f"deviation_um row {k + 1}: azimuth {a:g}° does not increase (after {az[k - 1]:g}°); "
                                 "list the certificate's trace in order")
        gaps = np.diff(az + [az[0] + 360.0])
        if gaps.max() > 30.0:
            k = int(np.argmax(gaps))
            raise ValueError(f"deviation_um: {gaps[k]:g}° between {az[k]:g}° and the next row; a lobe of order 6 needs a "
                             "row every 30° at most: give the certificate's trace at that spacing or finer")
        return self

    def at(self, azimuth_rad: np.ndarray) -> np.ndarray:
        """The deviation, µm, at azimuths (rad, any range): linear between the rows, periodic."""
        az = np.array([row[0] for row in self.deviation_um])
        dev = np.array([row[1] for row in self.deviation_um])
        return np.asarray(np.interp(np.mod(np.degrees(azimuth_rad), 360.0), az, dev, period=360.0), float)


class MultistationUncertainty(StrictModel):
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
    laser_tracer_sphere_form_um: float = Field(0.0, ge=0.0, le=100.0, description=(
        "the form deviation of the tracer's reference sphere, µm, peak to valley (ISO 12181-1: the radius within ± half "
        "of it), from the tracer's specification or certificate (Type B, e.g. 0.05 for the LaserTRACER class). Fixed to "
        "the tracer's base, which turns with the table, it reads each point differently from each station: lobes about "
        "the tracer's vertical, σ = PV/(2√2) in every direction. Not stated: the specified class of the product "
        "metadata.instruments.laser_tracer.id names (an Etalon LaserTRACER's 0.05), said so in the budget; a tracer "
        "with no published figure: named in not_included"))
    laser_tracer_sphere_max_order: int = Field(6, ge=2, le=360, description=(
        "the highest lobe order (lobes per turn) of that form (e.g. 6)"))
    laser_tracer_sphere_map: SphereMap | None = Field(None, description=(
        "the reference sphere's map from its certificate: the lengths are corrected by it and the budget carries its "
        "uncertainty instead of the form (laser_tracer_sphere_form_um then unused)"))


class MultistationVerification(VerificationBase):
    __doc__ = VerificationBase.__doc__
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


class MultistationDurations(StrictModel):
    """What takes time besides the motions and settling: the planned and the simulated clock count it
    (a run on hardware takes what it takes)."""

    tracer_sample_s: float = Field(0.1, ge=0.0, le=600.0, description="time one laser-tracer sample takes (its "
                                                                       "integration and transfer), s")
    reference_tracer_s: float = Field(30.0, ge=0.0, le=3600.0, description="time to (re-)reference the tracer's beam, s")
    move_tracer_s: float = Field(900.0, ge=0.0, le=86400.0, description="time the operator takes to move the tracer to "
                                                                        "another mount and fix it, s")


class SecondMount(StrictModel):
    """Measure the whole plan again with the tracer moved to a second place on the table: the
    network estimator then separates the table's error motions from its rotation (one mount
    cannot). Put it at the same height as the first (the tilt about the line joining the mounts
    is invisible, and with mounts at different heights it would leak into the angles)."""

    first_station_guess_mm: Vec3 = Field(description="the tracer's centre at the first station once moved, CMM frame, "
                                                      "mm (nominal, for the solver's start; e.g. [-22.6, 128.0, 122.5])")


class LaserTracerMultistation(ProcedureBase):
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
