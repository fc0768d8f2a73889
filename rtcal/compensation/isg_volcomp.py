"""ISG / Beckhoff TwinCAT CNC Volumetric Compensation (TF5280): the rotary axis C as an error-parameter
file in the ISG CSV format, file_format ISG_CSV (docs/compensation.md has the rules with their sources).

What the manual says and this writer does (Beckhoff Information System, TF5280 "Volumetric
compensation", the same pages at isg-stuttgart.de/fileadmin/kernel/kernel-html/en-GB/):
- ISG CSV format (…/296429067.html): a header names the columns, arguments and parameters alike;
  the records follow in rows; row comments start with ``//``; a ``#`` makes a "file break", after
  which a new header and its records follow. rtcal writes the position (location) errors as one
  record under ``X0C Y0C A0C B0C``, a ``#``, then the component errors under ``C ECC …``.
- Units of measure (…/296426379.html): parameter values in millimetres (offsets) or rad (angles);
  the argument of a rotary axis in degrees, [0°, 360°].
- List of parameters (…/296423819.html): position errors X0C … C0C, component errors EXC, EYC,
  EZC, EAC, EBC, ECC of the C axis (ISO 230-1's names without the E of the location errors).
- Constancy at modulo passages, splicing (…/296434699.html): a record at 360° with the 0° values
  ("splicing by hand"), or ``enable_splicing`` (P-VOLC-00015) for a 1D table: rtcal writes the
  360° record, so the kernel's splicing is not needed.
- Interpolation (P-VOLC-00014): GRID (the default) refuses data not on a grid: the records lie on
  one even grid of C (``--step-deg`` for irregular targets).
The manual's own examples are tests/data/isg_volcomp/ (their "…" elisions left out). Not found in
the stored pages: whether ECC's sign is the error or its correction (rtcal writes ISO 230-1's error,
actual − commanded, as for every parameter; the manual's negate, P-VOLC-00009, acts on the X/Y/Z
output) and a direction-dependent parameter (none is listed: ECC is the mean of both directions,
the reversal stays the axis's backlash compensation's) — check one point on the control first.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from rtcal.compensation.base import ASCII, CompensationFormat, FormatOption
from rtcal.compensation.geometry import MOTION_UNITS, RAD_PER_ARCSEC, ErrorMotions, MeasuredLocation
from rtcal.compensation.table import ARCSEC_PER_DEG, CompensationError, CompensationTable, regular_table

AXES = "XYZABC"
ARGUMENTS = frozenset(AXES)
PARAMETERS = frozenset({f"E{a}{b}" for a in AXES for b in AXES} | {f"{a}0{b}" for a in AXES for b in AXES}
                       | {f"P0{a}" for a in "XYZ"} | {f"N0{a}" for a in "XYZ"} | {f"P{a}{b}" for a in "XYZ" for b in "ABC"}
                       | {f"V{a}{b}" for a in "XYZ" for b in AXES})
MAX_GAP_DEG = 60.0  # error motions interpolated over no wider gap (as `rtcal compensate --max-gap-deg`'s default)
NUMBER = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$")


@dataclass(frozen=True)
class Block:
    """One header and its records, as the control reads them: ``line`` is the header's line number."""

    header: tuple[str, ...]
    rows: np.ndarray  # records × columns
    line: int

    def column(self, name: str) -> np.ndarray:
        return self.rows[:, self.header.index(name)]


