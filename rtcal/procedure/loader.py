"""Load procedures and scenarios from YAML with located errors."""

from __future__ import annotations

import json
from pathlib import Path

from typing import Annotated, Union

from pydantic import Field, TypeAdapter

from rtcal.procedure.models import PROCEDURE_MODELS, Procedure
from rtcal.yamlfile import FileProblems, Problem, load_yaml, locate, read_text, validate_file, validate_text
from simulators.scenario import Scenario


def load_procedure(path: str | Path) -> Procedure:
    """Validate a procedure file; raises :class:`FileProblems` naming file, line and field."""
    path = Path(path)
    text = read_text(path)
    data, locations = load_yaml(text, str(path))
    if not isinstance(data, dict):
        raise FileProblems([Problem(str(path), *locations[()], "(document)", "expected a mapping with a `method` key")])
    method = data.get("method")
    if not isinstance(method, str) or method not in PROCEDURE_MODELS:
        line, col = locate(("method",), locations)
        known = ", ".join(sorted(PROCEDURE_MODELS))
        msg = "required key is missing" if method is None else f"unknown method {method!r}"
        raise FileProblems([Problem(str(path), line, col, "method", f"{msg}; one of: {known}")])
    return validate_text(text, PROCEDURE_MODELS[method], str(path))


def load_scenario(path: str | Path) -> Scenario:
    """Validate a bench scenario file."""
    return validate_file(path, Scenario)


def is_procedure_text(text: str) -> bool:
    """A procedure names a method or instruments at the top level; anything else is a scenario."""
    try:
        data, _ = load_yaml(text, "?")
    except FileProblems:
        return True
    return isinstance(data, dict) and ("method" in data or "instruments" in data)


def procedure_schema() -> str:
    """JSON Schema of procedure files (one branch per ``method``), for editors."""
    union = Annotated[Union[tuple(PROCEDURE_MODELS.values())], Field(discriminator="method")]
    schema = TypeAdapter(union).json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "rtcal procedure"
    return json.dumps(schema, indent=2)


def scenario_schema() -> str:
    schema = TypeAdapter(Scenario).json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "rtcal bench scenario"
    return json.dumps(schema, indent=2)
