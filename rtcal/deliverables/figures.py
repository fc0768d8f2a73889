"""Figures: matplotlib without a display (the Agg backend), shared by every plot rtcal writes."""

from __future__ import annotations

import textwrap

import matplotlib

matplotlib.use("Agg")
matplotlib.rcParams["text.parse_math"] = False  # every text drawn as written: a serial or a name with `$…$` is no formula
import matplotlib.pyplot as plt  # noqa: E402  (re-exported for the modules that plot)

__all__ = ["legend_below", "plt"]


def legend_below(fig, ncol: int = 2) -> None:
    """One legend for every axes of the figure, outside them below (the figure made with
    ``layout="constrained"``): a legend inside the axes can cover data, this one cannot. Labels
    repeated across axes are shown once."""
    handles, labels = [], []
    for ax in fig.axes:
        for h, label in zip(*ax.get_legend_handles_labels()):
            if label not in labels:
                handles.append(h)
                labels.append(label)
    if handles:
        # constrained layout sizes the legend's height, not its width: a label longer than its
        # column is wrapped, or the legend runs past the figure's edges
        font_pt = 8
        column_chars = int(fig.get_figwidth() * 72 / (font_pt * 0.6) / ncol) - 8
        labels = [textwrap.fill(label.replace(" = ", "\u00a0=\u00a0"), column_chars) for label in labels]  # k = 2 kept whole
        fig.legend(handles, labels, loc="outside lower center", ncol=ncol, fontsize=font_pt, frameon=False)
