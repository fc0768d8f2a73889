"""The simulated bench: one geometric error model that every simulated instrument observes.

It holds the physical state (table angle, probe position, tracer reference) and the truth.
Instruments ask it where things really are; they add only their own reading noise.

Frames: the CMM frame is the reference; its origin lies on the table on the nominal axis.
A point p fixed to the table (table frame, mm) is, at commanded angle θ and actual angle θa,

    p_cmm = O + R_axis · ( c + δ(θ) + R(εx(θ), εy(θ)) · (Rz(θa)·p − c) )

with O the axis point, R_axis the axis squareness to the CMM table, c the tilt centre on the
axis, δ = (δx, δy, δz) and εx, εy the error motions (see :mod:`simulators.scenario`).
"""

from __future__ import annotations

import hashlib
import math
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Iterator

import numpy as np

from rtcal.solvers.air import ciddor_n
from rtcal.clock import Clock, VirtualClock
from rtcal.solvers.harmonics import evaluate
from rtcal.units import arcsec_to_rad, rad_to_arcsec, um_to_mm
from simulators.controllers import controller
from simulators.faults import FaultInjector
from simulators.scenario import Scenario


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class StageMove:
    """Truth of one table move: commanded and actual angle (rad), approach direction."""

    commanded_rad: float
    actual_rad: float
    direction: int


@dataclass
class Truth:
    """What really happened, for tests and for a simulated run's results; never for solvers."""

    stage_moves: list[StageMove] = field(default_factory=list)


