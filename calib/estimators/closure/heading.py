"""The hand's heading spread, learned from the turns that show it.

A turn by hand ends turned by a small heading h_j about the vertical u_j (``calib.estimators.closure.placement``): a
device spun a little on the table as it is put back. No accelerometer sees it, but the closure does: the component
u_j . r_j of a turn's closure is its heading plus noise, except where a scale factor moves the same component. A
full turn about a horizontal axis moves its closure along that axis, across u_j, so its heading stands alone; a turn
about the vertical moves k along u_j, where heading and scale factor cannot be told apart. The horizontal turns
therefore measure the hand's heading spread tau_h, and the vertical one carries it as its prior.

tau_h is estimated by restricted maximum likelihood (REML) on the fit linearised at the current iterate: with the
turn covariances C_j(tau) = B_j + tau^2 u_j u_j^T (B_j the reading noise's and the tilt's), the fixed rows (rests,
priors) whitened, and F(tau) the Fisher information of the parameters,

    -2 log L_R(tau) = sum_j log det C_j + log det F + min over the parameters of the weighted residual sum,

summed over the turns that show their heading (the others keep the spread as their prior); the log det F term
counts what the parameters absorb of those turns' residuals, which ML would read as less heading than there was.

A turn about the vertical is a third look where two are few. Its closure's vertical component is its heading plus
k_z's error, but k_z is not the vertical turn's alone: the other turns, never exactly about their axes, move the z
axis too, and what they say of k_z against what the vertical turn says is that turn's heading plus their error. The
REML over every turn with a measured vertical counts it (log det F takes off what k_z absorbs, so a k_z the others
barely see leaves that turn almost no weight), and is taken where it agrees with the horizontal turns: their own
likelihood at the joint spread within ``CONSISTENT_LR`` of their best, and the joint spread below the grid's end.
Otherwise the horizontal turns' spread stands, and a vertical turn far from theirs, as when it stopped short, is
reported as the misfit it is. With two horizontal turns alone a spread under half the true one comes out in a fifth
of recordings (its square scatters as chi^2 with 2 degrees of freedom), and the vertical turn, weighed as if the hand
were more careful than it was, moved k_z by up to 1.5x what the true spread allows; with the third look, 1.14x.

The minimum is found on a grid of tau^2 (a little below 0, 0, and log-spaced up to ``MAX_HEADING_PRIOR_DEG``^2)
refined by a parabola. Below 0 it is kept as found for the parameters' variances, which are then unbiased (turns
closing better than their noise says are as likely as turns closing worse), and the fit's weights carry tau^2 = 0.

Its information, I = tr(P G P G) / 2 with P the REML projection and G_j = u_j u_j^T, gives var(tau^2), and with it
each parameter's Satterthwaite degrees of freedom, 2 v^2 / ((dv/d tau^2)^2 var(tau^2)), v its variance with every
turn of a measured vertical carrying the spread: a k_z that leans on a spread learned from three turns is known with
few degrees of freedom, and its interval is a Student-t's. Its width is drawn from the spreads the turns that show
their heading allow (``calib.estimators.closure.fiducial``): the t's quantile times a scale that may differ from the
standard error, narrower where those turns closed better than their noise says, wider where they leave a large
spread possible.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from calib.distributions import t_isf
from calib.estimators.closure.fiducial import fiducial_halfwidths
from calib.estimators.closure.fit import ClosureData, System
from calib.estimators.closure.placement import MAX_DOF, MAX_HEADING_PRIOR_DEG, HeadingSpread, placement_model
from calib.quality import HeadingReport
from calib.stages.placement import TurnTilts
from calib.units import DEG

EVIDENCE_MIN_DEG = 30.0  # a turn whose axis is at least this far from the vertical shows its heading
_GRID = np.geomspace(1e-3, MAX_HEADING_PRIOR_DEG, 64) * DEG  # the positive spreads tried, tau (rad)
# how far (-2 log likelihood ratio) the horizontal turns may be from their own spread at the one the vertical turns
# join them at: chi^2_1's 99.9th percentile
CONSISTENT_LR = 10.83


@dataclass(frozen=True)
class HeadingEvidence:
    """What learning the spread needs: the turns' measured tilts and which turns show their heading."""

    tilts: TurnTilts
    shows: np.ndarray  # (J,) bool

    @property
    def turns(self) -> int:
        return int(self.shows.sum())

    def data_with(self, data: ClosureData, spread_deg: float) -> ClosureData:
        """``data`` with the placement covariance of a heading spread of ``spread_deg``."""
        return replace(data, place_cov=placement_model(self.tilts, spread_deg).cov[None])


