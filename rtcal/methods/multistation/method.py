"""The laser-tracer multi-station method (seed 000): plan, instruments, measurement, analysis.

:class:`MultistationMethod` implements :class:`rtcal.methods.protocol.Method`; its analysis is a
typed :class:`rtcal.results.msr.MultistationAnalysis`. Its files, figures and report sections
are the output layer's (:mod:`rtcal.methods.multistation.outputs`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Callable, Iterable, Sequence

import numpy as np

from drivers import factory
from rtcal.solvers.air import STANDARD_AIR, index_sensitivity, standard_air_n
from rtcal.methods.multistation.dataset import multistation_data
from rtcal.api import (EnvironmentSummary, Estimate, Operator, PositioningDeviations, RunReadings, RunResults, Scenario, Timing,
                       address_of, choose_recommended, deviation_block, not_covered, residual_test, run_estimators, walk,
                       with_residual_test)
from rtcal.methods.multistation.procedure import LaserTracerMultistation
from rtcal.results import model as rm  # its estimate blocks stay in the shared model (docs/architecture.md)
from rtcal.methods.multistation import results as msr
from rtcal.methods.multistation.plan import MultistationInstrumentSet, MultistationPlan, planned_readings
from rtcal.methods.multistation.recalibration import MultistationRecalibration
from rtcal.solvers.air import correct_lengths
from rtcal.solvers.lm import LMParameters
from rtcal.solvers.network import CMM_NAMES, NetworkEstimate, solve_network
from rtcal.solvers.paper000 import PAPER_NOTES, PaperEstimate, StationChain, solve_paper
from rtcal.solvers.selfcal import initial_guesses
from rtcal.solvers.shared_dead_path import (
    SharedDeadPathEstimate,
    solve_shared_dead_path,
)
from rtcal.solvers.station_budget import StationBudget, StationNoiseModel
from rtcal.solvers.station_data import MultistationData
from simulators.bench import Bench
from simulators.instruments import (
    SimCmm,
    SimEnvironmentSensor,
    SimLaserTracer,
    SimStage,
)
from simulators.scenario import AngularHarmonic, CmmFieldTerm, EnvironmentScenario, LinearHarmonic, SphereLobe
from simulators.truth import station_truth

from rtcal.methods.multistation.noise import (AIR_QUANTITIES, DEFAULT_TABLE_EXPANSION_PPM_PER_K, DEFAULT_TABLE_EXPANSION_U_PPM_PER_K,
                                              DEFAULT_TABLE_MATERIAL, air_index_bound, air_index_noise, air_index_sigma,
                                              noise_model, sphere_form, stated_air_ranges, stated_table_range,
                                              table_expansion, mount_sensor, table_sensor)

if TYPE_CHECKING:
    from rtcal.methods.multistation.planner import MultistationPlanner
    from rtcal.methods.multistation.outputs import MultistationOutputs


def _round(values: Iterable[float] | np.ndarray, digits: int = 6) -> list[float]:
    rounded: list[float] = np.round(np.asarray(values, dtype=float), digits).tolist()
    return rounded


def _growth_mm_per_ppm(data: MultistationData, proc: LaserTracerMultistation, lengths: np.ndarray, offset: np.ndarray,
                       guess: Sequence[float]) -> np.ndarray:
    """How much each length shortens per ppm/K of the table's growth about the axis: 1e-6·(T − 20 °C)·u·ρ (u from
    station to point, ρ the station's distance vector from the axis, the stations from the nominal geometry)."""
    nominal = np.deg2rad(data.nominal_angles_deg)
    axis = np.array(proc.solver.axis_point_mm, float)
    stations = initial_guesses(np.asarray(guess, float), nominal, axis, data.points_mm, lengths)[:, :3]
    diff = np.asarray(data.points_mm, float)[:, None, :] - stations[None, :, :]
    unit = diff / np.linalg.norm(diff, axis=2)[..., None]
    rho = stations - axis
    rho[:, 2] = 0.0
    out: np.ndarray = 1e-6 * offset * np.einsum("ijk,jk->ij", unit, rho)
    return out


def _per_mount(data: MultistationData, proc: LaserTracerMultistation, offsets: Sequence[np.ndarray]) -> list[np.ndarray]:
    """:func:`_growth_mm_per_ppm` for the first mount and each other mount, in that order."""
    second = proc.second_mount.first_station_guess_mm if proc.second_mount else proc.solver.first_station_guess_mm
    out = [_growth_mm_per_ppm(data, proc, data.lengths_mm, offsets[0], proc.solver.first_station_guess_mm)]
    return out + [_growth_mm_per_ppm(data, proc, o.lengths_mm, off, second) for o, off in zip(data.other_mounts, offsets[1:])]


