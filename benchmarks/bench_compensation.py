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
Prints E and B (ISO 230-2, arcsec) before → after, and what `rtcal compensate` warned.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.compensation_loop import VERIFY, measure_after, measure_before, seated  # noqa: E402


def line(label: str, before: dict, after: dict) -> str:
    return (f"  {label:<34} E {before['E']:6.1f}″ → {after['E']:5.1f}″ ({before['E'] / after['E']:4.1f}×)"
            f"   B {before['B']:4.1f}″ → {after['B']:4.1f}″")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dense", action="store_true", help="also calibrate every 7.5° and verify between those targets")
    args = parser.parse_args()
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


if __name__ == "__main__":
    main()
