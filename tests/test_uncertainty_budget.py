"""The GUM machinery: REML variance components and propagation, against brute force and simulation."""

from __future__ import annotations

import numpy as np

from rtcal.solvers.uncertainty import DeviationBudget, Source, difference_matrix, propagate, reml_scales


def _dense_reml(J, r, sources, iterations=200):
    """Textbook REML by Fisher scoring with dense N×N matrices: the oracle for the structured form."""
    def vmat(s):
        e = np.asarray(s.effect, float)
        return np.diag(e**2) if e.ndim == 1 else e @ e.T

    a = [s for s in sources if s.type == "A"]
    fixed = sum((vmat(s) for s in sources if s.type == "B"), np.zeros((len(r), len(r))))
    mats = [vmat(s) for s in a]
    theta = np.ones(len(a))
    for _ in range(iterations):
        V = fixed + sum(t * m for t, m in zip(theta, mats))
        Vi = np.linalg.inv(V)
        P = Vi - Vi @ J @ np.linalg.inv(J.T @ Vi @ J) @ J.T @ Vi
        score = np.array([0.5 * (r @ P @ m @ P @ r - np.trace(P @ m)) for m in mats])
        info = np.array([[0.5 * np.trace(P @ mk @ P @ ml) for ml in mats] for mk in mats])
        theta = np.maximum(theta + np.linalg.solve(info, score), 1e-12)
    return theta


def _problem(rng, n_groups=12, per_group=8, p=4, s_noise=0.5, s_group=1.5, s_fixed=0.3):
    N = n_groups * per_group
    J = rng.standard_normal((N, p))
    group = np.repeat(np.arange(n_groups), per_group)
    G = np.zeros((N, n_groups))
    G[np.arange(N), group] = rng.uniform(0.5, 1.5, N)  # a random effect shared by each group
    B = rng.standard_normal((N, 2)) * 0.2  # a known (Type B) low-rank source
    w = rng.uniform(0.8, 1.2, N)
    y = J @ rng.standard_normal(p) + s_noise * w * rng.standard_normal(N) + G @ (s_group * rng.standard_normal(n_groups)) \
        + B @ (s_fixed * rng.standard_normal(2))
    r = y - J @ np.linalg.lstsq(J, y, rcond=None)[0]
    sources = [Source("noise", "A", w, 1.0, "u"), Source("group", "A", G, 1.0, "u"), Source("fixed", "B", B * s_fixed, s_fixed, "u")]
    return J, r, sources


def test_structured_reml_equals_dense_reml():
    """The Woodbury form gives the textbook REML to 1e-6 relative (both iterate to convergence)."""
    rng = np.random.default_rng(1)
    J, r, sources = _problem(rng)
    est = reml_scales(J, r, sources, tolerance=1e-12, max_iterations=500)
    dense = _dense_reml(J, r, sources)
    np.testing.assert_allclose([est.scale["noise"], est.scale["group"]], dense, rtol=1e-6)


def test_structured_reml_equals_dense_reml_with_diagonal_sources():
    """Two diagonal Type A sources (one noise on half the residuals, one on the other, overlapping
    at 16) and a diagonal Type B source beside the grouped one: the diagonal path of the Woodbury
    form equals the textbook REML to 1e-6 relative."""
    rng = np.random.default_rng(5)
    J, r, sources = _problem(rng)
    N = len(r)
    first = np.where(np.arange(N) < N // 2 + 8, rng.uniform(0.8, 1.2, N), 0.0)
    second = np.where(np.arange(N) >= N // 2 - 8, rng.uniform(0.3, 0.6, N), 0.0)
    sources = [Source("noise 1", "A", first, 1.0, "u"), Source("noise 2", "A", second, 1.0, "u"), sources[1],
               Source("known, diagonal", "B", np.full(N, 0.1), 0.1, "u"), sources[2]]
    est = reml_scales(J, r, sources, tolerance=1e-12, max_iterations=500)
    dense = _dense_reml(J, r, sources)
    np.testing.assert_allclose([est.scale["noise 1"], est.scale["noise 2"], est.scale["group"]], dense, rtol=1e-6)


def test_propagation_is_exact():
    """propagate() returns G·H·F·Fᵀ·Hᵀ·Gᵀ per source (θ times it for Type A), to rounding."""
    rng = np.random.default_rng(4)
    J, _, sources = _problem(rng)
    G = rng.standard_normal((3, J.shape[1]))
    H = np.linalg.pinv(J)
    from rtcal.solvers.uncertainty import VarianceEstimate

    theta = {"noise": 0.7, "group": 2.5}
    components = propagate(H, sources, VarianceEstimate(theta, {}, 0, True), G)
    for s, c in zip(sources, components):
        F = np.diag(s.effect) if np.ndim(s.effect) == 1 else s.effect
        expected = theta.get(s.name, 1.0) * (G @ H @ F @ F.T @ H.T @ G.T)
        np.testing.assert_allclose(c.covariance_arcsec2, expected, rtol=1e-12, atol=1e-14)
        assert c.type == s.type


def test_reml_recovers_the_variance_components():
    """200 simulated problems with σ_noise = 0.5, σ_group = 1.5: the mean estimates lie within 5 %
    (REML is nearly unbiased; 200 × 96 residuals put the mean's own spread near 1–3 %), and the
    spread of the estimates agrees with the Fisher-information standard error within 25 %."""
    rng = np.random.default_rng(7)
    noise, group, se = [], [], []
    for _ in range(200):
        J, r, sources = _problem(rng)
        est = reml_scales(J, r, sources)
        noise.append(np.sqrt(est.scale["noise"]))
        group.append(np.sqrt(est.scale["group"]))
        se.append(est.scale_sigma["noise"])
    assert abs(np.mean(noise) / 0.5 - 1) < 0.05
    assert abs(np.mean(group) / 1.5 - 1) < 0.05
    spread = np.std(np.square(noise))
    assert 0.75 < np.mean(se) / spread < 1.25


def test_propagation_matches_simulation_of_a_linear_estimator():
    """A least-squares estimate's output Gx̂: the propagated covariance equals the covariance of
    5000 simulated estimates within 5 % on the diagonal (the Monte Carlo's own spread is 2 %)."""
    rng = np.random.default_rng(3)
    J, _, sources = _problem(rng)
    sources = [Source("noise", "B", sources[0].effect * 0.5, 0.5, "u"), Source("group", "B", sources[1].effect * 1.5, 1.5, "u")]
    G = rng.standard_normal((3, J.shape[1]))
    H = np.linalg.pinv(J)
    from rtcal.solvers.uncertainty import VarianceEstimate

    budget = DeviationBudget(propagate(H, sources, VarianceEstimate({}, {}, 0, True), G))
    sims = []
    for _ in range(5000):
        y = sources[0].effect * rng.standard_normal(len(J)) + sources[1].effect @ rng.standard_normal(sources[1].effect.shape[1])
        sims.append(G @ (H @ y))
    np.testing.assert_allclose(budget.uncertainty_arcsec, np.std(sims, axis=0), rtol=0.05)


def test_difference_matrix():
    np.testing.assert_array_equal(difference_matrix(3) @ np.array([1.0, 4.0, 9.0]), [3.0, 5.0])
