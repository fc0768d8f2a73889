"""YAML files validated by pydantic, with every problem located as file:line:column: field.

PyYAML's composer gives each node its position; we keep a map from the path of keys and
indices to (line, column) and translate pydantic's error locations through it. Duplicate keys
are an error (PyYAML would silently keep the last). Only plain data is constructed (safe
loader): a procedure file cannot execute code.

A hostile file costs bounded time and memory: only regular files of at most
``MAX_FILE_BYTES`` are read, nesting stops at ``MAX_DEPTH`` levels, aliases may add at most
``ALIAS_BUDGET`` values beyond those written out (no "billion laughs"), and numbers are at most
``MAX_NUMBER_CHARS`` characters long.
"""

from __future__ import annotations

import difflib
import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar, get_args

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
NUMBER_TAGS = {"tag:yaml.org,2002:int", "tag:yaml.org,2002:float"}
MAX_FILE_BYTES = 256 * 1024  # a procedure with 10 000 listed points is about 250 KB; parsing 256 KiB takes ~3 s
MAX_DEPTH = 32  # procedures nest 4 levels deep
ALIAS_BUDGET = 10_000  # values that aliases may add beyond those written out
MAX_NUMBER_CHARS = 100
TIMESTAMP_TAG = "tag:yaml.org,2002:timestamp"
BOOL_TAG = "tag:yaml.org,2002:bool"
OCTAL = re.compile(r"[-+]?0[0-7_]+")  # YAML 1.1 reads 010 as 8


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing nesting beyond MAX_DEPTH before its recursive composer
    gets deep (a RecursionError otherwise), and counting the nodes written out. An unquoted date
    (``calibration_due: 2027-03-31``) is text, not a timestamp."""

    yaml_implicit_resolvers = {first: [(tag, regexp) for tag, regexp in resolvers if tag != TIMESTAMP_TAG]
                               for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}

    def __init__(self, text: str, file: str):
        super().__init__(text)
        self.file = file
        self.depth = 0
        self.nodes = 0

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            return super().compose_node(parent, index)
        self.depth += 1
        self.nodes += 1
        try:
            if self.depth > MAX_DEPTH:
                mark = self.peek_event().start_mark
                raise FileProblems([Problem(self.file, mark.line + 1, mark.column + 1, "(document)",
                                            f"nesting deeper than {MAX_DEPTH} levels")])
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1


class _Walk:
    """State of one walk over a composed document: where each key path is, how many values
    may still be built (aliases share nodes, so expanding them could multiply without end)."""

    def __init__(self, file: str, written_nodes: int):
        self.file = file
        self.locations: dict[Path_, tuple[int, int]] = {}
        self.budget = written_nodes + ALIAS_BUDGET
        self.constructor = yaml.SafeLoader("")

    def problem(self, node: yaml.Node, path: Path_, message: str) -> FileProblems:
        shown = _field_name(path[:8]) + ("…" if len(path) > 8 else "")
        return FileProblems([Problem(self.file, node.start_mark.line + 1, node.start_mark.column + 1, shown, message)])

    def scalar(self, node: yaml.ScalarNode, path: Path_) -> Any:
        """A scalar node's value by PyYAML's safe constructor (its tag is already resolved).

        YAML 1.1's surprises are read as YAML 1.2 reads them or refused: ``yes``/``no``/``on``/``off``
        are text (a number field refuses them; a true/false field takes them), ``1:30`` (base 60:
        90) and ``010`` (octal: 8) are refused with what they would have meant."""
        if node.tag == BOOL_TAG and node.value.lower() not in ("true", "false"):
            return node.value
        if node.tag in NUMBER_TAGS:
            if len(node.value) > MAX_NUMBER_CHARS:
                raise self.problem(node, path, f"a number of {len(node.value)} characters; at most {MAX_NUMBER_CHARS} are read")
            if ":" in node.value:
                raise self.problem(node, path, f"`{node.value}` reads as a base-60 number in YAML 1.1 (1:30 is 90); "
                                               "write a decimal number (e.g. 1.5), or quote it if it is text")
            if node.tag == "tag:yaml.org,2002:int" and OCTAL.fullmatch(node.value):
                raise self.problem(node, path, f"`{node.value}` has a leading zero, which YAML 1.1 reads as octal "
                                               f"({self.constructor.construct_object(node)}); write it without the leading zero")
        try:
            return self.constructor.construct_object(node, deep=True)
        except (ValueError, OverflowError) as exc:
            raise self.problem(node, path, f"not a usable number: {exc}") from None


def _walk(node: yaml.Node, path: Path_, w: _Walk) -> Any:
    out, file = w.locations, w.file
    out.setdefault(path, (node.start_mark.line + 1, node.start_mark.column + 1))  # a key keeps its own position
    w.budget -= 1
    if w.budget < 0:
        raise w.problem(node, path, f"aliases expand to more than {ALIAS_BUDGET} values beyond those written out; "
                                    "write the values out instead")
    if len(path) > MAX_DEPTH:
        raise w.problem(node, path, f"nesting deeper than {MAX_DEPTH} levels (a recursive alias?)")
    if node.tag not in PLAIN_TAGS:
        raise FileProblems([Problem(file, *out[path], _field_name(path), f"YAML tag {node.tag!r} is not allowed: plain data only")])
    if isinstance(node, yaml.MappingNode):
        result: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            key = w.scalar(key_node, path) if isinstance(key_node, yaml.ScalarNode) and key_node.tag in PLAIN_TAGS else None
            if not isinstance(key, (str, int, float, bool)) or key is None:
                raise FileProblems([Problem(file, key_node.start_mark.line + 1, key_node.start_mark.column + 1,
                                            _field_name(path), "keys must be plain scalars")])
            if key in result:
                line, col = key_node.start_mark.line + 1, key_node.start_mark.column + 1
                raise FileProblems([Problem(file, line, col, _field_name(path + (key,)),
                                            f"duplicate key (first given on line {out[path + (key,)][0]})")])
            out[path + (key,)] = (key_node.start_mark.line + 1, key_node.start_mark.column + 1)
            result[key] = _walk(value_node, path + (key,), w)
        return result
    if isinstance(node, yaml.SequenceNode):
        return [_walk(child, path + (i,), w) for i, child in enumerate(node.value)]
    return w.scalar(node, path)


def _char_name(character: int | str | bytes) -> str:
    return f"U+{character:04X}" if isinstance(character, int) else repr(character)


def _line_column(text: str, index: int) -> tuple[int, int]:
    line = text.count("\n", 0, index) + 1
    return line, index - (text.rfind("\n", 0, index) + 1) + 1


def load_yaml(text: str, file: str) -> tuple[Any, dict[Path_, tuple[int, int]]]:
    """Parse YAML text into plain data and a map of key paths to (line, column)."""
    if len(text) > MAX_FILE_BYTES:
        raise FileProblems([Problem(file, 1, 1, "(file)", f"{len(text)} characters; at most {MAX_FILE_BYTES} are read")])
    loader = None
    try:
        loader = _BoundedLoader(text, file)
        node = loader.get_single_node()
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line, col = (mark.line + 1, mark.column + 1) if mark else (1, 1)
        raise FileProblems([Problem(file, line, col, "(syntax)", str(exc.problem or exc).strip())]) from None
    except yaml.reader.ReaderError as exc:
        raise FileProblems([Problem(file, *_line_column(text, exc.position), "(syntax)",
                                    f"character {_char_name(exc.character)} is not allowed in YAML")]) from None
    except yaml.YAMLError as exc:
        raise FileProblems([Problem(file, 1, 1, "(syntax)", str(exc))]) from None
    finally:
        if loader is not None:
            loader.dispose()
    if node is None:
        return None, {(): (1, 1)}
    walk = _Walk(file, loader.nodes)
    return _walk(node, (), walk), walk.locations


def locate(path: Path_, locations: dict[Path_, tuple[int, int]]) -> tuple[int, int]:
    """Position of the deepest existing prefix of ``path`` (a missing key points at its parent)."""
    for cut in range(len(path), -1, -1):
        if path[:cut] in locations:
            return locations[path[:cut]]
    return (1, 1)


def _models_in(annotation: Any) -> list[type[BaseModel]]:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for arg in get_args(annotation) for m in _models_in(arg)]


def _keys_at(model: type[BaseModel] | None, path: Path_) -> list[str]:
    """The keys the model accepts at ``path`` (every alternative of a union), for suggestions."""
    current = [model] if model is not None else []
    for key in path:
        if isinstance(key, int):
            continue
        if any(key in c.model_fields for c in current):  # else a union's tag in pydantic's location: not a key
            current = [m for c in current if key in c.model_fields for m in _models_in(c.model_fields[key].annotation)]
    return sorted({name for m in current for name in m.model_fields})


def _unknown_key(model: type[BaseModel] | None, path: Path_) -> str:
    name = path[-1] if path and isinstance(path[-1], str) else ""
    close = difflib.get_close_matches(name, _keys_at(model, path[:-1]), n=1, cutoff=0.6)
    if close:
        return f"unknown key; did you mean `{close[0]}`?"
    return "unknown key (check the spelling; `rtcal schema` lists the keys)"


def problems_from_validation(exc: ValidationError, locations: dict[Path_, tuple[int, int]], file: str,
                             model: type[BaseModel] | None = None) -> list[Problem]:
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
            message = _unknown_key(model, tuple(p for p in err["loc"] if isinstance(p, (int, str))))
        elif err["type"] in ("int_parsing", "float_parsing", "bool_parsing") and isinstance(err.get("input"), str):
            message += f" (read `{err['input'][:40]}`)"
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
        raise FileProblems(problems_from_validation(exc, locations, file, model)) from None


def read_bytes(path: str | Path, max_bytes: int = MAX_FILE_BYTES) -> bytes:
    """A regular file of at most ``max_bytes``; anything else (a device such as /dev/zero, a
    pipe, a directory, a larger file) is a located problem, found without reading it."""
    flags = os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)  # O_NONBLOCK: opening a FIFO must not wait
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        raise FileProblems([Problem(str(path), 1, 1, "(file)", f"cannot read: {exc.strerror or exc}")]) from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            kind = "a directory" if stat.S_ISDIR(info.st_mode) else "a device, pipe or socket"
            raise FileProblems([Problem(str(path), 1, 1, "(file)", f"cannot read: {kind}, not a regular file")])
        if info.st_size > max_bytes:
            raise FileProblems([Problem(str(path), 1, 1, "(file)",
                                        f"{info.st_size} bytes; at most {max_bytes} are read (is it the right file?)")])
        chunks, size = [], 0
        while size <= max_bytes:
            try:
                chunk = os.read(fd, max_bytes + 1 - size)
            except OSError as exc:
                raise FileProblems([Problem(str(path), 1, 1, "(file)", f"cannot read: {exc.strerror or exc}")]) from None
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        if size > max_bytes:
            raise FileProblems([Problem(str(path), 1, 1, "(file)", f"more than {max_bytes} bytes; at most {max_bytes} are read")])
        return b"".join(chunks)
    finally:
        os.close(fd)


def read_text(path: str | Path) -> str:
    """A user's file as UTF-8 text; unreadable, oversized or non-regular files are located problems."""
    data = read_bytes(path)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise FileProblems([Problem(str(path), line, column, "(file)", "not UTF-8 text")]) from None


def problem_at(file: str | Path, field_path: tuple, message: str) -> Problem:
    """A located problem for a field of a file already known to parse (e.g. a cross-file check)."""
    try:
        _, locations = load_yaml(read_text(file), str(file))
    except FileProblems:
        locations = {}
    line, col = locate(tuple(field_path), locations)
    return Problem(str(file), line, col, _field_name(tuple(field_path)), message)
