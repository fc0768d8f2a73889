"""Seed-001 solvers: tilt/radial separation, harmonic analysis and closure, against known truth."""

from __future__ import annotations

import numpy as np
import pytest

from rtcal.solvers.abbe import extrapolation_factor, grating_shift_mm, predicted_encoder_error_arcsec, separate_tilt_radial
from rtcal.solvers.closure import solve_closure
from rtcal.solvers.harmonics import fit_harmonics, resolvable_orders


def test_tilt_radial_separation_and_extrapolation():
    tilt, radial = 2e-5, 1.2e-3  # rad, mm
    r1, r2 = radial + tilt * 50, radial + tilt * 70
    t, d = separate_tilt_radial(r1, r2, 50, 70)
    assert abs(t - tilt) < 1e-15 and abs(d - radial) < 1e-15
    for zs in (40.0, 60.0, 150.0):  # below, between and beyond the indicators
        assert abs(grating_shift_mm(r1, r2, 50, 70, zs) - (radial + tilt * zs)) < 1e-15
    assert extrapolation_factor(50, 70, 150) == 5.0
    # seed 001: 1 µm at rE = 32 mm is about 6 arcsec
    assert 6.4 < predicted_encoder_error_arcsec(1e-3, 32.0) < 6.5


def test_harmonic_fit_recovers_orders_amplitudes_phases():
    """Orders 1, 3, 12 injected on 96 angles with 0.2″ noise; recovered within 4σ; others absent at 4σ."""
    rng = np.random.default_rng(7)
    theta = np.deg2rad(3.75 * np.arange(96))
    injected = {1: (20.0, np.deg2rad(40)), 3: (2.0, np.deg2rad(-100)), 12: (6.0, np.deg2rad(-30))}
    y = sum(a * np.sin(n * theta + p) for n, (a, p) in injected.items()) + 3.0 + 0.2 * rng.standard_normal(96)
    fit = fit_harmonics(theta, y, resolvable_orders(theta, 24))
    assert [t.order for t in fit.terms] == list(range(1, 24))  # 2·23 + 1 ≤ 96/2
    for t in fit.terms:
        if t.order in injected:
            a, p = injected[t.order]
            assert abs(t.amplitude - a) < 4 * t.amplitude_sigma
            assert abs(np.angle(np.exp(1j * (t.phase_rad - p)))) < 4 * t.phase_sigma_rad
            assert t.significant
        else:
            assert t.amplitude < 4 * t.amplitude_sigma
    assert abs(fit.offsets[0] - 3.0) < 0.2
    assert 0.15 < fit.sigma < 0.25


def test_nyquist_and_degrees_of_freedom_limit_the_orders():
    theta = np.deg2rad(15.0 * np.arange(24))
    assert resolvable_orders(np.tile(theta, 4), 24)[-1] == 11  # Nyquist of 24 distinct angles
    assert resolvable_orders(theta, 24)[-1] == 5  # 2K + 1 ≤ 12


@pytest.mark.parametrize("offset_deg", [0.0, 7.5, 5.0])
def test_the_nyquist_order_is_seen_on_a_grid_that_misses_0(offset_deg):
    """24 angles every 15° from an offset (a polygon seated between faces): order 12 shows the part
    A·sin(12·θ0 + φ) whatever θ0 is — at 7.5° that is A·cos φ, which a column cos(12θ) (zero on
    that grid) would miss entirely."""
    rng = np.random.default_rng(3)
    theta = np.deg2rad(offset_deg + 15.0 * np.arange(24))
    a, phi = 6.0, np.deg2rad(-30)
    y = 20 * np.sin(theta + 0.7) + a * np.sin(12 * theta + phi) + 0.05 * rng.standard_normal(24)
    fit = fit_harmonics(np.tile(theta, 4), np.tile(y, 4) + 0.05 * rng.standard_normal(96), resolvable_orders(np.tile(theta, 4), 24),
                        aliased_order=12)
    term = fit.terms[-1]
    assert term.order == 12 and term.aliased and term.significant
    assert term.amplitude == pytest.approx(abs(a * np.sin(12 * theta[0] + phi)), abs=0.05)
    # the reported phase reproduces the visible values at the samples
    np.testing.assert_allclose(term.amplitude * np.sin(12 * theta + term.phase_rad), a * np.sin(12 * theta + phi), atol=0.05)


def _closure_data(rng, eps, faces_err, offsets_faces, noise):
    n = len(eps)
    vals, ti, fi, gi = [], [], [], []
    for j, off in enumerate(offsets_faces):
        c = rng.normal(0, 5.0)
        for l in range(n):
            k = (l - off) % n
            vals.append(eps[l] + faces_err[k] + c + noise * rng.standard_normal())
            ti.append(l), fi.append(k), gi.append(j)
    return solve_closure(np.array(vals), np.array(ti), np.array(fi), np.array(gi), np.zeros(n), n)


