"""Logged readings → solver inputs. Reads the store only; knows nothing of instruments."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rtcal.solvers.abbe import AbbeVisits
from rtcal.store import RunStore


@dataclass(frozen=True)
class MultistationData:
    """Arrays for the seed-000 solvers, from the raw readings."""

    points_mm: np.ndarray  # n×3, CMM-reported, averaged over visits
    lengths_mm: np.ndarray  # n×m, tracer samples averaged; NaN where the reading was skipped
    segments: np.ndarray  # n×m tracking segment of each length (−1 where skipped)
    nominal_angles_deg: np.ndarray  # m
    raw_readings: int  # planned readings present (point, station pairs with a length)


def multistation_data(store: RunStore, nominal_angles_deg: np.ndarray, n_points: int) -> MultistationData:
    m = len(nominal_angles_deg)
    pos_sum = np.zeros((n_points, 3))
    pos_count = np.zeros((n_points, 3))
    for r in store.readings(instrument="cmm"):
        if not r.quantity.startswith("position_"):
            continue
        axis = "xyz".index(r.quantity[len("position_")])
        pos_sum[r.point, axis] += r.value
        pos_count[r.point, axis] += 1
    len_sum = np.zeros((n_points, m))
    len_count = np.zeros((n_points, m))
    segments = np.full((n_points, m), -1)
    for r in store.readings(instrument="laser_tracer", quantity="length_mm"):
        len_sum[r.point, r.station] += r.value
        len_count[r.point, r.station] += 1
        segments[r.point, r.station] = r.segment
    if np.any(pos_count == 0):
        raise ValueError(f"the CMM position of {int(np.sum(pos_count[:, 0] == 0))} points was never read")
    with np.errstate(invalid="ignore", divide="ignore"):
        lengths = np.where(len_count > 0, len_sum / np.maximum(len_count, 1), np.nan)
    return MultistationData(pos_sum / pos_count, lengths, segments,
                            np.asarray(nominal_angles_deg, float), int(np.sum(len_count > 0)))


def _one_attempt_per_visit(readings: list) -> list:
    """The readings of one attempt per planned visit: the last that skipped nothing, else the
    last one (a visit retaken on resume is not averaged with its first, partial, attempt)."""
    attempts: dict[int | None, dict[int | None, list]] = {}
    for r in readings:
        attempts.setdefault(r.plan_index, {}).setdefault(r.attempt, []).append(r)
    chosen = []
    for by_attempt in attempts.values():
        whole = [a for a, rows in by_attempt.items() if all(x.quantity != "skipped" for x in rows)]
        key = (lambda a: -1 if a is None else a)
        chosen += by_attempt[max(whole, key=key)] if whole else by_attempt[max(by_attempt, key=key)]
    return chosen


def abbe_visits(store: RunStore, seatings_deg: list[float]) -> AbbeVisits:
    """One row per stage visit (seating, run, direction, step), samples averaged per instrument."""
    sums: dict[tuple, dict[str, list[float]]] = {}
    commanded: dict[tuple, float] = {}
    for r in _one_attempt_per_visit(list(store.readings())):
        key = (r.seating, r.run, r.direction, r.station)
        commanded[key] = r.commanded_angle_deg
        sums.setdefault(key, {}).setdefault(f"{r.instrument}.{r.quantity}", []).append(r.value)
    keys = list(sums)

    def column(name: str) -> np.ndarray:
        return np.array([np.mean(sums[k][name]) if name in sums[k] else np.nan for k in keys])

    return AbbeVisits(
        commanded_deg=np.array([commanded[k] for k in keys]),
        seating_deg=np.array([seatings_deg[k[0]] for k in keys]),
        seating_index=np.array([k[0] for k in keys]),
        direction=np.array([k[2] for k in keys]),
        encoder_deg=column("encoder.angle_deg"),
        autocollimator_arcsec=column("autocollimator.x_arcsec"),
        indicator1_um=column("dial_indicator_1.y_um"),
        indicator2_um=column("dial_indicator_2.y_um"),
    )
