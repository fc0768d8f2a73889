"""The conditions beside every reading of any plan: the environment sensor, read just before the
readings it accompanies, never holding them up (an optional step)."""

from __future__ import annotations

from drivers.interfaces import DESCRIPTIONS, EnvironmentSensor
from drivers.kinds import recorded
from rtcal.engine.steps import Read

ENVIRONMENT_FIELDS = tuple(DESCRIPTIONS["environment"])
ENVIRONMENT_QUANTITIES = recorded("environment", *ENVIRONMENT_FIELDS)


def environment_read(what: str) -> Read:
    """The conditions beside a reading (every method): never holds up the reading it accompanies."""
    return Read("environment", ENVIRONMENT_QUANTITIES, _environment_values, None, what, optional=True)


def _environment_values(sensor: EnvironmentSensor) -> list[float]:
    env = sensor.read()
    return [float(getattr(env, name)) for name in ENVIRONMENT_FIELDS]  # NaN: not measured, not stored
