"""A Gauss-Markov bias seen through still blocks, in state-space form: every operation in O(NB).

The still block mean rates of one axis are y_b = x(t_b) + n_b, with x a stationary first-order
Gauss-Markov process (std sigma, time constant tau) and n_b white (std sd_b). Their covariance
C = sigma^2 M + D, M_ab = exp(-|t_a - t_b| / tau), D = diag(sd^2), is dense, but the process is
Markov: M^-1 = Q is tridiagonal, Q = Lq^T Lq with Lq the lower-bidiagonal innovation form
x_b - phi_b x_{b-1} (phi_b = exp(-(t_b - t_{b-1}) / tau)) scaled by sqrt(1 - phi_b^2). So

- C^-1 v = D^-1 v - D^-1 B^-1 D^-1 v with B = Q / sigma^2 + D^-1 tridiagonal (Woodbury),
- log det C = log det D + log det(sigma^2 M) + log det B,
- the expected process given the blocks is sigma^2 M C^-1 y = y - D C^-1 y, with posterior covariance B^-1,
- between two blocks the process is a bridge of the two: E[x(t) | y] = alpha x^_a + beta x^_b,
- the Cholesky whitening L_C^-1 v (time order, as a dense factorisation gives) is the Kalman filter's
  standardised innovations.

Every banded system is solved by LAPACK (scipy.linalg); the one loop over blocks is the Kalman gain
recursion, vectorised over axes and recordings. Arrays carry blocks on their last axis but one
where a right-hand side has columns: (..., NB) for one column, (..., NB, m) for several.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_solve_banded, cholesky_banded, solve_banded


def transitions(t: np.ndarray, tau: float) -> np.ndarray:
    """phi_b = exp(-(t_b - t_{b-1}) / tau) between consecutive block times t (NB,): (NB - 1,)."""
    return np.exp(-np.diff(t) / tau)


def recursion(a: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """y_0 = rhs_0, y_i = a_i y_{i-1} + rhs_i along the first axis of rhs (n, ...), with a (n - 1,) the coefficient of
    each step: one lower-bidiagonal solve for every column at once."""
    n = rhs.shape[0]
    if n == 1:
        return np.array(rhs, dtype=float)
    ab = np.zeros((2, n))
    ab[0] = 1.0
    ab[1, :-1] = -a
    return solve_banded((1, 0), ab, rhs.reshape(n, -1), check_finite=False).reshape(rhs.shape)


def correlate(t: np.ndarray, tau: float, v: np.ndarray) -> np.ndarray:
    """M v with M_ab = exp(-|t_a - t_b| / tau), v (NB, m): two first-order recursions (forward and backward sums)."""
    phi = transitions(t, tau)
    return recursion(phi, v) + recursion(phi[::-1], v[::-1])[::-1] - v


def _precision_bands(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Diagonal (NB,) and first off-diagonal (NB - 1,) of Q = M^-1."""
    s2 = 1.0 - phi**2
    lq_sub = -phi / np.sqrt(s2)  # Lq[b, b-1]
    lq_diag = np.concatenate(([1.0], 1.0 / np.sqrt(s2)))
    diag = lq_diag**2
    diag[:-1] += lq_sub**2
    off = lq_sub * lq_diag[1:]
    return diag, off


