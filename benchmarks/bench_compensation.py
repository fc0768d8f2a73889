"""The closed loop calibrate → compensate → load → verify on the shipped simulated bench, at the
calibration targets and between them: the figures docs/compensation.md quotes.

    python benchmarks/bench_compensation.py [--dense]

The shipped ISO 230-2 test (procedures/iso230_2_polygon.yaml, 12 targets on multiples of 15°)
on its bench (procedures/scenarios/abbe_bench.yaml: a 20″ once-per-turn error, the worm's 6″
12th harmonic — period 30° — an 8″ reversal, a 0.002° stepper); its LinuxCNC table at the
measured targets (the default) loaded into the simulated controller; the test again, and the
verification between the targets (procedures/iso230_2_verification.yaml: the polygon seated
7.5° round), each with another seed. ``--dense`` adds a calibration every 7.5° (the
verification procedure seated at 0° and 7.5°), verified between its targets (3.75° and 11.25°),
with its table at the measured targets and resampled onto a 15° grid (--step-deg 15).
``--fanuc-units`` puts a FANUC table on an IS-B axis (detection unit 0.001°): one written for
IS-C (0.0001°) — refused by the bench's loading, which compares the unit the file states with the
axis's; and what the control would do with it had the file not said (its first line stripped) —
and one written for IS-B. Prints E and B (ISO 230-2, arcsec) before → after, and what
`rtcal compensate` warned. ``--backlash-misread`` (tests/data/smooth_reversal_bench.yaml): the HEIDENHAIN
table applied as rtcal reads its BACKLASH column (the negative direction's curve) and as a control
that adds it to the axis column would (that column replaced by C + BACKLASH, read rtcal's way).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.compensation_loop import (ISO, VERIFY, fanuc_options, load_table, measure_after, measure_before,  # noqa: E402
                                     rtcal, seated)

IS_B = {"detection_unit_deg": 0.001}


def line(label: str, before: dict, after: dict) -> str:
    return (f"  {label:<34} E {before['E']:6.1f}″ → {after['E']:5.1f}″ ({before['E'] / after['E']:4.1f}×)"
            f"   B {before['B']:4.1f}″ → {after['B']:4.1f}″")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dense", action="store_true", help="also calibrate every 7.5° and verify between those targets")
    parser.add_argument("--fanuc-units", action="store_true", help="only: a FANUC table on an IS-B axis, for the right and "
                                                                  "the wrong detection unit")
    parser.add_argument("--backlash-misread", action="store_true", help="only: a HEIDENHAIN table's BACKLASH column read "
                                                                       "both ways")
    args = parser.parse_args()
    if args.backlash_misread:
        backlash_misread()
        return
    if args.fanuc_units:
        fanuc_units()
        return
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        before = measure_before(work / "iso")
        after = measure_after(before, work / "iso", "measured")
        print("ISO 230-2 test (12 targets), LinuxCNC table at the measured targets:")
        print(line("at the calibration targets", before.at, after.at))
        print(line("between them (24 targets, +7.5°)", before.between, after.between))
        print("  " + after.console.strip().replace("\n", "\n  "))
        if args.dense:
            calibration = seated(VERIFY, [0, 7.5], work / "dense.yaml")
            between = seated(VERIFY, [3.75, 11.25], work / "dense-between.yaml")
            before = measure_before(work / "dense", calibration, between)
            for name, options in (("measured", ()), ("grid15", ("--step-deg", "15"))):
                after = measure_after(before, work / "dense", name, options, calibration=calibration, between=between)
                print(f"every 7.5° (48 targets), table {'at the measured targets' if not options else 'on a 15° grid'}:")
                print(line("at the calibration targets", before.at, after.at))
                print(line("between them (48 targets, +3.75°)", before.between, after.between))
                print("  " + after.console.strip().replace("\n", "\n  "))


def fanuc_units() -> None:
    """The ISO test's FANUC table (--step-deg 15) on an IS-B axis: for IS-C, for IS-C unstated, for IS-B."""
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        before = measure_before(work)
        wrong = work / "is-c.fanuc"
        code, _, err = rtcal("compensate", before.calibration, "--format", "fanuc", "--step-deg", "15", "--out", wrong,
                             *fanuc_options({"detection_unit_deg": 0.0001}))
        assert code == 0, err
        code, _, err = rtcal("validate", load_table(wrong, "fanuc", axis=IS_B))
        print("FANUC table for IS-C (0.0001°) loaded on an IS-B axis (0.001°):")
        print(f"  refused (exit {code}): {err.strip()}")
        unstated = "%\n" + wrong.read_text().split("\n", 1)[1]  # what the control takes: it skips the statement
        print(f"  unstated, as the control reads it: E {before.at['E']:.1f}″ → {predicted_e(before, unstated):.1f}″ "
              "predicted (the calibration's readings plus the trims the IS-B control applies; a run aborts: the axis "
              "is sent beyond the autocollimator's face window)")
        right = measure_after(before, work, "is-b", ("--step-deg", "15"), fmt="fanuc", axis=IS_B)
        print("FANUC table for IS-B on the IS-B axis:")
        print(line("at the calibration targets", before.at, right.at))
        print(line("between them (24 targets, +7.5°)", before.between, right.between))
        print(f"  predicted as above: E {before.at['E']:.1f}″ → "
              f"{predicted_e(before, (work / 'is-b.fanuc').read_text()):.1f}″ (its own readings: no new noise)")


