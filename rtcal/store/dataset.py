"""Logged readings → solver inputs. Reads the store only: what each stored quantity is (its field,
its purpose) comes from the store's descriptions, never from parsing its name."""

from __future__ import annotations

from typing import Iterable

import numpy as np

from rtcal.solvers.air import ciddor_n
from rtcal.solvers.abbe import AbbeVisits
from rtcal.solvers.station_data import MountReadings, MultistationData
from rtcal.store.runstore import MARKERS, SKIPPED, RunStore, StoredDescription


def _quantity(described: dict[tuple[str, str], StoredDescription], instrument: str, field: str, purpose: str = "") -> str:
    """The quantity ``instrument``'s ``field`` read for ``purpose`` is stored under."""
    for d in described.values():
        if d.instrument == instrument and d.field == field and d.purpose == purpose:
            return d.quantity
    raise KeyError(f"{instrument}.{field} ({purpose or 'reading'}) is not described in the store")


def multistation_data(store: RunStore, nominal_angles_deg: np.ndarray, n_points: int, mounts: int = 1) -> MultistationData:
    """Lengths per point and station (samples averaged), per tracer mount (the readings' seating),
    with their tracking segments and stage visits; CMM positions averaged over every visit. The
    readings of a rejected attempt (they contradicted the commands) are kept in the store and used
    nowhere; lengths count only from an attempt that was stored whole."""
    m = len(nominal_angles_deg)
    described = store.described()
    rejected = store.rejected_attempts()
    unfinished = rejected | {(r.plan_index, r.attempt) for r in store.readings(quantity=SKIPPED)}
    pos_sum = np.zeros((n_points, 3))
    pos_count = np.zeros((n_points, 3))
    axes = {_quantity(described, "cmm", f"position_{a}_mm"): k for k, a in enumerate("xyz")}  # a position read on arrival
    for r in store.readings(instrument="cmm"):
        if r.quantity not in axes or (r.plan_index, r.attempt) in rejected:
            continue
        axis = axes[r.quantity]
        pos_sum[r.point, axis] += r.value
        pos_count[r.point, axis] += 1
    env: dict[tuple[int, int, int], dict[str, list[float]]] = {}
    for r in store.readings(instrument="environment"):
        if r.point is None or r.station is None:  # not taken at a length: no length's air
            continue
        d = described.get((r.instrument, r.quantity))
        if d is not None and not d.purpose and (r.plan_index, r.attempt) not in rejected:
            env.setdefault((r.seating or 0, r.point, r.station), {}).setdefault(d.field, []).append(r.value)
    len_sum = np.zeros((mounts, n_points, m))
    len_count = np.zeros((mounts, n_points, m))
    time_sum = np.zeros((mounts, n_points, m))
    segments = np.full((mounts, n_points, m), -1)
    visits = np.full((mounts, n_points, m), -1)
    visit, last = -1, None
    for r in store.readings(instrument="laser_tracer", quantity=_quantity(described, "laser_tracer", "length_mm")):
        if (r.plan_index, r.attempt) in unfinished:
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
    index = summary = material = None
    if env:
        index = np.full((mounts, n_points, m), np.nan)
        material = np.full((mounts, n_points, m), np.nan)
        for (k, i, j), q in env.items():
            if all(name in q for name in ("air_temperature_c", "air_pressure_pa", "humidity_pct")):
                index[k, i, j] = ciddor_n(float(np.mean(q["air_temperature_c"])), float(np.mean(q["air_pressure_pa"])),
                                          float(np.mean(q["humidity_pct"])))
            if "material_temperature_c" in q:
                material[k, i, j] = np.mean(q["material_temperature_c"])
        summary = summarise_conditions(env.values())
        if not np.isfinite(material).any():  # a sensor without a table thermometer
            material = None
    others = tuple(MountReadings(lengths[k], segments[k], visits[k], None if index is None else index[k], times[k],
                                 None if material is None else material[k])
                   for k in range(1, mounts))
    return MultistationData(pos_sum / pos_count, lengths[0], segments[0], np.asarray(nominal_angles_deg, float),
                            int(np.sum(len_count > 0)), visits[0], pos_count[:, 0], others,
                            None if index is None else index[0], summary, times[0],
                            None if material is None else material[0])


