"""One engine executes any plan: it moves, reads, applies the fault policies, records, pauses and
stops safely. Everything else subscribes to the documents it publishes.

Written once here, for every method:

- **attempts** — each attempt at a planned reading has its own number; its readings are
  committed together (the checkpoint) before the next motion. An attempt whose step was skipped
  is committed with a skip mark and stays pending; one the method's checks contradict is
  committed with a rejected mark and taken again as the policy of the instrument named says;
  one interrupted (a safe stop, Ctrl-C, a remote abort) keeps what it took, marked.
- **the retake pass** — where the plan asks for it, what this start skipped is taken once more
  after the pass and before the run leaves a group (a tracer mount).
- **tracking segments** — a tracking instrument (the laser tracer) is referenced when it has no
  segment; a new group, a lost beam or a pause leaves it without one.
- **pause, resume, abort** — requested from any thread (the control socket, the live view): a
  pause takes effect at the next checkpoint, with the reading in hand committed and the machines
  still; resume approaches anew; abort stops like Ctrl-C, at once: it interrupts the motion or
  reading in progress (:mod:`rtcal.engine.signals`), and an abort acknowledged before the run
  finished measuring never ends in results. Once measuring has finished an abort is refused.
- **confirm** — an operator step (or a fault the operator must clear) waits in the operator object;
  a remote confirm is handed to it when it is :class:`~rtcal.engine.operator.Confirmable`
  (refused with NothingToConfirm when nothing waits), and an abort ends the wait. What the
  operator is asked is published as an ``operator`` document, its answer as a ``confirm`` event.
- **one safe-state path** — however a run ends early (a fault abort, a remote abort, Ctrl-C,
  SIGTERM, SIGHUP, SIGQUIT or any other signal that would end the process, an unexpected error)
  every device the engine moved is sent its stop, then each is watched until its position is
  seen not to change (``wait_stopped``), before the exception goes on to the caller, which
  records the status and closes the connections; a second signal does not cut the stop short.
  Each machine is then a ``stopped`` event (where it was seen at rest) or a ``moving`` event
  (it may still be moving: its last position and why it was not seen still), and the exception
  carries a note naming it. Each abort and interruption is an ``abort`` event naming who asked
  (the live page, `rtcal control`, the signal), which says "every machine the run moved was
  stopped" only when each was seen at rest.

Documents (``subscriber(name, doc)``, called in the engine's thread, in order): ``start``,
``state``, ``attempt``, ``readings``, ``event``, ``operator_step`` (an operator step begins: its stated
``seconds``), ``operator``, ``done``, ``stop``. The store writer, the console
progress and the live view are subscribers (:mod:`rtcal.engine.subscribers`).
"""

from __future__ import annotations

import math
import threading
from functools import partial
from typing import Any, Callable, Collection, Iterable, Mapping, Protocol, Sequence, TypeGuard, runtime_checkable

import numpy as np

from drivers.errors import InstrumentError, InstrumentFault, TrackingLost
from drivers.interfaces import FieldDescription, Instrument, StopSeen, Value
from rtcal.clock import Clock, VirtualClock
from rtcal.engine import signals
from rtcal.engine.walk import Motion, Timing
from rtcal.engine.faults import RETAKE, FaultHandler, RunAborted, Skip
from rtcal.engine.plan import Attempt, Entry, Plan
from rtcal.engine.steps import (Move, OperatorStep, Parallel, Read, ReadSamples, Reference, Samples, Settle, Skipped,
                                Step, Validate)
from rtcal.store.runstore import REJECTED, SKIPPED, Reading, descriptions_of, row_context
from rtcal.engine.checks import Contradiction
from rtcal.engine.motion import Turning, approach
from rtcal.engine.operator import Confirmable, NothingToConfirm

Subscriber = Callable[[str, dict[str, Any]], None]


class Device(Protocol):
    """What the engine asks of every device: reset what it latched (the kinds' interfaces, drivers/interfaces.py)."""

    def recover(self) -> None: ...


