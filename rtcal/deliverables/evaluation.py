"""Positioning-test evaluation: ISO 230-2 and VDI/DGQ 3441, pure functions of a deviation table.

Formulas, sources and what could not be confirmed against the standards' own text:
docs/evaluation.md. For target P_i and approach j: x_ij = actual − target; per direction
x̄_i = (1/n_i)·Σ_j x_ij over that target's own n_i approaches (the first of a published
evaluator's four errors divided by the number of targets), s_i = √(Σ_j (x_ij − x̄_i)²/(n_i − 1)).

- ISO 230-2 (1997, 2006, 2014): B_i = x̄_i↑ − x̄_i↓ (↑ minus ↓: swapping them flips B's sign, the
  second error), B = max|B_i|, B̄ = mean B_i; R_i↑ = 4s_i↑, R_i = max(2s_i↑ + 2s_i↓ + |B_i|, R_i↑,
  R_i↓) and R = max R_i (not from R↑ and R↓ alone: the fourth error); E↑ = max x̄↑ − min x̄↑, E over both directions
  (the minimum over both: the third error took it with the wrong comparison), M = range of
  x̄_i = (x̄↑ + x̄↓)/2, A↑ = max(x̄↑ + 2s↑) − min(x̄↑ − 2s↑), A over both directions.
- ISO 230-2:1988: ±3s in A and 6s in R (R_i↑ = 6s_i↑, R_i = max(3s↑ + 3s↓ + |B_i|, …)).
- VDI/DGQ 3441: U_j = |x̄↑ − x̄↓|, Ps_j = 6·(s↑ + s↓)/2, Pa = max x̄ − min x̄, P = max(x̄ + (U + Ps)/2)
  − min(x̄ − (U + Ps)/2); U_max, U_mean, Ps_max, Ps_mean.

What is undefined is None, never a number made from part of the data, and a note says why:
- one direction only: the bidirectional parameters (E, M, B, B_mean, R, A; U, P);
- a target with one approach in a direction: its s, and so R and A of that direction (and the
  bidirectional R, A; Ps, P) — s needs two approaches and a bound over the axis needs every target;
- a target approached in one direction only, when the other targets have both: it is left out
  of the bidirectional parameters (named in a note); E still uses every mean.
Values are rounded to 0.0001″ (far below any instrument's resolution) for the results file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # only a type here: `rtcal evaluate --help` lists STANDARDS without loading the results model
    from rtcal.deliverables.deviations import PositioningDeviations

STANDARDS = ("iso230-2", "iso230-2:1988", "vdi3441")
ALIASES = {"iso230-2:2014": "iso230-2", "iso230-2:2006": "iso230-2", "iso230-2:1997": "iso230-2"}
UNCONFIRMED = {
    "iso230-2:1988": "ISO 230-2:1988: ±3s in A and R = 6s are confirmed by secondary sources (docs/evaluation.md); "
                     "R_i, E, M and B with k = 3 follow the later editions' definitions, not confirmed against the "
                     "1988 text",
    "vdi3441": "VDI/DGQ 3441's definitions follow vendor software outputs; not confirmed against the guideline's text",
}
DIGITS = 4


@dataclass(frozen=True)
class TargetStatistics:
    """One target's approaches per direction: their number, mean and s (None below two)."""

    target_deg: float
    mean_up: float | None
    mean_down: float | None
    s_up: float | None
    s_down: float | None
    n_up: int
    n_down: int

    def side(self, direction: int) -> tuple[float | None, float | None, int]:
        return (self.mean_up, self.s_up, self.n_up) if direction > 0 else (self.mean_down, self.s_down, self.n_down)


