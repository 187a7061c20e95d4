"""The state-space Gauss-Markov algebra against the dense covariance it replaces, exactly."""

from __future__ import annotations

import numpy as np
import pytest

from calib.diagnosis.markov import GaussMarkovBlocks, bridge_weights, correlate, posterior_variance


def _dense(tb: np.ndarray, tau: float) -> np.ndarray:
    return np.exp(-np.abs(tb[:, None] - tb[None, :]) / tau)


@pytest.fixture(params=[(1, 40, 7.0), (2, 3, 0.4), (3, 120, 300.0)], ids=["mixed", "few-short-tau", "many-long-tau"])
def case(request):
    seed, n, tau = request.param
    rng = np.random.default_rng(seed)
    # blocks in runs (stills) with gaps between them (turns), as the diagnosis cuts them
    tb = np.sort(rng.uniform(0.0, 2.0 * n, n))
    sd = rng.uniform(0.05, 0.2, (2, 3, n))
    sigma = 0.3
    C = sigma**2 * _dense(tb, tau) + np.einsum("rib,bc->ribc", sd**2, np.eye(n))
    return tb, tau, sigma, sd, C, rng


def test_correlate_is_the_dense_product(case):
    tb, tau, _, _, _, rng = case
    v = rng.standard_normal((tb.size, 2, 5))
    np.testing.assert_allclose(correlate(tb, tau, v), np.einsum("ab,bij->aij", _dense(tb, tau), v), atol=1e-12)


def test_solve_logdet_and_whitening_match_the_dense_cholesky(case):
    tb, tau, sigma, sd, C, rng = case
    g = GaussMarkovBlocks(tb, sigma, tau, sd)
    V = rng.standard_normal(sd.shape + (4,))
    np.testing.assert_allclose(g.solve(V), np.linalg.solve(C, V), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(g.solve(V[..., 0]), np.linalg.solve(C, V[..., :1])[..., 0], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(g.logdet(), np.linalg.slogdet(C)[1], rtol=1e-12, atol=1e-9)
    # the whitening is the dense lower Cholesky factor's, row for row (time order), not just any square root
    L = np.linalg.cholesky(C)
    np.testing.assert_allclose(g.whiten(V), np.linalg.solve(L, V), rtol=1e-9, atol=1e-9)


def test_smoothing_bridging_and_posterior_variance_are_kriging(case):
    tb, tau, sigma, sd, C, rng = case
    g = GaussMarkovBlocks(tb, sigma, tau, sd)
    V = rng.standard_normal(sd.shape + (3,))
    t = np.concatenate((rng.uniform(tb[0] - 5.0, tb[-1] + 5.0, 25), tb[:2]))
    c = sigma**2 * np.exp(-np.abs(t[:, None] - tb[None]) / tau)  # cov(x(t), x(t_b))
    kriged = np.einsum("tb,ribm->ritm", c, np.linalg.solve(C, V))
    a, b, alpha, beta, _ = bridge_weights(t, tb, tau)
    xs = g.smooth(V)
    bridged = alpha[:, None] * xs[..., a, :] + beta[:, None] * xs[..., b, :]
    np.testing.assert_allclose(bridged, kriged, atol=1e-10)
    cols = np.broadcast_to(c.T, sd.shape[:2] + c.T.shape)
    dense_var = sigma**2 - np.einsum("tb,ribt->rit", c, np.linalg.solve(C, cols))
    np.testing.assert_allclose(posterior_variance(g, t), dense_var, atol=1e-12)
