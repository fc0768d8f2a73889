"""A method written against rtcal.api alone runs end to end (issue 41, item 7): tests/plugins/ball_runout — a
dial indicator read at each target, its result in µm (not a positioning deviation), its own operator step
("mount the test ball"), its own context column (``ball_height_mm``), its indicator declared by kind under a
name of its own (``probe: {kind: dial_indicator}``) — in this process through the registry, and installed with
pip into a fresh environment, simulated in process and through `rtcal sim serve`'s addresses."""

from __future__ import annotations

import json
import signal
import sqlite3
import subprocess
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np
import pytest

import rtcal.methods as methods
from rtcal.procedure.yamlfile import FileProblems
from tests.test_plugins import venv_with_plugin

REPO = Path(__file__).resolve().parents[1]
PLUGIN = REPO / "tests" / "plugins" / "ball_runout"
BENCH = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"
PROCEDURE = """\
method: ball_runout
name: test ball runout (plugin)
instruments:
  stage: {backend: sim}
  probe: {kind: dial_indicator, backend: sim}
ball: {height_mm: 40}
steps: {targets_deg: [0, 60, 120, 180, 240, 300], runs: 3}
samples_per_reading: 2
settle_time_s: 0.5
"""


@pytest.fixture
def registry(monkeypatch):
    """This process's METHODS reading the sample's entry point as if it were installed; as it was after the test."""
    monkeypatch.syspath_prepend(str(PLUGIN))
    monkeypatch.setattr(methods, "entry_points", lambda group: [EntryPoint(
        "ball_runout", "rtcal_ball_runout:BallRunoutMethod", group)] if group == methods.ENTRY_POINT_GROUP else [])
    methods.METHODS.forget_plugins()
    yield methods.METHODS
    methods.METHODS.forget_plugins()


def _check_run(run_dir: Path, simulated: bool) -> dict:
    """What the run wrote: its µm result (within U of the bench's truth when simulated), no ISO 230-2 evaluation
    of it, the operator's step logged, and the ball's height beside every indicator reading in the store."""
    results = json.loads((run_dir / "results.json").read_text(encoding="utf-8"))
    assert results["method"] == "ball_runout" and results["recommended"] == "probe"
    e = results["estimates"]["probe"]
    assert (e["quantity"], e["unit"]) == ("radial displacement of the test ball", "µm") and len(e["value"]) == 12
    assert results["evaluation"] is None and "positioning_deviations" not in results and "conformity" not in results
    assert not (run_dir / "positioning_deviations.csv").exists() and (run_dir / "ball_runout.csv").exists()
    assert [ev["message"] for ev in results["events"] if ev["kind"] == "operator"] == ["test ball mounted at 40 mm"]
    assert results["ball_height_mm"] == 40.0
    x, U = np.array(e["value"], float), np.array(e["expanded_uncertainty"], float)
    if simulated:
        truth = np.array(results["truth"]["displacement_um"])
        assert np.ptp(truth) > 0.3, "the bench's table moves the ball radially"
        assert np.all(np.abs(x - truth) <= U + 0.02), (x - truth, U)
    with sqlite3.connect(run_dir / "run.sqlite") as db:
        contexts = {row[0] for row in db.execute("SELECT context FROM readings WHERE instrument = 'probe'")}
        meta = dict(db.execute("SELECT key, value FROM meta"))
    assert contexts == {json.dumps({"ball_height_mm": 40.0})}
    assert json.loads(meta["context_columns"]) == {"ball_height_mm": "the test ball's centre height above the table top, mm"}
    certificate = json.loads((run_dir / "certificate.json").read_text(encoding="utf-8"))
    assert certificate["deviations"] is None and certificate["parameters"] is None, "no positioning deviation is claimed"
    assert [t["heading"] for t in certificate["tables"]][0] == "Result: radial displacement of the test ball per target and direction"
    (brief,) = certificate["result_in_brief"]["rows"]
    assert brief["quantity"].startswith("radial displacement of the test ball") and brief["value_arcsec"].endswith("over 6 targets")
    assert " µm … " in brief["value_arcsec"] and brief["expanded_uncertainty_arcsec"].endswith(" µm")
    assert "roundness" in " ".join(certificate["result_in_brief"]["not_included"])
    html = (run_dir / "report.html").read_text(encoding="utf-8")
    assert "positioning deviation per target" not in html and "ISO 230-2:2014 parameters" not in html
    return results