def heading_evidence(tilts: TurnTilts, swept: np.ndarray) -> HeadingEvidence:
    """Which turns show their heading: the tilt beside them measured (so the vertical is known) and their axis, the
    direction they swept (``swept`` (J, 3) deg), at least ``EVIDENCE_MIN_DEG`` from the vertical."""
    axis = swept / np.maximum(np.linalg.norm(swept, axis=1, keepdims=True), 1e-12)
    with np.errstate(invalid="ignore"):
        cos_up = np.abs(np.sum(axis * np.nan_to_num(tilts.up), axis=1))
    shows = tilts.measured & (cos_up <= np.cos(np.radians(EVIDENCE_MIN_DEG)))
    return HeadingEvidence(tilts, shows)


def restricted_spread(turn_res: np.ndarray, turn_jac: np.ndarray, chol: np.ndarray, noise: np.ndarray,
                      fixed_res: np.ndarray, fixed_jac: np.ndarray, evidence: HeadingEvidence,
                      uncertainty: bool = True) -> HeadingSpread:
    """The REML heading spread at a fit's linearisation, and (with ``uncertainty``) its standard error and each
    parameter's degrees of freedom, standard error ratio and interval scale.

    ``turn_res`` (J, 3) and ``turn_jac`` (J, 3, P): the turns' whitened residuals and Jacobian, whitened by the lower
    Cholesky factors ``chol`` (J, 3, 3) of their covariances; ``noise`` (J, 3, 3) rad^2: the reading noise's part of
    those; ``fixed_res`` (M,) and ``fixed_jac`` (M, P): the other rows (rests, priors), whitened, which no spread
    changes.
    """
    tilts = evidence.tilts
    r_all = np.einsum("jab,jb->ja", chol, turn_res)  # unwhitened: rad
    A_all = np.einsum("jab,jbp->jap", chol, turn_jac)
    B_all = noise + placement_model(tilts, 0.0).cov  # all but the heading's part
    up_all = np.nan_to_num(tilts.up)

    def system(moving: np.ndarray) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """Covariances, their inverses, Fisher information and score at spreads tau2 (G,), the ``moving`` turns' with
        the spread, the others' (and the rests' and priors') as they are."""
        keep = ~moving
        fixed_j = np.concatenate((turn_jac[keep].reshape(-1, turn_jac.shape[-1]), fixed_jac))
        fixed_r = np.concatenate((turn_res[keep].ravel(), fixed_res))
        F0, h0 = fixed_j.T @ fixed_j, fixed_j.T @ fixed_r
        A, r, B, up = A_all[moving], r_all[moving], B_all[moving], up_all[moving]
        U = up[:, :, None] * up[:, None, :]

        def at(tau2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
            C = B[None] + tau2[:, None, None, None] * U[None]  # (G, J, 3, 3)
            W = np.linalg.inv(C)
            F = F0 + np.einsum("jap,gjaq->gpq", A, W @ A[None])
            h = h0 + np.einsum("jap,gja->gp", A, np.einsum("gjab,jb->gja", W, r))
            return C, W, F, h

        return at

    def floor(moving: np.ndarray) -> float:
        """How far below 0 tau^2 may go with every moving turn's covariance positive."""
        return float(np.min(np.einsum("ja,jab,jb->j", up_all[moving], B_all[moving], up_all[moving])))

    def reml_minimum(moving: np.ndarray) -> tuple[float, Callable[[float], float]]:
        """The REML spread tau^2 of the ``moving`` turns, and -2 log of its likelihood ratio at another tau^2."""
        reml = system(moving)
        grid = np.concatenate((-floor(moving) * np.linspace(0.9, 0.1, 9), [0.0], _GRID**2))
        base = float(fixed_res @ fixed_res) + float(turn_res[~moving].ravel() @ turn_res[~moving].ravel())
        r = r_all[moving]

        def objective(tau2: np.ndarray) -> np.ndarray:
            C, W, F, h = reml(tau2)
            fitted = np.linalg.solve(F, h[..., None])[..., 0]  # the parameters' step at each spread
            quad = base + np.einsum("ja,gja->g", r, np.einsum("gjab,jb->gja", W, r)) - np.einsum("gp,gp->g", h, fitted)
            return np.linalg.slogdet(C)[1].sum(axis=1) + np.linalg.slogdet(F)[1] + quad

        tau2 = _minimum(grid, objective(grid))
        least = float(objective(np.array([tau2]))[0])
        return tau2, lambda other: float(objective(np.array([other]))[0]) - least

    # the REML over the turns that show their heading; tau^2 may come out below 0 (those turns closing better than
    # their noise says): each variance is then unbiased, and the weights carry tau^2 >= 0
    shows = evidence.shows
    tau2, horizontal = reml_minimum(shows)
    # the turns about the vertical join where what they add agrees with the others: then their closures against what
    # the other turns say of k_z are evidence too (a third look where two are few); a turn stopped short is not heading
    moving = shows
    vertical = tilts.measured & ~shows
    if vertical.any():
        joined, _ = reml_minimum(tilts.measured)
        if joined < _GRID[-1] ** 2 and horizontal(joined) <= CONSISTENT_LR:
            tau2, moving = joined, tilts.measured
    tau = float(np.sqrt(max(tau2, 0.0)))
    if not uncertainty:
        return HeadingSpread(tau / DEG, "estimated", int(moving.sum()), vertical=int((moving & ~shows).sum()))
    reml = system(moving)
    # the information about tau^2 at the estimate: I = tr(P G P G) / 2, P the REML projection, G_j = u_j u_j^T
    _, W, F, _ = reml(np.array([tau2]))
    cov = np.linalg.inv(F[0])
    up = up_all[moving]
    WU = np.einsum("jab,jb->ja", W[0], up)  # W_j u_j
    AU = np.einsum("jap,ja->jp", A_all[moving], WU)  # A_j^T W_j u_j
    PG = np.diag(np.einsum("ja,ja->j", up, WU)) - AU @ cov @ AU.T  # u_j^T P_jk u_k
    info = 0.5 * float(np.sum(PG**2))
    var_tau2 = 1.0 / info if info > 0 else np.inf
    # each parameter's variance where every turn with a measured vertical carries the spread (the vertical one
    # included), and its dependence on tau^2: Satterthwaite's degrees of freedom
    measured = tilts.measured
    full = system(measured)
    signed = max(tau2, -0.9 * floor(measured))
    _, W, F, _ = full(np.array([signed]))
    cov = np.linalg.inv(F[0])
    WU = np.einsum("jab,jb->ja", W[0], up_all[measured])
    AU = np.einsum("jap,ja->jp", A_all[measured], WU)
    D = AU.T @ AU  # -dF/d tau^2
    dv = np.diag(cov @ D @ cov)  # d var / d tau^2
    # the weights carry an estimated spread: Kenward and Roger's addition to each variance, 2 var(tau^2) cov (Q - D cov D)
    # cov with Q = sum_j (u_j^T W_j u_j) AU_j AU_j^T, what a spread off by its error adds to the parameters' scatter
    Q = np.einsum("j,jp,jq->pq", np.einsum("ja,ja->j", up_all[measured], WU), AU, AU)
    at_signed = np.diag(cov)
    var = at_signed + 2.0 * var_tau2 * np.diag(cov @ (Q - D @ cov @ D) @ cov) if np.isfinite(var_tau2) else at_signed
    with np.errstate(divide="ignore", invalid="ignore"):
        dof = np.where(dv > 0, 2.0 * var**2 / (dv**2 * var_tau2), np.inf)
    dof = np.clip(np.nan_to_num(dof, nan=np.inf), 1.0, None)
    dof[dof >= MAX_DOF] = np.inf  # as many as this: a normal interval
    # each 95 % interval's width from the spreads the turns allow (calib.estimators.closure.fiducial), that Student-t's
    # shape kept: the scale its quantile is multiplied by
    C_all = np.einsum("jab,jcb->jac", chol, chol)
    half = fiducial_halfwidths(r_all, A_all, C_all, B_all, up_all, measured, shows, fixed_res, fixed_jac)
    scale = half / t_isf(0.025, dof)
    # the variance at the weights' spread: the same unless tau^2 came out below 0
    at_weights = at_signed if tau2 >= 0 else np.diag(np.linalg.inv(full(np.array([0.0]))[2][0]))
    sd_tau = np.sqrt(var_tau2) / (2 * tau) if tau > 0 else np.sqrt(np.sqrt(var_tau2))  # delta method; at 0, sd(tau^2)
    return HeadingSpread(tau / DEG, "estimated", int(moving.sum()), float(min(sd_tau / DEG, 1e3)), dof,
                         np.sqrt(var / at_weights), int((moving & ~shows).sum()), scale)


def _minimum(grid: np.ndarray, objective: np.ndarray) -> float:
    """The minimiser of ``objective`` over the sorted ``grid``, refined by a parabola through its neighbours (in
    log tau where they are all positive spreads, else in tau^2)."""
    i = int(np.argmin(objective))
    if not 0 < i < grid.size - 1:
        return float(grid[i])
    x = grid[i - 1 : i + 2]
    logs = bool(x[0] > 0)
    if logs:
        x = np.log(x)
    y = objective[i - 1 : i + 2]
    denom = (x[0] - x[1]) * (x[0] - x[2]) * (x[1] - x[2])
    a = (x[2] * (y[1] - y[0]) + x[1] * (y[0] - y[2]) + x[0] * (y[2] - y[1])) / denom
    b = (x[2] ** 2 * (y[0] - y[1]) + x[1] ** 2 * (y[2] - y[0]) + x[0] ** 2 * (y[1] - y[2])) / denom
    if a <= 0:
        return float(grid[i])
    best = float(np.clip(-b / (2 * a), x[0], x[2]))
    return float(np.exp(best)) if logs else best


def learn_heading(data: ClosureData, current: System, theta: np.ndarray,
                   with_prior: Callable[[np.ndarray, np.ndarray], np.ndarray], prior_rows: np.ndarray,
                   evidence: HeadingEvidence, uncertainty: bool = True) -> tuple[ClosureData, HeadingSpread]:
    """The heading spread the turns show at ``current`` (the system at ``theta``), and ``data`` carrying it; the
    spread's and the parameters' uncertainty with ``uncertainty`` (``restricted_spread``)."""
    J = data.J
    res = with_prior(current.res[0], theta)
    jac = np.vstack((current.J[0], prior_rows))
    assert current.terms.noise is not None  # the system was built with its weights
    heading = restricted_spread(res[: 3 * J].reshape(J, 3), jac[: 3 * J].reshape(J, 3, -1), current.chol[0],
                                current.terms.noise.reshape(J, 3, 3), res[3 * J :], jac[3 * J :], evidence,
                                uncertainty)
    return evidence.data_with(data, heading.spread_deg), heading


def heading_report(heading: HeadingSpread) -> HeadingReport:
    """``quality["placement"]["heading"]``: the spread carried, where it came from, and what that means."""
    spread = heading.spread_deg
    if heading.source == "estimated":
        sd = heading.spread_sd_deg
        about = (f"{heading.turns - heading.vertical} turn(s) about horizontal axes"
                 + (f" and {heading.vertical} about the vertical (against what the others say of its scale factor)"
                    if heading.vertical else ""))
        note = (f"learned from the closures of {about}: {spread:.2g} deg per turn"
                + (f" (standard error {sd:.2g})" if sd is not None else "")
                + "; the turn about the vertical carries it, where heading and scale factor cannot be told apart")
    elif heading.source == "stated":
        note = f"carried as the stated prior of {spread:.2g} deg per turn"
    elif heading.source == "unsettled":
        note = (f"the closures of the {heading.turns} turn(s) about horizontal axes did not settle on a spread (a turn far "
                f"from a full one pulls them apart; see the warnings): carried as the default prior of {spread:.2g} deg "
                "per turn")
    elif heading.source == "kit":
        note = (f"learned from the kit's mean recording, the tray's heading being every wearable's: {spread:.2g} deg "
                "per turn")
    else:
        note = (f"no turn about a horizontal axis with a measured rest beside it shows the heading: carried as the "
                f"default prior of {spread:.2g} deg per turn; state the site's with --heading-prior-deg")
    return {"spread_deg": float(spread), "source": heading.source, "turns": int(heading.turns),
            "spread_sd_deg": None if heading.spread_sd_deg is None else float(heading.spread_sd_deg), "note": note}
