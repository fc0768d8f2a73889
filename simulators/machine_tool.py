"""The simulated five-axis machine tool with a trunnion table (A about X carrying C, LinuxCNC's
xyzac-trt-kins) and the R-test's sphere and nest: one physical model that the simulated machine
(its joints) and the three simulated indicators (the nest) read, on the bench's clock and random
streams (:class:`simulators.bench.Bench`). docs/rtest.md states the frames and signs; the solver
(rtcal/solvers/rtest*.py) is never asked: this is an independent statement of the same physics.

- The table: a table point p (machine coordinates at A = C = 0) is at a_pt + Ra·(c_pt + Rc·(p − c_pt)
  − a_pt), Rc the rotation by the actual C angle about C's true line, Ra by A about A's true line,
  each built from the scenario's location errors as rotations of the nominal directions (Qa = Rz(C0A)·
  Ry(B0A) carries +X onto A's direction; Qc = Ry(B0C + B0A)·Rx(A0C) carries +Z onto C's).
- C's actual angle: the command + ECC(command) (harmonics), less the reversal when approached negative.
- The nest's zero point: M·J (the linear axes' scales and squarenesses) + the nest's offset and its
  zero's true error + a random error per move; the sphere drifts relative to it.
- Each sensor: a plunger along its true axis (the nominal direction turned by a random small rotation)
  with a flat face (tilted to the plunger by a random small angle) of finite radius; the reading is where
  the face touches the sphere — exact contact geometry, the face's rim beyond it — with the sphere's
  radius at the contact point (its form, a smooth random field of degrees 2–6 scaled to the
  certificate's peak to valley). Zero: the sphere's centre at the nest's true zero point (mastered).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Mapping

import numpy as np

from rtcal.solvers.harmonics import evaluate
from rtcal.units import arcsec_to_rad, rad_to_arcsec
from simulators.bench import rot_x, rot_y, rot_z

if TYPE_CHECKING:
    from simulators.bench import Bench

FORM_DEGREES = (2, 6)
FORM_TERMS = 16  # zonal terms per degree (random directions): an isotropic field with the degrees' covariance
ENGAGED_MM = 10.0  # closer than this, the sphere is among the sensors: off centre by more than the capture, it strikes


def _axis_rotation(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle_rad) * K + (1 - math.cos(angle_rad)) * K @ K


def _tilted(v: np.ndarray, sigma_rad: float, rng: np.random.Generator) -> np.ndarray:
    """``v`` (unit) turned by a random small rotation about an axis square to it (each component 1σ)."""
    a = np.cross(v, [1.0, 0.0, 0.0] if abs(v[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(v, a)
    w = sigma_rad * (rng.standard_normal() * a + rng.standard_normal() * b)
    angle = float(np.linalg.norm(w))
    return v if angle == 0 else _axis_rotation(w, angle) @ v


def _rodrigues(points: np.ndarray, point: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Points (K, 3) each turned by its angle about the line through ``point`` along the unit ``axis``."""
    v = points - point
    cos, sin = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return np.asarray(point + v * cos + np.cross(axis, v) * sin + np.outer(v @ axis, axis) * (1 - cos))


def _legendre(l_max: int, x: np.ndarray) -> list[np.ndarray]:
    P = [np.ones_like(x), x]
    for n in range(1, l_max):
        P.append(((2 * n + 1) * x * P[n] - n * P[n - 1]) / (n + 1))
    return P


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z * z)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


class SphereForm:
    """The radius's deviation over a sphere (µm) as a smooth random field: Σ_l Σ_r c_lr·P_l(v·w_lr) over
    degrees 2–6, rescaled so its peak to valley is ``form_um``."""

    def __init__(self, form_um: float, rng: np.random.Generator):
        lo, hi = FORM_DEGREES
        self.terms: list[tuple[int, np.ndarray, np.ndarray]] = []
        for degree in range(lo, hi + 1):
            dirs = rng.standard_normal((FORM_TERMS, 3))
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
            self.terms.append((degree, dirs, rng.standard_normal(FORM_TERMS) * math.sqrt((2 * degree + 1) / FORM_TERMS)))
        if form_um > 0:
            sample = self.raw(_fibonacci_sphere(4000))
            self.scale = form_um / float(sample.max() - sample.min())
        else:
            self.scale = 0.0

    def raw(self, v: np.ndarray) -> np.ndarray:
        v = np.atleast_2d(v)
        out = np.zeros(len(v))
        for degree, dirs, coef in self.terms:
            out += _legendre(degree, v @ dirs.T)[degree] @ coef
        return out

    def at_um(self, v: np.ndarray) -> float:
        """The radius's deviation at direction ``v`` (sphere frame), µm."""
        return float(self.scale * self.raw(np.asarray(v, float) / np.linalg.norm(v))[0]) if self.scale else 0.0


