"""The conditions beside every reading of any plan: the environment sensor, read just before the
readings it accompanies, never holding them up (an optional step)."""

from __future__ import annotations

from typing import Iterable

import numpy as np

from drivers.interfaces import DESCRIPTIONS
from rtcal.engine.steps import Read

ENVIRONMENT_FIELDS = tuple(DESCRIPTIONS["environment"])


def environment_read(what: str) -> Read:
    """The conditions beside a reading (every method): never holds up the reading it accompanies; what the
    sensor does not measure (NaN) is not stored."""
    return Read("environment", ENVIRONMENT_FIELDS, None, None, what, optional=True)


CONDITIONS = ("air_temperature_c", "air_pressure_pa", "humidity_pct", "material_temperature_c", "mount_temperature_c")


def summarise_conditions(groups: Iterable[dict[str, list[float]]]) -> dict[str, dict[str, float]] | None:
    """min, max and mean of each condition over the readings (None: nothing recorded)."""
    groups = list(groups)
    summary = {name: {"min": round(float(np.min(v)), 4), "max": round(float(np.max(v)), 4), "mean": round(float(np.mean(v)), 4)}
               for name in CONDITIONS if (v := [x for q in groups for x in q.get(name, [])])}
    return summary or None
