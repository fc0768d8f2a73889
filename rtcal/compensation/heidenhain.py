"""HEIDENHAIN nonlinear axis error compensation, a .COM table (docs/compensation.md): the
error curve (the measured error, 0 at the datum), entries 0 … 360°; the TNC 640 generation
with a BACKLASH column for the negative direction, the TNC 4xx generation one curve at a
power-of-two spacing whose points cover the turn. Sources: TNC 407/415/425 Technical Manual
01.98 pp. 4-26 … 4-31 (PDF pp. 151-156, 622), TNC 306/406 Technical Manual 3/97 p. 4-21, TNC
335/360 Technical Manual 8/95 p. 4-24, MANUALplus 620 Technical Manual (TNC 640 software
generation) 01/2012 pp. 708, 713-718."""

from __future__ import annotations

import math
import re
from typing import Any

import numpy as np

from rtcal.compensation.base import CompensationFormat, FormatOption, axis_option
from rtcal.compensation.siemens_lec import REFERENCE
from rtcal.compensation.table import (ARCSEC_PER_DEG, CompensationError, CompensationTable, empty, regular_table,
                                      sane)

NUMBER = r"([+-]?\d+(?:\.\d*)?)"
HEADER_4XX = re.compile(rf"BEGIN AXIS-([A-Z])\.COM DATUM:{NUMBER} DISTANCE:{NUMBER}")
HEADER_640 = re.compile(r"BEGIN AXIS_([A-Z])\.COM(?: MM| INCH)?")
# the TNC 4xx spacing is a power of two of the display step: "required distance of compensation
# points = 7 mm; possible power of two = 2^16 = 6.5536 mm" (TNC 407 p. 153), i.e. of 0.1 µm; for
# a rotary axis rtcal takes the same count of 0.0001°
TNC4XX_UNIT_DEG = 0.0001
GENERATIONS = ("tnc640", "tnc4xx")


def tnc4xx_spacing(step_deg: float, max_points: int) -> float:
    """The spacing of a TNC 4xx table over one turn: a power of two × 0.0001° (TNC 407 p. 153), the
    largest not beyond the table's step — and no finer than lets ``max_points`` entries cover the
    turn: "the entered distance between correction points must be large enough that the 64
    correction points will cover a complete revolution of 360°" (TNC 306/406 p. 4-21)."""
    finest = math.ceil(math.log2(360.0 / (max_points - 1) / TNC4XX_UNIT_DEG) - 1e-9)
    return float(2 ** max(math.floor(math.log2(step_deg / TNC4XX_UNIT_DEG) + 1e-9), finest) * TNC4XX_UNIT_DEG)


