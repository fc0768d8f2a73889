"""The R-test of a trunnion table (xyzac: A about X carrying C): the kinematic model with the eight
ISO 230-7 location errors, the nest of three flat-ended sensors and its calibration, and the
joint targets that keep the sphere in the nest. Pure functions: mm, radians and degrees in
(units in names), arrays and typed results out. The fit, budget and identifiability are in
:mod:`rtcal.solvers.rtest_fit`; docs/rtest.md states the frames and signs.

**Frames.** The machine frame is the frame of the linear axes' joint coordinates (X, Y, Z of the
tool relative to the table's base, as LinuxCNC's joints are). A point fixed to the table is
named by its machine coordinates at the reference pose A = C = 0 (its *table coordinates*). At a
pose (a, c) the table carries it to ``T(a, c)·p = G_A(a)(G_C(c)(p))``: first the rotation by c
about C's line as it lies at A = 0, then by a about A's line. Both turn right-handed about
their direction (+X for A, +Z for C): LinuxCNC's ``xyzac-trt-kins`` sense (trtfuncs.c,
``xyzacKinematicsInverse``: joints = Rx(a)·[Rz(c)·(p − r) − d] + r + d), so the nominal model
(no errors) *is* that module's, with r = (x-rot-point, y-rot-point, z-rot-point) on C and
r + (0, y-offset, z-offset) on A.

**Location errors** (paper000.md's signs: right-hand rotations that carry the nominal direction
onto the actual one), all at the reference pose:

- A (direction n_A, n_x > 0): Y0A, Z0A where A's line crosses the plane x = x_A of the nominal
  A point; B0A = atan(−n_z/n_x) (about Y), C0A = atan(n_y/n_x) (about Z).
- C relative to A (direction n_C, n_z > 0): X0C where C's line crosses z = z_C (the nominal C
  point's height), Y0C the same crossing's y less A's y at x = x_C (C's offset from A's line);
  A0C = −atan(n_y/n_z) (about X: it holds A's angular zero too, which no test can tell from it),
  B0C = atan(n_x/n_z) − B0A (C's squareness to A about Y).

ECC (C's angular positioning deviation) is added to the commanded c; positive: the table turned
further (right-handed about +Z) than commanded.

**The nest.** Three flat-ended sensors: a flat face pressed on a sphere reads the sphere centre's
displacement along the face normal exactly, whatever the sphere's radius, as long as the contact
stays on the face (:func:`flat_contact_ok`): the plunger then moves by n·Δc / (n·u), so readings
m = S·d with row i = n_i/(n_i·u_i), the sensor's effective direction (its unit direction when the
face is square to the plunger). d = sphere centre − nest zero point, machine frame. The nest
calibration (:func:`calibrate_nest`) solves S from linear moves of the nest around the sphere.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from rtcal.units import ARCSEC_PER_RAD

LOCATION_SYMBOLS = ("X0C_um", "Y0C_um", "A0C_arcsec", "B0C_arcsec", "Y0A_um", "Z0A_um", "B0A_arcsec", "C0A_arcsec")
# what the model names the eight (in this order in every parameter vector), mm or rad internally
LOCATION_NAMES = tuple(s.split("_")[0] for s in LOCATION_SYMBOLS)
LENGTHS = frozenset({"X0C", "Y0C", "Y0A", "Z0A", "Z0C", "X0A"})
# what no R-test of a table can determine, kept as model parameters so the identifiability check can
# show it (rtcal/solvers/rtest_fit.py): a line's point along itself, and the two angular zeros
STRUCTURAL = ("Z0C", "X0A", "C0C", "A0A")
MODEL_NAMES = LOCATION_NAMES + STRUCTURAL
AXES = ("x", "y", "z", "a", "c")


def to_internal(symbol: str, value: float) -> float:
    """A location error as the symbol states it (µm, arcsec) → mm or rad."""
    return value * 1e-3 if symbol.endswith("_um") else value / ARCSEC_PER_RAD


def to_symbol(symbol: str, value: float) -> float:
    """mm or rad → the symbol's unit (µm, arcsec)."""
    return value * 1e3 if symbol.endswith("_um") else value * ARCSEC_PER_RAD


