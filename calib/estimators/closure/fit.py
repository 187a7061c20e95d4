"""Weighted least squares over the closure model, shared by the single-recording and batch estimators.

Parameters theta of one recording: (k_x, k_y, k_z, b_x, b_y, b_z) for K = diag(k), and in the extended
model three more, (K_xy, K_xz, K_yz), the upper off-diagonal entries of K. The lower ones are fixed at
0: any K is a rotation times an upper-triangular matrix, and the rotation (the sensor frame's
orientation) is not observable without an external reference.

The residual vector of a recording stacks, each whitened to unit covariance:

- per turn j, the closing rotation vector r_j (closure_model), with the covariance that white reading
  noise gives it (linearised, so the sum of squares is the Gauss-Helmert approximation of the
  likelihood with the unknown hand trajectory profiled out);
- per still segment s of N_s samples, the mean reading against its model value:
  sqrt(N_s) (mean(m_s) + K^-1 b) / sigma, per axis (sigma: reading noise, from the stills).

Minimising the sum of squares is maximum likelihood; J^T J of the whitened Jacobian is the Fisher
information, whose inverse is the Cramer-Rao bound for the recording.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.estimators.closure.placement import HeadingSpread
from calib.numerics.gram import gram
from calib.numerics.rotation import ClosureTerms, closure_terms
from calib.numerics.windows import solve_lower
from calib.units import FULL_TURN_DEG

OFF_DIAGONAL: tuple[tuple[int, int], ...] = ((0, 1), (0, 2), (1, 2))


def n_params(extended: bool) -> int:
    """Number of parameters: 6 (diagonal K) or 9 (upper-triangular K)."""
    return 9 if extended else 6


def param_names(extended: bool) -> tuple[str, ...]:
    """Names of the entries of theta, in order."""
    names = ("k_x", "k_y", "k_z", "b_x", "b_y", "b_z")
    return names + ("K_xy", "K_xz", "K_yz") if extended else names


def calibration_matrix(theta: np.ndarray) -> np.ndarray:
    """K (R, 3, 3) from parameters theta (R, 6 or 9)."""
    R = theta.shape[0]
    K = np.zeros((R, 3, 3))
    K[:, [0, 1, 2], [0, 1, 2]] = theta[:, :3]
    if theta.shape[1] == 9:
        for p, (i, j) in enumerate(OFF_DIAGONAL):
            K[:, i, j] = theta[:, 6 + p]
    return K


@dataclass
class ClosureData:
    """The data of R recordings with J turns and S still segments each.

    ``m`` (n, R*J, 3): readings (deg/s) of each turn, time-first, turn j of recording r in column
    r*J + j, zero past the turn's end; ``dt`` (n, R*J) the interval each sample is held (s), 0 past
    the end. ``still_mean`` (R, S, 3) mean reading of each still (deg/s), ``still_n`` (R, S) its
    number of samples (0: absent). ``sigma`` (R, 3) reading noise std per axis (deg/s). ``place_target``
    (R, J, 3) rad and ``place_cov`` (R, J, 3, 3) rad^2: what each turn's closure is expected to be and the covariance
    the hand's placement adds to it (``calib.estimators.closure.placement``); None: put back exactly.
    """

    m: np.ndarray
    dt: np.ndarray
    still_mean: np.ndarray
    still_n: np.ndarray
    sigma: np.ndarray
    place_target: np.ndarray | None = None
    place_cov: np.ndarray | None = None

    @property
    def R(self) -> int:
        return int(self.still_mean.shape[0])

    @property
    def J(self) -> int:
        return int(self.m.shape[1] // self.R)

    @property
    def S(self) -> int:
        return int(self.still_mean.shape[1])

    def runs(self, idx: np.ndarray) -> ClosureData:
        """The data of a subset of the recordings."""
        seq = (np.asarray(idx)[:, None] * self.J + np.arange(self.J)).ravel()
        return ClosureData(self.m[:, seq], self.dt[:, seq], self.still_mean[idx], self.still_n[idx], self.sigma[idx],
                           None if self.place_target is None else self.place_target[idx],
                           None if self.place_cov is None else self.place_cov[idx])

    def dof(self, extended: bool) -> np.ndarray:
        """Degrees of freedom of the fit per recording: residuals minus parameters."""
        return 3 * self.J + 3 * (self.still_n > 0).sum(axis=1) - n_params(extended)


# --------------------------------------------------------------------------- start values


def bias_free_angles(data: ClosureData) -> tuple[np.ndarray, np.ndarray]:
    """Each turn's integrated reading less the rests' pooled mean reading beta, (R, J, 3) deg, and beta (R, 3) deg/s."""
    R, J = data.R, data.J
    w = data.still_n[..., None]
    beta = (data.still_mean * w).sum(axis=1) / np.maximum(w.sum(axis=1), 1.0)
    integ = np.einsum("tsi,ts->si", data.m, data.dt).reshape(R, J, 3)
    dur = data.dt.sum(axis=0).reshape(R, J)
    return integ - beta[:, None, :] * dur[..., None], beta


def start_values(data: ClosureData, extended: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Starting parameters from the stills and the per-turn integrated angles.

    With the raw offset beta = pooled still mean (m at rest = -K^-1 b), each turn's bias-compensated
    integrated reading a_j = sum (m_t - beta) dt_t is about K^-1 times its rotation vector, so
    sum_i k_i^2 a_ji^2 = (360 n_j)^2, with n_j = round(|a_j| / 360) >= 1 full turns: linear in k^2.
    Returns theta0 (R, P), the turn counts n_j (R, J) and the rank of the k^2 system per recording
    (3 when every axis is turned about).
    """
    R = data.R
    a, beta = bias_free_angles(data)
    turns = np.maximum(1.0, np.round(np.linalg.norm(a, axis=2) / FULL_TURN_DEG))
    A = a * a  # (R, J, 3)
    y = (FULL_TURN_DEG * turns) ** 2
    # scale the columns so that the rank test is about directions, not about magnitudes
    AtA = np.einsum("rji,rjk->rik", A, A)
    Aty = np.einsum("rji,rj->ri", A, y)
    scale = np.sqrt(np.maximum(np.einsum("rii->ri", AtA), 1e-300))
    N = AtA / (scale[:, :, None] * scale[:, None, :])
    ev = np.linalg.eigvalsh(N)
    rank = (ev > 1e-6 * np.maximum(ev[:, -1:], 1e-300)).sum(axis=1)
    k2 = np.full((R, 3), np.nan)
    ok = rank == 3
    if ok.any():
        k2[ok] = np.linalg.solve(N[ok], (Aty / scale)[ok][..., None])[..., 0] / scale[ok]
    k = np.sqrt(np.where(k2 > 0, k2, np.nan))
    theta = np.zeros((R, n_params(extended)))
    theta[:, :3] = k
    theta[:, 3:6] = -k * beta
    return theta, turns, rank


