"""Positioning-test evaluation: ISO 230-2 and VDI/DGQ 3441, pure functions of a deviation table.

Formulas as `../shared/reference/positioning_standards.md` gathers them. For target P_i and
approach j: x_ij = actual − target; per direction x̄_i = (1/n_i)·Σ_j x_ij over that target's own
n_i approaches (the first of a published evaluator's four errors divided by the number of
targets), s_i = √(Σ_j (x_ij − x̄_i)²/(n_i − 1)).

- ISO 230-2 (1997, 2006, 2014): B_i = x̄_i↑ − x̄_i↓ (↑ minus ↓: swapping them flips B's sign, the
  second error; it shows in B_i and B̄), B = max|B_i|, B̄ = mean B_i; R_i↑ = 4s_i↑, R_i =
  max(2s_i↑ + 2s_i↓ + |B_i|, R_i↑, R_i↓) and R = max R_i (not R↑: the fourth error); E↑ = max x̄↑ −
  min x̄↑ (the minimum over the same set: the third error took it with the wrong comparison), E
  over both directions, M = range of x̄_i = (x̄↑ + x̄↓)/2, A↑ = max(x̄↑ + 2s↑) − min(x̄↑ − 2s↑), A over
  both directions.
- ISO 230-2:1988: the same definitions with ±3s in the accuracy A and a repeatability of 6s
  (R_i↑ = 6s_i↑, R_i = max(3s↑ + 3s↓ + |B_i|, …)): the first edition's coverage of three standard
  deviations, as the reference notes state; this could not be confirmed against the purchased
  text and is marked so in the output's notes.
- VDI/DGQ 3441: U_j = |x̄↑ − x̄↓|, Ps_j = 6·(s↑ + s↓)/2, Pa = max x̄ − min x̄, P = max(x̄ + (U + Ps)/2) −
  min(x̄ − (U + Ps)/2); U_max, U_mean, Ps_max, Ps_mean (recalled from vendor outputs; marked so).

One direction only: the bidirectional parameters are None. One approach per target and
direction: s and everything built on it (R, A, Ps, P) are None. The notes say which and why.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rtcal.deviations import PositioningDeviations

STANDARDS = ("iso230-2", "iso230-2:1988", "vdi3441")
UNCONFIRMED = {
    "iso230-2:1988": "the 1988 edition's ±3s in A and 6s in R follow the gathered notes; not confirmed against the "
                     "standard's own text",
    "vdi3441": "VDI/DGQ 3441's definitions follow vendor software outputs; not confirmed against the guideline's text",
}


@dataclass(frozen=True)
class TargetStatistics:
    target_deg: float
    mean_up: float | None
    mean_down: float | None
    s_up: float | None
    s_down: float | None
    n_up: int
    n_down: int


def _stats(values: list[float]) -> tuple[float | None, float | None, int]:
    n = len(values)
    if n == 0:
        return None, None, 0
    mean = sum(values) / n
    s = (sum((v - mean) ** 2 for v in values) / (n - 1)) ** 0.5 if n > 1 else None
    return mean, s, n


def target_statistics(table: PositioningDeviations) -> list[TargetStatistics]:
    """Per target (ascending): mean and standard deviation of the approaches from each side."""
    out = []
    targets = sorted({round(float(t), 9) for t in table.target_deg})
    for t in targets:
        sel = np.isclose(table.target_deg, t, atol=1e-9) & np.isfinite(table.deviation_arcsec)
        up = [float(x) for x, d in zip(table.deviation_arcsec[sel], table.direction[sel]) if d > 0]
        down = [float(x) for x, d in zip(table.deviation_arcsec[sel], table.direction[sel]) if d < 0]
        mu, su, nu = _stats(up)
        md, sd, nd = _stats(down)
        out.append(TargetStatistics(t, mu, md, su, sd, nu, nd))
    return out


def _range(hi: list[float | None], lo: list[float | None]) -> float | None:
    hi = [v for v in hi if v is not None]
    lo = [v for v in lo if v is not None]
    return (max(hi) - min(lo)) if hi and lo else None


def _round(v: float | None, digits: int = 4) -> float | None:
    return None if v is None else round(float(v), digits)


def evaluate(table: PositioningDeviations, standard: str = "iso230-2") -> dict[str, Any]:
    """The standard's parameters (arcsec), keyed by its symbols, with per-target values and notes."""
    if standard not in STANDARDS:
        raise ValueError(f"unknown standard {standard!r}; one of {', '.join(STANDARDS)}")
    stats = target_statistics(table)
    notes: list[str] = []
    up = any(s.n_up for s in stats)
    down = any(s.n_down for s in stats)
    if not (up and down):
        notes.append("one direction only: the bidirectional parameters are not defined")
    if all(s.s_up is None and s.s_down is None for s in stats):
        notes.append("one approach per target and direction: no standard deviation, so no repeatability or accuracy")
    if standard in UNCONFIRMED:
        notes.append(UNCONFIRMED[standard])
    runs = sorted({int(r) for r in table.run})
    base = {"standard": standard, "unit": "arcsec", "targets": len(stats),
            "runs_per_direction": {"up": max((s.n_up for s in stats), default=0), "down": max((s.n_down for s in stats), default=0)},
            "runs": runs}
    if standard == "vdi3441":
        return {**base, **_vdi3441(stats, up and down), "notes": notes}
    return {**base, **_iso230_2(stats, up and down, 3.0 if standard.endswith("1988") else 2.0), "notes": notes}


