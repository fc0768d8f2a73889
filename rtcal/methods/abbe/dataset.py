"""The encoder Abbe-error method's readings as the solvers take them (seed 001): one row per stage
visit, and the conditions of the visits. Reads the store only: what each stored quantity is comes from
the store's descriptions, never from parsing its name."""

from __future__ import annotations

import numpy as np

from rtcal.solvers.abbe import AbbeVisits
from rtcal.api import RunReadings, summarise_conditions


def abbe_conditions(store: RunReadings) -> dict[str, dict[str, float]] | None:
    """The environment sensor's readings of the visits the analysis uses (those that count), summarised."""
    per_visit: dict[tuple[int | None, int | None], dict[str, list[float]]] = {}
    described = store.described()
    for r in store.counted():
        d = described.get((r.instrument, r.quantity))
        if d is not None and d.kind == "environment" and not d.purpose:
            per_visit.setdefault((r.plan_index, r.attempt), {}).setdefault(d.field, []).append(r.value)
    return summarise_conditions(per_visit.values())


def abbe_visits(store: RunReadings, seatings_deg: list[float]) -> AbbeVisits:
    """One row per stage visit (seating, run, direction, step), in the plan's order, samples averaged per
    instrument; only the readings that count (the store's one rule: a visit retaken on resume is not
    averaged with its first, partial, attempt; a rejected one is never used)."""
    Key = tuple[int | None, int | None, int | None, int | None]
    sums: dict[Key, dict[str, list[float]]] = {}
    commanded: dict[Key, float | None] = {}
    in_plan_order = sorted(store.counted(), key=lambda r: -1 if r.plan_index is None else r.plan_index)  # stable
    for r in in_plan_order:
        key = (r.seating, r.run, r.direction, r.station)
        commanded[key] = r.commanded_angle_deg
        sums.setdefault(key, {}).setdefault(f"{r.instrument}.{r.quantity}", []).append(r.value)
    keys = list(sums)

    def column(instrument: str, field: str) -> np.ndarray:
        name = f"{instrument}.{store.quantity_of(instrument, field)}"
        return np.array([np.mean(sums[k][name]) if name in sums[k] else np.nan for k in keys])

    return AbbeVisits(
        commanded_deg=np.array([commanded[k] for k in keys]),
        seating_deg=np.array([seatings_deg[k[0] or 0] for k in keys]),  # every visit of this method has its seating
        seating_index=np.array([k[0] for k in keys]),
        direction=np.array([k[2] for k in keys]),
        encoder_deg=column("encoder", "angle_deg"),
        autocollimator_arcsec=column("autocollimator", "x_arcsec"),
        indicator1_um=column("dial_indicator_1", "y_um"),
        indicator2_um=column("dial_indicator_2", "y_um"),
        run=np.array([k[1] for k in keys]),
    )
