"""results.json as one typed model: its published schema, its validation by every command that
reads a run, the method protocol, and that no consumer indexes results by string keys."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import jsonschema
import pytest

from rtcal.cli import main
from rtcal.methods import METHODS
from rtcal.methods.abbe.method import AbbeMethod
from rtcal.methods.multistation.method import MultistationMethod
from rtcal.methods.protocol import Method
from rtcal.methods import parse_results, read_results, results_schema
from rtcal.results import SCHEMA_VERSION, ResultsError
from rtcal.results.io import path_at

REPO = Path(__file__).resolve().parents[1]
SHIPPED = sorted((REPO / "procedures").glob("*.yaml"))


@pytest.fixture(scope="module")
def shipped_runs(tmp_path_factory) -> dict[str, Path]:
    """A run of every shipped procedure on its simulated bench."""
    base = tmp_path_factory.mktemp("shipped")
    runs = {}
    for procedure in SHIPPED:
        out = base / procedure.stem
        assert main(["run", str(procedure), "--out", str(out)]) == 0, procedure
        runs[procedure.stem] = out
    return runs


def _walk_properties(schema: dict) -> list[str]:
    """Every property of the schema (its definitions included) that has no description."""
    missing = []

    def walk(node: object, where: str) -> None:
        if isinstance(node, dict):
            for name, prop in (node.get("properties") or {}).items():
                if not isinstance(prop, dict) or not prop.get("description"):
                    missing.append(f"{where}.{name}")
            for key, sub in node.items():
                walk(sub, f"{where}/{key}")
        elif isinstance(node, list):
            for sub in node:
                walk(sub, where)

    walk(schema, "results")
    return missing


def test_schema_is_draft_2020_12_with_every_field_described(capsys):
    assert main(["schema", "--results"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert {"MultistationResults", "AbbeResults", "NetworkEstimate", "AbbeEstimate", "ClosureEstimate", "Evaluation",
            "DeviationTable", "Event", "UncertaintyBudget"} <= set(schema["$defs"])
    assert _walk_properties(schema) == []
    jsonschema.Draft202012Validator.check_schema(schema)


def test_the_schema_validates_every_shipped_procedures_results(shipped_runs, capsys):
    assert main(["schema", "--results"]) == 0
    validator = jsonschema.Draft202012Validator(json.loads(capsys.readouterr().out))
    for name, run in shipped_runs.items():
        data = json.loads((run / "results.json").read_text())
        assert data["schema_version"] == SCHEMA_VERSION
        errors = [f"{'.'.join(map(str, e.absolute_path))}: {e.message}" for e in validator.iter_errors(data)]
        assert errors == [], (name, errors[:3])
        results = read_results(run)  # and the model reads back what it wrote, value for value
        assert json.loads(json.dumps(results.model_dump(mode="json"))) == data
        assert all(st.status != "failed" for st in results.solver_status.values()), (name, results.solver_status)


def test_a_file_from_before_schema_version_reads_as_1_0(shipped_runs, tmp_path):
    data = json.loads((shipped_runs["encoder_abbe_error"] / "results.json").read_text())
    del data["schema_version"]
    assert parse_results(json.dumps(data)).schema_version == "1.0"
    data["schema_version"] = "2.0"
    with pytest.raises(ResultsError, match=r"schema_version: String should match"):
        parse_results(json.dumps(data), "x/results.json")


def _nest(depth: int) -> str:
    return "[" * depth + "]" * depth


# (what is done to results.json, the path the message must name)
TAMPERING = [
    ("missing key", lambda d: d.pop("estimates"), "estimates: Field required"),
    ("missing nested key", lambda d: d["positioning_deviations"].pop("run"), "positioning_deviations.run: Field required"),
    ("wrong type", lambda d: d.__setitem__("raw_readings", "many"), "raw_readings: Input should be a valid integer"),
    ("wrong nested type", lambda d: d["estimates"]["network"]["cumulative_deviation_arcsec"].__setitem__(3, "x"),
     "estimates.network.cumulative_deviation_arcsec.3: Input should be a valid number"),
    ("huge number", lambda d: d["positioning_deviations"]["deviation_arcsec"].__setitem__(2, 1e200),
     "positioning_deviations.deviation_arcsec.2: Input should be less than or equal to 10000000"),
    ("huge negative number", lambda d: d["estimates"]["network"]["cumulative_uncertainty_arcsec"].__setitem__(1, -1e200),
     "estimates.network.cumulative_uncertainty_arcsec.1: Input should be greater than or equal to 0"),
    ("unknown key", lambda d: d["positioning_deviations"].__setitem__("extra", 1), "positioning_deviations.extra: Extra inputs"),
    ("unknown method", lambda d: d.__setitem__("method", "nope"), "method: Input tag 'nope'"),
    ("rows of unequal length", lambda d: d["positioning_deviations"]["direction"].pop(),
     "positioning_deviations: direction has 10 rows, target_deg 11"),
]
TEXT_TAMPERING = [
    ("NaN", lambda t: t.replace('"measurement_duration_s": ', '"measurement_duration_s": NaN, "x": ', 1),
     "measurement_duration_s: Input should be a finite number"),
    ("Infinity", lambda t: re.sub(r'("cumulative_deviation_arcsec": \[\s*)[^,\]]+', r"\1Infinity", t, count=1),
     "estimates.paper.cumulative_deviation_arcsec.0: Input should be a finite number"),
    ("deep nesting", lambda t: t.replace('"events": [', '"events": [' + _nest(100_000) + ",", 1),
     "events.0.0.0.0"),
    ("integer too long", lambda t: t.replace('"raw_readings": ', '"raw_readings": 1' + "0" * 5000 + ", \"y\": ", 1),
     "raw_readings: not valid JSON: number out of range"),
    ("not JSON", lambda t: t[:10], "not valid JSON"),
    ("not an object", lambda t: "[1, 2]", "(document): Input should be an object"),
]


def _tampered(run: Path, tmp_path: Path, name: str) -> Path:
    """A copy of ``run`` to tamper with (its store too: resume reads it)."""
    copy = tmp_path / name.replace(" ", "_")
    shutil.copytree(run, copy, ignore=shutil.ignore_patterns("*.png", "*.pdf", "*.html"))
    return copy


COMMANDS = [
    lambda run, tmp: ["evaluate", str(run)],
    lambda run, tmp: ["compensate", str(run), "--format", "linuxcnc", "--out", str(tmp / "c.comp")],
    lambda run, tmp: ["compare", str(run), str(run), "--out", str(tmp)],
    lambda run, tmp: ["resume", str(run)],
]


def _refused(argv: list[str], capsys, path: str, expect: str) -> None:
    capsys.readouterr()
    assert main(argv) == 2, argv
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err[:500]
    assert f"{path}: {expect}" in err, (argv[0], err[:300])


@pytest.mark.parametrize("what, tamper, expect", TAMPERING, ids=[t[0] for t in TAMPERING])
def test_every_command_refuses_a_tampered_results_file(shipped_runs, tmp_path, capsys, what, tamper, expect):
    """Every command that reads a run: exit 2, one line naming the file and the field."""
    run = _tampered(shipped_runs["laser_tracer_multistation"], tmp_path, what)
    data = json.loads((run / "results.json").read_text())
    tamper(data)
    (run / "results.json").write_text(json.dumps(data))
    for command in COMMANDS:
        _refused(command(run, tmp_path), capsys, str(run / "results.json"), expect)


@pytest.mark.parametrize("what, tamper, expect", TEXT_TAMPERING, ids=[t[0] for t in TEXT_TAMPERING])
def test_every_command_refuses_a_malformed_results_file(shipped_runs, tmp_path, capsys, what, tamper, expect):
    run = _tampered(shipped_runs["laser_tracer_multistation"], tmp_path, what)
    (run / "results.json").write_text(tamper((run / "results.json").read_text()))
    for command in COMMANDS:
        _refused(command(run, tmp_path), capsys, str(run / "results.json"), expect)


def test_an_oversized_or_special_results_file_is_refused(shipped_runs, tmp_path, capsys, monkeypatch):
    import os

    import rtcal.results.io as results_io

    run = _tampered(shipped_runs["encoder_abbe_error"], tmp_path, "big")
    monkeypatch.setattr(results_io, "MAX_RESULTS_BYTES", 1000)
    _refused(["evaluate", str(run)], capsys, str(run / "results.json"), "larger than")
    monkeypatch.undo()
    (run / "results.json").unlink()
    os.mkfifo(run / "results.json")  # would block a plain open
    _refused(["evaluate", str(run)], capsys, str(run / "results.json"), "not a regular file")


def test_path_at_names_the_key_path_of_an_offset():
    text = '{"a": {"b": [1, {"c": [2, 3, 4'
    assert path_at(text, len(text)) == "a.b.1.c.2"
    assert path_at('{"x\\"y": [', 100) == 'x\\"y.0'


def test_both_methods_implement_the_protocol():
    for method in (MultistationMethod(), AbbeMethod()):
        assert isinstance(method, Method)
    assert set(METHODS) == {"laser_tracer_multistation", "encoder_abbe_error", "rtest"}
    assert all(isinstance(m, Method) and m.name == key for key, m in METHODS.items())


def test_method_modules_hold_no_outputs():
    """Figures, report sections, CSV writers and console text live in each method's outputs module."""
    for module in ("multistation", "abbe"):
        text = (REPO / "rtcal" / "methods" / module / "method.py").read_text()
        for word in ("matplotlib", "plt.", "csv.writer", "def report_body", "def summary", "def write_files",
                     "def method_text", "def certificate_figures"):
            assert word not in text, (module, word)


STRING_KEY_ACCESS = re.compile(r'results\["|results\.get\(|\best\["|\["estimates"\]|\["truth"\]|\["solver_status"\]|'
                               r'\["positioning_deviations"\]|\["cumulative_[a-z_]+"\]|analysis(\["|\.get\()')


def test_no_consumer_indexes_results_by_string_keys():
    """Outside the results model's own (de)serialisation, results are read through the model."""
    found = []
    for path in sorted((REPO / "rtcal").rglob("*.py")):
        if path.is_relative_to(REPO / "rtcal" / "results"):
            continue
        for k, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if STRING_KEY_ACCESS.search(line):
                found.append(f"{path.relative_to(REPO)}:{k}: {line.strip()}")
    assert found == []