# --------------------------------------------------------------------------- whitened system


@dataclass
class System:
    """Whitened residuals (R, M) and Jacobian (R, M, P) of R recordings at theta, with the turn weights."""

    res: np.ndarray
    jac: np.ndarray | None
    chol: np.ndarray  # (R, J, 3, 3) lower Cholesky factors of the closure covariances (rad^2)
    terms: ClosureTerms

    @property
    def J(self) -> np.ndarray:
        """The Jacobian (the system must have been built with jacobian=True)."""
        if self.jac is None:
            raise ValueError("this system was built without its Jacobian (jacobian=False)")
        return self.jac


def system(
    data: ClosureData,
    theta: np.ndarray,
    extended: bool,
    chol: np.ndarray | None = None,
    jacobian: bool = True,
) -> System:
    """Residuals (and Jacobian) at theta (R, P). Turn weights come from ``chol`` or are computed at theta."""
    K = calibration_matrix(theta)
    J = data.J
    terms = closure_terms(
        data.m,
        data.dt,
        np.repeat(K, J, axis=0),
        np.repeat(theta[:, 3:6], J, axis=0),
        sigma=np.repeat(data.sigma, J, axis=0) if chol is None else None,
        jacobian=jacobian or chol is None,
    )
    return assemble(data, theta, extended, terms, chol, jacobian)


