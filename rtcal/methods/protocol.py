"""The one shape every calibration method has: what the runner, planning and the CLI rely on.

A method is an object with the :class:`Method` protocol's members: the plan's size, its
instruments (simulated on the bench, or over their transports), what to fix before the first
motion, its plan of steps (which the one engine, :mod:`rtcal.engine`, executes), the analysis of the logged readings into a typed
:class:`~rtcal.results.model.Analysis`, and the Monte Carlo's draws of the stated systematic
errors, and everything else that differs between methods: its procedure and results models (the
loader and results.json reader pick them by ``method``), the control statement's checks, the
bench's own refusals, the conditions and instrument roles the certificate states, and its outputs
(files, figures, report sections: :mod:`rtcal.deliverables`, from the typed results alone). A new
method is an object with these members, registered in :data:`rtcal.methods.METHODS` (built in) or
by an installed package's entry point in the group ``rtcal.methods`` (docs/architecture.md).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping, Protocol, TypeVar, runtime_checkable

if TYPE_CHECKING:
    import numpy as np
    from pydantic import BaseModel

    from rtcal.deliverables.method_outputs import MethodOutputs

    from rtcal.engine.plan import Plan
    from rtcal.results.model import Analysis, EnvironmentSummary, RunResults
    from rtcal.store.runstore import RunReadings
    from rtcal.engine.operator import Operator
    from simulators.bench import Bench
    from simulators.scenario import Scenario


class PreparationError(Exception):
    """What a method's ``prepare`` cannot fix before the first motion with what it was given: a
    mistake the user corrects (the CLI says it in one line, exit 2)."""


class DataContradiction(ValueError):
    """The readings contradict the procedure's model (e.g. a geometry value): a fault, never a result.
    The run keeps its readings, writes no results or certificate and exits 1, as for an instrument
    contradiction. A ValueError: every command that re-solves stored readings (verify, evaluate)
    already turns one into a message and an exit code."""


class InstrumentSet(Protocol):
    """The instruments a method measures with, opened together and closed together; ``devices()``
    names each for the plan's steps."""

    def devices(self) -> dict[str, Any]: ...

    def close(self) -> None: ...


ProcedureT = TypeVar("ProcedureT", contravariant=True)
InstrumentsT = TypeVar("InstrumentsT", bound=InstrumentSet, covariant=True)


class Addressed(Protocol):
    """An instrument section of a procedure: `backend: sim` or an address."""

    @property
    def address(self) -> str | None: ...


def address_of(instrument: Addressed) -> str:
    """The address of an instrument a run reaches over its transport (validation refuses a
    procedure that mixes simulated instruments with addresses, so there is one)."""
    if instrument.address is None:
        raise ValueError("an instrument without an address cannot be opened over a transport (`backend: sim`?)")
    return instrument.address


@runtime_checkable
class Method(Protocol[ProcedureT, InstrumentsT]):
    """A calibration method over its procedure model ``ProcedureT`` and instrument set ``InstrumentsT``."""

    name: str
    """The procedure's ``method:`` this class implements."""

    @property
    def procedure_model(self) -> type[BaseModel]:
        """The procedure file's model (its ``method`` a ``Literal`` of :attr:`name`): the loader validates with it."""
        ...

    @property
    def operator_steps(self) -> bool:
        """Whether the plan has operator steps (re-seating a polygon, moving a tracer): the control
        statement then says who carried them out."""
        ...

    @property
    def estimators(self) -> tuple[str, ...]:
        """The estimator names this method's analysis may run and recommend (its results model's ``recommended``)."""
        ...

    @property
    def positioning_deviation(self) -> bool:
        """Whether its recommended result is an angular positioning deviation: the runner then evaluates ISO 230-2
        and VDI 3441 parameters and the procedure's acceptance from it, and `rtcal compensate` takes it; a result
        of its own quantity and unit (a runout in µm) is not (results' ``QuantityEstimate``), and its certificate
        has no positioning-test section it never made (Annex C's "not tested")."""
        ...

    @property
    def context_columns(self) -> Mapping[str, str]:
        """What this method's plan entries carry beyond the store's own columns (point, station, seating, run,
        direction, commanded_*, …), each name (its unit in it, e.g. ``ball_height_mm``) with what it is: stored
        with every reading of the entry in the readings' ``context`` column; an undeclared name stops the plan
        before anything moves."""
        ...

    @property
    def results_model(self) -> type[RunResults]:
        """results.json's model (its ``method`` a ``Literal`` of :attr:`name`): the runner assembles it,
        every command that reads a run validates with it."""
        ...

    def plan_length(self, proc: ProcedureT) -> int:
        """How many planned readings the procedure takes (resume counts against it)."""
        ...

    def sim_instruments(self, proc: ProcedureT, bench: Bench) -> InstrumentsT:
        """The instruments as in-process simulators reading ``bench``."""
        ...

    def transport_instruments(self, proc: ProcedureT) -> InstrumentsT:
        """The instruments at the procedure's addresses, over their real transports."""
        ...

    def prepare(self, proc: ProcedureT, operator: Operator) -> dict[str, str]:
        """What must be fixed before the first motion, as store metadata (may ask the operator);
        :class:`PreparationError` when it cannot be."""
        ...

    def plan(self, proc: ProcedureT, done: set[int], generation: int = 0, stage_step_deg: float = 0.0) -> Plan:
        """The order of work as steps for the engine, given the planned readings already stored
        (``done``) and the run's start number; ``stage_step_deg`` bounds the stage's feedback check."""
        ...

    def analyse(self, proc: ProcedureT, store: RunReadings, bench: Bench | None, estimate_noise: bool = True) -> Analysis:
        """The logged readings (read-only; :meth:`~rtcal.store.runstore.RunReadings.counted` says which count) →
        every estimate that can run, the recommended one, its positioning deviations, and the truth of a
        simulated run (``estimate_noise`` False: noise as stated)."""
        ...

    def draw_systematics(self, proc: ProcedureT, scenario: Scenario, rng: np.random.Generator) -> Scenario:
        """A Monte Carlo trial's bench: the stated systematic errors drawn from their distributions."""
        ...

    def scenario_problem(self, proc: ProcedureT, scenario: Scenario) -> tuple[tuple[str, ...], str] | None:
        """Why the simulated bench cannot carry out this procedure beyond its stage's and CMM's limits
        (the procedure's field path, the message), or None: refused before anything moves."""
        ...

    def checks_text(self, proc: ProcedureT) -> list[str]:
        """The certificate's lines on what this method's readings were checked against, besides the
        stage's feedback (every method's), with the procedure's tolerances."""
        ...

    def conditions(self, results: RunResults) -> EnvironmentSummary | None:
        """The air and table conditions the run recorded (None: no environment sensor)."""
        ...

    def instrument_roles(self, results: RunResults) -> dict[str, str]:
        """The certificate's role of each instrument and standard of this run, e.g. "reference standard:
        angle" (a reference standard's role begins with those words: the traceability statement cites its
        certificate), or "artefact: …" for a polygon separated by closure."""
        ...

    def outputs(self, results: RunResults) -> MethodOutputs:
        """The method's files, figures, report sections and console lines, from its results alone."""
        ...

    @property
    def planner(self) -> Any:
        """What ``rtcal plan`` may vary in this method's plans (``levers``, ``notes``, ``candidates``,
        ``pruning``, ``points_refusal``, ``choose_points``: rtcal/planning/levers.py's planners), or None:
        the plan is predicted as written, with no levers and no proposal."""
        ...
