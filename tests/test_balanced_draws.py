"""`rtcal uncertainty --balanced`: the systematic errors in antithetic pairs whose second moments are
exactly the stated ones."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from rtcal.cli import main
from rtcal.methods import METHODS
from rtcal.planning.montecarlo import ScriptedNormals, balanced_normals, plan_trials
from rtcal.methods import load_procedure
from rtcal.run.runner import resolve_scenario

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "procedures" / "laser_tracer_multistation.yaml"


def test_balanced_normals_are_antithetic_with_exact_second_moments():
    z = balanced_normals(40, 12, np.random.default_rng(3))
    assert z.shape == (80, 12)
    np.testing.assert_allclose(z[0::2], -z[1::2])
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(z.T @ z / 80, np.eye(12), atol=1e-12)


def test_the_method_draws_as_many_numbers_each_time_and_pairs_mirror(tmp_path):
    """The shipped procedure draws the CMM's 6 errors, 4 error-motion series of 6 orders (radial x, y;
    tilt x, y; no axial bound) and its LaserTRACER's sphere (its class assumed: a lobe's order and phase): 56 numbers. A pair's benches have opposite CMM errors and error motions
    half a period apart (a harmonic's phase + 180°)."""
    proc = load_procedure(SHIPPED)
    scenario, _ = resolve_scenario(SHIPPED, proc, None)
    counter = ScriptedNormals()
    METHODS[proc.method].draw_systematics(proc, scenario, counter)  # type: ignore[arg-type]
    assert counter.used == 6 + 4 * 2 * proc.uncertainty.error_motions.max_order + 2
    specs = plan_trials(SHIPPED, proc, scenario, 112, 5, tmp_path, balanced=True)
    a, b = (yaml.safe_load(s.scenario_yaml) for s in specs[:2])
    assert a["cmm"]["scale_error_ppm"] == [-v for v in b["cmm"]["scale_error_ppm"]]
    ha, hb = a["stage"]["radial_motion_x"][0], b["stage"]["radial_motion_x"][0]
    assert ha["amplitude_um"] == hb["amplitude_um"] and abs(abs(ha["phase_deg"] - hb["phase_deg"]) - 180) < 1e-9


def test_too_few_or_odd_trials_are_refused_on_one_line(tmp_path, capsys):
    assert main(["uncertainty", str(SHIPPED), "--trials", "7", "--balanced", "--out", str(tmp_path / "a")]) == 2
    assert "--balanced: balanced draws come in antithetic pairs" in capsys.readouterr().err
    assert main(["uncertainty", str(SHIPPED), "--trials", "20", "--balanced", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "at least 56 pairs of trials" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
