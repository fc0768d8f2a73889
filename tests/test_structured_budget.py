"""Issue 43 item 6: the budget computed in the network's structure (rtcal/solvers/structure.py) equals its dense
N×N statement (tests/dense_reference.py: V built whole, REML by Woodbury over dense factors, the residual test by
the full SVD of J and a Cholesky factor of QᵀVQ, the influence as pinv(J)) to 1e-9 on small networks: the paper,
shared-dead-path and network estimators, with every shape of source (diagonal, per point, per visit, low rank, the
error motions and the CMM field as factored maps, the uncorrected air's free course)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

import rtcal.solvers.network as network_module
import rtcal.solvers.paper000 as paper_module
import rtcal.solvers.shared_dead_path as shared_module
from rtcal.methods.multistation.procedure import GridPlan
from rtcal.solvers.network import solve_network
from rtcal.solvers.paper000 import cumulative_function, solve_paper
from rtcal.solvers.shared_dead_path import solve_shared_dead_path
from rtcal.solvers.station_budget import (AIR_DRIFT_SOURCE, StationNoiseModel, bounded_components, chain_jacobian,
                                          course_nuisance, error_motion_covariances, radial_sensitivity_mm, station_budget)
from rtcal.solvers.station_data import MultistationData
from rtcal.solvers.structure import Factored, Grouped, dense_effect
from rtcal.solvers.uncertainty import Covariance, Source, reml_scales, residual_check
from tests.dense_reference import dense_covariance, dense_propagate, dense_reml, dense_residual_check
from tests.synthetic import FIRST_GUESS_MM, PAPER_ANGLES_RAD, stations_mm

RTOL = 1e-9

SHIPPED = StationNoiseModel(length_noise_um=0.2, length_noise_ppm=0.3, point_noise_um=0.3, stage_repeatability_arcsec=0.2,
                            cmm_scale_ppm=1.0, cmm_squareness_arcsec=1.0, error_motion_radial_um=0.5,
                            error_motion_tilt_arcsec=1.0, air_index_sigma=1.2e-7, air_index_noise=3e-8,
                            table_expansion_ppm_per_k=11.5, table_expansion_u_ppm_per_k=2.0, material_temperature_sigma_k=0.1,
                            material_temperature_noise_k=0.02)
# station-major visits, no sensor (the air's course free in the test), a CMM field, an axial motion
NO_SENSOR = StationNoiseModel(length_noise_um=0.2, length_noise_ppm=0.3, point_noise_um=0.3, stage_repeatability_arcsec=0.3,
                              cmm_scale_ppm=1.0, cmm_squareness_arcsec=1.0, error_motion_radial_um=0.5,
                              error_motion_axial_um=0.3, error_motion_tilt_arcsec=1.0, air_index_bound=4e-7,
                              cmm_field_um=0.4, cmm_field_length_mm=200.0)


def _measurement(station_major: bool, seed: int = 43, noise: float = 1.0) -> MultistationData:
    """24 CMM points × 11 stations of the paper's geometry, lengths with tracer noise and points with CMM noise
    (``noise`` times their stated sizes; 0: exact)."""
    rng = np.random.default_rng(seed)
    points = GridPlan(layers=2, columns=3, rows=4).points_mm()
    centers = stations_mm(PAPER_ANGLES_RAD + np.deg2rad(rng.normal(0, 2e-3, 11)))
    true_points = points + noise * rng.normal(0, 0.3e-3, points.shape)  # what the CMM reports is off by its noise
    dist = np.linalg.norm(true_points[:, None, :] - centers[None, :, :], axis=2)
    lengths = dist - dist[0, 0] + noise * rng.normal(0, 0.25e-3, dist.shape)
    n, m = lengths.shape
    visits = np.tile(np.arange(m), (n, 1)) if station_major else np.arange(n * m).reshape(n, m)
    temperature = 20.3 + 0.2 * np.linspace(0, 1, n * m).reshape(n, m)
    return replace(MultistationData.from_arrays(points, lengths, np.rad2deg(PAPER_ANGLES_RAD)), visits=visits,
                   material_temperature_c=temperature)


class _Spy:
    """Records what a module hands to a function, and calls it."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, module: Any, name: str):
        self.calls: list[tuple[tuple, dict]] = []
        real = getattr(module, name)

        def spy(*args: Any, **kwargs: Any) -> Any:
            self.calls.append((args, kwargs))
            return real(*args, **kwargs)

        monkeypatch.setattr(module, name, spy)


