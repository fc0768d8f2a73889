"""The closed loop calibrate → compensate → load → verify, on the simulated bench, at the
calibration targets and between them: used by tests/test_compensation.py and by
benchmarks/bench_compensation.py, which prints the figures docs/compensation.md quotes."""

from __future__ import annotations

import contextlib
import io
import json
import re
from dataclasses import dataclass
from pathlib import Path

from rtcal.cli import main

REPO = Path(__file__).resolve().parents[1]
ISO = REPO / "procedures" / "iso230_2_polygon.yaml"
VERIFY = REPO / "procedures" / "iso230_2_verification.yaml"
BENCH = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"
AFTER_SEED = 7  # the runs with the table loaded draw fresh noise (the bench's own seed is 11)


def rtcal(*argv: str) -> tuple[int, str, str]:
    """``rtcal ARGV`` in process: exit status, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def seated(procedure: Path, seatings_deg: list[float], out: Path) -> Path:
    """``procedure`` with the polygon seated at ``seatings_deg`` (its targets move with it: a full
    turn at each seating's offset + k·15°), without its bench (give one with --scenario)."""
    text = re.sub(r"(?m)^  seatings_deg: \[[^\]]*\]", f"  seatings_deg: [{', '.join(f'{s:g}' for s in seatings_deg)}]",
                  procedure.read_text())
    out.write_text(re.sub(r"(?m)^bench: .*$", "", text))
    return out


# what an engineer reads off a SINUMERIK file's `;` lines and enters as MD32450 (siemens-lec)
MD32450 = re.compile(r"^; MD32450 \$MA_BACKLASH\[0,\w+\]: add ([+-]\d+\.\d+) deg to its present value", re.M)


def md32450_deg(table_text: str) -> float:
    """The change of MD32450 $MA_BACKLASH the file's `;` lines ask for, deg (0: none asked for);
    the simulated axis starts with MD32450 = 0, so it becomes the machine datum."""
    found = MD32450.findall(table_text)
    assert len(found) <= 1, found
    return float(found[0]) if found else 0.0


# the simulated FANUC axis's detection unit unless a loop gives another (docs/compensation.md's loop: IS-C)
AXIS: dict[str, dict[str, float]] = {"fanuc": {"detection_unit_deg": 0.0001}}


def load_table(table: Path, fmt: str, bench: Path = BENCH, axis: dict[str, float] | None = None) -> Path:
    """``bench`` with ``table`` loaded into the simulated controller (``stage.compensation``),
    the machine data its `;` lines ask for (MD32450, ``backlash_deg``) entered, and the axis's own
    (``axis``: a FANUC axis's ``detection_unit_deg``, default AXIS), written beside the table (the
    scenario names it relative to itself)."""
    text = bench.read_text()
    assert "\nstage:\n" in text, bench
    out = table.parent / f"{table.name}.bench.yaml"
    backlash = md32450_deg(table.read_text())
    md = f", backlash_deg: {backlash!r}" if backlash else ""
    md += "".join(f", {k}: {v!r}" for k, v in (AXIS.get(fmt, {}) if axis is None else axis).items())
    out.write_text(text.replace("\nstage:\n", f"\nstage:\n  compensation: {{format: {fmt}, file: {table.name}{md}}}\n", 1))
    return out


def fanuc_options(axis: dict[str, float] | None = None) -> tuple[str, ...]:
    """What `rtcal compensate --format fanuc` needs: the axis's detection unit (default AXIS) and a first point."""
    unit = (AXIS["fanuc"] if axis is None else axis)["detection_unit_deg"]
    return ("--detection-unit-deg", f"{unit:g}", "--first-point", "0")


def run(procedure: Path, out: Path, *options: str) -> dict:
    """ISO 230-2 figures of one run of ``procedure`` on the shipped bench (or ``--scenario``)."""
    if "--scenario" not in options:
        options = ("--scenario", str(BENCH), *options)
    code, _, err = rtcal("run", procedure, "--out", out, *options)
    assert code == 0, err
    return json.loads((out / "results.json").read_text())["evaluation"]["iso230_2"]


@dataclass(frozen=True)
class Before:
    """A calibration run and a run between its targets, on the bench as it is: ISO 230-2 figures."""

    calibration: Path
    at: dict
    between: dict


@dataclass(frozen=True)
class After:
    """The same two measurements with the table loaded (another seed), and what `compensate` printed."""

    at: dict
    between: dict
    console: str


def measure_before(work: Path, calibration: Path = ISO, between: Path = VERIFY) -> Before:
    return Before(work / "calibration", run(calibration, work / "calibration"), run(between, work / "between-before"))


def measure_after(before: Before, work: Path, name: str, compensate: tuple[str, ...] = (), fmt: str = "linuxcnc",
                  calibration: Path = ISO, between: Path = VERIFY, axis: dict[str, float] | None = None) -> After:
    """Write the table from ``before``'s calibration (`rtcal compensate` with ``compensate``'s
    options; a FANUC table for the axis's detection unit unless they give one), load it into the
    bench (with ``axis``'s machine data), and measure at the targets and between them again."""
    table = work / f"{name}.{fmt}"
    if fmt == "fanuc" and "--detection-unit-deg" not in compensate:
        compensate = (*compensate, *fanuc_options(axis))
    code, out, err = rtcal("compensate", before.calibration, "--format", fmt, "--out", table, *compensate)
    assert code == 0, err
    return measure_loaded(table, fmt, work, name, out + err, calibration, between, axis)


def measure_loaded(table: Path, fmt: str, work: Path, name: str, console: str = "", calibration: Path = ISO,
                   between: Path = VERIFY, axis: dict[str, float] | None = None) -> After:
    """``table`` (a file of format ``fmt``) loaded into the bench with ``axis``'s machine data, and
    the measurements at the calibration targets and between them (another seed)."""
    bench = load_table(table, fmt, axis=axis)
    options = ("--scenario", str(bench), "--seed", str(AFTER_SEED))
    return After(run(calibration, work / f"{name}-at", *options), run(between, work / f"{name}-between", *options),
                 console)
