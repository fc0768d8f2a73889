"""FANUC pitch error compensation for a rotary axis, bidirectional (docs/compensation.md):
parameters 3605 … 3627 and one incremental value per compensation point, as the control's I/O
file (``%``, ``N…P…;`` records, ``%``) or, with --listing, a listing to key in. Sources: FANUC
Series 0i-PB Parameter Manual B-63980EN/01 p. 100 (rotary example); Technical Report A-77810E
(bidirectional pitch error compensation, table (a)); Series 15i Parameter Manual B-63330EN/03
p. 25 (the I/O record format); the cnc.wiki setup guide (128 points, power cycle, N10000+k)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from rtcal.compensation.base import CompensationFormat, FormatOption, plain_ascii
from rtcal.compensation.table import ARCSEC_PER_DEG, CompensationError, CompensationTable, regular_table

FANUC_MAX_INCREMENT = 127  # a point's value, in detection units × magnification (−128 … 127)
FANUC_MAX_POINT = 1023  # highest compensation point number (0i series)
FANUC_GUIDE_POINTS = 128  # "maximum of 128 compensation points between extremes" (cnc.wiki setup guide)
PITCH_BASE = 10000  # pitch error data in the I/O file: N10000+k P…; (15i p. 25, cnc.wiki)
# series whose 3624/3625 are integers in detection units; the others take real values in the
# machine unit (deg) — 0i-D/0i-F, 30i/31i/32i (docs/compensation.md: [general], check the series)
INTEGER_SERIES = ("16i", "18i", "21i", "0i-a", "0i-b", "0i-c", "0i-pb")
REAL_SERIES = ("0i-d", "0i-f", "30i", "31i", "32i")
LISTING_LINE = re.compile(r"(\d+)( #0)? = ([+-]?\d+(?:\.\d*)?)(?:\s+\(.*\))?")
RECORD = re.compile(r"N(\d{5})(?:A(\d+))?P([+-]?\d+(?:\.\d*)?);")


INCREMENT_SYSTEMS = {0.001: "IS-B", 0.0001: "IS-C"}  # the detection units the manuals rtcal has name (15i p. 297: IS-B 3 decimals)
# the table's own statement of its detection unit: on the I/O file's first line, which the control
# skips ("data between the first % and the next LF is skipped", 16i/18i-TB Operator's Manual
# B-63524EN/01 p. 649), and in a listing's first comment
STATED_UNIT = re.compile(r"detection unit ([0-9.]+(?:e-?\d+)?) deg")


def increment_system(unit_deg: float) -> str:
    """The unit as the manuals name it ("0.001 deg, IS-B"), or just the number."""
    name = next((n for u, n in INCREMENT_SYSTEMS.items() if abs(unit_deg - u) < 1e-12), "")
    return f"{unit_deg:g} deg" + (f", {name}" if name else "")


@dataclass(frozen=True)
class Counts:
    """The running trim of each direction at its points (0 … n), in detection units × ``magnification``:
    rounded once and differenced, so the increments of a turn sum to exactly 0."""

    magnification: int
    up: np.ndarray
    down: np.ndarray

    @classmethod
    def of(cls, table: CompensationTable, unit_deg: float) -> "Counts":
        """The smallest magnification (3623) that keeps every increment within ±127."""
        for magnification in range(1, 101):
            unit = unit_deg * magnification
            up = np.round(np.asarray(table.trim_up_deg) / unit).astype(int)
            down = np.round(np.asarray(table.trim_down_deg) / unit).astype(int)
            if max(np.abs(np.diff(up)).max(), np.abs(np.diff(down)).max()) <= FANUC_MAX_INCREMENT:
                return cls(magnification, up, down)
        raise CompensationError(f"fanuc: increments exceed ±{FANUC_MAX_INCREMENT} even at magnification 100")


@dataclass(frozen=True)
class Points:
    """Which pitch error compensation points the two tables occupy: the positive-travel table from
    3620 (= 3621 on a rotary axis), the negative-travel table right after it (3626 its first)."""

    first: int
    n: int  # intervals per turn

    @property
    def up(self) -> range:
        return range(self.first, self.first + self.n + 1)

    @property
    def down(self) -> range:
        return range(self.first + self.n + 1, self.first + 2 * self.n + 2)

    def text(self) -> str:
        return (f"pitch error compensation points {self.up[0]} ... {self.down[-1]} (positive travel {self.up[0]} ... "
                f"{self.up[-1]}, negative travel {self.down[0]} ... {self.down[-1]})")


class FanucFormat(CompensationFormat):
    name = "fanuc"
    max_points = 1024
    fixed_pitch = "parameter 3624"
    sign = ("increments of the trim, detection units × magnification (3623): point k holds the trim's change over the "
            "interval ending at it; positive and negative travel tables (A-77810E)")
    comment = None  # the I/O file holds records only between its two '%' (15i p. 25); --listing takes (comments)
    one_direction = ("the negative-travel table would repeat the positive one with 3627 = 0: the bidirectional pitch error "
                     "compensation then compensates no reversal, and the unmeasured direction is assumed to follow the "
                     "measured one")
    options = (FormatOption("unit_deg", "--detection-unit-deg", "the axis's detection unit, deg: its increment system "
                            "(a table made for another unit scales every trim by the ratio: 10x between IS-B and IS-C)",
                            "required: 0.001 for IS-B, 0.0001 for IS-C", type=float, required=True),
               FormatOption("first_point", "--first-point", "number of the reference position's point, the axis's "
                            "parameter 3620 (pitch error points are shared by all axes: the file occupies this one and "
                            "the next 2 x 360/step + 1)", "required, e.g. the axis's 3620 as the machine has it",
                            type=int, required=True),
               FormatOption("series", "--series", "the control's series: the unit of 3624/3625 (integer detection units "
                            f"on {', '.join(INTEGER_SERIES)}; real degrees on {', '.join(REAL_SERIES)})", "default 0i-f",
                            pattern="|".join(re.escape(s) for s in INTEGER_SERIES + REAL_SERIES), noun="series",
                            example="0i-f"),
               FormatOption("reference_return", "--reference-return", "the direction of the axis's reference return "
                            "(1006#5 ZMI): 3627 belongs to the opposite approach", "default +",
                            pattern=r"[+-]", noun="direction (+ or -)", example="+"),
               FormatOption("axis_number", "--axis-number", "the axis's number in the I/O file's axis-type records (A<n>)",
                            "default 4", type=int),
               FormatOption("listing", "--listing", "write a listing to key in (3620 = 0  (comment)) instead of the I/O "
                            "file", flag_only=True))

    def write(self, table: CompensationTable, unit_deg: float | None = None, first_point: int | None = None,
              series: str = "0i-f", reference_return: str = "+", axis_number: int = 4, listing: bool = False) -> str:
        """Pitch error compensation, bidirectional (3605#0 = 1). Values are incremental, in detection
        units (``unit_deg``) × magnification (3623, the smallest that keeps every value within ±127):
        point k holds the change of the trim over the interval ending at it; over one turn they sum
        to zero and the reference point holds the same value as the last — "the No. of the farthest
        compensation position in the negative direction for the rotation axis is always equal to
        the compensation position No. of the reference position … For compensation position 60, set
        the same compensation value as for 68" (0i-PB p. 100). The positive-travel table is 3621 =
        3620 … 3622; the negative-travel table follows it, 3626 its farthest − point (A-77810E);
        3627 is the absolute value at the reference position of the approach opposite to the
        reference return (0i-D wording, A-77810E). The detection unit and the first point have no
        default: a wrong one moves the axis by a multiple of every trim, or overwrites another
        axis's table. The I/O file states its unit and points on its first line, which the control
        skips (16i Operator's Manual p. 649), and writes no 3605 record: a bit parameter travels as a
        whole byte (15i p. 25), and only bit #0 is rtcal's to set."""
        unit_deg, points = self._checked(table, unit_deg, first_point, axis_number)
        counts = Counts.of(table, unit_deg)
        inc_up, inc_down = np.diff(counts.up), np.diff(counts.down)
        # 3627: the other approach's absolute value at the reference position, that approach's table
        # being relative to the one the reference return sets
        at_reference = int(counts.down[0] - counts.up[0]) if reference_return == "+" else int(counts.up[0] - counts.down[0])
        real = series in REAL_SERIES
        interval = f"{table.step_deg:.4f}" if real else str(round(table.step_deg / unit_deg))
        per_rev = "360.0" if real else str(round(360.0 / unit_deg))
        unit_text = "deg" if real else "detection units"
        params = [(3620, str(points.first), "compensation point of the reference position"),
                  (3621, str(points.up[0]), "farthest point on the - side, positive travel"),
                  (3622, str(points.up[-1]), "farthest point on the + side, positive travel"),
                  (3623, str(counts.magnification), "magnification"),
                  (3624, interval, f"interval, {unit_text}"),
                  (3625, per_rev, f"travel per revolution, {unit_text}"),
                  (3626, str(points.down[0]), "farthest point on the - side, negative travel"),
                  (3627, str(at_reference), f"absolute value at the reference position, approach "
                                            f"{'negative' if reference_return == '+' else 'positive'}")]

        def values(inc: np.ndarray) -> list[int]:
            return [int(inc[-1])] + [int(v) for v in inc]  # the first point (0°) is the last (360°)

        pairs = list(zip(points.up, values(inc_up))) + list(zip(points.down, values(inc_down)))
        if listing:
            lines = [f"(FANUC pitch error compensation for the rotary axis; detection unit {increment_system(unit_deg)}; "
                     f"series {series}; written by rtcal)", f"({points.text()}: shared by all axes)",
                     *(f"({plain_ascii(f'rtcal warning: {w}')})" for w in table.warnings),
                     "3605 #0 = 1  (bidirectional pitch error compensation: bit #0 only, keep the other bits)"]
            lines += [f"{k} = {v}  ({what})" for k, v, what in params]
            lines += [f"{p} = {v:+d}" for p, v in pairs]
            return "\n".join(lines) + "\n"
        lines = [f"%(rtcal: detection unit {increment_system(unit_deg)}; points {points.up[0]}-{points.down[-1]}; "
                 "set 3605#0 = 1 by hand)"]
        lines += [f"N{k:05d}A{axis_number}P{v};" for k, v, _ in params]
        lines += [f"N{PITCH_BASE + p:05d}P{v:+d};" for p, v in pairs]
        lines.append("%")
        return "\n".join(lines) + "\n"

    def _checked(self, table: CompensationTable, unit_deg: float | None, first_point: int | None,
                 axis_number: int) -> tuple[float, Points]:
        """The detection unit and the points the tables occupy, or the refusal naming the option."""
        self.check_points(table)
        options = {o.keyword: o for o in self.options}
        if unit_deg is None:
            raise options["unit_deg"].missing(self.name)
        if first_point is None:
            raise options["first_point"].missing(self.name)
        if not unit_deg > 0 or abs(table.step_deg / unit_deg - round(table.step_deg / unit_deg)) > 1e-6:
            raise CompensationError(f"--detection-unit-deg {unit_deg:g}: must be positive and divide the {table.step_deg:g}° step")
        if not 1 <= axis_number <= 32:
            raise CompensationError(f"--axis-number {axis_number}: the axis's number, 1 … 32")
        points = Points(first_point, len(table.positions_deg) - 1)
        if first_point < 0 or points.down[-1] > FANUC_MAX_POINT:
            raise CompensationError(f"compensation points {first_point} … {points.down[-1]} do not fit 0 … {FANUC_MAX_POINT}: "
                                    "choose --first-point")
        return float(unit_deg), points


    def comment_note(self, **options: Any) -> str | None:
        return None if options.get("listing") else ("a FANUC I/O file holds only records between its two '%' (--listing "
                                                    "writes them as (...) lines)")

    def instructions(self, table: CompensationTable, **options: Any) -> list[str]:
        n = len(table.positions_deg)
        unit_deg, points = self._checked(table, options.get("unit_deg"), options.get("first_point"),
                                         options.get("axis_number", 4))
        series, ret = options.get("series", "0i-f"), options.get("reference_return", "+")
        lines = [f"the increments are in detection units of {increment_system(unit_deg)} (--detection-unit-deg): the "
                 "axis's increment system must be that one (parameter 1013 on a 0i/30i [general]); on an axis of another "
                 "unit every trim is scaled by the ratio (a table for IS-C on an IS-B axis moves it 10x each trim)",
                 f"the file occupies {points.text()}; the points 0 ... {FANUC_MAX_POINT} are shared by all axes: check "
                 "that no other axis's table (its 3621 ... 3622, 3626 ...) uses any of them",
                 ("key the listing in" if options.get("listing") else "read the file in (I/O, EDIT mode)")
                 + " with parameter write enabled (PWE = 1), and set 3605#0 = 1 (bidirectional pitch error compensation) "
                 "on the parameter screen: bit #0 only, keep the other seven as the machine has them (the file writes no "
                 "3605 record: a bit parameter travels as a whole byte)",
                 f"3627 assumes the reference return in the {ret} direction (1006#5 ZMI = {0 if ret == '+' else 1}; "
                 "--reference-return); 3624/3625 in "
                 + ("degrees" if series in REAL_SERIES else "detection units") + f" for series {series} (--series)",
                 "power the control off and on, then return the axis to its reference position (G28): the table acts "
                 "only after both (alarm PW1102 otherwise; cnc.wiki setup guide)"]
        if n > FANUC_GUIDE_POINTS:
            lines.append(f"warning: {n} points in each direction's table; a FANUC setup guide gives at most "
                         f"{FANUC_GUIDE_POINTS} between the extremes: check the control's manual or choose a larger --step-deg")
        return lines

    def readings(self, table: CompensationTable, **options: Any) -> list[str]:
        """Where each increment acts within its section: the 0i-PB says it is "output at the compensation
        position No. corresponding to each section" (p. 100), which reads as a step at a point as
        well as spread over the section; rtcal's simulated control spreads it (linear). The check is
        the middle of the section with the largest increment, where the two readings differ most."""
        unit_deg, _ = self._checked(table, options.get("unit_deg"), options.get("first_point"), options.get("axis_number", 4))
        counts = Counts.of(table, unit_deg)
        trim = counts.up * unit_deg * counts.magnification * ARCSEC_PER_DEG
        k = int(np.argmax(np.abs(np.diff(trim))))
        lo, hi = float(table.positions_deg[k]), float(table.positions_deg[k + 1])
        mid, before = (lo + hi) / 2, (lo + hi) / 2 - table.step_deg
        return [f"where an increment acts within its section (0i-PB p. 100: \"output at the compensation position No. "
                f"corresponding to each section\"): rtcal's simulated control spreads it linearly over the section; a "
                f"control may place it as a step at a point. Check in the middle of the section with the largest increment "
                f"({lo:g} ... {hi:g} deg, {trim[k + 1] - trim[k]:+.1f} arcsec): in MDI `G90 G00 C{before:g};` `G00 C{mid:g};` "
                "(C: the axis's address), read the error there with the reference, before loading the table and after; "
                f"it must change by {(trim[k] + trim[k + 1]) / 2:+.1f} arcsec (spread linearly); by {trim[k]:+.1f} or "
                f"{trim[k + 1]:+.1f} arcsec the control steps at a point, and the table leaves up to "
                f"{abs(trim[k + 1] - trim[k]) / 2:.1f} arcsec mid-section: write it with a smaller --step-deg"]

    def parse(self, text: str, where: str = "<fanuc>", unit_deg: float | None = None) -> CompensationTable:
        """The I/O file (or the listing) back to trims, as the control applies it: the running sum
        of the increments from the reference position, times the detection unit and the
        magnification; the table of the approach opposite to the reference return starts from 3627
        (in a listing or I/O file rtcal reads the reference return as positive). The unit: 360° /
        3625 when 3625 is an integer; else the one the file states (rtcal writes it on the first
        line), else ``unit_deg``; a unit given that the file contradicts is refused. Bidirectional
        when 3605#0 says so, or — rtcal writes no 3605 record — when the file holds 3626."""
        values, line_of, stated = self._records(text, where)
        degrees = values.pop(-3625, None) is not None  # 3625 in degrees (a real-unit series)
        try:
            ref, first, last, magnification, interval, per_rev = (values[k] for k in (3620, 3621, 3622, 3623, 3624, 3625))
        except KeyError as exc:
            raise CompensationError(f"{where}: parameter {exc.args[0]} is missing") from None
        if first != ref:
            raise CompensationError(f"{where}:{line_of[3621]}: a rotary axis's farthest − point (3621) is its reference point (3620)")
        n = int(last - first)
        if n < 2 or n >= self.max_points or interval <= 0 or magnification <= 0 or abs(n * interval - per_rev) > 1e-6 * per_rev:
            raise CompensationError(f"{where}:{line_of[3622]}: 3622 − 3621 = {n} intervals of {interval:g} must make one turn "
                                    f"of {per_rev:g} (3625), with magnification 3623 > 0")
        unit = stated_or_given(where, stated if stated is not None else (None if degrees else 360.0 / per_rev), unit_deg)
        if not degrees and abs(per_rev * unit - 360.0) > 1e-6:
            raise CompensationError(f"{where}:{line_of[3625]}: 3625 = {per_rev:g} detection units of {unit:g}° is not one turn")
        bidirectional = int(values[3605]) & 1 == 1 if 3605 in values else 3626 in values
        step = 360.0 / n
        ints = {k: int(v) for k, v in values.items() if k < 3605 or k > 3627}

        def trims(start: int, offset: int, what: str) -> np.ndarray:
            points = range(start, start + n + 1)
            missing = [p for p in points if p not in ints]
            if missing:
                raise CompensationError(f"{where}: {what}: compensation point {missing[0]} is missing")
            inc = np.array([ints[p] for p in points])
            if np.abs(inc).max() > FANUC_MAX_INCREMENT + 1:
                raise CompensationError(f"{where}:{line_of[points[int(np.argmax(np.abs(inc)))]]}: {what}: a value beyond "
                                        f"-128 … {FANUC_MAX_INCREMENT}")
            if inc[1:].sum() != 0 or inc[0] != inc[-1]:
                raise CompensationError(f"{where}:{line_of[points[-1]]}: {what}: a rotary table's increments must sum to zero "
                                        "over the turn, and its first and last points (the same position) hold one value")
            return (offset + np.concatenate([[0], np.cumsum(inc[1:])])) * unit * magnification

        positions = np.arange(n + 1) * step
        up = trims(int(first), 0, "positive travel")
        used = set(range(int(first), int(last) + 1))
        if bidirectional:
            if 3626 not in values:
                raise CompensationError(f"{where}: bidirectional (3605 #0 = 1) needs 3626, the negative-travel table's first point")
            start = int(values[3626])
            if used & set(range(start, start + n + 1)):
                raise CompensationError(f"{where}:{line_of[3626]}: the negative-travel table ({start} …) overlaps the positive one")
            down = trims(start, int(values.get(3627, 0)), "negative travel")
            used |= set(range(start, start + n + 1))
        else:
            down = up
        stray = sorted(k for k in ints if k not in used)
        if stray:
            raise CompensationError(f"{where}:{line_of[stray[0]]}: point {stray[0]} belongs to no table")
        return regular_table(positions, up, down, where, self.max_points)

    @staticmethod
    def _records(text: str, where: str) -> tuple[dict[int, float], dict[int, int], float | None]:
        """Parameters (by number) and compensation points (by point number) of an I/O file — '%',
        ``N…P…;`` records, '%' (15i p. 25; pitch data N10000+k, cnc.wiki) — or of a listing
        (``3620 = 0  (comment)``), and the detection unit the file states (its first line, which
        the control skips, or the listing's first comment). Key -3625 marks a 3625 written with a
        decimal point."""
        values: dict[int, float] = {}
        line_of: dict[int, int] = {}
        lines = text.splitlines()
        body = [(i, line.strip()) for i, line in enumerate(lines, start=1) if line.strip()]
        io_file = bool(body) and body[0][1].startswith("%")
        said = STATED_UNIT.search(body[0][1]) if body else None
        stated = float(said.group(1)) if said else None
        if io_file:
            if body[-1][1] != "%" or len(body) < 2:
                raise CompensationError(f"{where}:{body[-1][0]}: an I/O file ends with '%' (15i p. 25)")
            body = body[1:-1]
        for line_no, line in body:
            if io_file:
                m = RECORD.fullmatch(line.split("(", 1)[0].strip())  # the manual's example comments: ignored
                if not m:
                    raise CompensationError(f"{where}:{line_no}: expected a record N<number>[A<axis>]P<value>;: {line[:60]!r}")
                number, raw = int(m.group(1)), m.group(3)
                if number >= PITCH_BASE:
                    key = number - PITCH_BASE
                elif number == 3605:  # a bit parameter: #7 … #0
                    if not re.fullmatch(r"[01]{1,8}", raw):
                        raise CompensationError(f"{where}:{line_no}: 3605 is a bit parameter, e.g. P00000001")
                    key, raw = 3605, str(int(raw, 2))
                elif 3620 <= number <= 3627:
                    key = number
                else:
                    raise CompensationError(f"{where}:{line_no}: parameter {number} is not one of pitch error compensation's")
            else:
                if line.startswith("("):
                    continue
                lm = LISTING_LINE.fullmatch(line)
                if not lm or (lm.group(2) and lm.group(1) != "3605"):
                    raise CompensationError(f"{where}:{line_no}: expected `number = value` (or `3605 #0 = 1`): {line[:60]!r}")
                key, raw = int(lm.group(1)), lm.group(3)
            if key in values:
                raise CompensationError(f"{where}:{line_no}: {key} is given twice")
            if "." in raw and key not in (3624, 3625):
                raise CompensationError(f"{where}:{line_no}: {key} takes an integer")
            values[key], line_of[key] = float(raw), line_no
            if key == 3625 and "." in raw:
                values[-3625] = 1.0
        return values, line_of, stated


def stated_or_given(where: str, stated: float | None, given: float | None) -> float:
    """The detection unit a file is read in: the one it states (or implies), the one given, and
    never two that disagree."""
    if stated is not None and given is not None and abs(stated - given) > 1e-12:
        raise CompensationError(f"{where}: the table is for a detection unit of {increment_system(stated)}, the axis's is "
                                f"{increment_system(given)}: every trim would be {given / stated:g}x what it should; write "
                                f"it with --detection-unit-deg {given:g}")
    unit = stated if stated is not None else given
    if unit is None:
        raise CompensationError(f"{where}: 3624/3625 are in degrees and the file does not state its detection unit (rtcal "
                                "writes it on the first line): give the axis's (--detection-unit-deg)")
    return unit
