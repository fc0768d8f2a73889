"""Encoder error from tilt and radial motion of the shaft (seed 001), as pure functions.

Conventions (also in docs/seed001.md): heights are measured downward from the tilt centre;
the indicators read the shaft's Y displacement (the grating's tangential direction at the read
head, on +X) at heights L1 and L2; a right-handed tilt εx moves a point a height h below the
centre by +εx·h in Y. Hence

    r(h) = δy + εx·h,   εx = (r2 − r1)/(L2 − L1),   δy = r1 − εx·L1,

and the grating, Zs below the centre, shifts tangentially by Δt = δy + Zs·εx, which the encoder
reads as an extra angle Δt/rE (positive: the encoder reads more than the table turned):

    Δt = r1 + (r2 − r1)·(Zs − L1)/(L2 − L1)

— an extrapolation from the indicators whenever Zs lies outside [L1, L2], which multiplies
their errors by |1 − a| + |a| with a = (Zs − L1)/(L2 − L1).

Dial indicators, the encoder and the autocollimator have arbitrary zeros, constant while the
polygon stays seated: encoder errors are reported up to one constant per seating (its mean
over the faces removed, the same for both directions), and the positioning error εz relative
to the first target of the first direction (ISO 230-1's ECC), so that a reversal between the
directions stays visible.

Uncertainty (GUM, linear): every reported value is a linear function of the visits' readings
and of the face errors used, so its covariance is T·Σ·Tᵀ exactly, with Σ from per-visit random
errors (Type A from repeated runs or the closure residuals; else the stated instrument noise,
resolution/√12 and stage repeatability, Type B) and from the certificate's uncertainty (common
to every visit of a face). Repeatability of the stage cancels in the measured encoder error
(encoder and autocollimator see the same actual angle) except through face errors a closure
estimated from the readings; a reading's digit rounds the same way run after run, so repeated
runs cannot see it and it stays a Type B beside their scatter. A skipped reading leaves its
visit out, not its series.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rtcal.solvers.closure import ClosureResult, solve_closure
from rtcal.solvers.harmonics import (
    HarmonicFit,
    fit_harmonics,
    grid_nyquist,
    harmonic_amplitudes,
    nyquist_order,
    resolvable_orders,
    smooth_values,
)
from rtcal.solvers.uncertainty import BudgetComponent, DeviationBudget, ResidualCheck, SourceType
from rtcal.units import ARCSEC_PER_RAD


def separate_tilt_radial(r1_mm, r2_mm, l1_mm: float, l2_mm: float):
    """(εx in rad, δy at the tilt centre in mm) from two indicator readings."""
    tilt = (np.asarray(r2_mm) - np.asarray(r1_mm)) / (l2_mm - l1_mm)
    return tilt, np.asarray(r1_mm) - tilt * l1_mm


def extrapolation_factor(l1_mm: float, l2_mm: float, zs_mm: float) -> float:
    """a = (Zs − L1)/(L2 − L1): Δt = (1 − a)·r1 + a·r2."""
    return (zs_mm - l1_mm) / (l2_mm - l1_mm)


def grating_shift_mm(r1_mm, r2_mm, l1_mm: float, l2_mm: float, zs_mm: float):
    """Δt = δy + Zs·εx at the grating, from the indicators."""
    a = extrapolation_factor(l1_mm, l2_mm, zs_mm)
    return (1.0 - a) * np.asarray(r1_mm) + a * np.asarray(r2_mm)


def predicted_encoder_error_arcsec(shift_mm, radius_mm: float):
    """The encoder's misreading Δt/rE, arcsec."""
    return np.asarray(shift_mm) / radius_mm * ARCSEC_PER_RAD


@dataclass(frozen=True)
class AbbeVisits:
    """Every visit of the stage to a commanded angle, with the readings taken there."""

    commanded_deg: np.ndarray
    seating_deg: np.ndarray
    seating_index: np.ndarray
    direction: np.ndarray  # +1 / −1
    encoder_deg: np.ndarray
    autocollimator_arcsec: np.ndarray  # NaN where no face was in front
    indicator1_um: np.ndarray
    indicator2_um: np.ndarray
    run: np.ndarray | None = None  # 0-based run of each visit (None: all one run)


@dataclass(frozen=True)
class AbbeNoise:
    """The instruments' stated 1σ (Type B; repeated runs replace the random parts by Type A)."""

    autocollimator_noise_arcsec: float = 0.0
    autocollimator_resolution_arcsec: float = 0.0
    stage_repeatability_arcsec: float = 0.0
    encoder_noise_arcsec: float = 0.0
    encoder_resolution_arcsec: float = 0.0
    indicator_noise_um: float = 0.0
    indicator_resolution_um: float = 0.0
    certificate_uncertainty_arcsec: float = 0.0
    estimate: bool = True  # random parts from runs or closure residuals where possible; False: as stated
    autocollimator_scale_u_ppm: float = 0.0  # its scale's standard uncertainty, from its calibration certificate
    autocollimator_calibration_u_arcsec: float = 0.0  # its certificate's expanded uncertainty (k = 2) of an indication
    indicator_scale_u_ppm: float = 0.0  # each dial indicator's scale, standard uncertainty, from its certificate


@dataclass(frozen=True)
class AbbeSetup:
    faces: int
    indicator_heights_mm: tuple[float, float]
    grating_offset_mm: float
    encoder_radius_mm: float
    certificate_arcsec: np.ndarray | None  # None: separate face errors by closure
    max_order: int = 24
    noise: AbbeNoise = AbbeNoise()


@dataclass(frozen=True)
class ReferenceDeviation:
    """εz at the polygon's faces relative to the first target of the first direction (ECC), per
    (target, direction) averaged over runs and seatings, with its budget; and per run."""

    target_deg: np.ndarray
    direction: np.ndarray
    cumulative_arcsec: np.ndarray
    budget: DeviationBudget
    steps: np.ndarray  # per-step differences within each direction (rows × targets)
    rows_target_deg: np.ndarray  # per (target, direction, run)
    rows_direction: np.ndarray
    rows_run: np.ndarray  # from 1
    rows_arcsec: np.ndarray
    rows_uncertainty_arcsec: np.ndarray
    random_source: str  # where the per-visit random error's size came from


