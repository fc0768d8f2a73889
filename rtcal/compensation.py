"""Compensation tables for a rotary axis: one writer and one parser per controller format.

From a positioning-deviation table: per direction the mean deviation e = actual − commanded over
the runs at each target, resampled onto a regular grid over one turn by periodic linear
interpolation (a controller interpolates linearly between its entries too), and referred to the
axis datum (e = 0 at 0° in the positive direction: the reference point stays where it is). The
controller then commands θ + trim(θ) with trim = −e, so that the table reaches θ. How each
format expresses that (actual positions, trims, values that "move the axis negative",
increments) and its rules are in docs/compensation.md; every parser returns the trims, so a
written table can be read back and applied (rtcal's simulated controller does exactly that).

Formats: ``linuxcnc`` (type 0: nominal, forward actual, reverse actual), ``siemens-lec`` (one
table: the mean of both directions; the reversal is left to backlash compensation),
``siemens-cec`` (one table per direction), ``fanuc`` (pitch error compensation parameters,
incremental, bidirectional), ``heidenhain`` (a .COM table, one direction: the mean).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from rtcal.deviations import PositioningDeviations

FORMATS = ("linuxcnc", "siemens-lec", "siemens-cec", "fanuc", "heidenhain")
ARCSEC_PER_DEG = 3600.0
MAX_POINTS = {"linuxcnc": 256, "heidenhain": 256, "siemens-lec": 1000, "siemens-cec": 1000, "fanuc": 1024}


class CompensationError(ValueError):
    """A table that cannot be made or read; the message says why (and where, for a file)."""


@dataclass(frozen=True)
class CompensationTable:
    """Trims (deg) on a regular grid over one turn, 0 … 360 inclusive (the last equals the first)."""

    positions_deg: np.ndarray
    trim_up_deg: np.ndarray
    trim_down_deg: np.ndarray  # equal to trim_up_deg for a one-direction format

    @property
    def step_deg(self) -> float:
        return float(self.positions_deg[1] - self.positions_deg[0])

    def trim_deg(self, commanded_deg: float, direction: int) -> float:
        """What the controller adds to a command approached in ``direction``: linear between entries."""
        values = self.trim_up_deg if direction >= 0 else self.trim_down_deg
        return float(np.interp(np.mod(commanded_deg, 360.0), self.positions_deg, values))


def table_from_deviations(table: PositioningDeviations, step_deg: float = 15.0, max_gap_deg: float = 60.0) -> CompensationTable:
    """Trims on a regular grid from the measured deviations (mean over runs per target and direction)."""
    if not (0.0 < step_deg <= 90.0) or abs(360.0 / step_deg - round(360.0 / step_deg)) > 1e-9:
        raise CompensationError(f"--step-deg {step_deg:g}: the grid must divide one turn (e.g. 5, 10, 15, 30)")
    grid = np.linspace(0.0, 360.0, int(round(360.0 / step_deg)) + 1)
    errors = {}
    for d in (1, -1):
        sel = (table.direction == d) & np.isfinite(table.deviation_arcsec)
        if not sel.any():
            continue
        angles = np.mod(np.round(table.target_deg[sel], 9), 360.0)
        targets = np.unique(angles)
        means = np.array([table.deviation_arcsec[sel][angles == t].mean() for t in targets])
        gaps = np.diff(np.concatenate([targets, [targets[0] + 360.0]]))
        if len(targets) < 3 or gaps.max() > max_gap_deg + 1e-9:
            worst = int(np.argmax(gaps))
            raise CompensationError(
                f"the {'positive' if d > 0 else 'negative'} direction's targets leave a gap of {gaps.max():g}° after "
                f"{targets[worst]:g}° (at most {max_gap_deg:g}° is interpolated over): measure more targets")
        errors[d] = np.interp(grid, targets, means, period=360.0)
    if 1 not in errors:
        raise CompensationError("no deviations in the positive direction: nothing to refer the datum to")
    datum = errors[1][0]
    up = -(errors[1] - datum) / ARCSEC_PER_DEG
    down = -(errors[-1] - datum) / ARCSEC_PER_DEG if -1 in errors else up.copy()
    return CompensationTable(grid, up, down)


def _check_points(fmt: str, table: CompensationTable) -> None:
    if len(table.positions_deg) > MAX_POINTS[fmt]:
        raise CompensationError(f"{fmt}: {len(table.positions_deg)} points; the format takes at most {MAX_POINTS[fmt]} "
                                "(choose a larger --step-deg)")


# -- LinuxCNC ------------------------------------------------------------------------------
def write_linuxcnc(table: CompensationTable) -> str:
    """COMP_FILE_TYPE = 0: ``nominal forward_actual reverse_actual`` per line, degrees, ascending;
    no header or comment (LinuxCNC stops reading at the first line that is not three numbers)."""
    _check_points("linuxcnc", table)
    return "".join(f"{p:.6f} {p - u:.8f} {p - d:.8f}\n"
                   for p, u, d in zip(table.positions_deg, table.trim_up_deg, table.trim_down_deg))


def parse_linuxcnc(text: str, where: str = "<linuxcnc>") -> CompensationTable:
    rows = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        parts = line.split()
        if not parts:
            continue
        try:
            rows.append([float(v) for v in parts])
        except ValueError:
            raise CompensationError(f"{where}:{line_no}: expected three numbers (nominal, forward actual, reverse actual)") from None
        if len(parts) != 3 or not all(np.isfinite(rows[-1])):
            raise CompensationError(f"{where}:{line_no}: expected three finite numbers (nominal, forward actual, reverse actual)")
    return _regular(np.array(rows)[:, 0], np.array(rows)[:, 0] - np.array(rows)[:, 1], np.array(rows)[:, 0] - np.array(rows)[:, 2],
                    where, 256) if rows else _empty(where)


# -- Siemens ---------------------------------------------------------------------------
def write_siemens_lec(table: CompensationTable, axis: str = "C1") -> str:
    """LEC, one table (the mean of both directions): a positive value moves the axis negative, so
    the value is the deviation, −trim, in degrees; modulo: the value at MAX repeats MIN's."""
    _check_points("siemens-lec", table)
    mean = (table.trim_up_deg + table.trim_down_deg) / 2
    lines = ["%_N_AX_EEC_INI", "CHANDATA(1)"]
    lines += [f"$AA_ENC_COMP[0,{i},{axis}]={-v + 0.0:.8f}" for i, v in enumerate(mean)]
    lines += [f"$AA_ENC_COMP_STEP[0,{axis}]={table.step_deg:.6f}", f"$AA_ENC_COMP_MIN[0,{axis}]=0.0",
              f"$AA_ENC_COMP_MAX[0,{axis}]=360.0", f"$AA_ENC_COMP_IS_MODULO[0,{axis}]=1", "M17"]
    return "\n".join(lines) + "\n"


