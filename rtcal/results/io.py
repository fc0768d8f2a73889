"""results.json on disk: written from the model, read back validated, and its JSON Schema.

Reading is bounded (file size; pydantic's JSON parser limits nesting and refuses NaN and
numbers out of range) and every problem is one :class:`ResultsError` line naming the file and
the offending field's path, e.g. ``runs/x/results.json: estimates.network.radius_mm: …``. The model
is the results model of the method the file's ``method`` names, among the ``models`` the caller
passes (the registry of methods does: :func:`rtcal.methods.read_results`).
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
from collections.abc import Mapping
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, Union

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError
from pydantic_core import ErrorDetails

from rtcal.results.model import RunResults

FILENAME = "results.json"
MAX_RESULTS_BYTES = 200_000_000  # read whole: bounded


ResultsModels = Mapping[str, type[RunResults]]
"""Each method's results model, by the ``method`` results.json names."""


def _adapter(models: ResultsModels) -> TypeAdapter[RunResults]:
    """results.json as one of ``models``, told apart by ``method``."""
    return _adapter_of(tuple(models.values()))


@lru_cache(maxsize=4)
def _adapter_of(models: tuple[type[RunResults], ...]) -> TypeAdapter[RunResults]:
    union: Any = Annotated[Union[models], Field(discriminator="method")]  # built at run time from the registry
    return TypeAdapter(union)


class ResultsError(ValueError):
    """A results.json that cannot be used; the message names the file and the field."""