def on_mount_probe(data: MultistationData, proc: LaserTracerMultistation) -> MultistationData:
    """With a second probe on the tracer's mount (:func:`mount_sensor`) that read every mount's lengths: the
    temperature the stations grow with is the mount's, so the expansion's correction, its growth unknown and its
    budget take the mount probe's readings in place of the table sensor's (the stations are the tracer's positions:
    the table's rim does not move them). The table's readings stay in the store and the conditions; without the
    mount's readings (a thermometer not given), the table's sensor and its gradient line as without the probe."""
    recorded = [data.mount_temperature_c] + [o.mount_temperature_c for o in data.other_mounts]
    if not mount_sensor(proc) or any(t is None for t in recorded):
        return replace(data, mount_temperature_c=None)
    others = tuple(replace(o, material_temperature_c=o.mount_temperature_c) for o in data.other_mounts)
    return replace(data, material_temperature_c=data.mount_temperature_c, other_mounts=others)


def corrected_for_expansion(data: MultistationData, proc: LaserTracerMultistation) -> MultistationData:
    """The lengths as if the table were at 20 °C: each station, grown by g = α·(T − 20 °C) about the
    axis when its length was read (T the sensor's table temperature then), moved the length by
    −g·u·ρ (u from station to point, ρ the station's distance vector from the axis), which is added back."""
    alpha_ppm = table_expansion(proc)[0]
    offsets = data.material_offsets_k()
    if alpha_ppm == 0 or offsets is None:
        return data
    first, *rest = _per_mount(data, proc, offsets)
    others = tuple(replace(o, lengths_mm=o.lengths_mm + alpha_ppm * g) for o, g in zip(data.other_mounts, rest))
    return replace(data, lengths_mm=data.lengths_mm + alpha_ppm * first, other_mounts=others)


GROWTH_SOLVED_FROM_K = 0.2  # the table's sensed change over the run from which its growth per kelvin is solved


def with_growth_unknown(data: MultistationData, proc: LaserTracerMultistation) -> MultistationData:
    """The lengths' sensitivity to the table's growth per sensed kelvin beyond the α they were corrected with
    (:func:`corrected_for_expansion`'s increment per ppm/K), so that the shared-dead-path and network estimators solve
    it: a table of another material than stated or assumed, or a mount that warms faster than the sensor reads (a
    gradient) grows the stations by the same pattern in time, which the readings determine far better than any
    stated α. Only where a sensor reads the table and its reading changes by :data:`GROWTH_SOLVED_FROM_K` or more over
    the run (a steady table leaves it undetermined); ``uncertainty.table_expansion_ppm_per_k: 0`` states a table that
    does not grow, and nothing is solved."""
    offsets = data.material_offsets_k()
    if offsets is None or table_expansion(proc)[0] == 0:
        return data
    spread = max(float(np.nanmax(o) - np.nanmin(o)) for o in offsets)
    if spread < GROWTH_SOLVED_FROM_K:
        return data
    return replace(data, growth_mm_per_ppm=tuple(_per_mount(data, proc, offsets)))


def corrected_for_air(data: MultistationData, proc: LaserTracerMultistation) -> MultistationData:
    """The lengths as geometric lengths, each corrected with the air's index at its reading."""
    if data.air_index is None:
        return data
    nominal = np.deg2rad(data.nominal_angles_deg)
    axis = np.array(proc.solver.axis_point_mm)

    def fix(lengths: np.ndarray, index: np.ndarray | None, segments: np.ndarray, guess: Sequence[float]) -> np.ndarray:
        if index is None:  # a mount read without the environment sensor (none today: the sensor reads with every length)
            return lengths
        stations = initial_guesses(np.asarray(guess, float), nominal, axis, data.points_mm, lengths)[:, :3]
        return correct_lengths(lengths, index, segments, data.points_mm, stations, standard_air_n())

    second = proc.second_mount.first_station_guess_mm if proc.second_mount else proc.solver.first_station_guess_mm
    others = tuple(replace(o, lengths_mm=fix(o.lengths_mm, o.air_index, o.segments, second)) for o in data.other_mounts)
    return replace(data, lengths_mm=fix(data.lengths_mm, data.air_index, data.segments, proc.solver.first_station_guess_mm),
                   other_mounts=others)


def corrected_for_sphere(data: MultistationData, proc: LaserTracerMultistation) -> MultistationData:
    """The lengths corrected by the reference sphere's certified map (``uncertainty.laser_tracer_sphere_map``): each
    reads short by the sphere's deviation where its beam touches it, at the beam's azimuth about the axis less the
    station's own (the tracer's base turns with the table), from the nominal geometry — a station guess off by 1 mm
    turns that azimuth by about 0.06°, a few picometres of a 50 nm form."""
    smap = proc.uncertainty.laser_tracer_sphere_map
    if smap is None:
        return data
    nominal = np.deg2rad(data.nominal_angles_deg)
    axis = np.array(proc.solver.axis_point_mm)

    def fix(lengths: np.ndarray, guess: Sequence[float]) -> np.ndarray:
        stations = initial_guesses(np.asarray(guess, float), nominal, axis, data.points_mm, lengths)[:, :3]
        beam = np.asarray(data.points_mm, float)[:, None, :] - stations[None, :, :]
        rel = stations - axis
        psi = np.arctan2(beam[..., 1], beam[..., 0]) - np.arctan2(rel[:, 1], rel[:, 0])[None, :]
        return np.asarray(lengths, float) + smap.at(psi) * 1e-3

    second = proc.second_mount.first_station_guess_mm if proc.second_mount else proc.solver.first_station_guess_mm
    others = tuple(replace(o, lengths_mm=fix(o.lengths_mm, second)) for o in data.other_mounts)
    return replace(data, lengths_mm=fix(data.lengths_mm, proc.solver.first_station_guess_mm), other_mounts=others)


