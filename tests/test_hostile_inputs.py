"""Hostile procedure and scenario texts: each gives exit 2 and one located message naming the
field, for `validate` and for `run` (which must leave no store), within 30 s and 2 GB — the
reader's limits (aliases, depth, size, non-regular files, number length), the models' bounds
and finiteness, the bench rule, and the hints for misspelt keys and swapped files."""

from __future__ import annotations

import resource
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from rtcal.cli import main

REPO = Path(__file__).resolve().parents[1]
BASE = (REPO / "procedures" / "laser_tracer_multistation.yaml").read_text()
LAUGHS = "".join(f"{c}: &{c} [{', '.join([f'*{p}'] * 9) if p else ', '.join(['x'] * 9)}]\n"
                 for p, c in zip(["", "a", "b", "c", "d", "e", "f", "g"], "abcdefgh"))


def _edit(old: str, new: str) -> str:
    assert old in BASE, old
    return BASE.replace(old, new, 1)


# (file text, where (line:column: field), what the message says)
CASES = {
    "billion_laughs": ("method: laser_tracer_multistation\n" + LAUGHS, "aliases expand to more than"),
    "deep_nesting": ("method: laser_tracer_multistation\nname: " + "[" * 500 + "]" * 500 + "\n", "nesting deeper than 32"),
    "bench_device": (_edit("bench: scenarios/paper000_bench.yaml", "bench: /dev/zero"), "bench: '/dev/zero' lies outside"),
    "bench_escape": (_edit("bench: scenarios/paper000_bench.yaml", "bench: ../../../../etc/passwd"), "lies outside the procedure's folder"),
    "infinite_settle": (_edit("settle_time_s: 2.0", "settle_time_s: .inf"), "settle_time_s: Input should be a finite number"),
    "nan_settle": (_edit("settle_time_s: 2.0", "settle_time_s: .nan"), "settle_time_s: Input should be a finite number"),
    "huge_integer": (_edit("samples_per_reading: 1", "samples_per_reading: " + "9" * 5000),
                     "samples_per_reading: a number of 5000 characters"),
    "mathtext_name": (_edit("name: RT400 rotary table on a CMM, laser tracer multi-station calibration", 'name: "$\\\\frac{"'), "name: no `$`"),
    "stations_beyond_limit": (_edit("  count: 11", "  count: 3000"), "stations.count: Input should be less than or equal to"),
    "misspelt_key": (_edit("  count: 11", "  cont: 11"), "stations.cont: unknown key; did you mean `count`?"),
    "misspelt_section": (_edit("settle_time_s: 2.0", "settle_time_s: 2.0\nsolvr: {}"), "solvr: unknown key; did you mean `solver`?"),
}


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    shutil.copytree(REPO / "procedures" / "scenarios", tmp_path / "scenarios")
    for name, (text, _) in CASES.items():
        (tmp_path / f"{name}.yaml").write_text(text, encoding="utf-8")
    return tmp_path


@pytest.mark.parametrize("name", sorted(CASES))
def test_validate_and_run_refuse_with_a_located_message(folder, name, capsys):
    path = folder / f"{name}.yaml"
    expected = CASES[name][1]
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"{path}:") and expected in err, err
    assert err.split(":")[1].isdigit() and err.split(":")[2].isdigit(), err  # line and column
    out = folder / f"run-{name}"
    assert main(["run", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert expected in err and "Traceback" not in err, err
    assert not (out / "run.sqlite").exists()


def test_all_in_bounded_time_and_memory(folder):
    """The whole set through `rtcal validate` in one process limited to 2 GB, within 30 s."""
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))

    files = [str(folder / f"{name}.yaml") for name in sorted(CASES)]
    done = subprocess.run([sys.executable, "-m", "rtcal.cli", "validate", *files], capture_output=True, text=True,
                          timeout=30, preexec_fn=limit)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert all(f in done.stderr for f in files), done.stderr


def test_swapped_procedure_and_scenario_are_named(folder, capsys):
    """(`validate` takes either kind of file; `run` wants a procedure and a --scenario.)"""
    proc = REPO / "procedures" / "laser_tracer_multistation.yaml"
    bench = REPO / "procedures" / "scenarios" / "paper000_bench.yaml"
    assert main(["run", str(bench), "--out", str(folder / "x")]) == 2
    assert "this is a bench scenario, not a procedure: give it with `--scenario`" in capsys.readouterr().err
    assert main(["run", str(proc), "--scenario", str(proc), "--out", str(folder / "x")]) == 2
    assert "this is a procedure, not a bench scenario" in capsys.readouterr().err


def test_every_command_argument_is_described():
    """`--help` of every subcommand says what each argument is."""
    import argparse

    from rtcal.cli import build_parser

    missing = []

    def walk(parser: argparse.ArgumentParser, prefix: list[str]) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, prefix + [name])
            elif not isinstance(action, argparse._HelpAction) and not action.help:
                missing.append(" ".join(prefix + [action.dest]))

    walk(build_parser(), ["rtcal"])
    assert not missing, missing


def test_every_field_is_described():
    """Every property of the procedure and scenario JSON Schemas carries a description."""
    import json

    from rtcal.methods import procedure_schema
    from simulators.scenario_file import scenario_schema

    missing = []

    def walk(schema: dict, where: str) -> None:
        for name, prop in schema.get("properties", {}).items():
            if not prop.get("description"):
                missing.append(f"{where}.{name}")
        for name, sub in schema.get("$defs", {}).items():
            walk(sub, name)

    walk(json.loads(procedure_schema()), "procedure")
    walk(json.loads(scenario_schema()), "scenario")
    assert not missing, missing
