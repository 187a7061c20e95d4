"""Quaternion arrays: Hamilton products and running (prefix) products, vectorised.

Quaternions are stored component-first, (4, ...) in (x, y, z, w) order (scipy's scalar-last order
along the first axis). scipy.spatial.transform.Rotation gives exponentials, logarithms and matrices;
these plain-array products serve the scans over thousands of samples, where Rotation's per-call cost
of composition (~0.1 ms) would dominate.
"""

from __future__ import annotations

import numpy as np

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def _hamilton_structure() -> np.ndarray:
    """E[i, j, k]: component i of the product of basis quaternions e_j * e_k (x, y, z, w order)."""
    E = np.zeros((4, 4, 4))
    x, y, z, w = range(4)
    for i, j, k, s in (
        (x, w, x, 1), (x, x, w, 1), (x, y, z, 1), (x, z, y, -1),
        (y, w, y, 1), (y, x, z, -1), (y, y, w, 1), (y, z, x, 1),
        (z, w, z, 1), (z, x, y, 1), (z, y, x, -1), (z, z, w, 1),
        (w, w, w, 1), (w, x, x, -1), (w, y, y, -1), (w, z, z, -1),
    ):
        E[i, j, k] = s
    return E


_E = _hamilton_structure()
_SMALL = 4096  # below this many quaternions one einsum call beats sixteen array operations


def hamilton(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Composition p*q (rotation p after q, matrices R(p) R(q)) of quaternions stored (4, ...), (x, y, z, w)."""
    if p[0].size < _SMALL and q[0].size < _SMALL:
        return np.einsum("ijk,j...,k...->i...", _E, p, q)
    px, py, pz, pw = p
    qx, qy, qz, qw = q
    return np.stack(
        (
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
            pw * qw - px * qx - py * qy - pz * qz,
        )
    )


def _blocks(q: np.ndarray) -> tuple[np.ndarray, int]:
    """q (4, n, ...) padded with identities to nb*L samples and viewed as x[:, l, j] = q[:, j*L + l]."""
    n = q.shape[1]
    L = max(2, int(np.ceil(np.sqrt(n))))
    nb = -(-n // L)
    if nb * L != n:
        pad = np.zeros((4, nb * L - n) + q.shape[2:])
        pad[3] = 1.0
        q = np.concatenate((q, pad), axis=1)
    x = q.reshape((4, nb, L) + q.shape[2:]).swapaxes(1, 2)
    return np.ascontiguousarray(x), L


# p*q = R(q) p = L(p) q: the 4x4 matrices of multiplying by q on the right and by p on the left, as the components
# (x, y, z, w) they take (_PICK) and their signs
_RIGHT_PICK = np.array([[3, 2, 1, 0], [2, 3, 0, 1], [1, 0, 3, 2], [0, 1, 2, 3]])
_RIGHT_SIGN = np.array([[1, 1, -1, 1], [-1, 1, 1, 1], [1, -1, 1, 1], [-1, -1, -1, 1]], dtype=float)
_LEFT_SIGN = np.array([[1, -1, 1, 1], [1, 1, -1, 1], [-1, 1, 1, 1], [-1, -1, -1, 1]], dtype=float)
_SMALL_SCAN = 2048  # up to this many quaternions the matrix scan beats the Hamilton products' (per-call cost)


def prefix_products(q: np.ndarray) -> np.ndarray:
    """Inclusive running products P_t = q_0 q_1 ... q_t along axis 1 of q (4, n, ...).

    Blocked scan: running products inside blocks of ~sqrt(n) samples, then across the block totals,
    then one broadcast composition: ~2 sqrt(n) vectorised steps and ~2n compositions in all.
    """
    n = q.shape[1]
    if 4 < n and q[0].size <= _SMALL_SCAN:
        return _prefix_products_small(q)
    if n <= 4:
        out = q.copy()
        for i in range(1, n):
            out[:, i] = hamilton(out[:, i - 1], out[:, i])
        return out
    x, L = _blocks(q)
    for i in range(1, L):
        x[:, i] = hamilton(x[:, i - 1], x[:, i])
    totals = prefix_products(x[:, L - 1])  # (4, nb, ...): products of whole blocks 0..j
    before = np.empty_like(totals)  # exclusive: the product of the blocks before block j
    before[:, 0] = IDENTITY.reshape((4,) + (1,) * (totals.ndim - 2))
    before[:, 1:] = totals[:, :-1]
    x = hamilton(before[:, None], x)
    nb = x.shape[2]
    return x.swapaxes(1, 2).reshape((4, nb * L) + q.shape[2:])[:, :n]


def _prefix_products_small(q: np.ndarray) -> np.ndarray:
    """prefix_products for a few thousand quaternions, where each vectorised step's fixed cost dominates: the blocked
    scan with each step one stacked 4x4 matrix product (P_t = R(q_t) P_{t-1}, the matrices built in one gather), the
    block totals run through in sequence."""
    n, rest = q.shape[1], q.shape[2:]
    L = int(np.ceil(np.sqrt(n)))
    nb = -(-n // L)
    v = np.moveaxis(q, 0, -1)  # (n, ..., 4)
    if nb * L != n:
        pad = np.zeros((nb * L - n,) + rest + (4,))
        pad[..., 3] = 1.0
        v = np.concatenate((v, pad), axis=0)
    x = v.reshape((nb, L) + rest + (4, 1)).swapaxes(0, 1)  # (L, nb, ..., 4, 1): sample l of each block
    right = x[..., _RIGHT_PICK, 0] * _RIGHT_SIGN  # (L, nb, ..., 4, 4)
    inside = np.empty(x.shape)  # running products inside each block
    inside[0] = x[0]
    for i in range(1, L):
        np.matmul(right[i], inside[i - 1], out=inside[i])
    totals = inside[L - 1, ..., 0]
    right_totals = totals[..., _RIGHT_PICK] * _RIGHT_SIGN  # (nb, ..., 4, 4)
    before = np.empty((nb,) + rest + (4, 1))  # the product of the blocks before each
    before[0] = IDENTITY[:, None]
    for j in range(1, nb):
        np.matmul(right_totals[j - 1], before[j - 1], out=before[j])
    left_before = before[..., _RIGHT_PICK, 0] * _LEFT_SIGN  # (nb, ..., 4, 4)
    out = np.matmul(left_before, inside)[..., 0]  # (L, nb, ..., 4)
    out = out.swapaxes(0, 1).reshape((nb * L,) + rest + (4,))[:n]
    return np.moveaxis(out, -1, 0)


def total_products(q: np.ndarray) -> np.ndarray:
    """The full product q_0 q_1 ... q_{n-1} along axis 1 of q (4, n, ...), shape (4, ...)."""
    n = q.shape[1]
    if n <= 4:
        out = q[:, 0]
        for i in range(1, n):
            out = hamilton(out, q[:, i])
        return out
    x, L = _blocks(q)
    acc = x[:, 0]
    for i in range(1, L):
        acc = hamilton(acc, x[:, i])
    return total_products(acc)
