"""The air a laser interferometer counts in: its refractive index, and lengths corrected with it.

The index, from its published equations (as the NIST Engineering Metrology Toolbox documents
them: J. A. Stone and J. H. Zimmerman, "Index of refraction of air", Appendix A):

- :func:`ciddor_n`: P. E. Ciddor, Appl. Opt. 35, 1566 (1996), with the saturation vapour
  pressure of IAPWS (over water; over ice below 0 °C) and the enhancement factor of the
  Ciddor paper.
- :func:`edlen_n`: the Edlén equation as updated by Birch and Downs (1993, 1994), with NIST's
  modified water-vapour term.

A laser interferometer counts optical path: the length it reports is the geometric length times
the index of the air of the moment over the index it assumed. Both equations are tested against
NIST's published values (tests/test_air.py). Temperatures °C, pressures Pa, humidity % RH,
vacuum wavelength nm.

Lengths counted in real air, corrected to geometric lengths (:func:`correct_lengths`, a pure
function of the readings). A tracking interferometer referenced at t₀ and read at t, with the
air's index n(t) and the standard-air index n_std it assumes, reports

    l = (n(t)·L(t) − n(t₀)·L(t₀)) / n_std,

so the geometric distance is L(t) = r(t)·(l + K) with r = n_std/n(t) and K = n(t₀)·L(t₀)/n_std,
a constant of the tracking segment close to its dead path D. The solvers' model L = l_c + D then
holds for l_c = r·l + (r − 1)·K. The second term — the dead-path error of interferometry — is
about a micrometre per ppm of index at a metre; K is taken from the nominal geometry, good to
a millimetre, which is a nanometre in l_c.
"""

from __future__ import annotations

import math

import numpy as np

STANDARD_AIR = {"temperature_c": 20.0, "pressure_pa": 101325.0, "humidity_pct": 50.0, "co2_ppm": 450.0}
HENE_NM = 632.991  # vacuum wavelength of a He-Ne laser


def saturation_vapour_pressure_pa(temperature_c: float) -> float:
    """IAPWS saturation vapour pressure over water (t ≥ 0 °C) or over ice (t < 0 °C), Pa."""
    T = temperature_c + 273.15
    if temperature_c >= 0.0:
        K = (1.16705214528e03, -7.24213167032e05, -1.70738469401e01, 1.20208247025e04, -3.23255503223e06,
             1.49151086135e01, -4.82326573616e03, 4.05113405421e05, -2.38555575678e-01, 6.50175348448e02)
        omega = T + K[8] / (T - K[9])
        A = omega**2 + K[0] * omega + K[1]
        B = K[2] * omega**2 + K[3] * omega + K[4]
        C = K[5] * omega**2 + K[6] * omega + K[7]
        X = -B + math.sqrt(B * B - 4 * A * C)
        return 1e6 * (2 * C / X) ** 4
    theta = T / 273.16
    Y = -13.928169 * (1 - theta**-1.5) + 34.7078238 * (1 - theta**-1.25)
    return 611.657 * math.exp(Y)


def ciddor_n(temperature_c: float, pressure_pa: float, humidity_pct: float, wavelength_nm: float = HENE_NM,
             co2_ppm: float = 450.0) -> float:
    """Phase refractive index of moist air by Ciddor's equation."""
    t, p = temperature_c, pressure_pa
    T = t + 273.15
    pv = humidity_pct / 100.0 * saturation_vapour_pressure_pa(t)
    f = 1.00062 + 3.14e-8 * p + 5.6e-7 * t * t  # enhancement factor
    xv = f * pv / p
    S = (1000.0 / wavelength_nm) ** 2  # µm⁻²
    ras = 1e-8 * (5792105.0 / (238.0185 - S) + 167917.0 / (57.362 - S))
    rvs = 1.022e-8 * (295.235 + 2.6422 * S - 0.032380 * S**2 + 0.004028 * S**3)
    Ma = 0.0289635 + 1.2011e-8 * (co2_ppm - 400.0)
    raxs = ras * (1 + 5.34e-7 * (co2_ppm - 450.0))

    def Z(p_: float, T_: float, t_: float, xv_: float) -> float:
        return (1 - (p_ / T_) * (1.58123e-6 - 2.9331e-8 * t_ + 1.1043e-10 * t_ * t_ + (5.707e-6 - 2.051e-8 * t_) * xv_
                                 + (1.9898e-4 - 2.376e-6 * t_) * xv_ * xv_)
                + (p_ / T_) ** 2 * (1.83e-11 - 0.765e-8 * xv_ * xv_))

    R, Mv = 8.314472, 0.018015
    Za = Z(101325.0, 288.15, 15.0, 0.0)
    rho_axs = 101325.0 * Ma / (Za * R * 288.15)
    rho_vs = 1333.0 * Mv / (Z(1333.0, 293.15, 20.0, 1.0) * R * 293.15)
    Zm = Z(p, T, t, xv)
    rho_a = p * Ma * (1 - xv) / (Zm * R * T)
    rho_v = p * Mv * xv / (Zm * R * T)
    return 1.0 + (rho_a / rho_axs) * raxs + (rho_v / rho_vs) * rvs


def edlen_n(temperature_c: float, pressure_pa: float, humidity_pct: float, wavelength_nm: float = HENE_NM) -> float:
    """Phase refractive index of moist air by the Edlén equation (Birch and Downs), with NIST's
    water-vapour term."""
    t, p = temperature_c, pressure_pa
    pv = humidity_pct / 100.0 * saturation_vapour_pressure_pa(t)
    S = (1000.0 / wavelength_nm) ** 2
    ns = 1 + 1e-8 * (8342.54 + 2406147.0 / (130.0 - S) + 15998.0 / (38.9 - S))
    X = (1 + 1e-8 * (0.601 - 0.00972 * t) * p) / (1 + 0.0036610 * t)
    ntp = 1 + p * (ns - 1) * X / 96095.43
    return ntp - 1e-10 * (292.75 / (t + 273.15)) * (3.7345 - 0.0401 * S) * pv


def standard_air_n(wavelength_nm: float = HENE_NM) -> float:
    """The index a tracer assumes when it reports lengths for standard air (20 °C, 1013.25 hPa, 50 %)."""
    a = STANDARD_AIR
    return ciddor_n(a["temperature_c"], a["pressure_pa"], a["humidity_pct"], wavelength_nm, a["co2_ppm"])


def index_sensitivity(temperature_c: float = 20.0, pressure_pa: float = 101325.0, humidity_pct: float = 50.0,
                      wavelength_nm: float = HENE_NM) -> tuple[float, float, float]:
    """∂n/∂T (per K), ∂n/∂p (per Pa), ∂n/∂RH (per %) by central differences (for the budget)."""
    base = (temperature_c, pressure_pa, humidity_pct)
    steps = (0.01, 1.0, 0.1)
    out = []
    for k, h in enumerate(steps):
        up, down = list(base), list(base)
        up[k] += h
        down[k] -= h
        out.append((ciddor_n(up[0], up[1], up[2], wavelength_nm) - ciddor_n(down[0], down[1], down[2], wavelength_nm))
                   / (2 * h))
    return out[0], out[1], out[2]

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
