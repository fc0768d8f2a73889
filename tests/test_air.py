"""The refractive index of air against NIST's published values (Engineering Metrology Toolbox,
"Index of refraction of air", Stone and Zimmerman: the table of Ciddor and modified-Edlén results;
450 ppm CO2, vacuum wavelengths)."""

from __future__ import annotations

import pytest

from rtcal.solvers.air import ciddor_n, edlen_n, index_sensitivity, saturation_vapour_pressure_pa

# (t / °C, RH / %, p / kPa, λ / nm, n by Ciddor, n by modified Edlén), as NIST prints them (9 decimals)
NIST = [
    (20, 0, 101.325, 633, 1.000271800, 1.000271799),
    (20, 0, 60, 633, 1.000160924, 1.000160920),
    (20, 0, 120, 633, 1.000321916, 1.000321918),
    (50, 0, 100, 633, 1.000243285, 1.000243270),
    (5, 0, 100, 633, 1.000282756, 1.000282750),
    (-40, 0, 100, 633, 1.000337580, 1.000337471),
    (50, 100, 120, 633, 1.000287924, 1.000287864),
    (40, 75, 120, 633, 1.000299418, 1.000299406),
    (20, 100, 100, 633, 1.000267394, 1.000267394),
    (40, 100, 110, 1700, 1.000270247, 1.000270237),
    (20, 0, 101.325, 1700, 1.000268479, 1.000268483),
    (40, 100, 110, 300, 1.000289000, 1.000288922),
    (20, 0, 101.325, 300, 1.000286581, 1.000286579),
    (-40, 0, 120, 300, 1.000427233, 1.000427072),
]


@pytest.mark.parametrize("t, rh, p_kpa, lam, n_ciddor, n_edlen", NIST)
def test_nist_values(t, rh, p_kpa, lam, n_ciddor, n_edlen):
    """Agreement to 1e-9: the printed values' rounding is 5e-10 (measured: 6.1e-10 Ciddor, 4.0e-10
    Edlén at worst). 1e-9 of a metre is a nanometre."""
    assert ciddor_n(t, p_kpa * 1e3, rh, lam) == pytest.approx(n_ciddor, abs=1e-9)
    assert edlen_n(t, p_kpa * 1e3, rh, lam) == pytest.approx(n_edlen, abs=1e-9)


def test_saturation_vapour_pressure():
    """IAPWS: 2339.3 Pa at 20 °C; 611.2 Pa at 0 °C over water; 103.3 Pa at −20 °C over ice."""
    assert saturation_vapour_pressure_pa(20.0) == pytest.approx(2339.3, abs=0.5)
    assert saturation_vapour_pressure_pa(0.0) == pytest.approx(611.2, abs=0.5)
    assert saturation_vapour_pressure_pa(-20.0) == pytest.approx(103.3, abs=0.5)


def test_sensitivities_are_the_rules_of_thumb():
    """About −0.93 ppm per K, +0.27 ppm per hPa, −0.0085 ppm per % RH near standard air."""
    dT, dp, dh = index_sensitivity()
    assert dT == pytest.approx(-0.93e-6, rel=0.05)
    assert dp * 100 == pytest.approx(0.27e-6, rel=0.05)
    assert dh == pytest.approx(-0.0085e-6, rel=0.15)
