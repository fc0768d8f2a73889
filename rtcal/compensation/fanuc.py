"""FANUC pitch error compensation for a rotary axis, bidirectional (docs/compensation.md):
parameters 3605 … 3627 and one incremental value per compensation point."""

from __future__ import annotations

import re

import numpy as np

from rtcal.compensation.base import CompensationFormat, FormatOption
from rtcal.compensation.table import CompensationError, CompensationTable, regular_table

FANUC_MAX_INCREMENT = 127  # a point's value, in detection units × magnification (−128 … 127)
FANUC_MAX_POINT = 1023  # highest compensation point number (0i series)
FANUC_LINE = re.compile(r"(\d+)( #0)? = ([+-]?\d+)(?:\s+\(.*\))?")


class FanucFormat(CompensationFormat):
    name = "fanuc"
    max_points = 1024
    fixed_pitch = "parameter 3624"
    sign = ("increments of the trim, detection units × magnification (3623): point k holds the trim's change over the "
            "interval ending at it; positive and negative travel tables")
    comment = ("(", ")")
    one_direction = ("the negative-travel table would repeat the positive one with 3627 = 0: the bidirectional pitch error "
                     "compensation then compensates no reversal, and the unmeasured direction is assumed to follow the "
                     "measured one")
    options = (FormatOption("unit_deg", "--detection-unit-deg", "the axis's detection unit",
                            "default 0.0001, IS-C; 0.001 for IS-B", type=float),
               FormatOption("first_point", "--first-point", "number of the reference position's point, 3620",
                            "default 0", type=int))

    def write(self, table: CompensationTable, unit_deg: float = 0.0001, first_point: int = 0) -> str:
        """Pitch error compensation, bidirectional (parameter 3605#0 = 1), as a parameter listing.

        Values are incremental, in detection units (``unit_deg``) × magnification (3623, the smallest
        that keeps every value within ±127): point k holds the change of the trim over the interval
        ending at it; over one turn they sum to zero, and the reference point (0°) holds the same
        value as the last (360°, the same position). The positive-travel table is 3621 = 3620 …
        3622; the negative-travel table follows it, 3626 being its farthest point on the − side (its
        first, at 0°), and 3627 its absolute value at the reference position."""
        self.check_points(table)
        if not unit_deg > 0 or abs(table.step_deg / unit_deg - round(table.step_deg / unit_deg)) > 1e-6:
            raise CompensationError(f"--detection-unit-deg {unit_deg:g}: must be positive and divide the {table.step_deg:g}° step")
        n = len(table.positions_deg) - 1
        up_points = list(range(first_point, first_point + n + 1))
        down_points = list(range(first_point + n + 1, first_point + 2 * n + 2))
        if first_point < 0 or down_points[-1] > FANUC_MAX_POINT:
            raise CompensationError(f"compensation points {first_point} … {down_points[-1]} do not fit 0 … {FANUC_MAX_POINT}: "
                                    "choose --first-point")

        for magnification in range(1, 101):
            unit = unit_deg * magnification
            cum_up = np.round(table.trim_up_deg / unit).astype(int)  # quantise the running trim, then difference: Σ = 0
            cum_down = np.round(table.trim_down_deg / unit).astype(int)
            inc_up, inc_down = np.diff(cum_up), np.diff(cum_down)
            if max(np.abs(inc_up).max(), np.abs(inc_down).max()) <= FANUC_MAX_INCREMENT:
                break
        else:
            raise CompensationError(f"fanuc: increments exceed ±{FANUC_MAX_INCREMENT} even at magnification 100")

        def values(inc: np.ndarray) -> list[int]:
            return [int(inc[-1])] + [int(v) for v in inc]  # the first point (0°) is the last (360°)

        lines = [f"(FANUC pitch error compensation for the rotary axis; detection unit {unit_deg:g} deg; written by rtcal)",
                 *self.comment_lines(table), "3605 #0 = 1  (bidirectional pitch error compensation)",
                 f"3620 = {first_point}  (compensation point of the reference position)",
                 f"3621 = {up_points[0]}  (farthest point on the - side, positive travel)",
                 f"3622 = {up_points[-1]}  (farthest point on the + side, positive travel)",
                 f"3623 = {magnification}  (magnification)",
                 f"3624 = {round(table.step_deg / unit_deg)}  (interval, detection units)",
                 f"3625 = {round(360.0 / unit_deg)}  (travel per revolution, detection units)",
                 f"3626 = {down_points[0]}  (farthest point on the - side, negative travel)",
                 f"3627 = {int(cum_down[0] - cum_up[0])}  (absolute value at the reference position, negative travel)"]
        lines += [f"{p} = {v:+d}" for p, v in zip(up_points, values(inc_up))]
        lines += [f"{p} = {v:+d}" for p, v in zip(down_points, values(inc_down))]
        return "\n".join(lines) + "\n"

    def parse(self, text: str, where: str = "<fanuc>") -> CompensationTable:
        """The listing back to trims, as the control applies it: the running sum of the increments
        from the reference position, times the detection unit (360° / 3625) and the magnification;
        the negative-travel table starts from 3627."""
        values: dict[int, int] = {}
        line_of: dict[int, int] = {}
        for line_no, line in enumerate(text.splitlines(), start=1):
            line = line.strip()
            if not line or line.startswith("("):
                continue
            m = FANUC_LINE.fullmatch(line)
            if not m or (m.group(2) and m.group(1) != "3605"):
                raise CompensationError(f"{where}:{line_no}: expected `number = integer` (or `3605 #0 = 1`): {line[:60]!r}")
            key = int(m.group(1))
            if key in values:
                raise CompensationError(f"{where}:{line_no}: {key} is given twice")
            values[key], line_of[key] = int(m.group(3)), line_no
        try:
            ref, first, last, magnification, interval, per_rev = (values[k] for k in (3620, 3621, 3622, 3623, 3624, 3625))
        except KeyError as exc:
            raise CompensationError(f"{where}: parameter {exc.args[0]} is missing") from None
        if first != ref:
            raise CompensationError(f"{where}:{line_of[3621]}: a rotary axis's farthest − point (3621) is its reference point (3620)")
        n = last - first
        if n < 2 or interval <= 0 or magnification <= 0 or n * interval != per_rev:
            raise CompensationError(f"{where}:{line_of[3622]}: 3622 − 3621 = {n} intervals of {interval} units must make one turn "
                                    f"of {per_rev} (3625), with magnification 3623 > 0")
        unit = 360.0 / per_rev * magnification
        bidirectional = values.get(3605) == 1

        def trims(start: int, offset: int, what: str) -> np.ndarray:
            points = range(start, start + n + 1)
            missing = [p for p in points if p not in values]
            if missing:
                raise CompensationError(f"{where}: {what}: compensation point {missing[0]} is missing")
            inc = np.array([values[p] for p in points])
            if np.abs(inc).max() > FANUC_MAX_INCREMENT + 1:
                raise CompensationError(f"{where}:{line_of[points[int(np.argmax(np.abs(inc)))]]}: {what}: a value beyond "
                                        f"-128 … {FANUC_MAX_INCREMENT}")
            if inc[1:].sum() != 0 or inc[0] != inc[-1]:
                raise CompensationError(f"{where}:{line_of[points[-1]]}: {what}: a rotary table's increments must sum to zero "
                                        "over the turn, and its first and last points (the same position) hold one value")
            return (offset + np.concatenate([[0], np.cumsum(inc[1:])])) * unit

        positions = np.arange(n + 1) * interval * 360.0 / per_rev
        up = trims(first, 0, "positive travel")
        used = set(range(first, last + 1))
        if bidirectional:
            if 3626 not in values:
                raise CompensationError(f"{where}: bidirectional (3605 #0 = 1) needs 3626, the negative-travel table's first point")
            start = values[3626]
            if used & set(range(start, start + n + 1)):
                raise CompensationError(f"{where}:{line_of[3626]}: the negative-travel table ({start} …) overlaps the positive one")
            down = trims(start, values.get(3627, 0), "negative travel")
            used |= set(range(start, start + n + 1))
        else:
            down = up
        stray = sorted(k for k in values if k not in used and not 3605 <= k <= 3627)
        if stray:
            raise CompensationError(f"{where}:{line_of[stray[0]]}: point {stray[0]} belongs to no table")
        return regular_table(positions, up, down, where, self.max_points)