@dataclass(frozen=True)
class AbbeEstimate:
    angle_deg: np.ndarray  # per step: distinct (direction, angle), positive first
    direction: np.ndarray
    tilt_x_arcsec: np.ndarray
    radial_y_um: np.ndarray
    predicted_encoder_error_arcsec: np.ndarray
    predicted_sigma_arcsec: np.ndarray
    measured_encoder_error_arcsec: np.ndarray  # NaN where no face was in front
    measured_sigma_arcsec: np.ndarray
    residual_arcsec: np.ndarray
    residual_sigma_arcsec: np.ndarray
    positioning_error_arcsec: np.ndarray  # εz (ECC) from the autocollimator, NaN off the faces
    positioning_sigma_arcsec: np.ndarray
    encoder_vs_command_arcsec: np.ndarray
    face_error_arcsec: np.ndarray  # used: the certificate or the closure result
    closure: ClosureResult | None
    closure_table_angle_deg: np.ndarray | None
    closure_table_direction: np.ndarray | None
    reversal_arcsec: float | None  # from the encoder: mean ↑ − ↓ of encoder − command
    reversal_reference_arcsec: float | None  # from the autocollimator: mean ↑ − ↓ of εz
    repeatability_arcsec: float | None  # pooled 1σ of εz over repeated runs (None: one run)
    harmonics: dict[str, HarmonicFit]
    extrapolation_factor: float
    reference: ReferenceDeviation
    random_sigma_arcsec: float  # the per-visit random error of the reference as used (estimated or stated)
    random_sigma_type: str = "B"  # "A": estimated from closure residuals or runs; "B": as stated
    residual_check: ResidualCheck | None = None  # the repeated readings (runs or closure) against the stated noise
    scale_check: ScaleCheck | None = None  # measured against predicted encoder error: the geometry's scale


SCALE_BAND = 1.5  # measured/predicted beyond ×1.5 or ÷1.5: not an encoder's own error, a wrong geometry value
SCALE_DELTA_CHI2 = 49.0  # and the scale's share of χ² beyond 7σ (chance 3·10⁻¹²)


@dataclass(frozen=True)
class ScaleCheck:
    """Does the measured encoder error follow the predicted one at the scale the geometry says?

    measured = k·predicted + a·sin θ + b·cos θ + c is fitted with the stated 1σ of each step's
    residual (weights 1/σ²); the once-per-turn terms take the encoder's eccentricity, its own
    error. The residual's χ² alone (its Birge ratio against the stated noise) cannot be the test:
    the residual holds the encoder's own graduation error, which the method measures (an honest
    closure run shows a Birge ratio of 11, the ISO run with 0.032 mm for 32 mm the same 11). What
    no honest encoder error does is follow the prediction's shape at another scale: the part of χ²
    a scale removes, (k̂ − 1)²/σ_k², is χ²₁ when the geometry is right. The check fails when that
    part exceeds SCALE_DELTA_CHI2 and k̂ lies outside [1/SCALE_BAND, SCALE_BAND]: the prediction,
    i.e. encoder_radius_mm (prediction ∝ 1/rE), grating_offset_mm or indicator_heights_mm, is
    then wrong by about a factor 1/k̂."""

    scale: float  # k̂: measured ≈ k̂ · predicted
    scale_sigma: float
    delta_chi2: float  # (k̂ − 1)²/σ_k²
    birge_ratio: float  # √(χ²/ν) of measured − predicted against its stated σ
    dof: int
    failed: bool

    def message(self, encoder_radius_mm: float) -> str:
        return (f"the measured encoder error is {self.scale:.3g} × the predicted one (±{self.scale_sigma:.2g}; that "
                f"scale's χ² share {self.delta_chi2:.0f} against the stated noise, Birge ratio {self.birge_ratio:.3g} over "
                f"{self.dof + 1} steps): the readings contradict the procedure's geometry. Likely cause: a geometry value "
                f"wrong by a factor ≈ {1 / self.scale:.3g} — geometry.encoder_radius_mm = {encoder_radius_mm:g} fits as "
                f"≈ {encoder_radius_mm / self.scale:.3g} mm (m typed as mm? a diameter for a radius?), or grating_offset_mm "
                "or indicator_heights_mm")


def scale_check(angle_deg: np.ndarray, measured: np.ndarray, predicted: np.ndarray, sigma: np.ndarray,
                predicted_sigma: np.ndarray | None = None) -> ScaleCheck | None:
    """:class:`ScaleCheck` over the steps where all are finite (None: too few, or no prediction). The fit
    measured = k·predicted + once-per-turn + constant leaves an encoder's eccentricity (its own
    error, purely order 1) out of k̂. The prediction's own noise (``predicted_sigma``: coarse
    indicators on a shaft that barely moves) pulls k̂ towards 0 by λ = 1 − σ_p²/var(predicted):
    k̂ and σ_k are divided by λ (errors in the variable, at least 0.1)."""
    ok = np.isfinite(measured) & np.isfinite(predicted) & np.isfinite(sigma) & (sigma > 0)
    if predicted_sigma is not None:
        ok &= np.isfinite(predicted_sigma)
    if ok.sum() < 6:
        return None
    th = np.radians(np.asarray(angle_deg, float)[ok])
    m, p, w = measured[ok], predicted[ok], 1.0 / sigma[ok] ** 2
    X = np.column_stack([p, np.sin(th), np.cos(th), np.ones_like(th)])
    N = X.T @ (w[:, None] * X)
    if not np.all(np.isfinite(N)) or np.linalg.matrix_rank(N) < 4:
        return None
    cov = np.linalg.inv(N)
    k = float((cov @ (X.T @ (w * m)))[0])
    sk = float(np.sqrt(cov[0, 0]))
    if predicted_sigma is not None:  # the prediction's variation beyond the nuisance terms, against its noise
        Z = X[:, 1:]
        rest = p - Z @ np.linalg.lstsq(Z * np.sqrt(w)[:, None], p * np.sqrt(w), rcond=None)[0]
        spread = float(np.sum(w * rest**2))
        lam = max(1.0 - float(np.sum(w * predicted_sigma[ok] ** 2)) * (len(p) - 3) / len(p) / spread, 0.1) if spread > 0 else 1.0
        k, sk = k / lam, sk / lam
    dchi2 = (k - 1.0) ** 2 / sk**2
    dof = int(ok.sum()) - 1
    birge = float(np.sqrt(np.sum(w * (m - p - np.average(m - p, weights=w)) ** 2) / max(dof, 1)))
    outside = not (1.0 / SCALE_BAND <= k <= SCALE_BAND)
    return ScaleCheck(k, sk, float(dchi2), birge, dof, bool(outside and dchi2 > SCALE_DELTA_CHI2))