class Bench:
    """The physical state of a simulated bench, built from a :class:`Scenario`."""

    def __init__(self, scenario: Scenario, clock: Clock | None = None, seed: int | None = None, generation: int = 0):
        self.scenario = scenario
        self.clock = clock if clock is not None else VirtualClock()
        self.seed = scenario.seed if seed is None else seed
        self.generation = generation  # 0 for a run's first start, +1 for each resume: fresh draws
        self._rngs: dict[str, np.random.Generator] = {}
        st = scenario.stage
        self._eps_z = [h.to_rad() for h in st.positioning_error]
        self._dx = [h.to_mm() for h in st.radial_motion_x]
        self._dy = [h.to_mm() for h in st.radial_motion_y]
        self._dz = [h.to_mm() for h in st.axial_motion]
        self._ex = [h.to_rad() for h in st.tilt_motion_x]
        self._ey = [h.to_rad() for h in st.tilt_motion_y]
        self.axis_point_mm = np.array(st.axis_point_mm, dtype=float)
        self.axis_rotation = rot_y(arcsec_to_rad(st.axis_tilt_y_arcsec)) @ rot_x(arcsec_to_rad(st.axis_tilt_x_arcsec))
        self.tilt_center = np.array([0.0, 0.0, st.tilt_center_height_mm])
        cmm = scenario.cmm
        sx, sy, sz = (p * 1e-6 for p in cmm.scale_error_ppm)
        self.cmm_matrix = np.array(
            [
                [1.0 + sx, 0.0, 0.0],
                [arcsec_to_rad(cmm.squareness_xy_arcsec), 1.0 + sy, 0.0],
                [arcsec_to_rad(cmm.squareness_xz_arcsec), arcsec_to_rad(cmm.squareness_yz_arcsec), 1.0 + sz],
            ]
        )
        self.tracer_mount = 0
        self.tracer_in_table_mm = self._mount_point(0)
        enc = scenario.encoder
        self._graduation = [h.to_rad() for h in enc.graduation_error]
        poly = scenario.polygon
        errors = np.array(poly.face_errors_arcsec or [0.0] * poly.faces, dtype=float)
        self.face_errors_arcsec = errors - errors.mean()  # a polygon closes: Σ = 0
        cert_rng = self.persistent_rng("certificate")  # one polygon, one certificate
        self.face_certificate_arcsec = self.face_errors_arcsec + poly.certificate_uncertainty_arcsec * cert_rng.standard_normal(poly.faces)
        self.polygon_pitch_rad = 2 * math.pi / poly.faces
        self.polygon_rotation_rad = 0.0
        st_ = scenario.stepper
        self.step_rad = 2 * math.pi / (st_.steps_per_revolution * st_.worm_ratio) if st_.steps_per_revolution else 0.0
        comp = scenario.stage.compensation
        # the table as the controller applies it: read and applied as its manual says, apart from
        # rtcal's writer (simulators/controllers.py)
        self.compensation = (controller(comp.format, comp.text or "", comp.file or "compensation", comp.backlash_deg,
                                        comp.detection_unit_deg, comp.bidirectional) if comp is not None else None)
        # state
        self.commanded_rad = 0.0  # where the motor was sent (the user's command plus any compensation)
        self.target_rad = 0.0  # the user's command, in whole steps: what the controller shows, moves start from
        self.actual_rad = 0.0
        self.motor_rad = 0.0  # an external controller's motor position (follow_motor), unquantised
        self.last_direction = +1
        self.probe_target_mm = np.zeros(3)
        self.first_reading_s: float | None = None  # when the run's first reading was taken (the profiles' time 0)
        self.beam_broken = False  # the tracer's beam was interrupted since its last reference
        self.emergency_stop = False  # pressed: no motion until an operator releases it
        self.artefacts: dict[str, np.ndarray] = {}  # what an operator mounted on the table, at its point of the table
        self.truth = Truth()
        self.faults = FaultInjector(scenario.faults, self.rng)
        self.sphere_mounted = 0  # which of the machine's sphere set-ups is on its table (mount_sphere)
        self.machine: Any = None  # the five-axis machine of a scenario's `machine:` (simulators/machine_tool.py, made on first use)

    # -- randomness: one stream per named consumer, so interleaving never changes a draw
    @staticmethod
    def stream_key(name: str) -> int:
        """A stable 64-bit key from the whole name (distinct names, distinct streams)."""
        return int.from_bytes(hashlib.blake2b(name.encode(), digest_size=8).digest(), "little")

    def rng(self, name: str) -> np.random.Generator:
        if name not in self._rngs:
            key = self.stream_key(name)
            self._rngs[name] = np.random.default_rng([self.seed, key] + ([self.generation] if self.generation else []))
        return self._rngs[name]

    def persistent_rng(self, name: str) -> np.random.Generator:
        """Draws of physical facts that a software restart does not change (how a polygon sits)."""
        return np.random.default_rng([self.seed, self.stream_key(name)])

    # -- stage
    def positioning_error_rad(self, commanded_rad, direction: int = +1):
        """Systematic εz at the commanded angle (rad), with the reversal for a negative approach."""
        value = evaluate(self._eps_z, commanded_rad)
        if direction < 0:
            value = value - arcsec_to_rad(self.scenario.stage.reversal_arcsec)
        return value

    def quantise_command(self, commanded_rad: float) -> float:
        """The angle an open-loop stepper really commands: a whole number of steps."""
        return round(commanded_rad / self.step_rad) * self.step_rad if self.step_rad else float(commanded_rad)

    def motor_command_rad(self, commanded_rad: float, direction: int) -> float:
        """Where the controller sends the motor for a commanded angle: plus its compensation table's
        trim for the approach direction (interpolated, as the CNC does), in whole steps."""
        trim = 0.0 if self.compensation is None else math.radians(self.compensation.trim_deg(math.degrees(commanded_rad), direction))
        return self.quantise_command(commanded_rad + trim)

    def systematic_actual_rad(self, commanded_rad: float, direction: int) -> float:
        """The table's angle for a command approached in ``direction``, without repeatability: the
        motor's position plus εz there (the physics follows the motor, not the user's number)."""
        motor = commanded_rad + (0.0 if self.compensation is None else
                                 math.radians(self.compensation.trim_deg(math.degrees(commanded_rad), direction)))
        return self.quantise_command(motor) + float(self.positioning_error_rad(motor, direction))

    def move_stage(self, commanded_rad: float, direction: int) -> float:
        """Put the table at a commanded angle approached in ``direction``; returns the actual angle."""
        noise = arcsec_to_rad(self.scenario.stage.repeatability_arcsec) * self.rng("stage").standard_normal()
        self.last_direction = +1 if direction >= 0 else -1
        self.commanded_rad = self.motor_command_rad(commanded_rad, self.last_direction)
        self.target_rad = self.quantise_command(commanded_rad)
        self.actual_rad = self.systematic_actual_rad(commanded_rad, self.last_direction) + noise
        self.truth.stage_moves.append(StageMove(self.quantise_command(commanded_rad), self.actual_rad, self.last_direction))
        return self.actual_rad

    def follow_motor(self, motor_deg: float, command_deg: float) -> None:
        """The table driven by an external controller (LinuxCNC): it turns with the motor, whose
        position is the controller's compensated motor command (``joint.N.motor-pos-cmd``), in
        whole steps of the bench's stepper; its εz and reversal are those of the motor's angle and
        its direction of motion (the last change of the motor position), plus the repeatability
        drawn at every new position. ``command_deg`` (the uncompensated joint command) is what the
        controller shows. The controller applies the compensation: the bench holds none of its own."""
        motor = math.radians(motor_deg)
        if motor != self.motor_rad:
            self.last_direction = 1 if motor > self.motor_rad else -1
        self.motor_rad = motor
        noise = arcsec_to_rad(self.scenario.stage.repeatability_arcsec) * self.rng("stage").standard_normal()
        self.commanded_rad = self.quantise_command(motor)
        self.target_rad = math.radians(command_deg)
        self.actual_rad = self.commanded_rad + float(self.positioning_error_rad(motor, self.last_direction)) + noise

    def error_motions(self, commanded_rad: float) -> tuple[np.ndarray, float, float]:
        """(δx, δy, δz) in mm and (εx, εy) in rad at the commanded angle."""
        delta = np.array([evaluate(self._dx, commanded_rad), evaluate(self._dy, commanded_rad), evaluate(self._dz, commanded_rad)])
        return delta, float(evaluate(self._ex, commanded_rad)), float(evaluate(self._ey, commanded_rad))

    def table_point_in_axis_frame(self, p_table_mm: np.ndarray, growth: float | None = None) -> np.ndarray:
        """A table point in the housing frame (origin at the axis point, z along the axis); ``growth``: the
        relative radial growth of the region it sits in (default: the table's)."""
        delta, ex, ey = self.error_motions(self.commanded_rad)
        c = self.tilt_center
        p = np.asarray(p_table_mm, dtype=float)
        growth = self.table_growth() if growth is None else growth
        if growth:  # the table top and what is mounted on it grow radially about the axis
            p = np.array([p[0] * (1.0 + growth), p[1] * (1.0 + growth), p[2]])
        rotated = rot_z(self.actual_rad) @ p
        return c + delta + rot_y(ey) @ rot_x(ex) @ (rotated - c)

    def table_point_in_cmm(self, p_table_mm: np.ndarray, growth: float | None = None) -> np.ndarray:
        return self.axis_point_mm + self.axis_rotation @ self.table_point_in_axis_frame(p_table_mm, growth)

    # -- CMM and tracer
    def move_probe(self, target_mm: np.ndarray) -> None:
        self.probe_target_mm = np.asarray(target_mm, dtype=float).copy()

    def reflector_mm(self) -> np.ndarray:
        """Where the cat-eye really is: the commanded target through the CMM's geometric errors."""
        actual = self.cmm_matrix @ self.probe_target_mm
        for term in self.scenario.cmm.error_field:  # smooth errors beyond the affine model
            d = np.asarray(term.direction, float)
            d = d / (np.linalg.norm(d) or 1.0)
            actual["xyz".index(term.axis)] += um_to_mm(term.amplitude_um) * math.sin(
                2 * math.pi * float(d @ self.probe_target_mm) / term.wavelength_mm + math.radians(term.phase_deg))
        return actual

    def tracer_center_mm(self) -> np.ndarray:
        """The tracer's reference centre: on the table, grown with the temperature of the region that carries it."""
        return self.table_point_in_cmm(self.tracer_in_table_mm, self.mount_growth())

    def tracer_length_mm(self) -> float:
        """True distance from the tracer's reference centre to the reflector."""
        return float(np.linalg.norm(self.reflector_mm() - self.tracer_center_mm()))

    def sphere_deviation_mm(self) -> float:
        """The reference sphere's radius deviation where the beam touches it: the sphere is fixed to the tracer's base,
        which turns with the table, so the beam's azimuth in the base frame is its azimuth in the housing frame less
        the table's angle (the tilts, µrad, left out)."""
        lobes = self.scenario.laser_tracer.sphere_form
        if not lobes:
            return 0.0
        beam = self.axis_rotation.T @ (self.reflector_mm() - self.tracer_center_mm())
        psi = math.atan2(beam[1], beam[0]) - self.actual_rad
        return sum(um_to_mm(lobe.amplitude_um) * math.cos(lobe.order * psi + math.radians(lobe.phase_deg)) for lobe in lobes)

    def _mount_point(self, index: int) -> np.ndarray:
        lt = self.scenario.laser_tracer
        mount = lt.mount if index == 0 else lt.second_mount
        az = math.radians(mount.azimuth_deg)
        return np.array([mount.radius_mm * math.cos(az), mount.radius_mm * math.sin(az), mount.height_mm])

    def mount_tracer(self, index: int) -> None:
        """The operator moves the tracer to mount ``index`` (0: ``mount``, 1: ``second_mount``); its
        beam must be referenced again."""
        if index != self.tracer_mount:
            self.tracer_mount = index
            self.tracer_in_table_mm = self._mount_point(index)
            self.beam_broken = True

    # -- the table as a simulation sees it (simulators/facade.py: SimBench)
    def now_s(self) -> float:
        return self.clock.now_s()

    def table_angle_deg(self) -> float:
        return math.degrees(self.actual_rad)

    def commanded_angle_deg(self) -> float:
        return math.degrees(self.target_rad)

    def table_tilt_arcsec(self) -> tuple[float, float]:
        """The table's tilt about the housing's x and y axes now: the axis's tilt and its tilt error motion, arcsec."""
        st = self.scenario.stage
        _, ex, ey = self.error_motions(self.commanded_rad)
        return st.axis_tilt_x_arcsec + math.degrees(ex) * 3600.0, st.axis_tilt_y_arcsec + math.degrees(ey) * 3600.0

    def table_point_mm(self, on_table_mm: Any) -> np.ndarray:
        """Where a point of the table (its own frame, mm) is now, in the housing frame."""
        return self.table_point_in_axis_frame(np.asarray(on_table_mm, dtype=float))

    @contextmanager
    def systematic_state(self, commanded_deg: float, direction: int) -> Iterator[float]:
        """The bench with its table at ``commanded_deg`` approached in ``direction``, without repeatability (what a
        noise-free instrument would read there); yields εz there, arcsec. The present state is restored after."""
        cmd = self.quantise_command(math.radians(commanded_deg))
        actual = self.systematic_actual_rad(cmd, int(direction))
        with self.stage_state(self.motor_command_rad(cmd, int(direction)), actual):
            yield rad_to_arcsec(actual - math.radians(commanded_deg))

    def true_table_point_mm(self, on_table_mm: Any, commanded_deg: float, direction: int) -> np.ndarray:
        """The table point without noise, the table at ``commanded_deg`` approached in ``direction``."""
        with self.systematic_state(commanded_deg, direction):
            return self.table_point_mm(on_table_mm)

    def true_positioning_error_arcsec(self, commanded_deg: float, direction: int) -> float:
        with self.systematic_state(commanded_deg, direction) as error_arcsec:
            return error_arcsec

    def true_encoder_error_arcsec(self, commanded_deg: float, direction: int) -> float:
        """What a noise-free encoder misreads there (Abbe shift/rE, eccentricity, graduation), arcsec."""
        with self.systematic_state(commanded_deg, direction):
            return rad_to_arcsec(self.encoder_error_rad())

    # -- what an operator mounts on the table (a test ball, a sphere): its position turns with the table
    def mount_artefact(self, name: str, on_table_mm: tuple[float, float, float] | list[float]) -> None:
        """The operator mounts the artefact ``name`` at a point of the table (its own frame, mm): from now on
        :meth:`artefact_mm` says where the table's motion carries it."""
        where = np.asarray(on_table_mm, dtype=float)
        if where.shape != (3,) or not np.all(np.isfinite(where)) or np.any(np.abs(where) > 1e4):
            raise ValueError(f"{name}: a point on the table is three finite coordinates within 10 m, not {on_table_mm!r}")
        self.artefacts[str(name)] = where

    def artefact_mm(self, name: str) -> np.ndarray | None:
        """Where the artefact ``name`` is now, in the housing frame (origin on the axis, z along it), mm; None:
        nothing of that name is mounted."""
        where = self.artefacts.get(name)
        return None if where is None else self.table_point_in_axis_frame(where)

    def release_emergency_stop(self) -> None:
        """The operator releases the emergency stop (the run may move again)."""
        self.emergency_stop = False

    def mount_sphere(self, index: int) -> None:
        """The operator sets the R-test's sphere up at the scenario's position ``index`` (machine.sphere.positions_mm)."""
        spec = self.scenario.machine
        n = 0 if spec is None else len(spec.sphere.positions_mm)
        if not (isinstance(index, int) and 0 <= index < n):
            raise ValueError(f"sphere position {index!r}: the scenario sets up {n}")
        self.sphere_mounted = index
        if self.machine is not None:
            self.machine.mounted = index

    OPERATOR_ACTIONS = ("reseat_polygon", "mount_tracer", "mount_artefact", "polygon_certificate_arcsec",
                        "release_emergency_stop", "mount_sphere")
    """What the simulated operator of `rtcal sim serve` does on request (``DO <name> <JSON arguments>``): the
    bench's hands as a method's operator step uses them, nothing else."""

    # -- air and material
    def reading(self) -> None:
        """An instrument takes a reading now: the first one starts the profiles' time."""
        if self.first_reading_s is None:
            self.first_reading_s = self.clock.now_s()

    def environment(self) -> tuple[float, float, float, float]:
        """(air °C, air Pa, % RH, material °C) at the clock's present time: start + drift + profile."""
        e = self.scenario.environment
        now = self.clock.now_s()
        h = now / 3600.0
        dt, dp, dh, dm = e.offsets(None if self.first_reading_s is None else now - self.first_reading_s)
        return (e.air_temperature_c + e.air_temperature_drift_k_per_h * h + dt,
                e.air_pressure_pa + e.air_pressure_drift_pa_per_h * h + dp,
                min(max(e.humidity_pct + e.humidity_drift_pct_per_h * h + dh, 0.0), 100.0),
                e.material_temperature_c + e.material_temperature_drift_k_per_h * h + dm)

    def table_growth(self) -> float:
        """The table's relative radial growth about the axis now: α·(material temperature − 20 °C)."""
        alpha = self.scenario.stage.thermal_expansion_ppm_per_k
        return alpha * 1e-6 * (self.environment()[3] - 20.0) if alpha else 0.0

    def mount_temperature_c(self) -> float:
        """The temperature of the region that carries the tracer now: the table's, or with a gradient its own (the
        table's start, drifting at ``mount_temperature_drift_k_per_h``, plus the table's profile)."""
        e = self.scenario.environment
        if e.mount_temperature_drift_k_per_h is None:
            return self.environment()[3]
        now = self.clock.now_s()
        dm = e.offsets(None if self.first_reading_s is None else now - self.first_reading_s)[3]
        return e.material_temperature_c + e.mount_temperature_drift_k_per_h * now / 3600.0 + dm

    def mount_growth(self) -> float:
        """The relative radial growth of the region that carries the tracer: α·(its temperature − 20 °C)."""
        alpha = self.scenario.stage.thermal_expansion_ppm_per_k
        if self.scenario.environment.mount_temperature_drift_k_per_h is None or not alpha:
            return self.table_growth()
        return alpha * 1e-6 * (self.mount_temperature_c() - 20.0)

    def air_index(self) -> float:
        """The refractive index of the air the tracer's beam runs through, now (Ciddor, He-Ne)."""
        t, p, rh, _ = self.environment()
        return ciddor_n(t, p, rh)

    # -- shaft, encoder, polygon (seed 001)
    def shaft_y_mm(self, below_tilt_center_mm: float) -> float:
        """Y displacement of the shaft at a height below the tilt centre: δy + εx·below."""
        delta, ex, _ = self.error_motions(self.commanded_rad)
        return float(delta[1] + ex * below_tilt_center_mm)

    def grating_shift_mm(self) -> float:
        """Tangential (Y) shift of the grating under the read head: δy + Zs·εx + eccentricity."""
        enc = self.scenario.encoder
        ecc = um_to_mm(enc.eccentricity_um) * math.sin(self.actual_rad + math.radians(enc.eccentricity_phase_deg))
        return self.shaft_y_mm(enc.grating_offset_mm) + ecc

    def encoder_true_rad(self) -> float:
        """What a noise-free encoder reads: actual angle + Abbe shift/rE + graduation error."""
        return self.actual_rad + self.encoder_error_rad()

    def encoder_error_rad(self) -> float:
        shift = self.grating_shift_mm() / self.scenario.encoder.radius_mm
        return float(shift + evaluate(self._graduation, self.actual_rad))

    def reseat_polygon(self, offset_deg: float) -> None:
        """The operator turns the polygon on the table so faces come in front at offset + k·pitch.

        Each seating lands with its own error, the same whenever that seating is (re)visited
        after a software restart: the polygon did not move because the program died."""
        err = arcsec_to_rad(self.scenario.polygon.seating_error_arcsec) * self.persistent_rng(f"seating {offset_deg!r}").standard_normal()
        self.polygon_rotation_rad = math.radians(offset_deg) + err

    def polygon_certificate_arcsec(self) -> list[float]:
        """The simulated polygon's calibration certificate (its face errors, arcsec), as the operator hands it over."""
        return [float(v) for v in self.face_certificate_arcsec]

    def autocollimator_true(self) -> tuple[float, int]:
        """(deflection about the axis, rad; index of the face in front) for a noise-free autocollimator."""
        rel = self.actual_rad - self.polygon_rotation_rad
        k = round(rel / self.polygon_pitch_rad)
        face = k % self.scenario.polygon.faces
        x = rel - k * self.polygon_pitch_rad + arcsec_to_rad(self.face_errors_arcsec[face])
        return float(x), int(face)

    # -- truth summaries
    @contextmanager
    def stage_state(self, commanded_rad: float, actual_rad: float) -> Iterator[None]:
        """Evaluate physics at another stage state, restoring the present one afterwards."""
        saved = self.commanded_rad, self.actual_rad
        self.commanded_rad, self.actual_rad = commanded_rad, actual_rad
        try:
            yield
        finally:
            self.commanded_rad, self.actual_rad = saved