def not_included(proc: LaserTracerMultistation, data: MultistationData | None = None) -> list[str]:
    """Type B sources the procedure did not state: the budget is silent on them, and says so."""
    u = proc.uncertainty
    out = []
    measured = table_sensor(proc) and (data is None or data.material_offsets_k() is not None)
    if table_expansion(proc)[0] == 0 and "table_expansion_ppm_per_k" not in u.model_fields_set:
        out.append("thermal expansion of the table: no coefficient stated (uncertainty.table_expansion_ppm_per_k); the table "
                   "and the tracer on it grow about the axis with its temperature (steel: 11.5 ppm/K), which moves the "
                   "stations between readings")
    elif not measured and stated_table_range(proc) == 0:
        out.append("thermal expansion of the table: no sensor reads the table's temperature and no range is stated "
                   "(uncertainty.environment.material_temperature_k)")
    if max(u.error_motions.radial_um, u.error_motions.axial_um, u.error_motions.tilt_arcsec) == 0:
        out.append("error motions: no bounds stated (uncertainty.error_motions); one tracer mount cannot separate "
                   "them from the rotation, so a table with error motions is off by more than this budget says")
    else:
        em = u.error_motions
        unstated = [name for name, bound in (("radial (EXC, EYC)", em.radial_um), ("axial (EZC)", em.axial_um),
                                             ("tilt (EAC, EBC)", em.tilt_arcsec)) if bound == 0]
        if unstated:
            out.append(f"error motions {', '.join(unstated)}: no bound stated while the others are "
                       "(uncertainty.error_motions); taken as zero, which a table rarely is")
    if u.cmm_field_um == 0:
        out.append("CMM geometry beyond its three scales and three squarenesses (a smooth error field): not stated "
                   "(uncertainty.cmm_field_um); each estimate's residual test (against the whole budget) shows a field "
                   "only where the stations and dead paths cannot take it up: a smooth 1 µm field passes it unseen "
                   "while it moves the angles")
    if sphere_form(proc)[0] == 0 and u.laser_tracer_sphere_map is None:
        out.append("laser tracer reference sphere form: not stated (uncertainty.laser_tracer_sphere_form_um), and the tracer "
                   "named (metadata.instruments.laser_tracer.id) is no product with a published figure: U excludes it. The "
                   "sphere is fixed to the tracer's base, which turns with the table, so its form (a LaserTRACER's: below "
                   "50 nm peak to valley) reads each point differently from each station and moves the angles")
    if u.cmm_scale_ppm == 0 and u.cmm_squareness_arcsec == 0:
        out.append("CMM scale and squareness: not stated (uncertainty.cmm_scale_ppm, cmm_squareness_arcsec)")
    if u.stage_repeatability_arcsec == 0:
        out.append("stage repeatability per visit: not stated (uncertainty.stage_repeatability_arcsec)")
    if proc.instruments.environment is None:
        ranges = stated_air_ranges(proc)
        missing = [f"{label} (uncertainty.environment.{key})" for key, label, *_ in AIR_QUANTITIES if key not in ranges]
        if missing:
            out.append("air: no environment sensor and no range stated for its " + " or ".join(missing) + "; the lengths "
                       "assume standard air (20 °C, 1013.25 hPa, 50 % RH): 1 K, 3.7 hPa or 100 % RH of change is about "
                       "1 ppm of every length")
    return out


