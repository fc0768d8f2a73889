"""The file grammar both SINUMERIK tables share (``%_N_…_INI``: header, CHANDATA, ``;``
comments, ``$NAME[…]=value`` assignments, M17), read strictly: rtcal/compensation/siemens_lec.py
and siemens_cec.py build on it."""

from __future__ import annotations

import re
import textwrap

import numpy as np

from rtcal.compensation.base import ASCII, FormatOption, axis_option
from rtcal.compensation.table import CompensationError, CompensationTable

AXIS = axis_option(r"[A-Z][A-Z0-9_]{0,15}", "C1")
# the table's size is machine data the machine builder sets (LEC: MD38000 MM_ENC_COMP_MAX_POINTS,
# K3 03/2013 p. 242; CEC: MD18342 MM_CEC_MAX_POINTS[t], K3 p. 264), so no one number holds for
# every 840D; the documented fixed limits are 200 points: 808D LEC "up to 200 interpolation
# points (N = 0…199)" (808D p. 106) and 828D CEC "eight tables each with 200 interpolation points
# … This cannot be extended!" (K3 p. 264). 200 is the default; --max-points takes the machine's
# MD value, up to MAX_POINTS, the bound rtcal's parser reads (one turn at 0.01°)
DEFAULT_POINTS = 200
MAX_POINTS = 36001
# the longest line a SINUMERIK NC reads is stated in no manual rtcal has (the examples' lines are
# short): rtcal wraps its `;` lines at this width rather than write lines of 600 characters
LINE_WIDTH = 100
POINTS = FormatOption("max_points", "--max-points", "the most points the control's table takes (SINUMERIK: MD38000 "
                      "for LEC, MD18342 for CEC)", f"default {DEFAULT_POINTS}, the 808D/828D limit (K3 p. 264)", type=int)


def mean_from_reference(table: CompensationTable, reference_deg: float) -> np.ndarray:
    """The mean of both directions' deviations (−trim), referred to 0 at ``reference_deg`` (the axis's
    reference point): "the compensation value at the reference point [should be] zero. This prevents
    position jumps occurring when the LEC is activated" (K3 03/2013 p. 238; 808D p. 106). A constant
    offset of the whole curve changes no ISO 230-2 parameter."""
    mean = -(np.asarray(table.trim_up_deg) + np.asarray(table.trim_down_deg)) / 2
    return mean - float(np.interp(reference_deg, table.positions_deg, mean, period=360.0))


def memory_warning(md: str) -> str:
    """What a change of a memory-configuring machine datum (MD38000, MD18342) does: "The memory
    required in the static user memory is 6.4 KB (8 bytes per compensation value)" (K3 p. 242)."""
    return f"a change of {md} reorganises the NC memory (8 bytes of static user memory a point, K3 p. 242): back it up first"


def semicolon_lines(texts: list[str]) -> list[str]:
    """``;`` comment lines of at most LINE_WIDTH characters, plain ASCII; a text too long for one
    line goes on under ``;   ``."""
    out = []
    for text in texts:
        plain = "".join(c if c in "()" else ASCII.get(c, c) for c in text.removeprefix("; "))
        plain = plain.encode("ascii", "replace").decode()
        wrapped = textwrap.wrap(plain, LINE_WIDTH - 2, subsequent_indent="  ", break_long_words=True,
                                break_on_hyphens=False) or [""]
        out += [f"; {line}" for line in wrapped]
    return out


def line_length_reading() -> str:
    """The longest line the NC reads: not stated; the check on the machine."""
    return (f"the line length: no SINUMERIK manual rtcal has states the longest line the NC reads; rtcal keeps every "
            f"line within {LINE_WIDTH} characters (its `;` lines wrapped). Check when loading: an alarm naming a line of "
            "this file means the NC refuses it: delete the `;` lines (comments only, the table does not need them) and "
            "load it again")


def check_reference(reference_deg: float) -> float:
    """--reference-deg within one turn (also false for NaN)."""
    if not 0.0 <= reference_deg < 360.0:
        raise CompensationError(f"--reference-deg {reference_deg:g}: the reference point's angle lies in [0, 360)")
    return float(reference_deg)


