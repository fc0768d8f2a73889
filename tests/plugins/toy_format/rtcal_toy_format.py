"""``toy-csv``: a compensation table as CSV, ``position_deg,trim_up_arcsec,trim_down_arcsec``, one
row per point from 0° to 360° (any spacing: the measured targets), the trim the controller adds
to a command approached upwards and downwards, in arcsec; the controller wraps it modulo one turn.
A format a spreadsheet or a home-made controller reads: the sample of an rtcal compensation-format
plugin (one class, registered by the entry point in pyproject.toml)."""

from __future__ import annotations

import math

import numpy as np

from rtcal.api import CompensationError, CompensationFormat, CompensationTable, FormatOption, sane

HEADER = "position_deg,trim_up_arcsec,trim_down_arcsec"


class ToyCsvFormat(CompensationFormat):
    name = "toy-csv"
    max_points = 721
    sign = "the trim the controller adds to the command, arcsec, per approach direction"
    one_direction = "both trim columns hold the measured direction's values: no reversal is compensated"
    options = (FormatOption("trim_decimals", "--trim-decimals", "decimals of the trims (arcsec)", "default 3", type=int),)

    def write(self, table: CompensationTable, trim_decimals: int = 3) -> str:
        self.check_points(table)
        if not 0 <= trim_decimals <= 6:
            raise CompensationError(f"--trim-decimals {trim_decimals}: 0 … 6")
        rows = [f"{p:.6f},{u * 3600.0 + 0.0:.{trim_decimals}f},{d * 3600.0 + 0.0:.{trim_decimals}f}"
                for p, u, d in zip(table.positions_deg, table.trim_up_deg, table.trim_down_deg)]
        return "\n".join([HEADER, *rows]) + "\n"

    def parse(self, text: str, where: str = "<toy-csv>") -> CompensationTable:
        lines = text.splitlines()
        while lines and not lines[-1].strip():
            lines.pop()
        if not lines or lines[0].strip() != HEADER:
            raise CompensationError(f"{where}:1: expected the header {HEADER}")
        rows: list[list[float]] = []
        for line_no, line in enumerate(lines[1:], start=2):
            try:
                row = [float(v) for v in line.split(",")]
                if len(row) != 3 or not all(math.isfinite(v) for v in row):
                    raise ValueError
            except ValueError:
                raise CompensationError(f"{where}:{line_no}: expected three finite numbers separated by commas") from None
            if rows and row[0] <= rows[-1][0]:
                raise CompensationError(f"{where}:{line_no}: positions must increase strictly")
            rows.append(row)
        if not 3 <= len(rows) <= self.max_points:
            raise CompensationError(f"{where}: {len(rows)} rows (3 … {self.max_points})")
        a = np.array(rows)
        if abs(a[0, 0]) > 1e-6 or abs(a[-1, 0] - 360.0) > 1e-6 or np.any(a[0, 1:] != a[-1, 1:]):
            raise CompensationError(f"{where}: the rows run from 0 to 360°, the one at 360° repeating the one at 0°")
        up, down = a[:, 1] / 3600.0, a[:, 2] / 3600.0
        sane(up, down, where)
        return CompensationTable(a[:, 0], up, down)
