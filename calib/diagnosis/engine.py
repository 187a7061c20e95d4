"""Whitened residuals, Jacobians and fits of the nominal and extended models, for R recordings at once.

The residual vector of a recording stacks, each whitened to unit variance under the nominal model:

- ``closure`` (3 per turn): the closing rotation r_j = Log(prod_t Exp(w_t dt_t)) of each turn (deg),
  minus the placement rotation rho_j when that effect is modelled, weighted by the covariance white
  reading noise gives it (as in calib.estimators.closure.fit);
- ``still`` (3 per still block): the calibrated mean rate of each still block (deg/s), 0 at rest,
  weighted by k_i sigma_i / sqrt(N_block); the blocks carry the still means over time and whether the
  noise inside each still is white;
- ``tilt`` (2 per turn, with an accelerometer): the tilt across the turn measured from gravity minus
  the modelled one (deg), weighted by the accelerometer noise;
- for a **re-orientation** (a motion between rests that ends in a new pose) the rotation about gravity
  is unobservable: its closing rotation r_j (against the layout's reference rotation) is free in the
  direction of gravity, so its 3 closure rows are left empty and its 2 tilt rows hold the gravity the
  calibrated gyro carries against the accelerometer's, t_j - P_j r_j, weighted by the accelerometer
  noise plus P_j cov(r_j) P_j^T (the closure rows with a free rotation profiled out, exactly);
- ``prior`` rows of an effect (the heading of a placement error, the height of a clipped plateau).

The calibrated rate w_t and its Jacobian come from ``Model.rate``; the closing rotations and their
Jacobians from one vectorised pass per turn (same algebra as calib.numerics.rotation, with an arbitrary
design). Minimising the sum of squares (plus the log-determinant of a variance model) is maximum
likelihood; its value is the fit statistic ("deviance"; lower is better).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial.transform import Rotation

from calib.diagnosis.data import Problem
from calib.diagnosis.markov import GaussMarkovBlocks, bridge_weights
from calib.diagnosis.models import Model
from calib.numerics.quaternion import hamilton
from calib.numerics.rotation import left_jacobian, left_jacobian_inv, prefix_products
from calib.numerics.windows import solve_lower
from calib.units import DEG

_IDENTITY_Q = np.array([0.0, 0.0, 0.0, 1.0])
_CHUNK = 2_500_000  # elements of the (L, B, 3, P) Jacobian processed at once


@dataclass
class Closure:
    r: np.ndarray  # (B, 3) closing rotation vectors, deg
    jac: np.ndarray  # (B, 3, Pr) deg per parameter
    noise: np.ndarray  # (B, 3, 3) covariance from white reading noise, deg^2
    swept: np.ndarray  # (B, 3) integrated calibrated rate, deg


def closure_pass(model: Model, psi_cols: np.ndarray, prob: Problem, sigma_cols: np.ndarray, jacobian: bool = True) -> Closure:
    """Closing rotations of the R*J turns at parameters psi_cols (R*J, P), with Jacobian and noise covariance."""
    B = prob.dt.shape[1]
    Pr = model.rate_params.size
    lay = prob.layout
    ref = None
    if lay.ref is not None and lay.J:
        # closing rotations against each window's reference A: Log(A^T prod Exp(w dt)), A^T first in every product
        inv = lay.ref * [-1.0, -1.0, -1.0, 1.0]
        ref = np.tile(inv, (prob.R, 1))
    out: Closure | None = None
    for cols, length in _length_groups(prob.dt, 3 * max(Pr, 9)):
        part = _pass_chunk(model, psi_cols[cols], prob.turn.turn_first(cols, length), prob.dt[:length, cols],
                           sigma_cols[cols], jacobian, None if ref is None else ref[cols])
        if out is None:
            out = Closure(*(np.empty((B,) + getattr(part, f).shape[1:]) for f in ("r", "jac", "noise", "swept")))
        for f in ("r", "jac", "noise", "swept"):
            getattr(out, f)[cols] = getattr(part, f)
    if out is None:  # no turn
        return Closure(np.zeros((0, 3)), np.zeros((0, 3, Pr)), np.zeros((0, 3, 3)), np.zeros((0, 3)))
    return out


def _length_groups(dt: np.ndarray, per_sample: int) -> list[tuple[np.ndarray | slice, int]]:
    """The turn columns of ``dt`` (L, B) in groups, each with the samples its longest turn needs and no larger than
    ``_CHUNK`` elements of ``per_sample`` each a sample. Turns padded to the longest (a re-orientation of 8 s beside
    ones of 1 s) cost most of a pass in samples that add nothing, so turns of unlike lengths are grouped by length
    (within a factor 1.5); turns of like lengths stay in their order, as slices (views, not copies)."""
    L, B = dt.shape
    moving = dt > 0
    lengths = np.where(moving.any(axis=0), L - np.argmax(moving[::-1], axis=0), 1)
    order = np.argsort(lengths, kind="stable")
    groups: list[tuple[np.ndarray, int]] = []
    i = 0
    while i < B:
        shortest = lengths[order[i]]
        j = i + 1
        while j < B and lengths[order[j]] <= 1.5 * shortest and (j + 1 - i) * lengths[order[j]] * per_sample <= _CHUNK:
            j += 1
        cols = np.sort(order[i:j])
        groups.append((cols, int(lengths[order[j - 1]])))
        i = j
    if sum(int(c.size) * n for c, n in groups) > 0.75 * L * B:  # little padding to save: copies would cost more
        step = max(1, _CHUNK // max(1, L * per_sample))
        return [(slice(s, min(B, s + step)), L) for s in range(0, B, step)]
    return [(slice(int(c[0]), int(c[-1]) + 1) if c[-1] - c[0] + 1 == c.size else c, n) for c, n in groups]


def _pass_chunk(model, psi, inp, dt, sigma, jacobian, ref_inv=None) -> Closure:
    """``inp`` turn first (B, L); ``dt`` time first (L, B)."""
    L, B = dt.shape
    w, dw = model.rate(psi[:, None], inp, jacobian=True)  # (B, L, 3), (B, L, 3, Pr)
    w = w.transpose(1, 0, 2)
    wdt = dt * DEG
    u = w * wdt[..., None]
    swept = u.sum(axis=0) / DEG
    q = Rotation.from_rotvec(u.reshape(-1, 3)).as_quat()
    q = np.ascontiguousarray(q.T).reshape(4, L, B)
    att = prefix_products(q)
    first = np.broadcast_to(_IDENTITY_Q[:, None], (4, B))
    if ref_inv is not None:
        first = np.ascontiguousarray(ref_inv.T)
        att = hamilton(np.broadcast_to(first[:, None], att.shape), att)
    r = Rotation.from_quat(att[:, L - 1].T).as_rotvec()
    prev = np.empty_like(att)
    prev[:, 0] = first
    prev[:, 1:] = att[:, :-1]
    C = Rotation.from_quat(prev.reshape(4, -1).T).as_matrix().reshape(L, B, 3, 3)
    Hw = np.matmul(C, left_jacobian(u))
    Hw *= wdt[..., None, None]  # rad per (deg/s) of rate at sample t, before J_l(r)^-1
    jinv = left_jacobian_inv(r)
    # sums over samples as batched matrix products: (B, 3, 3L) @ (B, 3L, P)
    Hb = np.ascontiguousarray(Hw.transpose(1, 2, 0, 3)).reshape(B, 3, 3 * L)
    Db = dw.reshape(B, 3 * L, -1)  # turn first already: a view when the model made it contiguous
    jac = np.matmul(jinv, np.matmul(Hb, Db)) / DEG
    # reading noise enters the rate through dw/dm ~ K: cov of the rate noise is K diag(sigma^2) K^T
    k = psi[:, 0:3]
    Hs = Hb * np.tile(np.abs(k * sigma), (1, L))[:, None, :]  # Hb's columns run (sample, axis)
    G = np.matmul(Hs, Hs.transpose(0, 2, 1))
    noise = np.matmul(np.matmul(jinv, G), jinv.transpose(0, 2, 1)) / DEG**2
    return Closure(r / DEG, jac, noise, swept)


@dataclass
class Priors:
    """Pseudo-observations: rows (target - psi[idx]) / sd, per recording."""

    idx: np.ndarray  # (Q,) parameter indices
    target: np.ndarray  # (R, Q)
    sd: np.ndarray  # (R, Q)
    coef: np.ndarray | None = None  # (R, Q, P): rows coef . psi instead of psi[idx] when given


@dataclass
class System:
    res: np.ndarray  # (R, M) whitened residuals
    jac: np.ndarray | None  # (R, M, P)
    blocks: dict[str, slice]
    closure: Closure
    chol: np.ndarray  # (R, J, 3, 3) closure covariance factors, deg
    logdet: np.ndarray  # (R,) extra log-determinant of a variance model (0 for the nominal covariance)

    @property
    def J(self) -> np.ndarray:
        """The Jacobian (the system must have been built with jacobian=True)."""
        if self.jac is None:
            raise ValueError("this system was built without its Jacobian (jacobian=False)")
        return self.jac

    def deviance(self) -> np.ndarray:
        return np.einsum("rm,rm->r", self.res, self.res) + self.logdet


@dataclass
class Variance:
    """Extra covariance in true-rate units: a Gauss-Markov process through the still blocks and closures."""

    still: tuple[float, float] | None = None  # (sigma deg/s, tau s) of a Gauss-Markov bias seen by the still blocks
    closure: np.ndarray | None = None  # (R, J, 3, 3)
    turn_bias: np.ndarray | None = None  # (R, J) variance (deg/s)^2 of a bias offset common to each turn
    turn_path: Wander | None = None  # the expected bias wander at each turn sample from the still block rates


@dataclass
class Wander:
    """The expected bias wander at every turn sample given the still block rates: the process smoothed at the
    block times, bridged between the two blocks around each sample (calib.diagnosis.markov)."""

    blocks: GaussMarkovBlocks  # the process and the blocks' white noise, (R, 3) of them
    times: np.ndarray  # (L, J) turn sample times

    def __post_init__(self) -> None:
        a, b, alpha, beta, _ = bridge_weights(self.times, self.blocks.t, self.blocks.tau)
        rows = np.arange(a.size)
        nb = self.blocks.t.size
        # two blocks per turn sample: the bridge as a sparse (L*J, NB) matrix
        self._bridge = csr_matrix((np.concatenate((alpha.ravel(), beta.ravel())),
                                   (np.concatenate((rows, rows)), np.concatenate((a.ravel(), b.ravel())))),
                                  shape=(a.size, nb))

    def offsets(self, e: np.ndarray, de: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The wander x (L, R*J, 3) at the turn samples and its derivative (L, R*J, 3, Pr), from the still block
        rates e (R, NB, 3) and their derivatives de (R, NB, 3, Pr). A rest's calibrated rate K m + b is -x (its true
        rate is 0), so the wander is minus the rates' expected path."""
        R, NB, Pr = e.shape[0], e.shape[1], de.shape[-1]
        L, J = self.times.shape
        v = np.concatenate((e[..., None], de), axis=3).transpose(0, 2, 1, 3)  # (R, 3, NB, 1 + Pr)
        xs = self.blocks.smooth(v)
        cols = np.ascontiguousarray(xs.transpose(2, 0, 1, 3)).reshape(NB, -1)  # blocks first
        out = (self._bridge @ cols).reshape(L, J, R, 3, 1 + Pr).transpose(0, 2, 1, 3, 4).reshape(L, R * J, 3, 1 + Pr)
        return -out[..., 0], -out[..., 1:]


