"""The closure model: after a full turn the calibrated rotation increments multiply to the identity.

For a turn of samples t = 0 .. n-1 with calibrated rates w_t = K m_t + b (deg/s) held for dt_t seconds,
the increments are A_t = Exp(u_t), u_t = w_t dt_t (rad), the attitude after sample t is
C_t = A_0 A_1 ... A_t, and the closing residual is the rotation vector r = Log(C_{n-1}), which is 0
for the true parameters whatever the hand did (the device is back in its starting pose).

A perturbation du_t of one increment moves the residual by (left Jacobians J_l)

    dr = J_l(r)^-1 C_{t-1} J_l(u_t) du_t = J_l(r)^-1 H_t du_t,

which gives, in one vectorised pass over the samples, the Jacobian of r with respect to K and b and
the covariance of r caused by white reading noise (cov m = diag(sigma^2)):

    cov r = J_l(r)^-1 [ sum_t dt_t^2 H_t K diag(sigma^2) K^T H_t^T ] J_l(r)^-T.

Everything is batched over B independent turns (of one recording, or of many simulated runs): readings
are stored time-first, (n, B, 3), with dt_t = 0 past the end of shorter turns (a zero increment is the
identity, so padding changes nothing). Exponentials and logarithms come from
scipy.spatial.transform.Rotation. The running products use a vectorised Hamilton product on plain
quaternion arrays (x, y, z, w), and the sensitivities H_t are formed entry by entry from the
attitudes' matrix entries, because a pass needs thousands of compositions and millions of 3x3
products, and Rotation's composition carries a per-call cost of ~0.1 ms that would dominate it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from calib.numerics.quaternion import IDENTITY, hamilton, prefix_products, total_products  # noqa: F401  (re-exported)
from calib.units import DEG

# --------------------------------------------------------------------------- SO(3) Jacobians


def _so3_series(v: np.ndarray, c1, c2) -> np.ndarray:
    """c0 I + c1 [v]x + c2 v v^T for vectors v (..., 3), with c0 = 1 - c2 |v|^2 and c1, c2 arrays (...)."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    out = np.empty(v.shape + (3,))
    c0 = 1.0 - c2 * (x * x + y * y + z * z)
    cx, cy, cz = c2 * x, c2 * y, c2 * z
    out[..., 0, 0] = c0 + cx * x
    out[..., 1, 1] = c0 + cy * y
    out[..., 2, 2] = c0 + cz * z
    out[..., 0, 1] = cx * y - c1 * z
    out[..., 1, 0] = cx * y + c1 * z
    out[..., 0, 2] = cx * z + c1 * y
    out[..., 2, 0] = cx * z - c1 * y
    out[..., 1, 2] = cy * z - c1 * x
    out[..., 2, 1] = cy * z + c1 * x
    return out


