"""What a method says when it has nothing to say, said once (as PyMeasure's ``Procedure`` has empty
``startup`` and ``shutdown``): a simple method subclasses :class:`MethodBase` and is its procedure and
results models, its plan, its analysis and its outputs.

Everything :class:`~rtcal.methods.protocol.Method` asks beyond those has a default here: no operator
steps and no context columns of its own, no planner (``rtcal plan`` predicts the plan as written), nothing
to fix before the first motion, no systematic error for the Monte Carlo to draw, nothing the simulated bench
cannot do beyond its limits, no checks beyond the stage's, no conditions, each instrument's role left
unsaid, and its instruments opened by their kinds — simulated on the bench (the built-in kinds'
simulations) or at their addresses (:func:`drivers.factory.open_choice`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping

from drivers.factory import open_choice

if TYPE_CHECKING:
    import numpy as np
    from pydantic import BaseModel

    from rtcal.deliverables.method_outputs import MethodOutputs
    from rtcal.engine.operator import Operator
    from rtcal.engine.plan import Plan
    from rtcal.results.model import Analysis, EnvironmentSummary, RunResults
    from rtcal.store.runstore import RunReadings
    from simulators.facade import SimBench
    from simulators.scenario import Scenario


class Instruments:
    """A method's instruments by the procedure's names, opened together and closed together (the
    :class:`~rtcal.methods.protocol.InstrumentSet` a method without its own gets)."""

    def __init__(self, devices: Mapping[str, Any]):
        self._devices = dict(devices)

    def devices(self) -> dict[str, Any]:
        return dict(self._devices)

    def close(self) -> None:
        for device in self._devices.values():
            device.close()

    def __getitem__(self, name: str) -> Any:
        return self._devices[name]


class MethodBase:
    """The defaults of every member of :class:`~rtcal.methods.protocol.Method` a simple method does not need.

    A subclass gives ``name``, ``procedure_model``, ``results_model``, ``estimators``, ``plan`` (its
    ``entries`` say how many planned readings there are), ``analyse`` and ``outputs``; and
    ``positioning_deviation = False`` when its result is not an angular positioning deviation (a
    :class:`~rtcal.results.model.QuantityEstimate`): the runner then evaluates no ISO 230-2 parameters, no
    conformity and no compensation from it."""

    name: str
    procedure_model: type[BaseModel]
    results_model: type[RunResults]
    estimators: tuple[str, ...] = ()
    """The names the method's analysis may recommend (its results model's ``recommended``)."""
    positioning_deviation: bool = True
    """Whether the recommended result is an angular positioning deviation (ISO 230-2 evaluation, conformity and
    compensation follow, and the certificate's positioning-test sections: Annex C's "not tested" is left out
    of a method whose result is none)."""
    operator_steps: bool = False
    context_columns: Mapping[str, str] = {}
    planner: Any = None

    # -- what the subclass gives -----------------------------------------------------------------------
    def plan(self, proc: Any, done: set[int], generation: int = 0, stage_step_deg: float = 0.0) -> Plan:
        raise NotImplementedError(f"{type(self).__name__}.plan: a method's order of work (rtcal.api.PlanBase)")

    def analyse(self, proc: Any, store: RunReadings, bench: SimBench | None, estimate_noise: bool = True) -> Analysis:
        raise NotImplementedError(f"{type(self).__name__}.analyse: the readings that count → its Analysis")

    def outputs(self, results: RunResults) -> MethodOutputs:
        raise NotImplementedError(f"{type(self).__name__}.outputs: its files, figures and sections (rtcal.api.OutputsBase)")

    # -- what it need not give -------------------------------------------------------------------------
    def plan_length(self, proc: Any) -> int:
        """How many planned readings: the plan's entries."""
        return len(self.plan(proc, set()).entries)

    def sim_instruments(self, proc: Any, bench: SimBench) -> Instruments:
        """Every instrument the procedure uses, simulated on the bench by its kind (a kind without a built-in
        simulation: override this)."""
        from simulators.facade import simulated_instrument

        instruments = proc.instruments
        return Instruments({name: simulated_instrument(bench, getattr(instruments, name).kind_of(name))
                            for name in instruments.present()})

    def transport_instruments(self, proc: Any) -> Instruments:
        """Every instrument the procedure uses, at its address, by its kind."""
        instruments = proc.instruments
        opened: dict[str, Any] = {}
        try:
            for name in instruments.present():
                opened[name] = open_choice(name, getattr(instruments, name))
        except BaseException:
            Instruments(opened).close()
            raise
        return Instruments(opened)

    def prepare(self, proc: Any, operator: Operator) -> dict[str, str]:
        """Nothing to fix before the first motion."""
        return {}

    def draw_systematics(self, proc: Any, scenario: Scenario, rng: np.random.Generator) -> Scenario:
        """No stated systematic error for the Monte Carlo to draw."""
        return scenario

    def scenario_problem(self, proc: Any, scenario: Scenario) -> tuple[tuple[str, ...], str] | None:
        """Nothing the simulated bench cannot do beyond its stage's and CMM's limits."""
        return None

    def checks_text(self, proc: Any) -> list[str]:
        """No checks beyond the stage's (every method's)."""
        return []

    def conditions(self, results: RunResults) -> EnvironmentSummary | None:
        """No environment sensor."""
        return None

    def instrument_roles(self, results: RunResults) -> dict[str, str]:
        """No role stated for any instrument."""
        return {}
