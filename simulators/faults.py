"""Fault injection: which request of which instrument fails, and how (scenario ``faults``).

One injector per bench. Whatever answers a request — an in-process simulated instrument or a
protocol simulator's handler — asks :meth:`FaultInjector.draw` exactly once per request and
turns the fault into the typed error (in process) or the wire-level fault (over a protocol).
"""

from __future__ import annotations

from collections import defaultdict

from simulators.scenario import POSITION_READ_KINDS, FaultSpec

ALARM_CODES = {"stall": 0x30, "following_error": 0x10, "limit_switch": 0x66}


class FaultInjector:
    def __init__(self, faults: list[FaultSpec], rng_for):
        self.faults = list(faults)
        self.requests: dict[str, int] = defaultdict(int)
        self._rng_for = rng_for

    def draw(self, instrument: str, position_read: bool = False) -> FaultSpec | None:
        """Count one request of ``instrument``; return the fault it suffers, if any.

        Position reads (``position_read``) are counted on their own and suffer only the faults of
        another client moving the instrument, so adding a check of the position leaves every other
        fault schedule as it was."""
        key = f"{instrument} position" if position_read else instrument
        self.requests[key] += 1
        k = self.requests[key]
        for f in self.faults:
            if f.instrument != instrument or (f.kind in POSITION_READ_KINDS) != position_read:
                continue
            if k in f.at_request:
                return f
            if f.probability and self._rng_for(f"faults {key}").random() < f.probability:
                return f
        return None