def _left_jacobian_coefficients(a2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """c1 = (1 - cos a)/a^2 and c2 = (a - sin a)/a^3 for a^2 = a2; series below a = 0.1 rad (error < 1e-14)."""
    if np.all(a2 < 1e-2):
        c1 = 0.5 - a2 * (1.0 / 24.0 - a2 * (1.0 / 720.0 - a2 / 40320.0))
        c2 = 1.0 / 6.0 - a2 * (1.0 / 120.0 - a2 * (1.0 / 5040.0 - a2 / 362880.0))
        return c1, c2
    small = a2 < 1e-4
    a = np.sqrt(np.where(small, 1.0, a2))
    c1 = np.where(small, 0.5 - a2 * (1.0 / 24.0 - a2 / 720.0), (1.0 - np.cos(a)) / (a * a))
    c2 = np.where(small, 1.0 / 6.0 - a2 * (1.0 / 120.0 - a2 / 5040.0), (a - np.sin(a)) / (a * a * a))
    return c1, c2


def left_jacobian(v: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3), J_l(v) = I + (1 - cos a)/a^2 [v]x + (a - sin a)/a^3 [v]x^2, a = |v|, for v (..., 3) rad."""
    c1, c2 = _left_jacobian_coefficients(np.einsum("...i,...i->...", v, v))
    return _so3_series(v, c1, c2)  # [v]x^2 = v v^T - a^2 I


def left_jacobian_inv(v: np.ndarray) -> np.ndarray:
    """Inverse left Jacobian, J_l(v)^-1 = I - [v]x / 2 + (1/a^2 - (1 + cos a)/(2 a sin a)) [v]x^2, for |v| < pi."""
    a2 = np.einsum("...i,...i->...", v, v)
    small = a2 < 1e-4
    a = np.sqrt(np.where(small, 1.0, a2))
    c2 = np.where(small, 1.0 / 12.0 + a2 * (1.0 / 720.0 + a2 / 30240.0), 1.0 / (a * a) - (1.0 + np.cos(a)) / (2.0 * a * np.sin(a)))
    return _so3_series(v, np.full(a2.shape, -0.5), c2)


# --------------------------------------------------------------------------- the closure pass


@dataclass
class ClosureTerms:
    """Closure residuals of B turns and, if asked, their first-order terms.

    ``r`` (B, 3) rad. ``dK`` (B, 3, 3, 3): dr/dK_ij = dK[:, :, i, j] (rad per unit of K).
    ``db`` (B, 3, 3): dr/db (rad per deg/s). ``noise`` (B, 3, 3): cov r (rad^2) for reading noise
    ``sigma``. ``swept`` (B, 3): sum of w_t dt_t (deg), the integrated calibrated rate.
    """

    r: np.ndarray
    swept: np.ndarray
    dK: np.ndarray | None = None
    db: np.ndarray | None = None
    noise: np.ndarray | None = None
    dF: np.ndarray | None = None  # (B, 3, 3, 3) as dK with the readings m_j replaced by the ``force`` f_j


# Turns are processed in groups of about this many samples, so that the scan's working arrays stay in cache.
_CHUNK_SAMPLES = 100_000


def closure_terms(
    m: np.ndarray,
    dt: np.ndarray,
    K: np.ndarray,
    b: np.ndarray,
    sigma: np.ndarray | None = None,
    jacobian: bool = True,
    force: np.ndarray | None = None,
) -> ClosureTerms:
    """Closure residual of each of B turns, with Jacobian and noise covariance when ``jacobian``.

    m (n, B, 3) raw readings (deg/s); dt (n, B) s per sample, 0 for padding; K (B, 3, 3); b (B, 3)
    deg/s; sigma (B, 3) reading noise std (deg/s), for the covariance (None: not computed).
    ``force`` (n, B, 3): a per-sample quantity f whose sensitivities ``dF`` are wanted (with ``jacobian``),
    for a true-rate term linear in it (the g-sensitivity's specific force).
    """
    n, B = dt.shape
    step = max(1, _CHUNK_SAMPLES // max(n, 1))
    if B <= step:
        return _closure_chunk(m, dt, K, b, sigma, jacobian, force)
    parts = [
        _closure_chunk(m[:, s : s + step], dt[:, s : s + step], K[s : s + step], b[s : s + step],
                       None if sigma is None else sigma[s : s + step], jacobian,
                       None if force is None else force[:, s : s + step])
        for s in range(0, B, step)
    ]
    def cat(name: str) -> np.ndarray | None:
        return None if getattr(parts[0], name) is None else np.concatenate([getattr(p, name) for p in parts])

    return ClosureTerms(r=np.concatenate([p.r for p in parts]), swept=np.concatenate([p.swept for p in parts]),
                        dK=cat("dK"), db=cat("db"), noise=cat("noise"), dF=cat("dF"))


@dataclass
class RotationTerms:
    """The calibrated rotation over each of B motions and its first-order terms, as left perturbations.

    ``C`` (B, 3, 3): the attitude at the motion's end in its start frame (body end to body start).
    A parameter change moves it to Exp(dphi) C with dphi = dK[:, :, i, j] dK_ij + db @ d_b (rad):
    ``dK`` (B, 3, 3, 3), ``db`` (B, 3, 3). ``noise`` (B, 3, 3): cov dphi (rad^2) from reading noise.
    Unlike the closure residual these stay finite at every angle (no logarithm), so they serve motions
    of any size, e.g. the re-orientations between two rests.
    """

    C: np.ndarray
    dK: np.ndarray
    db: np.ndarray
    noise: np.ndarray | None = None
    dF: np.ndarray | None = None  # (B, 3, 3, 3) as dK with the readings m_j replaced by the ``force`` f_j


def _increments(m, dt, K, b) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The calibrated increments u_t = (K m_t + b) dt_t (n, B, 3) in rad, dt_t in rad per deg (n, B), and as
    quaternions (4, n, B)."""
    n, B = dt.shape
    w = np.matmul(m.transpose(1, 0, 2), K.transpose(0, 2, 1)).transpose(1, 0, 2) + b  # (n, B, 3) deg/s
    wdt = dt * DEG
    u = w * wdt[..., None]  # rad
    q = np.ascontiguousarray(Rotation.from_rotvec(u.reshape(-1, 3)).as_quat().T).reshape(4, n, B)
    return u, wdt, q


def _chunk_core(m, dt, K, b, sigma, force=None):
    """Attitudes, swept angles and the un-normalised sensitivities of B motions (see ``_closure_chunk``)."""
    n, B = dt.shape
    u, wdt, q = _increments(m, dt, K, b)
    swept = u.sum(axis=0) / DEG
    att = prefix_products(q)  # C_t, (4, n, B)
    prev = np.empty_like(att)  # C_{t-1}: identity for t = 0
    prev[:, 0] = IDENTITY[:, None]
    prev[:, 1:] = att[:, :-1]
    Hw = _sensitivities(prev, u, wdt)  # (9, n, B): wdt * C_{t-1} J_l(u_t), row-major 3x3
    H9 = Hw.transpose(2, 0, 1)  # (B, 9, n)
    db = np.matmul(H9, np.ones((n, 1))).reshape(B, 3, 3)  # sum over t (a product: a strided sum costs several times more)
    dK = np.matmul(H9, m.transpose(1, 0, 2)).reshape(B, 3, 3, 3)  # dK[b, a, i, j] = sum_t Hw[a, i] m_j
    dF = None if force is None else np.matmul(H9, force.transpose(1, 0, 2)).reshape(B, 3, 3, 3)
    inner = None
    if sigma is not None:
        S = np.matmul(K * np.asarray(sigma)[:, None, :] ** 2, K.transpose(0, 2, 1))  # K diag(sigma^2) K^T
        G = np.matmul(H9, H9.transpose(0, 2, 1)).reshape(B, 3, 3, 3, 3)  # G[b, a, i, c, j] = sum_t Hw[a, i] Hw[c, j]
        inner = np.einsum("baicj,bij->bac", G, S)
    return att[:, n - 1].T, swept, db, dK, inner, dF


def rotation_terms(m: np.ndarray, dt: np.ndarray, K: np.ndarray, b: np.ndarray, sigma: np.ndarray | None = None,
                   force: np.ndarray | None = None) -> RotationTerms:
    """The calibrated rotation of each of B motions with its left-perturbation Jacobian and noise covariance.

    Arguments as for ``closure_terms``.
    """
    q_end, _, db, dK, inner, dF = _chunk_core(m, dt, K, b, sigma, force)
    return RotationTerms(C=Rotation.from_quat(q_end).as_matrix(), dK=dK, db=db, noise=inner, dF=dF)


def _closure_chunk(m, dt, K, b, sigma, jacobian, force=None) -> ClosureTerms:
    if not jacobian:
        u, _, q = _increments(m, dt, K, b)
        return ClosureTerms(r=Rotation.from_quat(total_products(q).T).as_rotvec(), swept=u.sum(axis=0) / DEG)
    q_end, swept, db0, dK0, inner, dF0 = _chunk_core(m, dt, K, b, sigma, force)
    r = Rotation.from_quat(q_end).as_rotvec()
    jinv = left_jacobian_inv(r)  # (B, 3, 3)
    db = np.matmul(jinv, db0)
    dK = np.einsum("bac,bcij->baij", jinv, dK0)
    dF = None if dF0 is None else np.einsum("bac,bcij->baij", jinv, dF0)
    noise = None if inner is None else np.matmul(np.matmul(jinv, inner), jinv.transpose(0, 2, 1))
    return ClosureTerms(r=r, swept=swept, dK=dK, db=db, noise=noise, dF=dF)


def _matrix_components(q: np.ndarray) -> list[list[np.ndarray]]:
    """Rotation-matrix entries R[a][c] (arrays shaped like q[0]) of unit quaternions q (4, ...), (x, y, z, w)."""
    x, y, z, w = q
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return [
        [1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy)],
        [2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx)],
        [2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)],
    ]