def read_blocks(text: str, where: str = "<isg-csv>") -> list[Block]:
    """An ISG CSV file as the manual describes it: ``//`` row comments, ``#`` file breaks, each
    block a header of known argument and parameter names (none twice) and records of as many finite
    numbers. What the manual does not show (a comment after values, an unknown name, a short record)
    is a CompensationError with its line, never a guess."""
    blocks: list[Block] = []
    header: tuple[str, ...] | None = None
    start = 0
    rows: list[list[float]] = []

    def close() -> None:
        if header is not None:
            blocks.append(Block(header, np.asarray(rows, dtype=float).reshape(len(rows), len(header)), start))

    for n, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("//"):
            continue
        if line.startswith("#"):  # a file break: a new header follows
            close()
            header, rows = None, []
            continue
        if "//" in line:
            raise CompensationError(f"{where}:{n}: a comment after values (the manual's comments are whole lines "
                                    "starting with //)")
        tokens = line.split()
        if header is None:
            bad = next((t for t in tokens if t not in ARGUMENTS and t not in PARAMETERS), None)
            if bad is not None:
                raise CompensationError(f"{where}:{n}: {bad!r} is not an argument (X, Y, Z, A, B, C) or an error "
                                        "parameter of the manual's list")
            twice = next((t for t in tokens if tokens.count(t) > 1), None)
            if twice is not None:
                raise CompensationError(f"{where}:{n}: {twice} named twice in the header")
            header, start = tuple(tokens), n
            continue
        if len(tokens) != len(header) or not all(NUMBER.match(t) for t in tokens):
            raise CompensationError(f"{where}:{n}: a record of {len(header)} numbers ({' '.join(header)}) expected")
        values = [float(t) for t in tokens]
        if not all(math.isfinite(v) for v in values):
            raise CompensationError(f"{where}:{n}: values must be finite")
        rows.append(values)
    close()
    if not blocks:
        raise CompensationError(f"{where}: no header and no records")
    return blocks


def _plain(text: str) -> str:
    """A comment as a control's character set takes it: ASCII (a run's name or a frame's formula may not be)."""
    return "".join(c if c in "()" else ASCII.get(c, c) for c in text).encode("ascii", "replace").decode()


def _fmt(value: float, unit: str) -> str:
    """mm to 0.1 nm, rad to 10⁻¹⁰ (2·10⁻⁵″); plain decimals as the manual writes them."""
    text = f"{value:.7f}" if unit == "mm" else f"{value:.10f}"
    return text.lstrip("-") if float(text) == 0 else text  # no "-0.0000000"


