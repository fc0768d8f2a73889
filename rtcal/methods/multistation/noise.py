"""The multi-station procedure's stated noise and air, as the solvers and the planner take them."""

from __future__ import annotations

from typing import Any

import numpy as np

from rtcal.methods.multistation.procedure import LaserTracerMultistation
from rtcal.solvers.air import index_sensitivity
from rtcal.solvers.station_budget import StationNoiseModel

# The coefficient a table read by the sensor is corrected with when the procedure states none: a steel table
# (and the tracer's steel mount on it). Steels span about 10–13 ppm/K at 20 °C (carbon and low-alloy 11–12.5,
# cast iron 9–11; austenitic stainless 16–17 is outside and must be stated); 11.5 ± 2 ppm/K (1σ) covers them.
DEFAULT_TABLE_MATERIAL = "steel"
DEFAULT_TABLE_EXPANSION_PPM_PER_K = 11.5
DEFAULT_TABLE_EXPANSION_U_PPM_PER_K = 2.0

# The reference-sphere form a tracer's product specification states, peak to valley (ISO 12181-1 form deviation), µm:
# assumed when the procedure states none and metadata.instruments.laser_tracer.id names the product. Etalon's
# LaserTRACER (and -NG, -MT: the same stationary reference sphere) specifies its sphere's form deviation below 50 nm
# (docs/paper000.md, "Where the room breaks the budget"). A tracer named otherwise, or not named, states none: the
# budget then leaves the form out and says so (not_included).
SPECIFIED_SPHERE_FORM_UM: dict[str, tuple[str, float]] = {"lasertracer": ("Etalon LaserTRACER", 0.05)}


def noise_model(proc: LaserTracerMultistation, estimate: bool = True, mount_probe: bool | None = None) -> StationNoiseModel:
    """The procedure's ``uncertainty`` section as the solvers' noise model (``estimate``: Type A
    sizes from the readings; False: as stated, for a prediction). The tracer's noise is stated per
    sample; a reading averages ``samples_per_reading`` of them. ``mount_probe``: whether the lengths are corrected
    with a probe on the tracer's mount (default: as the procedure states, :func:`mount_sensor`; False where the
    readings carry none)."""
    u = proc.uncertainty
    on_mount = mount_sensor(proc) if mount_probe is None else mount_probe and mount_sensor(proc)
    em = u.error_motions
    per_reading = 1.0 / np.sqrt(proc.samples_per_reading)  # a reading averages its samples' independent noise
    return StationNoiseModel(
        length_noise_um=u.laser_tracer_noise_um * per_reading, length_noise_ppm=u.laser_tracer_noise_ppm * per_reading,
        point_noise_um=u.cmm_point_noise_um, stage_repeatability_arcsec=u.stage_repeatability_arcsec,
        cmm_scale_ppm=u.cmm_scale_ppm, cmm_squareness_arcsec=u.cmm_squareness_arcsec,
        error_motion_radial_um=em.radial_um, error_motion_axial_um=em.axial_um, error_motion_tilt_arcsec=em.tilt_arcsec,
        error_motion_max_order=em.max_order, tilt_center_z_mm=em.tilt_center_z_mm, estimate=estimate,
        air_index_sigma=air_index_sigma(proc), air_index_bound=air_index_bound(proc)[0], air_note=air_index_bound(proc)[1],
        table_expansion_ppm_per_k=table_expansion(proc)[0], table_expansion_u_ppm_per_k=table_expansion(proc)[1],
        table_expansion_assumed=table_expansion(proc)[2],
        material_temperature_sigma_k=(float(u.environment.mount_temperature_k or 0.0) if on_mount
                                      else u.environment.material_temperature_k if table_sensor(proc) else 0.0),
        material_temperature_bound_k=stated_table_range(proc), air_index_noise=air_index_noise(proc),
        material_temperature_noise_k=u.environment.material_temperature_noise_k if table_sensor(proc) else 0.0,
        cmm_field_um=u.cmm_field_um, cmm_field_length_mm=u.cmm_field_length_mm,
        mount_gradient_share=mount_gradient_share(proc, on_mount),
        mount_gradient_assumed=table_sensor(proc) and not on_mount and "mount_gradient_share" not in u.environment.model_fields_set,
        sphere_form_um=sphere_form(proc)[0], sphere_max_order=u.laser_tracer_sphere_max_order,
        sphere_form_assumed=sphere_form(proc)[1], temperature_on_mount=on_mount, **sphere_map_terms(proc))


def sphere_map_terms(proc: LaserTracerMultistation) -> dict[str, Any]:
    """The certified sphere map's standard uncertainty (its expanded U / 2) and note, when the lengths are corrected
    by one (:func:`rtcal.methods.multistation.method.corrected_for_sphere`)."""
    m = proc.uncertainty.laser_tracer_sphere_map
    if m is None:
        return {}
    return {"sphere_map_u_um": m.expanded_uncertainty_um / 2.0,
            "sphere_map_note": f"certificate {m.certificate}" if m.certificate else "its certificate, as stated"}