@runtime_checkable
class Mover(Device, Protocol):
    """A device the engine moves (a stage, a CMM): it checks targets, moves, stops at once, and says
    whether it was then seen at rest (what the one safe-state path asks of everything moved)."""

    def check_target(self, target: Any, /) -> None: ...

    def move_to(self, target: Any, /) -> None: ...

    def stop(self) -> None: ...

    def wait_stopped(self) -> StopSeen: ...


class Reader(Device, Protocol):
    """A device the engine reads: its described values (every reading goes through ``read_values``)."""

    kind: str

    def describe(self) -> dict[str, FieldDescription]: ...

    def read_values(self, fields: Collection[str] | None = None) -> dict[str, Value]: ...


@runtime_checkable
class Tracker(Reader, Protocol):
    """A tracking instrument (a laser tracer): referenced to start a segment."""

    def reference(self) -> int: ...

STEP_NAMES = ("Validate", "Move", "Parallel", "Settle", "Read", "ReadSamples", "Reference", "OperatorStep")
STATES = ("starting", "running", "paused", "stopping", "finished", "failed", "aborted")


class AbortRequested(KeyboardInterrupt):
    """A remote abort: the run stops as Ctrl-C stops it (safe state, status recorded, resumable);
    ``by`` names who asked (the live page, `rtcal control`)."""

    def __init__(self, by: str = "a remote request", when: str = ""):
        super().__init__(f"aborted by {by}{when}")
        self.by = by


class PlanError(TypeError):
    """A method's plan asks the engine for what it cannot do (a step it does not know, a context with no column
    to go into): the method's mistake, said in one line; the run stops safely as ``failed``, with an event."""


class MeasuringFinished(RuntimeError):
    """An abort after the last reading was stored: nothing moves any more, the results are being
    written; refused (the run ends as it would have)."""