def test_the_method_runs_reports_and_verifies_in_process(registry, tmp_path):
    from rtcal.methods import load_procedure
    from rtcal.run.runner import run_procedure
    from rtcal.run.verify import verify

    (tmp_path / "p.yaml").write_text(PROCEDURE)
    assert load_procedure(tmp_path / "p.yaml").instruments.probe.kind == "dial_indicator"
    run_procedure(tmp_path / "p.yaml", BENCH, out_dir=tmp_path / "run", show_progress=False)
    _check_run(tmp_path / "run", simulated=True)
    found = verify(tmp_path / "run", methods.METHODS)
    assert found.compared > 50 and not found.differences and not found.integrity


def test_its_instrument_is_declared_by_kind(registry, tmp_path):
    from rtcal.methods import load_procedure

    path = tmp_path / "p.yaml"
    path.write_text(PROCEDURE.replace("{kind: dial_indicator, backend: sim}", "{backend: sim}"))
    with pytest.raises(FileProblems, match=r"probe.kind: declare the probe's kind, `kind: dial_indicator`"):
        load_procedure(path)
    path.write_text(PROCEDURE.replace("kind: dial_indicator, backend: sim", "kind: dial_indicatr, backend: sim"))
    with pytest.raises(FileProblems, match=r"probe.kind: unknown kind 'dial_indicatr' \(known: stage, .*dial_indicator"):
        load_procedure(path)
    path.write_text(PROCEDURE.replace("backend: sim}\nball", "address: \"ipp://cmm:1294\"}\nball").replace(
        "stage: {backend: sim}", "stage: {address: \"modbus-tcp://h:502?unit=1\"}"))
    with pytest.raises(FileProblems, match=r"probe.address: a ipp address; the probe speaks serial"):
        load_procedure(path)


@pytest.mark.slow
def test_an_installed_method_plugin_runs_simulated_and_through_sim_serve(tmp_path):
    """A fresh venv that sees rtcal but not this process; the sample installed there with pip from its wheel; there
    `rtcal validate`, `rtcal run` and `rtcal verify` take its procedure simulated in process, then `rtcal sim serve`
    serves the bench and the run reaches the stage, a dial indicator (as its `probe`) and the simulated operator
    (who mounts the ball on the served bench) at the addresses it printed."""
    python = venv_with_plugin(PLUGIN, tmp_path)
    (tmp_path / "p.yaml").write_text(PROCEDURE)

    def rtcal(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([str(python), "-m", "rtcal.cli", *args], capture_output=True, text=True, timeout=300,
                              cwd=tmp_path)

    validated = rtcal("validate", "p.yaml")
    assert validated.returncode == 0 and validated.stdout.strip().endswith(": ok"), validated.stderr
    run = rtcal("run", "p.yaml", "--scenario", str(BENCH), "--out", "sim")
    assert run.returncode == 0, run.stderr
    assert "test ball runout: largest |displacement|" in run.stdout
    _check_run(tmp_path / "sim", simulated=True)
    verified = rtcal("verify", "sim")
    assert verified.returncode == 0 and "0 differ" in verified.stdout, verified.stdout + verified.stderr
    evaluated = rtcal("evaluate", "sim")
    assert evaluated.returncode == 2 and "no positioning_deviations" in evaluated.stderr, evaluated.stderr

    serve = subprocess.Popen([str(python), "-m", "rtcal.cli", "sim", "serve", "--scenario", str(BENCH), "--serial", "tcp",
                              "--no-pacing"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        assert serve.stdout is not None
        served = json.loads(serve.stdout.readline())
        addresses = {"stage": served["stage"], "probe": served["dial_indicator_1"], "operator": served["operator"]}
        (tmp_path / "a.json").write_text(json.dumps(addresses))
        wired = rtcal("run", "p.yaml", "--instruments", "a.json", "--virtual-clock", "--out", "wired")
    finally:
        serve.send_signal(signal.SIGTERM)
        serve.wait(30)
    assert wired.returncode == 0, wired.stderr
    results = _check_run(tmp_path / "wired", simulated=False)
    assert results["instruments"]["probe"].startswith("socket://") and "model=sylvac" in results["instruments"]["probe"]
    assert "truth" not in results