def check_size(max_points: int) -> None:
    if not 3 <= max_points <= MAX_POINTS:
        raise CompensationError(f"--max-points {max_points}: the control's table size, 3 … {MAX_POINTS}")


def axis_name(value: str) -> str:
    """An axis name as written, ``C1`` or ``(C1)`` (the manuals' examples write parentheses:
    802D sl p. 222 ``=(AX2)``, K3 p. 268 ``= (XX)``)."""
    value = value.strip()
    return value[1:-1].strip() if value.startswith("(") and value.endswith(")") else value
HEADER = {"AA_ENC_COMP": "%_N_AX_EEC_INI", "AN_CEC": "%_N_NC_CEC_INI"}
LINE = re.compile(r"\$(AA_ENC_COMP|AN_CEC)(_[A-Z_]+)?\[([^\]]*)\]\s*=\s*(\S+|\(\s*\S+\s*\))")


def values(text: str, where: str, name: str) -> tuple[dict[int, dict[int, float]], dict[int, dict[str, str]], dict]:
    """Points and settings per table of a ``%_N_…_INI`` file: the header, CHANDATA, ``;`` comments,
    ``$<name>…`` assignments and M17 at the end; anything else is an error on its line."""
    lines = text.splitlines()
    if not lines or lines[0].strip() != HEADER[name]:
        raise CompensationError(f"{where}:1: the first line must be {HEADER[name]}")
    points: dict[int, dict[int, float]] = {}
    settings: dict[int, dict[str, str]] = {}
    line_of: dict = {}
    ended = False
    for line_no, raw in enumerate(lines[1:], start=2):
        line = raw.split(";", 1)[0].strip()
        if not line or line.startswith("CHANDATA("):
            continue
        if ended:
            raise CompensationError(f"{where}:{line_no}: nothing may follow M17")
        if line == "M17":
            ended = True
            continue
        m = LINE.fullmatch(line)
        if not m or m.group(1) != name:
            raise CompensationError(f"{where}:{line_no}: not a ${name} assignment: {line[:60]!r}")
        suffix, index, value = m.group(2) or "", [i.strip() for i in m.group(3).split(",")], m.group(4)
        try:
            table_no = int(index[0])
            if not suffix:
                point = int(index[1])
                if point in points.setdefault(table_no, {}):
                    raise CompensationError(f"{where}:{line_no}: point {point} of table {table_no} is given twice")
                points[table_no][point] = float(value)
                line_of[(table_no, point)] = line_no
            else:
                settings.setdefault(table_no, {})[suffix] = value
                line_of[(table_no, suffix)] = line_no
        except (IndexError, ValueError):
            raise CompensationError(f"{where}:{line_no}: expected ${name}[table,point…]=number") from None
    if not ended:
        raise CompensationError(f"{where}: M17 is missing at the end (the file would not load)")
    return points, settings, line_of


def table(points: dict[int, float], settings: dict[str, str], where: str) -> tuple[np.ndarray, np.ndarray]:
    """One table's positions (from MIN, STEP, MAX) and values; a modulo table numbered without gaps."""
    try:
        step, lo, hi = float(settings["_STEP"]), float(settings["_MIN"]), float(settings["_MAX"])
    except (KeyError, ValueError):
        raise CompensationError(f"{where}: STEP, MIN and MAX must be given as numbers") from None
    if settings.get("_IS_MODULO", "0").strip() not in ("1", "1.0"):
        raise CompensationError(f"{where}: a rotary axis's table over one turn is a modulo table (IS_MODULO = 1)")
    if sorted(points) != list(range(len(points))):
        raise CompensationError(f"{where}: the points must be numbered 0, 1, 2, … without gaps")
    positions = lo + step * np.arange(len(points))
    if abs(positions[-1] - hi) > 1e-6:
        raise CompensationError(f"{where}: {len(points)} points of {step:g}° from {lo:g} do not end at MAX {hi:g}")
    return positions, np.array([points[i] for i in range(len(points))])