def failure_causes(proc: LaserTracerMultistation, noise: StationNoiseModel) -> list[str]:
    """What a failed residual test means on this procedure: the budget's assumptions about the room and the
    instruments that readings could contradict, most telling first (a certificate states them with the failure)."""
    u = proc.uncertainty
    out = []
    if noise.table_expansion_assumed:
        out.append(f"the table's expansion coefficient is not the assumed {noise.table_expansion_assumed}'s "
                   f"{noise.table_expansion_ppm_per_k:g} ± {noise.table_expansion_u_ppm_per_k:g} ppm/K (another material: "
                   "state uncertainty.table_expansion_ppm_per_k)")
    elif noise.table_expansion_ppm_per_k > 0 and noise.material_temperature_bound_k <= 0:
        out.append(f"the table's expansion coefficient is not the stated {noise.table_expansion_ppm_per_k:g} ± "
                   f"{noise.table_expansion_u_ppm_per_k:g} ppm/K")
    if noise.temperature_on_mount and noise.table_expansion_ppm_per_k > 0:
        # the lengths were corrected with the mount probe: what the budget then assumes of the mount is the probe's
        within = (f" beyond ± {noise.mount_gradient_share:.0%} of its change" if noise.mount_gradient_share > 0 else "")
        out.append(f"the probe on the tracer's mount does not read the region that carries the tracer within its stated "
                   f"± {noise.material_temperature_sigma_k:g} K (a poor contact, a lag behind the mount, or a gradient "
                   f"within the mount{within})")
    elif noise.mount_gradient_share > 0 and noise.table_expansion_ppm_per_k > 0:
        out.append(f"the tracer's mount changes temperature otherwise than the table's sensor reads (beyond ± "
                   f"{noise.mount_gradient_share:.0%} of its change{', assumed' if noise.mount_gradient_assumed else ''}: "
                   "a heat source under the table)")
    if noise.material_temperature_bound_k > 0:
        out.append(f"the table left the stated 20 ± {noise.material_temperature_bound_k:g} °C")
    if noise.air_index_bound > 0:
        out.append(f"the air left the stated ranges ({noise.air_note})")
    out.append("the CMM's geometry beyond its scales and squarenesses" + (f" exceeds the stated {u.cmm_field_um:g} µm field"
                                                                           if u.cmm_field_um > 0 else " (not stated)"))
    if noise.sphere_map_u_um > 0:
        out.append("the tracer's reference sphere is not as its certificate's map (laser_tracer_sphere_map) says, or "
                   "the map's azimuth is not set as the tracer is mounted")
    elif noise.sphere_form_um == 0:
        out.append("the tracer's reference sphere is out of round (its form not stated)")
    elif noise.sphere_form_assumed:
        out.append(f"the tracer's reference sphere is out of round beyond the {noise.sphere_form_assumed}'s specified "
                   f"{noise.sphere_form_um:g} µm (assumed, not stated)")
    else:
        out.append(f"the tracer's reference sphere is out of round beyond the stated {noise.sphere_form_um:g} µm peak to valley")
    em = u.error_motions
    out.append("the table's error motions exceed their stated bounds" if max(em.radial_um, em.axial_um, em.tilt_arcsec) > 0
               else "the table's error motions (no bounds stated)")
    out.append("the tracer's or the CMM's noise is larger than stated")
    return out


def _estimated_sigma(budget: StationBudget, source: str) -> float:
    sigma = budget.estimated_sigma(source)
    if sigma is None:
        raise ValueError(f"the budget has no source {source!r}")
    return round(float(sigma), 5)


def chain_fields(ch: StationChain, budget: StationBudget, omitted: list[str], causes: Sequence[str] = ()) -> dict[str, object]:
    """What every station-based estimator reports: the deviations and their budget, eq. 34 and 36, the chain."""
    return {
        **dict(deviation_block(ch.cumulative_deviation_arcsec, budget.cumulative,
                               not_included=not_covered(omitted, budget.residual_check, causes))),
        "eq34_sigma_arcsec": round(float(ch.sigma_arcsec), 4),
        "algorithm_error_arcsec": float(ch.algorithm_error_arcsec),
        "estimated_noise": rm.EstimatedNoise(tracer_length_noise_um_at_1m=_estimated_sigma(budget, "tracer length noise"),
                                             cmm_point_noise_um=_estimated_sigma(budget, "CMM point noise")),
        "plane": rm.Plane(a=ch.plane.a, b=ch.plane.b, c=ch.plane.c, e=ch.plane.e),
        "projected_stations_mm": [_round(p) for p in ch.projected_mm],
        "center_mm": _round(ch.center_mm),
    }


def paper_estimate(est: PaperEstimate, omitted: list[str], notes: list[str], causes: Sequence[str] = ()) -> rm.PaperEstimate:
    """``estimates.paper``: the printed method, station by station."""
    return rm.PaperEstimate(
        **chain_fields(est.chain, est.budget, omitted, causes),
        stations_mm=[_round([*f.center_mm, f.dead_path_mm]) for f in est.stations],
        station_rms_residual_um=_round([f.rms_residual_um for f in est.stations], 4),
        station_iterations=[f.iterations for f in est.stations],
        converged=est.converged,
        message=with_residual_test(est.message, est.budget.residual_check),
        residual_test=residual_test(est.budget.residual_check),
        notes=list(PAPER_NOTES) + notes,
    )


def _dead_paths(segment_ids: np.ndarray, dead_paths_mm: np.ndarray) -> dict[str, float]:
    return {str(int(s)): round(float(d), 6) for s, d in zip(segment_ids, dead_paths_mm)}


def shared_dead_path_estimate(est: SharedDeadPathEstimate, omitted: list[str], causes: Sequence[str] = ()) -> rm.SharedDeadPathEstimate:
    """``estimates.shared_dead_path``: all stations jointly, one dead path per segment."""
    return rm.SharedDeadPathEstimate(
        **chain_fields(est.chain, est.budget, omitted, causes),
        stations_mm=[_round(c) for c in est.centers_mm],
        dead_paths_mm=_dead_paths(est.segment_ids, est.dead_paths_mm),
        rms_residual_um=round(est.rms_residual_um, 4),
        converged=est.converged,
        message=with_residual_test(est.message + ("" if est.budget.variances.converged else
                                                  "; the noise sizes (REML) did not converge: the uncertainty is less certain"),
                                   est.budget.residual_check),
        residual_test=residual_test(est.budget.residual_check),
    )