def assemble(data: ClosureData, theta: np.ndarray, extended: bool, terms: ClosureTerms, chol: np.ndarray | None = None,
             jacobian: bool = True) -> System:
    """The whitened system at theta from its turns' closure ``terms`` (those of the same K and b: a diagonal fit's serve
    the extended model at zero non-orthogonality). Turn weights from ``chol``, else from ``terms.noise``."""
    R, J, S = data.R, data.J, data.S
    P = n_params(extended)
    K = calibration_matrix(theta)
    b = theta[:, 3:6]
    if chol is None:
        assert terms.noise is not None  # asked for with sigma
        cov = terms.noise.reshape(R, J, 3, 3)
        chol = np.linalg.cholesky(cov if data.place_cov is None else cov + data.place_cov)
    r = terms.r.reshape(R, J, 3)
    if data.place_target is not None:
        r = r - data.place_target
    res_turn = solve_lower(chol, r[..., None])[..., 0]

    Kinv = np.linalg.inv(K)
    beta = np.einsum("rij,rj->ri", Kinv, b)  # the reading at rest is -beta
    wstill = np.sqrt(data.still_n)[..., None] / data.sigma[:, None, :]  # (R, S, 3)
    res_still = wstill * (data.still_mean + beta[:, None, :])
    res = np.concatenate((res_turn.reshape(R, 3 * J), res_still.reshape(R, 3 * S)), axis=1)
    if not jacobian:
        return System(res, None, chol, terms)

    assert terms.dK is not None and terms.db is not None  # asked for with jacobian
    dK = terms.dK.reshape(R, J, 3, 3, 3)
    jt = np.empty((R, J, 3, P))
    jt[..., 0:3] = np.stack([dK[..., i, i] for i in range(3)], axis=-1)
    jt[..., 3:6] = terms.db.reshape(R, J, 3, 3)
    # d beta / d theta: d(K^-1 b)/db = K^-1, d(K^-1 b)/dK_ij = -K^-1[:, i] beta_j
    dbeta = np.empty((R, 3, P))
    for i in range(3):
        dbeta[:, :, i] = -Kinv[:, :, i] * beta[:, i, None]
    dbeta[:, :, 3:6] = Kinv
    if extended:
        for p, (i, j) in enumerate(OFF_DIAGONAL):
            jt[..., 6 + p] = dK[..., i, j]
            dbeta[:, :, 6 + p] = -Kinv[:, :, i] * beta[:, j, None]
    jac_turn = solve_lower(chol, jt)
    jac_still = wstill[..., None] * dbeta[:, None, :, :]  # (R, S, 3, P)
    jac = np.concatenate((jac_turn.reshape(R, 3 * J, P), jac_still.reshape(R, 3 * S, P)), axis=1)
    return System(res, jac, chol, terms)


# --------------------------------------------------------------------------- batched Gauss-Newton


@dataclass
class BatchFit:
    """Solutions of R recordings: theta (R, P), Fisher information (R, P, P), chi-square, iterations."""

    theta: np.ndarray
    fisher: np.ndarray
    chi2: np.ndarray
    dof: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    closure: np.ndarray  # (R, J, 3) closing rotation vectors at the solution (rad)


