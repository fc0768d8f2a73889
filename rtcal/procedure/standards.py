"""The standards whose figures rtcal gives from one run's positioning deviations, by the label that
`rtcal evaluate --standard`, a procedure's ``evaluation.standards`` and the certificate name them.

One entry per label: its title as a page heads its figures, the edition whose definitions it
applies, and what of it is confirmed (docs/evaluation.md has every source). Plain data, no
computation: the figures are :mod:`rtcal.deliverables.standards`'; the procedure model validates
its labels against this table (so the two cannot disagree).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Standard:
    """One label: ``title`` heads its figures wherever they appear (never another standard's),
    ``edition`` names the text whose definitions are applied, ``confirmed`` says what rests on
    that text and what on secondary sources (docs/evaluation.md)."""

    label: str
    title: str
    edition: str
    confirmed: str
    needs_limits: bool = False  # its figures need the procedure's acceptance limits (and the run's U)


STANDARDS: dict[str, Standard] = {s.label: s for s in (
    Standard("iso230-2", "ISO 230-2:2014 (definitions as in 2006 and 1997)", "ISO 230-2:2014",
             "definitions as docs/evaluation.md gives them, from the standard's public abstracts and vendor documents"),
    Standard("iso230-2:1988", "ISO 230-2:1988 (first edition: 3s)", "ISO 230-2:1988",
             "±3s in A and R = 6s from secondary sources (AMT; WIT Transactions vol. 23, 1999); R_i, E, M, B in "
             "the later editions' form with k = 3, not confirmed against the 1988 text"),
    Standard("vdi3441", "VDI/DGQ 3441:1977", "VDI/DGQ 3441:1977",
             "definitions recalled from vendor software outputs; not confirmed against the guideline's text"),
    Standard("upr", "UPR: unidirectional positioning repeatability (JMTBA guideline, on ISO 230-2:2014)",
             "ISO 230-2:2014",
             "UPR = the smaller of R↑ and R↓ of ISO 230-2:2014, and a 1988 figure is not a UPR: from a secondary source "
             "quoting the JMTBA export-control guideline (docs/evaluation.md); the guideline itself was not reached"),
    Standard("iso230-2:1988-vs-2014", "ISO 230-2:1988 and ISO 230-2:2014 figures of the same readings",
             "ISO 230-2:1988 and ISO 230-2:2014",
             "as each edition's own entry: the 2014 figures are recomputed from the readings' s_i, never scaled from a "
             "1988 figure (the rule the JMTBA guideline states for UPR, docs/evaluation.md)"),
    Standard("jis-b6190-2", "JIS B 6190-2 (Japanese adoption of ISO 230-2; figures identical to ISO 230-2's)",
             "JIS B 6190-2",
             "the edition in force and the ISO 230-2 edition it is identical to are not confirmed here (check the JIS "
             "cover page); an identical adoption (kikakurui.com lists the JIS B 6190 series as IDT of ISO 230): the figures are "
             "ISO 230-2's, under the JIS title"),
    Standard("gb-t-17421.2", "GB/T 17421.2-2016 (Chinese adoption of ISO 230-2; figures identical to ISO 230-2's)",
             "GB/T 17421.2-2016",
             "its published scope (gbstd.com) is ISO 230-2's word for word (Annexes A and B named); listed as replaced "
             "there: check the edition in force"),
    Standard("jis-b0182", "JIS B 0182:1993 (vocabulary of machine-tool tests: its 3s forms)", "JIS B 0182:1993",
             "No. 346 bidirectional repeatability max(3s↑ + 3s↓ + |B|, 6s↑, 6s↓) and No. 342 reversal value from a "
             "secondary copy of the vocabulary (kk.jisw.com); the axis value as the largest over the targets is rtcal's "
             "reading, not confirmed"),
    Standard("asme-b5.64", "ASME B5.64: test uncertainty ratio (TUR) beside each verdict", "ASME B5.64",
             "TUR = tolerance / U as the issue states it; ASME B5.64's text was not reached (docs/evaluation.md)",
             needs_limits=True),
)}

ALIASES = {"iso230-2:2014": "iso230-2", "iso230-2:2006": "iso230-2", "iso230-2:1997": "iso230-2"}
LABELS = tuple(STANDARDS)


def standard_named(label: str) -> Standard:
    """The entry of ``label`` (an alias too); ValueError listing the labels."""
    found = STANDARDS.get(ALIASES.get(label.lower(), label.lower()))
    if found is None:
        raise ValueError(f"unknown standard {label!r}; one of {', '.join(LABELS)}")
    return found
