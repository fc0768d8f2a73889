"""Clocks: simulated runs use a virtual clock so that settle times and motions cost no real time."""

from __future__ import annotations

import time
from typing import Callable, Protocol


class Clock(Protocol):
    def now_s(self) -> float: ...
    def sleep(self, seconds: float) -> None: ...


class VirtualClock:
    """Time that advances only when someone waits: motions and settle times of simulated runs."""

    def __init__(self, start_s: float = 0.0):
        self._t = float(start_s)

    def now_s(self) -> float:
        return self._t

    def sleep(self, seconds: float) -> None:
        if seconds < 0:
            raise ValueError("cannot sleep a negative time")
        self._t += seconds

    def concurrently(self, actions: list[Callable[[], None]]) -> list[BaseException | None]:
        """Run ``actions`` as if they started at the same instant: each sees the clock from now, and the
        clock ends at the latest of their ends. Returns what each raised (None: it finished)."""
        start, ends = self._t, []
        errors: list[BaseException | None] = []
        for action in actions:
            self._t = start
            try:
                action()
                errors.append(None)
            except Exception as exc:  # noqa: BLE001 — handed back to the caller, which decides
                errors.append(exc)
            ends.append(self._t)
        self._t = max(ends, default=start)
        return errors


class RealClock:
    """Wall-clock time since construction, plus ``start_s`` (where a resumed run's clock goes on), for
    runs against hardware."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._t0 = time.monotonic() - float(start_s)

    def now_s(self) -> float:
        return time.monotonic() - self._t0

    def sleep(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))
