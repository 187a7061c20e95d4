"""The estimator's closure engine (calib.numerics.rotation) and the diagnosis's (calib.diagnosis.engine) are two
implementations of one algebra: the diagnosis generalises the rate model w = K m + b to effect terms over a
batch of replicated recordings, the estimator keeps the full 3x3 K for the extended model. On the nominal
model, on the same turns, they must give the same closing rotations, Jacobians and noise covariances."""

from __future__ import annotations

import numpy as np
import pytest

from calib.diagnosis.data import build_problem, make_layout
from calib.diagnosis.engine import closure_pass
from calib.diagnosis.models import Model
from calib.numerics.rotation import closure_terms
from calib.simulator import simulate
from calib.stages.detector import detect_stages
from calib.units import DEG


@pytest.mark.parametrize("seed", [3, 11])
def test_the_two_closure_engines_agree_on_the_nominal_model(seed: int) -> None:
    rec, _ = simulate(seed, noise=0.05)
    layout = make_layout(rec, detect_stages(rec))
    assert layout.J == 3
    prob = build_problem(layout, rec.gyro[None])
    psi = np.array([1.012, 0.987, 1.021, 0.31, -0.22, 0.14])  # k (3), b (3 deg/s): away from the truth on purpose
    B = prob.dt.shape[1]
    sigma = np.tile([0.05, 0.04, 0.06], (B, 1))
    diag = closure_pass(Model((), layout.J), np.tile(psi, (B, 1)), prob, sigma)
    est = closure_terms(prob.turn.m, prob.dt, np.tile(np.diag(psi[:3]), (B, 1, 1)), np.tile(psi[3:], (B, 1)), sigma)
    assert np.abs(diag.r).max() > 1.0  # the turns do not close at these parameters: a real comparison
    np.testing.assert_allclose(diag.r, est.r / DEG, rtol=0, atol=1e-9)
    np.testing.assert_allclose(diag.swept, est.swept, rtol=0, atol=1e-9)
    # d r / d k_i is the diagonal entry of d r / d K; d r / d b the same in both (deg per unit, per deg/s)
    dk = np.stack([est.dK[:, :, i, i] for i in range(3)], axis=-1) / DEG
    np.testing.assert_allclose(diag.jac[:, :, 0:3], dk, rtol=0, atol=1e-9)
    np.testing.assert_allclose(diag.jac[:, :, 3:6], est.db / DEG, rtol=0, atol=1e-9)
    np.testing.assert_allclose(diag.noise, est.noise / DEG**2, rtol=0, atol=1e-9)
