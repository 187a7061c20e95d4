"""The re-orientations' joint noise: two motions that meet at a rest share that rest's gravity direction, so their
misfits are correlated; the fit whitens them together (``calib.estimators.multi_position.model.GravityTerms.covariance``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from calib.estimators.multi_position.estimator import _data, motions_between_rests
from calib.estimators.multi_position.model import Params, _gravity_terms, residual_layout, system
from calib.simulator import simulate
from calib.simulator.lab_scripts import multi_position_script
from calib.stages.detector import detect_stages


def test_the_covariance_is_the_scatter_of_the_noise_it_describes():
    """Drawn from its definition: each rest's mean direction off by noise that both its motions see, each rest's
    edges off its mean by offsets of their own, and each motion's integrated gyro noise."""
    rng = np.random.default_rng(1)
    S, G = 9, 8
    u = rng.standard_normal((S, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    C = Rotation.random(G, random_state=2).as_matrix()
    i_s, i_e = np.arange(G), np.arange(1, G + 1)
    i_e[3], i_s[5] = 5, 2  # motions need not chain: rest 5 is met three times, rest 2 twice as a start
    terms = _gravity_terms(C, u, (i_s, i_e))
    shared, edge = rng.uniform(1.0, 2.0, S) * 1e-6, rng.uniform(0.0, 1.0, S) * 1e-6
    gyro = np.stack([np.diag(rng.uniform(1.0, 2.0, 3)) * 1e-6 for _ in range(G)])
    cov = terms.covariance(gyro, shared, edge)

    N = 100_000
    across = np.eye(3) - u[:, :, None] * u[:, None, :]

    def across_gravity(var: np.ndarray) -> np.ndarray:
        return np.einsum("sij,nsj->nsi", across, rng.standard_normal((N, S, 3))) * np.sqrt(var)[None, :, None]

    mean_noise = across_gravity(shared)
    first_edge, last_edge = across_gravity(edge), across_gravity(edge)  # each edge its own offset, met by every
    # motion that meets it
    phi = rng.standard_normal((N, G, 3)) * np.sqrt(np.diagonal(gyro, axis1=1, axis2=2))[None]
    # the arriving motion meets the end rest's first edge, the leaving one the start rest's last edge
    rho = (np.einsum("gaj,ngj->nga", terms.at_end, mean_noise[:, i_e] + first_edge[:, i_e])
           - np.einsum("gia,ngi->nga", terms.basis, mean_noise[:, i_s] + last_edge[:, i_s])
           + np.einsum("gaj,ngj->nga", terms.d_phi, phi)).reshape(N, 2 * G)
    empirical = rho.T @ rho / N
    assert np.abs(cov - empirical).max() < 0.02 * np.abs(cov).max()
    blocks = cov.reshape(G, 2, G, 2)
    assert np.abs(blocks[0, :, 1, :]).max() > 0.1 * np.abs(blocks[0, :, 0, :]).max()  # neighbours correlate
    assert np.all(blocks[0, :, 2, :] == 0.0)  # motions with no rest in common do not
    more_edge = terms.covariance(gyro, shared, 3.0 * edge).reshape(G, 2, G, 2)
    np.testing.assert_allclose(more_edge[0, :, 1, :], blocks[0, :, 1, :])  # an edge's offset is not shared


def test_the_whitened_re_orientations_are_white_where_the_accelerometer_rules():
    """One imu_tk-like trajectory, fresh noise each time, a gyro quiet enough that the rests' gravity directions
    rule the re-orientations' misfits: at the true parameters the whitened misfits scatter as unit white noise,
    neighbours included (whitened one motion at a time, neighbours correlate by about a half)."""
    rng = np.random.default_rng(5)
    clean, truth = simulate(5, noise=0.0, fs=100.0, script=multi_position_script(rng, n=10, first_rest_s=10.0),
                            accel_noise_g=0.0)
    gyro_sd, accel_sd = 0.005, 0.01
    first = replace(clean, gyro=clean.gyro + rng.normal(0.0, gyro_sd, clean.gyro.shape),
                    accel=clean.accel + rng.normal(0.0, accel_sd, clean.accel.shape))
    stills, motions = motions_between_rests(detect_stages(first))
    p = Params(np.diag(truth.k), truth.b, None, np.array([1, 1, 1, 0, 0, 0, 0, 0, 0], dtype=float))
    rows = []
    for _ in range(200):
        rec = replace(clean, gyro=clean.gyro + rng.normal(0.0, gyro_sd, clean.gyro.shape),
                      accel=clean.accel + rng.normal(0.0, accel_sd, clean.accel.shape))
        data = _data(rec, stills, motions, np.zeros(9, dtype=bool))
        rows.append(system(p, data)[0][: residual_layout(data)["motions"]])
    r = np.array(rows)
    G = r.shape[1] // 2
    assert G >= 8
    scatter = r.T @ r / r.shape[0]
    assert 0.85 < np.mean(np.diag(scatter)) < 1.15
    neighbours = scatter.reshape(G, 2, G, 2)[np.arange(G - 1), :, np.arange(1, G), :]
    assert np.sqrt(np.mean(neighbours**2)) < 0.12, neighbours  # 200 draws: about 0.07 from chance
