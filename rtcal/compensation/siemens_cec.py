"""SINUMERIK CEC (sag/cross-error compensation of an axis on itself, docs/compensation.md): one
modulo table per approach direction, tables N and N+1; the value is added to the setpoint (the
trim), 0 at the reference point in the positive direction. Sources: K3 4.4.3/4.4.4, edition
03/2013 (pp. 238, 249, 264, 268); 802D sl example p. 222."""

from __future__ import annotations

from typing import Any

import numpy as np

from rtcal.compensation import _siemens
from rtcal.compensation.base import CompensationFormat, FormatOption
from rtcal.compensation.siemens_lec import REFERENCE
from rtcal.compensation.table import ARCSEC_PER_DEG, CompensationError, CompensationTable, regular_table

# the 828D has "eight tables each with 200 interpolation points … This cannot be extended!" (K3
# p. 264); an 840D has the tables its MD18342 configures (no count rtcal has a text for: --cec-tables)
DEFAULT_TABLES = 8
MAX_TABLES = 1000  # rtcal's bound on --cec-tables, not a control's
TABLE_INDEX = FormatOption("table_index", "--table-index", "the first of the two CEC tables (N positive, N+1 negative "
                           "approach; table numbers are shared NC resources: take two the machine does not use)",
                           "default 0", type=int)
TABLES = FormatOption("tables", "--cec-tables", "how many CEC tables the control has, numbered 0 ... N-1",
                      f"default {DEFAULT_TABLES}, the 828D's (K3 p. 264); an 840D's as its MD18342 configures", type=int)