def gauss_newton(
    data: ClosureData,
    theta0: np.ndarray,
    extended: bool,
    max_iter: int = 8,
    tol: float = 1e-4,
) -> BatchFit:
    """Gauss-Newton for R recordings at once, each with its own normal equations.

    The weights are recomputed at each iterate. A recording stops when every step is below ``tol``
    times that parameter's standard error; its chi-square and closure are then extrapolated linearly
    to the final step, which is negligible by then.
    """
    R = data.R
    P = n_params(extended)
    theta = theta0.copy()
    fisher = np.full((R, P, P), np.nan)
    chi2 = np.full(R, np.nan)
    closure = np.full((R, data.J, 3), np.nan)
    iterations = np.zeros(R, dtype=np.int64)
    converged = np.zeros(R, dtype=bool)
    active = np.flatnonzero(np.all(np.isfinite(theta), axis=1))
    for it in range(1, max_iter + 1):
        if active.size == 0:
            break
        sub = data.runs(active)
        sys_ = system(sub, theta[active], extended)
        A = gram(sys_.J)
        g = np.einsum("rmp,rm->rp", sys_.J, sys_.res)
        try:
            step = -np.linalg.solve(A, g[..., None])[..., 0]
            cov = np.linalg.inv(A)
        except np.linalg.LinAlgError:
            step = np.full_like(g, np.nan)
            cov = np.full_like(A, np.nan)
            for i in range(active.size):
                try:
                    step[i] = -np.linalg.solve(A[i], g[i])
                    cov[i] = np.linalg.inv(A[i])
                except np.linalg.LinAlgError:
                    pass
        theta[active] += step
        iterations[active] = it
        std = np.sqrt(np.abs(np.einsum("rpp->rp", cov)))
        done = np.all(np.abs(step) <= tol * std, axis=1) | ~np.all(np.isfinite(step), axis=1)
        if it == max_iter:
            done[:] = True
        fin = active[done]
        if fin.size:
            lin = sys_.res[done] + np.einsum("rmp,rp->rm", sys_.J[done], step[done])
            fisher[fin] = A[done]
            chi2[fin] = np.einsum("rm,rm->r", lin, lin)
            converged[fin] = np.all(np.abs(step[done]) <= tol * std[done], axis=1)
            r_lin = sys_.terms.r.reshape(-1, data.J, 3)[done]
            jt = _unwhiten_turn_jac(sys_, done, data.J)
            closure[fin] = r_lin + np.einsum("rjap,rp->rja", jt, step[done])
        active = active[~done]
    bad = ~np.all(np.isfinite(theta), axis=1)
    theta[bad] = np.nan
    return BatchFit(theta, fisher, chi2, data.dof(extended), iterations, converged & ~bad, closure)


def _unwhiten_turn_jac(sys_: System, rows: np.ndarray, J: int) -> np.ndarray:
    """dr/dtheta (R', J, 3, P) of the selected recordings, from the whitened Jacobian."""
    jac = sys_.J[rows][:, : 3 * J].reshape(-1, J, 3, sys_.J.shape[2])
    return np.einsum("rjab,rjbp->rjap", sys_.chol[rows], jac)


@dataclass
class ClosureFit:
    """A solved closure fit: parameters, whitened residuals, Fisher information and what the turns did at the solution."""

    theta: np.ndarray
    res: np.ndarray
    fisher: np.ndarray
    terms: ClosureTerms  # the turns' closure terms at the solution (their Jacobian and noise included)
    chol: np.ndarray  # (J, 3, 3)
    nfev: int
    converged: bool
    not_turned: np.ndarray | None = None  # (3,) axes no turn was about: their k had a prior, and is not determined
    priors: int = 0  # rows of prior knowledge among the residuals: each one observation more
    heading: HeadingSpread | None = None  # the heading spread learned with the fit (None: stated or default)

    @property
    def terms_r(self) -> np.ndarray:
        """(J, 3) closing rotation vectors at the solution, rad."""
        return self.terms.r

    @property
    def swept(self) -> np.ndarray:
        """(J, 3) integrated calibrated rate per turn, deg."""
        return self.terms.swept


@dataclass(frozen=True, eq=False)
class KPrior:
    """What is known of K besides the recording: a normal prior on each entry on and above its diagonal, of ``mean``
    and ``std`` (3, 3) (an infinite std: nothing known of that entry). A kit knows its sensors' non-orthogonalities
    average zero, and each wearable's K from the others'."""

    mean: np.ndarray
    std: np.ndarray

    @property
    def extended(self) -> bool:
        """Whether it knows something of an entry above the diagonal (the extended model's terms)."""
        return any(np.isfinite(self.std[i, j]) for i, j in OFF_DIAGONAL)

    def rows(self, extended: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(indices into theta, means, stds) of the entries it knows, of the diagonal or the ``extended`` model's."""
        entries = [((i, i), i) for i in range(3)] + ([((i, j), 6 + p) for p, (i, j) in enumerate(OFF_DIAGONAL)] if extended else [])
        known = [(index, float(self.mean[ij]), float(self.std[ij])) for ij, index in entries
                 if np.isfinite(self.std[ij]) and self.std[ij] > 0]
        return (np.array([k[0] for k in known], dtype=int), np.array([k[1] for k in known]), np.array([k[2] for k in known]))
