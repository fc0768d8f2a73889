"""The registry of calibration methods, above one folder per method (``multistation/``, ``abbe/``: each
holds everything that is its method's) and what methods share (the :class:`~rtcal.methods.protocol.Method`
protocol, the estimate block, the environment read, a planner's candidate). :data:`METHODS` holds the
built-in methods and those installed packages register in the entry-point group ``rtcal.methods``
(read once per process, on first use). Only the registry and the command line choose a method by the
procedure's ``method:``; :func:`load_procedure`, :func:`read_results` and the schemas here hand the
lower layers the registry's models.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from importlib.metadata import entry_points
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rtcal.methods.abbe.method import AbbeMethod
from rtcal.methods.multistation.method import MultistationMethod
from rtcal.methods.protocol import Method
from rtcal.procedure import loader
from rtcal.procedure.models import Procedure
from rtcal.methods.abbe.procedure import EncoderAbbeError
from rtcal.methods.multistation.procedure import LaserTracerMultistation
from rtcal.methods.abbe.plan import AbbeInstrumentSet
from rtcal.methods.multistation.plan import MultistationInstrumentSet

if TYPE_CHECKING:
    from pydantic import BaseModel

    from rtcal.results.model import RunResults

ENTRY_POINT_GROUP = "rtcal.methods"
MEMBERS = tuple(sorted({*Method.__annotations__, *(n for n in vars(Method) if not n.startswith("_"))}))  # what a method must have

# the type checker checks here that each class has the protocol's shape for its procedure and instruments
MULTISTATION: Method[LaserTracerMultistation, MultistationInstrumentSet] = MultistationMethod()
ABBE: Method[EncoderAbbeError, AbbeInstrumentSet] = AbbeMethod()
BUILTIN: dict[str, Method[Any, Any]] = {MULTISTATION.name: MULTISTATION, ABBE.name: ABBE}


class MethodRegistry(Mapping[str, "Method[Any, Any]"]):
    """Every method by the procedure's ``method:``: the built-in ones, then those of installed
    plugins (a plugin never replaces a built-in name). A plugin that fails to load is left out and
    named in :attr:`broken`, so that a broken package cannot stop the built-in methods."""

    def __init__(self, builtin: dict[str, Method[Any, Any]]):
        self._builtin = builtin
        self._plugins: dict[str, Method[Any, Any]] | None = None
        self.broken: dict[str, str] = {}

    def _all(self) -> dict[str, Method[Any, Any]]:
        if self._plugins is None:
            found: dict[str, Method[Any, Any]] = {}
            for ep in entry_points(group=ENTRY_POINT_GROUP):
                if ep.name in self._builtin or ep.name in found:
                    continue
                try:
                    obj = ep.load()
                    method = obj() if isinstance(obj, type) else obj
                    if method.name != ep.name:
                        raise ValueError(f"its entry point is {ep.name!r} but it implements {method.name!r}")
                    missing = [m for m in MEMBERS if not hasattr(method, m)]
                    if missing:
                        raise TypeError(f"it lacks {', '.join(missing)} of rtcal.methods.protocol.Method")
                except Exception as exc:  # noqa: BLE001 — a broken plugin is named, never a crash of the others
                    self.broken[ep.name] = f"{getattr(ep.dist, 'name', '?')}: {exc!r:.200}"
                    continue
                found[ep.name] = method
            self._plugins = found
        return {**self._builtin, **self._plugins}

    def __getitem__(self, name: str) -> Method[Any, Any]:
        return self._all()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._all())

    def __len__(self) -> int:
        return len(self._all())

    def procedure_models(self) -> dict[str, type[BaseModel]]:
        """Each method's procedure model, by ``method:`` (what the loader validates a file with)."""
        return {name: m.procedure_model for name, m in self._all().items()}

    def results_models(self) -> dict[str, type[RunResults]]:
        """Each method's results model, by ``method`` (what results.json is validated with)."""
        return {name: m.results_model for name, m in self._all().items()}


METHODS = MethodRegistry(BUILTIN)
"""Every method, by the procedure's ``method:`` (built in, and installed plugins')."""


def load_procedure(path: str | Path, large: bool = False, text: str | None = None) -> Procedure:
    """A procedure file validated by the model of the method its ``method:`` names (file:line:field errors)."""
    return loader.load_procedure(path, METHODS.procedure_models(), large, text, METHODS.broken)


def procedure_schema() -> str:
    """The JSON Schema of every method's procedure files."""
    return loader.procedure_schema(METHODS.procedure_models())


def read_results(path: str | Path) -> RunResults:
    """A run's results.json validated by the results model of the method it names."""
    from rtcal.results import io

    return io.read_results(path, METHODS.results_models())


def parse_results(data: bytes | str, where: str = "results.json") -> RunResults:
    """The text of a results.json validated by the results model of the method it names."""
    from rtcal.results import io

    return io.parse_results(data, METHODS.results_models(), where)


def results_schema() -> str:
    """The JSON Schema of results.json, every method's results."""
    from rtcal.results import io

    return io.results_schema(METHODS.results_models())
