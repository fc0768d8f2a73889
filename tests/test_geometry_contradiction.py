"""A wrong geometry value (m typed as mm, a diameter for a radius) is a fault the readings show, never a
PASS certificate: rtcal.solvers.abbe.scale_check, the run's exit 1, and validate's plausibility bound."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from rtcal.cli import main
from rtcal.solvers.abbe import SCALE_BAND, scale_check

REPO = Path(__file__).resolve().parents[1]
ISO = REPO / "procedures" / "iso230_2_polygon.yaml"
ABBE = REPO / "procedures" / "encoder_abbe_error.yaml"


def _steps(seed: int, scale: float, eccentricity_arcsec: float = 2.0):
    """Predicted Abbe error at the prediction's scale ``1/scale`` of the truth; measured = truth + an
    encoder's own once-per-turn error + noise; σ as stated (1.3″, the shipped ISO run's)."""
    rng = np.random.default_rng(seed)
    theta = np.radians(np.arange(0, 360, 15.0))
    truth = 14 * np.sin(theta + 0.7) + 5 * np.sin(2 * theta + 0.3) + 3 * np.sin(3 * theta)
    measured = truth + eccentricity_arcsec * np.sin(theta + rng.uniform(0, 2 * np.pi)) + rng.normal(0, 0.3, theta.size)
    sigma = np.full(theta.size, 1.3) / scale
    return np.degrees(theta), measured, truth / scale, sigma


@pytest.mark.parametrize("seed", range(5))
def test_an_honest_encoder_error_passes(seed):
    check = scale_check(*_steps(seed, 1.0))
    assert check is not None and not check.failed
    assert abs(check.scale - 1) < 0.05


def test_a_large_eccentricity_is_the_encoders_own_error():
    check = scale_check(*_steps(0, 1.0, eccentricity_arcsec=20.0))
    assert check is not None and not check.failed and abs(check.scale - 1) < 0.05


@pytest.mark.parametrize("factor", [1000.0, 0.001, 2.0, 0.5, 25.4])
def test_a_prediction_at_another_scale_fails(factor):
    check = scale_check(*_steps(0, factor))
    assert check is not None and check.failed
    assert check.scale == pytest.approx(factor, rel=0.05)
    fitted_mm = 32.0 * factor / check.scale
    assert abs(fitted_mm - 32.0) < 0.05 * 32.0 and not 1 / SCALE_BAND < check.scale < SCALE_BAND
    assert f"fits as ≈ {fitted_mm:.3g} mm" in check.message(32.0 * factor)


def _procedure(tmp_path: Path, source: Path, radius: str) -> Path:
    shutil.copytree(REPO / "procedures" / "scenarios", tmp_path / "scenarios")
    text, n = re.subn(r"encoder_radius_mm: 32\b", f"encoder_radius_mm: {radius}", source.read_text())
    assert n == 1
    path = tmp_path / source.name
    path.write_text(text)
    return path


@pytest.mark.parametrize("source", [ISO, ABBE])
def test_a_diameter_for_the_radius_fails_the_run(tmp_path, capsys, source):
    out = tmp_path / "run"
    assert main(["run", str(_procedure(tmp_path, source, "64")), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "check FAILED" in err and "encoder_radius_mm = 64 fits as" in err
    assert not (out / "results.json").exists() and not (out / "report.pdf").exists() and (out / "run.sqlite").exists()


def test_the_shipped_geometry_passes(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", str(_procedure(tmp_path, ISO, "32")), "--out", str(out)]) == 0
    assert "check FAILED" not in capsys.readouterr().err and (out / "results.json").exists()


def test_validate_refuses_metres_typed_as_mm(tmp_path, capsys):
    path = _procedure(tmp_path, ISO, "0.032")
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    line = next(i for i, t in enumerate(path.read_text().splitlines(), 1) if "encoder_radius_mm" in t)
    assert f"{path}:{line}:" in err and "geometry.encoder_radius_mm" in err and "metres typed as mm" in err


@pytest.mark.campaign
@pytest.mark.parametrize("source", [ISO, ABBE])
def test_false_alarm_rate_over_seeds(tmp_path, source):
    """Honest simulated benches over 40 seeds: not one run fails the scale check."""
    for seed in range(40):
        assert main(["run", str(source), "--seed", str(seed), "--out", str(tmp_path / f"r{seed}")]) == 0


def test_a_noisy_prediction_of_a_shaft_that_barely_moves_is_not_a_wrong_geometry():
    """Coarse indicators on a small motion: the prediction's own noise pulls the fitted scale towards 0
    (errors in the variable); the check corrects for it with the prediction's stated σ."""
    rng = np.random.default_rng(3)
    theta = np.radians(np.arange(0, 360, 1.0))
    truth = 2.0 * np.sin(2 * theta) + 1.5 * np.sin(3 * theta + 1.0)
    sigma_p = np.full(theta.size, 1.5)
    predicted = truth + rng.normal(0, 1.5, theta.size)
    measured = truth + rng.normal(0, 0.3, theta.size)
    sigma = np.hypot(sigma_p, 0.3)
    naive = scale_check(np.degrees(theta), measured, predicted, sigma)
    assert naive is not None and naive.failed  # what the correction is for
    check = scale_check(np.degrees(theta), measured, predicted, sigma, sigma_p)
    assert check is not None and not check.failed and abs(check.scale - 1) < 0.2
