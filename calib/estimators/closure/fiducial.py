"""Each parameter's interval where the heading spread is learned from few turns: a generalized pivotal quantity.

The fit's estimate, at the weights it used, is linear in the turns' errors, so each parameter's error has variance
a + b tau^2 at heading spread tau (the sandwich of the fit's gain with the turns' covariance B_j + tau^2 u_j u_j^T;
b comes from every turn with a measured vertical, the one about the vertical included). The turns that show their
heading leave, once the parameters are fitted, vertical residuals v whose covariance is S0 + tau^2 S1, so that at
the true spread q(tau^2) = v^T (S0 + tau^2 S1)^-1 v scatters as chi^2 with d (their number) degrees of freedom. For
each chi^2_d quantile U the spread solving q = U is a draw of what the recording says of tau^2 (Weerahandi's
generalized pivot; below 0 where they closed better than their noise says, down to where S0 + tau^2 S1 stops being a
covariance, and a draw that takes a parameter's variance below 0 leaves that parameter no error), and the interval's
half-width w holds ``level`` of the errors averaged over those draws: mean over U of P(|N(0, max(a + b tau^2(U), 0))|
<= w) = level. Cut short at the least the REML's own estimate may take (-0.9 times the least vertical noise variance
of a turn), the pivot held 96.8-97.5 % where the hand puts the device back exactly (2,000 recordings a setting).

Where every turn's noise is alike it is Student's prediction interval for a third closure from two seen, whatever the
spread and the noise; it errs wide where k_z's own noise is the larger, narrow where it is the smaller. On the heading
benchmark (bench/heading.py, 40 settings of 2,000 recordings) k_z's interval holds 94.2-95.8 % of the truths where the
hand turns the device as it puts it back and 96.0-96.6 % where it puts it back exactly (docs/benchmarks.md).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import eigh

from calib.distributions import chi2_isf, norm_sf
from calib.units import DEG

DRAWS = 400  # chi^2_d quantiles averaged over
# the positive spreads tried, deg^2: far beyond any hand's, as the few turns' smallest quantiles draw spreads many times
# the one they show
_POSITIVE = np.geomspace(1e-3, 90.0, 72) ** 2
# the spreads below 0 tried, as fractions of the way to the least there can be: dense where q rises steeply
_TOWARDS_LEAST = np.geomspace(1e-4, 0.98, 40)


def fiducial_halfwidths(r: np.ndarray, A: np.ndarray, C: np.ndarray, B: np.ndarray, up: np.ndarray,
                        measured: np.ndarray, shows: np.ndarray, fixed_res: np.ndarray, fixed_jac: np.ndarray,
                        level: float = 0.95) -> np.ndarray:
    """Each parameter's interval half-width (P,) at ``level``.

    ``r`` (J, 3) and ``A`` (J, 3, P): the turns' residuals (rad) and Jacobian; ``C`` (J, 3, 3): their covariances the
    fit weighed them by; ``B`` (J, 3, 3): their covariance without the heading; ``up`` (J, 3): each turn's vertical;
    ``measured`` (J,): the turns whose vertical is known (they carry the spread); ``shows`` (J,): those showing their
    heading; ``fixed_res`` (M,), ``fixed_jac`` (M, P): the other rows, whitened.
    """
    J, _, P = A.shape
    M = fixed_res.size
    W = np.zeros((3 * J + M, 3 * J + M))
    Sigma0, Sigma1 = np.zeros_like(W), np.zeros_like(W)
    U = up[:, :, None] * up[:, None, :]
    for j in range(J):
        block = slice(3 * j, 3 * j + 3)
        W[block, block] = np.linalg.inv(C[j])
        Sigma0[block, block] = B[j] if measured[j] else C[j]
        Sigma1[block, block] = U[j] if measured[j] else 0.0
    W[3 * J :, 3 * J :] = Sigma0[3 * J :, 3 * J :] = np.eye(M)
    X = np.vstack((A.reshape(3 * J, P), fixed_jac))
    gain = np.linalg.solve(X.T @ W @ X, X.T @ W)  # (P, N): the parameters' step from the rows' errors
    a = np.einsum("pn,nm,pm->p", gain, Sigma0, gain)
    b = np.einsum("pn,nm,pm->p", gain, Sigma1, gain)
    pick = np.zeros((int(shows.sum()), 3 * J + M))
    for i, turn in enumerate(np.flatnonzero(shows)):
        pick[i, 3 * turn : 3 * turn + 3] = up[turn]
    T = pick @ (np.eye(3 * J + M) - X @ gain)  # the shown verticals' residuals from the rows' errors
    v = pick @ np.concatenate((r.ravel(), fixed_res))
    S0, S1 = T @ Sigma0 @ T.T, T @ Sigma1 @ T.T
    tau2 = np.concatenate((_least(S0, S1, B[measured], up[measured]) * (1.0 - _TOWARDS_LEAST), [0.0],
                           _POSITIVE * DEG**2))
    S = S0[None] + tau2[:, None, None] * S1[None]
    valid = np.all(np.linalg.eigvalsh(S) > 0, axis=1)
    tau2, S = tau2[valid], S[valid]
    q = np.einsum("a,gab,b->g", v, np.linalg.inv(S), v)
    log_q = np.minimum.accumulate(np.log(np.maximum(q, 1e-300)))  # decreasing in tau^2
    d = pick.shape[0]
    draws = chi2_isf(1.0 - (np.arange(DRAWS) + 0.5) / DRAWS, d)
    spread = np.interp(np.log(draws), log_q[::-1], tau2[::-1], left=tau2[-1], right=tau2[0])  # q(spread) = draw
    # a spread below 0 that takes a parameter's variance below 0 leaves it none: that draw's error is 0
    sd = np.sqrt(np.maximum(a[None] + spread[:, None] * b[None], 1e-300))  # (DRAWS, P)
    return _holding(sd, level)


def _least(S0: np.ndarray, S1: np.ndarray, B: np.ndarray, up: np.ndarray) -> float:
    """The least tau^2 (< 0) where the shown verticals' covariance S0 + tau^2 S1 is still one: -1 / the largest
    eigenvalue of S1 against S0; where no spread moves them (or S0 is singular), minus the least vertical noise
    variance of a turn."""
    try:
        largest = float(eigh(S1, S0, eigvals_only=True)[-1]) if S0.size else 0.0
    except np.linalg.LinAlgError:
        largest = 0.0
    if largest > 0:
        return -1.0 / largest
    return -float(np.min(np.einsum("ja,jab,jb->j", up, B, up)))


def _holding(sd: np.ndarray, level: float) -> np.ndarray:
    """The w (P,) with mean over draws of P(|N(0, sd^2)| <= w) = ``level``, for each column of ``sd`` (D, P).

    That share is concave and increasing in w, so Newton's steps from w = 0 climb to it from below without passing it.
    """
    w = np.zeros(sd.shape[1])
    for _ in range(100):
        z = w[None] / sd
        held = np.mean(1.0 - 2.0 * norm_sf(z), axis=0)
        with np.errstate(over="ignore"):  # a draw with no error: its density is 0 at every w > 0
            slope = np.mean(np.sqrt(2.0 / np.pi) * np.exp(-0.5 * z**2) / sd, axis=0)
        step = (level - held) / np.maximum(slope, 1e-300)
        w = w + np.maximum(step, 0.0)
        if np.all(step <= 1e-12 * w):
            break
    return w