CONDITIONS = ("air_temperature_c", "air_pressure_pa", "humidity_pct", "material_temperature_c")


def summarise_conditions(groups: Iterable[dict[str, list[float]]]) -> dict[str, dict[str, float]] | None:
    """min, max and mean of each condition over the readings (None: nothing recorded)."""
    groups = list(groups)
    summary = {name: {"min": round(float(np.min(v)), 4), "max": round(float(np.max(v)), 4), "mean": round(float(np.mean(v)), 4)}
               for name in CONDITIONS if (v := [x for q in groups for x in q.get(name, [])])}
    return summary or None


def abbe_conditions(store: RunStore) -> dict[str, dict[str, float]] | None:
    """The environment sensor's readings of the visits the analysis uses, summarised."""
    per_visit: dict[tuple, dict[str, list[float]]] = {}
    described = store.described()
    for r in _one_attempt_per_visit(list(store.readings())):  # all of a visit's readings: its marks decide
        d = described.get((r.instrument, r.quantity))
        if d is not None and d.kind == "environment" and not d.purpose:
            per_visit.setdefault((r.plan_index, r.attempt), {}).setdefault(d.field, []).append(r.value)
    return summarise_conditions(per_visit.values())


def _one_attempt_per_visit(readings: list) -> list:
    """The readings of one attempt per planned visit: the last that skipped nothing, else the
    last one (a visit retaken on resume is not averaged with its first, partial, attempt). A
    rejected attempt (its readings contradicted the commands) is never chosen."""
    attempts: dict[int | None, dict[int | None, list]] = {}
    for r in readings:
        attempts.setdefault(r.plan_index, {}).setdefault(r.attempt, []).append(r)
    chosen = []
    for by_attempt in attempts.values():
        by_attempt = {a: rows for a, rows in by_attempt.items() if all(x.quantity != "rejected" for x in rows)}
        if not by_attempt:
            continue
        whole = [a for a, rows in by_attempt.items() if all(x.quantity not in MARKERS for x in rows)]
        key = (lambda a: -1 if a is None else a)
        chosen += by_attempt[max(whole, key=key)] if whole else by_attempt[max(by_attempt, key=key)]
    return chosen


def abbe_visits(store: RunStore, seatings_deg: list[float]) -> AbbeVisits:
    """One row per stage visit (seating, run, direction, step), samples averaged per instrument."""
    sums: dict[tuple, dict[str, list[float]]] = {}
    commanded: dict[tuple, float] = {}
    described = store.described()
    for r in _one_attempt_per_visit(list(store.readings())):
        key = (r.seating, r.run, r.direction, r.station)
        commanded[key] = r.commanded_angle_deg
        sums.setdefault(key, {}).setdefault(f"{r.instrument}.{r.quantity}", []).append(r.value)
    keys = list(sums)

    def column(instrument: str, field: str) -> np.ndarray:
        name = f"{instrument}.{_quantity(described, instrument, field)}"
        return np.array([np.mean(sums[k][name]) if name in sums[k] else np.nan for k in keys])

    return AbbeVisits(
        commanded_deg=np.array([commanded[k] for k in keys]),
        seating_deg=np.array([seatings_deg[k[0]] for k in keys]),
        seating_index=np.array([k[0] for k in keys]),
        direction=np.array([k[2] for k in keys]),
        encoder_deg=column("encoder", "angle_deg"),
        autocollimator_arcsec=column("autocollimator", "x_arcsec"),
        indicator1_um=column("dial_indicator_1", "y_um"),
        indicator2_um=column("dial_indicator_2", "y_um"),
        run=np.array([k[1] for k in keys]),
    )
