"""Compensation tables: each format written, read back and matching its documented syntax, and
the closed loop calibrate → compensate → verify on the simulated controller."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from rtcal.cli import main
from rtcal.compensation import PARSERS, WRITERS, CompensationError, table_from_deviations
from rtcal.deviations import PositioningDeviations

REPO = Path(__file__).resolve().parents[1]
ISO = REPO / "procedures" / "iso230_2_polygon.yaml"
BENCH = REPO / "tests" / "data" / "smooth_reversal_bench.yaml"
FORMATS = list(WRITERS)

# the documented line syntax of every format (docs/compensation.md)
SYNTAX = {
    "linuxcnc": [r"\d+\.\d{6} -?\d+\.\d{8} -?\d+\.\d{8}"],
    "siemens-lec": [r"%_N_AX_EEC_INI", r"CHANDATA\(1\)", r"\$AA_ENC_COMP\[0,\d+,C1\]=-?\d+\.\d{8}",
                    r"\$AA_ENC_COMP_(STEP|MIN|MAX|IS_MODULO)\[0,C1\]=[\d.]+", r"M17"],
    "siemens-cec": [r"%_N_NC_CEC_INI", r"CHANDATA\(1\)", r"\$AN_CEC\[[01],\d+\]=-?\d+\.\d{8}",
                    r"\$AN_CEC_(INPUT_AXIS|OUTPUT_AXIS)\[[01]\]=C1", r"\$AN_CEC_(STEP|MIN|MAX|DIRECTION|IS_MODULO)\[[01]\]=-?[\d.]+", r"M17"],
    "fanuc": [r"\(.*\)", r"36\d\d( #0)? = -?\d+  \(.*\)", r"\d{4} = [+-]\d+"],
    "heidenhain": [r"BEGIN AXIS-C\.COM DATUM:\+0\.0000 DISTANCE:\+\d+\.\d{4}", r"NR AXISPOS C", r"\d+ [+-]\d+\.\d{4} [+-]\d+\.\d{8}",
                   r"\[END\]"],
}


def _smooth_table() -> PositioningDeviations:
    """Deviations at irregular targets: 20″·sin(θ + 40°) + 3″ lower for a negative approach."""
    targets = np.array([0, 15, 45, 90, 105, 150, 180, 210, 240, 270, 315, 330], float)
    rows = [(t, d, r, 20 * np.sin(np.radians(t + 40)) - (3.0 if d < 0 else 0.0) + 0.01 * r)
            for t in targets for d in (1, -1) for r in (1, 2)]
    a = np.array(rows)
    return PositioningDeviations(a[:, 0], a[:, 1].astype(int), a[:, 2].astype(int), a[:, 3], np.full(len(a), 0.1))


@pytest.mark.parametrize("fmt", FORMATS)
def test_written_tables_read_back_and_match_their_syntax(fmt):
    comp = table_from_deviations(_smooth_table(), 15.0)
    text = WRITERS[fmt](comp)
    for line in text.splitlines():
        assert any(re.fullmatch(p, line) for p in SYNTAX[fmt]), (fmt, line)
    back = PARSERS[fmt](text, fmt)
    # one-direction formats keep the mean of both; FANUC quantises to its 0.0001° detection unit (0.36″)
    tol = 0.18 / 3600 + 1e-9 if fmt == "fanuc" else 1e-8
    if fmt in ("siemens-lec", "heidenhain"):
        mean = (comp.trim_up_deg + comp.trim_down_deg) / 2
        np.testing.assert_allclose(back.trim_up_deg, mean, atol=tol)
        np.testing.assert_allclose(back.trim_down_deg, mean, atol=tol)
    else:
        np.testing.assert_allclose(back.trim_up_deg, comp.trim_up_deg, atol=tol)
        np.testing.assert_allclose(back.trim_down_deg, comp.trim_down_deg, atol=tol)
    np.testing.assert_allclose(back.positions_deg, np.arange(0, 361, 15.0))


def test_the_rules_each_format_states():
    comp = table_from_deviations(_smooth_table(), 15.0)
    assert comp.trim_up_deg[0] == 0.0  # the datum stays put
    assert comp.trim_down_deg[0] == pytest.approx(3 / 3600)  # the reversal is compensated at the datum too
    fanuc = WRITERS["fanuc"](comp)
    inc = [int(v) for v in re.findall(r"^1\d{3} = ([+-]\d+)$", fanuc, re.M)]
    up = inc[:25]
    assert sum(up[1:]) == 0 and up[0] == up[-1]  # increments close the turn; 0° and 360° hold one value
    lec = WRITERS["siemens-lec"](comp)
    values = re.findall(r"\$AA_ENC_COMP\[0,(\d+),C1\]=(\S+)", lec)
    assert values[0][1] == values[-1][1]  # modulo: MAX repeats MIN
    with pytest.raises(CompensationError, match="at most 256"):
        WRITERS["linuxcnc"](table_from_deviations(_smooth_table(), 1.0))


def test_a_gap_too_wide_to_interpolate_is_refused(tmp_path, capsys):
    t = _smooth_table()
    sparse = t.select(np.isin(t.target_deg, [0, 90, 180]))
    with pytest.raises(CompensationError, match="gap of 180"):
        table_from_deviations(sparse)
    csv = tmp_path / "d.csv"
    sparse.write_csv(csv)
    assert main(["compensate", str(csv), "--format", "linuxcnc", "--out", str(tmp_path / "c.comp")]) == 2
    assert "measure more targets" in capsys.readouterr().err


@pytest.mark.parametrize("text, message", [
    ("0 0 0\n15 15 15\n", "3 … 256"),
    ("0 0 0\n180 180.1 180\n360 0.5 360\n", "below 1 degree"),
    ("0 0 0\n90 90 90\n200 200 200\n360 360 360\n", "evenly"),
    ("0 0 0\nabc\n", ":2: expected three numbers"),
])
def test_bad_tables_are_refused_with_a_line(text, message):
    with pytest.raises(CompensationError, match=message):
        PARSERS["linuxcnc"](text, "c.comp")


def _evaluate(run: Path) -> dict:
    return json.loads((run / "results.json").read_text())["evaluation"]["iso230_2"]


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("iso") / "calibration"
    assert main(["run", str(ISO), "--scenario", str(BENCH), "--out", str(out)]) == 0
    return out


@pytest.mark.parametrize("fmt", FORMATS)
def test_calibrate_compensate_verify(calibrated, tmp_path, fmt):
    """The ISO 230-2 test, its table loaded into the simulated controller, the test again: E (48″
    here) drops at least 8× and B (3″) at least 4× — for the two-direction formats; the
    one-direction formats (LEC, HEIDENHAIN) carry the mean of both directions, so they cut E but
    leave B to the backlash compensation, which the check reflects."""
    table = tmp_path / f"table.{fmt}"
    assert main(["compensate", str(calibrated), "--format", fmt, "--out", str(table)]) == 0
    bench = tmp_path / "compensated.yaml"
    text = BENCH.read_text().replace("  repeatability_arcsec: 0.1\n", f"  repeatability_arcsec: 0.1\n  compensation: {{format: {fmt}, file: {table.name}}}\n")
    bench.write_text(text)
    verify = tmp_path / "verify"
    assert main(["run", str(ISO), "--scenario", str(bench), "--out", str(verify)]) == 0
    before, after = _evaluate(calibrated), _evaluate(verify)
    assert before["E"] > 40 and before["B"] > 2.5
    if fmt in ("siemens-lec", "heidenhain"):
        assert after["E"] < before["E"] / 4  # the mean of both directions leaves ±B/2
        assert abs(after["B_mean"] - before["B_mean"]) < 0.5
    else:
        assert after["E"] < before["E"] / 8, (before["E"], after["E"])
        assert after["B"] < before["B"] / 4, (before["B"], after["B"])


def test_the_modbus_drive_simulator_applies_the_table(calibrated, tmp_path):
    """The same loop over Modbus TCP, serial lines and the simulated operator (`rtcal sim serve`)."""
    from tests.test_transport_end_to_end import sim_serve

    table = tmp_path / "table.comp"
    assert main(["compensate", str(calibrated), "--format", "linuxcnc", "--out", str(table)]) == 0
    bench = tmp_path / "compensated.yaml"
    bench.write_text(BENCH.read_text().replace("  repeatability_arcsec: 0.1\n",
                                               "  repeatability_arcsec: 0.1\n  compensation: {format: linuxcnc, file: table.comp}\n"))
    with sim_serve(bench) as addresses:
        assert main(["run", str(ISO), "--instruments", json.dumps(addresses), "--virtual-clock", "--out", str(tmp_path / "v")]) == 0
    before, after = _evaluate(calibrated), _evaluate(tmp_path / "v")
    assert after["E"] < before["E"] / 8 and after["B"] < before["B"] / 4


def test_a_bad_table_in_a_scenario_is_located(tmp_path, capsys):
    (tmp_path / "bad.comp").write_text("0 0 0\nnot numbers\n")
    bench = tmp_path / "bench.yaml"
    bench.write_text("stage:\n  compensation: {format: linuxcnc, file: bad.comp}\n")
    assert main(["validate", str(bench)]) == 2
    err = capsys.readouterr().err
    assert f"{bench}:2:" in err and "bad.comp:2: expected three numbers" in err