def write_siemens_cec(table: CompensationTable, axis: str = "C1") -> str:
    """CEC, one table per direction (table 0 positive, table 1 negative approach): the value is
    added to the axis's setpoint, so it is the trim, in degrees."""
    _check_points("siemens-cec", table)
    lines = ["%_N_NC_CEC_INI", "CHANDATA(1)"]
    for t, (values, sense) in enumerate(((table.trim_up_deg, 1), (table.trim_down_deg, -1))):
        lines += [f"$AN_CEC[{t},{i}]={v + 0.0:.8f}" for i, v in enumerate(values)]  # + 0.0: no "-0.0"
        lines += [f"$AN_CEC_INPUT_AXIS[{t}]={axis}", f"$AN_CEC_OUTPUT_AXIS[{t}]={axis}", f"$AN_CEC_STEP[{t}]={table.step_deg:.6f}",
                  f"$AN_CEC_MIN[{t}]=0.0", f"$AN_CEC_MAX[{t}]=360.0", f"$AN_CEC_DIRECTION[{t}]={sense}",
                  f"$AN_CEC_IS_MODULO[{t}]=1"]
    lines.append("M17")
    return "\n".join(lines) + "\n"


SIEMENS_LINE = re.compile(r"\$(AA_ENC_COMP|AN_CEC)(_[A-Z_]+)?\[([^\]]*)\]=(\S+)")


def _siemens_values(text: str, where: str) -> tuple[dict[tuple[str, int], dict[int, float]], dict[tuple[str, int], dict[str, str]]]:
    points: dict[tuple[str, int], dict[int, float]] = {}
    settings: dict[tuple[str, int], dict[str, str]] = {}
    for line_no, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line.startswith("$"):
            continue
        m = SIEMENS_LINE.fullmatch(line)
        if not m:
            raise CompensationError(f"{where}:{line_no}: not a compensation assignment: {line[:60]!r}")
        name, suffix, index, value = m.group(1), m.group(2) or "", m.group(3).split(","), m.group(4)
        table_no = int(index[0]) if index[0].strip().isdigit() else 0
        if not suffix:
            try:
                points.setdefault((name, table_no), {})[int(index[1])] = float(value)
            except (IndexError, ValueError):
                raise CompensationError(f"{where}:{line_no}: expected [table,point,...]=number") from None
        else:
            settings.setdefault((name, table_no), {})[suffix] = value
    return points, settings