def _iso230_2(stats: list[TargetStatistics], both: bool, k: float) -> dict[str, Any]:
    """ISO 230-2 with coverage k (2; 3 for the 1988 edition) in A and 2k·s in R."""
    per = []
    for s in stats:
        B_i = (s.mean_up - s.mean_down) if both and s.mean_up is not None and s.mean_down is not None else None
        mean = (s.mean_up + s.mean_down) / 2 if B_i is not None else None
        R_up = 2 * k * s.s_up if s.s_up is not None else None
        R_down = 2 * k * s.s_down if s.s_down is not None else None
        R_i = None
        if B_i is not None and s.s_up is not None and s.s_down is not None:
            R_i = max(k * s.s_up + k * s.s_down + abs(B_i), R_up, R_down)
        per.append({"target_deg": s.target_deg, "mean_up": s.mean_up, "mean_down": s.mean_down, "mean": mean, "B_i": B_i,
                    "s_up": s.s_up, "s_down": s.s_down, "R_up_i": R_up, "R_down_i": R_down, "R_i": R_i,
                    "n_up": s.n_up, "n_down": s.n_down})

    def col(key):
        return [p[key] for p in per]

    def acc(mean_key, s_key, sign):
        return [p[mean_key] + sign * k * p[s_key] if p[mean_key] is not None and p[s_key] is not None else None for p in per]

    E_up, E_down = _range(col("mean_up"), col("mean_up")), _range(col("mean_down"), col("mean_down"))
    B_values = [b for b in col("B_i") if b is not None]
    out = {
        "E_up": E_up, "E_down": E_down,
        "E": _range(col("mean_up") + col("mean_down"), col("mean_up") + col("mean_down")) if both else None,
        "M": _range(col("mean"), col("mean")) if both else None,
        "B": max(abs(b) for b in B_values) if B_values else None,
        "B_mean": sum(B_values) / len(B_values) if B_values else None,
        "R_up": max([r for r in col("R_up_i") if r is not None], default=None),
        "R_down": max([r for r in col("R_down_i") if r is not None], default=None),
        "R": max([r for r in col("R_i") if r is not None], default=None),
        "A_up": _range(acc("mean_up", "s_up", +1), acc("mean_up", "s_up", -1)) if any(col("s_up")) else None,
        "A_down": _range(acc("mean_down", "s_down", +1), acc("mean_down", "s_down", -1)) if any(col("s_down")) else None,
    }
    A_both = None
    if both and any(col("s_up")) and any(col("s_down")):
        A_both = _range(acc("mean_up", "s_up", +1) + acc("mean_down", "s_down", +1),
                        acc("mean_up", "s_up", -1) + acc("mean_down", "s_down", -1))
    out["A"] = A_both
    return {**{key: _round(v) for key, v in out.items()},
            "per_target": [{key: (_round(v) if isinstance(v, float) else v) for key, v in p.items()} for p in per]}


def _vdi3441(stats: list[TargetStatistics], both: bool) -> dict[str, Any]:
    per = []
    for s in stats:
        U = abs(s.mean_up - s.mean_down) if both and s.mean_up is not None and s.mean_down is not None else None
        mean = (s.mean_up + s.mean_down) / 2 if U is not None else (s.mean_up if s.mean_up is not None else s.mean_down)
        if both:
            Ps = 6 * (s.s_up + s.s_down) / 2 if s.s_up is not None and s.s_down is not None else None
        else:
            single = s.s_up if s.s_up is not None else s.s_down
            Ps = 6 * single if single is not None else None
        per.append({"target_deg": s.target_deg, "mean": mean, "U_j": U, "Ps_j": Ps, "n_up": s.n_up, "n_down": s.n_down})
    means = [p["mean"] for p in per if p["mean"] is not None]
    U = [p["U_j"] for p in per if p["U_j"] is not None]
    Ps = [p["Ps_j"] for p in per if p["Ps_j"] is not None]
    P = None
    if Ps and (U or not both):
        half = [((p["U_j"] or 0.0) + p["Ps_j"]) / 2 for p in per if p["Ps_j"] is not None and p["mean"] is not None]
        centre = [p["mean"] for p in per if p["Ps_j"] is not None and p["mean"] is not None]
        P = max(c + h for c, h in zip(centre, half)) - min(c - h for c, h in zip(centre, half))
    out = {"Pa": (max(means) - min(means)) if means else None, "P": P,
           "Ps_max": max(Ps) if Ps else None, "Ps_mean": sum(Ps) / len(Ps) if Ps else None,
           "U_max": max(U) if U else None, "U_mean": sum(U) / len(U) if U else None}
    return {**{key: _round(v) for key, v in out.items()},
            "per_target": [{key: (_round(v) if isinstance(v, float) else v) for key, v in p.items()} for p in per]}
