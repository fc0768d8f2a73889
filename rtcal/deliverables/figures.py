"""Figures: matplotlib without a display (the Agg backend), shared by every plot rtcal writes."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402,F401  (re-exported for the modules that plot)
