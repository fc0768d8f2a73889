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


def _centring_operator(groups: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """n×n: subtract from each entry the mean of its group's ``reference`` entries."""
    n = len(groups)
    C = np.eye(n)
    for g in np.unique(groups):
        members = np.flatnonzero(groups == g)
        ref = members[reference[members]]
        if ref.size:
            C[np.ix_(members, ref)] -= 1.0 / ref.size
    return C


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


def analyse_abbe(v: AbbeVisits, setup: AbbeSetup) -> AbbeEstimate:
    """Seed 001's analysis: tilt/radial separation, predicted vs measured encoder error, εz from
    the polygon with its budget, reversal, repeatability and harmonics."""
    noise = setup.noise
    pitch = 360.0 / setup.faces
    l1, l2 = setup.indicator_heights_mm
    cmd = np.asarray(v.commanded_deg, float)
    n_v = len(cmd)
    run = np.zeros(n_v, int) if v.run is None else np.asarray(v.run, int)
    angle = np.round(np.mod(cmd, 360.0), 9) % 360.0
    has_ac = np.isfinite(v.autocollimator_arcsec)
    if not has_ac.any():
        raise ValueError("no autocollimator reading: no polygon face was in front at any visit")
    face = np.mod(np.round((cmd - v.seating_deg) / pitch).astype(int), setup.faces)
    seating = np.asarray(v.seating_index, int)
    group = seating * 2 + (v.direction < 0)  # harmonic fits: one offset per seating and direction

    tilt_rad, radial_mm = separate_tilt_radial(v.indicator1_um * 1e-3, v.indicator2_um * 1e-3, l1, l2)
    a_fac = extrapolation_factor(l1, l2, setup.grating_offset_mm)
    shift = grating_shift_mm(v.indicator1_um * 1e-3, v.indicator2_um * 1e-3, l1, l2, setup.grating_offset_mm)
    predicted = predicted_encoder_error_arcsec(shift, setup.encoder_radius_mm)
    enc_vs_cmd = _wrap_arcsec(v.encoder_deg - cmd) * 3600.0

    # steps: distinct (direction, angle), positive direction first
    steps = sorted({(int(d), float(a)) for d, a in zip(v.direction, angle)}, key=lambda k: (-k[0], k[1]))
    key_of = {k: i for i, k in enumerate(steps)}
    step_idx = np.array([key_of[(int(d), float(a))] for d, a in zip(v.direction, angle)])
    s_dir = np.array([k[0] for k in steps])
    s_angle = np.array([k[1] for k in steps])
    n_s = len(steps)

    # --- face errors: the certificate, or closure from the whole-face seatings ---------------
    ac = np.flatnonzero(has_ac)  # the visits with a reference reading
    y = v.autocollimator_arcsec[ac]
    B = np.zeros((len(ac), setup.faces))
    B[np.arange(len(ac)), face[ac]] = 1.0
    closure = None
    closure_angles = closure_dirs = None
    if setup.certificate_arcsec is None:
        whole_v = has_ac & (np.abs((v.seating_deg / pitch) - np.round(v.seating_deg / pitch)) < 1e-9)
        whole = np.flatnonzero(whole_v[ac])  # positions within ac
        keys = sorted({(int(d), int(round(a / pitch)) % setup.faces) for d, a in zip(v.direction[ac][whole], angle[ac][whole])},
                      key=lambda k: (-k[0], k[1]))
        index = {k: i for i, k in enumerate(keys)}
        t_idx = [index[(int(d), int(round(a / pitch)) % setup.faces)] for d, a in zip(v.direction[ac][whole], angle[ac][whole])]
        closure = solve_closure(y[whole], np.array(t_idx), face[ac][whole], np.unique(seating[ac][whole], return_inverse=True)[1],
                                np.array([k[0] for k in keys]), setup.faces)
        face_error = closure.face_error
        n_t = len(keys)
        K_f = np.zeros((setup.faces, len(ac)))
        K_f[:, whole] = closure.solution_map[n_t : n_t + setup.faces]
        closure_angles = np.array([k[1] * pitch for k in keys])
        closure_dirs = np.array([k[0] for k in keys])
        to_eps = np.eye(len(ac)) - B @ K_f  # ε̂ = (I − B·K_f)·y
    else:
        face_error = np.asarray(setup.certificate_arcsec, float)
        to_eps = np.eye(len(ac))
    eps = y - B @ face_error  # εz + the seating's constant, per visit

    # --- εz per step: seating constants removed (mean over the seating's visits), averaged, referred
    centre = _centring_operator(seating[ac], np.ones(len(ac), bool))
    M = _mean_operator(step_idx[ac], n_s)
    face_steps = np.flatnonzero(M.sum(axis=1) > 0)
    ref_step = face_steps[0]  # the first target of the first direction
    R = np.eye(n_s) - np.outer(np.ones(n_s), np.eye(n_s)[ref_step])
    T_eps = R @ M @ centre  # steps ← ε̂ per visit
    eps_steps = T_eps @ eps
    eps_steps[np.setdiff1d(np.arange(n_s), face_steps)] = np.nan

    # per run: (step, run) rows referred to the same zero (the mean over runs at the first target)
    row_keys = sorted({(int(step_idx[i]), int(run[i])) for i in ac})
    row_of = {k: r for r, k in enumerate(row_keys)}
    M_rows = _mean_operator(np.array([row_of[(int(step_idx[i]), int(run[i]))] for i in ac]), len(row_keys))
    T_rows = (M_rows - np.outer(np.ones(len(row_keys)), M[ref_step])) @ centre

    # random per-visit error of ε̂: from the closure residuals, repeated runs, or as stated
    pooled = _pooled_sigma(eps, seating[ac] * n_s + step_idx[ac]) if len(np.unique(run)) > 1 else None
    random_parts: list[tuple[str, SourceType, float, str]]
    if closure is not None and noise.estimate:
        random_parts = [("closure residuals (autocollimator, repeatability)", "A", closure.sigma,
                         "per visit, from the closure fit's residuals")]
        source = "closure residuals"
    elif pooled is not None and noise.estimate:
        random_parts = [("repeatability over runs (autocollimator and stage)", "A", pooled[0],
                         f"per visit, pooled over {len(np.unique(run))} runs ({pooled[1]} degrees of freedom)")]
        source = f"{len(np.unique(run))} runs"
    else:
        random_parts = [("autocollimator noise", "B", noise.autocollimator_noise_arcsec, "per reading, as stated"),
                        ("autocollimator resolution", "B", noise.autocollimator_resolution_arcsec / np.sqrt(12),
                         f"{noise.autocollimator_resolution_arcsec:g}″ digit, uniform (q/√12)"),
                        ("stage repeatability", "B", noise.stage_repeatability_arcsec, "per visit, as stated")]
        source = "stated instrument noise" + (" (one run)" if pooled is None else "")
    random_variance = sum(sigma**2 for _, _, sigma, _ in random_parts)
    T_y = T_eps @ to_eps
    components = [BudgetComponent(name, typ, sigma, "″", _cov(T_y[face_steps], sigma**2), typ == "A", note)
                  for name, typ, sigma, note in random_parts if sigma > 0]
    if closure is None and pooled is not None and noise.estimate and noise.autocollimator_resolution_arcsec > 0:
        E_ac = _per_key(seating[ac] * n_s + step_idx[ac])  # a digit rounds the same value the same way every run
        components.append(BudgetComponent("autocollimator resolution", "B", noise.autocollimator_resolution_arcsec / np.sqrt(12),
                                          "″", _cov((T_y @ E_ac)[face_steps], noise.autocollimator_resolution_arcsec**2 / 12),
                                          False, "digit q, uniform (q/√12), the same at a target in every run"))
    if closure is None and noise.certificate_uncertainty_arcsec > 0:
        T_f = -(T_eps @ B)[face_steps]
        components.append(BudgetComponent("polygon certificate", "B", noise.certificate_uncertainty_arcsec, "″",
                                          _cov(T_f, noise.certificate_uncertainty_arcsec**2), False,
                                          "per face, common to every visit of that face"))
    if noise.autocollimator_scale_u_ppm > 0:  # a scale error s reads s·y too: ε̂ moves by T·(s·y)
        g = (T_y @ np.nan_to_num(y))[face_steps] * noise.autocollimator_scale_u_ppm * 1e-6
        components.append(BudgetComponent("autocollimator calibration (scale)", "B", noise.autocollimator_scale_u_ppm, "ppm",
                                          np.outer(g, g), False, "its scale's standard uncertainty from its calibration "
                                          "certificate, times each reading (one error for every reading)"))
    if noise.autocollimator_calibration_u_arcsec > 0:
        E_cal = _per_key(seating[ac] * n_s + step_idx[ac])  # the same indication error at a target in every run
        components.append(BudgetComponent("autocollimator calibration (certificate U)", "B",
                                          noise.autocollimator_calibration_u_arcsec / 2, "″",
                                          _cov((T_y @ E_cal)[face_steps], (noise.autocollimator_calibration_u_arcsec / 2) ** 2),
                                          False, "its certificate's expanded uncertainty of an indication (k = 2), "
                                          "the same at a target in every run"))
    if not components:
        components.append(BudgetComponent("none stated", "B", 0.0, "″", np.zeros((len(face_steps), len(face_steps))), False,
                                          "no noise stated for the instruments and only one run"))
    row_var = sum(sigma**2 * np.sum((T_rows @ to_eps) ** 2, axis=1) for _, _, sigma, _ in random_parts)
    if closure is None:
        row_var = row_var + noise.certificate_uncertainty_arcsec**2 * np.sum((T_rows @ B) ** 2, axis=1)
    eps_sigma = np.full(n_s, np.nan)
    budget = DeviationBudget(components)
    eps_sigma[face_steps] = budget.uncertainty_arcsec
    reference = ReferenceDeviation(
        s_angle[face_steps], s_dir[face_steps], eps_steps[face_steps], budget, steps_within_directions(s_dir[face_steps]),
        s_angle[[k[0] for k in row_keys]], s_dir[[k[0] for k in row_keys]], np.array([k[1] + 1 for k in row_keys]),
        T_rows @ eps, np.sqrt(row_var), source)

    # --- measured and predicted encoder error: one constant per seating (over the face visits).
    # A skipped reading (NaN) leaves its visit out of the operators, not the whole series.
    ac_res2 = noise.autocollimator_resolution_arcsec**2 / 12
    enc_res2 = noise.encoder_resolution_arcsec**2 / 12
    key_m = (seating[ac] * n_s + step_idx[ac])
    meas_visit = enc_vs_cmd[ac] - eps
    fm = np.isfinite(meas_visit)
    T_meas = _mean_operator(step_idx[ac][fm], n_s) @ _centring_operator(seating[ac][fm], np.ones(int(fm.sum()), bool))
    meas_steps = T_meas @ meas_visit[fm]
    meas_steps[T_meas.any(axis=1) == 0] = np.nan
    pooled_m = _pooled_sigma(meas_visit[fm], (seating[ac] * n_s + step_idx[ac])[fm]) if len(np.unique(run)) > 1 and noise.estimate else None
    if closure is None:
        # the stage's repeatability cancels (encoder and autocollimator see the same angle); a digit's rounding
        # repeats run after run, so repeated runs cannot see it: it stays Type B beside their scatter
        noise_m = pooled_m[0] ** 2 if pooled_m else noise.encoder_noise_arcsec**2 + noise.autocollimator_noise_arcsec**2
        meas_cov = (_cov(T_meas, noise_m) + _cov(T_meas @ _per_key(key_m[fm]), ac_res2 + enc_res2)
                    + _cov(T_meas @ B[fm], noise.certificate_uncertainty_arcsec**2))
    else:
        # measured = encoder error − (I − B·K_f)·n + B·K_f·s: the autocollimator noise n through the whole map, the
        # repeatability s only through the face errors the closure estimated from every visit
        rep2 = noise.stage_repeatability_arcsec**2
        ac2 = max(random_variance - rep2, 0.0) if noise.estimate else noise.autocollimator_noise_arcsec**2 + ac_res2
        BK = np.eye(len(ac)) - to_eps
        meas_cov = (_cov(T_meas @ to_eps[fm], ac2) + _cov(T_meas @ BK[fm], rep2)
                    + _cov(T_meas, noise.encoder_noise_arcsec**2 + enc_res2))
    meas_steps[np.setdiff1d(np.arange(n_s), face_steps)] = np.nan

    per_um = 1e-3 / setup.encoder_radius_mm * ARCSEC_PER_RAD
    through = ((1 - a_fac) ** 2 + a_fac**2) * per_um**2  # an indicator's µm² into the prediction's ″²
    fp = np.isfinite(predicted)
    T_pred = _mean_operator(step_idx[fp], n_s) @ _centring_operator(seating[fp], has_ac[fp])  # reference: the face visits
    pred_steps = T_pred @ predicted[fp]
    pred_steps[T_pred.any(axis=1) == 0] = np.nan
    pooled_p = _pooled_sigma(predicted[fp], (seating * n_s + step_idx)[fp]) if len(np.unique(run)) > 1 and noise.estimate else None
    noise_p = pooled_p[0] ** 2 if pooled_p else through * noise.indicator_noise_um**2
    pred_cov = (_cov(T_pred, noise_p)
                + _cov(T_pred @ _per_key((seating * n_s + step_idx)[fp]), through * noise.indicator_resolution_um**2 / 12))
    if noise.indicator_scale_u_ppm > 0:  # each indicator's scale error scales its share of the prediction
        for share, reading in ((1 - a_fac, v.indicator1_um), (a_fac, v.indicator2_um)):
            g = T_pred @ (share * reading * per_um)[fp] * noise.indicator_scale_u_ppm * 1e-6
            pred_cov = pred_cov + np.outer(np.nan_to_num(g), np.nan_to_num(g))
    residual = meas_steps - pred_steps
    res_var = np.diag(meas_cov) + np.diag(pred_cov)

    def per_step(x: np.ndarray) -> np.ndarray:
        """Mean over the visits of each step (NaN where none is finite)."""
        ok = np.isfinite(x)
        out = np.full(n_s, np.nan)
        sums = np.bincount(step_idx[ok], x[ok], n_s)
        counts = np.bincount(step_idx[ok], minlength=n_s)
        out[counts > 0] = sums[counts > 0] / counts[counts > 0]
        return out

    e_cmd = per_step(enc_vs_cmd)
    reversal = reversal_ref = None
    if set(np.unique(s_dir)) == {-1, 1}:
        up = {a: e for a, e, d in zip(s_angle, e_cmd, s_dir) if d > 0 and np.isfinite(e)}  # skipped steps have none
        common = [(up[a] - e) for a, e, d in zip(s_angle, e_cmd, s_dir) if d < 0 and a in up and np.isfinite(e)]
        reversal = float(np.mean(common)) if common else None
        up_r = {a: e for a, e, d in zip(s_angle, eps_steps, s_dir) if d > 0 and np.isfinite(e)}
        common_r = [(up_r[a] - e) for a, e, d in zip(s_angle, eps_steps, s_dir) if d < 0 and a in up_r and np.isfinite(e)]
        reversal_ref = float(np.mean(common_r)) if common_r else None

    rad = np.deg2rad
    harmonics: dict[str, HarmonicFit] = {}

    def add(name: str, angles_deg: np.ndarray, values: np.ndarray, groups: np.ndarray, floor: float,
            rounding: list[np.ndarray] | None = None) -> None:
        """Fit a series; ``rounding``: simulated errors of quantisation alone, for per-order thresholds."""
        ok = np.isfinite(values)
        th = rad(angles_deg[ok])
        orders = resolvable_orders(th, setup.max_order, len(np.unique(groups[ok])))
        nyq = nyquist_order(th)
        nyq = nyq if nyq is not None and nyq <= setup.max_order and (not orders or nyq == orders[-1] + 1) else None
        if orders:
            qthr = None
            if rounding:
                amps = np.max(harmonic_amplitudes(th, np.column_stack([e[ok] for e in rounding]), orders, groups[ok]), axis=0)
                qthr = dict(zip(orders, amps.tolist()))
            harmonics[name] = fit_harmonics(th, values[ok], orders, groups[ok], floor_sigma=floor, aliased_order=nyq,
                                            max_order=setup.max_order, quantisation_threshold=qthr,
                                            alternatives_up_to=grid_nyquist(th, setup.max_order))

    # what rounding the indicators to their digit does to a smooth shaft motion, for random zeros
    rounding: dict[str, list[np.ndarray]] = {k: [] for k in ("tilt", "radial", "predicted")}
    q = noise.indicator_resolution_um
    if q > 0:
        th_v, dgroup = rad(angle), (v.direction < 0).astype(int)
        # the motion's smooth part (low orders only: a fit of every order would reproduce the rounding itself)
        orders_v = resolvable_orders(th_v, SMOOTH_MOTION_ORDERS, 2)
        smooth = [smooth_values(th_v, r, orders_v, dgroup) for r in (v.indicator1_um, v.indicator2_um)]
        rng = np.random.default_rng(0)  # a fixed draw: the thresholds are a property of the setup, not of chance
        for _ in range(200):
            e1, e2 = (q * np.round((s_ + o) / q) - (s_ + o) for s_, o in zip(smooth, rng.uniform(0, q, 2)))
            tilt_e = (e2 - e1) / (l2 - l1)  # µm per mm = mrad
            rounding["tilt"].append(per_step(tilt_e * 1e-3 * ARCSEC_PER_RAD))
            rounding["radial"].append(per_step(e1 - tilt_e * l1))
            rounding["predicted"].append(T_pred @ (((1 - a_fac) * e1 + a_fac * e2) * per_um)[fp])

    ac_floor = noise.autocollimator_resolution_arcsec / np.sqrt(12)
    enc_floor = noise.encoder_resolution_arcsec / np.sqrt(12)
    pred_floor = np.sqrt((1 - a_fac) ** 2 + a_fac**2) * noise.indicator_resolution_um / np.sqrt(12) * per_um
    eps_visit = np.full(n_v, np.nan)
    eps_visit[ac] = centre @ eps
    add("positioning_error_arcsec", angle, eps_visit, group, ac_floor)
    add("encoder_vs_command_arcsec", angle, enc_vs_cmd, (v.direction < 0).astype(int), enc_floor)
    add("measured_encoder_error_arcsec", s_angle, meas_steps, (s_dir < 0).astype(int), np.hypot(ac_floor, enc_floor))
    add("predicted_encoder_error_arcsec", s_angle, pred_steps, (s_dir < 0).astype(int), pred_floor, rounding["predicted"])
    add("residual_arcsec", s_angle, residual, (s_dir < 0).astype(int), np.sqrt(ac_floor**2 + enc_floor**2 + pred_floor**2),
        rounding["predicted"])
    add("tilt_x_arcsec", s_angle, per_step(tilt_rad * ARCSEC_PER_RAD), (s_dir < 0).astype(int),
        np.sqrt(2) * noise.indicator_resolution_um / np.sqrt(12) * 1e-3 / abs(l2 - l1) * ARCSEC_PER_RAD, rounding["tilt"])
    add("radial_y_um", s_angle, per_step(radial_mm * 1e3), (s_dir < 0).astype(int),
        np.hypot(1 + l1 / (l2 - l1), l1 / (l2 - l1)) * noise.indicator_resolution_um / np.sqrt(12), rounding["radial"])

    return AbbeEstimate(
        angle_deg=s_angle, direction=s_dir,
        tilt_x_arcsec=per_step(tilt_rad * ARCSEC_PER_RAD), radial_y_um=per_step(radial_mm * 1e3),
        predicted_encoder_error_arcsec=pred_steps, predicted_sigma_arcsec=np.sqrt(np.diag(pred_cov)),
        measured_encoder_error_arcsec=meas_steps, measured_sigma_arcsec=np.where(np.isfinite(meas_steps), np.sqrt(np.diag(meas_cov)), np.nan),
        residual_arcsec=residual, residual_sigma_arcsec=np.where(np.isfinite(residual), np.sqrt(res_var), np.nan),
        positioning_error_arcsec=eps_steps, positioning_sigma_arcsec=eps_sigma, encoder_vs_command_arcsec=e_cmd,
        face_error_arcsec=face_error, closure=closure, closure_table_angle_deg=closure_angles,
        closure_table_direction=closure_dirs, reversal_arcsec=reversal, reversal_reference_arcsec=reversal_ref,
        repeatability_arcsec=None if pooled is None else pooled[0], harmonics=harmonics,
        extrapolation_factor=a_fac, reference=reference, random_sigma_arcsec=float(np.sqrt(random_variance)),
        random_sigma_type=random_parts[0][1],
        residual_check=_residual_check(noise, pooled, closure, len(whole) if closure is not None else 0),
        scale_check=scale_check(s_angle, meas_steps, pred_steps, np.sqrt(res_var), np.sqrt(np.diag(pred_cov))),
    )
