"""SINUMERIK CEC (sag/cross-error compensation of an axis on itself, docs/compensation.md): one
modulo table per approach direction, tables N and N+1; the value is added to the setpoint (the
trim). Sources: K3 4.4.3/4.4.4, edition 03/2013 (pp. 249, 264, 268); 802D sl example p. 222."""

from __future__ import annotations

from typing import Any

import numpy as np

from rtcal.compensation import _siemens
from rtcal.compensation.base import CompensationFormat, FormatOption
from rtcal.compensation.table import CompensationError, CompensationTable, regular_table

TABLE_INDEX = FormatOption("table_index", "--table-index", "the first of the two CEC tables (N positive, N+1 negative "
                           "approach; table numbers are shared NC resources: take two the machine does not use)",
                           "default 0", type=int)


class SiemensCecFormat(CompensationFormat):
    name = "siemens-cec"
    max_points = _siemens.MAX_POINTS
    fixed_pitch = "$AN_CEC_STEP"
    sign = ("the trim, deg, added to the axis's setpoint (sign not stated in the manuals rtcal has: check one point); "
            "table N the positive, N+1 the negative approach ($AN_CEC_DIRECTION 1 / -1, K3 p. 249)")
    comment = ("; ", "")
    one_direction = ("both CEC tables (DIRECTION 1 and -1) would hold the same values and compensate no reversal: that is "
                     "left to the axis's backlash compensation (keep it set), and the unmeasured direction is assumed to "
                     "follow the measured one")
    options = (_siemens.AXIS, TABLE_INDEX, _siemens.POINTS)

    def write(self, table: CompensationTable, axis: str = "C1", table_index: int = 0,
              max_points: int = _siemens.DEFAULT_POINTS) -> str:
        """CEC, one table per direction — "Position-dependent backlash compensation can be implemented
        using two tables, one of which affects the positive traversing direction, the other … the
        negative" (K3 4.4.4.3, p. 264): table N DIRECTION 1, table N+1 DIRECTION -1; the axis
        compensated on itself, written in parentheses as every manual example does (802D sl p. 222
        ``=(AX2)``, K3 p. 268); modulo, MAX's value equal to MIN's (p. 249)."""
        _siemens.check_size(max_points)
        if table_index < 0:
            raise CompensationError(f"--table-index {table_index}: a table number >= 0 (tables N and N+1 are written)")
        self.check_points(table, max_points)
        lines = ["%_N_NC_CEC_INI", *self.comment_lines(table),
                 *(f"; {line}" for line in self.instructions(table, axis=axis, table_index=table_index)), "CHANDATA(1)"]
        for t, (values, sense) in enumerate(((table.trim_up_deg, 1), (table.trim_down_deg, -1)), start=table_index):
            lines += [f"$AN_CEC[{t},{i}]={v + 0.0:.8f}" for i, v in enumerate(values)]  # + 0.0: no "-0.0"
            lines += [f"$AN_CEC_INPUT_AXIS[{t}]=({axis})", f"$AN_CEC_OUTPUT_AXIS[{t}]=({axis})",
                      f"$AN_CEC_STEP[{t}]={table.step_deg:.6f}", f"$AN_CEC_MIN[{t}]=0.0", f"$AN_CEC_MAX[{t}]=360.0",
                      f"$AN_CEC_DIRECTION[{t}]={sense}", f"$AN_CEC_MULT_BY_TABLE[{t}]=0", f"$AN_CEC_IS_MODULO[{t}]=1"]
        lines.append("M17")
        return "\n".join(lines) + "\n"

    def instructions(self, table: CompensationTable, **options: Any) -> list[str]:
        axis, t, n = options.get("axis", "C1"), int(options.get("table_index", 0)), len(table.positions_deg)
        return [f"MD18342 $MN_MM_CEC_MAX_POINTS[{t}] >= {n} and [{t + 1}] >= {n} (K3 p. 264; the 828D has 8 tables of "
                f"200 points); tables {t} and {t + 1} must not be in use for another compensation (sag tables often are)",
                f"MD32710 $MA_CEC_ENABLE[{axis}] = 1 and SD41300 $SN_CEC_TABLE_ENABLE[{t}] = [{t + 1}] = 1 (K3 4.4.3), "
                f"then POWER ON; the compensation acts once {axis} is referenced",
                "the sign of a CEC value (rtcal: added to the setpoint) is not stated in the manuals rtcal has: check one "
                "point with a reference before trusting the table (docs/compensation.md)"]

    def parse(self, text: str, where: str = "<siemens-cec>") -> CompensationTable:
        points, settings, _ = _siemens.values(text, where, "AN_CEC")
        tables: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for t, values in points.items():
            s = settings.get(t, {})
            axes = [_siemens.axis_name(s[k]) if k in s else None for k in ("_INPUT_AXIS", "_OUTPUT_AXIS")]
            if axes[0] is None or axes[0] != axes[1]:
                raise CompensationError(f"{where}: table {t}: rtcal reads a rotary axis compensated on itself "
                                        "($AN_CEC_INPUT_AXIS = $AN_CEC_OUTPUT_AXIS)")
            if s.get("_MULT_BY_TABLE", "0").strip() not in ("0", "0.0"):
                raise CompensationError(f"{where}: table {t}: $AN_CEC_MULT_BY_TABLE multiplies by another table; rtcal "
                                        "reads a table applied alone (0)")
            try:
                direction = int(float(s.get("_DIRECTION", "0")))
            except ValueError:
                raise CompensationError(f"{where}: table {t}: $AN_CEC_DIRECTION must be 1, -1 or 0") from None
            if direction not in (1, -1, 0) or direction in tables or (direction == 0 and tables):
                raise CompensationError(f"{where}: table {t}: one table per direction (DIRECTION 1 and -1), or one for both (0)")
            tables[direction] = _siemens.table(values, s, f"{where}: table {t}")
        if 0 in tables:
            positions, both = tables[0]
            return regular_table(positions, both, both, where, self.max_points)
        if 1 not in tables or -1 not in tables:
            raise CompensationError(f"{where}: a table for each direction ($AN_CEC_DIRECTION = 1 and -1) is needed")
        (positions, up), (positions_down, down) = tables[1], tables[-1]
        if len(positions) != len(positions_down) or not np.allclose(positions, positions_down):
            raise CompensationError(f"{where}: both directions' tables need the same MIN, MAX and STEP")
        return regular_table(positions, up, down, where, self.max_points)
