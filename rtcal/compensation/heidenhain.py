"""HEIDENHAIN nonlinear axis error compensation, a .COM table (docs/compensation.md): the
error curve (the measured error, 0 at the datum), entries 0 … 360°; the TNC 640 generation
with a BACKLASH column for the negative direction, the TNC 4xx generation one curve at a
power-of-two spacing. Sources: TNC 407/415/425 Technical Manual 01.98 pp. 4-26 … 4-31 (PDF
pp. 151-156, 622), TNC 335/360 Technical Manual 8/95 p. 4-24, MANUALplus 620 Technical Manual
(TNC 640 software generation) 01/2012 pp. 708, 713-718."""

from __future__ import annotations

import math
import re
from typing import Any

import numpy as np

from rtcal.compensation.base import CompensationFormat, FormatOption, axis_option
from rtcal.compensation.siemens_lec import REFERENCE
from rtcal.compensation.table import CompensationError, CompensationTable, empty, regular_table

NUMBER = r"([+-]?\d+(?:\.\d*)?)"
HEADER_4XX = re.compile(rf"BEGIN AXIS-([A-Z])\.COM DATUM:{NUMBER} DISTANCE:{NUMBER}")
HEADER_640 = re.compile(r"BEGIN AXIS_([A-Z])\.COM(?: MM| INCH)?")
# the TNC 4xx spacing is a power of two of the display step: "required distance of compensation
# points = 7 mm; possible power of two = 2^16 = 6.5536 mm" (TNC 407 p. 153), i.e. of 0.1 µm; for
# a rotary axis rtcal takes the same count of 0.0001°
TNC4XX_UNIT_DEG = 0.0001
GENERATIONS = ("tnc640", "tnc4xx")


def power_of_two_spacing(step_deg: float) -> tuple[float, float]:
    """The two power-of-two spacings (×0.0001°) either side of ``step_deg``."""
    k = math.floor(math.log2(step_deg / TNC4XX_UNIT_DEG))
    return 2 ** k * TNC4XX_UNIT_DEG, 2 ** (k + 1) * TNC4XX_UNIT_DEG