class SiemensCecFormat(CompensationFormat):
    name = "siemens-cec"
    max_points = _siemens.MAX_POINTS
    fixed_pitch = "$AN_CEC_STEP"
    sign = ("the trim, deg, added to the axis's setpoint (sign not stated in the manuals rtcal has: check one point); "
            "table N the positive, N+1 the negative approach ($AN_CEC_DIRECTION 1 / -1, K3 p. 249); 0 at the reference "
            "point in the positive direction")
    comment = ("; ", "")
    one_direction = ("both CEC tables (DIRECTION 1 and -1) would hold the same values and compensate no reversal: that is "
                     "left to the axis's backlash compensation (keep it set), and the unmeasured direction is assumed to "
                     "follow the measured one")
    options = (_siemens.AXIS, TABLE_INDEX, TABLES, REFERENCE, _siemens.POINTS)

    def write(self, table: CompensationTable, axis: str = "C1", table_index: int = 0, tables: int = DEFAULT_TABLES,
              reference_deg: float = 0.0, max_points: int = _siemens.DEFAULT_POINTS) -> str:
        """CEC, one table per direction — "Position-dependent backlash compensation can be implemented
        using two tables, one of which affects the positive traversing direction, the other … the
        negative" (K3 4.4.4.3, p. 264): table N DIRECTION 1, table N+1 DIRECTION -1, both among the
        control's tables; the axis compensated on itself, written in parentheses as every manual
        example does (802D sl p. 222 ``=(AX2)``, K3 p. 268); modulo, MAX's value equal to MIN's
        (p. 249). Both tables referred to 0 at the reference point in the positive direction (the
        negative keeps the reversal there), as K3 p. 238 asks of the LEC: "This prevents position
        jumps occurring when the LEC is activated"."""
        _siemens.check_size(max_points)
        self._check_tables(table_index, tables)
        reference_deg = _siemens.check_reference(reference_deg)
        self.check_points(table, max_points)
        at_reference = float(np.interp(reference_deg, table.positions_deg, table.trim_up_deg, period=360.0))
        notes = self.comment_lines(table) + self.instructions(table, axis=axis, table_index=table_index,
                                                              reference_deg=reference_deg)
        lines = ["%_N_NC_CEC_INI", *_siemens.semicolon_lines(notes), "CHANDATA(1)"]
        for t, (values, sense) in enumerate(((table.trim_up_deg, 1), (table.trim_down_deg, -1)), start=table_index):
            lines += [f"$AN_CEC[{t},{i}]={v - at_reference + 0.0:.8f}" for i, v in enumerate(values)]  # + 0.0: no "-0.0"
            lines += [f"$AN_CEC_INPUT_AXIS[{t}]=({axis})", f"$AN_CEC_OUTPUT_AXIS[{t}]=({axis})",
                      f"$AN_CEC_STEP[{t}]={table.step_deg:.6f}", f"$AN_CEC_MIN[{t}]=0.0", f"$AN_CEC_MAX[{t}]=360.0",
                      f"$AN_CEC_DIRECTION[{t}]={sense}", f"$AN_CEC_MULT_BY_TABLE[{t}]=0", f"$AN_CEC_IS_MODULO[{t}]=1"]
        lines.append("M17")
        return "\n".join(lines) + "\n"

    @staticmethod
    def _check_tables(table_index: int, tables: int) -> None:
        if not 2 <= tables <= MAX_TABLES:
            raise CompensationError(f"--cec-tables {tables}: the control's CEC tables, 2 ... {MAX_TABLES}")
        if not 0 <= table_index <= tables - 2:
            raise CompensationError(f"--table-index {table_index}: tables {table_index} and {table_index + 1} are written, "
                                    f"and the control has tables 0 ... {tables - 1} (--cec-tables {tables}; the 828D has "
                                    f"eight, K3 p. 264): a first table of 0 ... {tables - 2}")

    def instructions(self, table: CompensationTable, **options: Any) -> list[str]:
        axis, t, n = options.get("axis", "C1"), int(options.get("table_index", 0)), len(table.positions_deg)
        reference = float(options.get("reference_deg", 0.0))
        return [f"MD18342 $MN_MM_CEC_MAX_POINTS[{t}] >= {n} and [{t + 1}] >= {n} (K3 p. 264; the 828D has 8 tables of "
                f"200 points); {_siemens.memory_warning('MD18342')}; tables {t} and {t + 1} must not be in use for another "
                "compensation (sag tables often are)",
                f"MD32710 $MA_CEC_ENABLE[{axis}] = 1 and SD41300 $SN_CEC_TABLE_ENABLE[{t}] = [{t + 1}] = 1 (K3 4.4.3), "
                f"then POWER ON; the compensation acts once {axis} is referenced; the positive table is 0 at its reference "
                f"point, {reference:g} deg (--reference-deg: no position jump when the CEC is activated)",
                "the sign of a CEC value (rtcal: added to the setpoint) is not stated in the manuals rtcal has: check one "
                "point with a reference before trusting the table (docs/compensation.md)"]

    def readings(self, table: CompensationTable, **options: Any) -> list[str]:
        """The sign of a CEC value, and the line length: what no manual rtcal has settles."""
        axis, step = options.get("axis", "C1"), table.step_deg
        reference = float(options.get("reference_deg", 0.0))
        trims = (np.asarray(table.trim_up_deg) - float(np.interp(reference, table.positions_deg, table.trim_up_deg,
                                                                period=360.0))) * ARCSEC_PER_DEG
        k = int(np.argmax(np.abs(trims[:-1])))
        at = float(table.positions_deg[k])
        return [f"the sign: no manual rtcal has says whether a CEC value is added to the setpoint or taken from it; rtcal "
                f"adds it. Check at {at:g} deg, where the positive table's value is largest ({trims[k]:+.1f} arcsec): in MDA "
                f"`G90 G0 {axis}={at - step:g}` `G0 {axis}={at:g}`, read the error with the reference before loading the "
                f"table and after; it must change by {trims[k]:+.1f} arcsec (toward nominal); by {-trims[k]:+.1f} the "
                "control subtracts the value: do not use the table", _siemens.line_length_reading()]

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
