"""One wearable's calibration from the kit's: the mean's K and b carried through the wearable's map.

With g_ref = K_ref m_ref + b_ref (fitted on the kit's mean recording m_ref, on the reference's clock and in its frame)
and the wearable's map m_i = A m_ref + c (``calib.kit.coupling``), wearable i's diagonal K_i, its mounting R and its b follow:
K_i A = R K_ref makes every row of A K_ref^-1 a unit vector once scaled by k_i, so k_i = 1 / |row of A K_ref^-1|,
R = K_i A K_ref^-1 and b_i = R b_ref - K_i c. On its own clock, which runs ``rate`` times the reference's per tick,
its k and b are ``rate`` times these (``calib.effects.timing.ClockError``). Uncertainties are carried to first order.

The bias is then taken where the kit knows the true rate exactly, at its rests (zero): b_i = -K_i m_rest, from the
wearable's own readings at rest, which the coupling's c (carrying every other wearable's noise) can only blur.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.kit.clocks import ClockMap
from calib.kit.coupling import LinearMap

N_PARAMS = 19  # k_ref (3), b_ref (3), A (9, row by row), c (3), the clock's rate (1)


@dataclass(frozen=True, eq=False)
class MemberParams:
    """A wearable's k, b (its own clock), their 1-sigma and bounds, and its mounting against the reference."""

    k: np.ndarray
    b: np.ndarray
    k_std: np.ndarray
    b_std: np.ndarray
    k_bound: np.ndarray
    b_bound: np.ndarray
    mount: np.ndarray  # (3, 3) R: the wearable's axes from the reference's

    @property
    def mount_deg(self) -> float:
        """The angle of the mounting rotation, deg."""
        return float(np.degrees(np.arccos(np.clip((np.trace(self.mount) - 1.0) / 2.0, -1.0, 1.0))))


def derive(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """k, b (own clock) and R of one wearable from the parameter vector (k_ref, b_ref, A, c, rate)."""
    k_ref, b_ref, A, c, rate = p[0:3], p[3:6], p[6:15].reshape(3, 3), p[15:18], p[18]
    M = A / k_ref  # A K_ref^-1
    k = 1.0 / np.linalg.norm(M, axis=1)
    R = k[:, None] * M
    b = R @ b_ref - k * c
    return k * rate, b * rate, R


def member_params(k_ref: np.ndarray, b_ref: np.ndarray, ref_std: tuple[np.ndarray, np.ndarray],
                  ref_bound: tuple[np.ndarray, np.ndarray], coupling: LinearMap, clock: ClockMap) -> MemberParams:
    """A wearable's calibration from the reference's (``k_ref``, ``b_ref`` with their 1-sigma and bounds) and its
    coupling and clock; the uncertainty is the first-order propagation of every input's."""
    p = np.concatenate([k_ref, b_ref, coupling.A.ravel(), coupling.c, [clock.rate]])
    k, b, R = derive(p)
    jac = _jacobian(p)
    std = _propagate(jac, ref_std, coupling.cov, clock.rate_std)
    bound = _propagate(jac, ref_bound, coupling.bound_cov, clock.rate_std)
    return MemberParams(k, b, std[:3], std[3:], bound[:3], bound[3:], R)


def _jacobian(p: np.ndarray) -> np.ndarray:
    """d(k, b)/dp by central differences (6, 19)."""
    jac = np.empty((6, N_PARAMS))
    for j in range(N_PARAMS):
        h = 1e-6 * max(1.0, abs(p[j]))
        up, down = p.copy(), p.copy()
        up[j] += h
        down[j] -= h
        jac[:, j] = (np.concatenate(derive(up)[:2]) - np.concatenate(derive(down)[:2])) / (2 * h)
    return jac


def _propagate(jac: np.ndarray, ref: tuple[np.ndarray, np.ndarray], coupling_cov: np.ndarray, rate_std: float) -> np.ndarray:
    cov = np.zeros((N_PARAMS, N_PARAMS))
    cov[0:3, 0:3] = np.diag(np.asarray(ref[0]) ** 2)
    cov[3:6, 3:6] = np.diag(np.asarray(ref[1]) ** 2)
    for a in range(3):
        rows = [6 + 3 * a, 7 + 3 * a, 8 + 3 * a, 15 + a]
        cov[np.ix_(rows, rows)] = coupling_cov[a]
    cov[18, 18] = rate_std**2 if np.isfinite(rate_std) else 0.0
    return np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", jac, cov, jac), 0.0))


def rest_bias(params: MemberParams, rest_mean: np.ndarray, rest_samples: int, noise: np.ndarray) -> MemberParams:
    """``params`` with b = -k m_rest, from the wearable's mean reading at the kit's rests (``rest_samples`` of them,
    readings' noise std ``noise`` per axis, deg/s), and its uncertainty: the mean's noise and k's."""
    b = -params.k * rest_mean
    var_noise = (params.k * noise) ** 2 / max(rest_samples, 1)
    b_std = np.sqrt(var_noise + (rest_mean * params.k_std) ** 2)
    b_bound = np.sqrt(var_noise + (rest_mean * params.k_bound) ** 2)
    return MemberParams(params.k, b, params.k_std, b_std, params.k_bound, b_bound, params.mount)
