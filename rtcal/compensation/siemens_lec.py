"""SINUMERIK LEC (leadscrew/encoder error compensation, docs/compensation.md): one modulo table,
the mean of both directions; a positive value moves the axis negative."""

from __future__ import annotations

from rtcal.compensation import _siemens
from rtcal.compensation.base import CompensationFormat
from rtcal.compensation.table import CompensationError, CompensationTable, regular_table


class SiemensLecFormat(CompensationFormat):
    name = "siemens-lec"
    max_points = _siemens.MAX_POINTS
    fixed_pitch = "$AA_ENC_COMP_STEP"
    sign = "the deviation (−trim), deg: a positive value moves the axis negative; one table, the mean of both directions"
    comment = ("; ", "")
    one_direction = ("the one LEC table stands for the mean of both directions, the reversal left to the axis's backlash "
                     "compensation; from one direction it is that direction's curve, off the mean by half the reversal at "
                     "each target")
    options = (_siemens.AXIS,)

    def write(self, table: CompensationTable, axis: str = "C1") -> str:
        """LEC, one table (the mean of both directions): a positive value moves the axis negative, so
        the value is the deviation, −trim, in degrees; modulo: the value at MAX repeats MIN's."""
        self.check_points(table)
        mean = (table.trim_up_deg + table.trim_down_deg) / 2
        lines = ["%_N_AX_EEC_INI", *self.comment_lines(table), "CHANDATA(1)"]
        lines += [f"$AA_ENC_COMP[0,{i},{axis}]={-v + 0.0:.8f}" for i, v in enumerate(mean)]
        lines += [f"$AA_ENC_COMP_STEP[0,{axis}]={table.step_deg:.6f}", f"$AA_ENC_COMP_MIN[0,{axis}]=0.0",
                  f"$AA_ENC_COMP_MAX[0,{axis}]=360.0", f"$AA_ENC_COMP_IS_MODULO[0,{axis}]=1", "M17"]
        return "\n".join(lines) + "\n"

    def parse(self, text: str, where: str = "<siemens-lec>") -> CompensationTable:
        points, settings, _ = _siemens.values(text, where, "AA_ENC_COMP")
        if list(points) != [0]:
            raise CompensationError(f"{where}: expected one table, encoder 0 ($AA_ENC_COMP[0,…])")
        positions, values = _siemens.table(points[0], settings.get(0, {}), where)
        return regular_table(positions, -values, -values, where, self.max_points)
