"""Plane, circle and angle geometry of seed 000 (eqs. 18–36). Pure functions, mm and radians."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Plane:
    """aX + bY + cZ + e = 0 with (a, b, c) a unit normal, c ≥ 0 (eq. 19)."""

    a: float
    b: float
    c: float
    e: float

    @property
    def normal(self) -> np.ndarray:
        return np.array([self.a, self.b, self.c])


def fit_plane(points_mm: np.ndarray) -> Plane:
    """SVD of the centred coordinates (eq. 18): the normal is the last right singular vector."""
    pts = np.asarray(points_mm, dtype=float)
    centroid = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centroid)
    normal = vt[-1]
    if normal[2] < 0:
        normal = -normal
    e = -float(normal @ centroid)
    return Plane(float(normal[0]), float(normal[1]), float(normal[2]), e)


def project_to_plane(points_mm: np.ndarray, plane: Plane) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. 20–21: P' = P + λn with λ = −(n·P + e)/|n|². Returns (P', λ per point)."""
    pts = np.asarray(points_mm, dtype=float)
    n = plane.normal
    lam = -(pts @ n + plane.e) / float(n @ n)
    return pts + lam[:, None] * n, lam


def fit_circle_center(projected_mm: np.ndarray, plane: Plane) -> np.ndarray:
    """Centre (xc, yc, zc) of the circle through the projected stations (eqs. 22–31).

    Eq. 27 is a 2×2 linear system in the centred coordinates (u, v); eq. 28 is its
    Cramer solution, which we solve directly. Eq. 29 as printed reads xc = uc − X̄;
    the centring u = X − X̄ makes it xc = uc + X̄ (likewise yc), which we use. zc from the
    plane (eq. 31).
    """
    pts = np.asarray(projected_mm, dtype=float)
    xm, ym = pts[:, 0].mean(), pts[:, 1].mean()
    u, v = pts[:, 0] - xm, pts[:, 1] - ym
    suu, svv, suv = u @ u, v @ v, u @ v
    rhs = 0.5 * np.array([u @ u**2 + u @ v**2, v @ v**2 + v @ u**2])
    uc, vc = np.linalg.solve(np.array([[suu, suv], [suv, svv]]), rhs)
    xc, yc = uc + xm, vc + ym
    zc = -(plane.a * xc + plane.b * yc + plane.e) / plane.c
    return np.array([xc, yc, zc])


def adjacent_angles_rad(stations_mm: np.ndarray, center_mm: np.ndarray) -> np.ndarray:
    """Eq. 32: angle between adjacent stations seen from the centre, by the law of cosines."""
    pts = np.asarray(stations_mm, dtype=float)
    r = np.linalg.norm(pts - center_mm, axis=1)
    chord = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    cos_t = (r[:-1] ** 2 + r[1:] ** 2 - chord**2) / (2.0 * r[:-1] * r[1:])
    return np.arccos(np.clip(cos_t, -1.0, 1.0))


def step_directions(stations_mm: np.ndarray, center_mm: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """+1 where the step from one station to the next turns counterclockwise about ``normal``, else −1.

    Eq. 32's law of cosines gives the size of a step, never its sense; the sense is the sign of
    (r_j × r_j+1)·n with r the stations seen from the centre and n the plane's normal (+Z side).
    """
    r = np.asarray(stations_mm, dtype=float) - center_mm
    turn = np.cross(r[:-1], r[1:]) @ np.asarray(normal, dtype=float)
    return np.where(turn >= 0.0, 1.0, -1.0)


def sigma_eq34(deviations: np.ndarray, stations: int) -> float:
    """Eq. 34 as printed: ½·sqrt(Σ Δθ² / (m(m − 1))) with m the number of stations."""
    dev = np.asarray(deviations, dtype=float)
    return 0.5 * float(np.sqrt(np.sum(dev**2) / (stations * (stations - 1))))


def plane_tilt_rad(plane: Plane) -> float:
    """Eq. 35: α between the fitted plane γ and the CMM plane β (normal (0, 0, 1))."""
    n = plane.normal
    return float(np.arccos(np.clip(plane.c / np.linalg.norm(n), -1.0, 1.0)))


def algorithm_error_rad(theta_rad: float, alpha_rad: float) -> float:
    """Eq. 36: Δ = arctan(tanθ·cosα) − θ, the angle θ foreshortened by the tilt α.

    Written with atan2 so that it holds beyond ±90°, where it equals the printed arctan form.
    """
    return float(np.arctan2(np.sin(theta_rad) * np.cos(alpha_rad), np.cos(theta_rad)) - theta_rad)