def system(
    prob: Problem,
    model: Model,
    psi: np.ndarray,
    priors: Priors | None = None,
    variance: Variance | None = None,
    chol: np.ndarray | None = None,
) -> System:
    """Whitened residuals and Jacobian of R recordings at psi (R, P)."""
    R, J, NB = prob.R, prob.J, prob.NB
    P = model.P
    ridx = model.rate_params
    psi_cols = np.repeat(psi, J, axis=0)
    sig_cols = np.repeat(prob.sigma, J, axis=0)
    blocks: dict[str, slice] = {}
    move_terms = None
    res_parts, jac_parts = [], []
    logdet = np.zeros(R)
    pos = 0

    # still block rates (needed by the closures when a wandering bias links the two)
    e, de = model.rate(psi[:, None, :], prob.block)
    djs = np.zeros((R, NB, 3, P))
    djs[..., ridx] = de

    # closures
    if J:
        turn_prob = prob
        if variance is not None and variance.turn_path is not None:
            # the bias wander the still blocks imply, carried through each turn as an added rate
            from dataclasses import replace as _replace

            o, do = variance.turn_path.offsets(e, djs[..., ridx])
            turn_prob = _replace(prob, turn=_replace(prob.turn, offset=o, doffset=do))
        cl = closure_pass(model, psi_cols, turn_prob, sig_cols)
        r = cl.r.reshape(R, J, 3)
        jt = np.zeros((R, J, 3, P))
        jt[..., ridx] = cl.jac.reshape(R, J, 3, -1)
        offsets = model.closure_offsets()
        if offsets:
            r = r.copy()
            for j, s, B in offsets:
                q = B.shape[1]
                r[:, j] -= psi[:, s : s + q] @ B.T
                jt[:, j, :, s : s + q] -= B
        cov = cl.noise.reshape(R, J, 3, 3)
        extra_cov = variance is not None and (variance.closure is not None or variance.turn_bias is not None)
        if variance is not None and variance.closure is not None:
            cov = cov + variance.closure
        if variance is not None and variance.turn_bias is not None:
            Jb = jt[..., 3:6]  # closure per deg/s of bias, (R, J, 3, 3)
            cov = cov + variance.turn_bias[..., None, None] * np.matmul(Jb, Jb.transpose(0, 1, 3, 2))
        moves = prob.layout.moves
        if chol is None:
            chol = np.linalg.cholesky(cov)
            if extra_cov:
                base = np.linalg.cholesky(cl.noise.reshape(R, J, 3, 3))
                ld = 2.0 * (np.log(np.einsum("rjii->rji", chol)) - np.log(np.einsum("rjii->rji", base)))
                logdet += ld[:, ~moves].sum(axis=(1, 2))
        zc = solve_lower(chol, r[..., None])[..., 0]
        jc = solve_lower(chol, jt)
        if moves.any():
            # a re-orientation's closure is free about gravity: its evidence is in the tilt rows below
            zc[:, moves] = 0.0
            jc[:, moves] = 0.0
            move_terms = (r[:, moves], jt[:, moves], cov[:, moves], cl.noise.reshape(R, J, 3, 3)[:, moves], extra_cov)
        res_parts.append(zc.reshape(R, 3 * J))
        jac_parts.append(jc.reshape(R, 3 * J, P))
        blocks["closure"] = slice(0, 3 * J)
        pos = 3 * J
    else:
        cl = Closure(np.zeros((0, 3)), np.zeros((0, 3, ridx.size)), np.zeros((0, 3, 3)), np.zeros((0, 3)))
        chol = np.zeros((R, 0, 3, 3))

    # still blocks
    k = psi[:, 0:3]
    sd = np.abs(k)[:, None, :] * prob.sigma[:, None, :] / np.sqrt(prob.block_n)[None, :, None]  # (R, NB, 3)
    if variance is not None and variance.still is not None:
        # white noise plus the Gauss-Markov process, per axis: whitened in time order by the Kalman filter
        gm = GaussMarkovBlocks(prob.block.t[0], *variance.still, np.moveaxis(sd, 2, 1))
        rhs = np.concatenate((np.moveaxis(e, 2, 1)[..., None], np.moveaxis(djs, 2, 1), np.ones((R, 3, NB, 1))), axis=3)
        sol = gm.whiten(rhs)
        we, wj, w1 = sol[..., :1], sol[..., 1:-1], sol[..., -1]
        res_parts.append(np.moveaxis(we[..., 0], 1, 2).reshape(R, 3 * NB))
        jac_parts.append(np.moveaxis(wj, 1, 2).reshape(R, 3 * NB, P))
        logdet += (gm.logdet() - 2.0 * np.log(np.moveaxis(sd, 2, 1)).sum(axis=2)).sum(axis=1)
        # restricted likelihood: each axis' constant (the bias) integrated out, so that a variance it absorbs costs nothing
        logdet += (np.log(np.einsum("rib,rib->ri", w1, w1)) - np.log(np.sum(1.0 / sd**2, axis=1))).sum(axis=1)
    else:
        res_parts.append((e / sd).reshape(R, 3 * NB))
        jac_parts.append((djs / sd[..., None]).reshape(R, 3 * NB, P))
    blocks["still"] = slice(pos, pos + 3 * NB)
    pos += 3 * NB

    # tilt across turns (accelerometer)
    if prob.tilt is not None and J:
        tl = prob.tilts()
        sdt = np.where(np.isfinite(tl.sd), tl.sd, np.inf)[..., None]  # (R, J, 1)
        y = tl.tilt.copy()
        jtilt = np.zeros((R, J, 2, P))
        if "placement_error" in model.slices:
            s = model.slices["placement_error"].start
            rho = psi[:, s : s + 3 * J].reshape(R, J, 3)
            y = y - np.einsum("rjci,rji->rjc", tl.basis, rho)
            for j in range(J):
                jtilt[:, j, :, s + 3 * j : s + 3 * j + 3] = -tl.basis[:, j]
        zt, jzt = y / sdt, jtilt / sdt[..., None]
        if move_terms is not None:
            zt, jzt, ld = _gravity_rows(zt, jzt, tl, prob.layout.moves, move_terms)
            logdet += ld
        res_parts.append(zt.reshape(R, 2 * J))
        jac_parts.append(jzt.reshape(R, 2 * J, P))
        blocks["tilt"] = slice(pos, pos + 2 * J)
        pos += 2 * J

    if priors is not None and priors.idx.size:
        Q = priors.idx.size
        if priors.coef is not None:
            val = np.einsum("rqp,rp->rq", priors.coef, psi)
            jp = -priors.coef / priors.sd[..., None]
        else:
            val = psi[:, priors.idx]
            jp = np.zeros((R, Q, P))
            jp[:, np.arange(Q), priors.idx] = -1.0 / priors.sd
        res_parts.append((priors.target - val) / priors.sd)
        jac_parts.append(jp)
        blocks["prior"] = slice(pos, pos + Q)
        pos += Q

    res = np.concatenate(res_parts, axis=1)
    jac = np.concatenate(jac_parts, axis=1)
    return System(res, jac, blocks, cl, chol, logdet)


