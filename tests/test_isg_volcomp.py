"""The rotary axis as an ISG / Beckhoff TwinCAT CNC volumetric compensation table (issue 47, item 3):
the manual's ISG CSV examples read as the manual shows them, rtcal's file in the manual's units,
ranges, file breaks, comments and 360° splicing, the error motions and location errors from the runs
that measured them, and an independent ISO 230-1 forward model: the table applied to the simulated
axis leaves, at the measured targets, a residual within the data's U."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from rtcal.cli import main
from rtcal.compensation import CompensationError, get_format
from rtcal.compensation.isg_volcomp import read_blocks
from rtcal.methods import read_results

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data" / "isg_volcomp"
ABBE = REPO / "procedures" / "encoder_abbe_error.yaml"
BENCH = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"
RAD = math.pi / 648000.0  # rad per arcsec


# ---- the manual's examples -------------------------------------------------------------------
def test_the_manuals_examples_read_as_the_manual_shows_them():
    (pos,) = read_blocks((DATA / "manual_position_errors.csv").read_text())
    assert pos.header == ("Y0A", "Z0A", "X0B") and pos.rows.tolist() == [[0.1, 0.2, 0.11]]
    (x,) = read_blocks((DATA / "manual_component_errors_x.csv").read_text())
    assert x.header == ("X", "EXX", "EYX", "EZX", "EAX", "EBX", "ECX")
    assert x.rows.tolist() == [[0.0, 0.02, 0.01, 0.07, 0.0, 0.0042, 0.003], [10.0, 0.0, -0.1, 0.01, 0.0, 0.0011, 0.002]]
    (xz,) = read_blocks((DATA / "manual_component_errors_x_z.csv").read_text())
    assert xz.header[:2] == ("Z", "X") and xz.column("Z").tolist() == [0.0, 0.0, 100.0, 100.0]
    assert xz.column("EYX").tolist() == [0.01, -0.1, 0.02, -0.09]
    # the manual's "file break": position errors, a #, a new header and its records
    both = read_blocks((DATA / "manual_position_errors.csv").read_text() + "#\n"
                       + (DATA / "manual_component_errors_x.csv").read_text())
    assert [b.header[0] for b in both] == ["Y0A", "X"]


@pytest.mark.parametrize("text, message", [
    ("C ECC ECC\n0 0 0\n", "ECC named twice"),  # the manual's error ID 70469
    ("C ECX EQC\n0 0 0\n", "'EQC' is not an argument"),  # ID 70468: unknown identifier
    ("C ECC\n0 0 // zero\n", "a comment after values"),
    ("C ECC\n0\n", "a record of 2 numbers"),
    ("C ECC\n0 nan\n", "a record of 2 numbers"),
])
def test_what_the_manual_does_not_show_is_refused_with_its_line(text, message):
    with pytest.raises(CompensationError, match=message) as err:
        read_blocks(text, "f.csv")
    assert "f.csv:" in str(err.value)


# ---- rtcal's file ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def abbe_run(tmp_path_factory):
    """Seed 001's procedure on the shipped bench: 7.5° steps, faces every 15°, both directions."""
    out = tmp_path_factory.mktemp("abbe") / "run"
    assert main(["run", str(ABBE), "--out", str(out)]) == 0
    return out


def parse_independently(text: str) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """The file read again here, as the manual describes it (not rtcal's reader): whole-line // comments,
    a # file break, a header then records; the position block is the one without an argument column."""
    blocks, current = [], None
    for line in text.splitlines():
        if not line.strip() or line.startswith("//"):
            continue
        if line.startswith("#"):
            current = None
            continue
        if current is None:
            current = {"header": line.split(), "rows": []}
            blocks.append(current)
        else:
            current["rows"].append([float(v) for v in line.split()])
    position, component = {}, {}
    for b in blocks:
        cols = np.array(b["rows"]).T
        if "C" in b["header"]:
            component = dict(zip(b["header"], cols))
        else:
            position = {h: float(c[0]) for h, c in zip(b["header"], cols)}
    return position, component