def _side(group: np.ndarray, x: np.ndarray, targets: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per target: the number of approaches, their mean and s (NaN where undefined), two-pass."""
    n = np.bincount(group, minlength=targets)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(group, weights=x, minlength=targets) / n
        squares = np.bincount(group, weights=(x - mean[group]) ** 2, minlength=targets)
        s = np.where(n > 1, np.sqrt(squares / (n - 1)), np.nan)
    return n, mean, s


def target_statistics(table: PositioningDeviations) -> list[TargetStatistics]:
    """Per target (ascending): number, mean and s of the approaches from each side; rows
    without a deviation (missing readings) are left out. One sort: n log n in rows."""
    x = np.asarray(table.deviation_arcsec, float)
    ok = np.isfinite(x)
    targets, group = np.unique(np.round(np.asarray(table.target_deg, float)[ok], 9), return_inverse=True)
    up = np.asarray(table.direction, int)[ok] > 0
    sides = [_side(group[sel], x[ok][sel], len(targets)) for sel in (up, ~up)]

    def value(a: np.ndarray, k: int) -> float | None:
        return float(a[k]) if np.isfinite(a[k]) else None

    (n_up, mean_up, s_up), (n_down, mean_down, s_down) = sides
    return [TargetStatistics(float(t), mean_up=value(mean_up, k), mean_down=value(mean_down, k), s_up=value(s_up, k),
                             s_down=value(s_down, k), n_up=int(n_up[k]), n_down=int(n_down[k]))
            for k, t in enumerate(targets)]


def _span(values: list[float | None]) -> float | None:
    vals = [v for v in values if v is not None]
    return max(vals) - min(vals) if vals else None


def _deg_list(targets: list[float]) -> str:
    return ", ".join(f"{t:g}°" for t in targets)


def _round(v: Any) -> Any:
    return round(float(v), DIGITS) if isinstance(v, float) else v


def evaluate(table: PositioningDeviations, standard: str = "iso230-2") -> dict[str, Any]:
    """The standard's parameters (arcsec), keyed by its symbols, with per-target values and notes."""
    name = ALIASES.get(standard.lower(), standard.lower())
    if name not in STANDARDS:
        raise ValueError(f"unknown standard {standard!r}; one of {', '.join(STANDARDS)}")
    stats = target_statistics(table)
    if not stats:
        raise ValueError("no deviations to evaluate (every row is missing its deviation)")
    notes: list[str] = []
    missing = int(np.count_nonzero(~np.isfinite(np.asarray(table.deviation_arcsec, float))))
    if missing:
        notes.append(f"{missing} row(s) without a deviation (missing readings) are left out")
    has_up, has_down = any(s.n_up for s in stats), any(s.n_down for s in stats)
    if not (has_up and has_down):
        notes.append("one direction only: the bidirectional parameters are not defined")
    base = {"standard": name, "unit": "arcsec", "targets": len(stats),
            "runs_per_direction": {key: {"min": min(s.side(d)[2] for s in stats), "max": max(s.side(d)[2] for s in stats)}
                                   for d, key in ((1, "up"), (-1, "down"))},
            "runs": sorted({int(r) for r in table.run})}
    body = _vdi3441(stats, has_up and has_down, notes) if name == "vdi3441" else \
        _iso230_2(stats, has_up and has_down, 3.0 if name.endswith("1988") else 2.0, notes)
    if name in UNCONFIRMED:
        notes.append(UNCONFIRMED[name])
    return {**base, **body, "notes": notes}


def _one_approach_note(stats: list[TargetStatistics], direction: int, what: str) -> str | None:
    lone = [s.target_deg for s in stats if s.side(direction)[2] == 1]
    if not lone:
        return None
    sym = "↑" if direction > 0 else "↓"
    return f"one approach ({sym}) at {_deg_list(lone)}: s needs two, so {what} undefined"


@dataclass(frozen=True)
class _IsoTarget:
    """One target's ISO 230-2 values (arcsec); None where undefined (the field order is the
    results file's)."""

    target_deg: float
    mean_up: float | None
    mean_down: float | None
    mean: float | None
    B_i: float | None
    s_up: float | None
    s_down: float | None
    R_up_i: float | None
    R_down_i: float | None
    R_i: float | None
    n_up: int
    n_down: int

    @classmethod
    def of(cls, s: TargetStatistics, k: float) -> _IsoTarget:
        R_up = 2 * k * s.s_up if s.s_up is not None else None
        R_down = 2 * k * s.s_down if s.s_down is not None else None
        mean = B_i = R_i = None
        if s.mean_up is not None and s.mean_down is not None:  # approached from both sides
            B_i = s.mean_up - s.mean_down
            mean = (s.mean_up + s.mean_down) / 2
            if s.s_up is not None and s.s_down is not None and R_up is not None and R_down is not None:
                R_i = max(k * s.s_up + k * s.s_down + abs(B_i), R_up, R_down)
        return cls(s.target_deg, s.mean_up, s.mean_down, mean, B_i, s.s_up, s.s_down, R_up, R_down, R_i,
                   s.n_up, s.n_down)

    def side(self, direction: int) -> tuple[float | None, float | None, float | None, int]:
        """Mean, s, R_i and number of approaches of one direction."""
        return ((self.mean_up, self.s_up, self.R_up_i, self.n_up) if direction > 0
                else (self.mean_down, self.s_down, self.R_down_i, self.n_down))


@dataclass(frozen=True)
class _VdiTarget:
    """One target's VDI/DGQ 3441 values (arcsec); None where undefined."""

    target_deg: float
    mean: float | None
    U_j: float | None
    Ps_j: float | None
    n_up: int
    n_down: int


def _row(row: _IsoTarget | _VdiTarget) -> dict[str, Any]:
    """A per-target row for the results file, in field order, rounded."""
    return {f.name: _round(getattr(row, f.name)) for f in fields(row)}


def _iso230_2(stats: list[TargetStatistics], both: bool, k: float, notes: list[str]) -> dict[str, Any]:
    """ISO 230-2 with coverage k (2; 3 for the 1988 edition) in A and 2k·s in R."""
    per = [_IsoTarget.of(s, k) for s in stats]
    out: dict[str, float | None] = {}
    for d, key in ((1, "up"), (-1, "down")):
        rows = [p.side(d) for p in per if p.side(d)[3]]
        out[f"E_{key}"] = _span([mean for mean, _, _, _ in rows])
        # s = 0 is a value, not a missing one; R_i is defined wherever s is
        full = [(mean, sd, R) for mean, sd, R, _ in rows if mean is not None and sd is not None and R is not None]
        if rows and len(full) == len(rows):
            out[f"R_{key}"] = max(R for _, _, R in full)
            out[f"A_{key}"] = (max(mean + k * sd for mean, sd, _ in full)
                               - min(mean - k * sd for mean, sd, _ in full))
        else:
            out[f"R_{key}"] = out[f"A_{key}"] = None
            note = _one_approach_note(stats, d, f"R_{key} and A_{key} are")
            if note:
                notes.append(note)
    pairs = [p for p in per if p.B_i is not None]
    if both:
        lone = [p.target_deg for p in per if p.B_i is None]
        if lone:
            notes.append(f"approached in one direction only: {_deg_list(lone)}, left out of M, B, B_mean, R and A "
                         "(E uses every mean)")
        B_i = [p.B_i for p in pairs if p.B_i is not None]
        out["E"] = _span([p.mean_up for p in per] + [p.mean_down for p in per])
        out["M"] = _span([p.mean for p in pairs])
        out["B"] = max(abs(b) for b in B_i) if pairs else None
        out["B_mean"] = math.fsum(B_i) / len(pairs) if pairs else None
        full_pairs = [(p.mean_up, p.s_up, p.mean_down, p.s_down, p.R_i) for p in pairs
                      if p.mean_up is not None and p.s_up is not None and p.mean_down is not None
                      and p.s_down is not None and p.R_i is not None]
        if pairs and len(full_pairs) == len(pairs):  # R_i is defined where both s are
            out["R"] = max(R_i for _, _, _, _, R_i in full_pairs)
            out["A"] = (max(max(mu + k * su, md + k * sd) for mu, su, md, sd, _ in full_pairs)
                        - min(min(mu - k * su, md - k * sd) for mu, su, md, sd, _ in full_pairs))
        else:
            out["R"] = out["A"] = None
            if pairs:
                notes.append("s is undefined at some target (one approach): R and A are undefined")
    else:
        out.update({"E": None, "M": None, "B": None, "B_mean": None, "R": None, "A": None})
    order = ("E_up", "E_down", "E", "M", "B", "B_mean", "R_up", "R_down", "R", "A_up", "A_down", "A")
    return {**{key: _round(out[key]) for key in order},
            "per_target": [_row(p) for p in per]}


def _vdi3441(stats: list[TargetStatistics], both: bool, notes: list[str]) -> dict[str, Any]:
    per = []
    for s in stats:
        mean: float | None
        U: float | None
        Ps: float | None
        if both:
            mean = U = Ps = None
            if s.mean_up is not None and s.mean_down is not None:  # approached from both sides
                mean = (s.mean_up + s.mean_down) / 2
                U = abs(s.mean_up - s.mean_down)
                Ps = 6 * (s.s_up + s.s_down) / 2 if s.s_up is not None and s.s_down is not None else None
        else:  # one direction measured: its mean and scatter stand alone (noted)
            mean, sd, _ = s.side(1 if s.n_up else -1)
            U, Ps = None, (6 * sd if sd is not None else None)
        per.append(_VdiTarget(s.target_deg, mean, U, Ps, s.n_up, s.n_down))
    rows = [p for p in per if p.mean is not None]
    if both and len(rows) < len(per):
        notes.append(f"approached in one direction only: {_deg_list([p.target_deg for p in per if p.mean is None])}, "
                     "left out")
    Ps_j = [p.Ps_j for p in rows if p.Ps_j is not None]
    ps_ok = bool(rows) and len(Ps_j) == len(rows)
    if not ps_ok:
        lone = [p.target_deg for p in rows if p.Ps_j is None]
        notes.append(f"one approach in a direction at {_deg_list(lone)}: s needs two, so Ps_max, Ps_mean and P are "
                     "undefined")
    U_j = [p.U_j for p in rows if p.U_j is not None]  # with both directions, every row has U_j
    out: dict[str, float | None] = {
        "Pa": _span([p.mean for p in rows]),
        "P": None, "Ps_max": max(Ps_j) if ps_ok else None,
        "Ps_mean": math.fsum(Ps_j) / len(rows) if ps_ok else None,
        "U_max": max(U_j) if both and rows else None,
        "U_mean": math.fsum(U_j) / len(rows) if both and rows else None}
    if both and ps_ok:
        full = [(p.mean, p.U_j, p.Ps_j) for p in rows if p.mean is not None and p.U_j is not None and p.Ps_j is not None]
        out["P"] = (max(mean + (U + Ps) / 2 for mean, U, Ps in full)
                    - min(mean - (U + Ps) / 2 for mean, U, Ps in full))
    elif not both:
        notes.append("one direction only: Pa and Ps describe that direction alone; U and P need both")
    return {**{key: _round(v) for key, v in out.items()},
            "per_target": [_row(p) for p in per]}