def _siemens_table(values: dict[int, float], settings: dict[str, str], where: str) -> tuple[np.ndarray, np.ndarray]:
    try:
        step, lo, hi = float(settings["_STEP"]), float(settings["_MIN"]), float(settings["_MAX"])
    except (KeyError, ValueError):
        raise CompensationError(f"{where}: STEP, MIN and MAX must be given") from None
    if sorted(values) != list(range(len(values))):
        raise CompensationError(f"{where}: the points must be numbered 0, 1, 2, … without gaps")
    positions = lo + step * np.arange(len(values))
    if abs(positions[-1] - hi) > 1e-6:
        raise CompensationError(f"{where}: {len(values)} points of {step:g}° from {lo:g} do not end at MAX {hi:g}")
    return positions, np.array([values[i] for i in range(len(values))])


def parse_siemens_lec(text: str, where: str = "<siemens-lec>") -> CompensationTable:
    points, settings = _siemens_values(text, where)
    key = ("AA_ENC_COMP", 0)
    if key not in points:
        raise CompensationError(f"{where}: no $AA_ENC_COMP values")
    positions, values = _siemens_table(points[key], settings.get(key, {}), where)
    return _regular(positions, -values, -values, where, MAX_POINTS["siemens-lec"])


def parse_siemens_cec(text: str, where: str = "<siemens-cec>") -> CompensationTable:
    points, settings = _siemens_values(text, where)
    tables = {}
    for (name, t), values in points.items():
        direction = int(float(settings.get((name, t), {}).get("_DIRECTION", "0")))
        tables[direction] = _siemens_table(values, settings.get((name, t), {}), where)
    if 1 not in tables:
        raise CompensationError(f"{where}: no table for the positive direction ($AN_CEC_DIRECTION = 1)")
    positions, up = tables[1]
    down = tables.get(-1, (positions, up))[1]
    return _regular(positions, up, down, where, MAX_POINTS["siemens-cec"])


# -- FANUC -----------------------------------------------------------------------------
def write_fanuc(table: CompensationTable, unit_deg: float = 0.0001, first_point: int = 1000) -> str:
    """Pitch error compensation, bidirectional (parameter 3605#0 = 1), as a parameter listing.
    Values are incremental, in detection units (``unit_deg``) × magnification 1: point k holds the
    change of the trim from the grid position before it; over one turn they sum to zero, and the
    first point (0°) holds the same value as the last (360°), which is the same position. The
    negative-direction table follows the positive one; 3627 holds its value at the reference
    position relative to the positive table's."""
    _check_points("fanuc", table)
    n = len(table.positions_deg) - 1
    up_points = list(range(first_point, first_point + n + 1))
    down_points = list(range(first_point + n + 1, first_point + 2 * n + 2))

    def increments(trims: np.ndarray) -> list[int]:
        cumulative = np.round(trims / unit_deg).astype(int)  # quantise the running trim, then difference: Σ = 0
        inc = np.diff(cumulative).tolist()
        return [inc[-1]] + inc  # the first point (0°) is the last (360°)

    lines = [f"(FANUC pitch error compensation for the rotary axis; detection unit {unit_deg:g} deg; written by rtcal)",
             "3605 #0 = 1  (bidirectional pitch error compensation)",
             f"3620 = {first_point}  (compensation point of the reference position)",
             f"3621 = {up_points[0]}  (farthest point, negative side)", f"3622 = {up_points[-1]}  (farthest point, positive side)",
             "3623 = 1  (magnification)", f"3624 = {round(table.step_deg / unit_deg)}  (interval, detection units)",
             f"3625 = {round(360.0 / unit_deg)}  (travel per revolution, detection units)",
             f"3626 = {down_points[-1]}  (farthest point of the negative-direction table)",
             f"3627 = {int(round((table.trim_down_deg[0] - table.trim_up_deg[0]) / unit_deg))}  "
             "(value at the reference position, negative approach)"]
    lines += [f"{p} = {v:+d}" for p, v in zip(up_points, increments(table.trim_up_deg))]
    lines += [f"{p} = {v:+d}" for p, v in zip(down_points, increments(table.trim_down_deg))]
    return "\n".join(lines) + "\n"


FANUC_LINE = re.compile(r"(\d+)(?: #0)? = ([+-]?\d+)(?:\s+\(.*\))?")