def _close(actual: float, expected: float, absolute: float = 1e-300) -> None:
    assert actual == pytest.approx(expected, rel=RTOL, abs=absolute)


def _check_station_budget(call: tuple[tuple, dict], budget: Any, noise: StationNoiseModel, exact: bool = True) -> None:
    """``exact`` False: noise-free readings, whose residuals are rounding alone: the scales (≈ 1e-19 of the stated),
    their standard errors (from an information matrix at θ ≈ 0) and χ² agree to 1e-6 of the stated size, not to
    1e-9 of their own."""
    absolute = 1e-300 if exact else 1e-6
    J, r, station_columns, obs, stations, nominal, center, normal, chain, _ = call[0]
    Jd = J.toarray() if hasattr(J, "toarray") else np.asarray(J)
    sources = budget.sources
    # REML
    scales, scale_sigma, _ = dense_reml(Jd, r, sources)
    for name, value in scales.items():
        _close(budget.variances.scale[name], value, absolute)
        _close(budget.variances.scale_sigma[name], scale_sigma[name], absolute)
    # the propagation through pinv(J) and the chain
    G = chain_jacobian(stations, chain)
    influence = np.linalg.pinv(Jd)[np.asarray(station_columns).ravel()]
    dense = dict(zip([s.name for s in sources], dense_propagate(influence, sources, scales, G)))
    diff = np.asarray(obs.points_mm)[obs.point] - np.asarray(stations)[obs.station]
    L = np.linalg.norm(diff, axis=1)
    radial = radial_sensitivity_mm(diff / L[:, None], np.asarray(stations)[obs.station], center, normal)
    if noise.air_index_bound > 0:  # the uncorrected air as any course within its range replaces the straight line
        dense.pop(AIR_DRIFT_SOURCE)
        dense.update({c.name: c.covariance_arcsec2 for c in bounded_components(G @ influence, L, radial, obs.run_fraction,
                                                                               noise)})
    shown = {c.name: c.covariance_arcsec2 for c in budget.cumulative.components}
    compared = [name for name in dense if name in shown]
    assert len(compared) >= 5
    scale = max(float(np.max(np.abs(v))) for v in dense.values())  # a source the stations absorb is rounding alone
    for name in compared:
        np.testing.assert_allclose(shown[name], dense[name], rtol=RTOL, atol=1e-12 * scale, err_msg=name)
    # the residual test: V whole, the error motions through the stations, J with the air's free course
    N = len(r)
    V = dense_covariance(sources, N)
    D = np.zeros((N, 3 * len(stations)))
    for c in range(3):
        D[np.arange(N), 3 * obs.station + c] = -diff[:, c] / np.linalg.norm(diff, axis=1)
    for *_, cov in error_motion_covariances(stations, nominal, center, noise):
        V += D @ cov @ D.T
    course = course_nuisance(L, radial, obs.run_fraction, noise)
    expected = dense_residual_check(r, V, 0, jacobian=Jd if course is None else np.hstack([Jd, course]))
    got = budget.residual_check
    assert got is not None and expected is not None
    assert (got.dof, got.whole_budget) == (expected.dof, expected.whole_budget)
    _close(got.chi2, expected.chi2, absolute)
    _close(got.p_value, expected.p_value, absolute)


@pytest.mark.parametrize("noise, station_major, size", [(SHIPPED, False, 1.0), (NO_SENSOR, True, 1.0), (SHIPPED, False, 0.0)],
                         ids=["shipped", "no-sensor", "noise-free"])
