"""A bench scenario file read with located errors, and its JSON Schema: what `rtcal run --scenario`, `rtcal sim
serve --scenario` and a procedure's ``bench:`` read (moved from rtcal/procedure/loader.py: a procedure's layer
reads no simulator)."""

from __future__ import annotations

import json
from pathlib import Path

from pydantic import TypeAdapter

from rtcal.compensation import CompensationError, get_format
from rtcal.compensation.fanuc import FanucFormat
from rtcal.procedure.yamlfile import FileProblems, Problem, load_yaml, locate, problem_at, read_text, validate_text
from simulators.controllers import ControllerError, controller
from simulators.scenario import Scenario


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


def scenario_schema() -> str:
    schema = TypeAdapter(Scenario).json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "rtcal bench scenario"
    return json.dumps(schema, indent=2)