ERROR_MOTIONS_NOTE = (
    "per station at the mounts' plane, synchronous: the mean and the once-per-turn part removed (they belong to the "
    "axis average line, its direction and the mounts' positions); the tilt is the one about the horizontal axis "
    "perpendicular to the line joining the mounts (`tilt_axis_deg`): the tilt about that line cannot be seen, nor the "
    "axial motion EZC apart from it")


def network_estimate(est: NetworkEstimate, omitted: list[str], causes: Sequence[str] = ()) -> rm.NetworkEstimate:
    """``estimates.network``: one adjustment of axis, angles, dead paths, CMM and points (and, with
    a second mount, the error motions it separated)."""
    omitted = [o for o in omitted if not o.startswith("CMM scale")]  # solved here, not a Type B input
    em = est.error_motions
    motions = None
    if em is not None:
        omitted = [o for o in omitted if not o.startswith("error motions")]  # measured here
        mounts = [] if est.mounts_mm is None else [_round(p) for p in est.mounts_mm]
        motions = rm.ErrorMotions(
            note=ERROR_MOTIONS_NOTE,
            EXC_um=_round(em.radial_um[:, 0], 4), EYC_um=_round(em.radial_um[:, 1], 4),
            EXC_sigma_um=_round(em.radial_sigma_um[:, 0], 4), EYC_sigma_um=_round(em.radial_sigma_um[:, 1], 4),
            tilt_arcsec=_round(em.tilt_arcsec, 4), tilt_sigma_arcsec=_round(em.tilt_sigma_arcsec, 4),
            tilt_axis_deg=_round(em.tilt_axis_deg, 3), mounts_mm=mounts)
    cmm = {name: rm.CmmError(value=round(float(v), 4), sigma=round(float(s), 4) if np.isfinite(s) else None)
           for name, v, s in zip(CMM_NAMES, est.cmm_errors, est.cmm_errors_sigma)}
    return rm.NetworkEstimate(
        **dict(deviation_block(est.cumulative_deviation_arcsec, est.budget, not_included=not_covered(omitted, est.residual_check, causes))),
        estimated_noise=rm.EstimatedNoise(tracer_length_noise_um_at_1m=round(est.sigma_length_um, 5),
                                          cmm_point_noise_um=round(est.sigma_point_um, 5)),
        cmm_errors=rm.CmmErrors(**cmm),
        axis_point_mm=_round(est.axis_point_mm), axis_direction=_round(est.axis_direction, 9),
        radius_mm=round(est.radius_mm, 6),
        stations_mm=[_round(p) for p in est.stations_mm],
        dead_paths_mm=_dead_paths(est.segment_ids, est.dead_paths_mm),
        rms_length_residual_um=round(est.rms_length_residual_um, 4),
        rms_point_residual_um=round(est.rms_point_residual_um, 4),
        error_motions=motions,
        converged=est.converged,
        message=with_residual_test(est.message, est.residual_check),
        residual_test=residual_test(est.residual_check),
    )


def axis_location(est: NetworkEstimate) -> rm.AxisLocation | None:
    """``axis_location``: the network's axis line as ISO 230-7 location errors, each with its u (None if
    the solution has none to give: not finite)."""
    if est.axis_location is None or not np.all(np.isfinite(est.axis_location.covariance)):
        return None
    v, u = est.axis_location.values, est.axis_location.sigma
    return rm.AxisLocation(frame=rm.AXIS_CONVENTION, x0c_mm=round(float(v[0]), 6), x0c_mm_u=round(float(u[0]), 6),
                           y0c_mm=round(float(v[1]), 6), y0c_mm_u=round(float(u[1]), 6),
                           a0c_arcsec=round(float(v[2]), 4), a0c_arcsec_u=round(float(u[2]), 4),
                           b0c_arcsec=round(float(v[3]), 4), b0c_arcsec_u=round(float(u[3]), 4))


def error_motion_targets(est: NetworkEstimate, angles_deg: Sequence[float] | np.ndarray) -> list[rm.ErrorMotionTarget] | None:
    """``error_motions``: per target EXC, EYC (µm) and EAC, EBC (″) with u; None with one mount."""
    em = est.error_motions
    if em is None or em.tilt_xy_arcsec is None or em.radial_u_um is None or em.tilt_xy_u_arcsec is None:
        return None
    r, ru, t, tu = em.radial_um, em.radial_u_um, em.tilt_xy_arcsec, em.tilt_xy_u_arcsec
    return [rm.ErrorMotionTarget(target_deg=float(a), exc_um=round(float(r[j, 0]), 4), exc_um_u=round(float(ru[j, 0]), 4),
                                 eyc_um=round(float(r[j, 1]), 4), eyc_um_u=round(float(ru[j, 1]), 4),
                                 eac_arcsec=round(float(t[j, 0]), 4), eac_arcsec_u=round(float(tu[j, 0]), 4),
                                 ebc_arcsec=round(float(t[j, 1]), 4), ebc_arcsec_u=round(float(tu[j, 1]), 4))
            for j, a in enumerate(angles_deg)]