def _sensitivities(prev: np.ndarray, u: np.ndarray, wdt: np.ndarray) -> np.ndarray:
    """wdt_t * C_{t-1} J_l(u_t) for attitudes prev (4, n, B) and increments u (n, B, 3), as (9, n, B).

    Entry by entry on whole arrays: C J_l = c0 C + c1 C [u]x + c2 (C u) u^T with c0 = 1 - c2 |u|^2,
    which avoids millions of 3x3 matrix products.
    """
    ux, uy, uz = np.ascontiguousarray(np.moveaxis(u, -1, 0))  # contiguous components: every pass below is faster
    a2 = ux * ux + uy * uy + uz * uz
    c1, c2 = _left_jacobian_coefficients(a2)
    c0 = (1.0 - c2 * a2) * wdt
    c1 = c1 * wdt
    c2 = c2 * wdt
    C = _matrix_components(prev)
    out = np.empty((9,) + wdt.shape)
    for a in range(3):
        Ca0, Ca1, Ca2 = C[a]
        cu = c2 * (Ca0 * ux + Ca1 * uy + Ca2 * uz)
        out[3 * a] = c0 * Ca0 + c1 * (Ca1 * uz - Ca2 * uy) + cu * ux
        out[3 * a + 1] = c0 * Ca1 + c1 * (Ca2 * ux - Ca0 * uz) + cu * uy
        out[3 * a + 2] = c0 * Ca2 + c1 * (Ca0 * uy - Ca1 * ux) + cu * uz
    return out
