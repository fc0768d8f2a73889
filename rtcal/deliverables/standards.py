"""Every standard's figures from one positioning-deviation table, each with its edition, coverage
and definition, under its own standard's title (the labels: :mod:`rtcal.procedure.standards`).

A customer asks for figures by the standard they know: ISO 230-2:2014 with UPR (the export-control
guideline's figure), the 1988 edition's 3s figures beside 2014's for an old certificate, the national
adoptions (JIS B 6190-2, GB/T 17421.2: ISO 230-2's figures under their titles), JIS B 0182's 3s
forms, VDI/DGQ 3441, and ASME B5.64's test uncertainty ratio beside each verdict. The numbers are
:mod:`rtcal.deliverables.evaluation`'s (one evaluation per edition); this module names them —
never one standard's number under another's title. Sources and what is confirmed: docs/evaluation.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from rtcal.deliverables.evaluation import evaluate
from rtcal.procedure.standards import STANDARDS, Standard, standard_named

if TYPE_CHECKING:
    from rtcal.deliverables.deviations import PositioningDeviations
    from rtcal.results.model import Conformity

ARCSEC = "″"


@dataclass(frozen=True)
class Figure:
    """One figure as a page states it: symbol, value (``unit``: ″, or "" for a ratio), its U (k = 2;
    None: not evaluated for this form), the edition whose definition gives it, the coverage of the
    scatter in it, the definition in words, and what it stands beside (a verdict, for a TUR)."""

    symbol: str
    value: float | None
    edition: str
    coverage: str
    definition: str
    unit: str = ARCSEC
    expanded_uncertainty: float | None = None
    beside: str = ""

    def as_json(self) -> dict[str, Any]:
        return {"symbol": self.symbol, "value": None if self.value is None else round(self.value, 4),
                "unit": "arcsec" if self.unit == ARCSEC else "ratio",
                "U": None if self.expanded_uncertainty is None else round(self.expanded_uncertainty, 4),
                "edition": self.edition, "coverage": self.coverage, "definition": self.definition,
                **({"beside": self.beside} if self.beside else {})}


@dataclass(frozen=True)
class StandardFigures:
    """One standard's figures of a table: its label and title, the figures, the rule that links them
    to another edition or standard (empty: none), and notes (undefined figures, what is unconfirmed)."""

    label: str
    title: str
    edition: str
    figures: tuple[Figure, ...]
    rule: str = ""
    notes: tuple[str, ...] = field(default_factory=tuple)

    def as_json(self) -> dict[str, Any]:
        return {"standard": self.label, "title": self.title, "edition": self.edition, "unit": "arcsec",
                "figures": [f.as_json() for f in self.figures], "rule": self.rule, "notes": list(self.notes)}


# (key, symbol, definition, coverage of the scatter with k = 2; k is put in for the 1988 form)
ISO_FIGURES = (
    ("E_up", "E↑", "unidirectional systematic positional deviation, ↑: max x̄_i↑ − min x̄_i↑", "none (a span of means)"),
    ("E_down", "E↓", "unidirectional systematic positional deviation, ↓: max x̄_i↓ − min x̄_i↓", "none (a span of means)"),
    ("E", "E", "bidirectional systematic positional deviation: max(x̄_i↑, x̄_i↓) − min(x̄_i↑, x̄_i↓)",
     "none (a span of means)"),
    ("M", "M", "range of the mean bidirectional positional deviation: max x̄_i − min x̄_i, x̄_i = (x̄_i↑ + x̄_i↓)/2",
     "none (a span of means)"),
    ("B", "B", "reversal value of the axis: max |B_i|, B_i = x̄_i↑ − x̄_i↓", "none (a difference of means)"),
    ("B_mean", "B̄", "mean reversal value: (1/m)·Σ B_i", "none (a mean of differences)"),
    ("R_up", "R↑", "unidirectional repeatability, ↑: max R_i↑, R_i↑ = {2k}·s_i↑", "k = {k}: R_i↑ = {2k}·s_i↑"),
    ("R_down", "R↓", "unidirectional repeatability, ↓: max R_i↓, R_i↓ = {2k}·s_i↓", "k = {k}: R_i↓ = {2k}·s_i↓"),
    ("R", "R", "bidirectional repeatability: max R_i, R_i = max({k}s_i↑ + {k}s_i↓ + |B_i|, R_i↑, R_i↓)",
     "k = {k} on each side of the reversal"),
    ("A_up", "A↑", "unidirectional accuracy, ↑: max(x̄_i↑ + {k}s_i↑) − min(x̄_i↑ − {k}s_i↑)", "x̄ ± {k}s"),
    ("A_down", "A↓", "unidirectional accuracy, ↓: max(x̄_i↓ + {k}s_i↓) − min(x̄_i↓ − {k}s_i↓)", "x̄ ± {k}s"),
    ("A", "A", "bidirectional accuracy: max(x̄_i↑ + {k}s_i↑, x̄_i↓ + {k}s_i↓) − min(x̄_i↑ − {k}s_i↑, x̄_i↓ − {k}s_i↓)",
     "x̄ ± {k}s"),
)
UPR_DEFINITION = ("UPR, unidirectional positioning repeatability: the smaller of R↑ and R↓ of ISO 230-2:2014 (JMTBA "
                  "export-control guideline)")
UPR_COVERAGE = "k = 2: R = 4·s (ISO 230-2:2014)"
VDI_FIGURES = (
    ("Pa", "Pa", "position deviation: max x̄_j − min x̄_j", "none (a span of means)"),
    ("P", "P", "position uncertainty (VDI's term, a span of the data): max(x̄_j + (U_j + Ps_j)/2) − min(x̄_j − (U_j + Ps_j)/2)",
     "6s (Ps)"),
    ("Ps_max", "Ps max", "positional scatter, largest: Ps_j = 6·(s_j↑ + s_j↓)/2", "6s"),
    ("Ps_mean", "Ps mean", "positional scatter, mean of Ps_j", "6s"),
    ("U_max", "U max", "reversal span, largest: U_j = |x̄_j↑ − x̄_j↓| (VDI's U, not an uncertainty)", "none"),
    ("U_mean", "U mean", "reversal span, mean of U_j", "none"),
)
ONE_SIDED = "the tolerance T is the parameter's acceptance limit (an upper limit from 0)"
TUR_RULE = ("TUR = T / U: T the acceptance limit of the parameter (its tolerance), U the parameter's expanded uncertainty "
            "(k = 2) as the verdict used it; rtcal states the ratio beside the verdict and decides nothing on it "
            "(ASME B5.64's text was not reached: the ratio as the issue states it, docs/evaluation.md)")
CONVERSION_RULE = (
    "The 2014 figures are recomputed from the readings (their s_i), never scaled from the 1988 ones. What a 1988 figure "
    "alone gives: R↑ and R↓ times 4/6 (R_i = 6·s_i in 1988, 4·s_i in 2014, the same s_i), hence UPR = 4/6 × the smaller "
    "of the 1988 R↑ and R↓; E, E↑, E↓, M, B and B̄ are the same in both editions; R and A cannot be converted without "
    "the readings (the reversal B_i and the means enter with s_i). The JMTBA guideline's rule: a 1988 figure is not used "
    "as is (docs/evaluation.md).")


def _iso_figures(result: dict[str, Any], edition: str, k: int, with_upr: bool) -> list[Figure]:
    figures = []
    for key, symbol, definition, coverage in ISO_FIGURES:
        figures.append(Figure(symbol, result.get(key), edition, coverage.format(k=k, **{"2k": 2 * k}),
                              definition.format(k=k, **{"2k": 2 * k})))
        if key == "R_down" and with_upr:
            figures.append(Figure("UPR", upr(result), edition, UPR_COVERAGE, UPR_DEFINITION))
    return figures


def upr(result: dict[str, Any]) -> float | None:
    """The smaller of R↑ and R↓ (None unless both are defined: a UPR of one direction is not the
    guideline's figure)."""
    up, down = result.get("R_up"), result.get("R_down")
    return None if up is None or down is None else min(up, down)


def _with_u(figures: list[Figure], uncertainties: dict[str, float | None] | None) -> list[Figure]:
    """The ISO 230-2:2014 figures with the run's U (same keys); UPR takes the U of the direction it is."""
    if not uncertainties:
        return figures
    keys = {symbol: key for key, symbol, _, _ in ISO_FIGURES}
    out = []
    for f in figures:
        key = keys.get(f.symbol)
        U = uncertainties.get(key) if key else None
        if f.symbol == "UPR" and f.value is not None:
            up, down = (next((g.value for g in figures if g.symbol == s), None) for s in ("R↑", "R↓"))
            U = uncertainties.get("R_up" if f.value == up else "R_down")
        out.append(Figure(f.symbol, f.value, f.edition, f.coverage, f.definition, f.unit, U, f.beside))
    return out


def standard_figures(label: str, table: PositioningDeviations, uncertainties: dict[str, float | None] | None = None,
                     conformity: Conformity | None = None) -> StandardFigures:
    """The figures of standard ``label`` from ``table`` (arcsec); ``uncertainties``: U (k = 2) of the
    ISO 230-2:2014 parameters (a run's; None from a CSV), given beside the figures that are the same
    quantity; ``conformity``: the run's verdicts (ASME B5.64's ratio needs them). ValueError for an
    unknown label, or a figure the data cannot give (no verdict for a TUR)."""
    std = standard_named(label)
    found = _figures(std, table, uncertainties, conformity)
    return StandardFigures(found.label, found.title, found.edition, found.figures, found.rule,
                           found.notes + (f"What is confirmed: {std.confirmed}.",))


def _figures(std: Standard, table: PositioningDeviations, uncertainties: dict[str, float | None] | None,
             conformity: Conformity | None) -> StandardFigures:
    if std.label == "asme-b5.64":
        return _asme(std, conformity)
    iso = evaluate(table, "iso230-2")
    notes = tuple(iso["notes"])
    if std.label in ("iso230-2", "upr", "jis-b6190-2", "gb-t-17421.2"):
        figures = _with_u(_iso_figures(iso, std.edition, 2, with_upr=std.label in ("iso230-2", "upr")), uncertainties)
        if std.label == "upr":
            figures = [f for f in figures if f.symbol in ("R↑", "R↓", "UPR")]
            return StandardFigures(std.label, std.title, std.edition, tuple(figures), CONVERSION_RULE, notes)
        rule = ("" if std.label in ("iso230-2",) else
                f"{std.title.split(' (')[0]} adopts ISO 230-2: its figures are ISO 230-2's definitions applied to the same readings")
        return StandardFigures(std.label, std.title, std.edition, tuple(figures), rule, notes)
    old = evaluate(table, "iso230-2:1988")
    if std.label == "iso230-2:1988":
        return StandardFigures(std.label, std.title, std.edition, tuple(_iso_figures(old, std.edition, 3, False)), "",
                               tuple(old["notes"]))
    if std.label == "iso230-2:1988-vs-2014":
        new = _with_u(_iso_figures(iso, STANDARDS["iso230-2"].edition, 2, True), uncertainties)
        before = _iso_figures(old, STANDARDS["iso230-2:1988"].edition, 3, False)
        before.insert(next(i for i, f in enumerate(before) if f.symbol == "R↓") + 1,
                      Figure("UPR", None, STANDARDS["iso230-2:1988"].edition, "–",
                             "not defined in 1988: UPR is the 2014 figure (the guideline: a 1988 figure is not a UPR)"))
        paired = [f for pair in zip(before, new) for f in pair]
        return StandardFigures(std.label, std.title, std.edition, tuple(paired), CONVERSION_RULE,
                               tuple(dict.fromkeys(iso["notes"] + old["notes"])))
    if std.label == "jis-b0182":
        return _jis_b0182(std, old)
    vdi = evaluate(table, "vdi3441")
    return StandardFigures(std.label, std.title, std.edition,
                           tuple(Figure(symbol, vdi.get(key), std.edition, coverage, definition)
                                 for key, symbol, definition, coverage in VDI_FIGURES), "", tuple(vdi["notes"]))


def _jis_b0182(std: Standard, old: dict[str, Any]) -> StandardFigures:
    """JIS B 0182:1993's 3s forms: No. 346 is the 1988 edition's R (3s each side of the reversal, 6s
    one-sided), No. 342 the reversal value (largest over the targets: rtcal's reading)."""
    figures = (
        Figure("No. 346", old.get("R"), std.edition, "3s on each side of the reversal, 6s one-sided",
               "両方向繰返し位置決め精度 (bidirectional repeatability): max over the targets of max(3s↑ + 3s↓ + |B_i|, 6s↑, "
               "6s↓)"),
        Figure("No. 342", old.get("B"), std.edition, "none (a difference of means)",
               "ロストモーション/反転値 (reversal value): the difference of the mean unidirectional deviations x̄↑ − x̄↓, "
               "largest in magnitude over the targets"),
    )
    return StandardFigures(std.label, std.title, std.edition, figures,
                           "No. 346 equals ISO 230-2:1988's R of the same readings; ISO 230-2:2014's R uses 2s (see "
                           "iso230-2:1988-vs-2014)", tuple(old["notes"]))


def _asme(std: Standard, conformity: Conformity | None) -> StandardFigures:
    """One TUR per acceptance limit the run was decided on, beside its verdict."""
    if conformity is None:
        raise ValueError("asme-b5.64: the test uncertainty ratio needs acceptance limits and the run's U: give a run "
                         "directory whose procedure has `acceptance:` (a deviation CSV has neither)")
    figures = []
    for key, v in conformity.per_limit.items():
        U = v.expanded_uncertainty_arcsec
        ratio = v.limit_arcsec / U if U and U > 0 and math.isfinite(U) else None
        value = "–" if v.value_arcsec is None else f"{v.value_arcsec:.4g}″"
        figures.append(Figure(f"TUR ({key})", ratio, std.edition, f"U with k = {conformity.coverage_factor:g}",
                              f"T / U for {key}: {ONE_SIDED}", "", U,
                              f"{key} = {value} against T = {v.limit_arcsec:g}″ ({conformity.decision_rule} acceptance): "
                              f"{v.verdict}"))
    notes = ("a TUR is not defined where U is 0 or not evaluated",) if any(f.value is None for f in figures) else ()
    return StandardFigures(std.label, std.title, std.edition, tuple(figures), TUR_RULE, notes)
