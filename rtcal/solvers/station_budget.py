"""The uncertainty budget of a seed-000 estimate: what each source does to lengths, stations, angles.

Sources (the procedure's ``uncertainty`` section states them; DESIGN.md, issue "trustworthy
results"):

- **tracer length noise** (Type A): one independent error per length, shaped a + b·L as the
  tracer's specification says, its size estimated from the residuals;
- **CMM point noise** (Type A): one 3-D error per reported point (÷ √visits when a point's
  position was read at several visits), common to every station's length to that point — it
  largely cancels in the angles, which is why treating it as length noise overstated the
  uncertainty 4–15×; its size estimated from the residuals;
- **stage repeatability** (Type B, per visit): each stage visit turns the tracer about the axis
  by a random angle, shared by the lengths taken during that visit;
- **CMM scale and squareness** (Type B): the reported points are off by (M − I)·A, with M the
  CMM's (lower-triangular) scale/squareness matrix, common to every length;
- **error motions** (Type B): radial, axial and tilt error motions displace each station; no
  single-mount model sees them. Each is modelled as an unknown smooth function bounded by the
  stated value, a random Fourier series of orders 1..K with σ = bound/√3 at every angle, whose
  stations are correlated as (1/K)·Σ cos(k·Δθ).

Each source is propagated through the estimator's own linearisation and the plane/circle/angle
chain to the cumulative deviation (and its per-step differences).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from rtcal.solvers.uncertainty import BudgetComponent, DeviationBudget, Source, VarianceEstimate, propagate, reml_scales
from rtcal.units import arcsec_to_rad


@dataclass(frozen=True)
class StationNoiseModel:
    """What the lab states about a seed-000 measurement (1σ unless called a bound)."""

    length_noise_um: float = 0.2  # tracer a of a + b·L: the shape; the size is estimated (Type A)
    length_noise_ppm: float = 0.3  # tracer b, µm per m
    point_noise_um: float = 0.3  # CMM reading, per coordinate and visit: reference scale (Type A)
    stage_repeatability_arcsec: float = 0.0  # per visit (Type B)
    cmm_scale_ppm: float = 0.0  # per axis (Type B)
    cmm_squareness_arcsec: float = 0.0  # per axis pair (Type B)
    error_motion_radial_um: float = 0.0  # bound of EXC, EYC at the tilt centre
    error_motion_axial_um: float = 0.0  # bound of EZC
    error_motion_tilt_arcsec: float = 0.0  # bound of EAC, EBC
    error_motion_max_order: int = 6
    tilt_center_z_mm: float = 0.0  # height of the tilt centre in the CMM frame
    estimate: bool = True  # Type A sizes from the residuals; False: as stated (a prediction before measuring)
    air_index_sigma: float = 0.0  # of the air's refractive index the lengths were corrected with (0: not corrected)


@dataclass(frozen=True)
class StationObservations:
    """Which point, station and stage visit each residual of an estimator belongs to."""

    point: np.ndarray  # (N,) index into points
    station: np.ndarray  # (N,)
    visit: np.ndarray  # (N,) stage visit (shared by the lengths taken without the table moving)
    points_mm: np.ndarray  # (n, 3) as the solver used them
    point_visits: np.ndarray  # (n,) how many CMM readings were averaged into each point


def chain_jacobian(stations_mm: np.ndarray, chain: Callable[[np.ndarray], np.ndarray], h_mm: float = 1e-4) -> np.ndarray:
    """∂(output)/∂(station coordinates) by central differences (0.1 µm: far inside the linear range)."""
    base = np.asarray(stations_mm, float)
    cols = []
    for k in range(base.size):
        plus, minus = base.copy(), base.copy()
        plus.flat[k] += h_mm
        minus.flat[k] -= h_mm
        cols.append((chain(plus) - chain(minus)) / (2 * h_mm))
    return np.column_stack(cols)


def cmm_matrix_derivatives() -> list[tuple[str, np.ndarray]]:
    """∂M/∂q for the CMM's 3 scales (per ppm) and 3 squarenesses (per arcsec), M as in the bench."""
    out = []
    for k, axis in enumerate("xyz"):
        d = np.zeros((3, 3))
        d[k, k] = 1e-6
        out.append((f"scale_{axis}", d))
    for (r, c), name in (((1, 0), "xy"), ((2, 0), "xz"), ((2, 1), "yz")):
        d = np.zeros((3, 3))
        d[r, c] = arcsec_to_rad(1.0)
        out.append((f"squareness_{name}", d))
    return out


