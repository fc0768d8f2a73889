"""The periodic positioning error (issue 47, item 2; ISO 230-2:2014 Annex C as rtcal reads it): the
shipped fine-step procedure on the simulated bench with a worm harmonic, the figure and the period's
harmonics against the bench's truth, the procedure's checks, and the certificate's section (the
figure when tested, "not tested" otherwise)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from rtcal.cli import main
from rtcal.methods import read_results
from rtcal.solvers.harmonics import evaluate, Harmonic
from rtcal.solvers.periodic import periodic_error

REPO = Path(__file__).resolve().parents[1]
PROCEDURE = REPO / "procedures" / "periodic_error.yaml"
WORM_BENCH = REPO / "procedures" / "scenarios" / "worm_bench.yaml"


def true_periodic(scenario: Path, period_deg: float, targets_deg: np.ndarray) -> tuple[float, dict[int, float]]:
    """The bench's own periodic error of the period: the range over one period, at the targets, of its
    harmonics whose order is a multiple of 360°/period (the rest is slower: the arc's trend), and their amplitudes."""
    base = round(360.0 / period_deg)
    terms = [h for h in yaml.safe_load(scenario.read_text())["stage"]["positioning_error"] if h["order"] % base == 0]
    theta = np.radians(targets_deg[targets_deg <= targets_deg[0] + period_deg + 1e-9])
    values = evaluate([Harmonic(h["order"], h["amplitude_arcsec"], np.radians(h.get("phase_deg", 0.0))) for h in terms], theta)
    return float(np.ptp(values)), {h["order"]: h["amplitude_arcsec"] for h in terms}


@pytest.fixture(scope="module")
def periodic_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("periodic") / "run"
    assert main(["run", str(PROCEDURE), "--out", str(out)]) == 0
    return out


def test_the_shipped_procedure_recovers_the_benchs_worm_error(periodic_run):
    results = read_results(periodic_run)
    p = results.periodic_error
    assert p is not None and p.period_deg == pytest.approx(4.0) and p.worm_ratio == 90
    targets = np.array(sorted({t for t in p.target_deg}))
    assert targets[0] == 0 and targets[-1] >= 4.0 * 1.25 - 1e-9  # one period and a little more, both directions
    assert set(p.direction) == {1, -1}
    truth, amplitudes = true_periodic(WORM_BENCH, 4.0, targets)
    for value, U in ((p.periodic_error_up_arcsec, p.expanded_uncertainty_up_arcsec),
                     (p.periodic_error_down_arcsec, p.expanded_uncertainty_down_arcsec)):
        assert value is not None and U is not None and abs(value - truth) <= U, (value, truth, U)
    assert p.periodic_error_arcsec == max(p.periodic_error_up_arcsec, p.periodic_error_down_arcsec)
    by_order = {h.order: h for h in p.harmonics}
    for order, amplitude in amplitudes.items():  # the worm's period and its second harmonic
        h = by_order[order]
        assert h.significant and abs(h.amplitude_arcsec - amplitude) <= 3 * h.amplitude_sigma_arcsec + 0.02, (order, h)
        assert h.period_deg == pytest.approx(360.0 / order) and h.period_worm_revolutions == pytest.approx(90.0 / order)
    assert not any(h.significant for o, h in by_order.items() if o not in amplitudes)
    assert "not reached" in p.definition and "Annex C" in p.definition


def test_console_report_and_certificate_carry_it(periodic_run):
    cert = json.loads((periodic_run / "certificate.json").read_text())
    section = cert["periodic_error"]
    assert section["tested"] and "Annex C" in section["heading"]
    assert any("4° = 1 worm revolution" in r[1] for r in section["harmonic_rows"])
    assert any("periodic positioning error of the axis" in r["quantity"] for r in section["rows"])
    assert "periodic positioning error of ISO 230-2:2014 Annex C" in cert["method"]["paragraphs"][-1]
    report = (periodic_run / "report.md").read_text()
    assert "## Periodic positioning error (ISO 230-2:2014 Annex C)" in report and (periodic_run / "periodic_error.png").exists()


def test_a_run_without_the_test_says_not_tested(tmp_path):
    out = tmp_path / "run"
    assert main(["run", str(REPO / "procedures" / "encoder_abbe_error.yaml"), "--out", str(out)]) == 0
    cert = json.loads((out / "certificate.json").read_text())
    assert cert["periodic_error"]["tested"] is False and cert["periodic_error"]["statement"].startswith("Not tested")
    assert "was not tested" in cert["method"]["paragraphs"][-1]
    assert "Not tested" in (out / "report.md").read_text()
    assert read_results(out).periodic_error is None and "periodic_error" not in json.loads((out / "results.json").read_text())


def test_a_bench_without_a_worm_error_shows_none(tmp_path):
    """abbe_bench.yaml has no error of the worm's period: the figure is within its U of the slow error's
    leakage, and no harmonic of the period is significant."""
    out = tmp_path / "run"
    assert main(["run", str(PROCEDURE), "--scenario", str(REPO / "procedures" / "scenarios" / "abbe_bench.yaml"),
                 "--out", str(out)]) == 0
    p = read_results(out).periodic_error
    assert p is not None and p.periodic_error_arcsec < 1.5
    assert not any(h.significant for h in p.harmonics)


def test_the_solver_on_a_known_curve():
    """A 2″ worm error on a steep slow error, two directions 8″ apart, no noise: the figure is the
    range of the worm error at the targets, the harmonic its amplitude."""
    angle = np.round(np.arange(0, 5.0001, 0.1), 9)
    a = np.concatenate([angle, angle])
    d = np.concatenate([np.ones(len(angle), int), -np.ones(len(angle), int)])
    worm = 2.0 * np.sin(np.radians(90 * a + 30))
    slow = 6.0 * np.sin(np.radians(12 * a - 30)) + 20 * np.sin(np.radians(a + 40)) - 8.0 * (d < 0)
    found = periodic_error(a, d, worm + slow, 4.0, 0.0, 90.0)
    expected = float(np.ptp(worm[: 41]))
    assert found.per_direction_arcsec[1] == pytest.approx(expected, abs=0.1)
    assert found.per_direction_arcsec[-1] == pytest.approx(expected, abs=0.1)
    assert found.terms[0].order == 90 and found.terms[0].amplitude_arcsec == pytest.approx(2.0, abs=0.05)
    assert found.terms[0].period_worm_revolutions == pytest.approx(1.0)


@pytest.mark.parametrize("change, message", [
    ({"step_deg": 1.0}, "at least 8 are needed"),
    ({"worm_ratio": 7.5}, "does not divide the turn"),
    ({"start_deg": 7.5}, "not a polygon face position"),
    ({"start_deg": 358}, "past 360°"),
])
def test_the_procedure_is_checked(tmp_path, capsys, change, message):
    data = yaml.safe_load(PROCEDURE.read_text())
    data["periodic"].update(change)
    data.pop("bench")
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(data, allow_unicode=True))
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert message in err and "periodic" in err and "Traceback" not in err
