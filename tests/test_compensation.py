"""Compensation tables: each format written, read back and matching its documented syntax, and
the closed loop calibrate → compensate → verify on the simulated controller."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from rtcal.cli import main
from rtcal.deliverables.compensation import PARSERS, WRITERS, CompensationError, table_from_deviations, write_table
from rtcal.deliverables.deviations import PositioningDeviations

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
    "fanuc": [r"\(.*\)", r"36\d\d( #0)? = -?\d+  \(.*\)", r"\d{1,4} = [+-]\d+"],
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


def _documented_example(fmt: str) -> list[str]:
    """The syntax example under the format's heading in docs/compensation.md ("…" lines left out)."""
    doc = (REPO / "docs" / "compensation.md").read_text(encoding="utf-8")
    section = doc.split(f"(`--format {fmt}`)", 1)[1].split("\n## ", 1)[0]
    block = section.split("```\n", 1)[1].split("```", 1)[0]
    return [line for line in block.splitlines() if line.strip() and line.strip() != "…"]


@pytest.mark.parametrize("fmt", FORMATS)
def test_written_tables_read_back_and_match_their_syntax(fmt):
    comp = table_from_deviations(_smooth_table(), 15.0)
    text = WRITERS[fmt](comp)
    for line in text.splitlines():
        assert any(re.fullmatch(p, line) for p in SYNTAX[fmt]), (fmt, line)
    example = _documented_example(fmt)
    assert len(example) >= 3
    for line in example:  # the documentation shows what the writer writes
        assert any(re.fullmatch(p, line) for p in SYNTAX[fmt]), (fmt, "docs", line)
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
    inc = [int(v) for v in re.findall(r"^\d{1,4} = ([+-]\d+)$", fanuc, re.M)]
    up, down = inc[:25], inc[25:]
    assert len(down) == 25
    assert sum(up[1:]) == 0 and up[0] == up[-1]  # increments close the turn; 0° and 360° hold one value
    assert sum(down[1:]) == 0 and down[0] == down[-1]
    assert re.search(r"^3626 = 25 ", fanuc, re.M)  # the negative table's farthest point on the − side: its first
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
    ("0 0 0\n", "1 lines"),
    ("0 0 0\n180 180.1 180\n360 0.5 360\n", "below 1 degree"),
    ("0 0 0\n90 90 90\n90 90 90\n", ":3: nominal positions must increase strictly"),
    ("0 0 0\nabc\n", ":2: expected three finite numbers"),
    # LinuxCNC stops at the first line that is not three numbers: a blank line or a comment would
    # silently cut the table short on the machine, so rtcal refuses them
    ("0 0 0\n\n15 15 15\n30 30 30\n", ":2: expected three finite numbers .* would ignore the 2 line"),
    ("# from rtcal\n0 0 0\n15 15 15\n", ":1: expected three finite numbers"),
])
def test_bad_linuxcnc_tables_are_refused_with_a_line(text, message):
    with pytest.raises(CompensationError, match=message):
        PARSERS["linuxcnc"](text, "c.comp")


def _mutated(fmt: str, old: str, new: str) -> str:
    text = WRITERS[fmt](table_from_deviations(_smooth_table(), 15.0))
    assert old in text
    return text.replace(old, new, 1)


@pytest.mark.parametrize("fmt, old, new, message", [
    ("siemens-lec", "M17\n", "", "M17 is missing"),
    ("siemens-lec", "CHANDATA(1)\n", "CHANDATA(1)\nG01 X10\n", ":3: not a \\$AA_ENC_COMP assignment"),
    ("siemens-lec", "IS_MODULO[0,C1]=1", "IS_MODULO[0,C1]=0", "modulo table"),
    ("siemens-lec", "$AA_ENC_COMP[0,3,", "$AA_ENC_COMP[0,33,", "without gaps"),
    ("siemens-cec", "%_N_NC_CEC_INI", "%_N_AX_EEC_INI", ":1: the first line must be %_N_NC_CEC_INI"),
    ("siemens-cec", "$AN_CEC_DIRECTION[1]=-1", "$AN_CEC_DIRECTION[1]=1", "one table per direction"),
    ("fanuc", "3626 = 25 ", "3626 = 49 ", "point 50 is missing"),  # 3626 read as the table's last point
    ("fanuc", "\n1 = -10\n", "\n1 = -9\n", "must sum to zero"),
    ("fanuc", "3621 = 0 ", "3621 = 1 ", "3621"),
    ("heidenhain", "1 +15.0000", "1 +16.0000", ":4: AXISPOS 16 is not DATUM"),
    ("heidenhain", "[END]", "", "ends with \\[END\\]"),
])
def test_bad_tables_of_every_format_are_refused_with_a_reason(fmt, old, new, message):
    with pytest.raises(CompensationError, match=message):
        PARSERS[fmt](_mutated(fmt, old, new), "t")


