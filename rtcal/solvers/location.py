"""ISO 230-7 location errors of a rotary axis (X0C, Y0C, A0C, B0C) from an axis line, and the
stated model of the error motions the network needs to say how well it knows them.

Convention (issue 29's contract, docs/paper000.md "Location errors (ISO 230-7)"): in the CMM
frame, with n the axis direction pointing up (n_z > 0) and p a point on the axis,

    X0C, Y0C = where the axis line crosses z = 0:  p_xy − p_z·n_xy / n_z
    A0C = −atan(n_y / n_z),  B0C = atan(n_x / n_z)

A0C and B0C are the right-hand rotations about X and about Y that carry +Z onto n (a rotation
by A about X turns +Z to (0, −sin A, cos A); by B about Y to (sin B, 0, cos B)).
Pure functions: mm, radians in, mm and arcsec out.
"""

from __future__ import annotations

import numpy as np

from rtcal.solvers.station_budget import StationNoiseModel, harmonic_correlation
from rtcal.units import ARCSEC_PER_RAD, arcsec_to_rad


def location_from_axis(point_mm: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """(X0C mm, Y0C mm, A0C ″, B0C ″) of the line through ``point_mm`` along ``direction`` (either sense)."""
    p = np.asarray(point_mm, float)
    n = np.asarray(direction, float)
    n = n / np.linalg.norm(n)
    if n[2] < 0:
        n = -n
    if n[2] <= 1e-9:
        raise ValueError("the axis lies in the CMM's XY plane: it crosses z = 0 nowhere")
    t = -p[2] / n[2]
    return np.array([p[0] + t * n[0], p[1] + t * n[1],
                     -np.arctan2(n[1], n[2]) * ARCSEC_PER_RAD, np.arctan2(n[0], n[2]) * ARCSEC_PER_RAD])


def location_jacobian(point_mm: np.ndarray, small_xy: np.ndarray) -> np.ndarray:
    """4×5: ∂(X0C, Y0C, A0C, B0C)/∂(p_x, p_y, p_z, n_x, n_y) with n = (n_x, n_y, √(1 − n_x² − n_y²)),
    the network's parametrisation of the axis. Central differences: X0C and Y0C are linear in p,
    and 1e-7 rad leaves an error ~1e-14 of the derivative in n."""

    def f(v: np.ndarray) -> np.ndarray:
        nx, ny = v[3], v[4]
        return location_from_axis(v[:3], np.array([nx, ny, np.sqrt(max(1.0 - nx * nx - ny * ny, 1e-12))]))

    v0 = np.concatenate([np.asarray(point_mm, float), np.asarray(small_xy, float)])
    J = np.zeros((4, 5))
    for k, h in enumerate((1e-3, 1e-3, 1e-3, 1e-7, 1e-7)):
        dv = np.zeros(5)
        dv[k] = h
        J[:, k] = (f(v0 + dv) - f(v0 - dv)) / (2 * h)
    return J


def stated_motion_covariance(nominal_angles_rad: np.ndarray, lever_mm: float, noise: StationNoiseModel) -> np.ndarray:
    """5m×5m covariance of each station's (δx, δy, δz, εx, εy) as the network parametrises them
    (translation at the circle's centre, mm; tilt about the axis frame's X and Y, rad; station-major),
    under the procedure's stated model of the error motions: each an independent random Fourier series
    of orders 1..K with σ = bound/√2 at every angle (as the one-mount budget and `rtcal uncertainty`
    model them). The tilt about the tilt centre, ``lever_mm`` below the centre, moves the centre by
    ε × (0, 0, lever): δx += εy·lever, δy −= εx·lever."""
    rho = harmonic_correlation(np.asarray(nominal_angles_rad, float), max(noise.error_motion_max_order, 1))
    r, a = noise.error_motion_radial_um * 1e-3 / np.sqrt(2), noise.error_motion_axial_um * 1e-3 / np.sqrt(2)
    t = arcsec_to_rad(noise.error_motion_tilt_arcsec) / np.sqrt(2)
    B = np.eye(5)
    B[0, 4], B[1, 3] = lever_mm, -lever_mm
    per_station = B @ np.diag([r * r, r * r, a * a, t * t, t * t]) @ B.T
    return np.kron(rho, per_station)

