"""Walking a plan without instruments: its duration and reading count from a timing model.

The walker answers each step as an ideal bench would (a reading step's ``nominal``) and counts the
time each takes: a table turning at its speed (through the overshoot where the ISO approach needs
it), the CMM travelling at its speed, settle times, operator steps. This is what the simulated
bench's clock counts too, so the planner, `rtcal plan` and the Monte Carlo's drift draws need no
dry run into a temporary store.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np

from rtcal.engine.plan import Plan
from rtcal.engine.steps import (Move, OperatorStep, Parallel, Read, ReadSamples, Reference, Samples, Settle,
                                Step, Validate)


@dataclass(frozen=True)
class Timing:
    """How fast the machines move (from the bench a procedure runs on, or the lab's own figures)."""

    stage_speed_deg_per_s: float
    cmm_speed_mm_per_s: float = 50.0
    stage_start_deg: float = 0.0
    cmm_start_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    machine_speeds: tuple[float, float] = (50.0, 20.0)  # a machine tool's linear mm/s and rotary deg/s

    @classmethod
    def of_scenario(cls, scenario: Any) -> "Timing":
        m = getattr(scenario, "machine", None)
        speeds = (m.linear_speed_mm_per_s, m.rotary_speed_deg_per_s) if m is not None else (50.0, 20.0)
        return cls(scenario.stage.speed_deg_per_s, scenario.cmm.speed_mm_per_s, machine_speeds=speeds)


@dataclass
class PlanWalk:
    """What walking a plan found: its duration, its planned and instrument readings, its steps by kind."""

    duration_s: float = 0.0
    planned_readings: int = 0
    instrument_readings: int = 0
    motion_s: float = 0.0
    settle_s: float = 0.0
    operator_s: float = 0.0
    steps: dict[str, int] = field(default_factory=dict)
    listing: list[Step] | None = None
    """Every step in order, when the walk was asked to keep them (`walk(..., listing=True)`)."""
    entry_s: dict[int, tuple[float, float]] = field(default_factory=dict)
    """Per plan entry walked: (seconds, of which an operator's stated steps) it adds to the run, the steps
    before it since the last entry (a set-up, a re-seat) and, for the last, the steps after it counted in."""
    entry_motion_s: dict[int, float] = field(default_factory=dict)
    """… and of those seconds the motions' (at the timing's speeds, the walk's guess; settles and samples are
    the procedure's own): the time left fits the two paces apart."""


class Motion:
    """How long each motion takes at the timing's speeds, from where the last one left the machine: the
    walk's clock, and a wired run's on a virtual clock (its simulators move in their own processes)."""

    def __init__(self, timing: Timing):
        self.timing = timing
        self.stage_deg = timing.stage_start_deg
        self.cmm_mm = np.asarray(timing.cmm_start_mm, float)
        self.machine: dict[str, float] = {}

    def _machine_time(self, points: Any) -> float:
        """A machine tool's coordinated move through its points (drivers.interfaces.MachineTarget): each leg as long
        as its slowest axis at the timing's speeds (a tool-centre-point target's linear axes counted as its point's)."""
        seconds = 0.0
        for point in points:
            here = self.machine or {k: 0.0 for k in point}
            lin = max((abs(point[k] - here.get(k, 0.0)) for k in "xyz" if k in point), default=0.0)
            rot = max((abs(point[k] - here.get(k, 0.0)) for k in "abc" if k in point), default=0.0)
            seconds += max(lin / self.timing.machine_speeds[0], rot / self.timing.machine_speeds[1])
            self.machine = dict(point)
        return seconds

    def _stage_time(self, move: Move) -> float:
        """The table's travel: through the overshoot when it would arrive the other way (as
        :func:`rtcal.engine.motion.approach`), at the stage's speed."""
        target = float(move.target)
        legs = []
        if move.direction:
            arriving = 1 if target > self.stage_deg else -1 if target < self.stage_deg else 0
            if arriving != move.direction and move.overshoot_deg > 0:
                legs.append(target - move.direction * move.overshoot_deg)
        legs.append(target)
        travel = 0.0
        for leg in legs:
            travel += abs(leg - self.stage_deg)
            self.stage_deg = leg
        return travel / self.timing.stage_speed_deg_per_s

    def seconds(self, move: Move) -> float:
        if move.instrument == "stage":
            return self._stage_time(move)
        if hasattr(move.target, "points"):
            return self._machine_time(move.target.points())
        target = np.asarray(move.target, float)
        seconds = float(np.linalg.norm(target - self.cmm_mm)) / self.timing.cmm_speed_mm_per_s
        self.cmm_mm = target
        return seconds


class _Walker:
    def __init__(self, timing: Timing):
        self.motion = Motion(timing)
        self.tracking = False
        self.segment = -1
        self.walk = PlanWalk()

    def step(self, step: Step) -> Any:
        w = self.walk
        if w.listing is not None:
            w.listing.append(step)
        kind = type(step).__name__
        w.steps[kind] = w.steps.get(kind, 0) + 1
        if isinstance(step, Move):
            seconds = self.motion.seconds(step)
            w.motion_s += seconds
            w.duration_s += seconds
            return None
        if isinstance(step, Parallel):
            seconds = max(self.motion.seconds(m) for m in step.moves)
            w.motion_s += seconds
            w.duration_s += seconds
            return None
        if isinstance(step, Settle):
            w.settle_s += step.seconds
            w.duration_s += step.seconds
            return None
        if isinstance(step, Read):
            if not step.optional:
                w.instrument_readings += len(step.fields)
            return step.nominal
        if isinstance(step, ReadSamples):
            w.instrument_readings += step.count
            w.duration_s += step.count * step.sample_s
            return Samples((step.nominal,) * step.count, False, self.segment)
        if isinstance(step, Reference):
            referenced, self.tracking = not self.tracking, True
            if referenced:
                self.segment += 1
                w.operator_s += step.seconds
                w.duration_s += step.seconds
            return referenced
        if isinstance(step, OperatorStep):
            w.operator_s += step.seconds
            w.duration_s += step.seconds
            self.tracking = False
            return None
        if isinstance(step, Validate):
            return None
        raise TypeError(f"not a step: {step!r}")

    def drive(self, attempt: Any) -> None:
        answer: Any = None
        while True:
            try:
                step = attempt.send(answer)
            except StopIteration:
                return
            answer = self.step(step)

    def leave(self, plan: Plan, group: int) -> None:
        found = plan.leave_group(group, self.segment if self.tracking else None)
        if found is not None:
            self.drive(found[1])

    def run(self, steps: Iterable[Step]) -> None:
        for step in steps:
            self.step(step)


def walk(plan: Plan, timing: Timing, done: Iterable[int] = (), listing: bool = False) -> PlanWalk:
    """Walk ``plan`` (the entries not in ``done``) as an ideal bench would answer it; ``listing`` keeps every step."""
    done = set(done)
    walker = _Walker(timing)
    if listing:
        walker.walk.listing = []
    walker.run(plan.prologue())
    group: int | None = None
    first = True
    w = walker.walk
    mark = (0.0, 0.0, 0.0)
    last: int | None = None
    for entry in plan.entries:
        if entry.index in done:
            continue
        if entry.group != group:
            if group is not None:
                walker.leave(plan, group)
            walker.run(plan.enter_group(entry, first))
            group, first, walker.tracking = entry.group, False, False
        walker.drive(plan.attempt(entry))
        w.planned_readings += 1
        w.entry_s[entry.index] = (w.duration_s - mark[0], w.operator_s - mark[1])
        w.entry_motion_s[entry.index] = w.motion_s - mark[2]
        mark, last = (w.duration_s, w.operator_s, w.motion_s), entry.index
    if group is not None:
        walker.leave(plan, group)
    if last is not None:  # what follows the last entry is the last entry's to finish
        total, operator = w.entry_s[last]
        w.entry_s[last] = (total + w.duration_s - mark[0], operator + w.operator_s - mark[1])
        w.entry_motion_s[last] += w.motion_s - mark[2]
    return w
