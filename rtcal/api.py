"""rtcal's public face: everything a calibration method or an instrument kind may use of rtcal, in one module.

A method or a kind written outside rtcal (an installed plugin) imports rtcal only from here, and
``rtcal.solvers`` for mathematics; rtcal's own methods do too, as far as their solvers allow. Every name
below keeps its meaning across minor releases; a name that moves keeps a deprecation shim for one release.
rtcal ships ``py.typed``: ``mypy --strict`` checks a plugin against these types. Nothing is imported until a
name is first used (``rtcal --help`` pays for none of it).

**A method** (docs/architecture.md, "Writing a method", walks through tests/plugins/ball_runout) is one
object, registered under the entry-point group ``rtcal.methods`` (``name = "module:Class"``). Subclass
:class:`MethodBase`, which says "nothing" once for everything a simple method does not have, and give:

- ``name``, ``procedure_model`` (a :class:`ProcedureBase` subclass with ``method: Literal[name]`` — a
  :class:`CycleProcedureBase` when its plan is a :class:`TargetCycle` of its stage (targets, directions, runs,
  overrun; its visits, :class:`Visit`) —, its
  ``instruments`` an :class:`InstrumentsBase` of :class:`InstrumentChoice` — each may declare its ``kind``
  and ``address`` —, ``approaches``, ``plan_size``, ``planned_stage_deg``), ``results_model`` (a
  :class:`RunResults` subclass with ``method: Literal[name]`` and its own :class:`Analysis`),
  ``estimators`` (the names its analysis may recommend) and ``positioning_deviation`` (whether its result is
  an angular positioning deviation: then ISO 230-2 evaluation, conformity and compensation follow; a
  result in its own quantity and unit is a :class:`QuantityEstimate`);
- ``plan(proc, done, generation, stage_step_deg)``: a :class:`PlanBase` whose ``entries`` are the planned
  readings (:class:`Entry`: the store's columns, and the method's own ``context_columns``) and whose
  ``attempt(entry)`` yields steps — :class:`Move`, :class:`Settle`, :class:`Read` (fields its instruments'
  kinds describe, checked by a relation such as :class:`MotionChecks`'), :class:`OperatorStep` (words for a
  person, an action for the simulated bench); :func:`arrive` and :func:`stood_still` are "the stage moves,
  settles and is checked" and "it did not move while read";
- ``analyse(proc, store, bench, estimate_noise)``: the readings that count (:class:`RunReadings`'s
  ``counted``) → its :class:`Analysis`, with :func:`run_estimators`, :func:`choose_recommended`,
  :func:`deviation_block` or :func:`quantity_estimate`;
- ``outputs(results)``: an :class:`OutputsBase` (files, figures, report and certificate sections: numbers
  rounded as the certificate rounds them, :func:`u_text`, :func:`fmt`, :func:`significant`; figures on rtcal's
  backend, :data:`plt`, :func:`legend_below`; :func:`status_lines` for estimators that did not converge; the
  axis's :class:`ErrorMotions` and :class:`MeasuredLocation` for ISO 230-1 outputs);
- optionally ``planner``: what ``rtcal plan`` may vary (each a :class:`Candidate`; :func:`walk` with a
  :class:`Timing` is a plan's duration without any instrument);
- optionally ``recalibration``: a :class:`Recalibration`, how a reference instrument's new calibration
  (:class:`InstrumentCalibration`) enters a run already made (``rtcal catalog reassess``; a part it does not take
  raises :class:`CannotRecalibrate`).

**An instrument kind** is a subclass of :class:`Instrument` declaring ``kind``, ``fields`` (each a
:class:`FieldDescription`) and ``_raw_values``, registered under ``rtcal.instrument_kinds``; its simulation
reads the simulated bench only through :class:`SimBench`. **A driver model** (``rtcal.drivers``) is a driver
class of a kind's interface speaking its product's protocol (:class:`SerialLine`, :class:`Framing`,
:class:`Address`); **a compensation format** (``rtcal.compensation_formats``) a :class:`CompensationFormat`
(docs/drivers.md, docs/compensation.md).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from drivers.addresses import Address as Address
    from drivers.errors import InstrumentError as InstrumentError
    from drivers.errors import InstrumentFault as InstrumentFault
    from drivers.errors import InstrumentTimeout as InstrumentTimeout
    from drivers.errors import TrackingLost as TrackingLost
    from drivers.factory import open_choice as open_choice
    from drivers.factory import open_instrument as open_instrument
    from drivers.interfaces import DESCRIPTIONS as DESCRIPTIONS
    from drivers.interfaces import Autocollimator as Autocollimator
    from drivers.interfaces import Cmm as Cmm
    from drivers.interfaces import DialIndicator as DialIndicator
    from drivers.interfaces import Encoder as Encoder
    from drivers.interfaces import EnvironmentSensor as EnvironmentSensor
    from drivers.interfaces import FieldDescription as FieldDescription
    from drivers.interfaces import Instrument as Instrument
    from drivers.interfaces import LaserTracer as LaserTracer
    from drivers.interfaces import LengthReading as LengthReading
    from drivers.interfaces import MachineTarget as MachineTarget
    from drivers.interfaces import MachineTool as MachineTool
    from drivers.interfaces import RotaryStage as RotaryStage
    from drivers.interfaces import Value as Value
    from drivers.models import Framing as Framing
    from drivers.serial_line import SerialLine as SerialLine
    from rtcal.compensation import CompensationError as CompensationError
    from rtcal.compensation import CompensationFormat as CompensationFormat
    from rtcal.compensation import CompensationTable as CompensationTable
    from rtcal.compensation import FormatOption as FormatOption
    from rtcal.compensation import sane as sane
    from rtcal.compensation.geometry import ErrorMotions as ErrorMotions
    from rtcal.compensation.geometry import MeasuredLocation as MeasuredLocation
    from rtcal.compensation.geometry import RAD_PER_ARCSEC as RAD_PER_ARCSEC
    from rtcal.compensation.kinematics import KinematicsOutput as KinematicsOutput
    from rtcal.compensation.kinematics import LocationErrors as LocationErrors
    from rtcal.compensation.kinematics_registry import kinematics_format as kinematics_format
    from rtcal.deliverables.certificate import status_lines as status_lines
    from rtcal.deliverables.deviations import PositioningDeviations as PositioningDeviations
    from rtcal.deliverables.figures import legend_below as legend_below
    from rtcal.deliverables.figures import plt as plt
    from rtcal.deliverables.method_outputs import MethodOutputs as MethodOutputs
    from rtcal.deliverables.method_outputs import OutputsBase as OutputsBase
    from rtcal.deliverables.rounding import decimals as decimals
    from rtcal.deliverables.rounding import fmt as fmt
    from rtcal.deliverables.rounding import round_up as round_up
    from rtcal.deliverables.rounding import significant as significant
    from rtcal.deliverables.rounding import u_text as u_text
    from rtcal.engine.checks import Contradiction as Contradiction
    from rtcal.engine.checks import MotionChecks as MotionChecks
    from rtcal.engine.checks import UncommandedMotion as UncommandedMotion
    from rtcal.engine.checks import arrive as arrive
    from rtcal.engine.checks import combined_sigma as combined_sigma
    from rtcal.engine.checks import stood_still as stood_still
    from rtcal.engine.operator import Operator as Operator
    from rtcal.engine.plan import Attempt as Attempt
    from rtcal.engine.plan import Entry as Entry
    from rtcal.engine.plan import Plan as Plan
    from rtcal.engine.plan import PlanBase as PlanBase
    from rtcal.engine.steps import Move as Move
    from rtcal.engine.steps import OperatorStep as OperatorStep
    from rtcal.engine.steps import Parallel as Parallel
    from rtcal.engine.steps import Read as Read
    from rtcal.engine.steps import ReadSamples as ReadSamples
    from rtcal.engine.steps import Reference as Reference
    from rtcal.engine.steps import Samples as Samples
    from rtcal.engine.steps import Settle as Settle
    from rtcal.engine.steps import Skipped as Skipped
    from rtcal.engine.steps import Step as Step
    from rtcal.engine.steps import Validate as Validate
    from rtcal.engine.walk import Timing as Timing
    from rtcal.engine.walk import walk as walk
    from rtcal.methods.base import Instruments as Instruments
    from rtcal.methods.base import MethodBase as MethodBase
    from rtcal.methods.conditions import environment_read as environment_read
    from rtcal.methods.conditions import summarise_conditions as summarise_conditions
    from rtcal.methods.cycle import CycleProcedureBase as CycleProcedureBase
    from rtcal.methods.cycle import TargetCycle as TargetCycle
    from rtcal.methods.cycle import Visit as Visit
    from rtcal.methods.estimates import COVERAGE_FACTOR as COVERAGE_FACTOR
    from rtcal.methods.estimates import QuantitySource as QuantitySource
    from rtcal.methods.estimates import choose_recommended as choose_recommended
    from rtcal.methods.estimates import deviation_block as deviation_block
    from rtcal.methods.estimates import finite_or_none as finite_or_none
    from rtcal.methods.estimates import not_covered as not_covered
    from rtcal.methods.estimates import quantity_estimate as quantity_estimate
    from rtcal.methods.estimates import residual_test as residual_test
    from rtcal.methods.estimates import run_estimators as run_estimators
    from rtcal.methods.estimates import with_residual_test as with_residual_test
    from rtcal.methods.planner import Candidate as Candidate
    from rtcal.methods.protocol import DataContradiction as DataContradiction
    from rtcal.methods.protocol import InstrumentSet as InstrumentSet
    from rtcal.methods.protocol import Method as Method
    from rtcal.methods.protocol import PreparationError as PreparationError
    from rtcal.methods.protocol import address_of as address_of
    from rtcal.methods.recalibration import CannotRecalibrate as CannotRecalibrate
    from rtcal.methods.recalibration import InstrumentCalibration as InstrumentCalibration
    from rtcal.methods.recalibration import Recalibration as Recalibration
    from rtcal.procedure.models import Acceptance as Acceptance
    from rtcal.procedure.models import Angle_deg as Angle_deg
    from rtcal.procedure.models import CmmChoice as CmmChoice
    from rtcal.procedure.models import FaultPolicy as FaultPolicy
    from rtcal.procedure.models import InstrumentChoice as InstrumentChoice
    from rtcal.procedure.models import InstrumentsBase as InstrumentsBase
    from rtcal.procedure.models import ProcedureBase as ProcedureBase
    from rtcal.procedure.models import StageChoice as StageChoice
    from rtcal.procedure.models import StrictModel as StrictModel
    from rtcal.procedure.models import Vec3 as Vec3
    from rtcal.procedure.models import VerificationBase as VerificationBase
    from rtcal.procedure.models import plan_outside_limits as plan_outside_limits
    from rtcal.procedure.models import plan_size_problem as plan_size_problem
    from rtcal.results.model import Analysis as Analysis
    from rtcal.results.model import Arcsec as Arcsec
    from rtcal.results.model import Count as Count
    from rtcal.results.model import Deg as Deg
    from rtcal.results.model import DeviationBlock as DeviationBlock
    from rtcal.results.model import DeviationTable as DeviationTable
    from rtcal.results.model import Direction as Direction
    from rtcal.results.model import EnvironmentSummary as EnvironmentSummary
    from rtcal.results.model import Estimate as Estimate
    from rtcal.results.model import Mm as Mm
    from rtcal.results.model import NamedSet as NamedSet
    from rtcal.results.model import Number as Number
    from rtcal.results.model import QuantityEstimate as QuantityEstimate
    from rtcal.results.model import ResidualTest as ResidualTest
    from rtcal.results.model import ResultsModel as ResultsModel
    from rtcal.results.model import RunResults as RunResults
    from rtcal.results.model import SigmaArcsec as SigmaArcsec
    from rtcal.results.model import SolverStatus as SolverStatus
    from rtcal.results.model import TargetedEstimate as TargetedEstimate
    from rtcal.results.model import Text as Text
    from rtcal.results.model import Truth as Truth
    from rtcal.results.model import Um as Um
    from rtcal.store.runstore import Reading as Reading
    from rtcal.store.runstore import RunReadings as RunReadings
    from simulators.facade import SimBench as SimBench
    from simulators.facade import ideal_bench as ideal_bench
    from simulators.facade import simulated_instrument as simulated_instrument
    from simulators.facade import simulated_nest_indicator as simulated_nest_indicator
    from simulators.facade import true_c_deviation_arcsec as true_c_deviation_arcsec
    from simulators.facade import true_location_errors as true_location_errors
    from simulators.scenario import Scenario as Scenario

# where each name lives (what the TYPE_CHECKING imports above say to the type checker; tests/test_api.py holds
# the two together)
_WHERE = {
    "drivers.addresses": ("Address",),
    "drivers.errors": ("InstrumentError", "InstrumentFault", "InstrumentTimeout", "TrackingLost"),
    "drivers.factory": ("open_choice", "open_instrument"),
    "drivers.interfaces": ("DESCRIPTIONS",
                           "Autocollimator", "Cmm", "DialIndicator", "Encoder", "EnvironmentSensor", "FieldDescription",
                           "Instrument", "LaserTracer", "LengthReading", "MachineTarget", "MachineTool", "RotaryStage",
                           "Value"),
    "drivers.models": ("Framing",),
    "drivers.serial_line": ("SerialLine",),
    "rtcal.compensation": ("CompensationError", "CompensationFormat", "CompensationTable", "FormatOption", "sane"),
    "rtcal.compensation.geometry": ("ErrorMotions", "MeasuredLocation", "RAD_PER_ARCSEC"),
    "rtcal.compensation.kinematics": ("KinematicsOutput", "LocationErrors"),
    "rtcal.compensation.kinematics_registry": ("kinematics_format",),
    "rtcal.deliverables.certificate": ("status_lines",),
    "rtcal.deliverables.deviations": ("PositioningDeviations",),
    "rtcal.deliverables.figures": ("legend_below", "plt"),
    "rtcal.deliverables.method_outputs": ("MethodOutputs", "OutputsBase"),
    "rtcal.deliverables.rounding": ("decimals", "fmt", "round_up", "significant", "u_text"),
    "rtcal.engine.checks": ("Contradiction", "MotionChecks", "UncommandedMotion", "arrive", "combined_sigma", "stood_still"),
    "rtcal.engine.operator": ("Operator",),
    "rtcal.engine.plan": ("Attempt", "Entry", "Plan", "PlanBase"),
    "rtcal.engine.steps": ("Move", "OperatorStep", "Parallel", "Read", "ReadSamples", "Reference", "Samples", "Settle",
                           "Skipped", "Step", "Validate"),
    "rtcal.engine.walk": ("Timing", "walk"),
    "rtcal.methods.base": ("Instruments", "MethodBase"),
    "rtcal.methods.conditions": ("environment_read", "summarise_conditions"),
    "rtcal.methods.cycle": ("CycleProcedureBase", "TargetCycle", "Visit"),
    "rtcal.methods.estimates": ("COVERAGE_FACTOR", "QuantitySource", "choose_recommended", "deviation_block",
                                "finite_or_none", "not_covered", "quantity_estimate", "residual_test",
                                "run_estimators", "with_residual_test"),
    "rtcal.methods.planner": ("Candidate",),
    "rtcal.methods.protocol": ("DataContradiction", "InstrumentSet", "Method", "PreparationError", "address_of"),
    "rtcal.methods.recalibration": ("CannotRecalibrate", "InstrumentCalibration", "Recalibration"),
    "rtcal.procedure.models": ("Acceptance", "Angle_deg", "CmmChoice", "FaultPolicy", "InstrumentChoice",
                               "InstrumentsBase", "ProcedureBase", "StageChoice", "StrictModel", "Vec3",
                               "VerificationBase", "plan_outside_limits", "plan_size_problem"),
    "rtcal.results.model": ("Analysis", "Arcsec", "Count", "Deg", "DeviationBlock", "DeviationTable", "Direction",
                            "EnvironmentSummary", "Estimate", "Mm", "NamedSet", "Number", "QuantityEstimate",
                            "ResidualTest", "ResultsModel", "RunResults", "SigmaArcsec", "SolverStatus", "TargetedEstimate", "Text",
                            "Truth", "Um"),
    "rtcal.store.runstore": ("Reading", "RunReadings"),
    "simulators.facade": ("SimBench", "ideal_bench", "simulated_instrument", "simulated_nest_indicator",
                          "true_c_deviation_arcsec", "true_location_errors"),
    "simulators.scenario": ("Scenario",),
}
_MODULE_OF = {name: module for module, names in _WHERE.items() for name in names}
__all__ = sorted(_MODULE_OF)


def __getattr__(name: str) -> Any:
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r} (rtcal.api's names: rtcal.api.__all__)")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # once loaded, a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
