"""The simulated CNC controllers that apply a compensation table, each read and applied as its
manual describes — written apart from rtcal's writers (rtcal/compensation/) so that the closed
loop (ISO test → table → verification) does not only check a writer against its own reading.
Every controller here has its own parser of the file; what it applies is the amount added to
the commanded angle (deg) for an approach direction, i.e. where the motor is sent.

Sources (docs/compensation.md, ../shared/reference/compensation_formats.md):
- SINUMERIK LEC: Function Manual Extended Functions K3 03/2013 pp. 238, 241, 242.
- SINUMERIK CEC: K3 pp. 249, 264, 268; 802D sl p. 222.
- SINUMERIK backlash compensation MD32450 $MA_BACKLASH (machine data of the axis, not in the file):
  808D Parameter Manual 08/2013 (6FC5397-8EP40-0BA0) p. 228; 840C NC machine data 09.95 p. 6-41.
- FANUC: 0i-PB Parameter Manual B-63980EN/01 p. 100; Technical Report A-77810E; 15i Parameter
  Manual B-63330EN/03 p. 25 (I/O records).
- HEIDENHAIN: TNC 407 Technical Manual pp. 151-156; TNC 335 p. 4-24; MANUALplus 620 pp. 716-718.
Formats with no controller here (LinuxCNC, proven against the real LinuxCNC; plugins) are applied
through their own ``load`` (rtcal/compensation/base.py)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np


class ControllerError(ValueError):
    """The simulated control refuses the file (as the real one would raise an alarm)."""


class Applies(Protocol):
    def trim_deg(self, commanded_deg: float, direction: int) -> float: ...


@dataclass(frozen=True)
class CyclicCurve:
    """Values at points ``start + k·step`` over one turn, linear between points, repeated every 360°;
    points from 0° to beyond 360° (a TNC 4xx table) are read as they stand, the last interval
    across 360° from the entries either side."""

    positions_deg: np.ndarray
    values: np.ndarray

    def at(self, angle_deg: float) -> float:
        if self.positions_deg[0] == 0.0 and self.positions_deg[-1] > 360.0:
            return float(np.interp(np.mod(angle_deg, 360.0), self.positions_deg, self.values))
        return float(np.interp(np.mod(angle_deg, 360.0), self.positions_deg, self.values, period=360.0))


@dataclass(frozen=True)
class Applied:
    """What a controller adds to the command per approach direction: ``sign`` × the curve's value,
    plus its backlash compensation (``backlash_deg``, see ``with_backlash``)."""

    up: CyclicCurve
    down: CyclicCurve
    sign: float
    backlash_deg: float = 0.0
    reference_direction: int = +1

    def trim_deg(self, commanded_deg: float, direction: int) -> float:
        d = +1 if direction >= 0 else -1
        reversed_ = d != self.reference_direction  # approached against the reference approach: one reversal more
        return self.sign * (self.up if d > 0 else self.down).at(commanded_deg) + (d * self.backlash_deg if reversed_ else 0.0)


def with_backlash(applied: Applied, backlash_deg: float, reference_direction: int = +1) -> Applied:
    """SINUMERIK backlash compensation, MD32450: "Backlash on reversal between positive and negative
    travel directions. Input of the compensation value is positive, if the encoder is leading the
    machine part (normal situation) … always active after reference point approach" (808D Parameter
    Manual p. 228; the simulated axis counts as referenced); "The control compensates the backlash …
    each time the relevant axis changes its direction of travel" (840C MD 220*, p. 6-41). So on each
    reversal the motor travels the backlash further in the new direction: approached in the
    direction of the reference approach it stands at the command (where the axis was referenced),
    approached the other way the backlash further that way. Only the reversal changes, not a
    constant (which changes no ISO 230-2 figure anyway)."""
    return Applied(applied.up, applied.down, applied.sign, backlash_deg, reference_direction)


# -- SINUMERIK: %_N_..._INI files of $-assignments ----------------------------------------
SINUMERIK_LINE = re.compile(r"\$([A-Z_]+)\[([^\]]*)\]\s*=\s*(.+)")


def _sinumerik(text: str, where: str) -> list[tuple[str, list[str], str]]:
    """Every assignment of a SINUMERIK INI file (``;`` starts a comment, K3 p. 242's example)."""
    out = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split(";", 1)[0].strip()
        if not line or line.startswith("%") or line.startswith("CHANDATA") or line == "M17":
            continue
        m = SINUMERIK_LINE.fullmatch(line)
        if not m:
            raise ControllerError(f"{where}:{number}: the control does not take {line!r}")
        out.append((m.group(1), [i.strip() for i in m.group(2).split(",")], m.group(3).strip()))
    return out


def _interpolation_points(values: dict[int, float], step: float, lo: float, hi: float, where: str) -> CyclicCurve:
    """MIN, STEP, MAX and points 0 … N "without gaps" (K3 p. 241); modulo 360: MAX's value is MIN's."""
    n = int(round((hi - lo) / step))
    if sorted(values) != list(range(n + 1)):
        raise ControllerError(f"{where}: interpolation points 0 … {n} must all be assigned (K3 p. 241: no gaps)")
    if abs(lo) > 1e-9 or abs(hi - 360.0) > 1e-9:
        raise ControllerError(f"{where}: a modulo-360 rotary axis's table runs from MIN 0 to MAX 360 (K3 p. 241)")
    return CyclicCurve(lo + step * np.arange(n + 1), np.array([values[i] for i in range(n + 1)]))


def sinumerik_lec(text: str, where: str) -> Applied:
    """LEC: "A positive compensation value causes the corresponding machine axis to move in the
    negative direction" (K3 p. 238): the motor goes to command − value; one table, both directions;
    IS_MODULO 1 repeats it every turn (p. 241), linear between interpolation points."""
    points: dict[int, float] = {}
    setting: dict[str, float] = {}
    for name, index, value in _sinumerik(text, where):
        if name == "AA_ENC_COMP":
            if index[0] != "0":
                raise ControllerError(f"{where}: the simulated axis has one encoder (0)")
            points[int(index[1])] = float(value)
        elif name.startswith("AA_ENC_COMP_"):
            setting[name.removeprefix("AA_ENC_COMP_")] = float(value)
        else:
            raise ControllerError(f"{where}: ${name} is not LEC data")
    if setting.get("IS_MODULO") != 1:
        raise ControllerError(f"{where}: the rotary axis needs $AA_ENC_COMP_IS_MODULO = 1 (K3 p. 241)")
    curve = _interpolation_points(points, setting["STEP"], setting["MIN"], setting["MAX"], where)
    return Applied(curve, curve, -1.0)


def sinumerik_cec(text: str, where: str) -> Applied:
    """CEC: the table's value is added to the output axis's setpoint (the sign is not stated in the
    manuals' excerpts: this controller adds it); $AN_CEC_DIRECTION 1 acts on positive, −1 on
    negative, 0 on both traversing directions (K3 p. 249, two tables for position-dependent
    backlash p. 264); axis names as written, with or without parentheses (802D sl p. 222)."""
    points: dict[int, dict[int, float]] = {}
    setting: dict[int, dict[str, str]] = {}
    for name, index, value in _sinumerik(text, where):
        t = int(index[0])
        if name == "AN_CEC":
            points.setdefault(t, {})[int(index[1])] = float(value)
        elif name.startswith("AN_CEC_"):
            setting.setdefault(t, {})[name.removeprefix("AN_CEC_")] = value.strip("() ")
        else:
            raise ControllerError(f"{where}: ${name} is not CEC data")
    by_direction: dict[int, CyclicCurve] = {}
    for t, values in points.items():
        s = setting.get(t, {})
        if s.get("INPUT_AXIS") != s.get("OUTPUT_AXIS") or "INPUT_AXIS" not in s:
            raise ControllerError(f"{where}: table {t} compensates another axis than the rotary one")
        if float(s.get("IS_MODULO", "0")) != 1 or float(s.get("MULT_BY_TABLE", "0")) != 0:
            raise ControllerError(f"{where}: table {t}: the rotary axis's table is modulo and not multiplied")
        curve = _interpolation_points(values, float(s["STEP"]), float(s["MIN"]), float(s["MAX"]), f"{where}: table {t}")
        direction = int(float(s.get("DIRECTION", "0")))
        for d in ((1, -1) if direction == 0 else (direction,)):
            if d in by_direction:
                raise ControllerError(f"{where}: two tables act on direction {d}")
            by_direction[d] = curve
    if set(by_direction) != {1, -1}:
        raise ControllerError(f"{where}: no table acts on the {'positive' if 1 not in by_direction else 'negative'} direction")
    return Applied(by_direction[1], by_direction[-1], 1.0)


# -- FANUC: the I/O file ('%', N…P…; records, '%') or a listing -----------------------------
FANUC_RECORD = re.compile(r"N(\d{5})(?:A\d+)?P([+-]?[\d.]+);")
FANUC_LISTED = re.compile(r"(\d+)(?: #0)? = ([+-]?[\d.]+)")
FANUC_STATED_UNIT = re.compile(r"detection unit ([0-9.]+(?:e-?\d+)?) deg")


def fanuc_stated_unit(text: str) -> float | None:
    """The detection unit a FANUC file says it was made for, on its first line (the I/O file's
    ``%`` line, whose rest the control skips: 16i Operator's Manual B-63524EN/01 p. 649) — not
    read by the control: what the engineer who loads it is asked to compare with the axis."""
    first = next((line for line in text.splitlines() if line.strip()), "")
    m = FANUC_STATED_UNIT.search(first)
    return float(m.group(1)) if m else None


def fanuc(text: str, where: str, detection_unit_deg: float | None = None, reference_return: int = +1,
          bidirectional: bool = True) -> Applied:
    """Bidirectional pitch error compensation (A-77810E): the positive-travel table runs 3621 … 3622
    (3621 = 3620 on a rotary axis, 0i-PB p. 100), the negative-travel table from 3626; each point
    holds the change of the compensation over the section ending at it, "output at the
    compensation position No. corresponding to each section" (p. 100) — spread over the section
    here. The table of the reference-return direction is 0 at the reference position; the other
    starts from 3627. The amount is added to the command (the pitch error pulses move the axis).
    Units: the axis's ``detection_unit_deg`` (its increment system, whatever the file was made
    for) × 3623; without it, 360/3625 when 3625 is an integer. ``bidirectional``: the axis's
    3605#0 as set on the control, unless the file carries a 3605 record (a whole byte, 15i p. 25)."""
    lines = [line.split("(", 1)[0].strip() for line in text.splitlines()]
    lines = [line for line in lines if line]
    io_file = bool(lines) and lines[0] == "%"
    params: dict[int, str] = {}
    points: dict[int, int] = {}
    for line in (lines[1:-1] if io_file else lines):
        m = (FANUC_RECORD if io_file else FANUC_LISTED).fullmatch(line)
        if not m:
            raise ControllerError(f"{where}: the control does not read {line!r}")
        number = int(m.group(1))
        if io_file and number >= 10000:
            points[number - 10000] = int(m.group(2))
        elif 3600 <= number < 3700:
            params[number] = m.group(2)
        else:
            points[number] = int(m.group(2))
    ref, lo, hi = int(params[3620]), int(params[3621]), int(params[3622])
    if lo != ref:
        raise ControllerError(f"{where}: a rotary axis's 3621 equals 3620 (0i-PB p. 100)")
    per_rev = params[3625]
    if detection_unit_deg is None:
        if "." in per_rev:
            raise ControllerError(f"{where}: 3625 is in degrees: the simulated axis needs its detection unit (detection_unit_deg)")
        detection_unit_deg = 360.0 / int(per_rev)
    elif "." not in per_rev and abs(int(per_rev) * detection_unit_deg - 360.0) > 1e-9:
        raise ControllerError(f"{where}: 3625 = {per_rev} detection units of {detection_unit_deg:g}° is not one turn: this "
                              "control would place the points elsewhere (not simulated)")
    unit = detection_unit_deg * int(params[3623])
    n = hi - lo
    positions = np.linspace(0.0, 360.0, n + 1)

    def curve(first: int, start: int) -> CyclicCurve:
        inc = np.array([points[first + k] for k in range(1, n + 1)])
        if inc.sum() != 0:
            raise ControllerError(f"{where}: the increments of one turn do not sum to 0: the error accumulates per turn")
        return CyclicCurve(positions, (start + np.concatenate([[0], np.cumsum(inc)])) * unit)

    if 3605 in params:  # a bit parameter: 8 binary digits in the I/O file (15i p. 25), #0 in a listing
        bits = params[3605]
        bidirectional = int(bits, 2 if len(bits) == 8 else 10) & 1 == 1
    other = int(params.get(3627, "0"))
    up = curve(lo, 0 if reference_return > 0 else other)
    down = curve(int(params[3626]), other if reference_return > 0 else 0) if bidirectional and 3626 in params else up
    return Applied(up, down, 1.0)


# -- HEIDENHAIN: a .COM table -----------------------------------------------------------
def heidenhain(text: str, where: str) -> Applied:
    """Nonlinear axis error compensation: the table is the axis's error curve (TNC 407 p. 153,
    "Error in Z"; MP720 p. 151 "the error is positive if the table travel is too long"), which the
    control removes: the motor goes to command − error; linear between entries, 0 … 360 for a
    rotary axis (p. 156); the BACKLASH column the negative direction's values (MANUALplus 620
    p. 716). A TNC 4xx table's power-of-two spacing divides no turn: its entries cover it (TNC 306
    p. 4-21), and the interval across 360° is read from the entries either side (the first beyond
    360° counts; later ones are not "entries from 0 to 360"). Header and column line as rtcal
    writes them (their exact form is unconfirmed)."""
    rows = [line.split() for line in text.splitlines() if line.strip()]
    if not rows or rows[0][0] != "BEGIN" or rows[-1] != ["[END]"]:
        raise ControllerError(f"{where}: a .COM table runs from BEGIN to [END]")
    columns = rows[1]
    if columns[:2] != ["NR", "AXISPOS"]:
        raise ControllerError(f"{where}: no NR AXISPOS columns")
    a = np.array([[float(v) for v in r] for r in rows[2:-1]])
    beyond = np.nonzero(a[:, 1] >= 360.0 - 1e-9)[0]
    if a[0, 1] != 0.0 or not len(beyond):
        raise ControllerError(f"{where}: a rotary axis's entries run 0 … 360 (TNC 407 p. 156)")
    a = a[: beyond[0] + 1]
    up = CyclicCurve(a[:, 1], a[:, 2])
    down = CyclicCurve(a[:, 1], a[:, columns.index("BACKLASH")]) if "BACKLASH" in columns else up
    return Applied(up, down, -1.0)


CONTROLLERS: dict[str, Callable[[str, str], Applied]] = {
    "siemens-lec": sinumerik_lec, "siemens-cec": sinumerik_cec, "fanuc": fanuc, "heidenhain": heidenhain}
SINUMERIK = ("siemens-lec", "siemens-cec")  # the controls whose axis has MD32450


def controller(fmt: str, text: str, where: str, backlash_deg: float = 0.0, detection_unit_deg: float | None = None,
               bidirectional: bool = True) -> Applies:
    """The table as the simulated control of ``fmt`` applies it, with the SINUMERIK axis's
    MD32450 ``backlash_deg`` (``with_backlash``) or the FANUC axis's detection unit and 3605#0;
    formats without a controller here (LinuxCNC, plugins) through their own reading. Loading a
    FANUC table that states another detection unit than the axis's is refused: the control
    skips that statement, but the engineer loading it compares it with the axis, as
    `rtcal compensate` asks."""
    if backlash_deg and fmt not in SINUMERIK:
        raise ControllerError(f"{where}: backlash_deg is SINUMERIK machine data (MD32450); the {fmt} control has none")
    if detection_unit_deg is not None and fmt != "fanuc":
        raise ControllerError(f"{where}: detection_unit_deg is a FANUC axis's; the {fmt} control has none")
    if fmt == "fanuc":
        stated = fanuc_stated_unit(text)
        if stated is not None and detection_unit_deg is not None and abs(stated - detection_unit_deg) > 1e-12:
            raise ControllerError(f"{where}: the table is for a detection unit of {stated:g}°, the axis's is "
                                  f"{detection_unit_deg:g}° (detection_unit_deg): every trim would be "
                                  f"{detection_unit_deg / stated:g}x what it should; write it with --detection-unit-deg "
                                  f"{detection_unit_deg:g}")
    if fmt in CONTROLLERS:
        try:
            applied = (fanuc(text, where, detection_unit_deg, bidirectional=bidirectional) if fmt == "fanuc"
                       else CONTROLLERS[fmt](text, where))
        except (KeyError, IndexError, ValueError) as exc:
            if isinstance(exc, ControllerError):
                raise
            raise ControllerError(f"{where}: the simulated {fmt} control refuses the table ({exc})") from None
        return with_backlash(applied, backlash_deg) if backlash_deg else applied
    from rtcal.compensation import get_format
    return get_format(fmt).load(text, where)