def harmonic_correlation(angles_rad: np.ndarray, max_order: int) -> np.ndarray:
    """Correlation of a random Fourier series of orders 1..K with equal variance per order."""
    d = np.subtract.outer(angles_rad, angles_rad)
    k = np.arange(1, max_order + 1)
    return np.mean(np.cos(d[..., None] * k), axis=-1)


def error_motion_covariance(stations_mm: np.ndarray, nominal_angles_rad: np.ndarray, axis_center_mm: np.ndarray,
                            noise: StationNoiseModel) -> np.ndarray:
    """3m×3m covariance of the station displacements the bounded error motions can cause (mm²)."""
    m = len(stations_mm)
    rho = harmonic_correlation(np.asarray(nominal_angles_rad, float), max(noise.error_motion_max_order, 1))
    d = np.asarray(stations_mm, float) - np.array([axis_center_mm[0], axis_center_mm[1], noise.tilt_center_z_mm])
    s_r = noise.error_motion_radial_um * 1e-3 / np.sqrt(3)
    s_a = noise.error_motion_axial_um * 1e-3 / np.sqrt(3)
    s_t = arcsec_to_rad(noise.error_motion_tilt_arcsec) / np.sqrt(3)
    one = np.ones(m)
    # sensitivity of each station's displacement to each component: δx, δy, δz, εx, εy
    g = [(s_r, np.column_stack([one, 0 * one, 0 * one])), (s_r, np.column_stack([0 * one, one, 0 * one])),
         (s_a, np.column_stack([0 * one, 0 * one, one])),
         (s_t, np.column_stack([0 * one, -d[:, 2], d[:, 1]])),  # εx × d
         (s_t, np.column_stack([d[:, 2], 0 * one, -d[:, 0]]))]  # εy × d
    cov = np.zeros((3 * m, 3 * m))
    for s, gj in g:
        if s == 0:
            continue
        outer = np.einsum("ia,jb->iajb", gj, gj).reshape(3 * m, 3 * m)
        cov += s * s * np.kron(rho, np.ones((3, 3))) * outer
    return cov


def observation_sources(obs: StationObservations, stations_mm: np.ndarray, axis_center_mm: np.ndarray,
                        axis_direction: np.ndarray, noise: StationNoiseModel) -> list[Source]:
    """The sources that act on the lengths' residuals, each as its effect per 1σ of its inputs."""
    pts = np.asarray(obs.points_mm, float)
    P = np.asarray(stations_mm, float)[obs.station]
    A = pts[obs.point]
    diff = A - P
    L = np.linalg.norm(diff, axis=1)
    u = diff / L[:, None]  # ∂f/∂A; ∂f/∂P = −u
    N, n = len(L), len(pts)
    # tracer: a + b·L, the shape only (a floor keeps it invertible when stated as zero)
    a_mm, b = noise.length_noise_um * 1e-3, noise.length_noise_ppm * 1e-6
    shape = a_mm + b * L
    ref_len = shape if np.max(shape) > 0 else np.full(N, 1e-3)
    sources = [Source("tracer length noise", "A", ref_len, noise.length_noise_um if np.max(shape) > 0 else 1.0, "µm",
                      f"a + b·L with b/a as stated ({noise.length_noise_um:g} µm + {noise.length_noise_ppm:g} ppm); size from the residuals")]
    s_p = noise.point_noise_um * 1e-3 if noise.point_noise_um > 0 else 1e-3
    F = np.zeros((N, 3 * n))
    w = s_p / np.sqrt(np.maximum(np.asarray(obs.point_visits, float), 1.0))[obs.point]
    for c in range(3):
        F[np.arange(N), 3 * obs.point + c] = u[:, c] * w
    sources.append(Source("CMM point noise", "A", F, noise.point_noise_um if noise.point_noise_um > 0 else 1.0, "µm",
                          "per point and coordinate, common to all stations; size from the residuals"))
    if noise.stage_repeatability_arcsec > 0:
        visits, vidx = np.unique(obs.visit, return_inverse=True)
        axis = np.asarray(axis_direction, float) / np.linalg.norm(axis_direction)
        tangent = np.cross(axis, P - np.asarray(axis_center_mm, float))  # δP per rad about the axis
        Fv = np.zeros((N, len(visits)))
        Fv[np.arange(N), vidx] = -np.einsum("ij,ij->i", u, tangent) * arcsec_to_rad(noise.stage_repeatability_arcsec)
        sources.append(Source("stage repeatability", "B", Fv, noise.stage_repeatability_arcsec, "″",
                              "per visit, as stated"))
    if noise.air_index_sigma > 0:  # one error of the index for the whole run scales every counted distance
        sources.append(Source("air refractive index", "B", (L * noise.air_index_sigma)[:, None], noise.air_index_sigma * 1e6,
                              "ppm", "from the environment sensor's stated uncertainty, common to every length"))
    geometry = []
    for name, dM in cmm_matrix_derivatives():
        sigma = noise.cmm_scale_ppm if name.startswith("scale") else noise.cmm_squareness_arcsec
        if sigma > 0:
            geometry.append(-np.einsum("ij,ij->i", u, (pts @ dM.T)[obs.point]) * sigma)
    if geometry:
        sources.append(Source("CMM scale and squareness", "B", np.column_stack(geometry),
                              max(noise.cmm_scale_ppm, noise.cmm_squareness_arcsec), "ppm, ″",
                              f"{noise.cmm_scale_ppm:g} ppm per scale, {noise.cmm_squareness_arcsec:g}″ per squareness, as stated"))
    return sources