def covering(spacing_deg: float) -> np.ndarray:
    """Entries from 0° every ``spacing_deg`` up to the first at or beyond 360°: a power of two divides
    no turn, so the last lies beyond 360° and the one before it inside (the interval across 360°
    is read from both)."""
    return np.arange(math.ceil(360.0 / spacing_deg - 1e-9) + 1) * spacing_deg


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
                            "spacing, points covering the turn, one curve)", "default tnc640", pattern="|".join(GENERATIONS),
                            noun="generation", example="tnc640"))

    def write(self, table: CompensationTable, axis: str = "C", reference_deg: float = 0.0, generation: str = "tnc640") -> str:
        """The error curve: HEIDENHAIN's texts enter the error ("Error in Z [mm]", TNC 407 p. 153; "The
        error is positive if the table travel is too long", MP720 p. 151), so the value is −trim;
        "The error curve must always start with correction value = 0 at the datum point" (TNC 335
        p. 4-24): 0 at ``reference_deg``. A rotary axis's entries run 0 … 360 (TNC 407 p. 156).
        tnc640: AXISPOS per entry, the negative direction's curve in BACKLASH — "enter the
        compensation values measured in the negative direction of traverse in the BACKLASH column"
        (MANUALplus 620 p. 716). tnc4xx: DATUM 0° and a power-of-two DISTANCE (TNC 407 p. 153) whose
        entries cover the turn (TNC 306 p. 4-21), the last beyond 360° holding the curve's value
        there one turn on; the mean of both directions (no BACKLASH column in that generation's
        texts), resampled onto that spacing; 0 at the datum, the table's first entry."""
        # tnc4xx resamples onto its own spacing: the table's points need only be evenly spaced
        self.check_points(table, None if generation == "tnc640" else 360 * 100 + 1)
        if not 0.0 <= reference_deg < 360.0:
            raise CompensationError(f"--reference-deg {reference_deg:g}: the datum's angle lies in [0, 360)")
        up, down = -np.asarray(table.trim_up_deg, float), -np.asarray(table.trim_down_deg, float)
        if generation == "tnc4xx":
            if reference_deg != 0.0:
                raise CompensationError(f"heidenhain --generation tnc4xx: --reference-deg {reference_deg:g}: the error curve "
                                        "starts with 0 at the table's datum (TNC 335 p. 4-24), for a rotary axis its entry "
                                        "at 0° (TNC 407 p. 156: entries from 0 to 360): the reference is 0°")
            spacing = tnc4xx_spacing(table.step_deg, self.max_points)
            positions = covering(spacing)
            mean = np.interp(np.mod(positions, 360.0), table.positions_deg, (up + down) / 2)
            mean = mean - mean[0]
            lines = [f"BEGIN AXIS-{axis}.COM DATUM:+0.0000 DISTANCE:{spacing:+.4f}", f"NR AXISPOS {axis}"]
            lines += [f"{i} {p:+.4f} {v + 0.0:+.8f}" for i, (p, v) in enumerate(zip(positions, mean))]
        else:
            datum = float(np.interp(reference_deg, table.positions_deg, up, period=360.0))
            lines = [f"BEGIN AXIS_{axis}.COM", f"NR AXISPOS {axis} BACKLASH"]
            lines += [f"{i} {p:+.4f} {u - datum + 0.0:+.8f} {d - datum + 0.0:+.8f}"
                      for i, (p, u, d) in enumerate(zip(table.positions_deg, up, down))]
        lines.append("[END]")
        return "\n".join(lines) + "\n"

    def comment_note(self, **options: Any) -> str | None:
        return "a .COM table takes no comment line rtcal knows of"

    def instructions(self, table: CompensationTable, **options: Any) -> list[str]:
        axis, generation = options.get("axis", "C"), options.get("generation", "tnc640")
        reference = float(options.get("reference_deg", 0.0))
        assign = ("name it in the .CMA file (config.cma): the column " + axis + " of a line activated by * in ACTIVE "
                  "(MANUALplus 620 pp. 717-718); the axis's backlash (MP_backLash) is added at every reversal as well "
                  "(p. 708): set it so that the reversal is not compensated twice") if generation == "tnc640" else (
                  "name it in a .CMA line for the axis and set its MP730 bit (nonlinear compensation; TNC 407 pp. 4-26 "
                  "... 4-31); transfer it as .V, the .CMA as .S (p. 156)")
        lines = [f"load it as AXIS_{axis}.COM (the table's name in the .CMA file) and {assign}",
                 f"the values are the error curve, 0 at the datum ({reference:g} deg), as HEIDENHAIN's manuals enter it"]
        if generation == "tnc4xx":
            spacing = tnc4xx_spacing(table.step_deg, self.max_points)
            n = len(covering(spacing))
            lines.append(f"tnc4xx: the mean of both directions (the reversal is left to the axis's backlash compensation) "
                         f"every {spacing:g} deg = 2^{round(math.log2(spacing / TNC4XX_UNIT_DEG))} x 0.0001 deg (TNC 407 "
                         f"p. 153: a power of two), {n} entries from 0 to {(n - 1) * spacing:g} deg, covering the turn "
                         f"(TNC 306 p. 4-21); resampled from the table's {table.step_deg:g} deg points")
            if spacing > table.step_deg + 1e-9:
                lines.append(f"warning: {spacing:g} deg is coarser than the {table.step_deg:g} deg asked for: no finer power "
                             f"of two covers the turn in {self.max_points} entries")
        return lines

    def readings(self, table: CompensationTable, **options: Any) -> list[str]:
        """The sign of the values, the BACKLASH column (tnc640), the entry beyond 360° (tnc4xx) and
        the header: what no HEIDENHAIN text rtcal has states, each with its check on the machine."""
        axis, generation = options.get("axis", "C"), options.get("generation", "tnc640")
        up, down = -np.asarray(table.trim_up_deg) * ARCSEC_PER_DEG, -np.asarray(table.trim_down_deg) * ARCSEC_PER_DEG
        step = table.step_deg
        points = table.positions_deg[:-1]

        def move(angle: float, direction: int) -> str:  # HEIDENHAIN conversational positioning blocks
            return f"`L {axis}{angle - direction * step:+g} FMAX` `L {axis}{angle:+g} FMAX`"

        k = int(np.argmax(np.abs(up[:-1])))
        lines = [f"the sign: HEIDENHAIN's texts enter the error curve, none states that the control removes it. Check at "
                 f"{points[k]:g} deg, where the curve is largest ({up[k]:+.1f} arcsec): {move(points[k], 1)}, read the error "
                 "with the reference before loading the table and after; it must go from about "
                 f"{up[k]:+.1f} to about 0 arcsec; to about {2 * up[k]:+.1f} the control adds the curve: do not use the table"]
        if generation == "tnc4xx":
            spacing = tnc4xx_spacing(step, self.max_points)
            positions = covering(spacing)
            inside, beyond = positions[-2], positions[-1]
            at = (inside + 360.0) / 2
            mean = np.interp(np.mod(positions, 360.0), table.positions_deg, (up + down) / 2)
            mean = mean - mean[0]
            follows = float(np.interp(at, positions, mean))
            held = float(mean[-2])
            at = round(at, 3)
            lines.append(f"the entry beyond 360 deg ({beyond:g}): TNC 407 p. 156 says a rotary axis \"only recognizes "
                         f"corrections of entries from 0 to 360\"; rtcal reads the interval {inside:g} ... 360 deg from "
                         f"the entries either side, a control may hold the last one inside. Check at {at:g} deg: "
                         f"{move(at, 1)}, read the error before loading the table and after; it must change by "
                         f"{-follows:+.1f} arcsec (interpolated to the entry beyond 360); by {-held:+.1f} the control holds "
                         f"the last entry there")
        else:
            j = int(np.argmax(np.abs(up[:-1] - up[0])))
            datum = float(np.interp(float(options.get("reference_deg", 0.0)), table.positions_deg, up, period=360.0))
            column, backlash = up[j] - datum, down[j] - datum
            lines.append(f"the BACKLASH column: MANUALplus 620 p. 716 has it hold \"the compensation values measured in the "
                         "negative direction of traverse\" — rtcal writes the negative direction's whole curve there; a "
                         f"control may add it to the {axis} column for negative travel instead. Check at {points[j]:g} deg, "
                         f"approached negatively: {move(points[j], -1)}, read the error before loading the table and "
                         f"after; it must change by {-backlash:+.1f} arcsec (BACKLASH the negative curve); by "
                         f"{-(column + backlash):+.1f} the control adds it to the {axis} column: do not use the table")
        header = f"BEGIN AXIS_{axis}.COM" if generation == "tnc640" else f"BEGIN AXIS-{axis}.COM DATUM:... DISTANCE:..."
        lines.append(f"the header line (`{header}`) and the column line are from an open-source writer, not a HEIDENHAIN text. Check before loading: create an "
                     "empty .COM table on the control (its table editor), transfer it out (.V over the data interface, TNC "
                     "407 p. 156), and compare its first two lines with this file's; if they differ, put this file's rows "
                     "under the control's own header and column line")
        return lines

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
        if old:
            spacing = float(old.group(3))
            exponent = math.log2(spacing / TNC4XX_UNIT_DEG) if spacing > 0 else -1.0
            if abs(exponent - round(exponent)) > 1e-9 or exponent < 0:
                raise CompensationError(f"{where}:1: DISTANCE {spacing:g} is not a power of two × 0.0001° (TNC 407 p. 153)")
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
        if old:
            return self._tnc4xx(a, float(old.group(2)), float(old.group(3)), where)
        return regular_table(a[:, 1], -a[:, 2], -a[:, 3] if backlash else -a[:, 2], where, self.max_points)

    def _tnc4xx(self, a: np.ndarray, datum: float, spacing: float, where: str) -> CompensationTable:
        """A TNC 4xx table of a rotary axis: DATUM 0, a power-of-two DISTANCE, entries from 0° to the
        first at or beyond 360° (they cover the turn), the first 0 (the error curve starts at 0 at
        the datum), as many as the control takes."""
        if datum != 0.0:
            raise CompensationError(f"{where}:1: DATUM {datum:g}: a rotary axis's entries run from 0° (TNC 407 p. 156)")
        if not (len(a) <= self.max_points and a[-1, 1] >= 360.0 - 1e-9 and (len(a) < 2 or a[-2, 1] < 360.0 - 1e-9)):
            raise CompensationError(f"{where}: {len(a)} entries to {a[-1, 1]:g}°: they must cover the turn, the last at or "
                                    f"beyond 360° and the one before inside it (TNC 306 p. 4-21), at most {self.max_points}")
        if a[0, 2] != 0.0:
            raise CompensationError(f"{where}:3: the error curve starts with 0 at the datum (TNC 335 p. 4-24)")
        values = -a[:, 2]
        sane(values, values, where)
        return CompensationTable(a[:, 1], values, values)