class IsgVolcompFormat(CompensationFormat):
    name = "isg-volcomp"
    max_points = 3601  # one record per 0.1° over a turn; the control's own bound is vol_comp[i].max_records
    fixed_pitch = "interpolation GRID (P-VOLC-00014): records on one grid of C"
    sign = ("ISO 230-1 error parameters as measured (actual − nominal): ECC = e = −trim, the mean of both directions, "
            "in rad; EXC, EYC in mm, EAC, EBC in rad; X0C, Y0C in mm, A0C, B0C in rad")
    comment = ("// ", "")
    one_direction = ("VolComp holds one ECC per position, whatever the direction: the measured direction is written, and "
                     "the axis's reversal is not measured for its backlash compensation either")
    options = (
        FormatOption("error_motions", "--error-motions-from", "a run whose ISO 230-1 error motions to write",
                     "default: the source run's (EYC, EAC from the Abbe method's dial indicators; EXC, EYC, EAC, EBC from "
                     "seed 000's second mount)", metavar="RUN"),
        FormatOption("location", "--location-from", "a run whose location errors (X0C, Y0C, A0C, B0C; the R-test's "
                     "eight) to write", "default: the source run's (seed 000's network)", metavar="RUN"),
    )
    run_options: ClassVar[tuple[str, ...]] = ("error_motions", "location")  # the command line reads these runs

    def instructions(self, table: CompensationTable, **options: Any) -> list[str]:
        records = len(table.positions_deg) + (1 if options.get("location") is not None else 0)
        reversal = float(np.max(np.abs(table.trim_up_deg - table.trim_down_deg))) * ARCSEC_PER_DEG
        return [
            "list the file in the compensation's configuration: file[j] and file_format[j] ISG_CSV (P-VOLC-00012, "
            "P-VOLC-00013), the rotary axis's logical number as c (P-VOLC-00006)",
            f"vol_comp[i].max_records ≥ {records} (this file's records, plus any other file of the same compensation)",
            f"interpolation GRID (P-VOLC-00014): the records lie every {table.step_deg:g}° of C; enable_splicing "
            "(P-VOLC-00015) may stay 0: the 360° records repeat the 0° ones",
            f"ECC is the mean of both directions: the axis's reversal (up to {reversal:.2f}″ here) stays with its "
            "backlash compensation; check ECC's sign on one point before use (docs/compensation.md)",
        ]

    def write(self, table: CompensationTable, error_motions: ErrorMotions | None = None,
              location: MeasuredLocation | None = None) -> str:
        """The location errors as one record, a file break, then ECC (and the error motions given)
        against C from 0° to 360° on the table's grid, the 360° record repeating the 0° one."""
        self.check_points(table)
        c_deg = np.asarray(table.positions_deg, float)
        ecc_arcsec = -(np.asarray(table.trim_up_deg) + np.asarray(table.trim_down_deg)) / 2.0 * ARCSEC_PER_DEG
        ecc_arcsec = ecc_arcsec - ecc_arcsec[0]  # the reference point keeps its place: no jump when it is switched on
        columns: dict[str, tuple[np.ndarray, str]] = {"ECC": (ecc_arcsec * RAD_PER_ARCSEC, "rad")}
        lines = ["// rtcal isg-volcomp: ISO 230-1 error parameters of the rotary axis C, ISG CSV (TF5280 Volumetric "
                 "Compensation, file_format ISG_CSV)",
                 "// units (the manual's): argument C in degrees 0 ... 360; lengths in mm; angles in rad",
                 "// values are the axis's errors as measured (ISO 230-1: actual - nominal); ECC = angular positioning "
                 "error, the mean of both approach directions, 0 at C = 0",
                 "// records at C = 360 repeat those at C = 0 (splicing by hand, as the manual shows)"]
        if error_motions is not None:
            gap = error_motions.widest_gap_deg()
            if gap > MAX_GAP_DEG:
                raise CompensationError(f"{self.name}: the error motions ({error_motions.source}) leave a gap of {gap:g}° "
                                        f"(at most {MAX_GAP_DEG:g}° is interpolated over): not from a full turn")
            at = error_motions.at(c_deg)
            for name in MOTION_UNITS:
                if name in at:
                    columns[name] = (at[name], MOTION_UNITS[name])
            lines += [f"// error motions from {error_motions.source}: {error_motions.note}"]
            lines += [f"// u (1 sigma) of {name} up to {u:.3g} {MOTION_UNITS[name]}" for name, u in error_motions.u.items()]
        else:
            lines.append("// error motions: none given (EXC, EYC, EAC, EBC not in this file)")
        lines += self.comment_lines(table)
        if location is not None:
            si = location.in_si()
            lines += [f"// position (location) errors from {location.source}; frame: {location.errors.frame}",
                      "// X0C, Y0C are relative to that frame's origin: subtract the control's nominal centre of rotation "
                      "(PXC, PYC) if it is not that origin"]
            lines += [f"// u (1 sigma) of {name}: {u:.3g} {unit}" for name, (_, u, unit) in si.items()]
            lines += ["  ".join(si), "  ".join(_fmt(v, unit) for v, _, unit in si.values()), "#"]
        else:
            lines.append("// position (location) errors: none given (X0C, Y0C, A0C, B0C not in this file)")
        lines = [_plain(line) if line.startswith("//") else line for line in lines]
        lines += ["// component errors of C as functions of C", "  ".join(["C", *columns])]
        for i, c in enumerate(c_deg):
            lines.append("  ".join([f"{c:.4f}", *(_fmt(float(v[i]), unit) for v, unit in columns.values())]))
        return "\n".join(lines) + "\n"

    def parse(self, text: str, where: str = "<isg-volcomp>") -> CompensationTable:
        """The ``C ECC …`` block back to trims (−ECC, both directions), checked as every rotary table
        is (0 … 360°, evenly spaced, closing); the other blocks are read and checked, not applied."""
        blocks = read_blocks(text, where)
        found = [b for b in blocks if "C" in b.header and "ECC" in b.header]
        if len(found) != 1:
            raise CompensationError(f"{where}: {'no' if not found else 'more than one'} block with the argument C and ECC")
        block = found[0]
        other = [h for h in block.header if h in ARGUMENTS and h != "C"]
        if other:
            raise CompensationError(f"{where}:{block.line}: ECC against C and {', '.join(other)}: rtcal reads a table of C alone")
        trims = -block.column("ECC") / RAD_PER_ARCSEC / ARCSEC_PER_DEG
        return regular_table(block.column("C"), trims, trims.copy(), f"{where}:{block.line}", self.max_points)