class Engine:
    """Executes plans against ``devices`` (name → driver) on ``clock``; see the module docstring."""

    def __init__(self, devices: Mapping[str, Device], clock: Clock, operator: Any, subscribers: Sequence[Subscriber] = (),
                 new_attempt: Callable[[], int] | None = None, next_segment: int = 0, motion_timing: Timing | None = None,
                 context_columns: Collection[str] = ()):
        self.devices = dict(devices)
        self.context_columns = frozenset(context_columns)  # the method's own context, stored in the readings' `context`
        # a wired run on a virtual clock: its simulators move in their own processes, off this clock; each
        # motion then takes on it the time the walk gives it (at the bench's speeds), as an in-process one does
        self._motion = Motion(motion_timing) if motion_timing is not None and isinstance(clock, VirtualClock) else None
        self.clock = clock
        self.operator = operator
        self.subscribers = list(subscribers)
        self._attempts = new_attempt or _counter()
        self._next_segment = next_segment
        self.segment: int | None = None  # the tracking instrument's current segment; None: reference first
        self.state = "starting"
        self.faults_seen = 0
        self._moved: dict[str, Mover] = {}  # devices this engine has commanded, in order: what a safe stop stops
        self._safe = False
        self.stops: dict[str, StopSeen] = {}  # what the safe stop saw of each machine moved
        self._pause = threading.Event()
        self._abort = threading.Event()
        self._abort_by = ""
        self._requests = threading.Lock()  # an abort is either taken by the run or refused, never lost
        self._measured = False
        self._thread: threading.Thread | None = None  # the one running the plan: what an abort interrupts
        self._wake = threading.Event()
        self._plan: Plan | None = None
        self._faults: FaultHandler | None = None
        self._in_segment: dict[int, list[dict[str, Any]]] = {}  # tracking segment → contexts of the whole attempts in it
        self._tracking: set[str] = set()  # instruments read in tracking segments (ReadSamples)
        readers = {name: d for name, d in self.devices.items() if _describes(d)}
        self._fields = {name: d.describe() for name, d in readers.items()}
        self._described = {name: descriptions_of(name, d.kind, self._fields[name].values()) for name, d in readers.items()}
        if isinstance(operator, Confirmable):
            operator.listen(self._operator_asked)

    # ---- control, from any thread -------------------------------------------------------------
    def request_pause(self) -> None:
        self._pause.set()
        self._wake.set()

    def request_resume(self) -> None:
        self._pause.clear()
        self._wake.set()

    def request_abort(self, by: str = "a remote request") -> None:
        """Stop the run now, as Ctrl-C does: the motion or reading in progress is interrupted (the
        engine's thread is the main thread: every `rtcal run`), else the next step does not begin.
        MeasuringFinished once the last reading is stored."""
        with self._requests:
            if self._measured:
                raise MeasuringFinished("the run has finished measuring: nothing moves, its results are being written")
            first = not self._abort.is_set()
            if first:
                self._abort_by = by
            self._abort.set()
        self._wake.set()
        if isinstance(self.operator, Confirmable):  # an operator step waiting ends now
            self.operator.cancel()
        if first and self._thread is not None:
            signals.interrupt(AbortRequested(by), self._thread)

    def _check_abort(self, when: str = "") -> None:
        """Between steps: an abort requested (and not yet delivered into a blocking call) stops the run here."""
        if self._abort.is_set():
            signals.taken()
            raise AbortRequested(self._abort_by, when)

    def request_confirm(self, step: int | None = None) -> None:
        """Confirm the operator step (or the fault to clear) that waits — only wait ``step`` when given;
        NothingToConfirm if none (or another) waits."""
        if not isinstance(self.operator, Confirmable) or not self.operator.confirm(step):
            which = "no operator step waits now" if step is None else f"operator step {step} does not wait now"
            raise NothingToConfirm(f"nothing to confirm: {which}")

    # ---- documents ----------------------------------------------------------------------------
    def emit(self, name: str, **doc: Any) -> None:
        with signals.held():  # a commit is whole: an interruption waits for it
            for subscriber in self.subscribers:
                subscriber(name, doc)

    def _event(self, kind: str, instrument: str | None, message: str) -> None:
        if kind == "fault":
            self.faults_seen += 1
        self.emit("event", t_s=self.clock.now_s(), kind=kind, instrument=instrument, message=message)

    def _operator_asked(self, instruction: str | None, answer: str) -> None:
        """The operator's wait, in the engine's thread: what is asked (an ``operator`` document), then
        how it was answered (a ``confirm`` event)."""
        self.emit("operator", instruction=instruction, t_s=self.clock.now_s(), step=getattr(self.operator, "step", None))
        if instruction is None and answer:
            self._event("confirm", None, f"the operator confirmed {answer}")

    def _set_state(self, state: str) -> None:
        self.state = state
        self.emit("state", state=state, t_s=self.clock.now_s())

    # ---- the run -------------------------------------------------------------------------------
    def run(self, plan: Plan, done: Iterable[int] = ()) -> int:
        """Take every entry of ``plan`` not in ``done``; returns how many were stored whole.
        Raises RunAborted (a policy gave up), AbortRequested or KeyboardInterrupt after the safe stop."""
        done = set(done)
        self._plan = plan
        self._faults = FaultHandler(dict(plan.policies), self._event, self.clock, self.operator, self._safe_state)
        pending = [e for e in plan.entries if e.index not in done]
        self.emit("start", method=plan.method, planned=len(plan.entries), done=len(done), t_s=self.clock.now_s(),
                  descriptions=[d for rows in self._described.values() for d in rows])
        self._set_state("running")
        with signals.routed():  # a signal that would end the process, or an abort, interrupts what runs now
            try:
                self._thread = threading.current_thread()
                self._check_abort()
                self._check_contexts(plan, pending)
                for step in plan.prologue():
                    self._execute(step, {}, [])
                stored = self._pass(plan, pending, len(done))
                with self._requests:  # the last reading is stored: an abort acknowledged until now is taken
                    self._check_abort(" as the last readings finished")
                    self._measured = True
            except BaseException as exc:
                with signals.held():  # nothing cuts the stop short; what comes meanwhile is raised after it
                    if not self._safe:
                        self._safe_state()
                    moving = self.still_moving()
                    if moving:  # whoever prints the error says it too (the console)
                        exc.__notes__ = [*getattr(exc, "__notes__", []), *(f"WARNING: {m}" for m in moving.values())]
                    stopped = ("; ".join(moving.values()) if moving else "every machine the run moved was stopped" +
                               (f" ({self._where_stopped()})" if self.stops else ""))
                    if isinstance(exc, KeyboardInterrupt):
                        self._event("abort", None, f"{self._why(exc)}: {stopped}; `rtcal resume` goes on")
                    elif not isinstance(exc, RunAborted):  # a policy's abort said why already; anything else says it here
                        self._event("abort", None, f"{_what_stopped(exc)}: {stopped}")
                    self._set_state("failed" if isinstance(exc, RunAborted) or not isinstance(exc, KeyboardInterrupt)
                                    else "aborted")
                    self.emit("stop", state=self.state, reason=str(exc) or type(exc).__name__, t_s=self.clock.now_s())
                raise
            finally:
                self._thread = None
        self.emit("stop", state="measured", reason="", t_s=self.clock.now_s())
        return stored

    def _check_contexts(self, plan: Plan, pending: list[Entry]) -> None:
        """Before anything moves: every entry's context has a column to go into (PlanError naming the first that
        has not)."""
        for entry in pending:
            try:
                row_context(entry.context, self.context_columns)
            except ValueError as exc:
                raise PlanError(f"{plan.method}: planned reading {entry.index}: {exc}") from None

    def still_moving(self) -> dict[str, str]:
        """Each machine the safe stop did not see at rest → a line saying so, with its last position and why."""
        return {name: f"{name} may still be moving" + (f" (last seen at {seen.where})" if seen.where else "")
                + f": {seen.why}; stop it at the machine" for name, seen in self.stops.items() if not seen.still}

    def _where_stopped(self) -> str:
        return ", ".join(f"{name} seen at rest at {seen.where}" for name, seen in self.stops.items())

    def _why(self, exc: KeyboardInterrupt) -> str:
        """Who ended the run: the remote abort's sender, the signal, or Ctrl-C."""
        if isinstance(exc, (AbortRequested, signals.Interrupted)):
            return str(exc)
        if self._abort.is_set():  # the operator's wait ended by the abort
            return f"aborted by {self._abort_by}"
        return "interrupted by SIGINT (Ctrl-C)"

    def _pass(self, plan: Plan, pending: list[Entry], done_count: int) -> int:
        stored, skipped = 0, []  # type: tuple[int, list[Entry]]
        group: int | None = None
        first = True
        for entry in pending:
            if entry.group != group:
                if plan.retake_skipped and skipped:  # before the set-up they were planned on changes
                    stored += self._retake(skipped, done_count + stored)
                if group is not None:
                    self._leave(plan, group)
                for step in plan.enter_group(entry, first):
                    self._execute(step, {}, [])
                group, first, self.segment = entry.group, False, None  # a new set-up: reference anew
            if self._take(entry, done_count + stored):
                stored += 1
            else:
                skipped.append(entry)
            self._checkpoint()
        if plan.retake_skipped:
            stored += self._retake(skipped, done_count + stored)
        if group is not None:
            self._leave(plan, group)
        return stored

    def _leave(self, plan: Plan, group: int) -> None:
        """The plan's check before leaving a group (see :meth:`Plan.leave_group`)."""
        found = plan.leave_group(group, self.segment)
        if found is None:
            return
        context, steps = row_context(found[0], self.context_columns), found[1]
        readings: list[Reading] = []
        answer: Any = None
        try:
            while True:
                try:
                    step = steps.send(answer)
                except StopIteration:
                    break
                answer = self._unchecked(step, context, readings)
        except Contradiction as exc:
            self._commit(readings)
            segment = self.segment
            condemned = self._in_segment.pop(segment, []) if segment is not None else []
            self._commit([Reading(self.clock.now_s(), exc.instrument, REJECTED, 0.0, "", **c) for c in condemned])
            assert self._faults is not None
            self._faults.abort(exc.instrument, exc, "every reading of the segment is marked rejected: a resume takes them again")
        except InstrumentError as exc:
            self._commit(readings)
            self._event("check", exc.instrument, f"the check before leaving was not made: {exc}")
            return
        self._commit(readings)

    def _unchecked(self, step: Step, context: dict[str, Any], readings: list[Reading]) -> Any:
        """A step of a check outside the policies: motions and readings as they come."""
        if isinstance(step, Move):
            self._move(step)
            return None
        if isinstance(step, Settle):
            self.clock.sleep(step.seconds)
            return None
        if isinstance(step, ReadSamples):
            ((quantity, unit),) = self._recorded(step.instrument, (step.field,), step.purpose)
            values = []
            for n in range(step.count):
                values.append(self._values(step.instrument, (step.field,)))
                self._spend(step.sample_s)
                readings.append(Reading(self.clock.now_s(), step.instrument, quantity, values[-1], unit, sample=n,
                                        segment=self.segment, **context))
            return Samples(tuple(values), False, self.segment)
        raise PlanError(f"{type(step).__name__} is not a step a check before leaving a group may take (Move, Settle, "
                        "ReadSamples)")

    def _retake(self, skipped: list[Entry], done_count: int) -> int:
        """Once more, now that the fault may have passed."""
        stored = 0
        for entry in list(skipped):
            stored += self._take(entry, done_count + stored)
            self._checkpoint()
        skipped.clear()
        return stored

    def _checkpoint(self) -> None:
        """Between attempts: honour a pause (machines still, state `paused`) or an abort."""
        self._check_abort()
        if not self._pause.is_set():
            return
        self._set_state("paused")
        self._event("pause", None, "paused by a remote request: the machines hold still")
        while self._pause.is_set() and not self._abort.is_set():
            self._wake.wait(0.2)
            self._wake.clear()
        self._check_abort(" while paused")
        self._event("resume", None, "resumed by a remote request: the next reading approaches its targets anew")
        assert self._plan is not None
        self._plan.positions_unknown()
        self._set_state("running")

    def _take(self, entry: Entry, done_count: int) -> bool:
        """Attempts at ``entry`` until one is stored whole (True), or the policy skips it (False)."""
        assert self._plan is not None and self._faults is not None
        tries = 0
        while True:
            context = row_context({**entry.context, "attempt": self._attempts()}, self.context_columns)
            self.emit("attempt", index=entry.index, label=dict(entry.label), attempt=context["attempt"], t_s=self.clock.now_s())
            readings: list[Reading] = []
            try:
                whole = self._drive(self._plan.attempt(entry), context, readings)
            except Contradiction as exc:  # kept, marked, never used; the policy of the instrument named decides
                self._commit(readings + [Reading(self.clock.now_s(), exc.instrument, REJECTED, 0.0, "", **context)])
                if self._faults.rejected(exc, tries, entry.what) is not RETAKE:
                    self._done(entry, False, done_count)
                    return False
                tries += 1
                continue
            except RunAborted as exc:  # a safe stop keeps what the attempt took, marked by the instrument that stopped it
                marker = REJECTED if isinstance(exc.cause, Contradiction) else SKIPPED
                self._commit(readings + [Reading(self.clock.now_s(), exc.instrument, marker, 0.0, "", **context)])
                raise
            except BaseException:  # Ctrl-C, a remote abort mid-attempt, an unexpected error: keep what it took
                if readings:
                    self._safe_commit(readings + [Reading(self.clock.now_s(), "run", SKIPPED, 0.0, "", **context)])
                raise
            self._commit(readings)
            if whole:
                for segment in {r.segment for r in readings if r.segment is not None and r.instrument in self._tracking}:
                    self._in_segment.setdefault(segment, []).append(context)
            self._done(entry, whole, done_count)
            return whole

    def _done(self, entry: Entry, whole: bool, done_count: int) -> None:
        self.emit("done", index=entry.index, whole=whole, done=done_count + (1 if whole else 0), label=dict(entry.label),
                  faults=self.faults_seen, t_s=self.clock.now_s())

    def _commit(self, readings: list[Reading]) -> None:
        if readings:
            self.emit("readings", readings=readings)

    def _safe_commit(self, readings: list[Reading]) -> None:
        try:
            self._commit(readings)
        except Exception:  # the store itself failed: the error that stopped the run is the one to report
            pass

    def _drive(self, attempt: Attempt, context: dict[str, Any], readings: list[Reading]) -> bool:
        """Run one attempt's steps; True if it took everything (no skip mark)."""
        answer: Any = None
        thrown: BaseException | None = None
        while True:
            try:
                step = attempt.throw(thrown) if thrown is not None else attempt.send(answer)
            except StopIteration:
                break
            except Skipped:
                return False
            if self._abort.is_set():
                attempt.close()
                self._check_abort()
            answer, thrown = None, None
            try:
                answer = self._execute(step, context, readings)
            except (Skipped, Contradiction) as exc:  # the plan hears it (where its machines are is then unknown)
                thrown = exc
        return all(r.quantity != SKIPPED for r in readings)

    # ---- steps ---------------------------------------------------------------------------------
    def _mover(self, name: str) -> Mover:
        """The device ``name`` as a step that moves it needs it (a plan that asks a device for what it cannot
        do is a programming error, said before anything happens to it)."""
        device = self.devices[name]
        if not isinstance(device, Mover):
            raise TypeError(_not_a(name, device, "moved (check_target, move_to, stop)"))
        return device

    def _reader(self, name: str) -> Reader:
        device = self.devices[name]
        if not _describes(device):
            raise TypeError(_not_a(name, device, "read (describe, read_values)"))
        return device

    def _tracker(self, name: str) -> Tracker:
        device = self.devices[name]
        if not isinstance(device, Tracker):
            raise TypeError(_not_a(name, device, "referenced (reference)"))
        return device

    def _execute(self, step: Step, context: dict[str, Any], readings: list[Reading]) -> Any:
        if isinstance(step, Validate):
            for target in step.targets:
                self._mover(step.instrument).check_target(target)
            return None
        if isinstance(step, Settle):
            self.clock.sleep(step.seconds)
            return None
        if isinstance(step, Move):
            return self._policy(step.instrument, lambda: self._move(step), step.what, context, readings,
                                recover=self.devices[step.instrument].recover)
        if isinstance(step, Parallel):
            return self._parallel(step, context, readings)
        if isinstance(step, Read):
            return self._read(step, context, readings)
        if isinstance(step, ReadSamples):
            return self._samples(step, context, readings)
        if isinstance(step, Reference):
            if self.segment is not None:
                return False
            self._policy(step.instrument, lambda: self._reference(step.instrument, step.where, step.why, step.seconds),
                         step.why, context, readings)
            return True
        if isinstance(step, OperatorStep):  # logged once done ("polygon seated at …"), not when asked
            self.emit("operator_step", seconds=step.seconds, t_s=self.clock.now_s())  # the time left stops counting it
            self.operator.perform(step)
            self._event("operator", step.instrument, step.message)
            self._spend(step.seconds)
            return None
        raise PlanError(f"{type(step).__name__} is not a step the engine knows ({', '.join(STEP_NAMES)}): a plan yields "
                        "only these (rtcal.api)")

    def _policy(self, instrument: str, action: Callable[[], Any], what: str, context: dict[str, Any],
                readings: list[Reading], recover: Callable[[], None] | None = None,
                reacquire: Callable[[], None] | None = None, optional: bool = False, sample: int | None = None) -> Any:
        """``action()`` under the instrument's policy; a skip is marked in the attempt and thrown into the plan."""
        assert self._faults is not None
        result = self._faults.call(instrument, action, recover=recover, reacquire=reacquire, what=what)
        if isinstance(result, Skip):
            if isinstance(result.error, TrackingLost):
                self.segment = None  # the count is lost: the next reading references the tracer first
            if optional:
                return None
            readings.append(Reading(self.clock.now_s(), instrument, SKIPPED, 0.0, "", sample=sample, **context))
            raise Skipped(instrument, result.error)
        return result

    def _move(self, step: Move) -> None:
        device = self._moved.get(step.instrument)
        if device is None:  # registered before it is commanded: a stop mid-motion stops it too
            device = self._moved[step.instrument] = self._mover(step.instrument)
        start_s = self.clock.now_s()
        if step.direction:
            if not isinstance(device, Turning):
                raise TypeError(_not_a(step.instrument, device, "approached from one side (position_deg)"))
            approach(device, float(step.target), step.direction, step.overshoot_deg)
        else:
            device.move_to(step.target)
        if self._motion is not None:
            rest_s = self._motion.seconds(step) - (self.clock.now_s() - start_s)
            if rest_s > 0:
                self.clock.sleep(rest_s)

    def _parallel(self, step: Parallel, context: dict[str, Any], readings: list[Reading]) -> None:
        """Start the motions together; each that faulted is then ridden out under its own policy."""
        failed: list[Move] = []
        if isinstance(self.clock, VirtualClock):  # simulated: each motion from the same instant, the clock at the last to end
            outcomes = self.clock.concurrently([partial(self._move, move) for move in step.moves])
            for move, error in zip(step.moves, outcomes):
                if isinstance(error, InstrumentError):
                    failed.append(move)
                elif error is not None:
                    raise error
        else:
            errors: dict[int, BaseException] = {}

            def run(k: int, move: Move) -> None:
                try:
                    self._move(move)
                except BaseException as exc:  # re-raised below, in the engine's thread
                    errors[k] = exc

            threads = [threading.Thread(target=run, args=(k, m), daemon=True) for k, m in enumerate(step.moves)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            for k, exc in sorted(errors.items()):
                if not isinstance(exc, InstrumentError):
                    raise exc
                failed.append(step.moves[k])
        for move in failed:  # the fault is recorded and retried as a motion of its own
            self._execute(move, context, readings)

    def _recorded(self, instrument: str, fields: Sequence[str], purpose: str) -> list[tuple[str, str]]:
        """(quantity, unit) each field is stored as: what the instrument's description says (a plan names
        fields, never a quantity or a unit)."""
        described = self._fields.get(instrument)
        if described is None:
            raise TypeError(f"{instrument}: it does not describe its readings (describe(), read_values())")
        unknown = [f for f in fields if f not in described]
        if unknown:
            raise TypeError(f"{instrument}: {unknown} is not in its description {sorted(described)}")
        return [(described[f].quantity(purpose), described[f].unit) for f in fields]

    def _values(self, instrument: str, fields: tuple[str, ...], optional: bool = False) -> Any:
        """One reading of ``fields`` through the instrument's ``read_values``: a number, or a tuple in field
        order. A value the instrument reports as not measured (NaN) is a fault of a reading the plan needs."""
        read = self._reader(instrument).read_values(fields)
        values = tuple(read[f].value for f in fields)
        missing = [f for f, v in zip(fields, values) if math.isnan(v)]
        if missing and not optional:
            raise InstrumentFault(instrument, f"{', '.join(missing)} not measured (the instrument reports it invalid)")
        return values[0] if len(values) == 1 else values

    def _read(self, step: Read, context: dict[str, Any], readings: list[Reading]) -> Any:
        if step.instrument not in self.devices:
            return None
        recorded = self._recorded(step.instrument, step.fields, step.purpose)
        value = self._policy(step.instrument, lambda: self._values(step.instrument, step.fields, step.optional), step.what, context,
                             readings, optional=step.optional, sample=step.sample)
        if value is None:
            return None
        t = self.clock.now_s()
        readings.extend(Reading(t, step.instrument, q, v, unit, sample=step.sample, **context)
                        for (q, unit), v in zip(recorded, _as_values(value, len(recorded))) if math.isfinite(v))
        # every reading is kept as taken; one its relation contradicts rejects the attempt (thrown into the plan)
        return value if step.check is None else step.check(value)

    def _samples(self, step: ReadSamples, context: dict[str, Any], readings: list[Reading]) -> Samples:
        ((quantity, unit),) = self._recorded(step.instrument, (step.field,), step.purpose)
        self._tracking.add(step.instrument)
        reacquired = [False]

        def reacquire() -> None:
            self._reference(step.instrument, step.where, "reacquire", step.reference_s)
            reacquired[0] = True

        taken: list[Reading] = []
        any_reacquired = False
        while len(taken) < step.count:
            value = self._policy(step.instrument, lambda: self._values(step.instrument, (step.field,)), step.what,
                                 context, readings, reacquire=reacquire)
            self._spend(step.sample_s)
            if reacquired[0]:  # a reading never mixes two tracking segments
                taken, reacquired[0], any_reacquired = [], False, True
            taken.append(Reading(self.clock.now_s(), step.instrument, quantity, float(value), unit,
                                 sample=len(taken), segment=self.segment, **context))
        readings.extend(taken)
        return Samples(tuple(r.value for r in taken), any_reacquired, self.segment)

    def _spend(self, seconds: float) -> None:
        """Time a step takes beyond the devices' own (an operator, a tracer's integration): a simulated run's
        clock counts it as the walker does; on hardware it passes by itself."""
        if seconds > 0 and isinstance(self.clock, VirtualClock):
            self.clock.sleep(seconds)

    def _reference(self, instrument: str, where: str, why: str, seconds: float = 0.0) -> None:
        self._tracker(instrument).reference()
        self._spend(seconds)
        self.segment, self._next_segment = self._next_segment, self._next_segment + 1
        self._event(why, instrument, f"tracking segment {self.segment} referenced at {where}")

    def _safe_state(self) -> None:
        """Stop every device this engine moved — every stop sent first, then each machine watched
        until seen at rest (``stops``); a device that cannot be stopped is an event, and the others
        are still stopped. Each machine is then a ``stopped`` or a ``moving`` event."""
        self._safe = True
        with signals.held():  # a second signal, or an abort, does not cut the stop short
            failed: list[tuple[str, Exception]] = []
            for name, device in self._moved.items():  # first the machines, then the records
                try:
                    device.stop()
                except Exception as exc:  # noqa: BLE001 — a half-dead transport must not keep the others moving
                    failed.append((name, exc))
            try:
                self._set_state("stopping")  # (the page shows it while the machines are watched)
            except Exception:  # the store is gone too: the machines are watched all the same
                pass
            for name, device in self._moved.items():
                try:
                    self.stops[name] = device.wait_stopped()
                except Exception as exc:  # noqa: BLE001 — not seen at rest, whatever the reason
                    self.stops[name] = StopSeen(False, "", f"it could not be watched ({exc})")
            try:
                for name, error in failed:
                    self._event("fault", name, f"while stopping: {error}")
                for name, seen in self.stops.items():
                    if seen.still:
                        self._event("stopped", name, f"stopped: seen at rest at {seen.where}")
                for name, line in self.still_moving().items():
                    self._event("moving", name, line)
            except Exception:  # the store is gone too: nothing more to record
                pass


def _what_stopped(exc: BaseException) -> str:
    """An error that ended a run, in one line: a plan's mistake as it says it, anything else with its type."""
    if isinstance(exc, PlanError):
        return f"the method's plan: {exc}"
    return f"{type(exc).__name__}: {str(exc)[:300]}"


def _not_a(name: str, device: Device, what: str) -> str:
    return f"{name}: a {type(device).__name__} cannot be {what}, as the plan's step asks"


def _describes(device: Device) -> TypeGuard[Reader]:
    """A device that describes its readings (every rtcal instrument; a test's scripted stand-in may not)."""
    return isinstance(device, Instrument) and bool(device.kind)


def _as_values(value: Any, n: int) -> list[float]:
    if n == 1 and np.ndim(value) == 0:
        return [float(value)]
    return [float(v) for v in value]


def _counter() -> Callable[[], int]:
    n = [0]

    def next_value() -> int:
        n[0] += 1
        return n[0] - 1

    return next_value