def location_vector(errors: dict[str, float]) -> np.ndarray:
    """The eight location errors (symbol → µm or arcsec; absent ones 0) as the model's vector (mm, rad)."""
    unknown = sorted(set(errors) - set(LOCATION_SYMBOLS))
    if unknown:
        raise ValueError(f"unknown location errors {unknown}; the R-test's are {', '.join(LOCATION_SYMBOLS)}")
    return np.array([to_internal(s, float(errors.get(s, 0.0))) for s in LOCATION_SYMBOLS])


def location_dict(vector: np.ndarray) -> dict[str, float]:
    """The model's vector (mm, rad) → symbol → µm or arcsec."""
    return {s: to_symbol(s, float(v)) for s, v in zip(LOCATION_SYMBOLS, np.asarray(vector, float)[:8])}


@dataclass(frozen=True)
class TrunnionGeometry:
    """The nominal kinematics the controller holds (and the linear axes follow): a point of C's line
    at the reference pose (its z: the height X0C and Y0C are stated at) and a point of A's line (its
    x: the plane Y0A and Z0A are stated at), machine frame, mm. C is nominally along +Z, A along +X."""

    c_point_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    a_point_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def from_linuxcnc(cls, x_rot_point: float, y_rot_point: float, z_rot_point: float, y_offset: float,
                      z_offset: float) -> "TrunnionGeometry":
        """``xyzac-trt-kins``'s pins (mm): C through the rot point, A through rot point + (0, y-offset,
        z-offset) (trtfuncs.c: A turns about r + d, C about r); x-offset is not read by xyzac."""
        return cls((x_rot_point, y_rot_point, z_rot_point), (x_rot_point, y_rot_point + y_offset, z_rot_point + z_offset))


def _norm(v: np.ndarray) -> np.ndarray:
    """Unit vector along the last axis; complex-safe (no abs), for complex-step derivatives."""
    return v / np.sqrt(np.sum(v * v, axis=-1, keepdims=True))


