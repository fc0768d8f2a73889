"""What a method's planner works on (``Method.planner``, used by `rtcal plan`): a candidate plan as the
procedure's and the bench's YAML data, and the changes that made it, in words; and a proposed
procedure written beside its bench."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rtcal.outputs import write_output
from rtcal.procedure.yamlfile import read_text


@dataclass(frozen=True)
class Candidate:
    """A candidate: the procedure's and the bench's YAML data, and what was changed, in words."""

    procedure: dict[str, Any]
    bench: dict[str, Any]
    changes: tuple[str, ...] = ()


def bench_file_beside(out_path: Path) -> Path:
    """Where a procedure written to ``out_path`` gets its own bench: ``<stem>.bench.yaml`` beside it."""
    return out_path.with_name(f"{out_path.stem}.bench.yaml")


def keep_bench(procedure_path: Path, data_yaml: dict[str, Any], out_path: Path) -> Path | None:
    """Point ``data_yaml["bench"]`` (read from ``procedure_path``) at the same bench from ``out_path``'s
    folder (a procedure reads no bench outside its folder): a relative path when the bench is inside
    that folder, else a copy beside the new file, which is returned (to be named on the console)."""
    if not data_yaml.get("bench"):
        return None
    bench_file = (procedure_path.parent / data_yaml["bench"]).resolve()
    folder = out_path.resolve().parent
    if os.path.commonpath([folder, bench_file]) == str(folder):
        data_yaml["bench"] = os.path.relpath(bench_file, folder)
        return None
    copy = write_output(bench_file_beside(out_path), read_text(bench_file))
    data_yaml["bench"] = copy.name
    return copy
