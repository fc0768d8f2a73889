"""The conditions beside every reading of any plan: the environment sensor, read just before the
readings it accompanies, never holding them up (an optional step)."""

from __future__ import annotations

from drivers.interfaces import DESCRIPTIONS
from rtcal.engine.steps import Read

ENVIRONMENT_FIELDS = tuple(DESCRIPTIONS["environment"])


def environment_read(what: str) -> Read:
    """The conditions beside a reading (every method): never holds up the reading it accompanies; what the
    sensor does not measure (NaN) is not stored."""
    return Read("environment", ENVIRONMENT_FIELDS, None, None, what, optional=True)
