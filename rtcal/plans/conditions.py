"""The conditions beside every reading of any plan: the environment sensor, read just before the
readings it accompanies, never holding them up (an optional step)."""

from __future__ import annotations

from drivers.interfaces import EnvironmentSensor
from rtcal.engine.steps import Read

ENVIRONMENT_QUANTITIES = (("air_temperature_c", "degC"), ("air_pressure_pa", "Pa"), ("humidity_pct", "%"),
                          ("material_temperature_c", "degC"))


def environment_read(what: str) -> Read:
    """The conditions beside a reading (every method): never holds up the reading it accompanies."""
    return Read("environment", ENVIRONMENT_QUANTITIES, _environment_values, None, what, optional=True)


def _environment_values(sensor: EnvironmentSensor) -> list[float]:
    env = sensor.read()
    return [float(getattr(env, q)) for q, _ in ENVIRONMENT_QUANTITIES]  # NaN: not measured, not stored