def test_linuxcnc_holds_its_end_trims_outside_its_range():
    """LinuxCNC does not wrap a comp table (sentinel entries with zero slope beyond the first and
    last lines): a one-turn table applies its 0° trim at −10°, not its 350° trim; a table written
    over the joint's travel (--range-deg) carries the turn's periodic values there."""
    comp = table_from_deviations(_smooth_table(), 15.0)
    one_turn = PARSERS["linuxcnc"](WRITERS["linuxcnc"](comp), "c.comp")
    assert one_turn.trim_deg(-10.0, 1) == pytest.approx(one_turn.trim_deg(0.0, 1))
    assert one_turn.trim_deg(-10.0, 1) != pytest.approx(comp.trim_deg(350.0, 1), abs=1e-6)
    travel = PARSERS["linuxcnc"](write_table("linuxcnc", comp, range_deg=(-180.0, 180.0)), "c.comp")
    assert travel.positions_deg[0] == -180.0 and len(travel.positions_deg) == 25
    for a in (-145.0, -10.0, 100.0):
        for d in (1, -1):
            assert travel.trim_deg(a, d) == pytest.approx(comp.trim_deg(a, d), abs=1e-8)
    with pytest.raises(CompensationError, match="at most 256"):
        write_table("linuxcnc", comp, range_deg=(-1935.0, 1935.0))  # 259 lines
    with pytest.raises(CompensationError, match="takes no --range-deg"):
        write_table("fanuc", comp, range_deg=(0.0, 360.0))


def test_fanuc_magnification_keeps_values_within_range():
    """A large error (200″ sine): increments over 15° reach about 52″/0.36″ = 145 units, beyond
    ±127 at magnification 1, so 3623 = 2; the read-back is still within half a (doubled) unit."""
    t = _smooth_table()
    big = PositioningDeviations(t.target_deg, t.direction, t.run, 10 * t.deviation_arcsec, t.uncertainty_arcsec)
    comp = table_from_deviations(big, 15.0)
    text = WRITERS["fanuc"](comp)
    assert re.search(r"^3623 = 2 ", text, re.M)
    assert max(abs(int(v)) for v in re.findall(r"^\d{1,4} = ([+-]\d+)$", text, re.M)) <= 127
    back = PARSERS["fanuc"](text, "f")
    np.testing.assert_allclose(back.trim_up_deg, comp.trim_up_deg, atol=0.0002 / 2 + 1e-9)
    with pytest.raises(CompensationError, match="do not fit 0 … 1023"):
        write_table("fanuc", comp, first_point=1000)


def test_a_repeated_command_keeps_its_direction_on_a_compensated_stage(tmp_path):
    """The controller compensates the motor, not the user's number: commanding the same target
    again (a retry after a lost reply) is no move, so it keeps the approach direction, and the
    stage reports the commanded angle."""
    from rtcal.procedure.loader import load_scenario
    from simulators.bench import Bench
    from simulators.instruments import SimStage

    comp = table_from_deviations(_smooth_table(), 15.0)
    (tmp_path / "c.comp").write_text(WRITERS["linuxcnc"](comp))
    (tmp_path / "b.yaml").write_text("stage:\n  compensation: {format: linuxcnc, file: c.comp}\n")
    bench = Bench(load_scenario(tmp_path / "b.yaml"))
    stage = SimStage(bench)
    stage.move_to(80.0)
    stage.move_to(90.0)  # positive approach; the motor goes to 90° + trim (a few arcsec off 90°)
    first = bench.actual_rad
    assert bench.commanded_rad != pytest.approx(np.radians(90.0), abs=1e-9)
    stage.move_to(90.0)
    assert bench.last_direction == 1 and bench.actual_rad == pytest.approx(first, abs=1e-15)
    assert stage.position_deg() == pytest.approx(90.0)


def _evaluate(run: Path) -> dict:
    return json.loads((run / "results.json").read_text())["evaluation"]["iso230_2"]


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("iso") / "calibration"
    assert main(["run", str(ISO), "--scenario", str(BENCH), "--out", str(out)]) == 0
    return out


def _compensated_bench(calibrated: Path, tmp_path: Path, fmt: str) -> Path:
    table = tmp_path / f"table.{fmt}"
    assert main(["compensate", str(calibrated), "--format", fmt, "--step-deg", "15", "--out", str(table)]) == 0
    bench = tmp_path / "compensated.yaml"
    bench.write_text(BENCH.read_text().replace("  repeatability_arcsec: 0.1\n",
                                               f"  repeatability_arcsec: 0.1\n  compensation: {{format: {fmt}, file: {table.name}}}\n"))
    return bench