def harmonics(terms: list[dict], theta_deg: np.ndarray, key: str) -> np.ndarray:
    theta = np.radians(theta_deg)
    return sum((t[key] * np.sin(t["order"] * theta + math.radians(t.get("phase_deg", 0.0))) for t in terms),
               np.zeros_like(theta))


def test_the_table_applied_to_the_simulated_axis_leaves_a_residual_within_the_datas_u(abbe_run, tmp_path):
    """ISO 230-1's model of a C axis (small rotations): a point p of the table at command C lies at
    δ + Rx(EAC)·Rz(C + ECC)·p about the tilt centre. The bench's truth (its scenario's harmonics) and the
    table's parameters each give that position; their difference at the measured targets must lie
    within the U of the data the table came from: ECC's from the run, EYC's and EAC's from the dial
    indicators' digit (1 µm: their rounding repeats run after run, so it is the bound)."""
    out = tmp_path / "c.csv"
    assert main(["compensate", str(abbe_run), "--format", "isg-volcomp", "--step-deg", "15", "--out", str(out)]) == 0
    position, table = parse_independently(out.read_text())
    assert position == {} and set(table) == {"C", "ECC", "EYC", "EAC"}
    C = table["C"]
    assert C[0] == 0 and C[-1] == 360 and np.allclose(np.diff(C), 15)
    stage = yaml.safe_load(BENCH.read_text())["stage"]
    # truth, as the table defines its parameters: εz the mean of both approaches, 0 at C = 0; δy, εx less their mean
    eps = harmonics(stage["positioning_error"], C, "amplitude_arcsec") - stage["reversal_arcsec"] / 2
    eps -= eps[0]
    dy = harmonics(stage["radial_motion_y"], C, "amplitude_um") * 1e-3
    ex = harmonics(stage["tilt_motion_x"], C, "amplitude_arcsec") * RAD
    dy, ex = dy - dy[:-1].mean(), ex - ex[:-1].mean()
    results = read_results(abbe_run)
    U_ecc = max(results.recommended_estimate().cumulative_expanded_uncertainty_arcsec) * RAD
    q, (l1, l2) = 1e-3, (50.0, 70.0)  # the indicators' digit (mm) and heights below the tilt centre (mm)
    U_eyc = 2 * math.hypot(1 + l1 / (l2 - l1), l1 / (l2 - l1)) * q / math.sqrt(12)
    U_eac = 2 * math.sqrt(2) * q / math.sqrt(12) / (l2 - l1)
    assert np.all(np.abs(table["ECC"] - eps * RAD) <= U_ecc)
    assert np.all(np.abs(table["EYC"] - dy) <= U_eyc) and np.all(np.abs(table["EAC"] - ex) <= U_eac)

    def place(c_deg, ecc, eyc, eac, p):
        c = np.radians(c_deg) + ecc
        rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
        rx = np.array([[1, 0, 0], [0, np.cos(eac), -np.sin(eac)], [0, np.sin(eac), np.cos(eac)]])
        return np.array([0.0, eyc, 0.0]) + rx @ rz @ p

    for p in (np.array([100.0, 0.0, 0.0]), np.array([0.0, 150.0, -60.0])):  # on the table; one below the tilt centre
        R, h = math.hypot(p[0], p[1]), abs(p[2])
        U_point = math.sqrt((R * U_ecc) ** 2 + U_eyc**2 + (R * U_eac) ** 2 + (h * U_eac) ** 2)
        residual = before = 0.0
        for i, c in enumerate(C):
            truth = place(c, eps[i] * RAD, dy[i], ex[i], p)
            residual = max(residual, float(np.linalg.norm(truth - place(c, table["ECC"][i], table["EYC"][i], table["EAC"][i], p))))
            before = max(before, float(np.linalg.norm(truth - place(c, 0.0, 0.0, 0.0, p))))
        assert residual <= U_point, (p, residual, U_point)
        assert before > 3 * U_point  # the errors the table takes out are far above what it leaves