def test_paper_and_shared_dead_path_budgets_equal_their_dense_form(monkeypatch, noise, station_major, size):
    """On a noise-free bench REML drives θ to its floor (≈ 1e-300): the budget stays the dense one's, finite."""
    data = _measurement(station_major, noise=size)
    paper_spy = _Spy(monkeypatch, paper_module, "station_budget")
    shared_spy = _Spy(monkeypatch, shared_module, "station_budget")
    paper = solve_paper(data, FIRST_GUESS_MM, noise=noise)
    shared = solve_shared_dead_path(data, FIRST_GUESS_MM, noise=noise)
    _check_station_budget(paper_spy.calls[0], paper.budget, noise, exact=size > 0)
    _check_station_budget(shared_spy.calls[0], shared.budget, noise, exact=size > 0)
    args = shared_spy.calls[0][0]
    dense_jacobian = station_budget(args[0].toarray(), *args[1:])  # a dense Jacobian is taken alike
    assert dense_jacobian.residual_check is not None and shared.budget.residual_check is not None
    _close(dense_jacobian.residual_check.chi2, shared.budget.residual_check.chi2, 1e-300 if size > 0 else 1e-12)
    kinds = {s.name: type(s.effect).__name__ for s in shared.budget.sources}
    assert kinds["CMM point noise"] == "Grouped"  # the structure the budget is kept in, not a dense N × 3n
    if noise.cmm_field_um:
        assert any(k == "Factored" for k in kinds.values())


@pytest.mark.parametrize("noise", [SHIPPED, NO_SENSOR], ids=["shipped", "no-sensor"])
def test_the_network_residual_test_equals_its_dense_form(monkeypatch, noise):
    data = _measurement(station_major=noise is NO_SENSOR)
    spy = _Spy(monkeypatch, network_module, "residual_check")
    est = solve_network(data, FIRST_GUESS_MM, noise=noise)
    (r, covariance, parameters), kwargs = spy.calls[0]
    assert isinstance(covariance, Covariance)
    V = np.zeros((len(r), len(r)))
    for e in covariance.effects:
        F = dense_effect(e)
        V += np.diag(F**2) if F.ndim == 1 else F @ F.T
    # the lengths at the reported points against the whole budget, the globals' Jacobian (and the air's free course)
    assert len(r) == int(np.sum(np.isfinite(data.lengths_mm))) and kwargs["jacobian"].shape[0] == len(r)
    expected = dense_residual_check(r, V, parameters, jacobian=kwargs["jacobian"].toarray())
    assert est.residual_check is not None and expected is not None
    assert (est.residual_check.dof, est.residual_check.whole_budget) == (expected.dof, True)
    _close(est.residual_check.chi2, expected.chi2)


def test_reml_with_every_shape_of_source_equals_the_dense_form():
    """Diagonal, per-group, dense and factored sources, Type A among each shape but the factored one, and a
    rank-deficient Jacobian: the structured REML equals the dense one to 1e-9; so do the residual test with and
    without the Jacobian."""
    rng = np.random.default_rng(9)
    N, groups, p = 150, 25, 6
    group = rng.integers(0, groups, N)
    J = rng.standard_normal((N, p))
    J[:, 5] = J[:, 0] + J[:, 1]  # rank 5
    sparse_map = Grouped(rng.standard_normal((N, 2)), rng.integers(0, 10, N), 10).sparse()
    sources = [Source("noise", "A", rng.uniform(0.5, 1.5, N), 1.0, "u"),
               Source("per group", "A", Grouped(rng.standard_normal((N, 3)), group, groups), 1.0, "u"),
               Source("common", "A", rng.standard_normal((N, 2)) * 0.3, 1.0, "u"),
               Source("known noise", "B", np.full(N, 0.2), 0.2, "u"),
               Source("known common", "B", rng.standard_normal((N, 3)) * 0.1, 0.1, "u"),
               Source("factored", "B", Factored(sparse_map, rng.standard_normal((20, 4)) * 0.2), 0.2, "u")]
    truth = sum(dense_effect(s.effect) * rng.standard_normal(N) if np.ndim(s.effect) == 1
                else dense_effect(s.effect) @ rng.standard_normal(dense_effect(s.effect).shape[1]) for s in sources)
    r = truth - J @ np.linalg.lstsq(J, truth, rcond=None)[0]
    est = reml_scales(J, r, sources, tolerance=1e-10, max_iterations=200)
    scales, sigmas, _ = dense_reml(J, r, sources, tolerance=1e-10, max_iterations=200)
    for name in scales:
        _close(est.scale[name], scales[name])
        _close(est.scale_sigma[name], sigmas[name])
    V = dense_covariance(sources, N)
    for jacobian, parameters in ((J, 0), (None, p)):
        got = residual_check(r, Covariance.of_sources(sources), parameters, jacobian=jacobian)
        expected = dense_residual_check(r, V, parameters, jacobian=jacobian)
        assert got is not None and expected is not None and got.dof == expected.dof
        _close(got.chi2, expected.chi2)