def _random_series(sigma: float, max_order: int, rng: np.random.Generator,
                   cls: type[LinearHarmonic] | type[AngularHarmonic]) -> list[LinearHarmonic | AngularHarmonic]:
    """A random Fourier series of orders 1..K with σ at every angle: coefficients N(0, σ²/K)."""
    if sigma <= 0:
        return []
    a, b = rng.normal(0.0, sigma / np.sqrt(max_order), (2, max_order))
    key = "amplitude_um" if cls is LinearHarmonic else "amplitude_arcsec"
    return [cls(order=k + 1, **{key: float(np.hypot(a[k], b[k]))}, phase_deg=float(np.degrees(np.arctan2(b[k], a[k]))))
            for k in range(max_order)]


FIELD_TERMS_PER_AXIS = 30  # the scenario holds at most 100 terms


def _random_field(sigma_um: float, length_mm: float, rng: np.random.Generator) -> list[CmmFieldTerm]:
    """A CMM error field as the budget models it (:func:`rtcal.solvers.station_budget.cmm_field_source`), per
    coordinate K plane waves of random wave vectors ω ~ N(0, I/ℓ²), phases uniform and amplitude σ·√(2/K):
    E[e(p)·e(p')] = σ²·E[cos ω·(p − p')] = σ²·exp(−|p − p'|²/2ℓ²) (random Fourier features)."""
    k = FIELD_TERMS_PER_AXIS
    terms = []
    for axis in "xyz":
        for omega, phase in zip(rng.normal(0.0, 1.0 / length_mm, (k, 3)), rng.uniform(0.0, 360.0, k)):
            size = float(np.linalg.norm(omega))
            terms.append(CmmFieldTerm(axis=axis, amplitude_um=sigma_um * np.sqrt(2.0 / k), wavelength_mm=min(2 * np.pi / size, 1e6),
                                      direction=tuple(float(v) for v in omega / size), phase_deg=float(phase - 270.0)))
    return terms


def _random_lobes(form_um: float, max_order: int, rng: np.random.Generator) -> list[SphereLobe]:
    """A reference sphere within its stated form deviation (peak to valley ``form_um``) as the budget models it
    (:func:`rtcal.solvers.station_budget.sphere_form_source`): one lobe of that peak to valley, its order uniform in
    2..K and its phase uniform — a sphere at its class's limit, whose coefficients have the budget's covariance
    (σ² = PV²/8 spread equally over the orders). Gaussian lobes of that σ would be spheres far out of their class
    (peak to valley ≈ 5σ, 1.9 × the stated F): not what a stated bound describes."""
    orders = max(max_order, 2) - 1
    order = 2 + min(int(rng.uniform(0.0, orders)), orders - 1)
    return [SphereLobe(order=order, amplitude_um=form_um / 2.0, phase_deg=float(rng.uniform(-180.0, 180.0)))]


def lm_parameters(proc: LaserTracerMultistation) -> LMParameters:
    lm = proc.solver.lm
    return LMParameters(beta=lm.beta, sigma=lm.sigma, epsilon=lm.epsilon,
                        mu0=None if lm.mu0 == "residual_norm" else float(lm.mu0), max_iterations=lm.max_iterations)


ROLES = {"laser_tracer": "reference standard: length", "environment": "measuring instrument: conditions",
         "cmm": "positions the reflector", "stage": "the item's drive (commanded)"}
"""The certificate's role of each instrument (a reference standard's begins with those words)."""


