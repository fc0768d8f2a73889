"""Fault injection: which request of which instrument fails, and how (scenario ``faults``).

One injector per bench. Whatever answers a request — an in-process simulated instrument or a
protocol simulator's handler — asks :meth:`FaultInjector.draw` exactly once per request and
turns the fault into the typed error (in process) or the wire-level fault (over a protocol).
"""

from __future__ import annotations

from collections import defaultdict

from simulators.scenario import FaultSpec

ALARM_CODES = {"stall": 0x30, "following_error": 0x10, "limit_switch": 0x66}


class FaultInjector:
    def __init__(self, faults: list[FaultSpec], rng_for):
        self.faults = list(faults)
        self.requests: dict[str, int] = defaultdict(int)
        self._rng_for = rng_for

    def draw(self, instrument: str) -> FaultSpec | None:
        """Count one request of ``instrument``; return the fault it suffers, if any."""
        self.requests[instrument] += 1
        k = self.requests[instrument]
        for f in self.faults:
            if f.instrument != instrument:
                continue
            if k in f.at_request:
                return f
            if f.probability and self._rng_for(f"faults {instrument}").random() < f.probability:
                return f
        return None
