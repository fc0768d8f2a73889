"""The multi-station method's readings as the solvers take them (seed 000): lengths per point,
station and mount, the CMM's positions, the air. Reads the store only: what each stored quantity is
(its field, its purpose) comes from the store's descriptions, never from parsing its name."""

from __future__ import annotations

import numpy as np

from rtcal.solvers.air import ciddor_n
from rtcal.solvers.station_data import MountReadings, MultistationData
from rtcal.api import RunReadings, summarise_conditions


def multistation_data(store: RunReadings, nominal_angles_deg: np.ndarray, n_points: int, mounts: int = 1) -> MultistationData:
    """Lengths per point and station (samples averaged), per tracer mount (the readings' seating),
    with their tracking segments and stage visits; CMM positions averaged over every visit. Only the
    readings that count are used (the store's one rule: the attempt of each planned reading stored
    whole, else its last one not rejected); a length counts only from an attempt stored whole (the
    table and the probe were seen still after it)."""
    m = len(nominal_angles_deg)
    described = store.described()
    pos_sum = np.zeros((n_points, 3))
    pos_count = np.zeros((n_points, 3))
    axes = {store.quantity_of("cmm", f"position_{a}_mm"): k for k, a in enumerate("xyz")}  # a position read on arrival
    for r in store.counted("cmm"):
        if r.quantity not in axes or r.point is None:
            continue
        axis = axes[r.quantity]
        pos_sum[r.point, axis] += r.value
        pos_count[r.point, axis] += 1
    env: dict[tuple[int, int, int], dict[str, list[float]]] = {}
    for r in store.counted("environment"):
        if r.point is None or r.station is None:  # not taken at a length: no length's air
            continue
        d = described.get((r.instrument, r.quantity))
        if d is not None and not d.purpose:
            env.setdefault((r.seating or 0, r.point, r.station), {}).setdefault(d.field, []).append(r.value)
    len_sum = np.zeros((mounts, n_points, m))
    len_count = np.zeros((mounts, n_points, m))
    time_sum = np.zeros((mounts, n_points, m))
    segments = np.full((mounts, n_points, m), -1)
    visits = np.full((mounts, n_points, m), -1)
    visit, last = -1, None
    for r in store.counted("laser_tracer", "length_mm", whole_only=True):
        if r.point is None or r.station is None:
            continue
        k = r.seating or 0
        len_sum[k, r.point, r.station] += r.value
        len_count[k, r.point, r.station] += 1
        time_sum[k, r.point, r.station] += r.t_s
        segments[k, r.point, r.station] = r.segment
        if (k, r.station, r.segment) != last:  # the table moved (or a new start re-approached it)
            visit, last = visit + 1, (k, r.station, r.segment)
        visits[k, r.point, r.station] = visit
    if np.any(pos_count == 0):
        raise ValueError(f"the CMM position of {int(np.sum(pos_count[:, 0] == 0))} points was never read")
    with np.errstate(invalid="ignore", divide="ignore"):
        lengths = np.where(len_count > 0, len_sum / np.maximum(len_count, 1), np.nan)
        times = np.where(len_count > 0, time_sum / np.maximum(len_count, 1), np.nan)
    index = summary = material = mount = None
    if env:
        index = np.full((mounts, n_points, m), np.nan)
        material = np.full((mounts, n_points, m), np.nan)
        mount = np.full((mounts, n_points, m), np.nan)
        for (k, i, j), q in env.items():
            if all(name in q for name in ("air_temperature_c", "air_pressure_pa", "humidity_pct")):
                index[k, i, j] = ciddor_n(float(np.mean(q["air_temperature_c"])), float(np.mean(q["air_pressure_pa"])),
                                          float(np.mean(q["humidity_pct"])))
            if "material_temperature_c" in q:
                material[k, i, j] = np.mean(q["material_temperature_c"])
            if "mount_temperature_c" in q:
                mount[k, i, j] = np.mean(q["mount_temperature_c"])
        summary = summarise_conditions(env.values())
        if not np.isfinite(material).any():  # a sensor without a table thermometer
            material = None
        if not np.isfinite(mount).any():  # nor a second probe on the tracer's mount (the usual sensor)
            mount = None
    others = tuple(MountReadings(lengths[k], segments[k], visits[k], None if index is None else index[k], times[k],
                                 None if material is None else material[k], None if mount is None else mount[k])
                   for k in range(1, mounts))
    return MultistationData(pos_sum / pos_count, lengths[0], segments[0], np.asarray(nominal_angles_deg, float),
                            int(np.sum(len_count > 0)), visits[0], pos_count[:, 0], others,
                            None if index is None else index[0], summary, times[0],
                            None if material is None else material[0], None if mount is None else mount[0])
