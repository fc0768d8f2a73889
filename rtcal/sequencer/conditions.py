"""The conditions during the measurement: the environment sensor, read with every reading or
visit of any method, its values stored beside the readings they belong to."""

from __future__ import annotations

import math

from drivers.interfaces import EnvironmentSensor
from rtcal.clock import Clock
from rtcal.run.store import Reading
from rtcal.sequencer.faults import SKIPPED, FaultHandler

ENVIRONMENT_QUANTITIES = (("air_temperature_c", "degC"), ("air_pressure_pa", "Pa"), ("humidity_pct", "%"),
                          ("material_temperature_c", "degC"))


def read_environment(sensor: EnvironmentSensor | None, faults: FaultHandler, clock: Clock, state: dict,
                     what: str) -> list[Reading]:
    """The sensor's readings as stored rows (none without a sensor, or when its policy skipped
    it: a missing condition never holds up the reading it accompanies)."""
    if sensor is None:
        return []
    env = faults.call("environment", sensor.read, what=what)
    if env is SKIPPED:
        return []
    t = clock.now_s()
    return [Reading(t, "environment", q, float(getattr(env, q)), unit, **state)
            for q, unit in ENVIRONMENT_QUANTITIES if math.isfinite(getattr(env, q))]  # NaN: not measured