def test_units_ranges_splicing_and_the_location_from_seed_000(abbe_run, tmp_path):
    ms = tmp_path / "ms"
    assert main(["run", str(REPO / "procedures" / "laser_tracer_multistation.yaml"), "--out", str(ms)]) == 0
    out = tmp_path / "c.csv"
    assert main(["compensate", str(abbe_run), "--format", "isg-volcomp", "--step-deg", "15", "--location-from", str(ms),
                 "--out", str(out)]) == 0
    text = out.read_text()
    assert text.isascii()
    position, table = parse_independently(text)
    loc = read_results(ms).axis_location
    assert position == pytest.approx({"X0C": loc.x0c_mm, "Y0C": loc.y0c_mm, "A0C": loc.a0c_arcsec * RAD,
                                      "B0C": loc.b0c_arcsec * RAD}, abs=1e-7)
    lines = [line for line in text.splitlines() if not line.startswith("//")]
    assert lines[0].split() == ["X0C", "Y0C", "A0C", "B0C"] and lines[2] == "#" and lines[3].split()[:2] == ["C", "ECC"]
    for name, column in table.items():  # the 360° record repeats the 0° one (splicing by hand, as the manual shows)
        if name != "C":
            assert column[-1] == column[0], name
    assert "degrees 0 ... 360" in text and "mm" in text and "rad" in text
    assert "frame: CMM frame" in text and "PXC, PYC" in text
    # the file reads back (rtcal's reader) to the trims of the bidirectional mean
    back = get_format("isg-volcomp").parse(text, "c.csv")
    assert np.allclose(-back.trim_up_deg * 3600 * RAD, table["ECC"], atol=1e-12)


def test_a_named_run_without_them_is_one_line(abbe_run, tmp_path, capsys):
    out = tmp_path / "c.csv"
    assert main(["compensate", str(abbe_run), "--format", "isg-volcomp", "--step-deg", "15", "--location-from",
                 str(abbe_run), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "gives no location" in err and len(err.strip().splitlines()) == 1 and not out.exists()
    rows = (abbe_run / "positioning_deviations.csv").read_text().splitlines()
    irregular = tmp_path / "d.csv"  # without the 30° target: the records would not lie on a grid
    irregular.write_text("\n".join(r for r in rows if not r.startswith("30,")) + "\n")
    assert main(["compensate", str(irregular), "--format", "isg-volcomp", "--out", str(out)]) == 2
    assert "--step-deg 15 keeps every measured target" in capsys.readouterr().err


def test_the_simulated_controller_applies_it(abbe_run, tmp_path):
    """The table loaded into the simulated axis (the scenario's compensation: the bench commands C − ECC):
    ISO 230-2's M, the range of the mean bidirectional deviation ECC describes, falls to a few steps
    of the 7.2″ stepper; the reversal B, which ECC leaves to the backlash compensation, stays."""
    table = tmp_path / "c.csv"
    assert main(["compensate", str(abbe_run), "--format", "isg-volcomp", "--step-deg", "15", "--out", str(table)]) == 0
    scenario = yaml.safe_load(BENCH.read_text())
    scenario["stage"]["compensation"] = {"format": "isg-volcomp", "file": "c.csv"}
    (tmp_path / "after.yaml").write_text(yaml.safe_dump(scenario))
    after = tmp_path / "after"
    assert main(["run", str(ABBE), "--scenario", str(tmp_path / "after.yaml"), "--seed", "7", "--out", str(after)]) == 0
    before, later = read_results(abbe_run).evaluation.iso230_2, read_results(after).evaluation.iso230_2
    assert later.M < before.M / 4 and later.M < 10.0, (before.M, later.M)
    assert abs(later.B - before.B) < 3.0
