"""Lengths counted in real air, corrected to geometric lengths (a pure function of the readings).

A tracking interferometer counts optical path. Referenced at t₀ and read at t, with the air's
index n(t) and the standard-air index n_std it assumes, it reports

    l = (n(t)·L(t) − n(t₀)·L(t₀)) / n_std,

so the geometric distance is L(t) = r(t)·(l + K) with r = n_std/n(t) and K = n(t₀)·L(t₀)/n_std,
a constant of the tracking segment close to its dead path D. The solvers' model L = l_c + D then
holds for l_c = r·l + (r − 1)·K. The second term — the dead-path error of interferometry — is
about a micrometre per ppm of index at a metre; K is taken from the nominal geometry, good to
a millimetre, which is a nanometre in l_c.
"""

from __future__ import annotations

import numpy as np


def correct_lengths(lengths_mm: np.ndarray, air_index: np.ndarray, segments: np.ndarray, points_mm: np.ndarray,
                    stations_guess_mm: np.ndarray, standard_index: float) -> np.ndarray:
    """Geometric lengths (n×m) from counted ones. A length without its own index takes the mean
    index of its tracking segment."""
    lengths = np.asarray(lengths_mm, float)
    index = np.asarray(air_index, float).copy()
    valid = np.isfinite(lengths)
    dist = np.linalg.norm(np.asarray(points_mm)[:, None, :] - np.asarray(stations_guess_mm)[None, :, :], axis=2)
    out = lengths.copy()
    for s in np.unique(segments[valid]):
        sel = valid & (segments == s)
        known = sel & np.isfinite(index)
        n_seg = index[known].mean() if known.any() else standard_index
        index[sel & ~np.isfinite(index)] = n_seg
        K = float(np.median(dist[sel] - lengths[sel]))  # the segment's dead path, from the nominal geometry
        r = standard_index / index[sel]
        out[sel] = r * lengths[sel] + (r - 1.0) * K
    return out