def parse_fanuc(text: str, where: str = "<fanuc>") -> CompensationTable:
    values: dict[int, int] = {}
    for line_no, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("("):
            continue
        m = FANUC_LINE.fullmatch(line)
        if not m:
            raise CompensationError(f"{where}:{line_no}: expected `number = integer`: {line[:60]!r}")
        values[int(m.group(1))] = int(m.group(2))
    try:
        first, last, interval, per_rev, down_last = values[3621], values[3622], values[3624], values[3625], values[3626]
        offset = values.get(3627, 0)
    except KeyError as exc:
        raise CompensationError(f"{where}: parameter {exc.args[0]} is missing") from None
    unit = 360.0 / per_rev
    n = last - first
    if n < 2 or abs(n * interval - per_rev) > 0:
        raise CompensationError(f"{where}: {n} intervals of {interval} units do not make one turn of {per_rev}")

    def trims(points: range, start: int) -> np.ndarray:
        try:
            inc = np.array([values[p] for p in points])
        except KeyError as exc:
            raise CompensationError(f"{where}: compensation point {exc.args[0]} is missing") from None
        if inc[1:].sum() != 0 or inc[0] != inc[-1]:
            raise CompensationError(f"{where}: a rotary table's increments must sum to zero over the turn, and its first "
                                    "and last points (the same position) must hold the same value")
        return (start + np.concatenate([[0], np.cumsum(inc[1:])])) * unit

    positions = np.arange(n + 1) * interval * unit
    up = trims(range(first, last + 1), 0)
    down = trims(range(last + 1, down_last + 1), offset) if down_last > last else up
    return _regular(positions, up, down, where, MAX_POINTS["fanuc"])


# -- HEIDENHAIN ------------------------------------------------------------------------
def write_heidenhain(table: CompensationTable, axis: str = "C") -> str:
    """A .COM table for nonlinear axis error compensation: entries 0 … 360°, the compensation value
    of the axis added to its position (the trim), one direction (the mean of both)."""
    _check_points("heidenhain", table)
    mean = (table.trim_up_deg + table.trim_down_deg) / 2
    lines = [f"BEGIN AXIS-{axis}.COM DATUM:+0.0000 DISTANCE:{table.step_deg:+.4f}", f"NR AXISPOS {axis}"]
    lines += [f"{i} {p:+.4f} {v + 0.0:+.8f}" for i, (p, v) in enumerate(zip(table.positions_deg, mean))]
    lines.append("[END]")
    return "\n".join(lines) + "\n"


def parse_heidenhain(text: str, where: str = "<heidenhain>") -> CompensationTable:
    rows = []
    lines = text.splitlines()
    if not lines or not lines[0].startswith("BEGIN AXIS"):
        raise CompensationError(f"{where}:1: expected the header `BEGIN AXIS-C.COM …`")
    for line_no, line in enumerate(lines[2:], start=3):
        line = line.strip()
        if line == "[END]":
            break
        parts = line.split()
        try:
            if len(parts) != 3:
                raise ValueError
            rows.append((int(parts[0]), float(parts[1]), float(parts[2])))
        except ValueError:
            raise CompensationError(f"{where}:{line_no}: expected `NR AXISPOS value`") from None
    else:
        raise CompensationError(f"{where}: no [END]")
    if [r[0] for r in rows] != list(range(len(rows))):
        raise CompensationError(f"{where}: entries must be numbered 0, 1, 2, …")
    a = np.array(rows, float) if rows else np.zeros((0, 3))
    return _regular(a[:, 1], a[:, 2], a[:, 2], where, MAX_POINTS["heidenhain"]) if rows else _empty(where)


# -- common ----------------------------------------------------------------------------
def _empty(where: str) -> CompensationTable:
    raise CompensationError(f"{where}: no entries")


def _regular(positions: np.ndarray, up: np.ndarray, down: np.ndarray, where: str, max_points: int) -> CompensationTable:
    """Check what every format needs for a rotary axis: 0 … 360, evenly spaced, closing on itself."""
    positions = np.asarray(positions, float)
    if len(positions) < 3 or len(positions) > max_points:
        raise CompensationError(f"{where}: {len(positions)} entries (3 … {max_points})")
    steps = np.diff(positions)
    if np.any(steps <= 0):
        raise CompensationError(f"{where}: positions must be strictly ascending")
    if abs(positions[0]) > 1e-6 or abs(positions[-1] - 360.0) > 1e-6 or np.ptp(steps) > 1e-6:
        raise CompensationError(f"{where}: a rotary table's entries run evenly from 0 to 360 degrees")
    for name, values in (("positive", up), ("negative", down)):
        if not np.all(np.isfinite(values)) or np.max(np.abs(values)) > 1.0:
            raise CompensationError(f"{where}: {name}-direction values must be finite and below 1 degree")
        if abs(values[0] - values[-1]) > 1e-9:
            raise CompensationError(f"{where}: the {name}-direction value at 360° must equal the one at 0° (one turn closes)")
    return CompensationTable(positions, np.asarray(up, float), np.asarray(down, float))


WRITERS = {"linuxcnc": write_linuxcnc, "siemens-lec": write_siemens_lec, "siemens-cec": write_siemens_cec,
           "fanuc": write_fanuc, "heidenhain": write_heidenhain}
PARSERS = {"linuxcnc": parse_linuxcnc, "siemens-lec": parse_siemens_lec, "siemens-cec": parse_siemens_cec,
           "fanuc": parse_fanuc, "heidenhain": parse_heidenhain}
