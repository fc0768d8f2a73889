"""Load procedures and scenarios from YAML with located errors."""

from __future__ import annotations

import json
import os
from pathlib import Path

from collections.abc import Callable, Mapping
from typing import Annotated, Any, Union, cast

from pydantic import BaseModel, Field, TypeAdapter

from rtcal.moved import moved
from rtcal.procedure.models import Procedure
from rtcal.procedure.yamlfile import FileProblems, Problem, load_yaml, locate, problem_at, read_text, validate_text

NotAProcedure = Callable[[dict[str, Any]], "str | None"]
"""What a document without a ``method:`` may be instead (a bench scenario), in words, or None; ``{path}`` in the
words is the file's path."""


def load_procedure(path: str | Path, models: Mapping[str, type[BaseModel]], large: bool = False, text: str | None = None,
                   broken: Mapping[str, str] | None = None, not_a_procedure: NotAProcedure | None = None) -> Procedure:
    """Validate a procedure file (or its ``text``, already read) with the model its ``method:`` names
    in ``models``; raises :class:`FileProblems` naming file, line and field. ``large`` accepts plans
    beyond the default size limits (``rtcal run --large``); ``broken`` names the plugins that failed to
    load, for the "unknown method" message; ``not_a_procedure`` says what a document without one is instead. The
    registry of methods passes them (:func:`rtcal.methods.load_procedure`)."""
    path = Path(path)
    text = read_text(path) if text is None else text
    data, locations = load_yaml(text, str(path))
    if not isinstance(data, dict):
        raise FileProblems([Problem(str(path), *locations[()], "(document)", "expected a mapping with a `method` key")])
    method = data.get("method")
    if not isinstance(method, str) or method not in models:
        line, col = locate(("method",), locations)
        known = ", ".join(sorted(models))
        msg = "required key is missing" if method is None else f"unknown method {method!r}"
        instead = not_a_procedure(data) if method is None and not_a_procedure is not None else None
        if instead:
            raise FileProblems([Problem(str(path), line, col, "(document)", instead.replace("{path}", str(path)))])
        failed = (broken or {}).get(method) if isinstance(method, str) else None
        if failed:
            msg += f" (its plugin failed to load: {failed})"
        raise FileProblems([Problem(str(path), line, col, "method", f"{msg}; one of: {known}")])
    # typed as the base: a method's own attributes are read only by its own code (docs/architecture.md)
    return cast(Procedure, validate_text(text, models[method], str(path), context={"large": large}))


def bench_path(procedure_path: str | Path, proc: Procedure) -> Path | None:
    """The procedure's ``bench``, relative to the procedure file and inside its folder.

    A procedure names only scenarios that travel with it: a ``bench`` elsewhere (``/etc/…``,
    ``../../…``, a link leading out, a device) would be read and copied into the run store on
    the word of a file. A scenario from anywhere else is read when named on the command line.
    """
    if proc.bench is None:
        return None
    procedure_path = Path(procedure_path)
    folder = os.path.realpath(procedure_path.parent)
    candidate = procedure_path.parent / proc.bench
    real = os.path.realpath(candidate)
    if os.path.commonpath([folder, real]) != folder:
        raise FileProblems([problem_at(procedure_path, ("bench",),
                                       f"{proc.bench!r} lies outside the procedure's folder {folder}; name a scenario "
                                       "from elsewhere on the command line (`rtcal run --scenario FILE`)")])
    if not os.path.exists(real):
        raise FileProblems([problem_at(procedure_path, ("bench",), f"cannot read {proc.bench!r}: no such file "
                                       f"(relative to the procedure's folder {folder})")])
    if not os.path.isfile(real):
        raise FileProblems([problem_at(procedure_path, ("bench",), f"cannot read {proc.bench!r}: not a regular file "
                                       "(a directory or device); name a scenario file")])
    return candidate


def is_procedure_text(text: str) -> bool:
    """A procedure names a method or instruments at the top level; anything else is a scenario."""
    try:
        data, _ = load_yaml(text, "?")
    except FileProblems:
        return True
    return isinstance(data, dict) and ("method" in data or "instruments" in data)


def procedure_schema(models: Mapping[str, type[BaseModel]]) -> str:
    """JSON Schema of procedure files (one branch per ``method`` of ``models``), for editors."""
    union: Any = Annotated[Union[tuple(models.values())], Field(discriminator="method")]
    schema = TypeAdapter(union).json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "rtcal procedure"
    return json.dumps(schema, indent=2)


# a bench scenario's reading is the simulators' (a procedure's layer reads no simulator)
__getattr__ = moved(__name__, {"load_scenario": "simulators.scenario_file", "scenario_schema": "simulators.scenario_file"})