def _gravity_rows(zt: np.ndarray, jzt: np.ndarray, tl, moves: np.ndarray, terms) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tilt rows of the re-orientations: the measured tilt t minus the closing rotation r's components
    across gravity (P r), whitened by the accelerometer's variance plus P cov(r) P^T; and the extra
    log-determinant of a variance model beyond the white noise's."""
    r, jt, cov, noise, extra = terms
    Pm = tl.basis[:, moves]  # (R, M, 2, 3)
    sd = tl.sd[:, moves]
    y = tl.tilt[:, moves] - np.einsum("rmci,rmi->rmc", Pm, r)
    jy = -np.einsum("rmci,rmip->rmcp", Pm, jt)
    PT = Pm.transpose(0, 1, 3, 2)
    acc = np.einsum("rm,cd->rmcd", sd**2, np.eye(2))
    C = acc + Pm @ cov @ PT
    Lc = np.linalg.cholesky(C)
    zt, jzt = zt.copy(), jzt.copy()
    zt[:, moves] = np.linalg.solve(Lc, y[..., None])[..., 0]
    jzt[:, moves] = np.linalg.solve(Lc, jy)
    logdet = np.zeros(zt.shape[0])
    if extra:
        Lb = np.linalg.cholesky(acc + Pm @ noise @ PT)
        logdet = 2.0 * (np.log(np.einsum("rmii->rmi", Lc)) - np.log(np.einsum("rmii->rmi", Lb))).sum(axis=(1, 2))
    return zt, jzt, logdet
