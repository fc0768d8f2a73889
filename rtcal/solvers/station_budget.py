"""The uncertainty budget of a seed-000 estimate: what each source does to lengths, stations, angles.

Sources (the procedure's ``uncertainty`` section states them; docs/paper000.md derives each):

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
- **air refractive index** (Type B): with an environment sensor, the index each length was
  corrected with is off by the sensor's uncertainty, one error for the whole run (a scale of every
  counted distance); without one, the air drifts within the stated ranges and nothing corrects
  it — see :func:`air_drift_effect`;
- **sensor noise per reading** (Type B): each length is corrected with its own reading of the
  sensor, so the sensor's reading-to-reading noise (air index; the table temperature where the
  lengths are corrected for expansion) is one independent error per length — see
  :func:`sensor_noise_sources`;
- **error motions** (Type B): radial, axial and tilt error motions displace each station; no
  single-mount model sees them. Each is modelled as an unknown smooth function bounded by the
  stated value, a random Fourier series of orders 1..K with σ = bound/√2 at every angle (the
  σ of a sinusoid that reaches the bound: GUM's U-shaped law for a smooth motion), whose
  stations are correlated as (1/K)·Σ cos(k·Δθ). U (k = 2) then covers about 95 % of the motions
  within the bounds, not every one: a single harmonic at the bound in the worst phase can exceed
  it at some target — a second tracer mount measures them instead.

Each source is propagated through the estimator's own linearisation and the plane/circle/angle
chain to the cumulative deviation (and its per-step differences).

Every source keeps its structure (:mod:`rtcal.solvers.structure`), so that a budget costs in
proportion to the lengths, not their cube: one error per length is a vector (tracer, sensor noise,
a stage visit of one length), a CMM point's three errors a :class:`Grouped` block (c = 3, the
point's lengths its group; a stage visit of several lengths c = 1), a few errors common to every
length a dense (N, q) (the CMM's scales and squarenesses, the air's index, the table's
expansion), and the error motions a :class:`Factored` map of the stations' displacements times
the root of their covariance. A new physical term is added as one of these; the estimator's
Jacobian is sparse (a length touches one station's coordinates and one dead path).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np

from rtcal.solvers.structure import Effect, Factored, Grouped, column_basis, dense_effect, pseudo_inverse_gram, r_factor
from rtcal.solvers.uncertainty import (
    BudgetComponent,
    Covariance,
    DeviationBudget,
    Source,
    ResidualCheck,
    VarianceEstimate,
    difference_matrix,
    residual_check,
    propagate,
    scorable,
    reml_scales,
)
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
    air_index_bound: float = 0.0  # no sensor: the index's departure from what the lengths assume, bound over the run
    #                               (the root-sum-square of independent bounds: temperature, pressure, humidity)
    air_note: str = ""  # what the bound is made of (the stated ranges), for the budget's note
    table_expansion_ppm_per_k: float = 0.0  # the table's (and the mounted tracer's) radial growth about the axis per K
    table_expansion_u_ppm_per_k: float = 0.0  # its standard uncertainty
    table_expansion_assumed: str = ""  # the material whose default α is used, none being stated ("": α as stated)
    material_temperature_sigma_k: float = 0.0  # with a sensor reading the table: its 1σ (the lengths are corrected)
    material_temperature_bound_k: float = 0.0  # without one: the table within 20 °C ± this over the run, uncorrected
    air_index_noise: float = 0.0  # the sensor's own noise per reading, as 1σ of index: independent from length to length
    material_temperature_noise_k: float = 0.0  # the table sensor's noise per reading, K (1σ), with the lengths corrected
    cmm_field_um: float = 0.0  # the CMM's smooth geometric error beyond scales and squarenesses, 1σ per coordinate
    cmm_field_length_mm: float = 150.0  # its correlation length
    mount_gradient_share: float = 0.0  # with a sensor reading the table: how far the tracer's mount's temperature change
    #                                    may differ from the sensor's, as a share of the sensor's change (1σ)
    mount_gradient_assumed: bool = False  # the share is the default, not stated
    sphere_form_um: float = 0.0  # the tracer's reference sphere's form deviation, peak to valley (σ = PV/(2√2))
    sphere_max_order: int = 6  # its lobes' highest order
    sphere_form_assumed: str = ""  # the tracer model whose specified form is assumed, none being stated ("": as stated)
    sphere_map_u_um: float = 0.0  # the lengths corrected by the sphere's certified map: its standard uncertainty, µm
    sphere_map_note: str = ""  # which certificate
    temperature_on_mount: bool = False  # the lengths corrected with a probe on the tracer's mount, not the table's sensor


@dataclass(frozen=True)
class StationObservations:
    """Which point, station and stage visit each residual of an estimator belongs to."""

    point: np.ndarray  # (N,) index into points
    station: np.ndarray  # (N,)
    visit: np.ndarray  # (N,) stage visit (shared by the lengths taken without the table moving)
    points_mm: np.ndarray  # (n, 3) as the solver used them
    point_visits: np.ndarray  # (n,) how many CMM readings were averaged into each point
    run_fraction: np.ndarray | None = None  # (N,) each length's place in the run, −1 first … +1 last (air drift)
    material_offset_k: np.ndarray | None = None  # (N,) the table's measured temperature above 20 °C at each length


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


def error_motion_covariances(stations_mm: np.ndarray, nominal_angles_rad: np.ndarray, axis_center_mm: np.ndarray,
                             noise: StationNoiseModel) -> list[tuple[str, float, str, np.ndarray]]:
    """(name, bound, unit, 3m×3m covariance of the station displacements, mm²) for the radial, axial
    and tilt error motions the procedure bounds (σ = bound/√2 at every angle)."""
    m = len(stations_mm)
    rho = harmonic_correlation(np.asarray(nominal_angles_rad, float), max(noise.error_motion_max_order, 1))
    d = np.asarray(stations_mm, float) - np.array([axis_center_mm[0], axis_center_mm[1], noise.tilt_center_z_mm])
    one, zero = np.ones(m), np.zeros(m)
    kinds = [
        ("error motions, radial (EXC, EYC)", noise.error_motion_radial_um, "µm", noise.error_motion_radial_um * 1e-3,
         [np.column_stack([one, zero, zero]), np.column_stack([zero, one, zero])]),
        ("error motion, axial (EZC)", noise.error_motion_axial_um, "µm", noise.error_motion_axial_um * 1e-3,
         [np.column_stack([zero, zero, one])]),
        ("error motions, tilt (EAC, EBC)", noise.error_motion_tilt_arcsec, "″", arcsec_to_rad(noise.error_motion_tilt_arcsec),
         [np.column_stack([zero, -d[:, 2], d[:, 1]]), np.column_stack([d[:, 2], zero, -d[:, 0]])]),  # εx × d, εy × d
    ]
    out = []
    for name, bound, unit, bound_internal, sensitivities in kinds:
        if bound <= 0:
            continue
        s = bound_internal / np.sqrt(2)
        cov = np.zeros((3 * m, 3 * m))
        for gj in sensitivities:
            outer = np.einsum("ia,jb->iajb", gj, gj).reshape(3 * m, 3 * m)
            cov += s * s * np.kron(rho, np.ones((3, 3))) * outer
        out.append((name, bound, unit, cov))
    return out


AIR_DRIFT_SOURCE = "air refractive index (no sensor)"


def air_drift_effect(distances_mm: np.ndarray, run_fraction: np.ndarray, bound: float) -> np.ndarray:
    """(N, 2): what the air's index, uncorrected, does to the lengths' residuals per 1σ of its offset and
    of its drift over the run.

    A tracking interferometer referenced at t₀ reports l = (n(t)·L(t) − n(t₀)·L(t₀))/n_a, n_a the index
    it assumes. With n = n_a·(1 + Δn) the reading is L(t) − L(t₀) + Δn(t)·L(t) − Δn(t₀)·L(t₀): the
    last term is one constant per tracking segment, which its dead path absorbs (one per segment, or
    per station in the paper's model), so each length carries Δn(t)·L(t) — L the whole distance from the
    tracer to the reflector, not the counted one. A constant Δn is a scale of every distance (the
    network's CMM scales and radius largely take it up); a drift scales the lengths of different
    points and stations differently, which no unknown of the model can take up.

    Δn(t) is modelled as a straight line over the run between its values at the run's first and last
    length, each anywhere within ±B (rectangular, independent: GUM's distribution for a range with
    nothing known inside it). With τ = −1 at the first length and +1 at the last, Δn = a + b·τ with
    a, b the half sum and half difference of the two ends: σ(a) = σ(b) = B/√6, uncorrelated, and the
    line stays within ±B. A straight line because the air of a closed room drifts (weather, warm-up)
    over hours far more than it oscillates within a run; faster variations (an air conditioner's
    cycle) act as length noise, which the residuals' Type A estimate sees. ``rtcal uncertainty``
    draws the air the same way."""
    L = np.asarray(distances_mm, float)
    tau = np.nan_to_num(np.asarray(run_fraction, float))
    s = bound / np.sqrt(6.0)
    return np.column_stack([L * s, L * tau * s])


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
    at_1m = noise.length_noise_um + noise.length_noise_ppm  # the stated σ of a 1 m length, µm: its reference size
    sources = [Source("tracer length noise", "A", ref_len, at_1m if np.max(shape) > 0 else 1.0, "µm at 1 m",
                      f"a + b·L with b/a as stated ({noise.length_noise_um:g} µm + {noise.length_noise_ppm:g} ppm); size from the residuals")]
    s_p = noise.point_noise_um * 1e-3 if noise.point_noise_um > 0 else 1e-3
    w = s_p / np.sqrt(np.maximum(np.asarray(obs.point_visits, float), 1.0))[obs.point]
    F = Grouped(u * w[:, None], np.asarray(obs.point), n)  # a point's 3 errors move each of its lengths by u·δA
    sources.append(Source("CMM point noise", "A", F, noise.point_noise_um if noise.point_noise_um > 0 else 1.0, "µm",
                          "per point and coordinate, common to all stations; size from the residuals"))
    if noise.stage_repeatability_arcsec > 0:
        visits, vidx = np.unique(obs.visit, return_inverse=True)
        axis = np.asarray(axis_direction, float) / np.linalg.norm(axis_direction)
        tangent = np.cross(axis, P - np.asarray(axis_center_mm, float))  # δP per rad about the axis
        Fv = Grouped((-np.einsum("ij,ij->i", u, tangent) * arcsec_to_rad(noise.stage_repeatability_arcsec))[:, None],
                     vidx, len(visits))  # one turn per visit, shared by the visit's lengths
        sources.append(Source("stage repeatability", "B", Fv, noise.stage_repeatability_arcsec, "″",
                              "per visit, as stated"))
    if noise.air_index_sigma > 0:  # one error of the index for the whole run scales every counted distance
        sources.append(Source("air refractive index", "B", (L * noise.air_index_sigma)[:, None], noise.air_index_sigma * 1e6,
                              "ppm", "from the environment sensor's stated uncertainty, common to every length"))
    if noise.air_index_bound > 0:
        if obs.run_fraction is None:
            raise ValueError("the air's drift needs each length's place in the run")
        sources.append(air_drift_source(L, obs.run_fraction, noise))
    sources += table_expansion_sources(u, P, axis_center_mm, axis_direction, obs.material_offset_k, noise)
    sources += sensor_noise_sources(L, radial_sensitivity_mm(u, P, axis_center_mm, axis_direction), obs.material_offset_k,
                                    noise)
    if noise.cmm_field_um > 0:
        sources.append(cmm_field_source(u, obs.point, pts, noise))
    sources += mount_gradient_sources(radial_sensitivity_mm(u, P, axis_center_mm, axis_direction), obs.material_offset_k,
                                      obs.run_fraction, noise)
    if noise.sphere_form_um > 0 or noise.sphere_map_u_um > 0:
        sources.append(sphere_form_source(u, P, axis_center_mm, axis_direction, noise))
    for label, prefix, sigma, unit in (("CMM scales", "scale", noise.cmm_scale_ppm, "ppm"),
                                       ("CMM squarenesses", "squareness", noise.cmm_squareness_arcsec, "″")):
        columns = [-np.einsum("ij,ij->i", u, (pts @ dM.T)[obs.point]) * sigma
                   for name, dM in cmm_matrix_derivatives() if name.startswith(prefix)]
        if sigma > 0:
            sources.append(Source(label, "B", np.column_stack(columns), sigma, unit, "each of three, as stated"))
    return sources


CMM_FIELD_SOURCE = "CMM geometry beyond scales and squarenesses (smooth field)"


def cmm_field_source(unit_mm: np.ndarray, point: np.ndarray, points_mm: np.ndarray, noise: StationNoiseModel) -> Source:
    """The CMM's smooth geometric error (Type B): each coordinate's error over the volume a random field of
    1σ ``cmm_field_um`` with correlation exp(−d²/2ℓ²) between points d apart, independent between
    coordinates. Unlike the point noise it does not average out over points: neighbouring points are off
    alike, which bends the point cloud the stations are fitted to — a distortion the stations and dead
    paths partly take up, so the residuals barely show it while the angles carry it. Each length moves by
    u·e(A) of its point's error."""
    root = cmm_field_root_mm(points_mm, noise)
    pointwise = Grouped(np.asarray(unit_mm, float), np.asarray(point), len(root)).sparse()  # u·δA of each length's point
    return cmm_field_as_source(Factored(pointwise, field_mix(root)), noise)


def field_mix(root: np.ndarray) -> np.ndarray:
    """(3n, 3n): the points' errors (x, y, z of each point in turn) from the field's inputs (every x, then y, then z)."""
    n = len(root)
    mix = np.zeros((3 * n, 3 * n))
    for c in range(3):
        mix[c::3, c * n:(c + 1) * n] = root
    return mix


def cmm_field_root_mm(points_mm: np.ndarray, noise: StationNoiseModel) -> np.ndarray:
    """(n, n) R with R·Rᵀ the covariance of one coordinate's field error over the points, mm² (K may be
    singular for points close together: an eigen-root, not Cholesky)."""
    pts = np.asarray(points_mm, float)
    d2 = np.sum((pts[:, None, :] - pts[None, :, :]) ** 2, axis=2)
    w, vec = np.linalg.eigh(np.exp(-0.5 * d2 / noise.cmm_field_length_mm**2))
    return vec * np.sqrt(np.clip(w, 0.0, None))[None, :] * noise.cmm_field_um * 1e-3


def cmm_field_as_source(effect: Effect, noise: StationNoiseModel) -> Source:
    """The field's budget line, ``effect`` its (N, 3n) effect on an estimator's residuals."""
    return Source(CMM_FIELD_SOURCE, "B", effect, noise.cmm_field_um, "µm",
                  f"1σ per coordinate as stated, correlated over {noise.cmm_field_length_mm:g} mm (exp(−d²/2ℓ²)), "
                  "independent between coordinates; common to every station's length to a point and its neighbours")


def radial_sensitivity_mm(unit_mm: np.ndarray, stations_mm: np.ndarray, axis_center_mm: np.ndarray,
                          axis_direction: np.ndarray) -> np.ndarray:
    """(N,): how much each length shortens per unit of the table's relative radial growth g: the
    station moves by g·ρ (ρ its distance vector from the axis, across it), the length |A − P| by −u·ρ·g."""
    a = np.asarray(axis_direction, float) / np.linalg.norm(axis_direction)
    rel = np.asarray(stations_mm, float) - np.asarray(axis_center_mm, float)
    rho = rel - np.outer(rel @ a, a)
    return np.einsum("ij,ij->i", np.asarray(unit_mm, float), rho)


THERMAL_SOURCE = "thermal expansion of the table (coefficient)"
THERMAL_SENSOR_SOURCE = "thermal expansion: table temperature sensor"
THERMAL_MOUNT_SENSOR_SOURCE = "thermal expansion: temperature probe on the tracer's mount"
THERMAL_RANGE_SOURCE = "thermal expansion of the table (no temperature sensor)"


def table_expansion_sources(unit_mm: np.ndarray, stations_mm: np.ndarray, axis_center_mm: np.ndarray,
                            axis_direction: np.ndarray, material_offset_k: np.ndarray | None,
                            noise: StationNoiseModel) -> list[Source]:
    """With the table's temperature measured at each length (the lengths corrected for the growth
    α·ΔT of the table about the axis): what the correction leaves — the coefficient's uncertainty
    times each length's ΔT, and the sensor's uncertainty times α, one error for the run (Type B)."""
    if material_offset_k is None or noise.material_temperature_bound_k > 0:
        return []
    s = radial_sensitivity_mm(unit_mm, stations_mm, axis_center_mm, axis_direction)
    dT = np.nan_to_num(np.asarray(material_offset_k, float))
    out = []
    if noise.table_expansion_u_ppm_per_k > 0 and (np.any(dT != 0) or noise.table_expansion_assumed):  # an assumed α: always said
        out.append(Source(thermal_source_name(noise), "B", (s * dT * noise.table_expansion_u_ppm_per_k * 1e-6)[:, None],
                          noise.table_expansion_u_ppm_per_k, "ppm/K",
                          f"the lengths corrected for the table's growth about the axis, α = {noise.table_expansion_ppm_per_k:g} "
                          f"ppm/K, with the measured table temperature ({float(np.min(dT)) + 20:.2f}…{float(np.max(dT)) + 20:.2f} °C);"
                          + (f" α not stated: the default for a {noise.table_expansion_assumed} table, its uncertainty "
                             f"{noise.table_expansion_u_ppm_per_k:g} ppm/K (state uncertainty.table_expansion_ppm_per_k; "
                             "0 for a table that does not grow)" if noise.table_expansion_assumed
                             else " α's standard uncertainty as stated")))
    if noise.table_expansion_ppm_per_k > 0 and noise.material_temperature_sigma_k > 0:
        on_mount = noise.temperature_on_mount
        out.append(Source(THERMAL_MOUNT_SENSOR_SOURCE if on_mount else THERMAL_SENSOR_SOURCE, "B",
                          (s * noise.table_expansion_ppm_per_k * 1e-6 * noise.material_temperature_sigma_k)[:, None],
                          noise.material_temperature_sigma_k, "K",
                          ("the mount probe's uncertainty as stated (the lengths corrected with the temperature of the "
                           "region that carries the tracer)" if on_mount else "the table temperature's sensor uncertainty "
                           "as stated") + ", one error for the run, times α"))
    return out


def thermal_source_name(noise: StationNoiseModel) -> str:
    """The coefficient's budget line; it says when α is a default, not stated (every table and certificate shows it)."""
    if not noise.table_expansion_assumed:
        return THERMAL_SOURCE
    return (f"{THERMAL_SOURCE}: not stated, {noise.table_expansion_assumed}'s {noise.table_expansion_ppm_per_k:g} ± "
            f"{noise.table_expansion_u_ppm_per_k:g} ppm/K assumed")


MOUNT_GRADIENT_SOURCE = "thermal expansion: the tracer's mount against the table's sensor (gradient)"


def mount_gradient_sources(radial_mm: np.ndarray, material_offset_k: np.ndarray | None, run_fraction: np.ndarray | None,
                           noise: StationNoiseModel) -> list[Source]:
    """The sensor reads the table where it sits, not where the tracer is mounted (a motor under the table warms the
    mount faster than the rim): the lengths are corrected with the sensor's change ΔT_s(t) while the mount's region
    changed by (1 + γ)·ΔT_s(t), γ unknown with σ ``mount_gradient_share``. Each length then keeps α·γ·ΔT_s(t)·ρ of
    growth (ΔT_s from the run's first length: a constant gradient only scales the circle, which every estimator
    takes up), one input γ for the run (Type B, dense (N, 1)). A gradient that changes while the sensor's reading
    does not (a heat source with the sensor steady) is not this term: the method section says so."""
    if material_offset_k is None or noise.mount_gradient_share <= 0 or noise.table_expansion_ppm_per_k <= 0 \
            or noise.material_temperature_bound_k > 0:
        return []
    dT = np.nan_to_num(np.asarray(material_offset_k, float))
    first = int(np.argmin(np.nan_to_num(np.asarray(run_fraction, float), nan=np.inf))) if run_fraction is not None else 0
    change = dT - dT[first]
    share = noise.mount_gradient_share
    return [Source(MOUNT_GRADIENT_SOURCE, "B", (np.asarray(radial_mm, float) * noise.table_expansion_ppm_per_k * 1e-6 * share
                                                * change)[:, None], share * 100.0, "% of ΔT",
                   f"the region carrying the tracer changes temperature by (1 ± {share:g}) × the sensor's change "
                   f"({float(np.min(change)):+.2f}…{float(np.max(change)):+.2f} K over the run), times α = "
                   f"{noise.table_expansion_ppm_per_k:g} ppm/K"
                   + ("; not stated (uncertainty.environment.mount_gradient_share): ±50 % (1σ) assumed"
                      if noise.mount_gradient_assumed else "; as stated"))]


SPHERE_SOURCE = "laser tracer reference sphere form"


def sphere_form_source(unit_mm: np.ndarray, stations_mm: np.ndarray, axis_center_mm: np.ndarray,
                       axis_direction: np.ndarray, noise: StationNoiseModel) -> Source:
    """The tracer's reference sphere is not round: each length reads off by the sphere's departure where its beam
    touches it, a function of the beam's direction in the tracer's base frame — fixed to the base, which turns with
    the table, so each station sees the points through another part of the sphere. The stated figure is a form
    deviation as a sphere's specification or certificate gives it (ISO 12181-1 / ISO 1101: the minimum-zone peak to
    valley F, the radius within ±F/2), not an amplitude. Modelled as lobes about the tracer's vertical (the axis) of
    orders 2..K (order 0 is the dead path's, order 1 a shift of the centre that the stations take up), a random
    series with σ = F/(2√2) at every azimuth — the σ of one lobe whose peak to valley is F, the shape that puts the
    most of a given F into every direction — spread equally over the orders. The beam's azimuth in the base frame is
    its azimuth about the axis less the station's own (the base turns with the station; the sign of the axis then
    does not matter: it turns ψ into −ψ, which the random phases do not see). One set of 2(K − 1) inputs for the run
    (Type B, dense)."""
    a = np.asarray(axis_direction, float) / np.linalg.norm(axis_direction)
    e1 = np.cross(a, [0.0, 1.0, 0.0] if abs(a[0]) > 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    u = np.asarray(unit_mm, float)
    rel = np.asarray(stations_mm, float) - np.asarray(axis_center_mm, float)
    psi = np.arctan2(u @ e2, u @ e1) - np.arctan2(rel @ e2, rel @ e1)
    orders = np.arange(2, max(noise.sphere_max_order, 2) + 1)
    sigma_um = noise.sphere_map_u_um if noise.sphere_map_u_um > 0 else noise.sphere_form_um / (2.0 * np.sqrt(2.0))
    s = sigma_um * 1e-3 / np.sqrt(len(orders))
    F = np.hstack([np.cos(np.outer(psi, orders)) * s, np.sin(np.outer(psi, orders)) * s])
    if noise.sphere_map_u_um > 0:  # the lengths were corrected by the certificate's map: what remains is its error
        return Source(SPHERE_SOURCE + ": corrected by its certificate's map", "B", F, noise.sphere_map_u_um, "µm (1σ)",
                      f"the lengths corrected by the sphere's map ({noise.sphere_map_note}); what remains is the map's "
                      f"uncertainty, {noise.sphere_map_u_um:g} µm (1σ) in every direction, as lobes of orders "
                      f"2..{orders[-1]} about the tracer's vertical")
    origin = (f"assumed from the {noise.sphere_form_assumed}'s specification, not stated" if noise.sphere_form_assumed
              else "as stated")
    return Source(SPHERE_SOURCE + (f": not stated, the {noise.sphere_form_assumed}'s class assumed"
                                   if noise.sphere_form_assumed else ""), "B", F, noise.sphere_form_um, "µm (peak to valley)",
                  f"the sphere's form deviation {noise.sphere_form_um:g} µm peak to valley, {origin}: lobes of orders "
                  f"2..{orders[-1]} about the tracer's vertical, fixed to its base that turns with the table (σ = PV/(2√2) "
                  "in every direction)")


AIR_NOISE_SOURCE = "air refractive index: sensor noise per reading"
THERMAL_NOISE_SOURCE = "thermal expansion: table temperature sensor noise per reading"
THERMAL_MOUNT_NOISE_SOURCE = "thermal expansion: temperature probe on the tracer's mount, noise per reading"


def sensor_noise_sources(distances_mm: np.ndarray, radial_mm: np.ndarray, material_offset_k: np.ndarray | None,
                         noise: StationNoiseModel) -> list[Source]:
    """The environment sensor's own noise, one independent error per length (Type B, its size stated).

    Each length is corrected with the sensor's reading taken with it (:func:`rtcal.solvers.air.correct_lengths`):
    an error δn of that reading's index moves the corrected length by L·δn (L the whole tracer-to-reflector
    distance), and an error δT of its table temperature moves the expansion correction by α·δT·u·ρ. Neither is
    common to the run (as the sensor's stated uncertainty, `air refractive index`, is); the network weights each length
    with it (:func:`sensor_noise_variance_mm2`)."""
    out = []
    if noise.air_index_noise > 0:
        out.append(Source(AIR_NOISE_SOURCE, "B", np.asarray(distances_mm, float) * noise.air_index_noise,
                          noise.air_index_noise * 1e6, "ppm",
                          "the environment sensor's noise per reading (temperature, pressure, humidity as stated, by "
                          "Ciddor's sensitivities), independent from length to length"))
    if material_offset_k is not None and noise.material_temperature_bound_k <= 0 and noise.table_expansion_ppm_per_k > 0 \
            and noise.material_temperature_noise_k > 0:
        out.append(Source(THERMAL_MOUNT_NOISE_SOURCE if noise.temperature_on_mount else THERMAL_NOISE_SOURCE, "B",
                          np.asarray(radial_mm, float) * noise.table_expansion_ppm_per_k * 1e-6
                          * noise.material_temperature_noise_k, noise.material_temperature_noise_k, "K",
                          f"the {'mount probe' if noise.temperature_on_mount else 'table temperature'}'s noise per reading "
                          f"as stated, times α = {noise.table_expansion_ppm_per_k:g} "
                          "ppm/K, independent from length to length"))
    return out


def sensor_noise_variance_mm2(distances_mm: np.ndarray, radial_mm: np.ndarray, material_offset_k: np.ndarray | None,
                              noise: StationNoiseModel) -> np.ndarray:
    """(N,): each length's variance from :func:`sensor_noise_sources`, mm² (for a weighted estimator's weights)."""
    total = np.zeros(len(np.asarray(distances_mm)))
    for src in sensor_noise_sources(distances_mm, radial_mm, material_offset_k, noise):
        total = total + dense_effect(src.effect) ** 2  # each one vector: one input per length
    return total


def bounded_course_component(name: str, influence: np.ndarray, sensitivity: np.ndarray, run_time: np.ndarray,
                             bound: float, unit: str, note: str, shown_bound: float | None = None) -> BudgetComponent:
    """A quantity g(t) that takes ANY course within ±``bound`` over the run whose total variation is at
    most 4·bound (one swing across the whole range and back: a step at any moment, a drift, a cycle),
    uncorrected, acting on residual i as ``sensitivity[i]``·g(t_i); ``influence`` (m×N) maps residuals
    to the output.

    With the residuals grouped by time t_1 < … < t_K and S_j(t_k) = Σ_{t_i ≥ t_k} influence_ji·s_i,
    summation by parts gives e_j = g(t_1)·S_j(t_1) + Σ_k (g(t_k) − g(t_k−1))·S_j(t_k), so
    |e_j| ≤ bound·|S_j(t_1)| + 4·bound·max_k |S_j(t_k)| for every such course: a worst case, taken
    as the half-width of a rectangular distribution (σ_j = bound_j/√3, U = 1.15·bound_j). Targets are
    correlated as their S_j profiles are (the correlation a random walk of g would give). ``shown_bound``:
    the bound in the budget's ``unit`` when that differs from g's."""
    shown = bound if shown_bound is None else shown_bound
    W = np.asarray(influence, float) * np.asarray(sensitivity, float)[None, :]
    t = np.nan_to_num(np.asarray(run_time, float))
    order = np.argsort(t, kind="stable")
    times, first = np.unique(t[order], return_index=True)
    per_time = np.add.reduceat(W[:, order], first, axis=1) if W.shape[1] else np.zeros((W.shape[0], 0))
    S = np.cumsum(per_time[:, ::-1], axis=1)[:, ::-1]  # S_j(t_k): the response to a unit step at t_k
    if S.shape[1] == 0:
        return BudgetComponent(name, "B", shown, unit, np.zeros((W.shape[0], W.shape[0])), False, note)
    worst = bound * (np.abs(S[:, 0]) + 4.0 * np.max(np.abs(S), axis=1))
    sigma = worst / np.sqrt(3.0)
    norms = np.linalg.norm(S, axis=1)
    R = (S @ S.T) / np.maximum(np.outer(norms, norms), 1e-300)
    np.fill_diagonal(R, 1.0)
    return BudgetComponent(name, "B", shown, unit, np.outer(sigma, sigma) * R, False, note)


def bounded_components(influence: np.ndarray, distances_mm: np.ndarray, radial_mm: np.ndarray, run_time: np.ndarray,
                       noise: StationNoiseModel, arcsec_per_output: float = 1.0) -> list[BudgetComponent]:
    """The uncorrected air (no sensor) and the uncorrected table temperature (no table sensor) as
    :func:`bounded_course_component`s, in the output's unit."""
    out = []
    W = np.asarray(influence, float) * arcsec_per_output
    if noise.air_index_bound > 0:
        out.append(bounded_course_component(
            AIR_DRIFT_SOURCE, W, np.asarray(distances_mm, float), run_time, noise.air_index_bound,
            "ppm (bound)", f"no environment sensor, the lengths uncorrected: {noise.air_note or 'the air within the stated ranges'};"
            " any course of the index within ±its bound over the run (a step at any moment, a drift, a cycle: total "
            "variation ≤ 4·bound), worst case per target as a rectangular half-width", noise.air_index_bound * 1e6))
    if noise.material_temperature_bound_k > 0 and noise.table_expansion_ppm_per_k > 0:
        alpha = np.hypot(noise.table_expansion_ppm_per_k, noise.table_expansion_u_ppm_per_k) * 1e-6
        out.append(bounded_course_component(
            THERMAL_RANGE_SOURCE, W, alpha * np.asarray(radial_mm, float), run_time, noise.material_temperature_bound_k, "K (bound)",
            f"the table (and the tracer on it) grows about the axis by α = {noise.table_expansion_ppm_per_k:g} ± "
            f"{noise.table_expansion_u_ppm_per_k:g} ppm/K; no sensor reads its temperature: any course within 20 ± "
            f"{noise.material_temperature_bound_k:g} °C over the run (total variation ≤ 4·range), worst case per target "
            "as a rectangular half-width"))
    return out


COURSE_KNOTS = 40  # the uncorrected air's or table's course: free between this many knots over the run, for the test


def course_nuisance(distances_mm: np.ndarray, radial_mm: np.ndarray, run_fraction: np.ndarray,
                    noise: StationNoiseModel) -> np.ndarray | None:
    """(N, K): what an uncorrected air index or table temperature that takes ANY course over the run does to the
    residuals, as K piecewise-linear (hat) functions of the run's time times each length's sensitivity (None: a
    sensor corrects both). The bounded courses (:func:`bounded_course_component`) are no Gaussian: a step within
    the stated range is as likely as a drift, and a χ² test against any covariance would call it an error. The
    residual test takes these directions out as free unknowns (ν drops by K), so whatever course the quantity
    took within the run (a step, a cycle) does not fail it; what is left is tested against the rest of the budget."""
    sensitivities = []
    if noise.air_index_bound > 0:
        sensitivities.append(np.asarray(distances_mm, float) * noise.air_index_bound)
    if noise.material_temperature_bound_k > 0 and noise.table_expansion_ppm_per_k > 0:
        sensitivities.append(np.asarray(radial_mm, float) * noise.table_expansion_ppm_per_k * 1e-6
                             * noise.material_temperature_bound_k)
    if not sensitivities:
        return None
    t = np.nan_to_num(np.asarray(run_fraction, float))
    knots = np.linspace(-1.0, 1.0, COURSE_KNOTS)
    hats = np.clip(1.0 - np.abs(t[:, None] - knots[None, :]) / (knots[1] - knots[0]), 0.0, None)
    return np.hstack([hats * s[:, None] for s in sensitivities])


STEEP_SHARE = 0.125  # a knot interval over which the fitted course moves by more than this share of its bound is refined


def course_refinement(residuals: np.ndarray, covariance: Covariance, jacobian: Any, course: np.ndarray,
                      run_fraction: np.ndarray) -> np.ndarray:
    """(N, s): steps of the uncorrected course at every reading inside the knot intervals where it moves fast.

    :func:`course_nuisance`'s hats follow a course that is smooth between their knots; a step of the air within its
    range (1.8 K in a minute) falls between two knots, and on a low-noise tracer the misfit alone fails the test. The
    course's total variation is bounded (one swing across the range and back), so it can move fast in few knot
    intervals only: the hats are fitted (generalised least squares beside J), and in each interval where the fitted
    course moves by more than :data:`STEEP_SHARE` of its bound a free step is added at every reading, so that the
    course there takes any value at each reading. The test then holds any course within the bounds (ν drops by the
    steps added: on a bench as budgeted it fails at most at its stated rate); what the course cannot take up
    (another error) is tested against the rest of the budget."""
    C = np.asarray(course, float)
    N = C.shape[0]
    basis, _ = column_basis(jacobian)
    P = covariance.restricted(jacobian, basis)
    if P is None or C.shape[1] == 0:
        return np.zeros((N, 0))
    PC = np.column_stack([P.apply(c) for c in C.T])
    g = np.linalg.lstsq(C.T @ PC, PC.T @ np.asarray(residuals, float), rcond=None)[0]
    t = np.nan_to_num(np.asarray(run_fraction, float))
    knots = np.linspace(-1.0, 1.0, COURSE_KNOTS)
    steps = []
    for block in range(C.shape[1] // COURSE_KNOTS):
        cols = C[:, block * COURSE_KNOTS:(block + 1) * COURSE_KNOTS]
        sensitivity = cols.sum(axis=1)  # the hats sum to 1: each length's sensitivity to the course (per bound)
        for k in np.flatnonzero(np.abs(np.diff(g[block * COURSE_KNOTS:(block + 1) * COURSE_KNOTS])) > STEEP_SHARE):
            inside = np.unique(t[(t > knots[k]) & (t <= knots[k + 1])])
            steps += [sensitivity * (t >= tj) for tj in inside]
    if len(steps) > N // 4:  # more than a bounded course can need: leave the test to say so
        return np.zeros((N, 0))
    return np.column_stack(steps) if steps else np.zeros((N, 0))


AIR_COURSE_SOURCE = "air refractive index (no sensor): its course estimated from the lengths"


def air_course_hats(distances_mm: np.ndarray, run_fraction: np.ndarray, noise: StationNoiseModel,
                    drop_constant: bool) -> np.ndarray:
    """(N, K) mm per ppm: the uncorrected air index's course as piecewise-linear hats of the run's time
    (:func:`course_nuisance`'s) times each length's distance, for the hats that some reading falls under; an
    estimator that solves them reads each length long by their sum. Every length is checked against points the
    estimator knows (the CMM's), so an index common to all lengths at a time is observable; where the estimator also
    solves the CMM's scales, a constant index is only a scale, which they and the circle take up exactly
    (``drop_constant``: the first hat goes, the course is then relative to the run's start)."""
    hats = course_nuisance(distances_mm, distances_mm, run_fraction,
                           StationNoiseModel(air_index_bound=noise.air_index_bound))
    if hats is None:
        return np.zeros((len(distances_mm), 0))
    hats = hats / noise.air_index_bound * 1e-6
    used = np.flatnonzero(np.any(hats != 0.0, axis=0))
    return hats[:, used[1:] if drop_constant else used]


def air_course_steps(course_ppm: np.ndarray, hats: np.ndarray, distances_mm: np.ndarray, run_fraction: np.ndarray,
                     noise: StationNoiseModel) -> np.ndarray:
    """(N, s) mm per ppm: free steps of the air's course at every reading inside the knot intervals where the fitted
    hats (``course_ppm`` on ``hats``, :func:`air_course_hats`) move by more than :data:`STEEP_SHARE` of the stated
    bound, as :func:`course_refinement` gives the residual test: a step of the air (1.8 K in a minute) falls between
    two knots, which the hats alone smear over the interval. None where the course is smooth; none either when more
    than a quarter of the readings would need one (no bounded course does)."""
    L = np.asarray(distances_mm, float) * 1e-6
    t = np.nan_to_num(np.asarray(run_fraction, float))
    knots = np.linspace(-1.0, 1.0, COURSE_KNOTS)
    full = np.clip(1.0 - np.abs(t[:, None] - knots[None, :]) / (knots[1] - knots[0]), 0.0, None)
    at_knots = np.linalg.lstsq(full, (hats @ course_ppm) / L, rcond=None)[0]  # the fitted index at each knot, ppm
    steps = []
    for k in np.flatnonzero(np.abs(np.diff(at_knots)) > STEEP_SHARE * noise.air_index_bound * 1e6):
        steps += [L * (t >= tj) for tj in np.unique(t[(t > knots[k]) & (t <= knots[k + 1])])]
    if not steps or len(steps) > len(t) // 4:
        return np.zeros((len(t), 0))
    return np.column_stack(steps)


def air_course_seen(sigma_ppm: np.ndarray, noise: StationNoiseModel) -> bool:
    """Whether the lengths see the air's course at all: the σ of its value at each knot (its hats, before any step
    is added; ``sigma_ppm``) below 2·bound, the whole span the stated range allows the course relative to its start.
    Beyond that the readings know less of the course than the statement does, and the model without it with the
    range's worst case (:func:`bounded_course_component`) is the better answer: where the lengths at a time barely
    differ (a point's lengths to stations at one distance, each point on its own tracking segment: the course is then
    its dead path), with too few lengths under a hat, or a tracer too noisy for the range. A hat known worse than the
    range's own σ is still worth solving: the estimator propagates its σ (air_step: 0.2 µm tracer, hats to ±2 ppm, a
    ±1.6 ppm range; coverage 98 %, σ/RMS 1.2 on 20 trials, docs/paper000.md)."""
    sigma_ppm = np.asarray(sigma_ppm, float)
    return bool(np.all(np.isfinite(sigma_ppm)) and np.all(sigma_ppm < 2.0 * noise.air_index_bound * 1e6))


# the per-reading noise an estimate of the air's course carries into the deviations: its own line, beside these
COURSE_NOISE_SOURCES = ("tracer length noise", "CMM point noise", "stage repeatability", AIR_NOISE_SOURCE,
                        THERMAL_NOISE_SOURCE, THERMAL_MOUNT_NOISE_SOURCE)


def air_course_component(sigma_ppm: np.ndarray, covariance: np.ndarray, unknowns: int, noise: StationNoiseModel,
                         how: str) -> BudgetComponent:
    """The budget's line for the air's course solved (no sensor): its estimation uncertainty in the deviations
    (``covariance``, what the readings' noise does through the course's estimate), its σ per unknown (RMS shown);
    ``how``: what the estimator checks the lengths against and how it propagates."""
    sigma_ppm = np.asarray(sigma_ppm, float)
    return BudgetComponent(
        AIR_COURSE_SOURCE, "A", float(np.sqrt(np.mean(sigma_ppm**2))) if sigma_ppm.size else 0.0,
        "ppm (the course's σ, RMS)", 0.5 * (covariance + covariance.T), True,
        f"no environment sensor, the lengths uncorrected ({noise.air_note or 'the air within the stated ranges'}): the "
        f"index's course over the run solved beside the rotation ({unknowns} unknowns: a hat every "
        f"1/{COURSE_KNOTS - 1} of the run and a step at each reading where it moves fast), {how}")


def air_drift_source(distances_mm: np.ndarray, run_fraction: np.ndarray, noise: StationNoiseModel) -> Source:
    """The uncorrected air as a Type B source (:func:`air_drift_effect`), its σ in ppm of index."""
    return Source(AIR_DRIFT_SOURCE, "B", air_drift_effect(distances_mm, run_fraction, noise.air_index_bound),
                  noise.air_index_bound / np.sqrt(6.0) * 1e6, "ppm",
                  f"no environment sensor, the lengths uncorrected: {noise.air_note or 'the air within the stated ranges'}; "
                  "each linear over the run between its values at the first and the last length, each end anywhere "
                  "within the range (rectangular, independent); input σ: of the index's mean over the run and of its "
                  "half change, each (√(Σ bound²/6))")


@dataclass(frozen=True)
class StationBudget:
    """The cumulative deviation's budget (m targets), and the estimated Type A sizes."""

    cumulative: DeviationBudget
    variances: VarianceEstimate
    sources: list[Source]
    residual_check: ResidualCheck | None = None  # the residuals against the stated noise model

    @property
    def step_uncertainty_arcsec(self) -> np.ndarray:
        """1σ of the per-step deviations (eq. 33's Δθ), from the same covariance."""
        return self.cumulative.transformed(difference_matrix(len(self.cumulative.uncertainty_arcsec))).uncertainty_arcsec

    def estimated_sigma(self, name: str) -> float | None:
        for s in self.sources:
            if s.name == name:
                return self.variances.sigma(s)
        return None


def station_budget(
    jacobian: np.ndarray | Any,
    residuals: np.ndarray,
    station_columns: np.ndarray,
    obs: StationObservations,
    stations_mm: np.ndarray,
    nominal_angles_rad: np.ndarray,
    axis_center_mm: np.ndarray,
    axis_direction: np.ndarray,
    cumulative_of_stations: Callable[[np.ndarray], np.ndarray],
    noise: StationNoiseModel,
    air_course_columns: np.ndarray | None = None,
) -> StationBudget:
    """The budget of the cumulative deviation of an estimate with Jacobian J (N×p, dense or
    scipy.sparse: a length touches one station and one dead path) and residuals f.

    ``station_columns`` (m×3) says which unknowns are the stations' X, Y, Z; the cumulative
    deviation follows from the stations by ``cumulative_of_stations``. The estimator's influence
    on the stations, J⁺ = (JᵀJ)⁺Jᵀ, goes through J's R factor (p×p, from row chunks); with the
    chain's G only G·J⁺ (m×N) is formed.

    ``air_course_columns``: J's columns that are the uncorrected air's course the estimator solved (no sensor,
    :func:`air_course_hats`): its estimation uncertainty is then a line of its own (:data:`AIR_COURSE_SOURCE`), the
    range's worst case for the air goes, and the residual test's J holds the course.
    """
    J = _as_sparse(jacobian)
    solved = air_course_columns is not None and len(air_course_columns) > 0
    unsolved = replace(noise, air_index_bound=0.0) if solved else noise  # what is left to the range's worst case
    sources = observation_sources(obs, stations_mm, axis_center_mm, axis_direction, noise)
    variances = reml_scales(J, residuals, sources) if noise.estimate else VarianceEstimate({}, {}, 0, True)
    G = chain_jacobian(stations_mm, cumulative_of_stations)
    P = np.asarray(stations_mm, float)[obs.station]
    diff = np.asarray(obs.points_mm, float)[obs.point] - P
    L = np.linalg.norm(diff, axis=1)
    radial = radial_sensitivity_mm(diff / L[:, None], P, axis_center_mm, axis_direction)
    stated_zero = noise.point_noise_um <= 0 or (noise.length_noise_um <= 0 and noise.length_noise_ppm <= 0)
    N = len(np.asarray(residuals))
    course = None if stated_zero else course_nuisance(L, radial, obs.run_fraction if obs.run_fraction is not None
                                                      else np.linspace(-1, 1, N), unsolved)
    tested = J if course is None else _hstack(J, course)  # the residual test's J: the air's course free beside it
    R = r_factor(tested)  # J's R factor is its leading block: one pass over the rows for both
    # G·(rows of J⁺ for the stations) = (G·(JᵀJ)⁺[stations])·Jᵀ: the influence of every length on the output
    p = J.shape[1]
    influence = np.asarray((J @ (G @ pseudo_inverse_gram(R[:p, :p])[np.asarray(station_columns).ravel()]).T).T)
    components = propagate(influence, sources, variances, np.eye(len(G)))
    if solved:
        components = _air_course_line(components, J, R[:p, :p], np.asarray(air_course_columns), G, station_columns,
                                      sources, variances, noise)
    if noise.air_index_bound > 0 or noise.material_temperature_bound_k > 0:
        # the uncorrected air and table as any course within their ranges, not the straight line the REML's V assumes
        components = [c for c in components if c.name != AIR_DRIFT_SOURCE]
        components += bounded_components(influence, L, radial, obs.run_fraction if obs.run_fraction is not None
                                         else np.linspace(-1, 1, len(L)), unsolved)
    motions = error_motion_covariances(stations_mm, nominal_angles_rad, axis_center_mm, noise)
    for name, bound, unit, cov in motions:
        components.append(BudgetComponent(name, "B", bound, unit, G @ cov @ G.T, False,
                                          f"within ±bound (σ = bound/√2, orders 1..{noise.error_motion_max_order}): one "
                                          "mount cannot separate them from the rotation"))
    check = None
    if not stated_zero:  # the whole budget as stated (Type A at θ = 1), every source that moves the residuals
        V = _tested_covariance(sources, motions, diff / L[:, None], obs.station, len(stations_mm))
        steps = np.zeros((N, 0)) if course is None else course_refinement(
            residuals, V, J, course, obs.run_fraction if obs.run_fraction is not None else np.linspace(-1, 1, N))
        if steps.shape[1]:  # the course's fast moves, free at every reading there
            tested = _hstack(tested, steps / np.linalg.norm(steps, axis=0))
        check = residual_check(residuals, V, 0, jacobian=tested, jacobian_r=R if not steps.shape[1] else None,
                               scored=scorable(sources, skip=(AIR_DRIFT_SOURCE,)))
    return StationBudget(DeviationBudget(components), variances, sources, check)


def _tested_covariance(sources: list[Source], motions: list[Any], directions: np.ndarray, station: np.ndarray,
                       stations: int) -> Covariance:
    """The covariance the residual test holds the lengths to: every source as stated, the error motions through
    each length's direction (``directions``, unit, station to point) at its station."""
    V = Covariance.of_sources(sources)
    if motions:  # the error motions move the stations: each length by −u·δP of its station
        V = V.plus(Factored(Grouped(-directions, np.asarray(station), stations).sparse(),
                            covariance_root(np.sum([cov for *_, cov in motions], axis=0))))
    return V


def air_course_tested_steps(jacobian: Any, residuals: np.ndarray, obs: StationObservations, stations_mm: np.ndarray,
                            nominal_angles_rad: np.ndarray, axis_center_mm: np.ndarray, axis_direction: np.ndarray,
                            noise: StationNoiseModel) -> np.ndarray:
    """(N, s) mm per ppm: the steps of the air's course (no sensor) that the residual test would add
    (:func:`course_refinement`: the hats fitted by generalised least squares with the budget's covariance beside J)
    to an estimate without the course (``jacobian``, ``residuals``). An estimator that solves the course picks its
    steps so, not from its own unweighted fit of the hats: where the two fits disagree on which knot interval moves
    fast, a step the test would have freed is left out of the course and its misfit fails the test
    (air_step_low: 4 of 60 trials failed, 0 with the test's choice)."""
    J = _as_sparse(jacobian)
    P = np.asarray(stations_mm, float)[obs.station]
    diff = np.asarray(obs.points_mm, float)[obs.point] - P
    L = np.linalg.norm(diff, axis=1)
    t = obs.run_fraction if obs.run_fraction is not None else np.linspace(-1, 1, len(L))
    air = StationNoiseModel(air_index_bound=noise.air_index_bound)
    course = course_nuisance(L, L, t, air)
    if course is None:
        return np.zeros((len(L), 0))
    sources = observation_sources(obs, stations_mm, axis_center_mm, axis_direction, noise)
    motions = error_motion_covariances(stations_mm, nominal_angles_rad, axis_center_mm, noise)
    V = _tested_covariance(sources, motions, diff / L[:, None], obs.station, len(stations_mm))
    steps = course_refinement(residuals, V, J, course, t)
    return steps / noise.air_index_bound * 1e-6  # course_nuisance's sensitivity is L·bound: per ppm, as the hats


def _air_course_line(components: list[BudgetComponent], J: Any, R: np.ndarray, course: np.ndarray, G: np.ndarray,
                     station_columns: np.ndarray, sources: list[Source], variances: VarianceEstimate,
                     noise: StationNoiseModel) -> list[BudgetComponent]:
    """The budget with the air's course solved (J's ``course`` columns): the readings' noise
    (:data:`COURSE_NOISE_SOURCES`) each as it would act with the course known (J without those columns), and what
    estimating the course adds to them as its own line, their difference: the course's estimation uncertainty
    carried into the deviations. ``R``: J's R factor."""
    keep = np.setdiff1d(np.arange(J.shape[1]), course)
    J_known = J[:, keep]
    stations = np.searchsorted(keep, np.asarray(station_columns).ravel())  # the stations come before the course
    influence_known = np.asarray((J_known @ (G @ pseudo_inverse_gram(r_factor(J_known))[stations]).T).T)
    noisy = [i for i, src in enumerate(sources) if src.name in COURSE_NOISE_SOURCES]
    known = propagate(influence_known, [sources[i] for i in noisy], variances, np.eye(len(G)))
    extra = sum((components[i].covariance_arcsec2 - kc.covariance_arcsec2 for i, kc in zip(noisy, known)),
                np.zeros((len(G), len(G))))
    K = np.asarray((J @ pseudo_inverse_gram(R)[course].T).T)  # the course's unknowns ← the lengths
    sigma = np.sqrt(np.abs(np.diag(sum((c.covariance_arcsec2 for c in propagate(
        K, [sources[i] for i in noisy], variances, np.eye(len(course)))), np.zeros((len(course), len(course)))))))
    out = list(components)
    for i, kc in zip(noisy, known):
        out[i] = kc
    out.append(air_course_component(
        sigma, extra, len(course), noise, "the lengths checked against the points taken as known (so even a constant "
        "index is seen); its estimation uncertainty through the least-squares fit"))
    return out


def covariance_root(cov: np.ndarray) -> np.ndarray:
    """R with R·Rᵀ = cov for a positive semi-definite cov (an eigen-root: cov may be singular)."""
    w, vec = np.linalg.eigh(np.asarray(cov, float))
    keep = w > 0
    return np.asarray(vec[:, keep] * np.sqrt(w[keep])[None, :])


def _as_sparse(matrix: Any) -> Any:
    import scipy.sparse as sp

    return matrix.tocsr() if sp.issparse(matrix) else sp.csr_matrix(np.asarray(matrix, float))


def _hstack(J: Any, dense: np.ndarray) -> Any:
    import scipy.sparse as sp

    return sp.hstack([J, sp.csr_matrix(dense)]).tocsr()
