"""YAML files validated by pydantic, with every problem located as file:line:column: field.

PyYAML's composer gives each node its position; we keep a map from the path of keys and
indices to (line, column) and translate pydantic's error locations through it. Duplicate keys
are an error (PyYAML would silently keep the last). Only plain data is constructed (safe
loader): a procedure file cannot execute code.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

Path_ = tuple[Any, ...]
M = TypeVar("M", bound=BaseModel)


@dataclass(frozen=True)
class Problem:
    """One located problem in a user's file."""

    file: str
    line: int  # 1-based
    column: int  # 1-based
    field: str
    message: str

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}: {self.field}: {self.message}"


class FileProblems(Exception):
    """A user's file is not valid; ``problems`` says where and why."""

    def __init__(self, problems: list[Problem]):
        super().__init__("\n".join(str(p) for p in problems))
        self.problems = problems


def _field_name(path: Path_) -> str:
    parts = []
    for p in path:
        if isinstance(p, int):
            parts.append(f"[{p}]")
        else:
            parts.append(("." if parts else "") + str(p))
    return "".join(parts) or "(document)"


PLAIN_TAGS = {f"tag:yaml.org,2002:{t}" for t in ("str", "int", "float", "bool", "null", "seq", "map")}


def _scalar(node: yaml.ScalarNode) -> Any:
    """A scalar node's value by PyYAML's safe constructor (its tag is already resolved)."""
    return yaml.SafeLoader("").construct_object(node, deep=True)


def _walk(node: yaml.Node, path: Path_, out: dict[Path_, tuple[int, int]], file: str) -> Any:
    out.setdefault(path, (node.start_mark.line + 1, node.start_mark.column + 1))  # a key keeps its own position
    if node.tag not in PLAIN_TAGS:
        raise FileProblems([Problem(file, *out[path], _field_name(path), f"YAML tag {node.tag!r} is not allowed: plain data only")])
    if isinstance(node, yaml.MappingNode):
        result: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            key = _scalar(key_node) if isinstance(key_node, yaml.ScalarNode) and key_node.tag in PLAIN_TAGS else None
            if not isinstance(key, (str, int, float, bool)) or key is None:
                raise FileProblems([Problem(file, key_node.start_mark.line + 1, key_node.start_mark.column + 1,
                                            _field_name(path), "keys must be plain scalars")])
            if key in result:
                line, col = key_node.start_mark.line + 1, key_node.start_mark.column + 1
                raise FileProblems([Problem(file, line, col, _field_name(path + (key,)),
                                            f"duplicate key (first given on line {out[path + (key,)][0]})")])
            out[path + (key,)] = (key_node.start_mark.line + 1, key_node.start_mark.column + 1)
            result[key] = _walk(value_node, path + (key,), out, file)
        return result
    if isinstance(node, yaml.SequenceNode):
        return [_walk(child, path + (i,), out, file) for i, child in enumerate(node.value)]
    return _scalar(node)


def load_yaml(text: str, file: str) -> tuple[Any, dict[Path_, tuple[int, int]]]:
    """Parse YAML text into plain data and a map of key paths to (line, column)."""
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line, col = (mark.line + 1, mark.column + 1) if mark else (1, 1)
        raise FileProblems([Problem(file, line, col, "(syntax)", str(exc.problem or exc).strip())]) from None
    except yaml.YAMLError as exc:
        raise FileProblems([Problem(file, 1, 1, "(syntax)", str(exc))]) from None
    if node is None:
        return None, {(): (1, 1)}
    locations: dict[Path_, tuple[int, int]] = {}
    return _walk(node, (), locations, file), locations


def locate(path: Path_, locations: dict[Path_, tuple[int, int]]) -> tuple[int, int]:
    """Position of the deepest existing prefix of ``path`` (a missing key points at its parent)."""
    for cut in range(len(path), -1, -1):
        if path[:cut] in locations:
            return locations[path[:cut]]
    return (1, 1)


def problems_from_validation(exc: ValidationError, locations: dict[Path_, tuple[int, int]], file: str) -> list[Problem]:
    """Translate pydantic errors into located problems.

    Union tags in pydantic's locations (e.g. ``grid`` of a discriminated union) are not keys
    of the file and are dropped. A model-level check names its field by starting its message
    with ``field.path: ``.
    """
    keys = {p for path in locations for p in path if isinstance(p, str)}
    problems = []
    for err in exc.errors(include_url=False):
        path = tuple(p for p in err["loc"] if isinstance(p, int) or p in keys)
        message = str(err["msg"]).removeprefix("Value error, ")
        named = re.match(r"^([A-Za-z_][\w.]*): (.*)$", message, re.S) if err["type"] == "value_error" else None
        if named:
            path, message = path + tuple(named.group(1).split(".")), named.group(2)
        elif err["type"] == "extra_forbidden":
            message = "unknown key (check the spelling; `rtcal schema` lists the keys)"
        elif err["type"] == "missing":
            message = "too few items" if path and isinstance(path[-1], int) else "required key is missing"
        line, col = locate(path, locations)
        problems.append(Problem(file, line, col, _field_name(path), message))
    return problems


def validate_text(text: str, model: type[M], file: str, context: dict[str, Any] | None = None) -> M:
    """Parse and validate YAML text as ``model``; raise :class:`FileProblems` with locations."""
    data, locations = load_yaml(text, file)
    if not isinstance(data, dict):
        raise FileProblems([Problem(file, *locations[()], "(document)", "expected a mapping of keys at the top level")])
    try:
        return model.model_validate(data, context=context)
    except ValidationError as exc:
        raise FileProblems(problems_from_validation(exc, locations, file)) from None


def read_text(path: str | Path) -> str:
    """A user's file as text; unreadable files are a located problem too."""
    try:
        return Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise FileProblems([Problem(str(path), 1, 1, "(file)", f"cannot read: {exc}")]) from None


def validate_file(path: str | Path, model: type[M], context: dict[str, Any] | None = None) -> M:
    """Read and validate a YAML file."""
    return validate_text(read_text(path), model, str(path), context)


def problem_at(file: str | Path, field_path: tuple, message: str) -> Problem:
    """A located problem for a field of a file already known to parse (e.g. a cross-file check)."""
    try:
        _, locations = load_yaml(read_text(file), str(file))
    except FileProblems:
        locations = {}
    line, col = locate(tuple(field_path), locations)
    return Problem(str(file), line, col, _field_name(tuple(field_path)), message)
