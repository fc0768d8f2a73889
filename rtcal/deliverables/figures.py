"""Figures: matplotlib without a display (the Agg backend), shared by every plot rtcal writes."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402,F401  (re-exported for the modules that plot)


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
        fig.legend(handles, labels, loc="outside lower center", ncol=ncol, fontsize=8, frameon=False)