def backlash_misread() -> None:
    """E before and after the ISO test's HEIDENHAIN table on the smooth bench, BACKLASH read both ways."""
    smooth = REPO / "tests" / "data" / "smooth_reversal_bench.yaml"
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        calibration = work / "calibration"
        code, _, err = rtcal("run", ISO, "--scenario", smooth, "--out", calibration)
        assert code == 0, err
        table = work / "h.com"
        code, _, err = rtcal("compensate", calibration, "--format", "heidenhain", "--step-deg", "15", "--out", table)
        assert code == 0, err
        lines = table.read_text().splitlines()
        added = [" ".join([*r.split()[:3], f"{float(r.split()[2]) + float(r.split()[3]):+.8f}"]) for r in lines[2:-1]]
        misread = work / "added.com"
        misread.write_text("\n".join(lines[:2] + added + lines[-1:]) + "\n")

        def e_after(path: Path) -> float:
            out = work / f"{path.stem}-after"
            code, _, err = rtcal("run", ISO, "--scenario", load_table(path, "heidenhain", smooth), "--seed", "7", "--out", out)
            assert code == 0, err
            return float(json.loads((out / "results.json").read_text())["evaluation"]["iso230_2"]["E"])

        before = json.loads((calibration / "results.json").read_text())["evaluation"]["iso230_2"]["E"]
        print(f"HEIDENHAIN table, smooth bench: E {before:.1f}″ → {e_after(table):.2f}″ with BACKLASH the negative curve "
              f"(rtcal's reading), → {e_after(misread):.1f}″ with BACKLASH added to the C column")


def predicted_e(before, text: str) -> float:
    """ISO 230-2 E of the calibration's own readings with the trims the IS-B control applies added:
    the motor is sent command + trim, so each deviation moves by the trim."""
    import numpy as np

    from rtcal.deliverables.evaluation import evaluate
    from rtcal.run.inputs import read_deviation_table
    from simulators.controllers import fanuc

    table, _ = read_deviation_table(str(before.calibration))
    applied = fanuc(text, "table", IS_B["detection_unit_deg"])
    trims = np.array([applied.trim_deg(t, d) for t, d in zip(table.target_deg, table.direction)]) * 3600.0
    moved = type(table)(table.target_deg, table.direction, table.run, table.deviation_arcsec + trims,
                        table.uncertainty_arcsec)
    return float(evaluate(moved)["E"])


if __name__ == "__main__":
    main()
