"""HEIDENHAIN nonlinear axis error compensation, a .COM table (docs/compensation.md): entries
0 … 360° at one DISTANCE, the compensation value added to the axis position, one direction."""

from __future__ import annotations

import re

import numpy as np

from rtcal.compensation.base import CompensationFormat, axis_option
from rtcal.compensation.table import CompensationError, CompensationTable, empty, regular_table

HEIDENHAIN_HEADER = re.compile(r"BEGIN AXIS-([A-Z])\.COM DATUM:([+-]?\d+(?:\.\d*)?) DISTANCE:([+-]?\d+(?:\.\d*)?)")


class HeidenhainFormat(CompensationFormat):
    name = "heidenhain"
    max_points = 256
    fixed_pitch = "the header's DISTANCE"
    sign = "the trim, deg, added to the axis position; one table, the mean of both directions"
    one_direction = ("the one table stands for the mean of both directions, the reversal left to the axis's backlash "
                     "compensation; from one direction it is that direction's curve, off the mean by half the reversal at "
                     "each target")
    options = (axis_option(r"[A-Z]", "C"),)

    def write(self, table: CompensationTable, axis: str = "C") -> str:
        """A .COM table for nonlinear axis error compensation: entries 0 … 360°, the compensation value
        of the axis added to its position (the trim), one direction (the mean of both)."""
        self.check_points(table)
        mean = (table.trim_up_deg + table.trim_down_deg) / 2
        lines = [f"BEGIN AXIS-{axis}.COM DATUM:+0.0000 DISTANCE:{table.step_deg:+.4f}", f"NR AXISPOS {axis}"]
        lines += [f"{i} {p:+.4f} {v + 0.0:+.8f}" for i, (p, v) in enumerate(zip(table.positions_deg, mean))]
        lines.append("[END]")
        return "\n".join(lines) + "\n"

    def parse(self, text: str, where: str = "<heidenhain>") -> CompensationTable:
        lines = text.splitlines()
        while lines and not lines[-1].strip():
            lines.pop()
        header = HEIDENHAIN_HEADER.fullmatch(lines[0].strip()) if lines else None
        if not header:
            raise CompensationError(f"{where}:1: expected the header `BEGIN AXIS-C.COM DATUM:+0.0000 DISTANCE:+15.0000`")
        axis, datum, distance = header.group(1), float(header.group(2)), float(header.group(3))
        if len(lines) < 2 or lines[1].split() != ["NR", "AXISPOS", axis]:
            raise CompensationError(f"{where}:2: expected the column line `NR AXISPOS {axis}`")
        if lines[-1].strip() != "[END]":
            raise CompensationError(f"{where}:{len(lines)}: the table ends with [END]")
        rows: list[tuple[int, float, float]] = []
        for line_no, line in enumerate(lines[2:-1], start=3):
            parts = line.split()
            try:
                if len(parts) != 3:
                    raise ValueError
                row = (int(parts[0]), float(parts[1]), float(parts[2]))
            except ValueError:
                raise CompensationError(f"{where}:{line_no}: expected `NR AXISPOS value`") from None
            if row[0] != len(rows):
                raise CompensationError(f"{where}:{line_no}: NR {row[0]}: entries are numbered 0, 1, 2, …")
            if abs(row[1] - (datum + distance * row[0])) > 1e-4:
                raise CompensationError(f"{where}:{line_no}: AXISPOS {row[1]:g} is not DATUM + NR × DISTANCE")
            rows.append(row)
        if not rows:
            empty(where)
        a = np.array(rows, float)
        return regular_table(a[:, 1], a[:, 2], a[:, 2], where, self.max_points)
