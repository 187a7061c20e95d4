"""One wearable's calibration from the kit's: the mean's K and b carried through the wearable's map.

With g_ref = K_ref m_ref + b_ref (fitted on the kit's mean recording m_ref, on the reference's clock and in its frame)
and the wearable's map m_i = A m_ref + c (``calib.kit.coupling``), K_i A = R K_ref for its K_i, its mounting R and
b_i = R b_ref - K_i c. With K_i diagonal every row of A K_ref^-1 is a unit vector once scaled by k_i, so
k_i = 1 / |row of A K_ref^-1|; with K_i upper-triangular (non-orthogonal axes, ``calib.kit.axes``) A K_ref^-1 = K_i^-1 R
is its RQ decomposition. On its own clock, which runs ``rate`` times the reference's per tick, its K and b are ``rate``
times these (``calib.effects.timing.ClockError``). Uncertainties are carried to first order.

The bias is then taken where the kit knows the true rate exactly, at its rests (zero): b_i = -K_i m_rest, from the
wearable's own readings at rest, which the coupling's c (carrying every other wearable's noise) can only blur.

A wearable's non-orthogonality is reported as its ``tilt``: the off-diagonal entries of K D^-1 (D = diag(k)), i.e.
(K_xy / k_y, K_xz / k_z, K_yz / k_z), the true rate about one axis that reaches another's reading, per unit rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import rq

from calib.estimators.closure.fit import OFF_DIAGONAL, param_names
from calib.kit.clocks import ClockMap
from calib.kit.coupling import LinearMap

UPPER = (np.array([i for i, _ in OFF_DIAGONAL]), np.array([j for _, j in OFF_DIAGONAL]))  # K's xy, xz, yz entries
PARAMETERS = param_names(True)
N_PARAMS = 25  # K_ref (9, row by row), b_ref (3), A (9, row by row), c (3), the clock's rate (1)
N_OUT = 9  # k (3), b (3), tilt (3)


@dataclass(frozen=True, eq=False)
class RefCalibration:
    """The kit's mean calibration in the reference's frame: K_ref (3, 3), b_ref, and the std of every entry (K's
    off-diagonal entries: what the kit's common non-orthogonality is known to) as 1-sigma and as bound."""

    K: np.ndarray
    b: np.ndarray
    K_std: np.ndarray
    b_std: np.ndarray
    K_bound: np.ndarray
    b_bound: np.ndarray


@dataclass(frozen=True, eq=False)
class MemberParams:
    """A wearable's k, b (its own clock), their 1-sigma and bounds, its mounting against the reference, and its
    axes' non-orthogonality (``tilt``, None for a diagonal K) with its 1-sigma and bound."""

    k: np.ndarray
    b: np.ndarray
    k_std: np.ndarray
    b_std: np.ndarray
    k_bound: np.ndarray
    b_bound: np.ndarray
    mount: np.ndarray  # (3, 3) R: the wearable's axes from the reference's
    tilt: np.ndarray | None = None
    tilt_std: np.ndarray | None = None
    tilt_bound: np.ndarray | None = None

    @property
    def mount_deg(self) -> float:
        """The angle of the mounting rotation, deg."""
        return float(np.degrees(np.arccos(np.clip((np.trace(self.mount) - 1.0) / 2.0, -1.0, 1.0))))

    @property
    def K(self) -> np.ndarray:
        """K (3, 3): diag(k), with the tilt's entries above the diagonal when the axes are not orthogonal."""
        return _matrix(self.k, self.tilt)

    def K_spread(self, which: str = "std") -> np.ndarray | None:
        """The 1-sigma (``std``) or bound (``bound``) of every entry of K (3, 3); None for a diagonal K."""
        tilt = self.tilt_std if which == "std" else self.tilt_bound
        if self.tilt is None or tilt is None:
            return None
        out = np.diag(self.k_std if which == "std" else self.k_bound)
        out[UPPER] = tilt * self.k[UPPER[1]]
        return out


def _matrix(k: np.ndarray, tilt: np.ndarray | None) -> np.ndarray:
    K = np.diag(np.asarray(k, dtype=float))
    if tilt is not None:
        K[UPPER] = tilt * K[UPPER[1], UPPER[1]]
    return K


def derive(p: np.ndarray, full: bool) -> np.ndarray:
    """(k, b, tilt) of one wearable on its own clock from the parameter vector (K_ref, b_ref, A, c, rate); with
    ``full`` its K is upper-triangular (the RQ decomposition of A K_ref^-1), else diagonal (tilt 0)."""
    K_ref, b_ref, A, c, rate = p[0:9].reshape(3, 3), p[9:12], p[12:21].reshape(3, 3), p[21:24], p[24]
    M = A @ np.linalg.inv(K_ref)
    K, R = _split(M, full)
    b = R @ b_ref - K @ c
    return np.concatenate([np.diag(K) * rate, b * rate, tilt_of(K)])


def tilt_of(K: np.ndarray) -> np.ndarray:
    """The tilt of an upper-triangular K: the entries above the diagonal of K D^-1 (D = diag(k))."""
    return (K / np.diag(K)[None, :])[UPPER]


def _split(M: np.ndarray, full: bool) -> tuple[np.ndarray, np.ndarray]:
    """M = K^-1 R: (K, R) with K upper-triangular (``full``) or diagonal, R the rotation."""
    if full:
        U, Q = rq(M)
        sign = np.sign(np.diag(U))
        return np.linalg.inv(U * sign[None, :]), sign[:, None] * Q
    k = 1.0 / np.linalg.norm(M, axis=1)
    return np.diag(k), k[:, None] * M


def _vector(ref: RefCalibration, coupling: LinearMap, clock: ClockMap) -> np.ndarray:
    return np.concatenate([ref.K.ravel(), ref.b, coupling.A.ravel(), coupling.c, [clock.rate]])


def member_tilt(ref: RefCalibration, coupling: LinearMap, clock: ClockMap) -> np.ndarray:
    """A wearable's tilt (K_xy / k_y, K_xz / k_z, K_yz / k_z) with an upper-triangular K, without its uncertainty."""
    return derive(_vector(ref, coupling, clock), True)[6:9]


def member_params(ref: RefCalibration, coupling: LinearMap, clock: ClockMap, full: bool) -> MemberParams:
    """A wearable's calibration from the kit mean's ``ref`` and its coupling and clock (``full``: non-orthogonal
    axes); the uncertainty is the first-order propagation of every input's."""
    p = _vector(ref, coupling, clock)
    out = derive(p, full)
    M = coupling.A @ np.linalg.inv(ref.K)
    R = _split(M, full)[1]
    jac = _jacobian(p, full)
    std = _propagate(jac, ref.K_std, ref.b_std, coupling.cov, clock.rate_std)
    bound = _propagate(jac, ref.K_bound, ref.b_bound, coupling.bound_cov, clock.rate_std)
    tilt = (out[6:9], std[6:9], bound[6:9]) if full else (None, None, None)
    return MemberParams(out[:3], out[3:6], std[:3], std[3:6], bound[:3], bound[3:6], R, *tilt)


def _jacobian(p: np.ndarray, full: bool) -> np.ndarray:
    """d(k, b, tilt)/dp by central differences (9, 25)."""
    jac = np.empty((N_OUT, N_PARAMS))
    for j in range(N_PARAMS):
        h = 1e-6 * max(1.0, abs(p[j]))
        up, down = p.copy(), p.copy()
        up[j] += h
        down[j] -= h
        jac[:, j] = (derive(up, full) - derive(down, full)) / (2 * h)
    return jac


def _propagate(jac: np.ndarray, K_std: np.ndarray, b_std: np.ndarray, coupling_cov: np.ndarray,
               rate_std: float) -> np.ndarray:
    var = np.zeros(N_PARAMS)
    var[0:9] = np.nan_to_num(np.asarray(K_std, dtype=float).ravel() ** 2)
    var[9:12] = np.nan_to_num(np.asarray(b_std, dtype=float) ** 2)
    var[24] = rate_std**2 if np.isfinite(rate_std) else 0.0
    cov = np.diag(var)
    for a in range(3):
        rows = [12 + 3 * a, 13 + 3 * a, 14 + 3 * a, 21 + a]
        cov[np.ix_(rows, rows)] = coupling_cov[a]
    return np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", jac, cov, jac), 0.0))


def rest_bias(params: MemberParams, rest_mean: np.ndarray, rest_samples: int, noise: np.ndarray) -> MemberParams:
    """``params`` with b = -K m_rest, from the wearable's mean reading at the kit's rests (``rest_samples`` of them,
    readings' noise std ``noise`` per axis, deg/s), and its uncertainty: the mean's noise and K's."""
    K = params.K
    b = -K @ rest_mean
    var_noise = (K**2) @ (noise**2) / max(rest_samples, 1)

    def spread(which: str, k_spread: np.ndarray) -> np.ndarray:
        entries = params.K_spread(which)
        entries = np.diag(k_spread) if entries is None else entries
        return np.sqrt(var_noise + (entries**2) @ (rest_mean**2))

    return MemberParams(params.k, b, params.k_std, spread("std", params.k_std), params.k_bound,
                        spread("bound", params.k_bound), params.mount, params.tilt, params.tilt_std, params.tilt_bound)