def axis_lines(geometry: TrunnionGeometry, params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(A point, A direction, C point, C direction) at the reference pose, machine frame, from the model's
    parameter vector (the eight location errors, mm and rad, then optionally the structural Z0C, X0A,
    C0C, A0C). Inverse of the definitions in the module docstring."""
    p = np.zeros(len(MODEL_NAMES), dtype=np.asarray(params).dtype)
    p[: len(params)] = params
    x0c, y0c, a0c, b0c, y0a, z0a, b0a, c0a, z0c, x0a = p[:10]
    xa, ya, za = geometry.a_point_mm
    xc, yc, zc = geometry.c_point_mm
    one = np.ones((), dtype=p.dtype)
    a_dir = _norm(np.array([one, np.tan(c0a), -np.tan(b0a)]))
    # X0A and Z0C slide each line's point along the line itself (what no pose can see)
    a_point = np.array([xa + 0 * one, ya + y0a, za + z0a]) + x0a * a_dir
    c_dir = _norm(np.array([np.tan(b0c + b0a), -np.tan(a0c), one]))
    # A's y at x = x_C, then C's offset from it
    c_point = np.array([xc + x0c, ya + y0a + (xc - xa) * np.tan(c0a) + (yc - ya) + y0c, zc + 0 * one]) + z0c * c_dir
    return a_point, a_dir, c_point, c_dir


def rotate_about(points: np.ndarray, point: np.ndarray, direction: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Points (N, 3) turned right-handed by angle (N,) about the line through ``point`` along the unit
    ``direction`` (Rodrigues; complex-safe)."""
    v = points - point
    cos, sin = np.cos(angle_rad)[:, None], np.sin(angle_rad)[:, None]
    u = np.broadcast_to(direction, v.shape)
    return point + v * cos + np.cross(u, v) * sin + u * np.sum(u * v, axis=1, keepdims=True) * (1 - cos)


def table_to_machine(geometry: TrunnionGeometry, params: np.ndarray, a_rad: np.ndarray, c_rad: np.ndarray,
                     points_mm: np.ndarray) -> np.ndarray:
    """Where table points (N, 3; table coordinates) are at the poses (a, c) (N each; c the actual angle,
    ECC included): C's rotation, then A's, about the actual lines. The structural C0C and A0A (params
    10, 11) add to every c and a."""
    p = np.zeros(len(MODEL_NAMES), dtype=np.asarray(params).dtype)
    p[: len(params)] = params
    a_point, a_dir, c_point, c_dir = axis_lines(geometry, p)
    points = np.asarray(points_mm) + 0 * p[0]
    turned = rotate_about(points, c_point, c_dir, np.asarray(c_rad) + p[10])
    return rotate_about(turned, a_point, a_dir, np.asarray(a_rad) + p[11])


def nominal_table_to_machine(geometry: TrunnionGeometry, a_deg: np.ndarray, c_deg: np.ndarray,
                             points_mm: np.ndarray) -> np.ndarray:
    """The controller's model: the same with no errors."""
    a, c = np.radians(np.atleast_1d(a_deg)), np.radians(np.atleast_1d(c_deg))
    pts = np.broadcast_to(np.asarray(points_mm, float), (len(a), 3))
    return table_to_machine(geometry, np.zeros(8), a, c, pts)


def nominal_machine_to_table(geometry: TrunnionGeometry, a_deg: np.ndarray, c_deg: np.ndarray,
                             points_mm: np.ndarray) -> np.ndarray:
    """The controller's forward kinematics: machine points (N, 3) at the poses (a, c) → their table
    coordinates (where they are at A = C = 0); the inverse of :func:`nominal_table_to_machine`."""
    a, c = np.radians(np.atleast_1d(np.asarray(a_deg, float))), np.radians(np.atleast_1d(np.asarray(c_deg, float)))
    pts = np.broadcast_to(np.asarray(points_mm, float), (len(a), 3))
    a_point, a_dir, c_point, c_dir = axis_lines(geometry, np.zeros(8))
    return rotate_about(rotate_about(pts, a_point, a_dir, -a), c_point, c_dir, -c)


def joint_targets(geometry: TrunnionGeometry, sphere_mm: Sequence[float], a_deg: np.ndarray, c_deg: np.ndarray,
                  nest_offset_mm: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """(N, 5) joints X, Y, Z (mm), A, C (deg) that put the nest's zero point on the sphere's nominal
    centre at each (a, c): the nominal sphere path, as the controller's inverse kinematics would."""
    a, c = np.atleast_1d(np.asarray(a_deg, float)), np.atleast_1d(np.asarray(c_deg, float))
    xyz = nominal_table_to_machine(geometry, a, c, np.asarray(sphere_mm, float)) - np.asarray(nest_offset_mm, float)
    return np.column_stack([xyz, a, c])


def path_between(geometry: TrunnionGeometry, sphere_mm: Sequence[float], start: Sequence[float], end: Sequence[float],
                 nest_offset_mm: Sequence[float] = (0.0, 0.0, 0.0), max_step_deg: float = 1.0) -> np.ndarray:
    """Joint waypoints (K, 5) from pose ``start`` (a, c deg) to ``end``, the rotary axes in steps of at
    most ``max_step_deg`` with the linear axes on the nominal sphere path at each: a coordinated move
    through them keeps the sphere in the nest (the chord between waypoints strays by R·(1 − cos(step/2)),
    0.006 mm at R = 200 mm and 0.5°... choose the step for the nest's capture range). The last row is
    ``end``'s target; the first is the first step away from ``start``."""
    a0, c0 = (float(v) for v in start)
    a1, c1 = (float(v) for v in end)
    steps = max(1, int(np.ceil(max(abs(a1 - a0), abs(c1 - c0)) / max_step_deg)))
    f = np.arange(1, steps + 1) / steps
    return joint_targets(geometry, sphere_mm, a0 + f * (a1 - a0), c0 + f * (c1 - c0), nest_offset_mm)


def k_test_sequence(c_angles_deg: Sequence[float], tilt_deg: float | None, a_angles_deg: Sequence[float],
                    both_directions: bool = True) -> list[tuple[float, float, int]]:
    """(A deg, C deg, the direction C approaches from) of each reading of the ISO 10791-6 kinematic tests
    of a trunnion table, in order: the reference pose (0, 0, +); C turned through ``c_angles_deg`` at
    A = 0 (and back, if ``both_directions``); A turned through ``a_angles_deg`` at C = 0 (and back); C
    turned again at A = ``tilt_deg`` (None: not); the reference pose again, approached as at first (the
    drift). The linear axes follow the nominal sphere path throughout (:func:`path_between`)."""
    out: list[tuple[float, float, int]] = [(0.0, 0.0, 1)]
    c_dir = 1

    def c_test(a: float) -> None:
        nonlocal c_dir
        forward = [float(c) for c in c_angles_deg]
        for c in forward:
            out.append((a, c, 1))
        c_dir = 1
        if both_directions:
            for c in forward[::-1]:
                out.append((a, c, -1))
            c_dir = -1

    c_test(0.0)
    a_list = [float(a) for a in a_angles_deg]
    for a in a_list + (a_list[::-1] if both_directions else []):
        out.append((a, 0.0, c_dir))
    if tilt_deg is not None:
        c_test(float(tilt_deg))
    out.append((0.0, 0.0, 1))
    return out


def linearised_c_displacement(c_location_mm_rad: Sequence[float], p_mm: Sequence[float], theta_rad: np.ndarray,
                              ecc_rad: np.ndarray | None = None) -> np.ndarray:
    """The first-order displacement (N, 3) of a table point ``p`` (relative to C's nominal point) when C
    alone turns to θ, for C's location errors (X0C, Y0C mm; A0C, B0C rad) and ECC(θ) (docs/rtest.md;
    /work reference "rtest_kinematics" §1.2): δ(θ) = (I − R)·c + ((I − R)·ω) × R·p + ECC·e_z × R·p, with
    c = (X0C, Y0C, 0), ω = (A0C, B0C, 0) the rotation vector that tilts +Z onto C's line. What the exact
    model must agree with to second order (tests/test_rtest_solver.py)."""
    x0c, y0c, a0c, b0c = (float(v) for v in c_location_mm_rad)
    th = np.atleast_1d(np.asarray(theta_rad, float))
    e = np.zeros_like(th) if ecc_rad is None else np.asarray(ecc_rad, float)
    c = np.array([x0c, y0c, 0.0])
    w = np.array([a0c, b0c, 0.0])
    p = np.asarray(p_mm, float)
    out = np.zeros((len(th), 3))
    for k, (t, ek) in enumerate(zip(th, e)):
        ct, st = np.cos(t), np.sin(t)
        R = np.array([[ct, -st, 0.0], [st, ct, 0.0], [0.0, 0.0, 1.0]])
        Rp = R @ p
        out[k] = (np.eye(3) - R) @ c + np.cross((np.eye(3) - R) @ w, Rp) + ek * np.cross([0.0, 0.0, 1.0], Rp)
    return out


# -- the nest --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class NestCalibration:
    """The nest matrix S (row i: sensor i's effective direction, reading µm per µm of the sphere centre's
    displacement; its norm is 1/cos of the face's tilt to the plunger) and the covariance of its nine
    entries (row-major) from the calibration's reading noise. ``residual_um``: each calibration reading
    less the fit (M, 3); ``base_um``: the readings the fit puts at the start point."""

    matrix: np.ndarray
    covariance: np.ndarray
    residual_um: np.ndarray
    base_um: np.ndarray

    def directions(self) -> np.ndarray:
        """Each sensor's unit direction (3, 3)."""
        return self.matrix / np.linalg.norm(self.matrix, axis=1, keepdims=True)

    def direction_u_deg(self) -> np.ndarray:
        """Each direction's standard uncertainty as an angle, deg: √(trace of its row's covariance
        across the direction) / |row|."""
        out = []
        for i in range(3):
            C = self.covariance[3 * i:3 * i + 3, 3 * i:3 * i + 3]
            n = self.directions()[i]
            P = np.eye(3) - np.outer(n, n)
            out.append(np.degrees(np.sqrt(max(np.trace(P @ C @ P), 0.0)) / np.linalg.norm(self.matrix[i])))
        return np.array(out)

    def displacement_mm(self, readings_um: np.ndarray) -> np.ndarray:
        """Sphere centre − nest zero point (N, 3), mm, from readings (N, 3) µm: d = S⁻¹·m."""
        m = np.atleast_2d(np.asarray(readings_um, float))
        return np.linalg.solve(self.matrix, m.T).T * 1e-3


def calibrate_nest(moves_mm: np.ndarray, readings_um: np.ndarray, noise_um: float) -> NestCalibration:
    """The nest matrix from readings taken with the nest moved by the linear axes to M ≥ 4 points around
    the sphere (``moves_mm``, (M, 3): each point's nest position less the first's; the first row is
    usually 0): the sphere relative to the nest moves by −move, so sensor i reads b_i − s_i·move.
    Each sensor is one least squares of 4 unknowns (b_i, s_i) and M readings, its covariance
    σ²·(XᵀX)⁻¹ with σ = ``noise_um`` (the reading's stated 1σ, resolution included). Six moves ±x, ±y,
    ±z of a few tenths of a mm (with the start) determine S to σ/(move·√2) per entry. ValueError if
    the moves do not span three directions."""
    D = np.asarray(moves_mm, float) * 1e3
    m = np.asarray(readings_um, float)
    if D.ndim != 2 or D.shape[1] != 3 or m.shape != D.shape:
        raise ValueError("moves_mm and readings_um: (M, 3) each, the same M")
    X = np.column_stack([np.ones(len(D)), -D])
    if len(D) < 5 or np.linalg.matrix_rank(X) < 4:
        raise ValueError("the nest calibration's moves must span three directions (six moves ±x, ±y, ±z and the start)")
    XtX_inv = np.linalg.inv(X.T @ X)
    coef = XtX_inv @ X.T @ m  # (4, 3): row 0 the base readings, rows 1..3 the matrix's transpose
    S = coef[1:].T
    cov = np.zeros((9, 9))
    for i in range(3):
        cov[3 * i:3 * i + 3, 3 * i:3 * i + 3] = noise_um**2 * XtX_inv[1:, 1:]
    return NestCalibration(S, cov, m - X @ coef, coef[0])


def flat_contact_ok(displacement_mm: np.ndarray, nest: NestCalibration, flat_radius_mm: float) -> np.ndarray:
    """(N,) whether each sensor's contact stays on its flat face, where the linear form is exact: the
    sphere centre's displacement across each face normal (the contact point moves on the face by as
    much) within ``flat_radius_mm`` of where it was at the nest's zero. (N, 3) booleans."""
    d = np.atleast_2d(np.asarray(displacement_mm, float))
    out = np.zeros((len(d), 3), dtype=bool)
    for i, n in enumerate(nest.directions()):
        lateral = d - np.outer(d @ n, n)
        out[:, i] = np.sqrt(np.sum(lateral * lateral, axis=1)) <= flat_radius_mm
    return out