class MachineModel:
    """The machine's physical state and truth, built once per bench from its scenario's ``machine``."""

    def __init__(self, bench: "Bench"):
        spec = bench.scenario.machine
        if spec is None:
            raise ValueError("the scenario has no `machine:` (a five-axis machine with a trunnion table)")
        self.bench, self.spec = bench, spec
        le = spec.location_errors
        xa, ya, za = spec.kinematics.a_point_mm
        xc, yc, zc = spec.kinematics.c_point_mm
        self.Qa = rot_z(arcsec_to_rad(le.C0A_arcsec)) @ rot_y(arcsec_to_rad(le.B0A_arcsec))
        self.a_dir = self.Qa @ np.array([1.0, 0.0, 0.0])
        self.a_point = np.array([xa, ya + le.Y0A_um * 1e-3, za + le.Z0A_um * 1e-3])
        self.Qc = rot_y(arcsec_to_rad(le.B0C_arcsec + le.B0A_arcsec)) @ rot_x(arcsec_to_rad(le.A0C_arcsec))
        self.c_dir = self.Qc @ np.array([0.0, 0.0, 1.0])
        a_y_at_xc = self.a_point[1] + (xc - xa) * self.a_dir[1] / self.a_dir[0]
        self.c_point = np.array([xc + le.X0C_um * 1e-3, a_y_at_xc + (yc - ya) + le.Y0C_um * 1e-3, zc])
        self._ecc = [h.to_rad() for h in spec.c_positioning_error]
        la = spec.linear_axes
        sx, sy, sz = (p * 1e-6 for p in la.scale_error_ppm)
        self.linear_matrix = np.array([[1 + sx, 0.0, 0.0],
                                       [arcsec_to_rad(la.squareness_xy_arcsec), 1 + sy, 0.0],
                                       [arcsec_to_rad(la.squareness_xz_arcsec), arcsec_to_rad(la.squareness_yz_arcsec), 1 + sz]])
        sph = spec.sphere
        self.assumed_spheres_mm = np.array(sph.positions_mm, float)
        if sph.setup_offsets_um:
            offsets = np.array(sph.setup_offsets_um, float) * 1e-3
        else:
            offsets = sph.setup_sigma_um * 1e-3 * bench.persistent_rng("sphere set-up").standard_normal((len(sph.positions_mm), 3))
        self.spheres_mm = self.assumed_spheres_mm + offsets
        self.forms = [SphereForm(sph.form_um, bench.persistent_rng(f"sphere form {j}")) for j in range(len(sph.positions_mm))]
        nest = spec.nest
        nominal = np.array(nest.directions, float)
        self.nominal_directions = nominal / np.linalg.norm(nominal, axis=1, keepdims=True)
        rng = bench.persistent_rng("nest")
        self.sensor_axes = np.array([_tilted(u, math.radians(nest.direction_error_deg), rng) for u in self.nominal_directions])
        # each face's normal, pointing from the face to the sphere: against the plunger's axis, tilted
        self.face_normals = np.array([-_tilted(u, math.radians(nest.face_tilt_deg), rng) for u in self.sensor_axes])
        self.nest_zero_mm = np.array(nest.offset_mm, float) + np.array(nest.zero_error_um, float) * 1e-3
        # state
        self.joints: dict[str, float] = {a: 0.0 for a in ("x", "y", "z", "a", "c")}
        self.c_direction = 1
        self.random_mm = np.zeros(3)  # this move's random positioning error of the linear axes
        self.mounted = int(getattr(bench, "sphere_mounted", 0))  # which sphere set-up is on the table
        self.collision = ""  # where an external control (follow_joints) first drove the sphere into the nest

    # -- the table ---------------------------------------------------------------------------------
    def c_actual_rad(self, c_deg: float, direction: int) -> float:
        """C's actual angle for a command approached in ``direction``: + ECC, − the reversal if negative."""
        c = math.radians(c_deg)
        ecc = float(evaluate(self._ecc, c)) if self._ecc else 0.0
        if direction < 0:
            ecc -= arcsec_to_rad(self.spec.c_reversal_arcsec)
        return c + ecc

    def table_rotation(self, joints: Mapping[str, float], direction: int) -> tuple[np.ndarray, np.ndarray]:
        """(Ra·Rc, Ra·(c_pt − a_pt) + a_pt − Ra·Rc·c_pt): the table's rigid motion at the joints."""
        Rc = self.Qc @ rot_z(self.c_actual_rad(joints["c"], direction)) @ self.Qc.T
        Ra = self.Qa @ rot_x(math.radians(joints["a"])) @ self.Qa.T
        R = Ra @ Rc
        t = Ra @ (self.c_point - Rc @ self.c_point - self.a_point) + self.a_point
        return R, t

    def sphere_centre_mm(self, joints: Mapping[str, float] | None = None, direction: int | None = None) -> np.ndarray:
        j = self.joints if joints is None else joints
        R, t = self.table_rotation(j, self.c_direction if direction is None else direction)
        return np.asarray(R @ self.spheres_mm[self.mounted] + t)

    def nest_zero_point_mm(self, joints: Mapping[str, float] | None = None, random_mm: np.ndarray | None = None) -> np.ndarray:
        j = self.joints if joints is None else joints
        xyz = np.array([j["x"], j["y"], j["z"]])
        return np.asarray(self.linear_matrix @ xyz + self.nest_zero_mm + (self.random_mm if random_mm is None else random_mm))

    def drift_mm(self) -> np.ndarray:
        start = self.bench.first_reading_s
        if start is None:
            return np.zeros(3)
        d = self.spec.drift
        return np.array(d.amplitude_um, float) * 1e-3 * (1.0 - math.exp(-(self.bench.clock.now_s() - start) / d.time_constant_s))

    def displacement_mm(self) -> np.ndarray:
        """The sphere centre less the nest's zero point now (drift included), machine frame."""
        return self.sphere_centre_mm() + self.drift_mm() - self.nest_zero_point_mm()

    # -- motion --------------------------------------------------------------------------------------
    def strikes(self, joints: np.ndarray, direction: np.ndarray) -> int:
        """The first row of ``joints`` (K, 5: x, y, z, a, c) at which the sphere strikes the nest's body, or −1:
        within the capture it is measured; off the nest's zero point by more, and closer than ENGAGED_MM, it
        strikes a sensor — unless it lies below the nest's opening (the nest coming down onto it)."""
        J = np.atleast_2d(np.asarray(joints, float))
        c = np.radians(J[:, 4]) - np.where(np.asarray(direction) < 0, arcsec_to_rad(self.spec.c_reversal_arcsec), 0.0)
        if self._ecc:
            c = c + np.asarray(evaluate(self._ecc, np.radians(J[:, 4])), float)
        p = np.broadcast_to(self.spheres_mm[self.mounted], (len(J), 3))
        p = _rodrigues(p, self.c_point, self.c_dir, c)
        p = _rodrigues(p, self.a_point, self.a_dir, np.radians(J[:, 3]))
        d = p - (J[:, :3] @ self.linear_matrix.T + self.nest_zero_mm + self.random_mm)
        distance = np.linalg.norm(d, axis=1)
        capture = self.spec.nest.capture_mm
        below = (np.linalg.norm(d[:, :2], axis=1) <= capture) & (d[:, 2] < 0)
        bad = (distance > capture) & (distance <= ENGAGED_MM) & ~below
        return int(np.argmax(bad)) if bad.any() else -1

    def struck(self, joints: Mapping[str, float]) -> str:
        """Why the sphere struck the nest at ``joints`` (the fault's words)."""
        return (f"the sphere struck the nest at X {joints['x']:.3f} Y {joints['y']:.3f} Z {joints['z']:.3f} "
                f"A {joints['a']:.3f} C {joints['c']:.3f}: off the nest's zero point by more than its "
                f"{self.spec.nest.capture_mm:g} mm capture — a move without the sphere path between the poses?")

    def arrive(self, joints: Mapping[str, float], rng: np.random.Generator, direction: int | None = None) -> None:
        """The machine stands at ``joints``, C having last moved in ``direction`` (None: as from here)."""
        if direction is not None:
            self.c_direction = direction
        elif joints["c"] != self.joints["c"]:
            self.c_direction = 1 if joints["c"] > self.joints["c"] else -1
        self.joints = dict(joints)
        self.random_mm = self.spec.linear_axes.repeatability_um * 1e-3 * rng.standard_normal(3)

    def follow_joints(self, joints: Mapping[str, float], rng: np.random.Generator) -> None:
        """The machine driven by an external control (LinuxCNC's motor commands, streamed as they change):
        its joints are there now, C last moved the way it turned, a new random error of the linear axes
        at each new position (the repeatability, drawn as a real machine's arrives). A sphere driven into
        the nest is remembered (``collision``, the first) — a real nest would be wrecked: the hub says so."""
        direction = None if joints["c"] == self.joints["c"] else (1 if joints["c"] > self.joints["c"] else -1)
        self.arrive(joints, rng, direction)
        if not self.collision:
            row = np.array([[joints[a] for a in ("x", "y", "z", "a", "c")]])
            if self.strikes(row, np.array([self.c_direction])) >= 0:
                self.collision = self.struck(joints)

    # -- the nest -----------------------------------------------------------------------------------
    def sensor_mm(self, index: int) -> float:
        """Sensor ``index``'s plunger position (mm, pushed in positive), exact contact: the flat face where
        the contact lies on it, its rim otherwise; the stroke's end where the sphere does not reach it."""
        nest = self.spec.nest
        d = self.displacement_mm()
        u, f = self.sensor_axes[index], self.face_normals[index]
        rho = self.spec.sphere.radius_mm
        R, _ = self.table_rotation(self.joints, self.c_direction)
        form = self.forms[self.mounted]
        radius = rho + form.at_um(R.T @ -f) * 1e-3
        face0 = -rho * f  # the face's centre at the zero reading: on the master sphere at the zero point
        t = (float(f @ (d - face0)) - radius) / float(f @ u)
        contact = d - radius * f - (face0 + t * u)
        across = contact - float(contact @ f) * f
        reach = float(np.linalg.norm(across))
        if reach > nest.flat_radius_mm:  # the rim touches: |d − face(t) − r·e| = radius, the larger root
            e = across / reach
            w = d - face0 - nest.flat_radius_mm * e
            b = float(u @ w)
            disc = b * b - float(w @ w) + radius * radius
            t = b + math.sqrt(disc) if disc >= 0 else -nest.stroke_mm
        return float(min(max(t, -nest.stroke_mm), nest.stroke_mm))

    # -- truth ----------------------------------------------------------------------------------------
    def truth_location_errors(self) -> dict[str, float]:
        """The eight location errors of the true lines (µm, arcsec), by ISO 230-7's definitions
        (docs/rtest.md) — what a simulated run's truth states."""
        xa, ya, za = self.spec.kinematics.a_point_mm
        xc, yc, zc = self.spec.kinematics.c_point_mm
        na, nc = self.a_dir, self.c_dir
        b0a = math.atan2(-na[2], na[0])
        a_y_at_xc = self.a_point[1] + (xc - self.a_point[0]) * na[1] / na[0]
        return {"X0C_um": (self.c_point[0] - xc) * 1e3,
                "Y0C_um": (self.c_point[1] - a_y_at_xc - (yc - ya)) * 1e3,
                "A0C_arcsec": rad_to_arcsec(-math.atan2(nc[1], nc[2])),
                "B0C_arcsec": rad_to_arcsec(math.atan2(nc[0], nc[2]) - b0a),
                "Y0A_um": (self.a_point[1] - ya) * 1e3, "Z0A_um": (self.a_point[2] - za) * 1e3,
                "B0A_arcsec": rad_to_arcsec(b0a), "C0A_arcsec": rad_to_arcsec(math.atan2(na[1], na[0]))}

    def truth_ecc_arcsec(self, c_deg: float, direction: int) -> float:
        return rad_to_arcsec(self.c_actual_rad(c_deg, direction) - math.radians(c_deg))

    def truth_setup_offsets_um(self) -> np.ndarray:
        return (self.spheres_mm - self.assumed_spheres_mm) * 1e3


def machine_of(bench: "Bench") -> MachineModel:
    """The bench's one machine (made on first use): every simulated instrument of it reads this one."""
    model = getattr(bench, "machine", None)
    if model is None:
        model = MachineModel(bench)
        bench.machine = model
    return model

