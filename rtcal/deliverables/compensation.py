"""Compensation tables for a rotary axis: one writer and one parser per controller format.

From a positioning-deviation table: per direction the mean deviation e = actual − commanded over
the runs at each target, written at the measured targets themselves (or, when asked, resampled
onto a regular grid over one turn by periodic linear interpolation — a controller interpolates
linearly between its entries too), and referred to the axis datum (e = 0 at 0° in the positive
direction: the reference point stays where it is). Formats with a fixed pitch (SINUMERIK, FANUC,
HEIDENHAIN) take only evenly spaced points from 0°; irregular targets need a grid asked for. A
run measured in one direction is refused unless the caller allows writing its values both ways
(what that does to the machine's reversal compensation depends on the format: ONE_DIRECTION).
Whether the targets lie close enough together for the error the data show is checked against
its harmonics (:func:`interpolation_check`). The
controller then commands θ + trim(θ) with trim = −e, so that the table reaches θ. How each
format expresses that (actual positions, trims, values that "move the axis negative",
increments) and its rules are in docs/compensation.md; every parser returns the trims, so a
written table can be read back and applied (rtcal's simulated controller does exactly that:
modulo one turn for the rotary formats, with the end trims held beyond its range for LinuxCNC,
which does not wrap). A parser refuses, with its line, what the controller would read otherwise
than rtcal meant (LinuxCNC silently stops at the first line that is not three numbers).

Formats: ``linuxcnc`` (type 0: nominal, forward actual, reverse actual), ``siemens-lec`` (one
table: the mean of both directions; the reversal is left to backlash compensation),
``siemens-cec`` (one table per direction), ``fanuc`` (pitch error compensation parameters,
incremental, bidirectional), ``heidenhain`` (a .COM table, one direction: the mean).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from rtcal.deliverables.deviations import PositioningDeviations

FORMATS = ("linuxcnc", "siemens-lec", "siemens-cec", "fanuc", "heidenhain")
ARCSEC_PER_DEG = 3600.0
MAX_POINTS = {"linuxcnc": 256, "heidenhain": 256, "siemens-lec": 1000, "siemens-cec": 1000, "fanuc": 1024}


class CompensationError(ValueError):
    """A table that cannot be made or read; the message says why (and where, for a file)."""


FIXED_PITCH = {"siemens-lec": "$AA_ENC_COMP_STEP", "siemens-cec": "$AN_CEC_STEP", "fanuc": "parameter 3624",
               "heidenhain": "the header's DISTANCE"}  # formats whose points lie at one pitch from 0°
COMMENT = {"siemens-lec": "; ", "siemens-cec": "; ", "fanuc": "("}  # formats whose files take a comment line
# What writing one measured direction's values for both directions does to the machine's reversal
# (backlash) compensation, per format (docs/compensation.md)
ONE_DIRECTION = {
    "linuxcnc": "LinuxCNC ignores the joint's BACKLASH once a comp file is set, so forward and reverse columns with the "
                "same values leave the axis with no reversal (backlash) compensation at all",
    "siemens-cec": "both CEC tables (DIRECTION 1 and -1) would hold the same values and compensate no reversal: that is "
                   "left to the axis's backlash compensation (keep it set), and the unmeasured direction is assumed to "
                   "follow the measured one",
    "fanuc": "the negative-travel table would repeat the positive one with 3627 = 0: the bidirectional pitch error "
             "compensation then compensates no reversal, and the unmeasured direction is assumed to follow the measured one",
    "siemens-lec": "the one LEC table stands for the mean of both directions, the reversal left to the axis's backlash "
                   "compensation; from one direction it is that direction's curve, off the mean by half the reversal at "
                   "each target",
    "heidenhain": "the one table stands for the mean of both directions, the reversal left to the axis's backlash "
                  "compensation; from one direction it is that direction's curve, off the mean by half the reversal at "
                  "each target",
}
GRID_STEPS_DEG = (90, 60, 45, 40, 36, 30, 24, 20, 18, 15, 12, 10, 9, 8, 7.5, 6, 5, 4.5, 4, 3.6, 3, 2.5, 2, 1.5, 1.25, 1,
                  0.75, 0.5, 0.25)


@dataclass(frozen=True)
class CompensationTable:
    """Trims (deg) at ascending positions. From ``table_from_deviations``: one turn, 0 … 360
    inclusive (the last repeats the first), at the measured targets — with 0° (and so 360°)
    interpolated across the wrap when 0° was not measured — or on a regular grid when one was
    asked for (``resampled``).

    ``modulo``: the controller applies the table to the command modulo one turn (SINUMERIK modulo
    tables, FANUC rotary axes, HEIDENHAIN 0 … 360 tables). False for LinuxCNC, which does not wrap:
    beyond its first and last lines the end trims hold (its sentinel entries have zero slope), so
    its table must span the joint's travel.

    ``measured_targets``: how many distinct targets the table was made from (0: read from a file).
    ``warnings``: what the user must read before loading it (one direction written both ways,
    gaps too wide for the error the data show) — on the console, and in the file where the
    format takes comments.
    """

    positions_deg: np.ndarray
    trim_up_deg: np.ndarray
    trim_down_deg: np.ndarray  # equal to trim_up_deg for a one-direction format
    modulo: bool = True
    measured_targets: int = 0
    resampled: bool = False
    off_grid: int = 0  # measured targets a resampled grid does not hold (it keeps only their interpolation)
    warnings: tuple[str, ...] = ()

    @property
    def step_deg(self) -> float:
        return float(self.positions_deg[1] - self.positions_deg[0])

    @property
    def evenly_spaced(self) -> bool:
        """Entries at one pitch from 0° to 360° (what a format with a fixed pitch can hold)."""
        p = np.asarray(self.positions_deg, float)
        return len(p) >= 3 and abs(p[0]) < 1e-6 and abs(p[-1] - 360.0) < 1e-6 and float(np.ptp(np.diff(p))) < 1e-6

    def summary(self) -> str:
        """How many points were measured and how many written, e.g. "12 measured targets, 12 points
        written" or "12 measured targets resampled to 24 points every 15°" (per turn: the entry at
        360° repeats the one at 0°)."""
        per_turn = len(self.positions_deg) - 1
        if self.resampled:
            return (f"{self.measured_targets} measured targets resampled to {per_turn} points every {self.step_deg:g}° "
                    + (f"(--step-deg; {self.off_grid} of the measured targets lie between the grid's points, which keep "
                       "only their interpolation)" if self.off_grid else "(--step-deg; every measured target is a grid point)"))
        extra = per_turn - self.measured_targets
        return (f"{self.measured_targets} measured targets, {per_turn} points written"
                + (" (0° interpolated across the wrap: it was not measured)" if extra else ""))

    def trim_deg(self, commanded_deg: float, direction: int) -> float:
        """What the controller adds to a command approached in ``direction``: linear between entries."""
        values = self.trim_up_deg if direction >= 0 else self.trim_down_deg
        at = np.mod(commanded_deg, 360.0) if self.modulo else commanded_deg
        return float(np.interp(at, self.positions_deg, values))  # np.interp holds the end values outside


@dataclass(frozen=True)
class MeasuredDeviations:
    """Per direction (+1, −1): the distinct targets (deg, in [0, 360), ascending) and the mean
    deviation over the runs at each (arcsec); and per (target, direction) cell the count and the
    pooled within-cell sum of squares (the repeatability the runs show)."""

    targets: dict[int, np.ndarray]
    means: dict[int, np.ndarray]
    counts: dict[int, np.ndarray]
    within_ss: float
    within_dof: int


def measured_deviations(table: PositioningDeviations) -> MeasuredDeviations:
    targets, means, counts = {}, {}, {}
    within_ss, within_dof = 0.0, 0
    for d in (1, -1):
        sel = (table.direction == d) & np.isfinite(table.deviation_arcsec)
        if not sel.any():
            continue
        x = np.asarray(table.deviation_arcsec, float)[sel]
        angles = np.mod(np.round(table.target_deg[sel], 9), 360.0)
        t, group = np.unique(angles, return_inverse=True)  # sorted once: n log n in rows
        n = np.bincount(group)
        m = np.bincount(group, weights=x) / n
        within_ss += float(np.sum((x - m[group]) ** 2))
        within_dof += int(len(x) - len(t))
        targets[d], means[d], counts[d] = t, m, n
    return MeasuredDeviations(targets, means, counts, within_ss, within_dof)


def _gap(targets: np.ndarray) -> tuple[float, float]:
    """The widest gap between neighbouring targets over one turn, and the target it follows."""
    gaps = np.diff(np.concatenate([targets, [targets[0] + 360.0]]))
    k = int(np.argmax(gaps))
    return float(gaps[k]), float(targets[k])


def one_direction_message(fmt: str | None, direction: int) -> str:
    which = "positive" if direction > 0 else "negative"
    what = ONE_DIRECTION.get(fmt or "", "a table with the same values for both directions compensates no reversal")
    return f"one direction measured ({which} only): {what}"


def table_from_deviations(table: PositioningDeviations, step_deg: float | None = None, max_gap_deg: float = 60.0,
                          allow_one_direction: bool = False, fmt: str | None = None) -> CompensationTable:
    """Trims from the measured deviations (mean over runs per target and direction): at the
    measured targets, or on a regular grid every ``step_deg`` when given. A run measured in one
    direction is refused unless ``allow_one_direction`` (then its values are written for both,
    with a warning naming what that does on ``fmt``'s controller)."""
    if step_deg is not None and (not (0.0 < step_deg <= 90.0) or abs(360.0 / step_deg - round(360.0 / step_deg)) > 1e-9):
        raise CompensationError(f"--step-deg {step_deg:g}: the grid must divide one turn (e.g. 5, 10, 15, 30)")
    if not 0.0 < max_gap_deg <= 360.0:  # also false for NaN, which would let every gap through
        raise CompensationError(f"--max-gap-deg {max_gap_deg:g}: must lie in (0, 360]")
    data = measured_deviations(table)
    for d, targets in data.targets.items():
        gap, after = _gap(targets)
        if len(targets) < 3 or gap > max_gap_deg + 1e-9:
            raise CompensationError(
                f"the {'positive' if d > 0 else 'negative'} direction's targets leave a gap of {gap:g}° after "
                f"{after:g}° (at most {max_gap_deg:g}° is interpolated over): measure more targets")
    if not data.targets:
        raise CompensationError("no deviations: every row is missing its deviation")
    warnings = []
    if len(data.targets) == 1:
        (only,) = data.targets
        if not allow_one_direction:
            raise CompensationError(f"{one_direction_message(fmt, only)}; measure both directions, or give "
                                    "--allow-one-direction to write the measured values both ways knowingly")
        warnings.append(f"{one_direction_message(fmt, only)} (written both ways: --allow-one-direction)")
    measured = np.unique(np.concatenate(list(data.targets.values())))
    if step_deg is None:
        points = np.append(np.unique(np.concatenate([measured, [0.0]])), 360.0)
    else:
        points = np.linspace(0.0, 360.0, int(round(360.0 / step_deg)) + 1)
    k = measured / step_deg if step_deg is not None else np.zeros(0)
    off_grid = int(np.count_nonzero(np.abs(k - np.round(k)) * (step_deg or 0.0) > 1e-6))
    check = interpolation_check(data, step_deg)
    if check.warning:
        warnings.append(check.warning)
    errors = {d: np.interp(points, data.targets[d], data.means[d], period=360.0) for d in data.targets}
    first = 1 if 1 in errors else -1
    datum = errors[first][0]
    up = -(errors[first] - datum) / ARCSEC_PER_DEG
    down = -(errors[-1] - datum) / ARCSEC_PER_DEG if -1 in errors and 1 in errors else up.copy()
    return CompensationTable(points, up, down, measured_targets=len(measured), resampled=step_deg is not None,
                             off_grid=off_grid, warnings=tuple(warnings))


# -- are the targets close enough for the error they show? -----------------------------------
QUARTER_PERIOD = 0.25  # the rule: the widest gap below a quarter of the period of every error the data show
MAX_CHECKED_ORDER = 90  # period 4°: finer errors than this are beyond what a gap check of a calibration can see
LACK_OF_FIT_ALPHA = 0.01


@dataclass(frozen=True)
class GapCheck:
    """What the measured deviations say about the gaps between their targets.

    A linear table between targets g apart follows a harmonic of order n (period P = 360°/n,
    amplitude A) up to the chord, which misses it by up to A·(1 − cos(π·g/P)) in the middle of the
    gap: 7.6 % of A at g = P/8, 29 % at g = P/4, all of it at g = P/2 (where targets can sit on the
    zeros and the table sees nothing). The rule: the widest gap below a quarter of the period of
    every error the data show, i.e. n·g < 90°. "Show" means a harmonic the fit finds significant
    (orders up to what the targets resolve, rtcal.solvers.harmonics), or, with repeated runs, a
    lack of fit of those orders against the runs' own scatter — structure of a higher order than
    the targets resolve, whose period is then under 360°/(K + 1). A warning is given when the
    rule fails and what the table may miss exceeds twice the standard deviation of a target's
    mean (what a verification between the targets could see)."""

    gap_deg: float
    after_deg: float
    orders: tuple[int, ...] = ()
    significant: tuple[tuple[int, float], ...] = ()  # (order, amplitude ″)
    lack_of_fit_p: float | None = None
    unresolved_rms_arcsec: float = 0.0
    noise_arcsec: float = 0.0  # 1σ of a target's mean
    failing_order: int | None = None
    missed_arcsec: float = 0.0  # what the table may miss between the targets
    warning: str | None = None


FIT_BINS = 1024  # beyond this many targets a direction's means are fitted in bins of 360°/1024


def _binned(targets: np.ndarray, means: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """At most FIT_BINS (angle, mean, count) per direction: thousands of targets averaged in bins
    of 0.35°, which keep every order up to MAX_CHECKED_ORDER (a 4° period) to within 1.3 % and
    bound the fit's size (the count-weighted means; the runs' scatter stays the cells')."""
    if len(targets) <= FIT_BINS:
        return targets, means, counts
    _, index = np.unique(np.floor(targets / (360.0 / FIT_BINS)).astype(int), return_inverse=True)
    n = np.bincount(index, weights=counts)
    return (np.bincount(index, weights=counts * targets) / n, np.bincount(index, weights=counts * means) / n,
            n)


def interpolation_check(data: MeasuredDeviations, step_deg: float | None = None) -> GapCheck:
    """Check the widest gap the table interpolates over (between measured targets, or the grid's
    step if coarser) against the harmonics of the measured deviations (GapCheck: the rule)."""
    from scipy.stats import f as f_dist

    from rtcal.solvers.harmonics import fit_harmonics, resolvable_orders, smooth_values

    gap, after = max(_gap(t) for t in data.targets.values())
    if step_deg is not None and step_deg > gap:
        gap, after = float(step_deg), 0.0
    first_failing = int(np.ceil(QUARTER_PERIOD * 360.0 / gap - 1e-9))  # the lowest order n with n·g ≥ 90°
    if first_failing > MAX_CHECKED_ORDER + 1:
        return GapCheck(gap, after)
    dirs = sorted(data.targets)
    cells = [_binned(data.targets[d], data.means[d], data.counts[d]) for d in dirs]
    angles = np.radians(np.concatenate([c[0] for c in cells]))
    means = np.concatenate([c[1] for c in cells])
    counts = np.concatenate([c[2] for c in cells])
    groups = np.concatenate([np.full(len(c[0]), d) for c, d in zip(cells, dirs)])
    orders = resolvable_orders(angles, MAX_CHECKED_ORDER, n_offsets=len(dirs))
    if not orders:
        return GapCheck(gap, after)
    fit = fit_harmonics(angles, means, orders, groups)
    significant = tuple((t.order, t.amplitude) for t in fit.terms if t.significant)
    n_mean = float(np.mean(counts))  # approaches per fitted mean
    within = data.within_ss / data.within_dof if data.within_dof > 0 else None
    per_target = float(np.mean(np.concatenate(list(data.counts.values()))))
    noise = float(np.sqrt(within / per_target)) if within is not None else fit.sigma
    p_value, unresolved = None, 0.0
    lof_dof = len(means) - (2 * len(orders) + len(dirs))
    if within is not None and lof_dof > 0:
        lof_ms = float(np.sum(counts * (means - smooth_values(angles, means, orders, groups)) ** 2)) / lof_dof
        floor = (1e-9 * float(np.max(np.abs(means)))) ** 2
        p_value = float(f_dist.sf(lof_ms / max(within, floor), lof_dof, data.within_dof))
        unresolved = float(np.sqrt(max(lof_ms - within, 0.0) * lof_dof / n_mean / len(means)))  # RMS over the cells
    check = dict(gap_deg=gap, after_deg=after, orders=tuple(orders), significant=significant, lack_of_fit_p=p_value,
                 unresolved_rms_arcsec=unresolved, noise_arcsec=noise)
    failing = [(n, a) for n, a in significant if n >= first_failing]
    beyond = p_value is not None and p_value < LACK_OF_FIT_ALPHA and orders[-1] + 1 >= first_failing
    missed = float(sum(a * (1.0 - np.cos(min(np.pi * gap * n / 360.0, np.pi))) for n, a in failing))
    missed += float(np.sqrt(2.0) * unresolved) if beyond else 0.0  # a sine of that RMS, missed whole
    if not (failing or beyond) or missed <= 2.0 * noise:
        return GapCheck(**check)
    shown = []
    if failing:
        low, high = failing[0][0], failing[-1][0]
        which = f"order {high}" if low == high else f"orders {low}–{high}"
        shown.append(f"{which} (up to {max(a for _, a in failing):.2f}″; period {360 / high:.3g}°)")
    if beyond:
        k = orders[-1]
        targets = len(np.unique(np.concatenate(list(data.targets.values()))))
        shown.append(f"an error of order above {k}, which {targets} targets cannot resolve ({unresolved:.2f}″ "
                     f"RMS beyond orders 1–{k}: lack of fit, p = {p_value:.1g})")
    order = orders[-1] + 1 if beyond else failing[-1][0]
    quarter = f"{QUARTER_PERIOD * 360.0 / order:.3g}°{' (or closer still: the order may be higher)' if beyond else ''}"
    if step_deg is not None and gap == step_deg:
        span, advice = f"the {gap:g}° grid step", f"Give a --step-deg below {quarter}, or none (the measured targets)"
    else:
        span, advice = f"gaps up to {gap:g}° (after {after:g}°)", f"Measure targets closer than {quarter}"
    return GapCheck(**check, failing_order=order, missed_arcsec=missed, warning=(
        f"the table interpolates over {span}, too wide for the error the data show: {' and '.join(shown)}. "
        f"Linear interpolation over a gap of a quarter period or more misses up to A·(1 − cos(180°·gap/period)) of a "
        f"harmonic of amplitude A: here up to {missed:.1f}″ between the targets. {advice}, and verify between them"))


def _check_points(fmt: str, table: CompensationTable) -> None:
    if fmt in FIXED_PITCH and not table.evenly_spaced:
        step = next((s for s in GRID_STEPS_DEG if 360.0 / s + 1 <= MAX_POINTS[fmt]
                     and np.allclose(table.positions_deg / s, np.round(table.positions_deg / s), atol=1e-6)), None)
        hint = f"--step-deg {step:g} keeps every measured target" if step else "e.g. --step-deg 5"
        raise CompensationError(
            f"{fmt}: the {table.measured_targets or len(table.positions_deg) - 1} measured targets are not evenly spaced "
            f"from 0°, and the format holds points at one pitch ({FIXED_PITCH[fmt]}): give --step-deg to resample "
            f"them onto a grid ({hint}; the table then says so), or use a format that takes the measured targets (linuxcnc)")
    if len(table.positions_deg) > MAX_POINTS[fmt]:
        raise CompensationError(f"{fmt}: {len(table.positions_deg)} points; the format takes at most {MAX_POINTS[fmt]} "
                                "(choose a larger --step-deg)")


ASCII = {"″": " arcsec", "°": " deg", "—": "-", "–": "-", "−": "-", "…": "...", "·": "*", "×": "x", "≥": ">=",
         "≤": "<=", "π": "pi", "↑": "up", "↓": "down", "(": "[", ")": "]"}


def _comments(fmt: str, table: CompensationTable) -> list[str]:
    """The table's warnings as comment lines of ``fmt`` (plain ASCII: a controller's character set)."""
    lines = []
    for text in table.warnings:
        plain = "".join(ASCII.get(c, c) for c in f"rtcal warning: {text}").encode("ascii", "replace").decode()
        lines.append(f"; {plain}" if COMMENT[fmt] == "; " else f"({plain})")
    return lines


# -- LinuxCNC ------------------------------------------------------------------------------
def write_linuxcnc(table: CompensationTable, range_deg: tuple[float, float] = (0.0, 360.0)) -> str:
    """COMP_FILE_TYPE = 0: ``nominal forward_actual reverse_actual`` per line, degrees, ascending;
    no header or comment (LinuxCNC stops reading at the first line that is not three numbers).
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
    if len(turn) * len(turns) > 100 * MAX_POINTS["linuxcnc"]:
        raise CompensationError(f"linuxcnc: {len(turn)} points a turn over {lo:g} … {hi:g}°; LinuxCNC reads at most "
                                f"{MAX_POINTS['linuxcnc']} lines (a larger --step-deg or a narrower --range-deg)")
    nominal = (turn[None, :] + 360.0 * turns[:, None]).ravel()
    nominal = np.unique(np.round(np.concatenate([nominal[(nominal >= lo) & (nominal <= hi)], [lo, hi]]), 6))
    if len(nominal) > MAX_POINTS["linuxcnc"]:
        raise CompensationError(f"linuxcnc: {len(nominal)} lines over {lo:g} … {hi:g}°; LinuxCNC reads at most "
                                f"{MAX_POINTS['linuxcnc']} (fewer targets, a larger --step-deg or a narrower --range-deg)")
    up = np.array([table.trim_deg(a, +1) for a in nominal])
    down = np.array([table.trim_deg(a, -1) for a in nominal])
    return "".join(f"{p:.6f} {p - u:.8f} {p - d:.8f}\n" for p, u, d in zip(nominal, up, down))


def parse_linuxcnc(text: str, where: str = "<linuxcnc>") -> CompensationTable:
    """As LinuxCNC reads it (usrmotintf.cc): three numbers a line, trims = nominal − actual; but
    what LinuxCNC would silently drop (everything after a line that is not three numbers, a
    blank one included) is an error here, with its line."""
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()  # trailing blank lines end the table where it ends anyway
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
    if len(rows) < 2 or len(rows) > MAX_POINTS["linuxcnc"]:
        raise CompensationError(f"{where}: {len(rows)} lines (2 … {MAX_POINTS['linuxcnc']})")
    a = np.array(rows)
    bad = np.nonzero(np.diff(a[:, 0]) <= 0)[0]
    if len(bad):
        raise CompensationError(f"{where}:{bad[0] + 2}: nominal positions must increase strictly (LinuxCNC refuses the line)")
    up, down = a[:, 0] - a[:, 1], a[:, 0] - a[:, 2]
    _sane(up, down, where)
    return CompensationTable(a[:, 0], up, down, modulo=False)


# -- Siemens ---------------------------------------------------------------------------
def write_siemens_lec(table: CompensationTable, axis: str = "C1") -> str:
    """LEC, one table (the mean of both directions): a positive value moves the axis negative, so
    the value is the deviation, −trim, in degrees; modulo: the value at MAX repeats MIN's."""
    _check_points("siemens-lec", table)
    mean = (table.trim_up_deg + table.trim_down_deg) / 2
    lines = ["%_N_AX_EEC_INI", *_comments("siemens-lec", table), "CHANDATA(1)"]
    lines += [f"$AA_ENC_COMP[0,{i},{axis}]={-v + 0.0:.8f}" for i, v in enumerate(mean)]
    lines += [f"$AA_ENC_COMP_STEP[0,{axis}]={table.step_deg:.6f}", f"$AA_ENC_COMP_MIN[0,{axis}]=0.0",
              f"$AA_ENC_COMP_MAX[0,{axis}]=360.0", f"$AA_ENC_COMP_IS_MODULO[0,{axis}]=1", "M17"]
    return "\n".join(lines) + "\n"


def write_siemens_cec(table: CompensationTable, axis: str = "C1") -> str:
    """CEC, one table per direction (table 0 positive, table 1 negative approach): the value is
    added to the axis's setpoint, so it is the trim, in degrees."""
    _check_points("siemens-cec", table)
    lines = ["%_N_NC_CEC_INI", *_comments("siemens-cec", table), "CHANDATA(1)"]
    for t, (values, sense) in enumerate(((table.trim_up_deg, 1), (table.trim_down_deg, -1))):
        lines += [f"$AN_CEC[{t},{i}]={v + 0.0:.8f}" for i, v in enumerate(values)]  # + 0.0: no "-0.0"
        lines += [f"$AN_CEC_INPUT_AXIS[{t}]={axis}", f"$AN_CEC_OUTPUT_AXIS[{t}]={axis}", f"$AN_CEC_STEP[{t}]={table.step_deg:.6f}",
                  f"$AN_CEC_MIN[{t}]=0.0", f"$AN_CEC_MAX[{t}]=360.0", f"$AN_CEC_DIRECTION[{t}]={sense}",
                  f"$AN_CEC_IS_MODULO[{t}]=1"]
    lines.append("M17")
    return "\n".join(lines) + "\n"


SIEMENS_HEADER = {"AA_ENC_COMP": "%_N_AX_EEC_INI", "AN_CEC": "%_N_NC_CEC_INI"}
SIEMENS_LINE = re.compile(r"\$(AA_ENC_COMP|AN_CEC)(_[A-Z_]+)?\[([^\]]*)\]=(\S+)")


def _siemens_values(text: str, where: str, name: str) -> tuple[dict[int, dict[int, float]], dict[int, dict[str, str]], dict]:
    """Points and settings per table of a ``%_N_…_INI`` file: the header, CHANDATA, ``;`` comments,
    ``$<name>…`` assignments and M17 at the end; anything else is an error on its line."""
    lines = text.splitlines()
    if not lines or lines[0].strip() != SIEMENS_HEADER[name]:
        raise CompensationError(f"{where}:1: the first line must be {SIEMENS_HEADER[name]}")
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
        m = SIEMENS_LINE.fullmatch(line)
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


def _siemens_table(values: dict[int, float], settings: dict[str, str], where: str) -> tuple[np.ndarray, np.ndarray]:
    try:
        step, lo, hi = float(settings["_STEP"]), float(settings["_MIN"]), float(settings["_MAX"])
    except (KeyError, ValueError):
        raise CompensationError(f"{where}: STEP, MIN and MAX must be given as numbers") from None
    if settings.get("_IS_MODULO", "0").strip() not in ("1", "1.0"):
        raise CompensationError(f"{where}: a rotary axis's table over one turn is a modulo table (IS_MODULO = 1)")
    if sorted(values) != list(range(len(values))):
        raise CompensationError(f"{where}: the points must be numbered 0, 1, 2, … without gaps")
    positions = lo + step * np.arange(len(values))
    if abs(positions[-1] - hi) > 1e-6:
        raise CompensationError(f"{where}: {len(values)} points of {step:g}° from {lo:g} do not end at MAX {hi:g}")
    return positions, np.array([values[i] for i in range(len(values))])


def parse_siemens_lec(text: str, where: str = "<siemens-lec>") -> CompensationTable:
    points, settings, _ = _siemens_values(text, where, "AA_ENC_COMP")
    if list(points) != [0]:
        raise CompensationError(f"{where}: expected one table, encoder 0 ($AA_ENC_COMP[0,…])")
    positions, values = _siemens_table(points[0], settings.get(0, {}), where)
    return _regular(positions, -values, -values, where, MAX_POINTS["siemens-lec"])


def parse_siemens_cec(text: str, where: str = "<siemens-cec>") -> CompensationTable:
    points, settings, _ = _siemens_values(text, where, "AN_CEC")
    tables = {}
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
        tables[direction] = _siemens_table(values, s, f"{where}: table {t}")
    if 0 in tables:
        positions, both = tables[0]
        return _regular(positions, both, both, where, MAX_POINTS["siemens-cec"])
    if 1 not in tables or -1 not in tables:
        raise CompensationError(f"{where}: a table for each direction ($AN_CEC_DIRECTION = 1 and -1) is needed")
    (positions, up), (positions_down, down) = tables[1], tables[-1]
    if len(positions) != len(positions_down) or not np.allclose(positions, positions_down):
        raise CompensationError(f"{where}: both directions' tables need the same MIN, MAX and STEP")
    return _regular(positions, up, down, where, MAX_POINTS["siemens-cec"])


# -- FANUC -----------------------------------------------------------------------------
FANUC_MAX_INCREMENT = 127  # a point's value, in detection units × magnification (−128 … 127)
FANUC_MAX_POINT = 1023  # highest compensation point number (0i series)


def write_fanuc(table: CompensationTable, unit_deg: float = 0.0001, first_point: int = 0) -> str:
    """Pitch error compensation, bidirectional (parameter 3605#0 = 1), as a parameter listing.

    Values are incremental, in detection units (``unit_deg``) × magnification (3623, the smallest
    that keeps every value within ±127): point k holds the change of the trim over the interval
    ending at it; over one turn they sum to zero, and the reference point (0°) holds the same
    value as the last (360°, the same position). The positive-travel table is 3621 = 3620 …
    3622; the negative-travel table follows it, 3626 being its farthest point on the − side (its
    first, at 0°), and 3627 its absolute value at the reference position."""
    _check_points("fanuc", table)
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
             *_comments("fanuc", table), "3605 #0 = 1  (bidirectional pitch error compensation)",
             f"3620 = {first_point}  (compensation point of the reference position)",
             f"3621 = {up_points[0]}  (farthest point on the - side, positive travel)",
             f"3622 = {up_points[-1]}  (farthest point on the + side, positive travel)",
             f"3623 = {magnification}  (magnification)", f"3624 = {round(table.step_deg / unit_deg)}  (interval, detection units)",
             f"3625 = {round(360.0 / unit_deg)}  (travel per revolution, detection units)",
             f"3626 = {down_points[0]}  (farthest point on the - side, negative travel)",
             f"3627 = {int(cum_down[0] - cum_up[0])}  (absolute value at the reference position, negative travel)"]
    lines += [f"{p} = {v:+d}" for p, v in zip(up_points, values(inc_up))]
    lines += [f"{p} = {v:+d}" for p, v in zip(down_points, values(inc_down))]
    return "\n".join(lines) + "\n"


FANUC_LINE = re.compile(r"(\d+)( #0)? = ([+-]?\d+)(?:\s+\(.*\))?")


def parse_fanuc(text: str, where: str = "<fanuc>") -> CompensationTable:
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


HEIDENHAIN_HEADER = re.compile(r"BEGIN AXIS-([A-Z])\.COM DATUM:([+-]?\d+(?:\.\d*)?) DISTANCE:([+-]?\d+(?:\.\d*)?)")


def parse_heidenhain(text: str, where: str = "<heidenhain>") -> CompensationTable:
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
    rows = []
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
        _empty(where)
    a = np.array(rows, float)
    return _regular(a[:, 1], a[:, 2], a[:, 2], where, MAX_POINTS["heidenhain"])


# -- common ----------------------------------------------------------------------------
def _empty(where: str) -> CompensationTable:
    raise CompensationError(f"{where}: no entries")


def _sane(up: np.ndarray, down: np.ndarray, where: str) -> None:
    for name, values in (("positive", up), ("negative", down)):
        if not np.all(np.isfinite(values)) or np.max(np.abs(values)) > 1.0:
            raise CompensationError(f"{where}: {name}-direction values must be finite and below 1 degree")


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
    _sane(up, down, where)
    for name, values in (("positive", up), ("negative", down)):
        if abs(values[0] - values[-1]) > 1e-9:
            raise CompensationError(f"{where}: the {name}-direction value at 360° must equal the one at 0° (one turn closes)")
    return CompensationTable(positions, np.asarray(up, float), np.asarray(down, float))


OPTIONS = {"linuxcnc": ("range_deg",), "siemens-lec": ("axis",), "siemens-cec": ("axis",), "fanuc": ("unit_deg", "first_point"),
           "heidenhain": ("axis",)}  # what each writer takes besides the table (the CLI's format options)
FLAGS = {"range_deg": "--range-deg", "axis": "--axis", "unit_deg": "--detection-unit-deg", "first_point": "--first-point"}
AXIS_NAMES = {"siemens-lec": r"[A-Z][A-Z0-9_]{0,15}", "siemens-cec": r"[A-Z][A-Z0-9_]{0,15}", "heidenhain": r"[A-Z]"}


# the largest trim each format is written with, arcsec. None of the five formats' public references
# states a limit of the value itself (FANUC's increment per point is checked where it is written):
# rtcal's bound is the deviation a rotary table has at most (deviations.PLAUSIBLE_DEVIATION_ARCSEC);
# a trim beyond it would move the axis by what no calibration measured
MAX_TRIM_ARCSEC = {"linuxcnc": 3600.0, "siemens-lec": 3600.0, "siemens-cec": 3600.0, "fanuc": 3600.0, "heidenhain": 3600.0}


def check_trims(fmt: str, table: CompensationTable) -> None:
    """Every trim within what ``fmt`` is written with (MAX_TRIM_ARCSEC); CompensationError naming the worst."""
    for name in ("trim_up_deg", "trim_down_deg"):
        trims = np.asarray(getattr(table, name), float) * 3600.0
        if len(trims) and not (np.all(np.isfinite(trims)) and np.max(np.abs(trims)) <= MAX_TRIM_ARCSEC[fmt]):
            i = int(np.nanargmax(np.where(np.isfinite(trims), np.abs(trims), np.inf)))
            raise CompensationError(f"{fmt}: a trim of {trims[i]:.6g}″ at {float(table.positions_deg[i]):g}° "
                                    f"({name.removeprefix('trim_').removesuffix('_deg')}) lies beyond ±{MAX_TRIM_ARCSEC[fmt]:g}″: "
                                    "no table is written that would move the axis by more than any calibration measures")


def write_table(fmt: str, table: CompensationTable, **options) -> str:
    """The ``fmt`` file's text; an option the format does not take (or a bad axis name) is an error."""
    if fmt not in WRITERS:
        raise CompensationError(f"unknown format {fmt!r}; one of {', '.join(FORMATS)}")
    check_trims(fmt, table)
    extra = sorted(set(options) - set(OPTIONS[fmt]))
    if extra:
        raise CompensationError(f"{fmt} takes no {', '.join(FLAGS[o] for o in extra)} "
                                f"(its options: {', '.join(FLAGS[o] for o in OPTIONS[fmt])})")
    if "axis" in options and not re.fullmatch(AXIS_NAMES[fmt], options["axis"]):
        raise CompensationError(f"--axis {options['axis']!r} is not a {fmt} axis name (e.g. {'C' if fmt == 'heidenhain' else 'C1'})")
    return WRITERS[fmt](table, **options)


WRITERS = {"linuxcnc": write_linuxcnc, "siemens-lec": write_siemens_lec, "siemens-cec": write_siemens_cec,
           "fanuc": write_fanuc, "heidenhain": write_heidenhain}
PARSERS = {"linuxcnc": parse_linuxcnc, "siemens-lec": parse_siemens_lec, "siemens-cec": parse_siemens_cec,
           "fanuc": parse_fanuc, "heidenhain": parse_heidenhain}
