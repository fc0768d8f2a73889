"""How a positioning test departs from ISO 230-2's test for a rotary axis, in words for page 1.

ISO/IEC 17025 7.8.2.1 n) asks a certificate to state any deviation from the method. The test
rules below are those ../shared/reference/positioning_standards.md gives (commonly applied; the
purchased standard is the authority): five approaches per target and direction, both directions,
the principal positions 0°, 90°, 180°, 270° among the targets of an axis up to 360°, targets
spaced irregularly so that periodic errors show. A test that departs is evaluated all the same,
but its parameters are ISO 230-2's formulas applied to it, not ISO 230-2 results: the labels
(:func:`parameters_label`) say so on the certificate and the console.
"""

from __future__ import annotations

import numpy as np

from rtcal.deliverables.deviations import PositioningDeviations

APPROACHES = 5  # per target and direction
PRINCIPAL_DEG = (0.0, 90.0, 180.0, 270.0)
MIN_TARGETS = 5  # five targets at the least, as for a linear axis (below it the four principal positions cannot be spaced irregularly)


def departures(table: PositioningDeviations) -> list[str]:
    """Each way the test departs from ISO 230-2's test, in words (empty: it follows it)."""
    target = np.round(np.asarray(table.target_deg, float), 6)
    direction = np.asarray(table.direction, int)
    out: list[str] = []
    dirs = sorted(set(direction.tolist()))
    if len(dirs) < 2:
        out.append("one direction of approach only (ISO 230-2 asks both)")
    counts = [int(np.sum((target == t) & (direction == d))) for t in np.unique(target) for d in dirs]
    fewest = min(counts) if counts else 0
    if fewest < APPROACHES:
        runs = "1 run" if fewest == 1 else f"{fewest} runs"
        out.append(f"{runs} per target and direction (ISO 230-2 asks {APPROACHES})")
    targets = np.unique(target)
    if len(targets) < MIN_TARGETS:
        out.append(f"{len(targets)} target{'s' if len(targets) != 1 else ''} (at least {MIN_TARGETS} are expected)")
    span = float(targets.max() - targets.min()) if len(targets) else 0.0
    if span >= 270.0:
        on_circle = {round(float(t) % 360.0, 6) for t in targets}
        missing = [p for p in PRINCIPAL_DEG if p not in on_circle]
        if missing:
            out.append("the principal positions " + ", ".join(f"{p:g}°" for p in missing) + " are not among the targets")
    steps = np.diff(targets)
    if len(steps) >= 2 and np.allclose(steps, steps[0], atol=1e-6):
        out.append(f"targets equally spaced ({steps[0]:g}°; ISO 230-2 asks irregular spacing so that periodic errors show)")
    return out


def parameters_label(found: list[str]) -> str:
    """What the positioning parameters are called: ISO 230-2's when the test follows it, otherwise
    ISO 230-2's formulas applied to a test that departs from it, the departures said."""
    if not found:
        return "ISO 230-2:2014"
    return "positioning parameters computed as ISO 230-2 defines them (the test departs from it: " + "; ".join(found) + ")"
