"""The encoder Abbe-error method's readings as the solvers take them (seed 001): one row per stage
visit, and the conditions of the visits. Reads the store only: what each stored quantity is comes from
the store's descriptions, never from parsing its name."""

from __future__ import annotations

import numpy as np

from rtcal.methods.conditions import summarise_conditions
from rtcal.solvers.abbe import AbbeVisits
from rtcal.store.runstore import MARKERS, Reading, RunStore, stored_quantity as _quantity


def abbe_conditions(store: RunStore) -> dict[str, dict[str, float]] | None:
    """The environment sensor's readings of the visits the analysis uses, summarised."""
    per_visit: dict[tuple[int | None, int | None], dict[str, list[float]]] = {}
    described = store.described()
    for r in _one_attempt_per_visit(list(store.readings())):  # all of a visit's readings: its marks decide
        d = described.get((r.instrument, r.quantity))
        if d is not None and d.kind == "environment" and not d.purpose:
            per_visit.setdefault((r.plan_index, r.attempt), {}).setdefault(d.field, []).append(r.value)
    return summarise_conditions(per_visit.values())


def _one_attempt_per_visit(readings: list[Reading]) -> list[Reading]:
    """The readings of one attempt per planned visit: the last that skipped nothing, else the
    last one (a visit retaken on resume is not averaged with its first, partial, attempt). A
    rejected attempt (its readings contradicted the commands) is never chosen."""
    attempts: dict[int | None, dict[int | None, list[Reading]]] = {}
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
    Key = tuple[int | None, int | None, int | None, int | None]
    sums: dict[Key, dict[str, list[float]]] = {}
    commanded: dict[Key, float | None] = {}
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
        seating_deg=np.array([seatings_deg[k[0] or 0] for k in keys]),  # every visit of this method has its seating
        seating_index=np.array([k[0] for k in keys]),
        direction=np.array([k[2] for k in keys]),
        encoder_deg=column("encoder", "angle_deg"),
        autocollimator_arcsec=column("autocollimator", "x_arcsec"),
        indicator1_um=column("dial_indicator_1", "y_um"),
        indicator2_um=column("dial_indicator_2", "y_um"),
        run=np.array([k[1] for k in keys]),
    )
