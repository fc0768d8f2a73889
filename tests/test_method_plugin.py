"""A method is one seam: the registry (rtcal.methods.METHODS) reads installed packages' entry points
in the group ``rtcal.methods``, and a third method from a package (tests/plugins/toy_method: the
table's deviation read from its own encoder against the command) validates, runs, reports and
verifies with no change to rtcal's files — in this process through the registry, and installed with
pip into a fresh environment through the `rtcal` command."""

from __future__ import annotations

import json
import subprocess
import sys
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np
import pytest

import rtcal.methods as methods
from rtcal.methods import load_procedure
from rtcal.procedure.yamlfile import FileProblems
from tests.test_plugins import venv_with_plugin

REPO = Path(__file__).resolve().parents[1]
PLUGIN = REPO / "tests" / "plugins" / "toy_method"
BENCH = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"
PROCEDURE = """\
method: encoder_vs_command
name: encoder against the command (plugin)
instruments: {stage: {backend: sim}, encoder: {backend: sim}}
steps: {targets_deg: [0, 60, 120, 180, 240, 300], runs: 2}
settle_time_s: 0.5
"""
CLAIMS_OF_OTHER_METHODS = ("autocollimator", "polygon", "laser tracer", "dial indicator", "cmm")


def _entry_points(*specs: tuple[str, str]) -> list[EntryPoint]:
    return [EntryPoint(name, value, methods.ENTRY_POINT_GROUP) for name, value in specs]


@pytest.fixture
def toy_registry(monkeypatch):
    """This process's METHODS reading the toy package's entry point (and a broken one, and one that would
    replace a built-in) as if they were installed; as it was after the test."""
    monkeypatch.syspath_prepend(str(PLUGIN))
    monkeypatch.setattr(methods, "entry_points", lambda group: _entry_points(
        ("encoder_vs_command", "rtcal_toy_method:EncoderVsCommandMethod"),
        ("broken_method", "rtcal_no_such_module:Method"),
        ("encoder_abbe_error", "rtcal_toy_method:EncoderVsCommandMethod")) if group == methods.ENTRY_POINT_GROUP else [])
    monkeypatch.setattr(methods.METHODS, "_plugins", None)  # read again, through the entry points above
    monkeypatch.setattr(methods.METHODS, "broken", {})
    return methods.METHODS


def _check_results(results: dict, run_dir: Path) -> None:
    """The plugin's results: its method, deviations that match the simulated bench's truth within U, and a
    certificate that states only what this method did."""
    assert results["method"] == "encoder_vs_command" and results["recommended"] == "encoder"
    e = results["estimates"]["encoder"]
    x, U = np.array(e["cumulative_deviation_arcsec"]), np.array(e["cumulative_expanded_uncertainty_arcsec"])
    truth = np.array(results["truth"]["cumulative_deviation_arcsec"])
    assert len(x) == 12 and np.ptp(truth) > 10.0, "the bench's encoder sees the table's error"
    assert np.all(U[1:] > 0) and np.all(np.abs(x - truth) <= U + 1e-9), (x - truth, U)
    assert len(results["positioning_deviations"]["target_deg"]) == 24 and results["evaluation"] is not None
    checks = " ".join(results["control"]["checks"]).lower()
    assert "encoder" in checks and not any(word in checks for word in CLAIMS_OF_OTHER_METHODS), checks
    for name in ("report.md", "report.html"):
        text = (run_dir / name).read_text(encoding="utf-8").lower()
        assert "own encoder" in text and not any(w in text for w in ("autocollimator", "polygon")), name
    assert (run_dir / "report.pdf").stat().st_size > 0 and (run_dir / "encoder_deviation.png").stat().st_size > 0


def test_the_registry_reads_entry_points(toy_registry, tmp_path):
    assert list(toy_registry) == ["laser_tracer_multistation", "encoder_abbe_error", "rtest", "encoder_vs_command"]
    assert toy_registry["encoder_abbe_error"] is methods.ABBE, "a plugin never replaces a built-in method"
    assert "rtcal_no_such_module" in toy_registry.broken["broken_method"] and "broken_method" not in toy_registry
    path = tmp_path / "p.yaml"
    path.write_text(PROCEDURE.replace("encoder_vs_command", "broken_method"))
    with pytest.raises(FileProblems, match=r"unknown method 'broken_method' \(its plugin failed to load: .*rtcal_no_such_module"):
        load_procedure(path)
    path.write_text(PROCEDURE)
    assert type(load_procedure(path)).__name__ == "EncoderVsCommand"


def test_without_the_plugin_the_method_is_unknown(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text(PROCEDURE)
    with pytest.raises(FileProblems, match="unknown method 'encoder_vs_command'; one of: encoder_abbe_error"):
        load_procedure(path)


@pytest.mark.slow
def test_a_plugin_method_runs_reports_and_verifies_in_process(toy_registry, tmp_path):
    from rtcal.methods import read_results
    from rtcal.run.runner import run_procedure
    from rtcal.run.verify import verify

    (tmp_path / "p.yaml").write_text(PROCEDURE)
    outcome = run_procedure(tmp_path / "p.yaml", BENCH, out_dir=tmp_path / "run", show_progress=False)
    _check_results(json.loads((tmp_path / "run" / "results.json").read_text()), tmp_path / "run")
    assert type(read_results(tmp_path / "run")).__name__ == "EncoderResults" == type(outcome.results).__name__
    found = verify(tmp_path / "run", methods.METHODS)
    assert found.compared > 100 and not found.differences and not found.integrity


@pytest.mark.slow
def test_an_installed_method_plugin_validates_runs_and_verifies(tmp_path):
    """A fresh venv that sees rtcal (and its dependencies) but not this test's process; the toy method
    installed into it with pip from a wheel of tests/plugins/toy_method; there `rtcal validate`, `rtcal
    run` (simulated) and `rtcal verify` take a procedure of that method."""
    python = venv_with_plugin(PLUGIN, tmp_path)
    procedure = tmp_path / "encoder.yaml"
    procedure.write_text(PROCEDURE)

    def rtcal(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([str(python), "-m", "rtcal.cli", *args], capture_output=True, text=True, timeout=300,
                              cwd=tmp_path)

    validated = rtcal("validate", str(procedure))
    assert validated.returncode == 0 and validated.stdout.strip().endswith(": ok"), validated.stderr
    bad = tmp_path / "bad.yaml"
    bad.write_text(PROCEDURE.replace("runs: 2", "runs: 0"))
    refused = rtcal("validate", str(bad))
    assert refused.returncode == 2 and "steps.runs" in refused.stderr and "Traceback" not in refused.stderr, refused.stderr
    run = rtcal("run", str(procedure), "--scenario", str(BENCH), "--out", str(tmp_path / "run"))
    assert run.returncode == 0, run.stderr
    assert "encoder − command: largest |deviation|" in run.stdout
    _check_results(json.loads((tmp_path / "run" / "results.json").read_text()), tmp_path / "run")
    verified = rtcal("verify", str(tmp_path / "run"))
    assert verified.returncode == 0 and "0 differ" in verified.stdout, verified.stdout + verified.stderr