@dataclass(frozen=True)
class StationBudget:
    """The cumulative deviation's budget (m targets), and the estimated Type A sizes."""

    cumulative: DeviationBudget
    variances: VarianceEstimate
    sources: list[Source]

    @property
    def step_uncertainty_arcsec(self) -> np.ndarray:
        """1σ of the per-step deviations (eq. 33's Δθ), from the same covariance."""
        n = len(self.cumulative.uncertainty_arcsec)
        return self.cumulative.transformed(np.eye(n)[1:] - np.eye(n)[:-1]).uncertainty_arcsec

    def estimated_sigma(self, name: str) -> float | None:
        for s in self.sources:
            if s.name == name:
                return self.variances.sigma(s)
        return None


def station_budget(
    jacobian: np.ndarray,
    residuals: np.ndarray,
    station_columns: np.ndarray,
    obs: StationObservations,
    stations_mm: np.ndarray,
    nominal_angles_rad: np.ndarray,
    axis_center_mm: np.ndarray,
    axis_direction: np.ndarray,
    cumulative_of_stations: Callable[[np.ndarray], np.ndarray],
    noise: StationNoiseModel,
) -> StationBudget:
    """The budget of the cumulative deviation of an estimate with Jacobian J (N×p) and residuals f.

    ``station_columns`` (m×3) says which unknowns are the stations' X, Y, Z; the cumulative
    deviation follows from the stations by ``cumulative_of_stations``.
    """
    J = np.asarray(jacobian, float)
    sources = observation_sources(obs, stations_mm, axis_center_mm, axis_direction, noise)
    variances = reml_scales(J, residuals, sources) if noise.estimate else VarianceEstimate({}, {}, 0, True)
    influence = np.linalg.pinv(J)[np.asarray(station_columns).ravel()]  # ∂(stations)/∂f, up to sign
    G = chain_jacobian(stations_mm, cumulative_of_stations)
    components = propagate(influence, sources, variances, G)
    if max(noise.error_motion_radial_um, noise.error_motion_axial_um, noise.error_motion_tilt_arcsec) > 0:
        cov = error_motion_covariance(stations_mm, nominal_angles_rad, axis_center_mm, noise)
        components.append(BudgetComponent(
            "error motions", "B", max(noise.error_motion_radial_um, noise.error_motion_tilt_arcsec), "µm, ″",
            G @ cov @ G.T, False,
            f"bounds {noise.error_motion_radial_um:g} µm radial, {noise.error_motion_axial_um:g} µm axial, "
            f"{noise.error_motion_tilt_arcsec:g}″ tilt (σ = bound/√3, orders 1..{noise.error_motion_max_order}); "
            "one mount cannot separate them from the rotation"))
    return StationBudget(DeviationBudget(components), variances, sources)
