"""`rtcal run` end to end on the simulated bench, through the CLI, into a real run directory."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rtcal.cli import main

REPO = Path(__file__).resolve().parents[1]
PROCEDURE = REPO / "procedures" / "laser_tracer_multistation.yaml"
NOISE_FREE = REPO / "tests" / "data" / "noise_free_bench.yaml"


@pytest.fixture(scope="module")
def noise_free_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run") / "noise_free"
    assert main(["run", str(PROCEDURE), "--scenario", str(NOISE_FREE), "--out", str(out)]) == 0
    return out


def test_run_directory_holds_every_output(noise_free_run):
    for name in ("results.json", "deviations.csv", "deviation.png", "report.md", "run.sqlite"):
        assert (noise_free_run / name).stat().st_size > 0, name


def test_results_contract(noise_free_run):
    r = json.loads((noise_free_run / "results.json").read_text())
    assert r["nominal_angles_deg"] == [-145.0 + 30.0 * k for k in range(11)]
    paper = r["estimates"]["paper"]
    assert len(paper["deviation_arcsec"]) == 10
    assert isinstance(paper["eq34_sigma_arcsec"], float) and isinstance(paper["algorithm_error_arcsec"], float)
    assert len(r["truth"]["deviation_arcsec"]) == 10
    assert r["raw_readings"] == 704


@pytest.mark.parametrize("estimator", ["paper", "shared_dead_path"])
def test_noise_free_run_recovers_injected_deviations(noise_free_run, estimator):
    """No noise anywhere, εz + reversal + a 22″ axis tilt: every estimator is exact to 0.01″."""
    r = json.loads((noise_free_run / "results.json").read_text())
    err = np.array(r["estimates"][estimator]["deviation_arcsec"]) - np.array(r["truth"]["deviation_arcsec"])
    assert np.max(np.abs(err)) < 0.01


def test_store_keeps_every_raw_reading_with_its_state(noise_free_run):
    db = sqlite3.connect(noise_free_run / "run.sqlite")
    n_len = db.execute("SELECT COUNT(*) FROM readings WHERE instrument='laser_tracer' AND plan_index IS NOT NULL").fetchone()[0]
    assert n_len == 704
    # and the tracer measured again at its reference point at the end of the pass (no plan index: not planned)
    assert db.execute("SELECT COUNT(*) FROM readings WHERE quantity='return_length_mm' AND plan_index IS NULL").fetchone()[0] == 1
    pairs = db.execute("SELECT COUNT(DISTINCT point || ',' || station) FROM readings WHERE instrument='laser_tracer'").fetchone()[0]
    assert pairs == 704  # each planned reading exactly once
    assert db.execute("SELECT COUNT(*) FROM readings WHERE instrument='cmm' AND quantity LIKE 'position%'").fetchone()[0] == 64 * 3
    # and the checks' readings: the CMM's position and the stage's feedback before and after every reading
    assert db.execute("SELECT COUNT(*) FROM readings WHERE instrument='cmm' AND quantity LIKE 'check%'").fetchone()[0] == (704 - 64) * 3
    assert db.execute("SELECT COUNT(*) FROM readings WHERE instrument='cmm' AND quantity LIKE 'after%'").fetchone()[0] == 704 * 3
    assert db.execute("SELECT COUNT(*) FROM readings WHERE instrument='stage' AND quantity='feedback_deg'").fetchone()[0] == 704
    assert db.execute("SELECT COUNT(*) FROM readings WHERE instrument='stage' AND quantity='feedback_after_deg'").fetchone()[0] == 704
    meta = dict(db.execute("SELECT key, value FROM meta"))
    assert meta["seed"] == "1" and meta["software_version"] and "method:" in meta["procedure_yaml"]
    assert "positioning_error" in meta["scenario_yaml"]
    nulls = db.execute("SELECT COUNT(*) FROM readings WHERE t_s IS NULL OR commanded_angle_deg IS NULL").fetchone()[0]
    assert nulls == 0


@pytest.mark.parametrize("estimator", ["paper", "shared_dead_path"])
def test_paper_bench_noisy_run_error_is_within_its_uncertainty(tmp_path, estimator):
    """The shipped paper-like bench (0.2 µm + 0.3 ppm length noise, 0.3 µm CMM point noise, error
    motions, repeatability 0.2″). Each deviation's error must lie within 3.5σ of the reported
    uncertainty (per-deviation 3.5σ: about 1 in 2000 by chance), and the RMS error within a
    factor 0.3–2.5 of the RMS uncertainty (10 correlated samples)."""
    out = tmp_path / "paper"
    assert main(["run", str(PROCEDURE), "--out", str(out)]) == 0
    r = json.loads((out / "results.json").read_text())
    est = r["estimates"][estimator]
    err = np.array(est["deviation_arcsec"]) - np.array(r["truth"]["realized_deviation_arcsec"])
    unc = np.array(est["uncertainty_arcsec"])
    assert np.all(np.abs(err) < 3.5 * unc), (err, unc)
    ratio = np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(unc**2))
    assert 0.3 < ratio < 2.5


def test_same_seed_same_results(tmp_path, noise_free_run):
    out = tmp_path / "again"
    assert main(["run", str(PROCEDURE), "--scenario", str(NOISE_FREE), "--out", str(out)]) == 0
    a = json.loads((noise_free_run / "results.json").read_text())["estimates"]
    b = json.loads((out / "results.json").read_text())["estimates"]
    assert a == b


def test_refuses_to_overwrite_a_run(noise_free_run, capsys):
    assert main(["run", str(PROCEDURE), "--scenario", str(NOISE_FREE), "--out", str(noise_free_run)]) == 2
    assert "already holds a run" in capsys.readouterr().err


def test_console_script_runs_as_a_newcomer_would(tmp_path):
    """The installed entry point, in a fresh process, from another working directory."""
    out = tmp_path / "cli"
    proc = subprocess.run([sys.executable, "-m", "rtcal.cli", "run", str(PROCEDURE), "--scenario", str(NOISE_FREE),
                           "--out", str(out)], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "results in" in proc.stdout
