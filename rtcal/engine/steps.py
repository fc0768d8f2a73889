"""The vocabulary a plan speaks: small frozen steps the engine executes, and what it answers.

A plan (each method's ``plan.py`` under :mod:`rtcal.methods`) is data and order: which device moves where, what is read and how
it is checked. It does no I/O itself. The engine (:mod:`rtcal.engine.engine`) executes every
step under the procedure's fault policies and records what it reads; walking a plan with a
timing model (:mod:`rtcal.engine.walk`) gives its duration without any instrument.

A step that reads or moves names its instrument; the device is looked up by that name in the
run's instruments. A reading names the described fields it takes (never a driver method): the
engine does every read through the instrument's ``read_values`` and stores what its description
says. Where a reading must be checked against the command, the step carries the relation the
values must satisfy (``check``, pure: no I/O): a plan knows what to expect, the engine reads and
rides out a fault. Each reading step also carries ``nominal``, what an ideal bench would give,
which the walker answers in its place.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Union

from drivers.errors import InstrumentError
from rtcal.moved import moved


class Skipped(Exception):
    """Thrown into a plan where an instrument's ``on_fault`` policy skipped a step: the attempt
    ends as not whole (resume and the retake pass take it again) unless the plan catches it."""

    def __init__(self, instrument: str, error: InstrumentError | None):
        super().__init__(f"{instrument}: {error}")
        self.instrument = instrument
        self.error = error


@dataclass(frozen=True)
class Validate:
    """Before anything moves: every target the plan will command is within the device's limits."""

    instrument: str
    targets: tuple[Any, ...]


@dataclass(frozen=True)
class Move:
    """Move one device. A stage with ``direction`` ±1 arrives at ``target`` moving that way (ISO 230-2),
    passing it by ``overshoot_deg`` first where it would arrive the other way."""

    instrument: str
    target: Any
    direction: int = 0
    overshoot_deg: float = 0.0
    what: str = ""


@dataclass(frozen=True)
class Parallel:
    """Motions the plan declares independent (the table indexing while the CMM travels): the engine
    starts them together; a motion that faults is then ridden out under its policy alone."""

    moves: tuple[Move, ...]


@dataclass(frozen=True)
class Settle:
    seconds: float


Relation = Callable[[Any], Any]
"""What a reading's values must satisfy: a pure function of the values read (a number, or a tuple in the
step's field order) that returns them as the plan takes them, or raises
:class:`~rtcal.engine.checks.Contradiction` (or an instrument fault: an axis the instrument reports
invalid). It does no I/O: the engine reads, the relation only judges."""


@dataclass(frozen=True)
class Read:
    """One reading of ``fields`` of the instrument, named as its kind's description names them, taken for
    ``purpose`` (drivers/interfaces.py PURPOSES: the stored quantity and unit follow from the description).
    The engine reads them with ``read_values`` under the instrument's fault policy, stores each finite
    value (NaN: "not measured"), then checks ``check``: a contradiction rejects the attempt, which the
    policy of the instrument named retakes, skips or aborts (the one path of every failed check). The
    plan receives the checked value (one field: a number; several: a tuple). ``optional`` readings
    (conditions) never hold up the attempt they accompany; ``nominal`` is what the walker answers."""

    instrument: str
    fields: tuple[str, ...]
    check: Relation | None = field(default=None, compare=False)
    nominal: Any = field(default=None, compare=False)
    what: str = ""
    purpose: str = ""
    sample: int | None = None
    optional: bool = False


@dataclass(frozen=True)
class ReadSamples:
    """``count`` samples of ``field`` of a tracking instrument (a laser tracer), stamped with its tracking
    segment. A lost beam is re-acquired where the policy says so, and the samples start again: an attempt
    never mixes two tracking segments."""

    instrument: str
    field: str
    count: int
    nominal: float = 0.0
    where: str = ""
    what: str = ""
    sample_s: float = 0.0
    """What one sample takes (integration, transfer): counted by the walker and by a simulated run's clock."""
    reference_s: float = 0.0
    """What re-acquiring the beam takes."""
    purpose: str = ""


@dataclass(frozen=True)
class Samples:
    """What :class:`ReadSamples` answers: the values, and whether the beam was re-acquired on the way."""

    values: tuple[float, ...]
    reacquired: bool
    segment: int | None = None


@dataclass(frozen=True)
class Reference:
    """Reference a tracking instrument (a new tracking segment) when it has none; the engine answers
    True if it referenced, False if it was tracking already."""

    instrument: str
    where: str
    why: str = "reference"
    seconds: float = 0.0


SimulatedAction = Callable[[Any], None]
"""What the simulated operator does in a person's place, given the simulated bench's hands (rtcal.api's
``SimBench``: its polygon re-seated, its tracer moved, an artefact mounted): in a run on the bench in this
process, on the bench itself; in a run on `rtcal sim serve`, each call is sent to its simulated operator."""


@dataclass(frozen=True)
class OperatorStep:
    """A person's step mid-run (re-seat the polygon, move the tracer, mount a test ball), as bluesky's ``input``
    message: ``instruction`` is what the person is asked (at the terminal and on the live page) and confirms
    (Enter, the page's Done, `rtcal control … confirm`); ``simulate`` is what the simulated operator does
    instead (None: nothing to do on a simulated bench); ``task`` the step in a few words, for "the procedure
    needs an operator to <task>". Once done it is logged as an ``operator`` event saying ``message``. ``seconds``
    is what it takes: the walker counts it, and so does a simulated run's clock (on hardware it takes what it
    takes). The engine only asks, waits, confirms or cancels: the words and the action are the method's."""

    instruction: str
    message: str
    simulate: SimulatedAction | None = field(default=None, compare=False)
    task: str = "carry out a set-up step"
    instrument: str | None = None
    seconds: float = 0.0

    def __post_init__(self) -> None:
        if not (isinstance(self.instruction, str) and isinstance(self.message, str) and isinstance(self.task, str)) \
                or (self.simulate is not None and not callable(self.simulate)):
            raise TypeError("OperatorStep(instruction, message, simulate=…, task=…): the words the person is asked, the "
                            "event once done, what the simulated operator does (a function of the bench's hands) — an "
                            "operator step names no operator method (rtcal.api)")


Step = Union[Validate, Move, Parallel, Settle, Read, ReadSamples, Reference, OperatorStep]


@dataclass(frozen=True)
class _RemovedRecover:
    """What ``Recover(instrument)`` was — "reset what a device latched" as a plan's step —, importable for one
    release so that a plan written for it still imports. The engine executes no such step (a plan that yields one
    stops as failed, naming the steps it knows): the instrument's fault policy resets the device itself."""

    instrument: str


_RemovedRecover.__name__ = _RemovedRecover.__qualname__ = "Recover"

__getattr__ = moved(__name__, {}, removed={"Recover": (
    _RemovedRecover, "the engine resets a device itself — a Move or Read that faults is retried under the "
    "instrument's fault policy (the procedure's on_fault), which calls the device's recover() before each retry, and "
    "a Read's check rejects a reading that contradicts the command, which the policy retakes; a plan yields no Recover")})
