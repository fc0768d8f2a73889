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

Dial indicators, the encoder and the autocollimator have arbitrary zeros, so encoder errors
and positioning errors are reported up to a constant (mean over the turn removed) per pass.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rtcal.solvers.closure import ClosureResult, solve_closure
from rtcal.solvers.harmonic_analysis import HarmonicFit, fit_harmonics, resolvable_orders
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


@dataclass(frozen=True)
class AbbeSetup:
    faces: int
    indicator_heights_mm: tuple[float, float]
    grating_offset_mm: float
    encoder_radius_mm: float
    certificate_arcsec: np.ndarray | None  # None: separate face errors by closure
    max_order: int = 24


@dataclass(frozen=True)
class AbbeEstimate:
    angle_deg: np.ndarray  # per step: distinct (direction, angle), positive first
    direction: np.ndarray
    tilt_x_arcsec: np.ndarray
    radial_y_um: np.ndarray
    predicted_encoder_error_arcsec: np.ndarray
    measured_encoder_error_arcsec: np.ndarray  # NaN where no face was in front
    residual_arcsec: np.ndarray
    positioning_error_arcsec: np.ndarray  # the stage's εz from the autocollimator, NaN off the faces
    encoder_vs_command_arcsec: np.ndarray
    face_error_arcsec: np.ndarray  # used: the certificate or the closure result
    closure: ClosureResult | None
    closure_table_angle_deg: np.ndarray | None
    closure_table_direction: np.ndarray | None
    reversal_arcsec: float | None
    harmonics: dict[str, HarmonicFit]
    extrapolation_factor: float


def _wrap_arcsec(value_deg):
    return (np.asarray(value_deg) + 180.0) % 360.0 - 180.0


def _group_mean_removed(values: np.ndarray, groups: np.ndarray) -> np.ndarray:
    out = values.copy()
    for g in np.unique(groups):
        sel = groups == g
        out[sel] -= np.nanmean(values[sel])
    return out