class MultistationMethod:
    """Seed 000's laser-tracer multi-station method (:class:`rtcal.methods.protocol.Method`)."""

    name = "laser_tracer_multistation"
    procedure_model = LaserTracerMultistation
    results_model = msr.MultistationResults
    operator_steps = True  # the tracer's reference point, a second mount
    context_columns: dict[str, str] = {}  # its plan's entries carry the store's own columns only
    estimators = ("paper", "shared_dead_path", "network")
    positioning_deviation = True  # εz: evaluation, conformity and compensation follow
    recalibration = MultistationRecalibration()  # a reference instrument's new calibration (catalog reassess)

    def plan_length(self, proc: LaserTracerMultistation) -> int:
        return len(planned_readings(proc))

    def scenario_problem(self, proc: LaserTracerMultistation, scenario: Scenario) -> tuple[tuple[str, ...], str] | None:
        """The stage's and CMM's limits are every method's check (rtcal/run/runner.py): nothing besides."""
        return None

    def checks_text(self, proc: LaserTracerMultistation) -> list[str]:
        v = proc.verification
        return [f"CMM: its reported position within {v.cmm_tolerance_mm:g} mm of the commanded point before the length "
                "is read, and unmoved after it",
                f"laser tracer: each length within {v.tracer_tolerance_mm:g} mm of what the nominal geometry expects"]

    def conditions(self, results: RunResults) -> EnvironmentSummary | None:
        return results.environment if isinstance(results, msr.MultistationResults) else None

    def instrument_roles(self, results: RunResults) -> dict[str, str]:
        """Each instrument's role on the certificate (a reference standard's begins with those words)."""
        return dict(ROLES)

    @property
    def planner(self) -> MultistationPlanner:
        from rtcal.methods.multistation.planner import MultistationPlanner

        return MultistationPlanner()

    def outputs(self, results: RunResults) -> MultistationOutputs:
        from rtcal.methods.multistation.outputs import MultistationOutputs

        if not isinstance(results, msr.MultistationResults):
            raise TypeError(f"multi-station outputs need multi-station results, not {type(results).__name__}")
        return MultistationOutputs(results)

    def sim_instruments(self, proc: LaserTracerMultistation, bench: Bench) -> MultistationInstrumentSet:
        env = SimEnvironmentSensor(bench, mount_probe=mount_sensor(proc)) if proc.instruments.environment is not None else None
        return MultistationInstrumentSet(stage=SimStage(bench), cmm=SimCmm(bench), laser_tracer=SimLaserTracer(bench),
                                         environment=env)

    def transport_instruments(self, proc: LaserTracerMultistation) -> MultistationInstrumentSet:
        i = proc.instruments
        stage = factory.open_stage(address_of(i.stage), i.stage.soft_limits_deg, i.stage.timeout_s)
        cmm = factory.open_cmm(address_of(i.cmm), i.cmm.volume_min_mm, i.cmm.volume_max_mm, i.cmm.timeout_s, i.cmm.tool,
                               i.cmm.home)
        tracer = factory.open_laser_tracer(address_of(i.laser_tracer), i.laser_tracer.timeout_s)
        env = factory.open_environment(address_of(i.environment), i.environment.timeout_s) if i.environment is not None else None
        return MultistationInstrumentSet(stage=stage, cmm=cmm, laser_tracer=tracer, environment=env)

    def prepare(self, proc: LaserTracerMultistation, operator: Operator) -> dict[str, str]:
        """Nothing to fix before the first motion."""
        return {}

    def plan(self, proc: LaserTracerMultistation, done: set[int], generation: int = 0,
             stage_step_deg: float = 0.0) -> MultistationPlan:
        return MultistationPlan(proc, stage_step_deg)

    def analyse(self, proc: LaserTracerMultistation, store: RunReadings, bench: Bench | None,
                estimate_noise: bool = True) -> msr.MultistationAnalysis:
        """Logged readings → every estimator that can run (a failure is recorded, not fatal), the
        recommended one, its positioning-deviation table, and the truth of a simulated run."""
        angles = proc.stations.angles_deg()
        data = on_mount_probe(corrected_for_sphere(corrected_for_air(multistation_data(
            store, angles, len(proc.points_array()), proc.mounts), proc), proc), proc)
        data = with_growth_unknown(corrected_for_expansion(data, proc), proc)
        guess, axis = np.array(proc.solver.first_station_guess_mm), np.array(proc.solver.axis_point_mm)
        noise = noise_model(proc, estimate_noise, mount_probe=data.mount_temperature_c is not None)
        omitted = not_included(proc, data)
        if table_sensor(proc) and data.material_offsets_k() is None:  # the sensor read no table temperature
            noise = replace(noise, material_temperature_sigma_k=0.0)
        segments = len(set(data.segments[np.isfinite(data.lengths_mm)].tolist()))
        paper_notes = [] if segments <= 1 else [
            f"The tracer was referenced {segments} times (re-acquisitions or resumed starts): the per-station model "
            "then carries one dead path per station and segment, which weakens it further; shared_dead_path does not "
            "suffer from this."]
        second = [np.array(proc.second_mount.first_station_guess_mm)] if proc.second_mount else None
        solved: dict[str, NetworkEstimate] = {}  # the network's own solution: the axis and error motions come from it

        def network() -> Estimate:
            solved["network"] = solve_network(data, guess, axis, noise, mount_guesses_mm=second)
            return network_estimate(solved["network"], omitted, causes)

        causes = failure_causes(proc, noise)
        solvers: dict[str, Callable[[], Estimate]] = {
            "paper": lambda: paper_estimate(solve_paper(data, guess, axis, lm_parameters(proc), noise), omitted, paper_notes,
                                            causes),
            "shared_dead_path": lambda: shared_dead_path_estimate(solve_shared_dead_path(data, guess, axis, noise), omitted,
                                                                  causes),
            "network": network,
        }
        estimates, status = run_estimators({k: f for k, f in solvers.items() if k in proc.solver.estimators})
        recommended = choose_recommended(estimates, status)
        direction = 1 if proc.stations.approach == "positive" else -1
        table = None
        if recommended is not None:
            e = estimates[recommended]
            table = PositioningDeviations(np.asarray(angles, float), np.full(len(angles), direction), np.ones(len(angles), int),
                                          np.array(e.cumulative_deviation_arcsec, float),
                                          np.array(e.cumulative_uncertainty_arcsec, float), estimator=recommended).to_model()
        return msr.MultistationAnalysis(
            nominal_angles_deg=[float(a) for a in angles],
            raw_readings=data.raw_readings,
            environment=None if data.environment is None else EnvironmentSummary.model_validate(data.environment),
            recommended=recommended,
            solver_status=status,
            estimates=msr.MultistationEstimates(**estimates),
            positioning_deviations=table,
            truth=None if bench is None else msr.StationTruth.model_validate(station_truth(bench, angles, direction)),
            axis_location=axis_location(solved["network"]) if "network" in estimates and "network" in solved else None,
            error_motions=error_motion_targets(solved["network"], angles) if "network" in estimates and "network" in solved
            else None,
        )

    def draw_systematics(self, proc: LaserTracerMultistation, scenario: Scenario, rng: np.random.Generator) -> Scenario:
        """A bench whose unknown systematic errors are drawn as the procedure's budget models them:
        CMM scales and squarenesses N(0, u), error motions as random series with σ = bound/√2
        (for `rtcal uncertainty`; GUM Supplement 1)."""
        u = proc.uncertainty
        em = u.error_motions
        k = em.max_order
        cmm = scenario.cmm.model_copy(update={
            "scale_error_ppm": tuple(float(x) for x in rng.normal(0.0, u.cmm_scale_ppm, 3)),
            "squareness_xy_arcsec": float(rng.normal(0.0, u.cmm_squareness_arcsec)),
            "squareness_xz_arcsec": float(rng.normal(0.0, u.cmm_squareness_arcsec)),
            "squareness_yz_arcsec": float(rng.normal(0.0, u.cmm_squareness_arcsec))})
        if u.cmm_field_um > 0:  # the stated field replaces the bench's
            cmm = cmm.model_copy(update={"error_field": _random_field(u.cmm_field_um, u.cmm_field_length_mm, rng)})
        r, ax, t = em.radial_um / np.sqrt(2), em.axial_um / np.sqrt(2), em.tilt_arcsec / np.sqrt(2)
        stage = scenario.stage.model_copy(update={
            "radial_motion_x": _random_series(r, k, rng, LinearHarmonic), "radial_motion_y": _random_series(r, k, rng, LinearHarmonic),
            "axial_motion": _random_series(ax, k, rng, LinearHarmonic),
            "tilt_motion_x": _random_series(t, k, rng, AngularHarmonic), "tilt_motion_y": _random_series(t, k, rng, AngularHarmonic),
            "tilt_center_height_mm": em.tilt_center_z_mm - scenario.stage.axis_point_mm[2]})
        update = {"cmm": cmm, "stage": stage}
        if sphere_form(proc)[0] > 0:  # the stated (or assumed) form replaces the bench's, drawn as the budget models it
            update["laser_tracer"] = scenario.laser_tracer.model_copy(update={"sphere_form": _random_lobes(
                sphere_form(proc)[0], u.laser_tracer_sphere_max_order, rng)})
        ranges = stated_air_ranges(proc)
        if ranges:  # no sensor: the air at the run's first and last length anywhere in its range, linear between
            update["environment"] = self._drawn_air(proc, scenario, ranges, rng)
        return scenario.model_copy(update=update)

    def _drawn_air(self, proc: LaserTracerMultistation, scenario: Scenario, ranges: dict[str, float],
                   rng: np.random.Generator) -> EnvironmentScenario:
        """The air as the budget models it without a sensor (:func:`rtcal.solvers.station_budget.air_drift_effect`):
        each stated quantity at the run's start and end independently uniform within ± its range about standard
        air, changing linearly over the planned run's duration."""
        hours = self.planned_duration_s(proc, scenario) / 3600.0
        env = scenario.environment
        update = {}
        for key, start_field, drift_field, standard in (
                ("air_temperature_k", "air_temperature_c", "air_temperature_drift_k_per_h", STANDARD_AIR["temperature_c"]),
                ("air_pressure_pa", "air_pressure_pa", "air_pressure_drift_pa_per_h", STANDARD_AIR["pressure_pa"]),
                ("humidity_pct", "humidity_pct", "humidity_drift_pct_per_h", STANDARD_AIR["humidity_pct"])):
            r = ranges.get(key, 0.0)
            first, last = (float(v) for v in rng.uniform(-r, r, 2))
            profile = {"air_temperature_k": env.air_temperature_profile, "air_pressure_pa": env.air_pressure_profile,
                       "humidity_pct": env.humidity_profile}[key]
            if profile:  # the bench states this quantity's course (a step, a cycle): it is the trial's air
                continue
            update[start_field] = standard + first
            update[drift_field] = (last - first) / hours if hours > 0 else 0.0
        return env.model_copy(update=update)

    def planned_duration_s(self, proc: LaserTracerMultistation, scenario: Scenario) -> float:
        """How long the plan takes on this bench: the plan walked with the bench's speeds (no instrument, no store)."""
        return walk(self.plan(proc, set()), Timing.of_scenario(scenario)).duration_s
