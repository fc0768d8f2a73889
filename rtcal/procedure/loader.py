"""Load procedures and scenarios from YAML with located errors."""

from __future__ import annotations

import json
import os
from pathlib import Path

from collections.abc import Mapping
from typing import Annotated, Any, Union, cast

from pydantic import BaseModel, Field, TypeAdapter

from rtcal.procedure.models import Procedure
from rtcal.compensation import CompensationError, get_format
from rtcal.compensation.fanuc import FanucFormat
from rtcal.procedure.yamlfile import FileProblems, Problem, load_yaml, locate, problem_at, read_text, validate_text
from simulators.controllers import ControllerError, controller
from simulators.scenario import Scenario


def load_procedure(path: str | Path, models: Mapping[str, type[BaseModel]], large: bool = False, text: str | None = None,
                   broken: Mapping[str, str] | None = None) -> Procedure:
    """Validate a procedure file (or its ``text``, already read) with the model its ``method:`` names
    in ``models``; raises :class:`FileProblems` naming file, line and field. ``large`` accepts plans
    beyond the default size limits (``rtcal run --large``); ``broken`` names the plugins that failed to
    load, for the "unknown method" message. The registry of methods passes both
    (:func:`rtcal.methods.load_procedure`)."""
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
        if method is None and data and set(data) <= set(Scenario.model_fields):
            raise FileProblems([Problem(str(path), line, col, "(document)", "this is a bench scenario, not a procedure: "
                                        "give it with `--scenario` (e.g. `rtcal run PROCEDURE.yaml --scenario "
                                        f"{path}`)")])
        failed = (broken or {}).get(method) if isinstance(method, str) else None
        if failed:
            msg += f" (its plugin failed to load: {failed})"
        raise FileProblems([Problem(str(path), line, col, "method", f"{msg}; one of: {known}")])
    # typed as the base: a method's own attributes are read only by its own code (docs/architecture.md)
    return cast(Procedure, validate_text(text, models[method], str(path), context={"large": large}))


def load_scenario(path: str | Path, text: str | None = None) -> Scenario:
    """Validate a bench scenario file (or its ``text``, already read); a compensation table it
    names is read (relative to it) and checked."""
    text = read_text(path) if text is None else text
    data, locations = load_yaml(text, str(path))
    if isinstance(data, dict) and "method" in data:
        raise FileProblems([Problem(str(path), *locate(("method",), locations), "(document)",
                                    "this is a procedure, not a bench scenario: give it as the procedure "
                                    "(`rtcal run FILE`), and a bench with --scenario")])
    scenario = validate_text(text, Scenario, str(path))
    comp = scenario.stage.compensation
    if comp is None:
        return scenario
    where = ("stage", "compensation", "file" if comp.file else "text")
    table = comp.text
    if comp.file is not None:
        table_path = Path(path).parent / comp.file
        try:
            if table_path.stat().st_size > 1_000_000:
                raise FileProblems([problem_at(path, where, f"{table_path} is larger than 1 MB: not a compensation table")])
            table = table_path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise FileProblems([problem_at(path, where, f"cannot read {table_path}: {exc}")]) from None
    if table is None:  # never: the model holds a file or a text (CompensationScenario)
        raise FileProblems([problem_at(path, where, "give the table's file")])
    try:  # rtcal's strict reading (a FANUC table in the axis's detection unit), then as the simulated control loads it
        fmt = get_format(comp.format)
        if isinstance(fmt, FanucFormat):
            fmt.parse(table, comp.file or "text", unit_deg=comp.detection_unit_deg)
        else:
            fmt.parse(table, comp.file or "text")
        controller(comp.format, table, comp.file or "text", comp.backlash_deg, comp.detection_unit_deg, comp.bidirectional)
    except (CompensationError, ControllerError) as exc:
        raise FileProblems([problem_at(path, where, str(exc))]) from None
    return scenario.model_copy(update={"stage": scenario.stage.model_copy(update={
        "compensation": comp.model_copy(update={"text": table, "file": None})})})


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


def scenario_schema() -> str:
    schema = TypeAdapter(Scenario).json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "rtcal bench scenario"
    return json.dumps(schema, indent=2)