@pytest.mark.parametrize("fmt", FORMATS)
def test_calibrate_compensate_verify(calibrated, tmp_path, fmt):
    """The ISO 230-2 test, its table loaded into the simulated controller, the test again with
    another seed (fresh repeatability, autocollimator noise and polygon certificate: a table that
    only fitted the first run's noise would not pass): E (44″ here) drops at least 8× and B (3.1″)
    at least 4× for the two-direction formats. This is what proves each format's sign: with the
    sign wrong the table doubles the error instead. The one-direction formats (LEC, HEIDENHAIN)
    carry the mean of both directions: each direction's curve (E↑, E↓) and M drop at least 8×,
    and B stays (it is the backlash compensation's job)."""
    bench = _compensated_bench(calibrated, tmp_path, fmt)
    verify = tmp_path / "verify"
    assert main(["run", str(ISO), "--scenario", str(bench), "--seed", "7", "--out", str(verify)]) == 0
    before, after = _evaluate(calibrated), _evaluate(verify)
    assert before["E"] > 40 and before["B"] > 2.5
    if fmt in ("siemens-lec", "heidenhain"):
        for key in ("E_up", "E_down", "M"):
            assert after[key] < before[key] / 8, (key, before[key], after[key])
        assert abs(after["B"] - before["B"]) < 0.5
    else:
        assert after["E"] < before["E"] / 8, (before["E"], after["E"])
        assert after["B"] < before["B"] / 4, (before["B"], after["B"])


def test_the_modbus_drive_simulator_applies_the_table(calibrated, tmp_path):
    """The same loop over Modbus TCP, serial lines and the simulated operator (`rtcal sim serve`,
    another seed): the AZ drive simulator moves through the same compensated controller."""
    from tests.test_transport_end_to_end import sim_serve

    bench = _compensated_bench(calibrated, tmp_path, "linuxcnc")
    with sim_serve(bench, "--seed", "8") as addresses:
        assert main(["run", str(ISO), "--instruments", json.dumps(addresses), "--virtual-clock", "--out", str(tmp_path / "v")]) == 0
    before, after = _evaluate(calibrated), _evaluate(tmp_path / "v")
    assert after["E"] < before["E"] / 8 and after["B"] < before["B"] / 4


def test_a_bad_table_in_a_scenario_is_located(tmp_path, capsys):
    (tmp_path / "bad.comp").write_text("0 0 0\nnot numbers\n")
    bench = tmp_path / "bench.yaml"
    bench.write_text("stage:\n  compensation: {format: linuxcnc, file: bad.comp}\n")
    assert main(["validate", str(bench)]) == 2
    err = capsys.readouterr().err
    assert f"{bench}:2:" in err and "bad.comp:2: expected three finite numbers" in err


@pytest.mark.parametrize("options, message", [
    (["--format", "linuxcnc", "--step-deg", "7"], "--step-deg 7: the grid must divide one turn"),
    (["--format", "linuxcnc", "--axis", "C"], "linuxcnc takes no --axis"),
    (["--format", "fanuc", "--step-deg", "15", "--first-point", "1000"], "do not fit 0 … 1023"),
    (["--format", "siemens-lec", "--axis", "c1"], "not a siemens-lec axis name"),
])
def test_compensate_refuses_bad_options_in_one_line(tmp_path, capsys, options, message):
    csv = tmp_path / "d.csv"
    _smooth_table().write_csv(csv)
    assert main(["compensate", str(csv), *options, "--out", str(tmp_path / "t")]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "t").exists()


def test_compensate_options_reach_the_file(tmp_path):
    csv = tmp_path / "d.csv"
    _smooth_table().write_csv(csv)
    assert main(["compensate", str(csv), "--format", "linuxcnc", "--range-deg", "-180", "180", "--out", str(tmp_path / "c")]) == 0
    assert (tmp_path / "c").read_text().splitlines()[0].startswith("-180.000000 ")
    assert main(["compensate", str(csv), "--format", "heidenhain", "--step-deg", "15", "--axis", "B",
                 "--out", str(tmp_path / "h")]) == 0
    assert (tmp_path / "h").read_text().startswith("BEGIN AXIS-B.COM ")
    assert main(["compensate", str(csv), "--format", "fanuc", "--step-deg", "15", "--detection-unit-deg", "0.001", "--first-point", "100",
                 "--out", str(tmp_path / "f")]) == 0
    text = (tmp_path / "f").read_text()
    assert "3620 = 100 " in text and "3625 = 360000 " in text
