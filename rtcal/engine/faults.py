"""Fault policies: every instrument call the engine makes goes through :class:`FaultHandler`.

A typed instrument error is recorded as a ``fault`` event; the call is retried with doubling
backoff (a drive alarm is reset first; a lost tracker is re-acquired at once when its policy
says so); when the retries are spent the policy's ``then`` decides: skip, pause for the
operator, re-acquire, or abort to a safe state. Every action is an event in the run store.

A fault that outlasts skipping — ``max_skips_in_a_row`` planned readings of one instrument
skipped with no success between (an emergency stop, a beam that stays broken) — stops the run
in a safe state instead of skipping the rest of the plan; `rtcal resume` retakes the skips.
An operator who cannot be reached (no terminal) is a fault too: the run stops safely.
"""

from __future__ import annotations

from typing import Any, Callable, Mapping, Protocol

from drivers.errors import InstrumentError, TrackingLost
from rtcal.clock import Clock
from rtcal.engine.operator import Operator
from rtcal.procedure.models import FaultPolicy
from rtcal.engine.checks import Contradiction, UncommandedMotion

SKIPPED = object()
RETAKE = object()


class Skip:
    """What :meth:`FaultHandler.call` answers when the policy skipped the call: the error that made it."""

    def __init__(self, error: InstrumentError | None):
        self.error = error


class EventSink(Protocol):
    def __call__(self, kind: str, instrument: str | None, message: str) -> None: ...


class RunAborted(InstrumentError):
    """A fault the policy would not ride out: the run stopped in a safe state, readings kept."""

    cause: InstrumentError | None = None