def finite(data: Any) -> Any:
    """``data`` with every NaN and ±infinity (in lists and dicts too) as None: strict JSON has no
    such numbers, and ``json.dumps(..., allow_nan=False)`` then holds."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {k: finite(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [finite(v) for v in data]
    return data


def results_json(results: RunResults) -> str:
    """The file's text: the model's keys, JSON with no NaN, two-space indents."""
    return json.dumps(results.model_dump(mode="json"), indent=2, allow_nan=False) + "\n"


def write_results(run_dir: Path, results: RunResults) -> Path:
    path = Path(run_dir) / FILENAME
    path.write_text(results_json(results), encoding="utf-8")
    return path


def read_results(run_dir: str | Path, models: ResultsModels) -> RunResults:
    """The validated results of a run directory; :class:`ResultsError` names what is wrong."""
    path = Path(run_dir) / FILENAME
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # a FIFO planted as results.json must not block
    except OSError as exc:
        raise ResultsError(f"{path}: cannot read: {exc.strerror or exc}") from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):  # a folder opens too, and fdopen would refuse it with the fd's number
        os.close(fd)
        raise ResultsError(f"{path}: not a regular file")
    with os.fdopen(fd, "rb") as fh:
        if st.st_size > MAX_RESULTS_BYTES:
            raise ResultsError(f"{path}: larger than {MAX_RESULTS_BYTES // 1_000_000} MB: not a results file rtcal wrote")
        try:
            data = fh.read(MAX_RESULTS_BYTES + 1)
        except OSError as exc:
            raise ResultsError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if len(data) > MAX_RESULTS_BYTES:
        raise ResultsError(f"{path}: larger than {MAX_RESULTS_BYTES // 1_000_000} MB: not a results file rtcal wrote")
    return parse_results(data, models, str(path))


class _Named(BaseModel):
    """What results.json names first of all: its method (everything else read by that method's model)."""

    model_config = ConfigDict(extra="ignore")
    method: str


@lru_cache(maxsize=8)
def _adapter_one(model: type[RunResults]) -> TypeAdapter[RunResults]:
    return TypeAdapter(model)


def _named_model(data: bytes | str, models: ResultsModels) -> type[RunResults] | None:
    """The results model of the method the file names (only that method is loaded), or None: no method one of
    ``models`` knows is named (then every model is asked, for the message)."""
    try:
        name = TypeAdapter(_Named).validate_json(data).method
    except ValidationError:
        return None
    return models[name] if name in models else None


def parse_results(data: bytes | str, models: ResultsModels, where: str = FILENAME) -> RunResults:
    """Validate the text of a results.json (``where`` names it in messages) by the model of the method it names."""
    model = _named_model(data, models)
    try:
        return (_adapter_one(model) if model is not None else _adapter(models)).validate_json(data, strict=True)
    except ValidationError as exc:
        told_apart = models if model is None else {}  # the union's errors start with the method's tag, one model's do not
        raise ResultsError(f"{where}: {_printable(_first_problem(exc.errors(), data, told_apart))}") from None


def _printable(text: str, limit: int = 400) -> str:
    """One line a terminal shows as it is: control, invisible and bidi characters escaped, bounded."""
    text = "".join(c if c.isprintable() else f"\\u{ord(c):04x}" for c in text)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _first_problem(errors: list[ErrorDetails], data: bytes | str, models: ResultsModels) -> str:
    e = errors[0]
    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
    loc = list(e["loc"])
    if loc and loc[0] in models:
        loc = loc[1:]  # the method the file is told apart by, not a key of it
    msg = str(e["msg"]).removeprefix("Value error, ")
    if e["type"] == "json_invalid":
        text = data.decode("utf-8", errors="replace") if isinstance(data, bytes) else data
        where = _path_at_error(text, msg)
        return f"{where + ': ' if where else ''}not valid JSON: {msg.removeprefix('Invalid JSON: ')}"
    if e["type"] == "union_tag_invalid" or (e["type"] == "missing" and loc == []):
        return f"method: {msg}"
    path = ".".join(str(part) for part in loc) or "(document)"
    value = e.get("input")
    shown = f" (got {_short(value)})" if e["type"] not in ("missing", "extra_forbidden") and not isinstance(value, (dict, list)) else ""
    return f"{path}: {msg}{shown}{more}"


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "…"


def _path_at_error(text: str, message: str) -> str:
    """The key path at a parse error's ``line L column C`` (deep nesting, a number out of range)."""
    m = re.search(r"line (\d+) column (\d+)", message)
    if not m:
        return ""
    line, column = int(m.group(1)), int(m.group(2))
    lines = text.split("\n", line)
    offset = sum(len(s) + 1 for s in lines[: line - 1]) + column - 1
    return path_at(text, offset)


_TOKENS = re.compile(r'"(?:[^"\\]|\\.)*"?|[{}\[\],:]')


def path_at(text: str, offset: int, max_parts: int = 12) -> str:
    """The key path (``a.b.3``) of the JSON value at ``offset``: a scan of the text up to there."""
    stack: list[list[Any]] = []  # per open container: [bracket, key or index]
    key: str | None = None
    for m in _TOKENS.finditer(text, 0, min(offset, len(text))):
        token = m.group()
        if token[0] == '"':
            key = token[1:-1]
        elif token == ":" and stack and stack[-1][0] == "{":
            stack[-1][1] = key
        elif token == "," and stack:
            stack[-1][1] = stack[-1][1] + 1 if stack[-1][0] == "[" else None
        elif token in "{[":
            stack.append([token, 0 if token == "[" else None])
        elif token in "}]" and stack:
            stack.pop()
    parts = [str(p) for _, p in stack if p is not None]
    if len(parts) > max_parts:
        parts = parts[:max_parts] + [f"… ({len(parts) - max_parts} levels deeper)"]
    return ".".join(parts)


def results_schema(models: ResultsModels) -> str:
    """JSON Schema (draft 2020-12) of results.json, every field described."""
    schema = _adapter(models).json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "rtcal results.json"
    schema["description"] = ("The results of one rtcal run (schema_version 1.x): its metadata, every estimate with "
                             "its uncertainty budget, the positioning deviations, their evaluation and the run's log.")
    return json.dumps(schema, indent=2)
