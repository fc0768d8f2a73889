"""The R-test's adjustment: the eight location errors, each sphere's set-up offset and C's angular
positioning deviation from the sphere-centre displacements (:mod:`rtcal.solvers.rtest`), by
Gauss–Newton on the exact rotations (the first step is the linearised model; it iterates until
the step is below a nanometre), with a GUM budget per parameter, the residual test, and the
identifiability check that refuses what the poses cannot separate. :func:`predict_rtest` gives
the same check and the expected U per parameter before anything moves (``rtcal plan``).

**Unknowns.** x = [X0C, Y0C, A0C, B0C, Y0A, Z0A, B0A, C0A (mm, rad); σ_j (mm, 3 per sphere set-up:
where sphere j really sits less where the path assumed it); ECC (rad) per commanded C angle and
approach direction, relative to the first pose's (its constant is C's angular zero, which a sphere
of unknown azimuth hides)]. The model of pose k: d_k = T(x; a_k, c_k + ECC)·(ŝ_j + σ_j) − J_k − n̂,
J_k the commanded joints, n̂ the nest zero point's stated offset from them.

**Budget** (each source's effect on the displacements, propagated by the weighted adjustment's
influence matrix H = (JᵀWJ)⁻¹JᵀW; u(k = 1) per parameter and source):

- sensors: each reading's noise and resolution (σ² + r²/12), through S⁻¹ and the drift correction;
- sphere form: the sphere's radius at each contact point, a smooth random field of degrees 2–6 with
  σ = F/4 for the certificate's form deviation F (peak to valley); readings that touch nearby
  points of the sphere are correlated as the field says (Σ_l g·P_l(u·v));
- nest calibration: the covariance of S's nine entries (:func:`~rtcal.solvers.rtest.calibrate_nest`);
- linear axes: scale (ppm) and squareness (″) errors of X, Y, Z acting on the commanded joints
  (e = E·J, E lower triangular as the bench's CMM), and a random positioning error per pose;
- nest zero: where the nest's zero point really is on the spindle (tool length and centring): a
  constant displacement, which moves σ and, with it, X0C, Y0A, Z0A one for one — the R-test locates
  the axes relative to the nest, the control needs them relative to the spindle;
- drift: what the linear correction from the repeated first pose misses, up to ``drift_nonlinearity``
  of the measured drift (a parabola through both ends, the shape of a drift that slows).

The residual test is :func:`rtcal.solvers.uncertainty.residual_check` in the whitened space, with the
estimator's Jacobian: χ²(ν) exactly on a machine as budgeted.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from rtcal.solvers.rtest import (LENGTHS, LOCATION_NAMES, LOCATION_SYMBOLS, MODEL_NAMES, STRUCTURAL, NestCalibration,
                                 TrunnionGeometry, flat_contact_ok, table_to_machine, to_symbol)
from rtcal.solvers.uncertainty import ResidualCheck, residual_check
from rtcal.units import ARCSEC_PER_RAD

SOURCES = ("sensors", "sphere form", "nest calibration", "linear axes", "nest zero", "drift")
NULL_TOLERANCE = 1e-6  # a parameter whose share of the data's null space exceeds this is not separable
SINGULAR_TOLERANCE = 1e-9  # singular values below this (columns scaled to 1) span the null space
MAX_ITERATIONS = 30
STEP_TOLERANCE = 1e-9  # mm and rad: Gauss–Newton stops once no step is larger
WHY_STRUCTURAL = {
    "Z0C": "a point of C's line along the line itself: moving it along C changes no pose",
    "X0A": "a point of A's line along the line itself: moving it along A changes no pose",
    "C0C": ("C's angular zero: the sphere's azimuth on the table is not known, and turning every pose by a constant "
            "angle about C is the same as the sphere sitting that much further round (its set-up offset)"),
    "A0A": ("A's angular zero: a constant angle about A is the same as C's line tilted about X (A0C) with the sphere set "
            "up elsewhere; the fit reports their sum as A0C"),
}


class RTestDataError(ValueError):
    """The readings cannot be adjusted as they are (one line a person can act on)."""


@dataclass(frozen=True)
class RTestPoses:
    """What was commanded at each reading: joints X, Y, Z (mm), A, C (deg), (N, 5); the sphere set-up
    (index into the setup's spheres), the direction C last moved before the reading (±1) and when it was
    taken (s)."""

    joints: np.ndarray
    sphere: np.ndarray
    c_direction: np.ndarray
    time_s: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.joints)
        if np.asarray(self.joints).shape != (n, 5) or not (len(self.sphere) == len(self.c_direction) == len(self.time_s) == n):
            raise RTestDataError("poses: joints (N, 5) and N sphere indices, C directions and times")

    @classmethod
    def of(cls, joints: np.ndarray, sphere: Sequence[int] | None = None, c_direction: Sequence[int] | None = None,
           time_s: Sequence[float] | None = None) -> "RTestPoses":
        """Poses with defaults: one sphere, C moving positive, one reading a second."""
        j = np.asarray(joints, float)
        n = len(j)
        return cls(j, np.zeros(n, int) if sphere is None else np.asarray(sphere, int),
                   np.ones(n, int) if c_direction is None else np.asarray(c_direction, int),
                   np.arange(n, dtype=float) if time_s is None else np.asarray(time_s, float))


@dataclass(frozen=True)
class RTestSetup:
    """The set-up: the controller's kinematics, where the path assumed each sphere (table coordinates, mm),
    the nest zero point's offset from the commanded joints (mm), the pair (first, repeat) of poses whose
    difference is the drift (None: no drift correction) and the radius of the sensors' flat faces (mm).
    ``drift_pairs`` instead: one pair per sphere set-up, each correcting the poses of its own set-up (the
    sphere moved between them, each group's first pose repeated at its end); a single pair corrects all."""

    geometry: TrunnionGeometry
    spheres_mm: np.ndarray
    nest_offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    drift_pair: tuple[int, int] | None = None
    flat_radius_mm: float = 2.0
    drift_pairs: tuple[tuple[int, int], ...] = ()

    def pairs(self) -> tuple[tuple[int, int], ...]:
        """The drift pairs in use (``drift_pairs``, else ``drift_pair`` alone, else none)."""
        if self.drift_pairs:
            return tuple((int(a), int(b)) for a, b in self.drift_pairs)
        return () if self.drift_pair is None else ((int(self.drift_pair[0]), int(self.drift_pair[1])),)


@dataclass(frozen=True)
class StatedUncertainty:
    """The procedure's statement of what the readings and the machine may be off by (1σ unless said)."""

    sensor_noise_um: float = 0.1
    sensor_resolution_um: float = 0.1
    sphere_form_um: float = 0.25  # the certificate's form deviation, peak to valley
    form_degrees: tuple[int, int] = (2, 6)
    nest_zero_um: float = 1.0
    linear_scale_ppm: float = 3.0
    linear_squareness_arcsec: float = 2.0
    linear_repeatability_um: float = 0.3
    drift_nonlinearity: float = 0.25  # the share of the measured drift a linear correction may miss
    expected_drift_um: float = 2.0  # per axis, for a prediction (no drift measured yet)

    def reading_sigma_um(self) -> float:
        return float(np.sqrt(self.sensor_noise_um**2 + self.sensor_resolution_um**2 / 12.0))

    def form_sigma_um(self) -> float:
        return self.sphere_form_um / 4.0


@dataclass(frozen=True)
class Parameter:
    """One reported quantity in its symbol's unit: value, u (1σ), U = 2u, and u per source."""

    symbol: str
    value: float
    u: float
    budget: dict[str, float]

    @property
    def U(self) -> float:
        return 2.0 * self.u


@dataclass(frozen=True)
class Identifiability:
    """Which of the eight the poses separate, why the others are refused, and what the structural
    parameters (Z0C, X0A, C0C, A0A) could not be told apart from."""

    estimable: tuple[str, ...]
    refused: dict[str, str]
    structural: dict[str, str]


@dataclass(frozen=True)
class RTestResult:
    """The adjustment: the location errors reported (symbol → Parameter), the set-up offsets (per sphere:
    x, y, z µm), ECC per (commanded C deg, direction) in arcsec, the identifiability, the residual test,
    the drift the repeated pose showed (µm), and the sphere-centre displacements (µm, per fitted pose):
    ``before_um`` as measured (drift corrected) less what the spheres' set-up offsets do (the machine's
    own deviation from the nominal sphere path), ``after_um`` what remains once the eight location errors
    are compensated (ECC and the residual), ``residual_um`` what the whole model leaves."""

    location: dict[str, Parameter]
    setup_offsets: list[tuple[Parameter, Parameter, Parameter]]
    ecc: dict[tuple[float, int], Parameter]
    identifiability: Identifiability
    residual_test: ResidualCheck | None
    drift_um: np.ndarray
    before_um: np.ndarray
    after_um: np.ndarray
    residual_um: np.ndarray
    iterations: int
    linearisation_um: float
    fitted_poses: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    drifts_um: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # per drift pair (``drift_um``: the first)


@dataclass(frozen=True)
class RTestPrediction:
    """Before anything moves: the U (k = 2) each estimable location error is expected to have, and
    what cannot be determined with this plan (symbol → why)."""

    U: dict[str, float]
    budget: dict[str, dict[str, float]]
    identifiability: Identifiability


# -- the layout of the unknowns ----------------------------------------------------------------------
@dataclass(frozen=True)
class _Layout:
    n_spheres: int
    keys: tuple[tuple[float, int], ...]  # ECC keys; keys[0] is the reference (ECC 0)
    key_of_pose: np.ndarray

    @property
    def names(self) -> tuple[str, ...]:
        setup = tuple(f"σ{j}{a}" for j in range(self.n_spheres) for a in "xyz")
        return LOCATION_NAMES + setup + tuple(f"ECC({c:g}°,{'+' if d > 0 else '−'})" for c, d in self.keys[1:])

    @property
    def size(self) -> int:
        return 8 + 3 * self.n_spheres + len(self.keys) - 1


def _layout(poses: RTestPoses, n_spheres: int, fitted: np.ndarray) -> _Layout:
    keys: list[tuple[float, int]] = []
    index = np.zeros(len(poses.joints), int)
    for k in fitted:
        key = (round(float(poses.joints[k, 4]), 6), 1 if poses.c_direction[k] >= 0 else -1)
        if key not in keys:
            keys.append(key)
        index[k] = keys.index(key)
    return _Layout(n_spheres, tuple(keys), index)


def _model(x: np.ndarray, structural: np.ndarray, layout: _Layout, poses: RTestPoses, setup: RTestSetup,
           rows: np.ndarray) -> np.ndarray:
    """d̂ (len(rows), 3), mm: the sphere centre less the nest zero point at each pose of ``rows``."""
    ns = layout.n_spheres
    params = np.concatenate([x[:8], structural])
    sigma = x[8:8 + 3 * ns].reshape(ns, 3)
    ecc = np.concatenate([np.zeros(1, dtype=x.dtype), x[8 + 3 * ns:]])
    j = poses.joints[rows]
    sph = np.asarray(poses.sphere)[rows]
    pts = np.asarray(setup.spheres_mm, float)[sph] + sigma[sph]
    c = np.radians(j[:, 4]) + ecc[layout.key_of_pose[rows]]
    at = table_to_machine(setup.geometry, params, np.radians(j[:, 3]), c, pts)
    return at - j[:, :3] - np.asarray(setup.nest_offset_mm, float)


def _jacobian(x: np.ndarray, layout: _Layout, poses: RTestPoses, setup: RTestSetup, rows: np.ndarray,
              structural_columns: bool = False) -> np.ndarray:
    """∂d̂/∂x (3N, n) by complex steps (exact to rounding); with ``structural_columns`` the four
    structural parameters' columns instead."""
    h = 1e-30
    n = 4 if structural_columns else len(x)
    cols = []
    for i in range(n):
        xs = x.astype(complex)
        st = np.zeros(4, complex)
        if structural_columns:
            st[i] += 1j * h
        else:
            xs[i] += 1j * h
        cols.append(np.imag(_model(xs, st, layout, poses, setup, rows)).ravel() / h)
    return np.column_stack(cols)


def _whitening(nest: NestCalibration, stated: StatedUncertainty) -> np.ndarray:
    """Λ (3×3) with Λ·Σ_d·Λᵀ = I for one pose's white part: readings (noise, resolution, form's variance)
    through S⁻¹, and the linear axes' random positioning."""
    Sinv = np.linalg.inv(nest.matrix)
    var_m = (stated.reading_sigma_um() ** 2 + stated.form_sigma_um() ** 2) * 1e-6
    cov = var_m * Sinv @ Sinv.T + (stated.linear_repeatability_um * 1e-3) ** 2 * np.eye(3)
    return np.asarray(np.linalg.inv(np.linalg.cholesky(cov)))


# -- identifiability --------------------------------------------------------------------------------
def _identify(Jw: np.ndarray, names: Sequence[str]) -> tuple[np.ndarray, dict[str, str]]:
    """Which columns are estimable (their parameter has no share in the null space of the scaled,
    whitened Jacobian), and for each other one of the eight, why not."""
    norms = np.linalg.norm(Jw, axis=0)
    zero = norms <= 1e-12 * max(float(norms.max()), 1e-300)
    scaled = Jw / np.where(zero, 1.0, norms)
    scaled[:, zero] = 0.0
    _, s, Vt = np.linalg.svd(scaled, full_matrices=True)
    s_full = np.zeros(Vt.shape[0])
    s_full[: len(s)] = s
    null = Vt[s_full <= SINGULAR_TOLERANCE * max(float(s_full.max()), 1e-300)]
    share = np.linalg.norm(null, axis=0) if len(null) else np.zeros(len(names))
    estimable = (share <= NULL_TOLERANCE) & ~zero
    why: dict[str, str] = {}
    projector = null.T @ null if len(null) else np.zeros((len(names), len(names)))
    for i, name in enumerate(names):
        if estimable[i] or name not in LOCATION_NAMES:
            continue
        if zero[i]:
            why[name] = "no pose of this plan moves it (the axis it belongs to never turns, or turns without the sphere off it)"
            continue
        share = projector[:, i]  # e_i's part in the null space (whatever basis the SVD chose)
        partners = [_display(names[k]) for k in np.argsort(-np.abs(share))
                    if k != i and not zero[k] and abs(share[k]) > NULL_TOLERANCE]
        why[name] = "cannot be separated from " + (", ".join(partners[:4]) if partners else "the other parameters") + \
                    " with these poses"
    return estimable, why


def _display(name: str) -> str:
    """A parameter as messages name it: a location error by its symbol (X0C_um), the others as they are."""
    return name + _suffix(name)


def _structural(Jw_fit: np.ndarray, Jw_struct: np.ndarray) -> dict[str, str]:
    """Each structural parameter's column against the span of the fitted ones (every column of the fit,
    separable or not): within it (or zero), it cannot be determined, for the reason WHY_STRUCTURAL gives."""
    norms = np.linalg.norm(Jw_fit, axis=0)
    scale = float(np.max(norms))
    U, sv, _ = np.linalg.svd(Jw_fit / np.where(norms > 1e-12 * scale, norms, np.inf), full_matrices=False)
    Q = U[:, sv > SINGULAR_TOLERANCE * float(sv.max())]  # the range of the fitted columns
    out = {}
    for i, name in enumerate(STRUCTURAL):
        col = Jw_struct[:, i]
        n = float(np.linalg.norm(col))
        left = 0.0 if n <= 1e-10 * scale else float(np.linalg.norm(col - Q @ (Q.T @ col))) / n
        if left <= NULL_TOLERANCE:
            out[name] = WHY_STRUCTURAL[name]
        else:
            out[name] = (f"{WHY_STRUCTURAL[name]} — but these poses would separate {left:.1e} of it: the model still "
                         "holds it at 0")
    return out


# -- the budget ---------------------------------------------------------------------------------------
def _legendre(l_max: int, x: np.ndarray) -> list[np.ndarray]:
    P = [np.ones_like(x), x]
    for n in range(1, l_max):
        P.append(((2 * n + 1) * x * P[n] - n * P[n - 1]) / (n + 1))
    return P


def form_covariance_um2(contact_dirs: np.ndarray, sphere: np.ndarray, sigma_um: float, degrees: tuple[int, int]) -> np.ndarray:
    """Covariance of the form error at each contact (M contact directions, unit, in each sphere's own
    frame; ``sphere`` (M,) which sphere each touches): an isotropic random field of the degrees given,
    each degree an equal share of σ², Cov = Σ_l g·P_l(u·v); contacts on different spheres are
    independent."""
    lo, hi = degrees
    g = sigma_um**2 / (hi - lo + 1)
    cosines = np.clip(contact_dirs @ contact_dirs.T, -1.0, 1.0)
    P = _legendre(hi, cosines)
    C = g * sum(P[l] for l in range(lo, hi + 1))
    same = np.asarray(sphere)[:, None] == np.asarray(sphere)[None, :]
    return np.asarray(np.where(same, C, 0.0))


def _sqrt_psd(C: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(C)
    keep = w > max(float(w.max()), 0.0) * 1e-12
    return np.asarray(V[:, keep] * np.sqrt(w[keep]))


def _rotation_parts(poses: RTestPoses, rows: np.ndarray) -> np.ndarray:
    """The nominal rotation Rx(a)·Rz(c) of each pose (len(rows), 3, 3)."""
    a, c = np.radians(poses.joints[rows, 3]), np.radians(poses.joints[rows, 4])
    ca, sa, cc, sc = np.cos(a), np.sin(a), np.cos(c), np.sin(c)
    R = np.zeros((len(rows), 3, 3))
    R[:, 0, 0], R[:, 0, 1] = cc, -sc
    R[:, 1, 0], R[:, 1, 1], R[:, 1, 2] = ca * sc, ca * cc, -sa
    R[:, 2, 0], R[:, 2, 1], R[:, 2, 2] = sa * sc, sa * cc, ca
    return R


def _drift_map(poses: RTestPoses, setup: RTestSetup) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(fitted pose indices, L (3N_fit × 3N_all) the linear drift correction, w (N_fit,) each fitted
    pose's fraction of the time between its pair, g (N_fit,) the pair correcting it (−1 none), gap
    (N_fit,) how much of the drift before its group's first pose the correction takes out, in units of
    that group's measured drift — see below). One pair corrects every pose; several each correct the
    poses of their own sphere set-up, in the order taken.

    Between two groups the sphere is moved, so no pose measures the drift accumulated before a later
    group's first pose — and, constant in the machine frame, no set-up offset (constant on the table) can
    take it. It is bridged: the drift goes on at the mean of the rates its neighbours' pairs measured
    (D_p = D_{p−1} + Δ_{p−1} + ½·gap·(Δ_{p−1}/T_{p−1} + Δ_p/T_p)), linear in the readings, so the
    sensors' part of its uncertainty is in L; the budget's drift source adds ``drift_nonlinearity`` of it."""
    n = len(poses.joints)
    pairs = setup.pairs()
    if not pairs:
        rows = np.arange(n)
        return rows, np.eye(3 * n), np.zeros(n), np.full(n, -1), np.zeros((0, 0))
    sphere = np.asarray(poses.sphere)
    group = np.full(n, -1)
    for p, (i0, i1) in enumerate(pairs):
        if not (0 <= i0 < n and 0 <= i1 < n and i0 != i1):
            raise RTestDataError(f"drift pair {(i0, i1)}: two different poses of the {n}")
        if not np.allclose(poses.joints[i0], poses.joints[i1], atol=1e-6) or sphere[i0] != sphere[i1]:
            raise RTestDataError(f"drift pair: pose {i1} does not repeat pose {i0} (the same joints and sphere)")
        if not float(poses.time_s[i1]) > float(poses.time_s[i0]):
            raise RTestDataError("drift pair: the repeat must be taken after the first")
        members = np.ones(n, bool) if len(pairs) == 1 else sphere == sphere[i0]
        if np.any(group[members] >= 0):
            raise RTestDataError(f"drift pairs: two pairs for sphere set-up {int(sphere[i0]) + 1} (one per set-up)")
        group[members] = p
    repeats = {i1 for _, i1 in pairs}
    rows = np.array([k for k in range(n) if k not in repeats])
    t = np.asarray(poses.time_s, float)
    span = [t[i1] - t[i0] for i0, i1 in pairs]
    # the drift before each group's first pose, as coefficients of the pairs' measured drifts Δ_q
    before = np.zeros((len(pairs), len(pairs)))
    for p in range(1, len(pairs)):
        gap = t[pairs[p][0]] - t[pairs[p - 1][1]]
        if gap < 0:
            raise RTestDataError("drift pairs: each group's poses after the previous group's repeat")
        before[p] = before[p - 1]
        before[p, p - 1] += 1.0 + 0.5 * gap / span[p - 1]
        before[p, p] += 0.5 * gap / span[p]
    w = np.zeros(len(rows))
    L = np.zeros((3 * len(rows), 3 * n))
    for r, k in enumerate(rows):
        L[3 * r:3 * r + 3, 3 * k:3 * k + 3] += np.eye(3)
        if group[k] < 0:
            continue
        i0, i1 = pairs[group[k]]
        w[r] = (t[k] - t[i0]) / (t[i1] - t[i0])
        coef = before[group[k]].copy()
        coef[group[k]] += w[r]
        for q, (j0, j1) in enumerate(pairs):
            L[3 * r:3 * r + 3, 3 * j1:3 * j1 + 3] -= coef[q] * np.eye(3)
            L[3 * r:3 * r + 3, 3 * j0:3 * j0 + 3] += coef[q] * np.eye(3)
    return rows, L, w, group[rows], before


def _sources(poses: RTestPoses, setup: RTestSetup, nest: NestCalibration, stated: StatedUncertainty,
             d_all_mm: np.ndarray, drift_mm: np.ndarray, L: np.ndarray, w: np.ndarray,
             group: np.ndarray, before: np.ndarray) -> dict[str, np.ndarray]:
    """Each source's effect on the fitted displacements (3N_fit × q), mm per 1σ of its q inputs (``drift_mm``:
    each drift pair's measured drift, (pairs, 3))."""
    n = len(poses.joints)
    Sinv = np.linalg.inv(nest.matrix)
    B = np.kron(np.eye(n), Sinv) * 1e-3  # readings µm → displacements mm
    out: dict[str, np.ndarray] = {"sensors": L @ B * stated.reading_sigma_um()}
    if stated.sphere_form_um > 0:
        R = _rotation_parts(poses, np.arange(n))
        dirs = nest.directions()
        contact = np.einsum("kji,sj->ksi", R, dirs).reshape(3 * n, 3)  # Rᵀ·â for each pose and sensor
        sphere = np.repeat(np.asarray(poses.sphere), 3)
        C = form_covariance_um2(contact, sphere, stated.form_sigma_um(), stated.form_degrees)
        out["sphere form"] = L @ B @ _sqrt_psd(C)
    # nest calibration: δd = −S⁻¹·δS·d
    G = np.zeros((3 * n, 9))
    for k in range(n):
        for i in range(3):
            for j in range(3):
                G[3 * k:3 * k + 3, 3 * i + j] = -Sinv[:, i] * d_all_mm[k, j]
    out["nest calibration"] = L @ G @ _sqrt_psd(nest.covariance)
    # linear axes: the nest stands at J + E·J (E lower triangular: scales on the diagonal, squareness below)
    J = poses.joints[:, :3]
    lin = np.zeros((3 * n, 6))
    scale, square = stated.linear_scale_ppm * 1e-6, stated.linear_squareness_arcsec / ARCSEC_PER_RAD
    for col, (a, b, u) in enumerate(((0, 0, scale), (1, 1, scale), (2, 2, scale), (1, 0, square), (2, 0, square),
                                     (2, 1, square))):
        lin[3 * np.arange(n) + a, col] = -J[:, b] * u
    out["linear axes"] = np.hstack([L @ lin, L * stated.linear_repeatability_um * 1e-3])
    out["nest zero"] = L @ np.tile(-np.eye(3), (n, 1)) * stated.nest_zero_um * 1e-3
    if setup.pairs():
        bump = 4.0 * w * (1.0 - w)
        k = len(drift_mm)
        drift = np.zeros((3 * len(w), 6 * k))  # each pair's miss, and each bridge's, independent of the others'
        bridged = before @ np.asarray(drift_mm).reshape(k, 3)  # the drift bridged before each group (0 for the first)
        for p, pair_drift in enumerate(drift_mm):
            mine = np.nonzero(group == p)[0]
            for a in range(3):
                drift[3 * mine + a, 3 * p + a] = bump[mine] * stated.drift_nonlinearity * abs(pair_drift[a]) / np.sqrt(3.0)
                drift[3 * mine + a, 3 * (k + p) + a] = stated.drift_nonlinearity * abs(bridged[p, a]) / np.sqrt(3.0)
        out["drift"] = drift
    return out


def _unit(name: str) -> float:
    """Internal → reported unit factor (µm per mm or ″ per rad)."""
    if name in LENGTHS or name.startswith("σ"):
        return 1e3
    return ARCSEC_PER_RAD


# -- the adjustment ---------------------------------------------------------------------------------
def _pinv(Jw: np.ndarray) -> np.ndarray:
    """The minimum-norm least-squares inverse of the whitened Jacobian, its columns scaled to 1 first (so
    that mm and rad weigh alike) and singular values below SINGULAR_TOLERANCE dropped — the rank the
    identifiability check sees. An estimable parameter's row of it is the same for every generalised
    inverse: what the fit reports does not depend on how the inseparable ones are shared out."""
    norms = np.linalg.norm(Jw, axis=0)
    scale = np.where(norms > 1e-12 * max(float(norms.max()), 1e-300), norms, np.inf)
    P = np.linalg.pinv(Jw / scale, rcond=SINGULAR_TOLERANCE)
    return np.asarray(P / scale[:, None])


@dataclass(frozen=True)
class _Adjustment:
    layout: _Layout
    rows: np.ndarray
    d: np.ndarray  # the fitted displacements, drift corrected (N_fit, 3), mm
    x: np.ndarray
    estimable: np.ndarray
    variances: dict[str, np.ndarray]  # per source, each parameter's variance
    sources: dict[str, np.ndarray]
    W_half: np.ndarray
    J: np.ndarray
    identifiability: Identifiability
    iterations: int
    linearisation_um: float


def _analyse(poses: RTestPoses, setup: RTestSetup, nest: NestCalibration, stated: StatedUncertainty,
             d_all_mm: np.ndarray, drift_mm: np.ndarray, solve: bool) -> _Adjustment:
    n_spheres = len(np.asarray(setup.spheres_mm).reshape(-1, 3))
    if np.any(np.asarray(poses.sphere) < 0) or np.any(np.asarray(poses.sphere) >= n_spheres):
        raise RTestDataError(f"poses name sphere set-ups beyond the {n_spheres} given")
    rows, L, w, group, before = _drift_map(poses, setup)
    layout = _layout(poses, n_spheres, rows)
    d = (L @ d_all_mm.ravel()).reshape(-1, 3)
    W_half = np.kron(np.eye(len(rows)), _whitening(nest, stated))
    x = np.zeros(layout.size)
    J = _jacobian(x, layout, poses, setup, rows)
    estimable, why = _identify(W_half @ J, layout.names)
    iterations, linearisation = 0, 0.0
    if solve:
        J0, f0 = J.copy(), _model(x, np.zeros(4), layout, poses, setup, rows).ravel()
        for iterations in range(1, MAX_ITERATIONS + 1):
            r = d.ravel() - _model(x, np.zeros(4), layout, poses, setup, rows).ravel()
            step = _pinv(W_half @ J) @ (W_half @ r)
            x = x + step
            J = _jacobian(x, layout, poses, setup, rows)
            if np.max(np.abs(step)) < STEP_TOLERANCE:
                break
        else:
            raise RTestDataError(f"the adjustment did not converge in {MAX_ITERATIONS} iterations: the location errors "
                                 "or set-up offsets are beyond what the model follows (millimetres, degrees)")
        exact = _model(x, np.zeros(4), layout, poses, setup, rows).ravel()
        linearisation = float(np.max(np.abs(exact - (f0 + J0 @ x)))) * 1e3
    H = _pinv(W_half @ J) @ W_half  # influence of the displacements (mm) on every parameter (estimable rows unique)
    sources = _sources(poses, setup, nest, stated, d_all_mm, drift_mm, L, w, group, before)
    variances = {name: np.sum((H @ F) ** 2, axis=1) for name, F in sources.items()}
    structural = _structural(W_half @ J, W_half @ _jacobian(x, layout, poses, setup, rows, structural_columns=True))
    ident = Identifiability(tuple(_display(layout.names[i]) for i in np.nonzero(estimable)[0] if i < 8),
                            {_display(k): v for k, v in why.items()}, {_display(k): v for k, v in structural.items()})
    return _Adjustment(layout, rows, d, x, estimable, variances, sources, W_half, J, ident, iterations, linearisation)


def _suffix(name: str) -> str:
    return ("_um" if name in LENGTHS else "_arcsec") if name in MODEL_NAMES else ""


def _parameter(symbol: str, value: float, variances: dict[str, np.ndarray], i: int, factor: float) -> Parameter:
    budget = {src: float(np.sqrt(v[i])) * factor for src, v in variances.items()}
    return Parameter(symbol, value * factor, float(np.sqrt(sum(b * b for b in budget.values()))), budget)


def solve_rtest(poses: RTestPoses, readings_um: np.ndarray, setup: RTestSetup, nest: NestCalibration,
                stated: StatedUncertainty) -> RTestResult:
    """The location errors with their budgets from the readings (N, 3) µm, each relative to the nest's
    zero (the sphere centre at the nest zero point reads 0), taken at the poses. Only what the poses
    separate is reported (``identifiability`` says why the rest is not); the fit itself keeps every
    parameter (minimum norm where the data cannot tell them apart), so a combination the data do see is
    never forced onto the reported ones. RTestDataError for readings the model cannot take (a contact off
    its flat face, a drift pair that is none)."""
    m = np.asarray(readings_um, float)
    if m.shape != (len(poses.joints), 3) or not np.all(np.isfinite(m)):
        raise RTestDataError(f"readings: {len(poses.joints)} rows of three finite numbers, one per pose")
    d_all = nest.displacement_mm(m)
    ok = flat_contact_ok(d_all, nest, setup.flat_radius_mm)
    if not ok.all():
        k, i = (int(v[0]) for v in np.nonzero(~ok))
        raise RTestDataError(f"pose {k + 1}: sensor {i + 1}'s contact left its flat face (more than "
                             f"{setup.flat_radius_mm:g} mm across it), where the nest's linear form no longer holds: "
                             "centre the sphere in the nest at the start, or use sensors with larger flats")
    drifts = np.array([d_all[i1] - d_all[i0] for i0, i1 in setup.pairs()]).reshape(-1, 3)
    drift = drifts[0] if len(drifts) else np.zeros(3)
    adj = _analyse(poses, setup, nest, stated, d_all, drifts, True)
    layout, rows, x, W_half = adj.layout, adj.rows, adj.x, adj.W_half
    r = adj.d.ravel() - _model(x, np.zeros(4), layout, poses, setup, rows).ravel()
    V = sum(F @ F.T for F in adj.sources.values())
    check = residual_check(W_half @ r, W_half @ V @ W_half.T, 0, jacobian=W_half @ adj.J)

    def reported(symbol: str, i: int, factor: float) -> Parameter:
        if not adj.estimable[i]:
            return Parameter(symbol, float("nan"), float("nan"), {})
        return _parameter(symbol, float(x[i]), adj.variances, i, factor)

    location = {LOCATION_SYMBOLS[i]: reported(LOCATION_SYMBOLS[i], i, _unit(name))
                for i, name in enumerate(LOCATION_NAMES) if adj.estimable[i]}
    setup_offsets = []
    for j in range(layout.n_spheres):
        trio = [reported(f"σ{j + 1}_{axis}_um", 8 + 3 * j + a, 1e3) for a, axis in enumerate("xyz")]
        setup_offsets.append((trio[0], trio[1], trio[2]))
    ecc = {layout.keys[0]: Parameter("ECC_arcsec", 0.0, 0.0, {})}
    for q, key in enumerate(layout.keys[1:], start=1):
        i = 8 + 3 * layout.n_spheres + q - 1
        if adj.estimable[i]:
            ecc[key] = reported("ECC_arcsec", i, ARCSEC_PER_RAD)
    ns = 3 * layout.n_spheres

    def at(loc: bool, ecc_: bool) -> np.ndarray:
        y = x.copy()
        if not loc:
            y[:8] = 0.0
        if not ecc_:
            y[8 + ns:] = 0.0
        return _model(y, np.zeros(4), layout, poses, setup, rows)

    nominal = _model(np.zeros_like(x), np.zeros(4), layout, poses, setup, rows)
    setup_only = at(False, False) - nominal  # what the spheres' set-up offsets alone do
    compensated = at(True, True) - at(False, True)  # what the eight location errors do
    d = adj.d
    return RTestResult(location, setup_offsets, ecc, adj.identifiability, check, drift * 1e3, (d - setup_only) * 1e3,
                       (d - setup_only - compensated) * 1e3, r.reshape(-1, 3) * 1e3, adj.iterations,
                       adj.linearisation_um, rows, drifts * 1e3)


def predict_rtest(poses: RTestPoses, setup: RTestSetup, nest: NestCalibration, stated: StatedUncertainty) -> RTestPrediction:
    """Before anything moves: each location error's expected U (k = 2) and budget, and the
    identifiability of the plan, at the nominal machine (no errors, the sphere where the path assumes
    it; the drift as ``stated.expected_drift_um`` on each axis)."""
    n = len(poses.joints)
    drift = np.full((max(len(setup.pairs()), 1), 3), stated.expected_drift_um * 1e-3)
    adj = _analyse(poses, setup, nest, stated, np.zeros((n, 3)), drift, False)
    U, budget = {}, {}
    for i, name in enumerate(LOCATION_NAMES):
        if adj.estimable[i]:
            p = _parameter(LOCATION_SYMBOLS[i], 0.0, adj.variances, i, _unit(name))
            U[LOCATION_SYMBOLS[i]] = p.U
            budget[LOCATION_SYMBOLS[i]] = p.budget
    return RTestPrediction(U, budget, adj.identifiability)


def nominal_nest(directions: np.ndarray, moves_mm: np.ndarray, noise_um: float) -> NestCalibration:
    """The nest calibration a plan expects: the nominal sensor directions (3, 3; rows) and the
    covariance :func:`~rtcal.solvers.rtest.calibrate_nest` would give with these moves and noise."""
    D = np.asarray(moves_mm, float) * 1e3
    X = np.column_stack([np.ones(len(D)), -D])
    inv = np.linalg.inv(X.T @ X)
    cov = np.zeros((9, 9))
    for i in range(3):
        cov[3 * i:3 * i + 3, 3 * i:3 * i + 3] = noise_um**2 * inv[1:, 1:]
    S = np.asarray(directions, float)
    return NestCalibration(S, cov, np.zeros((len(D), 3)), np.zeros(3))


def location_from_lines(a_point: np.ndarray, a_dir: np.ndarray, c_point: np.ndarray, c_dir: np.ndarray,
                        geometry: TrunnionGeometry) -> dict[str, float]:
    """The eight location errors (µm, arcsec) of two lines (A's and C's at the reference pose), by the
    definitions in :mod:`rtcal.solvers.rtest` — what a simulated machine's truth is stated as."""
    xa, ya, za = geometry.a_point_mm
    xc, yc, zc = geometry.c_point_mm
    na = np.asarray(a_dir, float) / np.linalg.norm(a_dir)
    if na[0] < 0:
        na = -na
    nc = np.asarray(c_dir, float) / np.linalg.norm(c_dir)
    if nc[2] < 0:
        nc = -nc
    t = (xa - a_point[0]) / na[0]
    ya_at, za_at = a_point[1] + t * na[1], a_point[2] + t * na[2]
    s = (zc - c_point[2]) / nc[2]
    xc_at, yc_at = c_point[0] + s * nc[0], c_point[1] + s * nc[1]
    a_y_at_xc = a_point[1] + (xc - a_point[0]) / na[0] * na[1]
    b0a = np.arctan2(-na[2], na[0])
    values = {"Y0A_um": ya_at - ya, "Z0A_um": za_at - za, "B0A_arcsec": b0a, "C0A_arcsec": np.arctan2(na[1], na[0]),
              "X0C_um": xc_at - xc, "Y0C_um": (yc_at - a_y_at_xc) - (yc - ya),
              "A0C_arcsec": -np.arctan2(nc[1], nc[2]), "B0C_arcsec": np.arctan2(nc[0], nc[2]) - b0a}
    return {s_: to_symbol(s_, float(values[s_])) for s_ in LOCATION_SYMBOLS}