def sphere_form(proc: LaserTracerMultistation) -> tuple[float, str]:
    """(the reference sphere's form deviation PV, µm; the tracer model whose specification it is assumed from, or ""):
    as stated; none stated, the named product's specified class (:data:`SPECIFIED_SPHERE_FORM_UM`) — a tracer's
    sphere is never round, and a budget silent on it is short by the form's whole effect (issue 44); (0, "") when the
    tracer is not a product with a published figure."""
    u = proc.uncertainty
    if u.laser_tracer_sphere_map is not None:  # the map corrects the lengths: only its own uncertainty remains
        return 0.0, ""
    if "laser_tracer_sphere_form_um" in u.model_fields_set:
        return float(u.laser_tracer_sphere_form_um), ""
    record = proc.metadata.instruments.get("laser_tracer")
    name = "" if record is None else record.id.lower().replace(" ", "").replace("-", "")
    for key, (model, form_um) in SPECIFIED_SPHERE_FORM_UM.items():
        if key in name:
            return form_um, model
    return 0.0, ""


AIR_QUANTITIES = (("air_temperature_k", "temperature", "K", 0), ("air_pressure_pa", "pressure", "Pa", 1),
                  ("humidity_pct", "humidity", "% RH", 2))


def stated_air_ranges(proc: LaserTracerMultistation) -> dict[str, float]:
    """Without an environment sensor, the ranges the procedure states for the air during the run
    (``uncertainty.environment``, only the keys written: the defaults are a sensor's uncertainty)."""
    u = proc.uncertainty
    if proc.instruments.environment is not None or "environment" not in u.model_fields_set:
        return {}
    return {key: float(getattr(u.environment, key)) for key, *_ in AIR_QUANTITIES if key in u.environment.model_fields_set}


def table_sensor(proc: LaserTracerMultistation) -> bool:
    """Whether an environment sensor reads the table's temperature with the lengths (the simulated one
    does; a real one whose readings carry no material temperature is treated as without, at analysis)."""
    return proc.instruments.environment is not None


def mount_sensor(proc: LaserTracerMultistation) -> bool:
    """Whether the procedure states a second material probe on the tracer's mount
    (``uncertainty.environment.mount_temperature_k``), read with the table's sensor."""
    return table_sensor(proc) and proc.uncertainty.environment.mount_temperature_k is not None


def mount_gradient_share(proc: LaserTracerMultistation, on_mount: bool) -> float:
    """The gradient line's share (1σ of the mount's change beyond the probe's the lengths were corrected with): with
    the table's sensor as stated or 0.5 assumed; with a probe on the mount only as stated (the probe reads the region
    that carries the tracer: what it cannot see, a lab states)."""
    e = proc.uncertainty.environment
    if not table_sensor(proc) or (on_mount and "mount_gradient_share" not in e.model_fields_set):
        return 0.0
    return float(e.mount_gradient_share)


def table_expansion(proc: LaserTracerMultistation) -> tuple[float, float, str]:
    """(α, u(α), the material assumed or ""): as stated; with a sensor reading the table's temperature and no
    α stated, the default for a steel table — a table read warm and never corrected would leave its growth
    (1 K/h: about 1″ over a run) outside the budget. ``table_expansion_ppm_per_k: 0`` states a table that does not grow."""
    u = proc.uncertainty
    if "table_expansion_ppm_per_k" in u.model_fields_set or not table_sensor(proc):
        return float(u.table_expansion_ppm_per_k), float(u.table_expansion_u_ppm_per_k), ""
    stated_u = "table_expansion_u_ppm_per_k" in u.model_fields_set
    return (DEFAULT_TABLE_EXPANSION_PPM_PER_K, float(u.table_expansion_u_ppm_per_k) if stated_u
            else DEFAULT_TABLE_EXPANSION_U_PPM_PER_K, DEFAULT_TABLE_MATERIAL)


def stated_table_range(proc: LaserTracerMultistation) -> float:
    """Without a sensor: the table's temperature range ± about 20 °C the procedure states (0: none stated)."""
    u = proc.uncertainty
    if table_sensor(proc) or "environment" not in u.model_fields_set or \
            "material_temperature_k" not in u.environment.model_fields_set:
        return 0.0
    return float(u.environment.material_temperature_k)


def air_index_sigma(proc: LaserTracerMultistation) -> float:
    """1σ of the air's index the lengths are corrected with, from the sensor's stated uncertainty (0: no sensor)."""
    if proc.instruments.environment is None:
        return 0.0
    e = proc.uncertainty.environment
    dT, dp, dh = index_sensitivity()
    return float(np.sqrt((dT * e.air_temperature_k) ** 2 + (dp * e.air_pressure_pa) ** 2 + (dh * e.humidity_pct) ** 2))


def air_index_noise(proc: LaserTracerMultistation) -> float:
    """1σ of the index each length is corrected with from the sensor's own noise per reading (independent
    from length to length, unlike :func:`air_index_sigma`'s common error; 0: no sensor)."""
    if proc.instruments.environment is None:
        return 0.0
    e = proc.uncertainty.environment
    dT, dp, dh = index_sensitivity()
    return float(np.sqrt((dT * e.air_temperature_noise_k) ** 2 + (dp * e.air_pressure_noise_pa) ** 2
                         + (dh * e.humidity_noise_pct) ** 2))


def air_index_bound(proc: LaserTracerMultistation) -> tuple[float, str]:
    """Without a sensor: the root-sum-square of the index's bounds over the run from each stated
    range (the lengths then assume standard air and nothing corrects them), and what it is made of."""
    ranges = stated_air_ranges(proc)
    sensitivity = index_sensitivity()
    parts, squares = [], 0.0
    for key, label, unit, k in AIR_QUANTITIES:
        if ranges.get(key, 0.0) > 0:
            bound = abs(sensitivity[k]) * ranges[key]
            squares += bound**2
            parts.append(f"{label} ±{ranges[key]:g} {unit} (index ±{bound * 1e6:.2g} ppm)")
    return float(np.sqrt(squares)), ", ".join(parts)