def analyse_abbe(v: AbbeVisits, setup: AbbeSetup) -> AbbeEstimate:
    """Seed 001's analysis: tilt/radial separation, predicted vs measured encoder error, harmonics."""
    pitch = 360.0 / setup.faces
    l1, l2 = setup.indicator_heights_mm
    cmd = np.asarray(v.commanded_deg, float)
    angle = np.round(np.mod(cmd, 360.0), 9) % 360.0
    has_ac = np.isfinite(v.autocollimator_arcsec)
    face = np.mod(np.round((cmd - v.seating_deg) / pitch).astype(int), setup.faces)
    group = v.seating_index * 2 + (v.direction < 0)  # one unknown constant per seating and direction

    tilt_rad, radial_mm = separate_tilt_radial(v.indicator1_um * 1e-3, v.indicator2_um * 1e-3, l1, l2)
    shift = grating_shift_mm(v.indicator1_um * 1e-3, v.indicator2_um * 1e-3, l1, l2, setup.grating_offset_mm)
    predicted = predicted_encoder_error_arcsec(shift, setup.encoder_radius_mm)
    enc_vs_cmd = _wrap_arcsec(v.encoder_deg - cmd) * 3600.0

    closure = None
    closure_angles = closure_dirs = None
    if setup.certificate_arcsec is None:
        whole = has_ac & (np.abs((v.seating_deg / pitch) - np.round(v.seating_deg / pitch)) < 1e-9)
        keys = sorted({(int(d), int(round(a / pitch)) % setup.faces) for d, a in zip(v.direction[whole], angle[whole])},
                      key=lambda k: (-k[0], k[1]))
        index = {k: i for i, k in enumerate(keys)}
        t_idx = [index[(int(d), int(round(a / pitch)) % setup.faces)] for d, a in zip(v.direction[whole], angle[whole])]
        closure = solve_closure(v.autocollimator_arcsec[whole], np.array(t_idx), face[whole],
                                np.unique(group[whole], return_inverse=True)[1], np.array([k[0] for k in keys]), setup.faces)
        face_error = closure.face_error
        closure_angles = np.array([k[1] * pitch for k in keys])
        closure_dirs = np.array([k[0] for k in keys])
    else:
        face_error = np.asarray(setup.certificate_arcsec, float)

    eps_visit = np.full(len(cmd), np.nan)
    eps_visit[has_ac] = v.autocollimator_arcsec[has_ac] - face_error[face[has_ac]]
    eps_visit = _group_mean_removed(eps_visit, group) if has_ac.any() else eps_visit
    measured_visit = enc_vs_cmd - eps_visit

    # per step: distinct (direction, angle), averaged over runs and seatings
    steps = sorted({(int(d), float(a)) for d, a in zip(v.direction, angle)}, key=lambda k: (-k[0], k[1]))
    key_of = {k: i for i, k in enumerate(steps)}
    step_idx = np.array([key_of[(int(d), float(a))] for d, a in zip(v.direction, angle)])

    def per_step(x: np.ndarray) -> np.ndarray:
        out = np.full(len(steps), np.nan)
        for i in range(len(steps)):
            sel = (step_idx == i) & np.isfinite(x)
            if sel.any():
                out[i] = x[sel].mean()
        return out

    s_dir = np.array([k[0] for k in steps])
    s_angle = np.array([k[1] for k in steps])
    s_meas, s_pred, s_eps = per_step(measured_visit), per_step(predicted), per_step(eps_visit)
    for d in np.unique(s_dir):  # arbitrary zeros: remove the mean over the faces, per direction
        sel = s_dir == d
        faces_sel = sel & np.isfinite(s_meas)
        ref = faces_sel if faces_sel.any() else sel
        s_meas[sel] -= np.nanmean(s_meas[faces_sel]) if faces_sel.any() else 0.0
        s_pred[sel] -= np.mean(s_pred[ref])
    residual = s_meas - s_pred

    reversal = None
    if set(np.unique(s_dir)) == {-1, 1}:
        e_cmd = per_step(enc_vs_cmd)
        up = {a: e for a, e, d in zip(s_angle, e_cmd, s_dir) if d > 0}
        common = [(up[a] - e) for a, e, d in zip(s_angle, e_cmd, s_dir) if d < 0 and a in up]
        reversal = float(np.mean(common)) if common else None

    rad = np.deg2rad
    harmonics: dict[str, HarmonicFit] = {}
    def add(name: str, angles_deg: np.ndarray, values: np.ndarray, groups: np.ndarray) -> None:
        ok = np.isfinite(values)
        orders = resolvable_orders(rad(angles_deg[ok]), setup.max_order, len(np.unique(groups[ok])))
        if orders:
            harmonics[name] = fit_harmonics(rad(angles_deg[ok]), values[ok], orders, groups[ok])

    add("positioning_error_arcsec", angle, eps_visit, group)
    add("encoder_vs_command_arcsec", angle, enc_vs_cmd, (v.direction < 0).astype(int))
    add("measured_encoder_error_arcsec", s_angle, s_meas, (s_dir < 0).astype(int))
    add("predicted_encoder_error_arcsec", s_angle, s_pred, (s_dir < 0).astype(int))
    add("residual_arcsec", s_angle, residual, (s_dir < 0).astype(int))
    add("tilt_x_arcsec", s_angle, per_step(tilt_rad * ARCSEC_PER_RAD), (s_dir < 0).astype(int))
    add("radial_y_um", s_angle, per_step(radial_mm * 1e3), (s_dir < 0).astype(int))

    return AbbeEstimate(
        angle_deg=s_angle, direction=s_dir,
        tilt_x_arcsec=per_step(tilt_rad * ARCSEC_PER_RAD), radial_y_um=per_step(radial_mm * 1e3),
        predicted_encoder_error_arcsec=s_pred, measured_encoder_error_arcsec=s_meas, residual_arcsec=residual,
        positioning_error_arcsec=s_eps, encoder_vs_command_arcsec=per_step(enc_vs_cmd),
        face_error_arcsec=face_error, closure=closure, closure_table_angle_deg=closure_angles,
        closure_table_direction=closure_dirs, reversal_arcsec=reversal, harmonics=harmonics,
        extrapolation_factor=extrapolation_factor(l1, l2, setup.grating_offset_mm),
    )