class HeidenhainFormat(CompensationFormat):
    name = "heidenhain"
    max_points = 256  # "Compensation value table (.COM) has more than 256 entries" is an error (TNC 407 p. 622)
    fixed_pitch = "the table's AXISPOS spacing"
    sign = ("the error curve (actual − nominal, deg; the opposite of the trim), 0 at the datum (TNC 407 p. 153 'Error in "
            "Z', MP720 p. 151; TNC 335 p. 4-24); tnc640: the positive direction's curve, the negative direction's in "
            "BACKLASH (MANUALplus 620 p. 716)")
    one_direction = ("the BACKLASH column would repeat the positive direction's curve and compensate no reversal: that is "
                     "left to the axis's backlash compensation, and the unmeasured direction is assumed to follow the "
                     "measured one")
    options = (axis_option(r"[A-Z]", "C"), REFERENCE,
               FormatOption("generation", "--generation", "the HEIDENHAIN control generation: tnc640 (TNC 640/620, "
                            "MANUALplus 620: AXISPOS any spacing, BACKLASH column) or tnc4xx (TNC 4xx: power-of-two "
                            "spacing, one curve)", "default tnc640", pattern="|".join(GENERATIONS), noun="generation",
                            example="tnc640"))

    def write(self, table: CompensationTable, axis: str = "C", reference_deg: float = 0.0, generation: str = "tnc640") -> str:
        """The error curve: HEIDENHAIN's texts enter the error ("Error in Z [mm]", TNC 407 p. 153; "The
        error is positive if the table travel is too long", MP720 p. 151), so the value is −trim;
        "The error curve must always start with correction value = 0 at the datum point" (TNC 335
        p. 4-24): 0 at ``reference_deg``. A rotary axis's entries run 0 … 360 (TNC 407 p. 156).
        tnc640: AXISPOS per entry, the negative direction's curve in BACKLASH — "enter the
        compensation values measured in the negative direction of traverse in the BACKLASH column"
        (MANUALplus 620 p. 716). tnc4xx: DATUM and a power-of-two DISTANCE (TNC 407 p. 153), the
        mean of both directions (no BACKLASH column in that generation's texts)."""
        self.check_points(table)
        if not 0.0 <= reference_deg < 360.0:
            raise CompensationError(f"--reference-deg {reference_deg:g}: the datum's angle lies in [0, 360)")
        up, down = -np.asarray(table.trim_up_deg, float), -np.asarray(table.trim_down_deg, float)
        if generation == "tnc4xx":
            units = table.step_deg / TNC4XX_UNIT_DEG
            if abs(2 ** round(math.log2(units)) - units) > 1e-6:
                lo, hi = power_of_two_spacing(table.step_deg)
                raise CompensationError(
                    f"heidenhain --generation tnc4xx: the spacing of {table.step_deg:g}° is not a power of two (TNC 407 "
                    f"p. 153: 2^n × 0.0001°); the nearest are {lo:g}° and {hi:g}°, and no power of two of at least "
                    f"{360 / (self.max_points - 1):.3g}° divides 360°, so no one-turn table fits: use --generation tnc640")
            mean = (up + down) / 2
            mean = mean - float(np.interp(reference_deg, table.positions_deg, mean, period=360.0))
            lines = [f"BEGIN AXIS-{axis}.COM DATUM:+0.0000 DISTANCE:{table.step_deg:+.4f}", f"NR AXISPOS {axis}"]
            lines += [f"{i} {p:+.4f} {v + 0.0:+.8f}" for i, (p, v) in enumerate(zip(table.positions_deg, mean))]
        else:
            datum = float(np.interp(reference_deg, table.positions_deg, up, period=360.0))
            lines = [f"BEGIN AXIS_{axis}.COM", f"NR AXISPOS {axis} BACKLASH"]
            lines += [f"{i} {p:+.4f} {u - datum + 0.0:+.8f} {d - datum + 0.0:+.8f}"
                      for i, (p, u, d) in enumerate(zip(table.positions_deg, up, down))]
        lines.append("[END]")
        return "\n".join(lines) + "\n"

    def instructions(self, table: CompensationTable, **options: Any) -> list[str]:
        axis, generation = options.get("axis", "C"), options.get("generation", "tnc640")
        reference = float(options.get("reference_deg", 0.0))
        assign = ("name it in the .CMA file (config.cma): the column " + axis + " of a line activated by * in ACTIVE "
                  "(MANUALplus 620 pp. 717-718); the axis's backlash (MP_backLash) is added at every reversal as well "
                  "(p. 708): set it so that the reversal is not compensated twice") if generation == "tnc640" else (
                  "name it in a .CMA line for the axis and set its MP730 bit (nonlinear compensation; TNC 407 pp. 4-26 "
                  "... 4-31); transfer it as .V, the .CMA as .S (p. 156)")
        return [f"load it as AXIS_{axis}.COM (the table's name in the .CMA file) and {assign}",
                f"the values are the error curve, 0 at the datum ({reference:g} deg), as HEIDENHAIN's manuals enter it; no "
                "text rtcal has states the nonlinear compensation's sign outright: check one point before trusting the "
                "table (docs/compensation.md)"]

    def parse(self, text: str, where: str = "<heidenhain>") -> CompensationTable:
        """Either generation's table back to trims (−error): the TNC 640's AXISPOS/value/BACKLASH
        columns, or the TNC 4xx's DATUM + NR × DISTANCE."""
        lines = text.splitlines()
        while lines and not lines[-1].strip():
            lines.pop()
        first = lines[0].strip() if lines else ""
        old, new = HEADER_4XX.fullmatch(first), HEADER_640.fullmatch(first)
        if not (old or new):
            raise CompensationError(f"{where}:1: expected the header `BEGIN AXIS_C.COM` (TNC 640) or "
                                    "`BEGIN AXIS-C.COM DATUM:+0.0000 DISTANCE:+6.5536` (TNC 4xx)")
        match = old or new
        assert match is not None
        axis = match.group(1)
        columns = lines[1].split() if len(lines) > 1 else []
        backlash = columns == ["NR", "AXISPOS", axis, "BACKLASH"]
        if columns != ["NR", "AXISPOS", axis] and not backlash:
            raise CompensationError(f"{where}:2: expected the column line `NR AXISPOS {axis}` (or with BACKLASH)")
        if lines[-1].strip() != "[END]":
            raise CompensationError(f"{where}:{len(lines)}: the table ends with [END]")
        width = len(columns)
        rows: list[list[float]] = []
        for line_no, line in enumerate(lines[2:-1], start=3):
            parts = line.split()
            try:
                if len(parts) != width:
                    raise ValueError
                row = [float(v) for v in parts]
            except ValueError:
                raise CompensationError(f"{where}:{line_no}: expected `{' '.join(columns)}`") from None
            if row[0] != len(rows):
                raise CompensationError(f"{where}:{line_no}: NR {row[0]:g}: entries are numbered 0, 1, 2, …")
            if old and abs(row[1] - (float(old.group(2)) + float(old.group(3)) * row[0])) > 1e-4:
                raise CompensationError(f"{where}:{line_no}: AXISPOS {row[1]:g} is not DATUM + NR × DISTANCE")
            rows.append(row)
        if not rows:
            empty(where)
        a = np.array(rows, float)
        return regular_table(a[:, 1], -a[:, 2], -a[:, 3] if backlash else -a[:, 2], where, self.max_points)