class FaultHandler:
    def __init__(self, policies: Mapping[str, FaultPolicy], events: EventSink, clock: Clock, operator: Operator,
                 safe_state: Callable[[], None]):
        self.policies = policies
        self.events = events
        self.clock = clock
        self.operator = operator
        self.safe_state = safe_state
        self.skips_in_a_row: dict[str, int] = {}

    def event(self, kind: str, instrument: str | None, message: str) -> None:
        self.events(kind, instrument, message)

    def call(self, instrument: str, action: Callable[[], Any], *, recover: Callable[[], None] | None = None,
             reacquire: Callable[[], None] | None = None, what: str = "") -> Any:
        """``action()``'s result, or a :class:`Skip`; raises RunAborted when the policy gives up."""
        policy = self.policies[instrument]
        rounds = 2 if policy.then in ("pause", "reacquire") else 1
        last: InstrumentError | None = None
        for round_ in range(rounds):
            for attempt in range(policy.retries + 1):
                try:
                    result = action()
                except InstrumentError as exc:
                    last = exc
                    self.event("fault", instrument, f"{what}: {exc}" if what else str(exc))
                    if isinstance(exc, UncommandedMotion):  # no retry gives rtcal its machine back
                        self.abort(exc.instrument, exc, "the machine moved while nothing was commanded")
                else:
                    self.skips_in_a_row[instrument] = 0
                    return result
                if attempt == policy.retries:
                    break
                if isinstance(last, TrackingLost) and reacquire is not None and policy.then == "reacquire":
                    self._reacquire(instrument, reacquire, last)
                    continue
                self.clock.sleep(policy.backoff_s * 2**attempt)
                self.event("retry", instrument, f"retry {attempt + 1} of {policy.retries} after {policy.backoff_s * 2**attempt:g} s")
                self._recover(instrument, recover)
            if policy.then == "skip":
                self.event("skip", instrument, f"{what or 'reading'} skipped after {policy.retries + 1} attempts")
                self.skips_in_a_row[instrument] = self.skips_in_a_row.get(instrument, 0) + 1
                if self.skips_in_a_row[instrument] >= policy.max_skips_in_a_row:
                    self.abort(instrument, last, f"{self.skips_in_a_row[instrument]} planned readings skipped in a row: "
                                                 "the fault persists")
                return Skip(last)
            if round_ == 0 and policy.then == "pause":
                self.event("pause", instrument, "waiting for the operator")
                try:
                    self.operator.clear_fault(f"{instrument}: {last}")
                except InstrumentError as exc:  # OperatorUnavailable: no terminal, a simulated operator gone
                    self.event("fault", exc.instrument, str(exc))
                    self.abort(instrument, last, f"no operator could clear it ({exc})")
                # the cause is gone: reset what the machine latched (a drive alarm) and re-reference a lost tracer
                self._recover(instrument, recover)
                if isinstance(last, TrackingLost) and reacquire is not None:
                    self._reacquire(instrument, reacquire, last)
            elif round_ == 0 and policy.then == "reacquire" and reacquire is not None:
                self._reacquire(instrument, reacquire, last)
            else:
                break
        self.abort(instrument, last)

    def rejected(self, exc: Contradiction, tries: int, what: str) -> object:
        """A planned reading whose readings contradict the commands (found once they were taken):
        RETAKE it (the policy's retries, after its backoff), or SKIPPED (skip, pause and reacquire:
        retaken after the pass and on resume), or abort; the policy of the instrument named decides."""
        policy = self.policies[exc.instrument]
        self.event("fault", exc.instrument, f"{what}: {exc}" if what else str(exc))
        if isinstance(exc, UncommandedMotion):  # no retake gives rtcal its machine back
            self.abort(exc.instrument, exc, "the machine moved while nothing was commanded")
        if tries < policy.retries:
            self.clock.sleep(policy.backoff_s * 2**tries)
            self.event("retry", exc.instrument, f"retry {tries + 1} of {policy.retries}: the reading taken again")
            return RETAKE
        if policy.then == "abort":
            self.abort(exc.instrument, exc)
        if policy.then == "pause":
            self.event("pause", exc.instrument, "waiting for the operator")
            try:
                self.operator.clear_fault(f"{exc.instrument}: {exc}")
            except InstrumentError as unreachable:
                self.event("fault", unreachable.instrument, str(unreachable))
                self.abort(exc.instrument, exc, f"no operator could clear it ({unreachable})")
        self.event("skip", exc.instrument, f"{what or 'reading'} rejected after {policy.retries + 1} attempts; taken again later")
        self.skips_in_a_row[exc.instrument] = self.skips_in_a_row.get(exc.instrument, 0) + 1
        if self.skips_in_a_row[exc.instrument] >= policy.max_skips_in_a_row:
            self.abort(exc.instrument, exc, f"{self.skips_in_a_row[exc.instrument]} planned readings rejected in a row: "
                                            "the contradiction persists")
        return SKIPPED

    def _recover(self, instrument: str, recover: Callable[[], None] | None) -> None:
        """Reset what the machine latched (a drive alarm); a failure is a fault event, and the next
        attempt says whether the instrument is back."""
        if recover is None:
            return
        try:
            recover()
        except InstrumentError as exc:
            self.event("fault", instrument, f"recovery failed: {exc}")

    def _reacquire(self, instrument: str, reacquire: Callable[[], None], last: InstrumentError | None) -> None:
        """Re-reference; an instrument that cannot even do that (its line died) stops the run safely."""
        try:
            reacquire()
        except InstrumentError as exc:
            self.event("fault", exc.instrument, f"re-acquiring failed: {exc}")
            self.abort(instrument, exc, "it could not be re-acquired")

    def abort(self, instrument: str, error: InstrumentError | None, why: str = "") -> None:
        because = f" ({why})" if why else ""
        self.event("abort", instrument, f"aborted: {error}{because}; stopping the machines")
        try:
            self.safe_state()
        except InstrumentError as exc:
            self.event("fault", instrument, f"while stopping: {exc}")
        aborted = RunAborted(instrument, f"run aborted after {error}{because}; every reading taken is kept — "
                                        "`rtcal resume` of the run goes on and retakes what was skipped")
        aborted.cause = error
        raise aborted
