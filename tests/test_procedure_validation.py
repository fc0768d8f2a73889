"""Bad procedure and scenario files: exit code 2 and `file:line:column: field: message`, no traceback."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from rtcal.cli import main

REPO = Path(__file__).resolve().parents[1]
GOOD = (REPO / "procedures" / "laser_tracer_multistation.yaml").read_text()

# (name, file text, marker: the text on the expected line (None: line 1), expected field, message text)
BAD_PROCEDURES = [
    ("unknown_key", GOOD.replace("samples_per_reading: 1", "samples_per_readin: 1"), "samples_per_readin", "samples_per_readin", "unknown key"),
    ("wrong_type", GOOD.replace("count: 11", "count: eleven"), "count: eleven", "stations.count", "integer"),
    ("too_few_stations", GOOD.replace("count: 11", "count: 3"), "count: 3", "stations.count", "greater than or equal to 4"),
    ("negative_settle", GOOD.replace("settle_time_s: 2.0", "settle_time_s: -1"), "settle_time_s", "settle_time_s", "greater than or equal to 0"),
    ("bad_order", GOOD.replace("order: point_major ", "order: random "), "order: random", "order", "point_major"),
    ("duplicate_key", GOOD.replace("samples_per_reading: 1", "samples_per_reading: 1\nsamples_per_reading: 2"), "samples_per_reading: 2", "samples_per_reading", "duplicate key"),
    ("syntax", GOOD.replace("  step_deg: 30", "  step_deg: [30"), "count: 11", "(syntax)", ""),
    ("unknown_method", GOOD.replace("method: laser_tracer_multistation", "method: laser_tracker"), "method: laser_tracker", "method", "unknown method"),
    ("missing_method", GOOD.replace("method: laser_tracer_multistation\n", ""), "name: RT400", "method", "required key is missing"),
    ("bad_backend", GOOD.replace("cmm: {backend: sim, tool: CatEye}", "cmm: {backend: simulated, tool: CatEye}"), "backend: simulated", "instruments.cmm.backend", "'sim'"),
    ("bad_lm_beta", GOOD.replace("beta: 0.55", "beta: 1.5"), "beta: 1.5", "solver.lm.beta", "less than 1"),
    ("too_few_points", GOOD.replace("layers: 4", "layers: 1").replace("columns: 4", "columns: 3"), "points:", "points", "n ≥ 16"),
    ("coplanar_points", GOOD.replace("volume_size_mm: [450, 600, 450]", "volume_size_mm: [450, 600, 0]"), "points:", "points", "coplanar"),
    ("bad_vector", GOOD.replace("volume_min_mm: [700, -300, 100]", "volume_min_mm: [700, -300]"), "volume_min_mm: [700", "points.volume_min_mm", "too few items"),
    ("full_turn", GOOD.replace("step_deg: 30", "step_deg: 40"), "stations:", "stations", "≥ 360°"),
    ("not_a_mapping", "- just\n- a list\n", None, "(document)", "mapping"),
]


@pytest.mark.parametrize("name,text,marker,field,needle", BAD_PROCEDURES, ids=[b[0] for b in BAD_PROCEDURES])
def test_bad_procedure_is_located(tmp_path, capsys, name, text, marker, field, needle):
    line = 1 if marker is None else next(k for k, t in enumerate(text.splitlines(), 1) if marker in t)
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    (tmp_path / "scenarios").mkdir()
    (tmp_path / "scenarios" / "paper000_bench.yaml").write_text("seed: 1\n")
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    pattern = re.compile(rf"^{re.escape(str(path))}:(\d+):(\d+): (.+?): (.*)$")
    matches = [pattern.match(e) for e in err]
    assert all(matches), err
    assert any(int(m.group(1)) == line and m.group(3).startswith(field) and needle in m.group(4) for m in matches), err
    # run gives the same located message and exit code
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()


BAD_SCENARIOS = [
    ("unknown_stage_key", "stage:\n  positioning_eror: []\n", 2, "stage.positioning_eror", "unknown key"),
    ("harmonic_unit", "stage:\n  positioning_error:\n    - {order: 1, amplitude_um: 4}\n", 3, "stage.positioning_error[0]", ""),
    ("negative_noise", "laser_tracer:\n  length_noise_um: -0.2\n", 2, "laser_tracer.length_noise_um", "greater than or equal to 0"),
    ("seed_text", "seed: seven\n", 1, "seed", "integer"),
]


@pytest.mark.parametrize("name,text,line,field,needle", BAD_SCENARIOS, ids=[b[0] for b in BAD_SCENARIOS])
def test_bad_scenario_is_located(tmp_path, capsys, name, text, line, field, needle):
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}:{line}:" in err and field in err and needle in err, err
    assert main(["run", str(REPO / "procedures" / "laser_tracer_multistation.yaml"), "--scenario", str(path),
                 "--out", str(tmp_path / "out")]) == 2


def test_shipped_files_validate(capsys):
    files = sorted(str(p) for p in (REPO / "procedures").rglob("*.yaml"))
    assert main(["validate", *files]) == 0


def test_an_unquoted_date_is_text(tmp_path, capsys):
    """`calibration_due: 2027-03-31` as a person writes it (YAML 1.1 made it a timestamp, which was
    refused); a date that does not exist is refused where it is written."""
    path = tmp_path / "p.yaml"
    path.write_text("method: laser_tracer_multistation\nmetadata:\n  instruments:\n"
                    "    cmm: {id: CMM-1, calibration_due: 2027-03-31}\n")
    assert main(["validate", str(path)]) == 0
    path.write_text(path.read_text().replace("2027-03-31", "2027-02-30"))
    assert main(["validate", str(path)]) == 2
    assert f"{path}:4:" in capsys.readouterr().err


def test_yaml_cannot_execute_code(tmp_path, capsys):
    path = tmp_path / "evil.yaml"
    path.write_text("method: !!python/object/apply:os.system ['echo pwned']\n")
    assert main(["validate", str(path)]) == 2
    assert "pwned" not in capsys.readouterr().out


def test_missing_file_is_a_located_error(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.yaml")]) == 2
    assert "cannot read" in capsys.readouterr().err


def test_schema_is_json_schema_with_the_procedure_keys(capsys):
    assert main(["schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert set(schema["discriminator"]["mapping"]) == {"laser_tracer_multistation", "encoder_abbe_error", "rtest"}
    multistation = schema["$defs"]["LaserTracerMultistation"]["properties"]
    assert {"method", "stations", "points", "order", "solver", "instruments"} <= set(multistation)
    assert {"steps", "polygon", "geometry"} <= set(schema["$defs"]["EncoderAbbeError"]["properties"])
    assert main(["schema", "--scenario"]) == 0
    assert {"seed", "stage", "cmm", "laser_tracer"} <= set(json.loads(capsys.readouterr().out)["properties"])


def test_no_traceback_for_user_errors_in_a_fresh_process(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(GOOD.replace("count: 11", "count: many"))
    proc = subprocess.run([sys.executable, "-m", "rtcal.cli", "run", str(path)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and "stations.count" in proc.stderr
