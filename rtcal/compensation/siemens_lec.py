"""SINUMERIK LEC (measuring-system / leadscrew error compensation, docs/compensation.md): one
modulo table, the mean of both directions, referred to 0 at the reference point; a positive
value moves the axis negative. Sources: Siemens Function Manual Extended Functions, K3
"Compensations" 4.4.2, edition 03/2013 (pp. 238, 241, 242), and the 808D manual (p. 106). The
reversal the one table cannot hold goes to the axis's backlash compensation, MD32450 $MA_BACKLASH:
"Input of the compensation value is positive, if the encoder is leading the machine part (normal
situation), negative, if the encoder is behind the machine part" (SINUMERIK 808D Parameter Manual
08/2013, 6FC5397-8EP40-0BA0, p. 228); "Positive backlash (normal case): actual encoder value ahead
of real actual value (table): too little table travel" (SINUMERIK 840C NC machine data 09.95,
MD 220*, p. 6-41)."""

from __future__ import annotations

from typing import Any

import numpy as np

from rtcal.compensation import _siemens
from rtcal.compensation.base import CompensationFormat, FormatOption
from rtcal.compensation.table import CompensationError, CompensationTable, regular_table

REFERENCE = FormatOption("reference_deg", "--reference-deg", "the angle of the axis's reference point (datum), where "
                         "the table is 0", "default 0", type=float)


class SiemensLecFormat(CompensationFormat):
    name = "siemens-lec"
    max_points = _siemens.MAX_POINTS
    fixed_pitch = "$AA_ENC_COMP_STEP"
    sign = ("the deviation (−trim), deg: a positive value moves the axis negative (K3 p. 238); one table, the mean of "
            "both directions, 0 at the reference point (K3 p. 238)")
    comment = ("; ", "")
    one_direction = ("the one LEC table stands for the mean of both directions, the reversal left to the axis's backlash "
                     "compensation; from one direction it is that direction's curve, off the mean by half the reversal at "
                     "each target")
    options = (_siemens.AXIS, REFERENCE, _siemens.POINTS)

    def write(self, table: CompensationTable, axis: str = "C1", reference_deg: float = 0.0,
              max_points: int = _siemens.DEFAULT_POINTS) -> str:
        """One LEC table: "A positive compensation value causes the corresponding machine axis to move
        in the negative direction" (K3 p. 238), so the value is the deviation (−trim), in degrees;
        the mean of both directions (one table per encoder), 0 at the reference point (K3 p. 238);
        MIN 0, MAX 360, IS_MODULO 1, the value at MAX equal to MIN's, no gaps (K3 p. 241). What the
        control needs to take it (MD32700, MD38000, POWER ON, a referenced axis) as ``;`` lines."""
        _siemens.check_size(max_points)
        self.check_points(table, max_points)
        values = _siemens.mean_from_reference(table, _siemens.check_reference(reference_deg))
        lines = ["%_N_AX_EEC_INI", *_siemens.semicolon_lines(self.comment_lines(table) + self.instructions(
                     table, axis=axis, reference_deg=reference_deg)), "CHANDATA(1)"]
        lines += [f"$AA_ENC_COMP[0,{i},{axis}]={v + 0.0:.8f}" for i, v in enumerate(values)]
        lines += [f"$AA_ENC_COMP_STEP[0,{axis}]={table.step_deg:.6f}", f"$AA_ENC_COMP_MIN[0,{axis}]=0.0",
                  f"$AA_ENC_COMP_MAX[0,{axis}]=360.0", f"$AA_ENC_COMP_IS_MODULO[0,{axis}]=1", "M17"]
        return "\n".join(lines) + "\n"

    def instructions(self, table: CompensationTable, **options: Any) -> list[str]:
        axis, n = options.get("axis", "C1"), len(table.positions_deg)
        reference = float(options.get("reference_deg", 0.0))
        backlash = backlash_change_deg(table)
        if np.array_equal(table.trim_up_deg, table.trim_down_deg):
            md32450 = (f"MD32450 $MA_BACKLASH[0,{axis}]: leave it as it is (one direction measured: the reversal is "
                       "not known)")
        else:
            md32450 = (f"MD32450 $MA_BACKLASH[0,{axis}]: add {backlash:+.8f} deg to its present value (the table is the "
                       f"mean of both directions; the reversal measured, {-backlash * 3600.0:+.2f} arcsec on average, is "
                       "the backlash compensation's; 808D Parameter Manual p. 228: positive when the encoder leads the "
                       "machine part); NEW CONF")
        return [f"MD38000 $MA_MM_ENC_COMP_MAX_POINTS[0,{axis}] >= {n} (the table's {n} points; K3 p. 242; on an 808D at "
                f"most 200, p. 106); {_siemens.memory_warning('MD38000')}",
                f"load this file while MD32700 $MA_ENC_COMP_ENABLE[0,{axis}] = 0, then set it to 1 and POWER ON (K3 p. 238, "
                "808D p. 106)",
                f"the compensation acts only once {axis} is referenced; the table is 0 at its reference point, {reference:g} deg "
                "(K3 p. 238: no position jump when the LEC is activated)",
                md32450]

    def readings(self, table: CompensationTable, **options: Any) -> list[str]:
        return [_siemens.line_length_reading()]

    def parse(self, text: str, where: str = "<siemens-lec>") -> CompensationTable:
        points, settings, _ = _siemens.values(text, where, "AA_ENC_COMP")
        if list(points) != [0]:
            raise CompensationError(f"{where}: expected one table, encoder 0 ($AA_ENC_COMP[0,…])")
        positions, values = _siemens.table(points[0], settings.get(0, {}), where)
        return regular_table(positions, -values, -values, where, self.max_points)


def backlash_change_deg(table: CompensationTable) -> float:
    """What to add to MD32450 so the backlash compensation takes the reversal the one LEC table
    (the mean) leaves, deg. Positive backlash b: after a reversal the table travels b too little
    in the new direction (840C MD 220*, p. 6-41), so it lags in both directions: x̄↓ − x̄↑ = b
    (ISO 230-2, x = actual − target). A trim is −x per direction, so the value is the mean over
    one turn's points of x̄↓ − x̄↑ = trim↑ − trim↓ = −mean(B) (the entry at 360° repeats 0°'s)."""
    p = np.asarray(table.positions_deg, float)
    points = len(p) - 1 if len(p) > 1 and abs(p[-1] - p[0] - 360.0) < 1e-6 else len(p)
    return float(np.mean((np.asarray(table.trim_up_deg) - np.asarray(table.trim_down_deg))[:points]))
