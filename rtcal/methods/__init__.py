"""The registry of calibration methods — a face: it imports no method. :data:`METHODS` holds the built-in
methods, named in :data:`BUILTIN` (``name → "module:Class"``, one folder each: ``multistation/``, ``abbe/``),
and those installed packages register in the entry-point group ``rtcal.methods``, all loaded the same way on
first use (:class:`rtcal.registry.Registry`): asking for one method imports its folder only, and importing a
module of a method's folder (``rtcal.methods.abbe.results``) imports no other method. Only the registry and
the command line choose a method by the procedure's ``method:``; :func:`load_procedure`, :func:`read_results`
and the schemas here hand the lower layers the registry's models, looking up only the method a file names.
What methods share — the protocol, the bases, the estimate block, the environment read, a planner's
candidate — sits beside the folders (rtcal.api is a method's one import of rtcal).
"""

from __future__ import annotations

from importlib.metadata import entry_points
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rtcal.methods.protocol import Method
from rtcal.registry import Lazy, Registry

if TYPE_CHECKING:
    from rtcal.methods.abbe.method import AbbeMethod
    from rtcal.methods.abbe.plan import AbbeInstrumentSet
    from rtcal.methods.abbe.procedure import EncoderAbbeError
    from rtcal.methods.multistation.method import MultistationMethod
    from rtcal.methods.multistation.plan import MultistationInstrumentSet
    from rtcal.methods.multistation.procedure import LaserTracerMultistation
    from rtcal.procedure.models import Procedure
    from rtcal.results.model import RunResults

    # the type checker checks here that each built-in class has the protocol's shape for its procedure and instruments
    _MULTISTATION: Method[LaserTracerMultistation, MultistationInstrumentSet] = MultistationMethod()
    _ABBE: Method[EncoderAbbeError, AbbeInstrumentSet] = AbbeMethod()

ENTRY_POINT_GROUP = "rtcal.methods"
BUILTIN = {"laser_tracer_multistation": "rtcal.methods.multistation.method:MultistationMethod",
           "encoder_abbe_error": "rtcal.methods.abbe.method:AbbeMethod",
           "rtest": "rtcal.methods.rtest.method:RTestMethod"}
"""The built-in methods, registered as a plugin is (by name and ``module:Class``)."""
MEMBERS = tuple(sorted({*Method.__annotations__, *(n for n in vars(Method) if not n.startswith("_"))}))  # what a method must have


def method_of(name: str, obj: Any, plugin: str) -> Method[Any, Any]:
    """A method from what its table entry or entry point names (a class is instantiated), checked: the name it
    implements is the one it is registered under, and it has every member of the protocol."""
    method = obj() if isinstance(obj, type) else obj
    if getattr(method, "name", None) != name:
        raise ValueError(f"its entry point is {name!r} but it implements {getattr(method, 'name', None)!r}")
    if not isinstance(method, Method):
        missing = [m for m in MEMBERS if not hasattr(method, m)]
        raise TypeError(f"it lacks {', '.join(missing)} of rtcal.methods.protocol.Method (rtcal.api.MethodBase has them)")
    return method


METHODS: Registry[Method[Any, Any]] = Registry("method", ENTRY_POINT_GROUP, BUILTIN, method_of,
                                               lambda group: entry_points(group=group))
"""Every method, by the procedure's ``method:`` (built in, and installed plugins'); a plugin that fails to load
is named in ``METHODS.broken`` and never stops the others."""


def procedure_models() -> Lazy:
    """Each method's procedure model, by ``method:`` (what the loader validates a file with): loaded only for the
    method a file names."""
    return Lazy(METHODS, lambda m: m.procedure_model)


def results_models() -> Lazy:
    """Each method's results model, by ``method`` (what results.json is validated with)."""
    return Lazy(METHODS, lambda m: m.results_model)


def _scenario_hint(data: dict[str, Any]) -> str | None:
    """Why a file with no ``method:`` may be a bench scenario given as a procedure (None: it is not one)."""
    from simulators.scenario import Scenario

    if data and set(data) <= set(Scenario.model_fields):
        return "this is a bench scenario, not a procedure: give it with `--scenario` (e.g. `rtcal run PROCEDURE.yaml --scenario {path}`)"
    return None


def load_procedure(path: str | Path, large: bool = False, text: str | None = None) -> Procedure:
    """A procedure file validated by the model of the method its ``method:`` names (file:line:field errors)."""
    from rtcal.procedure import loader

    return loader.load_procedure(path, procedure_models(), large, text, METHODS.broken, _scenario_hint)


def procedure_schema() -> str:
    """The JSON Schema of every method's procedure files."""
    from rtcal.procedure import loader

    return loader.procedure_schema(procedure_models())


def read_results(path: str | Path) -> RunResults:
    """A run's results.json validated by the results model of the method it names."""
    from rtcal.results import io

    return io.read_results(path, results_models())


def parse_results(data: bytes | str, where: str = "results.json") -> RunResults:
    """The text of a results.json validated by the results model of the method it names."""
    from rtcal.results import io

    return io.parse_results(data, results_models(), where)


def results_schema() -> str:
    """The JSON Schema of results.json, every method's results."""
    from rtcal.results import io

    return io.results_schema(results_models())


def __getattr__(name: str) -> Any:
    """``MULTISTATION`` and ``ABBE``: the built-in method objects, loaded when asked for."""
    if name in ("MULTISTATION", "ABBE"):
        return METHODS["laser_tracer_multistation" if name == "MULTISTATION" else "encoder_abbe_error"]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


if TYPE_CHECKING:
    MULTISTATION: Method[Any, Any]
    ABBE: Method[Any, Any]
