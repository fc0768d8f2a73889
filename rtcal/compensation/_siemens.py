"""The file grammar both SINUMERIK tables share (``%_N_…_INI``: header, CHANDATA, ``;``
comments, ``$NAME[…]=value`` assignments, M17), read strictly: rtcal/compensation/siemens_lec.py
and siemens_cec.py build on it."""

from __future__ import annotations

import re

import numpy as np

from rtcal.compensation.base import axis_option
from rtcal.compensation.table import CompensationError

AXIS = axis_option(r"[A-Z][A-Z0-9_]{0,15}", "C1")
MAX_POINTS = 1000
HEADER = {"AA_ENC_COMP": "%_N_AX_EEC_INI", "AN_CEC": "%_N_NC_CEC_INI"}
LINE = re.compile(r"\$(AA_ENC_COMP|AN_CEC)(_[A-Z_]+)?\[([^\]]*)\]=(\S+)")


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