def test_closure_uncertainty_matches_monte_carlo():
    """Six seatings (0, 1, 3, 7, 12, 18 faces), 0.2″ reading noise, 300 trials.

    The spread of the estimates around the injected errors must match the 1σ the solver
    reports: 300 trials give a standard deviation to ±4 % (1σ), so the ratio must lie in 0.85–1.15.
    """
    rng = np.random.default_rng(11)
    n = 24
    eps = 20 * np.sin(np.deg2rad(15 * np.arange(n)) + 0.7)
    eps -= eps.mean()
    faces_err = rng.normal(0, 0.8, n)
    faces_err -= faces_err.mean()
    face_dev, table_dev, face_sig, table_sig = [], [], [], []
    for _ in range(300):
        r = _closure_data(rng, eps, faces_err, [0, 1, 3, 7, 12, 18], 0.2)
        face_dev.append(r.face_error - faces_err)
        table_dev.append(r.table_error - eps)
        face_sig.append(r.face_sigma)
        table_sig.append(r.table_sigma)
    ratio_face = np.std(face_dev, axis=0).mean() / np.mean(face_sig)
    ratio_table = np.std(table_dev, axis=0).mean() / np.mean(table_sig)
    assert 0.85 < ratio_face < 1.15 and 0.85 < ratio_table < 1.15, (ratio_face, ratio_table)
    assert abs(np.mean(face_dev)) < 0.01  # unbiased


def test_closure_needs_connected_seatings():
    rng = np.random.default_rng(1)
    with pytest.raises(ValueError, match="not solvable"):
        _closure_data(rng, np.zeros(24), np.zeros(24), [0], 0.1)


@pytest.mark.campaign  # a Monte Carlo of the family error rate
def test_harmonic_significance_holds_its_family_error_rate_on_white_noise():
    """1000 series of pure white noise (96 angles in two directions' groups, orders 1–23 and the
    aliased Nyquist term tested): the chance of any order flagged is the family α = 1 %. The
    binomial spread over 1000 series is ±0.3 %, so at most 2 % may have a false flag (measured
    ≈1 %); a per-order test (no Bonferroni) would flag in ~20 % of them."""
    rng = np.random.default_rng(11)
    theta = np.deg2rad(7.5 * np.arange(48))
    angles = np.concatenate([theta, theta])
    groups = np.repeat([0, 1], 48)
    orders = resolvable_orders(angles, 23)
    flagged = 0
    for _ in range(1000):
        y = 0.3 * rng.standard_normal(96) + np.where(groups == 0, 1.0, -2.0)
        fit = fit_harmonics(angles, y, orders, groups=groups, aliased_order=24)
        flagged += any(t.significant for t in fit.terms)
    assert flagged <= 20, flagged


def _many_runs(runs: int, rng: np.random.Generator):
    """An ISO-like series: 24 faces every 15°, both directions, ``runs`` runs, a certificate."""
    from rtcal.solvers.abbe import AbbeNoise, AbbeSetup, AbbeVisits

    targets = np.arange(24) * 15.0
    cmd = np.tile(np.concatenate([targets, targets[::-1]]), runs)
    direction = np.tile(np.concatenate([np.ones(24), -np.ones(24)]), runs)
    run = np.repeat(np.arange(runs), 48)
    n = len(cmd)
    eps = 3.0 * np.sin(np.radians(cmd))
    visits = AbbeVisits(cmd, np.zeros(n), np.zeros(n, int), direction, cmd + eps / 3600.0,
                        -eps + rng.normal(0, 0.2, n), rng.normal(0, 1, n), rng.normal(0, 1, n), run)
    setup = AbbeSetup(24, (50.0, 70.0), 60.0, 32.0, np.zeros(24),
                      noise=AbbeNoise(autocollimator_noise_arcsec=0.2, autocollimator_resolution_arcsec=0.1,
                                      stage_repeatability_arcsec=0.3, certificate_uncertainty_arcsec=0.1))
    return visits, setup


def test_the_analysis_holds_no_visits_by_visits_matrix():
    """Issue 43: εz per step and per run went through visits × visits operators (the seatings' centring, ε̂ ← y, the
    rows' map): 3 840 visits took hundreds of MB and O(visits³). They are applied in their structure now: the
    analysis of 3 840 visits peaks well under one such matrix (118 MB), and 96 visits give what they gave."""
    import tracemalloc

    from rtcal.solvers.abbe import analyse_abbe

    analyse_abbe(*_many_runs(2, np.random.default_rng(1)))  # what loads on first use is not the analysis' memory
    visits, setup = _many_runs(80, np.random.default_rng(43))
    tracemalloc.start()
    est = analyse_abbe(visits, setup)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 60e6, peak / 1e6
    assert np.all(np.isfinite(est.reference.rows_uncertainty_arcsec)) and len(est.reference.rows_arcsec) == 3840
