"""Compensation tables for a rotary axis from a run's positioning deviations.

From a positioning-deviation table: per direction the mean deviation e = actual − commanded over
the runs at each target, written at the measured targets themselves (or, when asked, resampled
onto a regular grid over one turn by periodic linear interpolation — a controller interpolates
linearly between its entries too), and referred to the axis datum (e = 0 at 0° in the positive
direction: the reference point stays where it is). Formats with a fixed pitch (SINUMERIK, FANUC,
HEIDENHAIN) take only evenly spaced points from 0°; irregular targets need a grid asked for. A
run measured in one direction is refused unless the caller allows writing its values both ways
(what that does to the machine's reversal compensation depends on the format: its
``one_direction``). Whether the targets lie close enough together for the error the data show is
checked against its harmonics (:func:`interpolation_check`). The controller then commands
θ + trim(θ) with trim = −e, so that the table reaches θ.

How each format writes and reads the trims is its class in rtcal/compensation/ (one module per
format, one registry, plugins through the entry-point group ``rtcal.compensation_formats``);
docs/compensation.md has the built-ins' rules and sign. The names below that older code imports
(``write_table``, ``PARSERS``, ``WRITERS``, ``COMMENT``, ``MAX_TRIM_ARCSEC``, ``parse_linuxcnc``)
are views of that registry, not tables of their own.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rtcal.compensation import registry
from rtcal.compensation.base import CompensationFormat
from rtcal.compensation.registry import check_trims, format_names, get_format, write_table
from rtcal.compensation.table import ARCSEC_PER_DEG, CompensationError, CompensationTable
from rtcal.deliverables.deviations import PositioningDeviations

__all__ = ["COMMENT", "FORMATS", "MAX_TRIM_ARCSEC", "PARSERS", "WRITERS", "CompensationError", "CompensationTable",
           "GapCheck", "MeasuredDeviations", "check_trims", "format_names", "get_format", "interpolation_check",
           "measured_deviations", "one_direction_message", "parse_linuxcnc", "table_from_deviations", "write_table"]

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
    known = registry.formats().get(fmt or "")
    what = known.one_direction if known is not None else CompensationFormat.one_direction
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

    from rtcal.solvers.harmonics import fit_harmonics, grid_nyquist, resolvable_orders, smooth_values

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
    # an order the targets cannot tell from an unmodelled one is leakage, not an error the data show
    fit = fit_harmonics(angles, means, orders, groups, alternatives_up_to=grid_nyquist(angles, MAX_CHECKED_ORDER))
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
    leaked = [t for t in fit.terms if t.not_separable_from]  # an unresolved order's share that fell into fitted ones
    unresolved = float(np.hypot(unresolved, np.sqrt(sum(t.amplitude**2 / 2.0 for t in leaked))))
    check = GapCheck(gap_deg=gap, after_deg=after, orders=tuple(orders), significant=significant, lack_of_fit_p=p_value,
                     unresolved_rms_arcsec=unresolved, noise_arcsec=noise)
    failing = [(n, a) for n, a in significant if n >= first_failing]
    lack_of_fit = p_value is not None and p_value < LACK_OF_FIT_ALPHA
    beyond = (lack_of_fit or bool(leaked)) and orders[-1] + 1 >= first_failing
    missed = float(sum(a * (1.0 - np.cos(min(np.pi * gap * n / 360.0, np.pi))) for n, a in failing))
    missed += float(np.sqrt(2.0) * unresolved) if beyond else 0.0  # a sine of that RMS, missed whole
    if not (failing or beyond) or missed <= 2.0 * noise:
        return check
    shown = []
    if failing:
        low, high = failing[0][0], failing[-1][0]
        which = f"order {high}" if low == high else f"orders {low}–{high}"
        top, amp = max(failing, key=lambda f: f[1])
        periods = f"period {360 / high:.3g}°" if low == high else f"periods {360 / low:.3g}°–{360 / high:.3g}°"
        shown.append(f"{which} (up to {amp:.2f}″ at order {top}; {periods})" if low != high else f"{which} ({amp:.2f}″; {periods})")
    if beyond:
        k = orders[-1]
        targets = len(np.unique(np.concatenate(list(data.targets.values()))))
        evidence = ([f"lack of fit, p = {p_value:.1g}"] if lack_of_fit else []) + (
            [f"leakage into order{'s' if len(leaked) > 1 else ''} {', '.join(str(t.order) for t in leaked)}, which the "
             "targets cannot tell from higher orders"] if leaked else [])
        shown.append(f"an error of order above {k}, which {targets} targets cannot resolve ({unresolved:.2f}″ "
                     f"RMS beyond orders 1–{k}: {'; '.join(evidence)})")
    order = orders[-1] + 1 if beyond else failing[-1][0]
    quarter = f"{QUARTER_PERIOD * 360.0 / order:.3g}°{' (or closer still: the order may be higher)' if beyond else ''}"
    if step_deg is not None and gap == step_deg:
        span, advice = f"the {gap:g}° grid step", f"Give a --step-deg below {quarter}, or none (the measured targets)"
    else:
        span, advice = f"gaps up to {gap:g}° (after {after:g}°)", f"Measure targets closer than {quarter}"
    return replace(check, failing_order=order, missed_arcsec=missed, warning=(
        f"the table interpolates over {span}, too wide for the error the data show: {' and '.join(shown)}. "
        f"Linear interpolation over a gap of a quarter period or more misses up to A·(1 − cos(180°·gap/period)) of a "
        f"harmonic of amplitude A: here up to {missed:.1f}″ between the targets. {advice}, and verify between them"))


# -- the names older code imports: read-only views of the registry --------------------
class _ByFormat(Mapping[str, Any]):
    """One attribute of every registered format, by name (formats for which ``get`` gives None left out)."""

    def __init__(self, get: Callable[[CompensationFormat], Any]) -> None:
        self._get = get

    def _items(self) -> dict[str, Any]:
        return {name: v for name, fmt in registry.formats().items() if (v := self._get(fmt)) is not None}

    def __getitem__(self, name: str) -> Any:
        return self._items()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._items())

    def __len__(self) -> int:
        return len(self._items())


FORMATS = tuple(registry.BUILTIN)  # the built-ins; format_names() adds the installed plugins'
WRITERS: Mapping[str, Callable[..., str]] = _ByFormat(lambda f: f.write)
PARSERS: Mapping[str, Callable[..., CompensationTable]] = _ByFormat(lambda f: f.parse)
COMMENT: Mapping[str, str] = _ByFormat(lambda f: f.comment[0] if f.comment else None)  # formats whose files take comments
MAX_TRIM_ARCSEC: Mapping[str, float] = _ByFormat(lambda f: f.max_trim_arcsec)
parse_linuxcnc = registry.get_format("linuxcnc").parse
