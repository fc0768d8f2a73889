"""LinuxCNC, COMP_FILE_TYPE = 0 (docs/compensation.md, docs/protocols/linuxcnc.md): per line
``nominal forward_actual reverse_actual``, degrees; any spacing; the table does not wrap. The
type is stated after the table, in ``#`` lines: LinuxCNC (usrmotLoadComp, usrmotintf.cc) reads
triplets up to the first line that is not three numbers, so a footer is never read, whereas a
header would end the table before its first line."""

from __future__ import annotations

import re
from typing import Any, ClassVar

import numpy as np

from rtcal.compensation.base import CompensationFormat, FormatOption, plain_ascii
from rtcal.compensation.table import CompensationError, CompensationTable, sane


class LinuxCncFormat(CompensationFormat):
    name = "linuxcnc"
    max_points = 256
    sign = "actual positions: the trim is nominal − actual, per direction (forward and reverse columns)"
    one_direction = ("LinuxCNC ignores the joint's BACKLASH once a comp file is set, so forward and reverse columns with the "
                     "same values leave the axis with no reversal (backlash) compensation at all")
    options = (FormatOption("range_deg", "--range-deg", "the joint's travel to cover",
                            "default 0 360; LinuxCNC does not wrap a table", type=float, nargs=2, metavar=("LO", "HI")),)
    wraps = False
    comment = ("# rtcal: ", "")  # after the table only: LinuxCNC stops reading at the first line that is not three numbers
    loading: ClassVar[str] = ("load it with COMP_FILE_TYPE = 0 in the joint's INI section (nominal, measured forward, measured reverse); "
               "read as type 1 (trims) it would move the joint by about its own position")
    footer = "# rtcal: "

    def instructions(self, table: CompensationTable, **options: Any) -> list[str]:
        return [self.loading]

    def write(self, table: CompensationTable, range_deg: tuple[float, float] = (0.0, 360.0)) -> str:
        """COMP_FILE_TYPE = 0: ``nominal forward_actual reverse_actual`` per line, degrees, ascending,
        then a ``#`` footer saying the type (LinuxCNC stops reading at the first line that is not three
        numbers: a footer is never read, a header would end the table).
        Lines at the table's points (measured targets or grid, any spacing) repeated every turn over
        ``range_deg``, the joint's travel (default one turn), and at its two ends: LinuxCNC does not
        wrap a table, so a joint that travels −145 … 155° needs lines there."""
        lo, hi = (float(v) for v in range_deg)
        if not (abs(lo) <= 36000.0 and abs(hi) <= 36000.0):  # also false for NaN
            raise CompensationError(f"--range-deg {lo:g} {hi:g}: the travel must lie within ±36000° (100 turns)")
        if not hi > lo:
            raise CompensationError(f"--range-deg {lo:g} {hi:g}: an ascending range (the joint's lowest and highest position)")
        turn = np.asarray(table.positions_deg[:-1], float)  # one turn: the last entry (360°) repeats the first
        turns = np.arange(np.floor((lo - turn.max()) / 360.0), np.ceil((hi - turn.min()) / 360.0) + 1)
        if len(turn) * len(turns) > 100 * self.max_points:
            raise CompensationError(f"linuxcnc: {len(turn)} points a turn over {lo:g} … {hi:g}°; LinuxCNC reads at most "
                                    f"{self.max_points} lines (a larger --step-deg or a narrower --range-deg)")
        nominal = (turn[None, :] + 360.0 * turns[:, None]).ravel()
        nominal = np.unique(np.round(np.concatenate([nominal[(nominal >= lo) & (nominal <= hi)], [lo, hi]]), 6))
        if len(nominal) > self.max_points:
            raise CompensationError(f"linuxcnc: {len(nominal)} lines over {lo:g} … {hi:g}°; LinuxCNC reads at most "
                                    f"{self.max_points} (fewer targets, a larger --step-deg or a narrower --range-deg)")
        up = np.array([table.trim_deg(a, +1) for a in nominal])
        down = np.array([table.trim_deg(a, -1) for a in nominal])
        rows = "".join(f"{p:.6f} {p - u:.8f} {p - d:.8f}\n" for p, u, d in zip(nominal, up, down))
        warnings = "".join(f"{self.footer}{plain_ascii(f'warning: {w}')}\n" for w in table.warnings)
        return (rows + f"{self.footer}COMP_FILE_TYPE = 0: {self.loading}\n"
                f"{self.footer}LinuxCNC stops reading at the first line that is not three numbers (this one)\n" + warnings)

    def parse(self, text: str, where: str = "<linuxcnc>") -> CompensationTable:
        """As LinuxCNC reads it (usrmotintf.cc): three numbers a line, trims = nominal − actual; but
        what LinuxCNC would silently drop (everything after a line that is not three numbers, a
        blank one included) is an error here, with its line. A footer of ``#`` lines (and blank
        ones) ends the table as rtcal writes it; a footer that says another type is refused."""
        lines = text.splitlines()
        while lines and (not lines[-1].strip() or lines[-1].lstrip().startswith("#")):
            line = lines.pop()  # a footer (and trailing blank lines) ends the table where it ends anyway
            kind = re.search(r"COMP_FILE_TYPE\s*=\s*(\d+)", line)
            if kind and kind.group(1) != "0":
                raise CompensationError(f"{where}: its comment says COMP_FILE_TYPE = {kind.group(1)}; rtcal reads and writes "
                                        "type 0 (nominal, measured forward, measured reverse)")
        rows = []
        for line_no, line in enumerate(lines, start=1):
            parts = line.split()
            try:
                values = [float(v) for v in parts]
                if len(values) != 3 or not all(np.isfinite(values)):
                    raise ValueError
            except ValueError:
                rest = len(lines) - line_no
                raise CompensationError(f"{where}:{line_no}: expected three finite numbers (nominal, forward actual, reverse "
                                        f"actual); LinuxCNC stops reading here{f' and would ignore the {rest} line(s) after it' if rest else ''}") from None
            rows.append(values)
        if len(rows) < 2 or len(rows) > self.max_points:
            raise CompensationError(f"{where}: {len(rows)} lines (2 … {self.max_points})")
        a = np.array(rows)
        bad = np.nonzero(np.diff(a[:, 0]) <= 0)[0]
        if len(bad):
            raise CompensationError(f"{where}:{bad[0] + 2}: nominal positions must increase strictly (LinuxCNC refuses the line)")
        up, down = a[:, 0] - a[:, 1], a[:, 0] - a[:, 2]
        sane(up, down, where)
        return CompensationTable(a[:, 0], up, down, modulo=False)
