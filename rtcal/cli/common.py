"""What every command shares: exit codes, the one-line user error, the parser class, option types
and the few output helpers. No domain logic: commands call into the package."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any, NoReturn

from rtcal.outputs import is_disk_failure
from rtcal.procedure.yamlfile import FileProblems
from rtcal.errors import UserError  # noqa: F401  (re-exported: the CLI's modules and tests import it here)

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_NOT_CONVERGED = 0, 1, 2, 3
EXIT_INTERRUPTED = 130
MAX_SEED = 2**63 - 1


class Parser(argparse.ArgumentParser):
    """argparse with its mistakes on one line (what, and where to read more), exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: {message} (see `{self.prog} --help`)\n")


def seed(text: str) -> int:
    """``--seed``: a whole number 0 … 2⁶³ − 1 (numpy's generators take no negative seeds)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"{text} is outside 0 … {MAX_SEED}")
    return value


def one_line(text: object) -> str:
    return " ".join(str(text).split())


def disk_failure(exc: OSError, folder: str | Path | None = None) -> str:
    """One line for a write the disk refused: what, where, and that it is the disk's doing."""
    where = f"{exc.filename}: " if exc.filename else (f"in {folder}: " if folder else "")
    return f"rtcal: the disk refused a write: {where}{exc.strerror or exc}"


def make_folder(folder: Path, option: str) -> None:
    """Create an output folder (and its parents); a path that cannot be one is the user's to change."""
    if os.path.lexists(folder) and not folder.is_dir():
        raise UserError(f"{option} {folder}: exists and is not a directory")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        if is_disk_failure(exc):
            raise
        raise UserError(f"{option} {folder}: cannot create: {exc.strerror or exc}") from None


def parse_instruments_option(text: str) -> dict[str, str]:
    """``--instruments``: a JSON object of name → address, inline or in a file."""
    from rtcal.procedure.yamlfile import read_text

    source = text
    if not text.lstrip().startswith("{"):
        try:
            source = read_text(text)
        except FileProblems as exc:
            raise UserError(f"--instruments: {exc.problems[0].file}: {exc.problems[0].message}") from None
    try:
        data = json.loads(source.strip().splitlines()[0] if source.strip() else "")
    except (json.JSONDecodeError, IndexError) as exc:
        raise UserError(f"--instruments: not a JSON object of instrument addresses ({exc})") from None
    except RecursionError:
        raise UserError("--instruments: not a JSON object of instrument addresses (nested too deeply)") from None
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise UserError("--instruments: expected a JSON object mapping instrument names to address strings")
    return data


def json_text(data: Any, indent: str = "") -> str:
    """JSON with a line per key and per row of a table (a list of objects), each line written by
    json's C encoder — ``indent=`` would send the whole document through its pure-Python one,
    which takes seconds for a table of 100 000 rows. Strict JSON: a NaN or infinity is null."""
    inner = indent + "  "
    if isinstance(data, dict) and data:
        items = ",\n".join(f"{inner}{json.dumps(str(k))}: {json_text(v, inner)}" for k, v in data.items())
        return "{\n" + items + "\n" + indent + "}"
    if isinstance(data, list) and data and all(isinstance(v, dict) for v in data):
        return "[\n" + ",\n".join(inner + _strict(v) for v in data) + "\n" + indent + "]"
    return _strict(data)


def _strict(data: Any) -> str:
    try:
        return json.dumps(data, allow_nan=False)
    except ValueError:  # a NaN or infinity somewhere (rare): each one null
        from rtcal.results.io import finite

        return json.dumps(finite(data), allow_nan=False)
