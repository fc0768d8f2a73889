"""SINUMERIK CEC (sag/cross-error compensation of an axis on itself, docs/compensation.md): one
modulo table per approach direction; the value is added to the setpoint (the trim)."""

from __future__ import annotations

import numpy as np

from rtcal.compensation import _siemens
from rtcal.compensation.base import CompensationFormat
from rtcal.compensation.table import CompensationError, CompensationTable, regular_table


class SiemensCecFormat(CompensationFormat):
    name = "siemens-cec"
    max_points = _siemens.MAX_POINTS
    fixed_pitch = "$AN_CEC_STEP"
    sign = "the trim, deg, added to the axis's setpoint; table 0 the positive, table 1 the negative approach"
    comment = ("; ", "")
    one_direction = ("both CEC tables (DIRECTION 1 and -1) would hold the same values and compensate no reversal: that is "
                     "left to the axis's backlash compensation (keep it set), and the unmeasured direction is assumed to "
                     "follow the measured one")
    options = (_siemens.AXIS,)

    def write(self, table: CompensationTable, axis: str = "C1") -> str:
        """CEC, one table per direction (table 0 positive, table 1 negative approach): the value is
        added to the axis's setpoint, so it is the trim, in degrees."""
        self.check_points(table)
        lines = ["%_N_NC_CEC_INI", *self.comment_lines(table), "CHANDATA(1)"]
        for t, (values, sense) in enumerate(((table.trim_up_deg, 1), (table.trim_down_deg, -1))):
            lines += [f"$AN_CEC[{t},{i}]={v + 0.0:.8f}" for i, v in enumerate(values)]  # + 0.0: no "-0.0"
            lines += [f"$AN_CEC_INPUT_AXIS[{t}]={axis}", f"$AN_CEC_OUTPUT_AXIS[{t}]={axis}",
                      f"$AN_CEC_STEP[{t}]={table.step_deg:.6f}", f"$AN_CEC_MIN[{t}]=0.0", f"$AN_CEC_MAX[{t}]=360.0",
                      f"$AN_CEC_DIRECTION[{t}]={sense}", f"$AN_CEC_IS_MODULO[{t}]=1"]
        lines.append("M17")
        return "\n".join(lines) + "\n"

    def parse(self, text: str, where: str = "<siemens-cec>") -> CompensationTable:
        points, settings, _ = _siemens.values(text, where, "AN_CEC")
        tables: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for t, values in points.items():
            s = settings.get(t, {})
            if s.get("_INPUT_AXIS") is None or s.get("_INPUT_AXIS") != s.get("_OUTPUT_AXIS"):
                raise CompensationError(f"{where}: table {t}: rtcal reads a rotary axis compensated on itself "
                                        "($AN_CEC_INPUT_AXIS = $AN_CEC_OUTPUT_AXIS)")
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