@dataclass
class GaussMarkovBlocks:
    """C = sigma^2 M + diag(sd^2) for the block times ``t`` (NB,) and white-noise std ``sd`` (..., NB)."""

    t: np.ndarray
    sigma: float
    tau: float
    sd: np.ndarray

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float)
        self.sd = np.asarray(self.sd, dtype=float)
        self.phi = transitions(self.t, self.tau)
        self.lead = self.sd.shape[:-1]
        qd, qo = _precision_bands(self.phi)
        s2 = self.sigma**2
        n = self.t.size
        flat_sd = self.sd.reshape(-1, n)
        # B = Q / sigma^2 + D^-1 in LAPACK's upper banded storage, one factor per axis and recording
        self._factors = []
        self._logdet_b = np.empty(flat_sd.shape[0])
        for i, sd in enumerate(flat_sd):
            ab = np.zeros((2, n))
            ab[1] = qd / s2 + 1.0 / sd**2
            ab[0, 1:] = qo / s2
            c = cholesky_banded(ab, lower=False, check_finite=False)
            self._factors.append(c)
            self._logdet_b[i] = 2.0 * np.log(c[1]).sum()
        self._logdet_m = float(np.log1p(-self.phi**2).sum())

    def _flat(self, v: np.ndarray) -> np.ndarray:
        """v (*lead, NB, ...) with its leading axes as one: (axes and recordings, NB, ...)."""
        return np.ascontiguousarray(v).reshape((-1, self.t.size) + v.shape[len(self.lead) + 1:])

    def _d(self, v: np.ndarray) -> np.ndarray:
        """diag(sd^2) as an array broadcasting against v."""
        extra = v.ndim - len(self.lead) - 1
        return (self.sd**2).reshape(self.sd.shape + (1,) * extra)

    def solve(self, v: np.ndarray) -> np.ndarray:
        """C^-1 v for v (*lead, NB) or (*lead, NB, m)."""
        d = self._d(v)
        dv = v / d
        flat = self._flat(dv)
        b_inv = np.stack([cho_solve_banded((c, False), x, check_finite=False) for c, x in zip(self._factors, flat, strict=True)])
        return dv - b_inv.reshape(v.shape) / d

    def logdet(self) -> np.ndarray:
        """log det C per axis and recording: (*lead,)."""
        logdet_d = 2.0 * np.log(self.sd).sum(axis=-1)
        n = self.t.size
        return logdet_d + n * np.log(self.sigma**2) + self._logdet_m + self._logdet_b.reshape(self.lead)

    def smooth(self, v: np.ndarray) -> np.ndarray:
        """The expected process at the block times given the block rates v: sigma^2 M C^-1 v = v - D C^-1 v."""
        return v - self._d(v) * self.solve(v)

    def posterior_bands(self) -> tuple[np.ndarray, np.ndarray]:
        """Posterior variance of the process at each block (*lead, NB) and covariance of neighbours (*lead, NB - 1):
        the main and first off-diagonal of B^-1."""
        n = self.t.size
        var = np.empty(self.lead + (n,))
        cov = np.empty(self.lead + (max(n - 1, 0),))
        flat_v, flat_c = var.reshape(-1, n), cov.reshape(-1, max(n - 1, 0))
        for i, c in enumerate(self._factors):
            v, o = _banded_inverse_bands(c)
            flat_v[i], flat_c[i] = v, o
        return var, cov

    def whiten(self, v: np.ndarray) -> np.ndarray:
        """L_C^-1 v, with L_C the lower Cholesky factor of C in time order: the standardised Kalman innovations."""
        n = self.t.size
        s2 = self.sigma**2
        d = self.sd**2  # (*lead, NB)
        gain = np.empty_like(d)
        innov = np.empty_like(d)
        p = np.full(self.lead, s2)
        for b in range(n):
            if b:
                f = self.phi[b - 1]
                p = f * f * p + s2 * (1.0 - f * f)
            s = p + d[..., b]
            innov[..., b] = s
            gain[..., b] = p / s
            p = p * d[..., b] / s
        # predictions xp_0 = 0, xp_{b+1} = phi_{b+1} ((1 - K_b) xp_b + K_b v_b): a first-order recursion in xp
        shape = (n,) + (1,) * (v.ndim - len(self.lead) - 1)
        flat_v = self._flat(v)
        pred = np.zeros_like(flat_v, dtype=float)
        for i, g in enumerate(gain.reshape(-1, n)):
            rhs = np.zeros_like(flat_v[i], dtype=float)
            rhs[1:] = (self.phi * g[:-1]).reshape((n - 1,) + shape[1:]) * flat_v[i][:-1]
            pred[i] = recursion(self.phi * (1.0 - g[:-1]), rhs)
        out = (flat_v - pred) / np.sqrt(innov.reshape(-1, n)).reshape((-1,) + shape)
        return out.reshape(v.shape)


def _banded_inverse_bands(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Main and first off-diagonal of B^-1 from B's upper banded Cholesky factor c (2, n), B = U^T U.

    Takahashi's recursion for a bidiagonal U, from the last row up: Z = B^-1, Z_nn = 1 / u_nn^2,
    Z_{i,i+1} = -(u_{i,i+1} / u_ii) Z_{i+1,i+1}, Z_ii = 1 / u_ii^2 - (u_{i,i+1} / u_ii) Z_{i,i+1}."""
    n = c.shape[1]
    d = c[1]
    u = c[0, 1:]  # U[i, i+1]
    ratio = u / d[:-1]
    var = np.empty(n)
    off = np.empty(max(n - 1, 0))
    var[-1] = 1.0 / d[-1] ** 2
    for i in range(n - 2, -1, -1):
        off[i] = -ratio[i] * var[i + 1]
        var[i] = 1.0 / d[i] ** 2 - ratio[i] * off[i]
    return var, off


def bridge_weights(t: np.ndarray, tb: np.ndarray, tau: float) -> tuple[np.ndarray, ...]:
    """For times t (...,) among block times tb (NB,): the blocks before and after (a, b), and the weights of
    E[x(t) | x_a, x_b] = alpha x_a + beta x_b with its conditional variance in units of sigma^2.
    Before the first block only b counts (alpha 0), after the last only a (beta 0)."""
    n = tb.size
    b = np.searchsorted(tb, t, side="right")
    a = b - 1
    has_a, has_b = a >= 0, b < n
    ta = tb[np.clip(a, 0, n - 1)]
    tbb = tb[np.clip(b, 0, n - 1)]
    f1 = np.where(has_a, np.exp(-np.abs(t - ta) / tau), 0.0)
    f2 = np.where(has_b, np.exp(-np.abs(tbb - t) / tau), 0.0)
    den = 1.0 - (f1 * f2) ** 2
    both = has_a & has_b
    safe = np.where(both, den, 1.0)
    alpha = np.where(both, f1 * (1.0 - f2**2) / safe, f1)
    beta = np.where(both, f2 * (1.0 - f1**2) / safe, f2)
    cond = np.where(both, (1.0 - f1**2) * (1.0 - f2**2) / safe, 1.0 - np.maximum(f1, f2) ** 2)
    return np.clip(a, 0, n - 1), np.clip(b, 0, n - 1), alpha, beta, cond


def posterior_variance(blocks: GaussMarkovBlocks, t: np.ndarray) -> np.ndarray:
    """Var(x(t) | block rates) at times t (m,): (*lead, m), from the bridge of the two blocks around each time."""
    a, b, alpha, beta, cond = bridge_weights(t, blocks.t, blocks.tau)
    var, off = blocks.posterior_bands()
    n = blocks.t.size
    cross = off[..., np.minimum(a, max(n - 2, 0))] if n > 1 else np.zeros(blocks.lead + t.shape)
    cross = np.where(b == a + 1, cross, 0.0)
    return blocks.sigma**2 * cond + alpha**2 * var[..., a] + beta**2 * var[..., b] + 2.0 * alpha * beta * cross
