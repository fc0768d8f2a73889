"""What the engine needs of a plan: its planned readings in order and, for each, the steps of one attempt.

A method (:mod:`rtcal.methods`) turns its procedure and what the store already holds into a
:class:`Plan`. The engine walks :attr:`Plan.entries` (skipping those already stored), enters each
entry's ``group`` (a polygon seating, a tracer mount: an operator's set-up) when it changes, and
runs :meth:`Plan.attempt` for each pending entry until it is stored whole, rejected or skipped.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Generator, Iterable, Mapping, Protocol

from rtcal.engine.steps import Step
from rtcal.procedure.models import FaultPolicy

Attempt = Generator[Step, Any, None]


@dataclass(frozen=True)
class Entry:
    """One planned reading. ``context`` lands in the store's columns of every reading the attempt takes
    (plan_index included); ``label`` says where the run is, for people (progress, live view)."""

    index: int
    group: int
    context: Mapping[str, Any]
    label: Mapping[str, Any] = field(default_factory=dict)
    what: str = ""


class Plan(Protocol):
    @property
    def method(self) -> str: ...

    @property
    def entries(self) -> list[Entry]: ...

    @property
    def policies(self) -> Mapping[str, FaultPolicy]: ...

    @property
    def retake_skipped(self) -> bool:
        """After the pass (and before the group changes), take once more what this start skipped."""
        ...

    def prologue(self) -> Iterable[Step]:
        """Steps before any motion (every target checked against the device's limits)."""
        ...

    def enter_group(self, entry: Entry, first: bool) -> Iterable[Step]:
        """The operator's steps when the run reaches ``entry.group`` (``first``: the first group of this start)."""
        ...

    def attempt(self, entry: Entry) -> Attempt:
        """The steps of one attempt at ``entry``; raises Contradiction where the method's checks fail."""
        ...

    def leave_group(self, group: int, segment: int | None) -> "tuple[Mapping[str, Any], Attempt] | None":
        """A check before the run leaves ``group`` and at the end of the pass (the tracer measured again
        where its tracking ``segment`` was referenced), as the store columns of its readings and its
        steps; None: nothing to check. Its steps run outside the fault policies: an instrument error
        leaves the check undone (an event says so); a Contradiction condemns the tracking segment —
        every attempt stored in it is marked rejected and the run stops safely."""
        ...

    def positions_unknown(self) -> None:
        """The machines may have moved (a pause, an operator): the next attempt approaches anew."""
        ...


class PlanBase:
    """What a plan says when it has nothing to say: no check before anything moves beyond what the subclass
    yields, no operator's set-up between groups, nothing to forget when the machines may have moved, no
    check before leaving a group, and a skipped reading taken again only by a resume. A subclass sets
    ``method``, ``entries`` and ``policies`` (instrument → :class:`FaultPolicy`) and gives :meth:`attempt`."""

    method: str
    entries: list[Entry]
    policies: Mapping[str, FaultPolicy]
    retake_skipped: bool = False

    def prologue(self) -> Iterable[Step]:
        return ()

    def enter_group(self, entry: Entry, first: bool) -> Iterable[Step]:
        return ()

    def attempt(self, entry: Entry) -> Attempt:
        raise NotImplementedError(f"{type(self).__name__}.attempt: the steps of one attempt at a planned reading")

    def leave_group(self, group: int, segment: int | None) -> "tuple[Mapping[str, Any], Attempt] | None":
        return None

    def positions_unknown(self) -> None:
        return None