SMOOTH_MOTION_ORDERS = 4  # the shaft motion whose rounding is simulated: orders 1..4 of the indicator readings


def _wrap_arcsec(value_deg):
    return (np.asarray(value_deg) + 180.0) % 360.0 - 180.0


def _mean_operator(keys: np.ndarray, n_keys: int) -> np.ndarray:
    """(n_keys × n) averaging each key's entries (a row of zeros for a key with none)."""
    M = np.zeros((n_keys, len(keys)))
    M[keys, np.arange(len(keys))] = 1.0
    counts = M.sum(axis=1, keepdims=True)
    return np.divide(M, counts, out=np.zeros_like(M), where=counts > 0)


def _centring_groups(groups: np.ndarray, reference: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """(members, reference members) of each group that has a reference."""
    out = []
    for g in np.unique(groups):
        members = np.flatnonzero(groups == g)
        ref = members[reference[members]]
        if ref.size:
            out.append((members, ref))
    return out


def _centred(X: np.ndarray, groups: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """X·C, C (n×n) subtracting from each entry the mean of its group's ``reference`` entries, without C:
    (X·C)[:, ref] −= Σ over the group's members of X[:, member] / |ref| — O(rows·n), not O(rows·n²)."""
    X = np.asarray(X, float)
    out = X.copy()
    for members, ref in _centring_groups(groups, reference):
        out[:, ref] -= X[:, members].sum(axis=1, keepdims=True) / ref.size
    return out


def _centre(x: np.ndarray, groups: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """C·x: each entry less the mean of its group's ``reference`` entries."""
    out = np.array(x, float)
    for members, ref in _centring_groups(groups, reference):
        out[members] -= np.mean(x[ref])
    return out


def steps_within_directions(directions: np.ndarray) -> np.ndarray:
    """(k×n): differences of consecutive targets of the same direction (targets sorted per direction)."""
    d = np.asarray(directions)
    rows = []
    for sense in (1, -1):
        idx = np.flatnonzero(d == sense)
        for a, b in zip(idx[:-1], idx[1:]):
            r = np.zeros(len(d))
            r[a], r[b] = -1.0, 1.0
            rows.append(r)
    return np.array(rows).reshape(-1, len(d))


def _per_key(keys: np.ndarray) -> np.ndarray:
    """(n × keys): 1 where a visit belongs to a key — for an error all runs of that key share (a
    digit's rounding of the same value)."""
    _, idx = np.unique(keys, return_inverse=True)
    E = np.zeros((len(keys), int(idx.max()) + 1 if len(keys) else 0))
    E[np.arange(len(keys)), idx] = 1.0
    return E


def _pooled_sigma(values: np.ndarray, groups: np.ndarray) -> tuple[float, int] | None:
    """Pooled 1σ of repeated values within groups, and its degrees of freedom (None: no repeats)."""
    ss, dof = 0.0, 0
    for g in np.unique(groups):
        x = values[groups == g]
        if len(x) > 1:
            ss += float(np.sum((x - x.mean()) ** 2))
            dof += len(x) - 1
    return (float(np.sqrt(ss / dof)), dof) if dof else None


def _cov(T: np.ndarray, variance: float) -> np.ndarray:
    return variance * (T @ T.T)


def _residual_check(noise: AbbeNoise, pooled: tuple[float, int] | None, closure, n_closure: int) -> ResidualCheck | None:
    """The scatter the data show — over repeated runs, or the closure fit's residuals — against the
    stated per-visit random error (autocollimator noise and digit, stage repeatability): χ² = ν·s²/s₀²."""
    from scipy.stats import chi2 as chi2_dist

    s0 = float(np.sqrt(noise.autocollimator_noise_arcsec**2 + noise.autocollimator_resolution_arcsec**2 / 12
                       + noise.stage_repeatability_arcsec**2))
    if s0 <= 0:
        return None
    if closure is not None and closure.sigma > 0:
        dof = max(int(round(n_closure * closure.residual_rms**2 / closure.sigma**2)), 1)
        sigma = closure.sigma
    elif pooled is not None:
        sigma, dof = pooled
    else:
        return None
    chi2 = dof * (sigma / s0) ** 2
    return ResidualCheck(float(chi2), int(dof), float(sigma / s0), float(chi2_dist.sf(chi2, dof)))


@dataclass(frozen=True)
class _Steps:
    """The distinct (direction, angle) of the visits, positive direction first: the rows of every
    per-step result, so that both directions of one angle stay apart (reversal)."""

    index: np.ndarray  # each visit's step
    angle_deg: np.ndarray
    direction: np.ndarray

    @property
    def n(self) -> int:
        return len(self.angle_deg)

    def mean(self, x: np.ndarray) -> np.ndarray:
        """Mean over the visits of each step (NaN where none is finite)."""
        ok = np.isfinite(x)
        out = np.full(self.n, np.nan)
        sums = np.bincount(self.index[ok], x[ok], self.n)
        counts = np.bincount(self.index[ok], minlength=self.n)
        out[counts > 0] = sums[counts > 0] / counts[counts > 0]
        return out


def _steps(direction: np.ndarray, angle_deg: np.ndarray) -> _Steps:
    """Each visit's step among the distinct (direction, angle), sorted positive direction first."""
    steps = sorted({(int(d), float(a)) for d, a in zip(direction, angle_deg)}, key=lambda k: (-k[0], k[1]))
    key_of = {k: i for i, k in enumerate(steps)}
    index = np.array([key_of[(int(d), float(a))] for d, a in zip(direction, angle_deg)])
    return _Steps(index, np.array([k[1] for k in steps]), np.array([k[0] for k in steps]))


@dataclass(frozen=True)
class _Geometry:
    """The visits as every phase reads them: where the stage was, which face and seating, the
    shaft's motion from the indicators and the encoder's reading against the command."""

    angle_deg: np.ndarray  # commanded, in [0, 360)
    run: np.ndarray
    n_runs: int
    seating: np.ndarray
    face: np.ndarray  # the polygon face in front
    has_ac: np.ndarray  # a reference reading was taken
    group: np.ndarray  # harmonic fits: one offset per seating and direction
    tilt_rad: np.ndarray
    radial_mm: np.ndarray
    a_fac: float  # extrapolation factor (Zs − L1)/(L2 − L1)
    arcsec_per_um: float  # a tangential µm at the grating as the encoder's ″
    predicted_arcsec: np.ndarray  # per visit
    enc_vs_cmd_arcsec: np.ndarray
    steps: _Steps
    key: np.ndarray  # (seating, step) per visit: what a digit rounds the same way in every run


def _visit_geometry(v: AbbeVisits, setup: AbbeSetup) -> _Geometry:
    """Tilt/radial separation and the predicted encoder error per visit (the model of the module
    docstring), and the bookkeeping (faces, seatings, runs, steps) every later phase indexes by."""
    pitch = 360.0 / setup.faces
    l1, l2 = setup.indicator_heights_mm
    cmd = np.asarray(v.commanded_deg, float)
    run = np.zeros(len(cmd), int) if v.run is None else np.asarray(v.run, int)
    angle = np.round(np.mod(cmd, 360.0), 9) % 360.0
    has_ac = np.isfinite(v.autocollimator_arcsec)
    if not has_ac.any():
        raise ValueError("no autocollimator reading: no polygon face was in front at any visit")
    seating = np.asarray(v.seating_index, int)
    tilt_rad, radial_mm = separate_tilt_radial(v.indicator1_um * 1e-3, v.indicator2_um * 1e-3, l1, l2)
    shift = grating_shift_mm(v.indicator1_um * 1e-3, v.indicator2_um * 1e-3, l1, l2, setup.grating_offset_mm)
    steps = _steps(v.direction, angle)
    return _Geometry(
        angle_deg=angle, run=run, n_runs=len(np.unique(run)), seating=seating,
        face=np.mod(np.round((cmd - v.seating_deg) / pitch).astype(int), setup.faces), has_ac=has_ac,
        group=seating * 2 + (v.direction < 0), tilt_rad=tilt_rad, radial_mm=radial_mm,
        a_fac=extrapolation_factor(l1, l2, setup.grating_offset_mm),
        arcsec_per_um=1e-3 / setup.encoder_radius_mm * ARCSEC_PER_RAD,
        predicted_arcsec=predicted_encoder_error_arcsec(shift, setup.encoder_radius_mm),
        enc_vs_cmd_arcsec=_wrap_arcsec(v.encoder_deg - cmd) * 3600.0, steps=steps,
        key=seating * steps.n + steps.index)


@dataclass(frozen=True)
class _FaceErrors:
    """The face visits' readings and the face errors they are corrected by: ε̂ = (I − B·K_f)·y exactly
    (K_f None: the certificate's, ε̂ = y − B·f), the linear map the covariances propagate through —
    applied as X − (X·B)·K_f, never as an n×n matrix (:meth:`through`)."""

    ac: np.ndarray  # the visits with a reference reading
    y: np.ndarray  # their autocollimator readings
    B: np.ndarray  # face visit × face: 1 where that face was in front
    face_error: np.ndarray  # used: the certificate or the closure result
    K_f: np.ndarray | None  # faces ← y: closure's map to the face errors (None: the certificate's)
    eps: np.ndarray  # εz + the seating's constant, per face visit
    closure: ClosureResult | None
    closure_angles_deg: np.ndarray | None
    closure_dirs: np.ndarray | None
    n_closure: int  # face visits the closure used (0: the certificate)

    def through(self, X: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """X·(I − B·K_f), or X·(I − B·K_f)[rows] for X over those rows only (X·I[rows] puts X's columns at rows)."""
        n = len(self.ac)
        if rows is None:
            spread = np.asarray(X, float)
            B = self.B
        else:
            spread = np.zeros((X.shape[0], n))
            spread[:, np.flatnonzero(rows) if rows.dtype == bool else rows] = X
            B = self.B[rows]
        return spread if self.K_f is None else spread - (X @ B) @ self.K_f

    def closure_part(self, X: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """X·(B·K_f)[rows]: the part of ε̂ the closure's face errors carry (zero with a certificate)."""
        if self.K_f is None:
            return np.zeros((X.shape[0], len(self.ac)))
        return (X @ self.B[rows]) @ self.K_f


def _closure(v: AbbeVisits, setup: AbbeSetup, g: _Geometry, ac: np.ndarray, y: np.ndarray
             ) -> tuple[ClosureResult, np.ndarray, np.ndarray, np.ndarray, int]:
    """Face errors by closure from the seatings at whole multiples of the pitch (only there does
    every target meet a face), and K_f, the map from the face visits' readings to them."""
    pitch = 360.0 / setup.faces
    angle = g.angle_deg
    whole_v = g.has_ac & (np.abs((v.seating_deg / pitch) - np.round(v.seating_deg / pitch)) < 1e-9)
    whole = np.flatnonzero(whole_v[ac])  # positions within ac
    keys = sorted({(int(d), int(round(a / pitch)) % setup.faces) for d, a in zip(v.direction[ac][whole], angle[ac][whole])},
                  key=lambda k: (-k[0], k[1]))
    index = {k: i for i, k in enumerate(keys)}
    t_idx = [index[(int(d), int(round(a / pitch)) % setup.faces)] for d, a in zip(v.direction[ac][whole], angle[ac][whole])]
    closure = solve_closure(y[whole], np.array(t_idx), g.face[ac][whole], np.unique(g.seating[ac][whole], return_inverse=True)[1],
                            np.array([k[0] for k in keys]), setup.faces)
    n_t = len(keys)
    K_f = np.zeros((setup.faces, len(ac)))
    K_f[:, whole] = closure.solution_map[n_t : n_t + setup.faces]
    return closure, K_f, np.array([k[1] * pitch for k in keys]), np.array([k[0] for k in keys]), len(whole)


def _face_errors(v: AbbeVisits, setup: AbbeSetup, g: _Geometry) -> _FaceErrors:
    """The polygon's face errors — the certificate's, or closure's — taken out of the readings,
    leaving εz plus one constant per seating at each face visit."""
    ac = np.flatnonzero(g.has_ac)
    y = v.autocollimator_arcsec[ac]
    B = np.zeros((len(ac), setup.faces))
    B[np.arange(len(ac)), g.face[ac]] = 1.0
    if setup.certificate_arcsec is None:
        closure, K_f, angles, dirs, n_closure = _closure(v, setup, g, ac, y)
        face_error = closure.face_error
        return _FaceErrors(ac, y, B, face_error, K_f, y - B @ face_error, closure, angles, dirs, n_closure)  # ε̂ = (I − B·K_f)·y
    face_error = np.asarray(setup.certificate_arcsec, float)
    return _FaceErrors(ac, y, B, face_error, None, y - B @ face_error, None, None, None, 0)


@dataclass(frozen=True)
class _RowMap:
    """rows ← ε̂ per face visit as T = S − U·Wᵀ: S sparse (each (step, run) row the mean of its visits), U·Wᵀ of
    low rank (each seating's mean and the reference step taken out): T·X costs O(visits) and each row's norm a
    chunk of rows at a time, where the rows × visits matrix (rows ≈ visits: one per step and run) times the
    visits × visits map cost O(visits³) and O(visits²) of memory."""

    S: Any  # scipy.sparse (rows, n)
    U: np.ndarray  # (rows, k)
    W: np.ndarray  # (n, k)

    def times(self, X: np.ndarray) -> np.ndarray:
        """T·X."""
        return np.asarray(self.S @ X) - self.U @ (self.W.T @ X)

    def row_norms2(self, f: "_FaceErrors", chunk_rows: int = 256) -> np.ndarray:
        """‖(T·(I − B·K_f))_r‖² per row (T's own rows with a certificate), rows formed a chunk at a time."""
        out = np.empty(self.S.shape[0])
        for start in range(0, len(out), chunk_rows):
            stop = min(start + chunk_rows, len(out))
            T = self.S[start:stop].toarray() - self.U[start:stop] @ self.W.T
            out[start:stop] = np.sum(f.through(T) ** 2, axis=1)
        return out


@dataclass(frozen=True)
class _EpsOperators:
    """εz per step and per (step, run) row as linear maps of ε̂ per face visit: seating constants
    removed (mean over the seating's visits), averaged, referred to the first target of the first
    direction (ECC) — linear, so that the budget is T·Σ·Tᵀ."""

    centred_eps: np.ndarray  # ε̂ per face visit, each seating's mean removed
    T_eps: np.ndarray  # steps ← ε̂ per face visit
    face_steps: np.ndarray  # the steps with a reference reading
    eps_steps: np.ndarray  # εz per step, NaN off the faces
    row_keys: list[tuple[int, int]]  # (step, run)
    T_rows: _RowMap  # rows ← ε̂ per face visit


def _eps_operators(g: _Geometry, f: _FaceErrors) -> _EpsOperators:
    """The maps of :class:`_EpsOperators`; each run's rows referred to the same zero (the mean
    over runs at the first target), so that runs stay comparable."""
    import scipy.sparse as sp

    n_s, step_idx = g.steps.n, g.steps.index
    seating, every = g.seating[f.ac], np.ones(len(f.ac), bool)
    M = _mean_operator(step_idx[f.ac], n_s)
    face_steps = np.flatnonzero(M.sum(axis=1) > 0)
    ref_step = face_steps[0]  # the first target of the first direction
    R = np.eye(n_s) - np.outer(np.ones(n_s), np.eye(n_s)[ref_step])
    T_eps = _centred(R @ M, seating, every)
    eps_steps = T_eps @ f.eps
    eps_steps[np.setdiff1d(np.arange(n_s), face_steps)] = np.nan
    row_keys = sorted({(int(step_idx[i]), int(g.run[i])) for i in f.ac})
    row_of = {k: r for r, k in enumerate(row_keys)}
    rows = np.array([row_of[(int(step_idx[i]), int(g.run[i]))] for i in f.ac], int)
    n = len(f.ac)
    count = np.bincount(rows, minlength=len(row_keys))
    M_rows = sp.csr_matrix((1.0 / count[rows], (rows, np.arange(n))), shape=(len(row_keys), n))
    # (M_rows − 1·M[ref])·C = M_rows − Σ_g (M_rows·1_g)·1_gᵀ/|g| − 1·(M[ref]·C): sparse less rank seatings + 1
    groups = _centring_groups(seating, every)
    U = np.column_stack([np.asarray(M_rows[:, members].sum(axis=1)).ravel() for members, _ in groups]
                        + [np.ones(len(row_keys))])
    W = np.zeros((n, len(groups) + 1))
    for k, (members, ref) in enumerate(groups):
        W[ref, k] = 1.0 / ref.size
    W[:, -1] = _centred(M[ref_step][None, :], seating, every)[0]
    return _EpsOperators(_centre(f.eps, seating, every), T_eps, face_steps, eps_steps, row_keys, _RowMap(M_rows, U, W))


_RandomPart = tuple[str, SourceType, float, str]  # name, GUM type, 1σ per visit (″), note


def _random_parts(noise: AbbeNoise, closure: ClosureResult | None, pooled: tuple[float, int] | None,
                  n_runs: int) -> tuple[list[_RandomPart], str]:
    """The per-visit random error of ε̂ and where its size came from: the closure residuals or
    repeated runs when they can tell (Type A), else the stated instrument noise (Type B)."""
    if closure is not None and noise.estimate:
        return ([("closure residuals (autocollimator, repeatability)", "A", closure.sigma,
                  "per visit, from the closure fit's residuals")], "closure residuals")
    if pooled is not None and noise.estimate:
        return ([("repeatability over runs (autocollimator and stage)", "A", pooled[0],
                  f"per visit, pooled over {n_runs} runs ({pooled[1]} degrees of freedom)")], f"{n_runs} runs")
    return ([("autocollimator noise", "B", noise.autocollimator_noise_arcsec, "per reading, as stated"),
             ("autocollimator resolution", "B", noise.autocollimator_resolution_arcsec / np.sqrt(12),
              f"{noise.autocollimator_resolution_arcsec:g}″ digit, uniform (q/√12)"),
             ("stage repeatability", "B", noise.stage_repeatability_arcsec, "per visit, as stated")],
            "stated instrument noise" + (" (one run)" if pooled is None else ""))


def _budget_components(noise: AbbeNoise, g: _Geometry, f: _FaceErrors, ops: _EpsOperators,
                       random_parts: list[_RandomPart], pooled: tuple[float, int] | None) -> list[BudgetComponent]:
    """εz's budget, one component per independent source, each its covariance over the face steps:
    the random parts, then what repeats run after run (a digit, the certificates) and the scale."""
    fs, T_y = ops.face_steps, f.through(ops.T_eps)
    components = [BudgetComponent(name, typ, sigma, "″", _cov(T_y[fs], sigma**2), typ == "A", note)
                  for name, typ, sigma, note in random_parts if sigma > 0]
    if f.closure is None and pooled is not None and noise.estimate and noise.autocollimator_resolution_arcsec > 0:
        E_ac = _per_key(g.key[f.ac])  # a digit rounds the same value the same way every run
        components.append(BudgetComponent("autocollimator resolution", "B", noise.autocollimator_resolution_arcsec / np.sqrt(12),
                                          "″", _cov((T_y @ E_ac)[fs], noise.autocollimator_resolution_arcsec**2 / 12),
                                          False, "digit q, uniform (q/√12), the same at a target in every run"))
    if f.closure is None and noise.certificate_uncertainty_arcsec > 0:
        T_f = -(ops.T_eps @ f.B)[fs]
        components.append(BudgetComponent("polygon certificate", "B", noise.certificate_uncertainty_arcsec, "″",
                                          _cov(T_f, noise.certificate_uncertainty_arcsec**2), False,
                                          "per face, common to every visit of that face"))
    if noise.autocollimator_scale_u_ppm > 0:  # a scale error s reads s·y too: ε̂ moves by T·(s·y)
        s = (T_y @ np.nan_to_num(f.y))[fs] * noise.autocollimator_scale_u_ppm * 1e-6
        components.append(BudgetComponent("autocollimator calibration (scale)", "B", noise.autocollimator_scale_u_ppm, "ppm",
                                          np.outer(s, s), False, "its scale's standard uncertainty from its calibration "
                                          "certificate, times each reading (one error for every reading)"))
    if noise.autocollimator_calibration_u_arcsec > 0:
        E_cal = _per_key(g.key[f.ac])  # the same indication error at a target in every run
        components.append(BudgetComponent("autocollimator calibration (certificate U)", "B",
                                          noise.autocollimator_calibration_u_arcsec / 2, "″",
                                          _cov((T_y @ E_cal)[fs], (noise.autocollimator_calibration_u_arcsec / 2) ** 2),
                                          False, "its certificate's expanded uncertainty of an indication (k = 2), "
                                          "the same at a target in every run"))
    if not components:
        components.append(BudgetComponent("none stated", "B", 0.0, "″", np.zeros((len(fs), len(fs))), False,
                                          "no noise stated for the instruments and only one run"))
    return components


def _reference_deviation(noise: AbbeNoise, g: _Geometry, f: _FaceErrors, ops: _EpsOperators, random_parts: list[_RandomPart],
                         source: str, pooled: tuple[float, int] | None) -> tuple[ReferenceDeviation, np.ndarray]:
    """εz per step with its budget, and per run with each row's own 1σ (random parts and, with a
    certificate, its uncertainty); and εz's 1σ per step (NaN off the faces)."""
    budget = DeviationBudget(_budget_components(noise, g, f, ops, random_parts, pooled))
    row_var = sum(sigma**2 * ops.T_rows.row_norms2(f) for _, _, sigma, _ in random_parts)
    if f.closure is None:
        row_var = row_var + noise.certificate_uncertainty_arcsec**2 * np.sum(ops.T_rows.times(f.B) ** 2, axis=1)
    eps_sigma = np.full(g.steps.n, np.nan)
    eps_sigma[ops.face_steps] = budget.uncertainty_arcsec
    s_angle, s_dir, fs, rows = g.steps.angle_deg, g.steps.direction, ops.face_steps, ops.row_keys
    reference = ReferenceDeviation(
        s_angle[fs], s_dir[fs], ops.eps_steps[fs], budget, steps_within_directions(s_dir[fs]),
        s_angle[[k[0] for k in rows]], s_dir[[k[0] for k in rows]], np.array([k[1] + 1 for k in rows]),
        ops.T_rows.times(f.eps), np.sqrt(row_var), source)
    return reference, eps_sigma


def _measured(noise: AbbeNoise, g: _Geometry, f: _FaceErrors, ops: _EpsOperators,
              random_variance: float) -> tuple[np.ndarray, np.ndarray]:
    """The measured encoder error per step (encoder − command − εz, one constant per seating over
    the face visits) and its covariance; a skipped reading (NaN) leaves its visit out of the
    operators, not the whole series."""
    n_s, step_idx, ac = g.steps.n, g.steps.index, f.ac
    ac_res2 = noise.autocollimator_resolution_arcsec**2 / 12
    enc_res2 = noise.encoder_resolution_arcsec**2 / 12
    key_m = g.key[ac]
    meas_visit = g.enc_vs_cmd_arcsec[ac] - f.eps
    fm = np.isfinite(meas_visit)
    T_meas = _centred(_mean_operator(step_idx[ac][fm], n_s), g.seating[ac][fm], np.ones(int(fm.sum()), bool))
    meas_steps = T_meas @ meas_visit[fm]
    meas_steps[T_meas.any(axis=1) == 0] = np.nan
    pooled_m = _pooled_sigma(meas_visit[fm], key_m[fm]) if g.n_runs > 1 and noise.estimate else None
    if f.closure is None:
        # the stage's repeatability cancels (encoder and autocollimator see the same angle); a digit's rounding
        # repeats run after run, so repeated runs cannot see it: it stays Type B beside their scatter
        noise_m = pooled_m[0] ** 2 if pooled_m else noise.encoder_noise_arcsec**2 + noise.autocollimator_noise_arcsec**2
        meas_cov = (_cov(T_meas, noise_m) + _cov(T_meas @ _per_key(key_m[fm]), ac_res2 + enc_res2)
                    + _cov(T_meas @ f.B[fm], noise.certificate_uncertainty_arcsec**2))
    else:
        # measured = encoder error − (I − B·K_f)·n + B·K_f·s: the autocollimator noise n through the whole map, the
        # repeatability s only through the face errors the closure estimated from every visit
        rep2 = noise.stage_repeatability_arcsec**2
        ac2 = max(random_variance - rep2, 0.0) if noise.estimate else noise.autocollimator_noise_arcsec**2 + ac_res2
        meas_cov = (_cov(f.through(T_meas, fm), ac2) + _cov(f.closure_part(T_meas, fm), rep2)
                    + _cov(T_meas, noise.encoder_noise_arcsec**2 + enc_res2))
    meas_steps[np.setdiff1d(np.arange(n_s), ops.face_steps)] = np.nan
    return meas_steps, meas_cov


@dataclass(frozen=True)
class _Prediction:
    """The predicted encoder error per step, its covariance, and the map from the visits (the
    finite ones) that made it — the rounding thresholds go through the same map."""

    steps_arcsec: np.ndarray
    cov: np.ndarray
    T: np.ndarray  # steps ← predicted per finite visit
    finite: np.ndarray  # the visits with both indicator readings


def _predicted(v: AbbeVisits, noise: AbbeNoise, g: _Geometry) -> _Prediction:
    """The indicators' prediction per step, one constant per seating over its face visits (the
    measured error's zero), with the indicators' noise, digit and scale through it."""
    n_s, step_idx, a_fac, per_um = g.steps.n, g.steps.index, g.a_fac, g.arcsec_per_um
    through = ((1 - a_fac) ** 2 + a_fac**2) * per_um**2  # an indicator's µm² into the prediction's ″²
    fp = np.isfinite(g.predicted_arcsec)
    T_pred = _centred(_mean_operator(step_idx[fp], n_s), g.seating[fp], g.has_ac[fp])  # reference: the face visits
    pred_steps = T_pred @ g.predicted_arcsec[fp]
    pred_steps[T_pred.any(axis=1) == 0] = np.nan
    pooled_p = _pooled_sigma(g.predicted_arcsec[fp], g.key[fp]) if g.n_runs > 1 and noise.estimate else None
    noise_p = pooled_p[0] ** 2 if pooled_p else through * noise.indicator_noise_um**2
    pred_cov = (_cov(T_pred, noise_p)
                + _cov(T_pred @ _per_key(g.key[fp]), through * noise.indicator_resolution_um**2 / 12))
    if noise.indicator_scale_u_ppm > 0:  # each indicator's scale error scales its share of the prediction
        for share, reading in ((1 - a_fac, v.indicator1_um), (a_fac, v.indicator2_um)):
            s = T_pred @ (share * reading * per_um)[fp] * noise.indicator_scale_u_ppm * 1e-6
            pred_cov = pred_cov + np.outer(np.nan_to_num(s), np.nan_to_num(s))
    return _Prediction(pred_steps, pred_cov, T_pred, fp)


def _reversal(steps: _Steps, values: np.ndarray) -> float | None:
    """Mean ↑ − ↓ of a per-step series over the angles both directions reached (None: one direction,
    or no angle in common — skipped steps have no value)."""
    if set(np.unique(steps.direction)) != {-1, 1}:
        return None
    triples = list(zip(steps.angle_deg, values, steps.direction))
    up = {a: e for a, e, d in triples if d > 0 and np.isfinite(e)}
    common = [(up[a] - e) for a, e, d in triples if d < 0 and a in up and np.isfinite(e)]
    return float(np.mean(common)) if common else None


def _indicator_rounding(v: AbbeVisits, setup: AbbeSetup, g: _Geometry, pred: _Prediction) -> dict[str, list[np.ndarray]]:
    """What rounding the indicators to their digit does to a smooth shaft motion, for random zeros:
    200 simulated error series of tilt, radial motion and prediction, from which the harmonic fits
    take per-order thresholds (a digit's pattern is not the shaft's)."""
    rounding: dict[str, list[np.ndarray]] = {k: [] for k in ("tilt", "radial", "predicted")}
    q = setup.noise.indicator_resolution_um
    if q <= 0:
        return rounding
    l1, l2 = setup.indicator_heights_mm
    a_fac, per_um = g.a_fac, g.arcsec_per_um
    th_v, dgroup = np.deg2rad(g.angle_deg), (v.direction < 0).astype(int)
    # the motion's smooth part (low orders only: a fit of every order would reproduce the rounding itself)
    orders_v = resolvable_orders(th_v, SMOOTH_MOTION_ORDERS, 2)
    smooth = [smooth_values(th_v, r, orders_v, dgroup) for r in (v.indicator1_um, v.indicator2_um)]
    rng = np.random.default_rng(0)  # a fixed draw: the thresholds are a property of the setup, not of chance
    for _ in range(200):
        e1, e2 = (q * np.round((s_ + o) / q) - (s_ + o) for s_, o in zip(smooth, rng.uniform(0, q, 2)))
        tilt_e = (e2 - e1) / (l2 - l1)  # µm per mm = mrad
        rounding["tilt"].append(g.steps.mean(tilt_e * 1e-3 * ARCSEC_PER_RAD))
        rounding["radial"].append(g.steps.mean(e1 - tilt_e * l1))
        rounding["predicted"].append(pred.T @ (((1 - a_fac) * e1 + a_fac * e2) * per_um)[pred.finite])
    return rounding


def _fit_series(max_order: int, angles_deg: np.ndarray, values: np.ndarray, groups: np.ndarray, floor: float,
                rounding: list[np.ndarray] | None = None) -> HarmonicFit | None:
    """The harmonic fit of one series over the orders its angles resolve (None: none); ``rounding``:
    simulated errors of quantisation alone, for per-order thresholds."""
    ok = np.isfinite(values)
    th = np.deg2rad(angles_deg[ok])
    orders = resolvable_orders(th, max_order, len(np.unique(groups[ok])))
    nyq = nyquist_order(th)
    nyq = nyq if nyq is not None and nyq <= max_order and (not orders or nyq == orders[-1] + 1) else None
    if not orders:
        return None
    qthr = None
    if rounding:
        amps = np.max(harmonic_amplitudes(th, np.column_stack([e[ok] for e in rounding]), orders, groups[ok]), axis=0)
        qthr = dict(zip(orders, amps.tolist()))
    return fit_harmonics(th, values[ok], orders, groups[ok], floor_sigma=floor, aliased_order=nyq, max_order=max_order,
                         quantisation_threshold=qthr, alternatives_up_to=grid_nyquist(th, max_order))


def _harmonic_fits(v: AbbeVisits, setup: AbbeSetup, g: _Geometry, eps_visit: np.ndarray, series: dict[str, np.ndarray],
                   rounding: dict[str, list[np.ndarray]]) -> dict[str, HarmonicFit]:
    """Every series' harmonics, each with the floor its instruments' digits set (an amplitude below
    it is no evidence) and, for the indicators' series, the simulated rounding thresholds."""
    noise, (l1, l2), a_fac = setup.noise, setup.indicator_heights_mm, g.a_fac
    ac_floor = noise.autocollimator_resolution_arcsec / np.sqrt(12)
    enc_floor = noise.encoder_resolution_arcsec / np.sqrt(12)
    pred_floor = np.sqrt((1 - a_fac) ** 2 + a_fac**2) * noise.indicator_resolution_um / np.sqrt(12) * g.arcsec_per_um
    visit_dir, step_dir = (v.direction < 0).astype(int), (g.steps.direction < 0).astype(int)
    per_visit = [("positioning_error_arcsec", eps_visit, g.group, ac_floor, None),
                 ("encoder_vs_command_arcsec", g.enc_vs_cmd_arcsec, visit_dir, enc_floor, None)]
    per_step = [
        ("measured_encoder_error_arcsec", np.hypot(ac_floor, enc_floor), None),
        ("predicted_encoder_error_arcsec", pred_floor, rounding["predicted"]),
        ("residual_arcsec", np.sqrt(ac_floor**2 + enc_floor**2 + pred_floor**2), rounding["predicted"]),
        ("tilt_x_arcsec", np.sqrt(2) * noise.indicator_resolution_um / np.sqrt(12) * 1e-3 / abs(l2 - l1) * ARCSEC_PER_RAD,
         rounding["tilt"]),
        ("radial_y_um", np.hypot(1 + l1 / (l2 - l1), l1 / (l2 - l1)) * noise.indicator_resolution_um / np.sqrt(12),
         rounding["radial"])]
    fits = [(name, _fit_series(setup.max_order, g.angle_deg, values, groups, floor, rnd))
            for name, values, groups, floor, rnd in per_visit]
    fits += [(name, _fit_series(setup.max_order, g.steps.angle_deg, series[name], step_dir, floor, rnd))
             for name, floor, rnd in per_step]
    return {name: fit for name, fit in fits if fit is not None}


def analyse_abbe(v: AbbeVisits, setup: AbbeSetup) -> AbbeEstimate:
    """Seed 001's analysis: tilt/radial separation, predicted vs measured encoder error, εz from
    the polygon with its budget, reversal, repeatability and harmonics — one phase each."""
    noise = setup.noise
    g = _visit_geometry(v, setup)
    f = _face_errors(v, setup, g)
    ops = _eps_operators(g, f)
    pooled = _pooled_sigma(f.eps, g.key[f.ac]) if g.n_runs > 1 else None
    random_parts, source = _random_parts(noise, f.closure, pooled, g.n_runs)
    random_variance = sum(sigma**2 for _, _, sigma, _ in random_parts)
    reference, eps_sigma = _reference_deviation(noise, g, f, ops, random_parts, source, pooled)
    meas_steps, meas_cov = _measured(noise, g, f, ops, random_variance)
    pred = _predicted(v, noise, g)
    residual = meas_steps - pred.steps_arcsec
    res_var = np.diag(meas_cov) + np.diag(pred.cov)
    series = {"measured_encoder_error_arcsec": meas_steps, "predicted_encoder_error_arcsec": pred.steps_arcsec,
              "residual_arcsec": residual, "tilt_x_arcsec": g.steps.mean(g.tilt_rad * ARCSEC_PER_RAD),
              "radial_y_um": g.steps.mean(g.radial_mm * 1e3)}
    e_cmd = g.steps.mean(g.enc_vs_cmd_arcsec)
    eps_visit = np.full(len(g.angle_deg), np.nan)
    eps_visit[f.ac] = ops.centred_eps
    harmonics = _harmonic_fits(v, setup, g, eps_visit, series, _indicator_rounding(v, setup, g, pred))
    return AbbeEstimate(
        angle_deg=g.steps.angle_deg, direction=g.steps.direction,
        tilt_x_arcsec=series["tilt_x_arcsec"], radial_y_um=series["radial_y_um"],
        predicted_encoder_error_arcsec=pred.steps_arcsec, predicted_sigma_arcsec=np.sqrt(np.diag(pred.cov)),
        measured_encoder_error_arcsec=meas_steps, measured_sigma_arcsec=np.where(np.isfinite(meas_steps), np.sqrt(np.diag(meas_cov)), np.nan),
        residual_arcsec=residual, residual_sigma_arcsec=np.where(np.isfinite(residual), np.sqrt(res_var), np.nan),
        positioning_error_arcsec=ops.eps_steps, positioning_sigma_arcsec=eps_sigma,
        encoder_vs_command_arcsec=e_cmd,
        face_error_arcsec=f.face_error, closure=f.closure, closure_table_angle_deg=f.closure_angles_deg,
        closure_table_direction=f.closure_dirs, reversal_arcsec=_reversal(g.steps, e_cmd),
        reversal_reference_arcsec=_reversal(g.steps, ops.eps_steps),
        repeatability_arcsec=None if pooled is None else pooled[0], harmonics=harmonics,
        extrapolation_factor=g.a_fac, reference=reference, random_sigma_arcsec=float(np.sqrt(random_variance)),
        random_sigma_type=random_parts[0][1], residual_check=_residual_check(noise, pooled, f.closure, f.n_closure),
        scale_check=scale_check(g.steps.angle_deg, meas_steps, pred.steps_arcsec, np.sqrt(res_var), np.sqrt(np.diag(pred.cov))),
    )
