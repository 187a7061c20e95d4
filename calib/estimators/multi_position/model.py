"""The residual system of the multi-position fit (``calib.estimators.multi_position.estimator``): whitened residuals and Jacobian.

Parameters, in order: K (row-major, 9), b (3), the g-sensitivity G (row-major, 9, only when fitted) and the free
accelerometer parameters (``calib.estimators.accel.PARAMS``). The model is g = K (m - G a) + b, a the calibrated specific force
(g) at each sample; G = 0 is the paper's eq. (1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.estimators.accel import apply_model
from calib.noise.accel_floor import AccelFloor
from calib.noise.motion import MotionNoise
from calib.numerics.rotation import closure_terms, rotation_terms

FD_STEP = 1e-6  # central-difference step of the accelerometer parameters
SETTLE_SHARE = 0.5625  # (1/2 / (2/3))^2: a steady drift's edge-to-mean part over its thirds-to-thirds part, squared
SETTLE_CHI2 = (10.83, 13.82)  # chi-square quantiles at 0.999, 1 and 2 degrees of freedom
THIRDS_NOISE = 6.0  # variance of the difference of two thirds' means over that of the whole mean, white noise


@dataclass(frozen=True)
class AccelRests:
    """The accelerometer over each rest."""

    mean: np.ndarray  # (N, 3) raw mean reading of each rest, g
    sd: np.ndarray  # (N,) its within-rest std (mean over axes), g, times the root of its colour (scatter of a mean)
    n: np.ndarray  # (N,) samples averaged
    drift: np.ndarray  # (N, 3) raw mean of the rest's last third minus its first third, g (the device settling)
    seconds: np.ndarray  # (N,) time the mean is taken over, s
    floor: AccelFloor  # the scatter of a mean beyond white noise, per raw axis (``calib.noise.accel_floor``)


@dataclass(frozen=True)
class Windows:
    """Samples of B motions, time-first and zero-padded (``calib.estimators.closure.fit.windows``)."""

    gyro: np.ndarray  # (L, B, 3) raw readings, deg/s
    accel: np.ndarray  # (L, B, 3) raw accelerometer, g
    dt: np.ndarray  # (L, B) s per sample, 0 past a window's end


@dataclass(frozen=True)
class Data:
    """Everything the residuals are computed from."""

    mean: np.ndarray  # (S, 3) gyro mean of each rest
    count: np.ndarray
    sigma: np.ndarray  # (3,) gyro reading noise, per sample
    sigma_slow: np.ndarray  # (3,) the same noise as it scatters means and integrals over many samples (its colour counted)
    motion_noise: MotionNoise  # how much noisier the gyro is while moving (``calib.noise.motion``)
    gravity: Windows | None  # motions constrained by the gravity directions at their ends
    turns: Windows | None  # full turns: closure to the identity
    pairs: tuple[np.ndarray, np.ndarray]  # rest before and after each gravity motion
    rests: AccelRests
    free_a: np.ndarray  # (9,) accelerometer parameters fitted jointly

    @property
    def sigma_moving(self) -> np.ndarray:
        """(3,) the noise that scatters a motion's integrated rotation: the rests' with the motions' excess counted."""
        return self.sigma_slow * np.sqrt(self.motion_noise.counted)


@dataclass
class Params:
    """One point of the fit."""

    K: np.ndarray
    b: np.ndarray
    G: np.ndarray | None  # None: the g-sensitivity is not part of the model
    xa: np.ndarray  # (9,) accelerometer parameters

    @property
    def n_gyro(self) -> int:
        """Parameters before the accelerometer's: K, b and G when fitted."""
        return 12 if self.G is None else 21

    def stepped(self, step: np.ndarray, free_a: np.ndarray) -> Params:
        """The point moved by a Gauss-Newton step over the parameters in the documented order."""
        xa = self.xa.copy()
        xa[free_a] += step[self.n_gyro:]
        G = None if self.G is None else self.G + step[12:21].reshape(3, 3)
        return Params(self.K + step[:9].reshape(3, 3), self.b + step[9:12], G, xa)


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices [v]x (..., 3, 3)."""
    x, y, z = np.moveaxis(v, -1, 0)
    zero = np.zeros_like(x)
    return np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)


def perp_basis(u: np.ndarray) -> np.ndarray:
    """(N, 3, 2): two orthonormal vectors perpendicular to each unit vector u (N, 3)."""
    helper = np.where(np.abs(u[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(u, e1)
    return np.stack([e1, e2], axis=-1)


@dataclass(frozen=True)
class RestGravity:
    """The calibrated accelerometer over each rest: its gravity direction, the noise of its mean, and its drift
    between its first and last thirds split about gravity (the device settling, ``directions``)."""

    u: np.ndarray  # (N, 3) unit gravity direction
    norm: np.ndarray  # (N,) |a|, g
    var_g: np.ndarray  # (N,) the white noise variance of the mean, per component (g^2)
    floor_across: np.ndarray  # (N,) the accelerometer's floor across gravity, per component (g^2)
    floor_along: np.ndarray  # (N,) the same along gravity (g^2)
    across: np.ndarray  # (N,) the drift's component across gravity, squared, per component (g^2)
    along: np.ndarray  # (N,) the drift along gravity, squared (g^2)

    @property
    def thirds_noise_across(self) -> np.ndarray:
        """Variance per component of the thirds' difference across gravity from noise alone: the white part
        and the floor (two means, each off by the floor)."""
        return THIRDS_NOISE * self.var_g + 2.0 * self.floor_across

    @property
    def thirds_noise_along(self) -> np.ndarray:
        """The same along gravity."""
        return THIRDS_NOISE * self.var_g + 2.0 * self.floor_along

    @property
    def counted_across(self) -> np.ndarray:
        """Rests whose drift across gravity is beyond what noise alone gives one time in a thousand."""
        return 2.0 * self.across > SETTLE_CHI2[1] * self.thirds_noise_across

    @property
    def excess_across(self) -> np.ndarray:
        """The drift across gravity beyond the noise's, where it counts, per component (g^2)."""
        return np.where(self.counted_across, self.across - self.thirds_noise_across, 0.0)

    @property
    def excess_along(self) -> np.ndarray:
        """The same along gravity (g^2)."""
        noise = self.thirds_noise_along
        return np.where(self.along > SETTLE_CHI2[0] * noise, self.along - noise, 0.0)


def rest_gravity(xa: np.ndarray, rests: AccelRests) -> RestGravity:
    """The rests' gravity, noise and drift, the accelerometer calibrated by ``xa``."""
    a = apply_model(xa, rests.mean)
    norm = np.linalg.norm(a, axis=1)
    u = a / norm[:, None]
    scale = float(np.mean(np.abs(xa[0:3])))
    var_g = (rests.sd * scale / np.sqrt(rests.n)) ** 2
    floor2 = (rests.floor.sd * scale) ** 2
    floor_along = (u**2) @ floor2
    drift = apply_model(xa, rests.drift) - apply_model(xa, np.zeros((1, 3)))  # the model's linear part
    along = np.sum(drift * u, axis=1) ** 2
    return RestGravity(u, norm, var_g, (float(floor2.sum()) - floor_along) / 2.0, floor_along,
                       (np.sum(drift**2, axis=1) - along) / 2.0, along)


def settling_rate_variance(g: RestGravity, seconds: np.ndarray) -> np.ndarray:
    """(N,) (deg/s)^2 per axis: the true rate a settling rest's tilt puts into its mean gyro reading. A steady tilt
    that moves gravity by the thirds' drift d turns at 1.5 d / T on average (d over two thirds of the rest)."""
    excess = g.excess_across / g.norm**2  # rad^2 per component
    return np.degrees(1.0) ** 2 * 4.0 * SETTLE_SHARE * excess / seconds**2  # (2 * 3/4 d / T)^2


def directions(xa: np.ndarray, rests: AccelRests) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit gravity directions (N, 3), their noise variance per component (rad^2) and |a| - 1 whitened.

    Both variances count the accelerometer's floor (``calib.noise.accel_floor``) beside its white noise, and the rest's
    settling: a rest whose mean reading drifts between its first and last thirds by more than its noise explains (a
    device rocking or easing into place) is taken to differ at its edges from its mean by half its drift
    (SETTLE_SHARE of the thirds' difference, squared). Across gravity that widens the direction's variance, along it
    the magnitude's. A drift counts only where noise alone would give it one time in a thousand (SETTLE_CHI2), so
    quiet rests keep their noise."""
    return _directions(rest_gravity(xa, rests))


def _directions(g: RestGravity) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    shared, edge = direction_noise(g)
    var_mag = g.var_g + g.floor_along + SETTLE_SHARE * g.excess_along
    return g.u, shared + edge, (g.norm - 1.0) / np.sqrt(var_mag)


def direction_noise(g: RestGravity) -> tuple[np.ndarray, np.ndarray]:
    """(N,) each, rad^2 per component across gravity: the noise of a rest's mean direction (white and floor), which
    both motions that meet the rest share, and the offset of each of its edges from that mean where it settles (half
    its drift), which each motion meets alone."""
    return (g.var_g + g.floor_across) / g.norm**2, SETTLE_SHARE * g.excess_across / g.norm**2


def _motion_inputs(p: Params, w: Windows) -> tuple[np.ndarray, np.ndarray | None]:
    """The readings with the g-sensitivity taken out, m - G a, and the calibrated specific force a (None without G)."""
    if p.G is None:
        return w.gyro, None
    force = apply_model(p.xa, w.accel)
    return w.gyro - force @ p.G.T, force


def _tiled(p: Params, B: int) -> tuple[np.ndarray, np.ndarray]:
    return np.broadcast_to(p.K, (B, 3, 3)).copy(), np.broadcast_to(p.b, (B, 3)).copy()


def motion_rotations(p: Params, data: Data, noise: bool = False):
    """The calibrated rotation of each gravity motion (``calib.numerics.rotation.RotationTerms``)."""
    w = data.gravity
    assert w is not None
    B = w.dt.shape[1]
    m, force = _motion_inputs(p, w)
    return rotation_terms(m, w.dt, *_tiled(p, B), sigma=np.broadcast_to(data.sigma_moving, (B, 3)).copy() if noise else None,
                          force=force)


def gravity_misfit(p: Params, data: Data) -> np.ndarray:
    """(G, 2) rad: the end rest's gravity carried to the start, minus the start's, perpendicular to it."""
    u, _, _ = directions(p.xa, data.rests)
    return _gravity_terms(motion_rotations(p, data).C, u, data.pairs).rho


def gravity_z(p: Params, data: Data) -> np.ndarray:
    """(G,) each motion's gravity misfit in units of its own noise (its 2x2 block of the joint covariance)."""
    gravity = rest_gravity(p.xa, data.rests)
    rt = motion_rotations(p, data, noise=True)
    assert rt.noise is not None
    terms = _gravity_terms(rt.C, gravity.u, data.pairs)
    G = terms.rho.shape[0]
    own = terms.covariance(rt.noise, *direction_noise(gravity)).reshape(G, 2, G, 2)[np.arange(G), :, np.arange(G), :]
    return np.sqrt(np.einsum("ga,ga->g", terms.rho, np.linalg.solve(own, terms.rho[..., None])[..., 0]))


@dataclass(frozen=True)
class GravityTerms:
    """The gravity misfits of G motions and what their noise is made of (``_gravity_terms``)."""

    rho: np.ndarray  # (G, 2) rad: the end rest's direction carried to the start, minus the start's, in ``basis``
    basis: np.ndarray  # (G, 3, 2) two unit vectors across the start rest's gravity
    at_end: np.ndarray  # (G, 2, 3) d rho / d (end rest's direction): basis^T C
    d_phi: np.ndarray  # (G, 2, 3) d rho / d (the motion's rotation vector)
    u: np.ndarray  # (S, 3) the rests' gravity directions
    pairs: tuple[np.ndarray, np.ndarray]  # rest before and after each motion

    def covariance(self, gyro_noise: np.ndarray, shared: np.ndarray, edge: np.ndarray) -> np.ndarray:
        """(2G, 2G) joint noise of the misfits, rows motion-major: each motion's integrated gyro noise (``gyro_noise``,
        (G, 3, 3) in its rotation vector), and the rests' directions (``direction_noise``), which correlate the
        misfits of the two motions that meet a rest through its mean's noise ``shared``. Its edges' offsets from the
        mean (``edge``, where it settles) are each motion's own: the arriving motion meets its first edge, the leaving
        one its last, and a device that eases into place moves most early, so they need not cancel."""
        i_s, i_e = self.pairs
        G = self.rho.shape[0]
        g = np.arange(G)
        # each motion meets two rests: the rest, the edge it meets (arriving: the first), and how the rest's
        # direction's noise enters the motion's misfit
        motion, rest = np.concatenate([g, g]), np.concatenate([i_e, i_s])
        arriving = np.arange(2 * G) < G
        maps = np.concatenate([self.at_end, -self.basis.transpose(0, 2, 1)])
        a, b = np.nonzero(rest[:, None] == rest[None, :])  # every pair of meetings at one rest, both orders
        r = rest[a]
        across = np.eye(3) - self.u[r, :, None] * self.u[r, None, :]  # a direction's noise lies across gravity
        weight = (shared[r] + np.where(arriving[a] == arriving[b], edge[r], 0.0))[:, None, None] * across
        blocks = np.einsum("pij,pjk,plk->pil", maps[a], weight, maps[b])
        cov = np.zeros((G, G, 2, 2))
        np.add.at(cov, (motion[a], motion[b]), blocks)
        cov[g, g] += self.d_phi @ gyro_noise @ self.d_phi.transpose(0, 2, 1)
        return cov.transpose(0, 2, 1, 3).reshape(2 * G, 2 * G)


def _gravity_terms(C: np.ndarray, u: np.ndarray, pairs: tuple[np.ndarray, np.ndarray]) -> GravityTerms:
    """The misfits of the motions whose calibrated rotations are ``C`` (G, 3, 3), between rests of directions ``u``."""
    i_s, i_e = pairs
    basis = perp_basis(u[i_s])
    v = np.einsum("gij,gj->gi", C, u[i_e])
    rho = np.einsum("gia,gi->ga", basis, v - u[i_s])
    at_end = np.einsum("gia,gij->gaj", basis, C)
    return GravityTerms(rho, basis, at_end, -np.einsum("gia,gij->gaj", basis, skew(v)), u, pairs)


def _accel_differences(xa: np.ndarray, data: Data) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each free accelerometer parameter, by central differences over +-FD_STEP: the change of the gravity
    directions (F, N, 3) and of the calibrated rest means (F, N, 3) (not yet divided by 2 FD_STEP), and
    d(whitened |a| - 1)/d parameter (F, N)."""
    free = np.flatnonzero(data.free_a)
    shape = (free.size, data.rests.n.size)
    du, da, dmag = np.zeros(shape + (3,)), np.zeros(shape + (3,)), np.zeros(shape)
    for c, i in enumerate(free):
        xp, xm = xa.copy(), xa.copy()
        xp[i] += FD_STEP
        xm[i] -= FD_STEP
        (up, _, mp), (um, _, mm) = directions(xp, data.rests), directions(xm, data.rests)
        du[c] = up - um
        da[c] = apply_model(xp, data.rests.mean) - apply_model(xm, data.rests.mean)
        dmag[c] = (mp - mm) / (2 * FD_STEP)
    return du, da, dmag


def _force_jacobian(dF: np.ndarray, K: np.ndarray) -> np.ndarray:
    """d phi / d G_ij (B, 3, 9) from the force sensitivities: the true rate moves by -K[:, i] a_j."""
    B = dF.shape[0]
    return -np.einsum("bacj,ci->baij", dF, K).reshape(B, 3, 9)


def residual_layout(data: Data) -> dict[str, int]:
    """How many of ``system``'s residual rows each kind of constraint takes, in its order."""
    return {"motions": 2 * data.pairs[0].size, "full_turns": 0 if data.turns is None else 3 * data.turns.dt.shape[1],
            "rests": data.mean.size, "accelerometer_magnitude": data.rests.n.size if data.free_a.any() else 0}


def system(p: Params, data: Data) -> tuple[np.ndarray, np.ndarray]:
    """Whitened residuals and Jacobian over the parameters (module docstring): gravity motions, full turns,
    gyro rests, accelerometer magnitudes. The motions' dependence on the accelerometer through G a is left
    out of the Jacobian (second order: G times an accelerometer correction)."""
    free = np.flatnonzero(data.free_a)
    ng = p.n_gyro
    P = ng + free.size
    res_parts, jac_parts = [], []
    gravity = rest_gravity(p.xa, data.rests)
    u, _, mag = _directions(gravity)
    du, da, dmag = _accel_differences(p.xa, data)
    if data.gravity is not None:
        i_s, i_e = data.pairs
        rt = motion_rotations(p, data, noise=True)
        terms = _gravity_terms(rt.C, u, data.pairs)
        G = terms.rho.shape[0]
        parts = [rt.dK.reshape(G, 3, 9), rt.db] + ([] if rt.dF is None else [_force_jacobian(rt.dF, p.K)])
        dgyro = terms.d_phi @ np.concatenate(parts, axis=-1)
        assert rt.noise is not None
        L = np.linalg.cholesky(terms.covariance(rt.noise, *direction_noise(gravity)))
        dacc = np.zeros((G, 2, free.size))
        for c in range(free.size):  # the directions' dependence on the accelerometer
            dv = np.einsum("gij,gj->gi", rt.C, du[c][i_e]) - du[c][i_s]
            dacc[:, :, c] = np.einsum("gia,gi->ga", terms.basis, dv) / (2 * FD_STEP)
        # one general solve for both: LAPACK's triangular solve with many right-hand sides stalls on busy cores
        whitened = np.linalg.solve(L, np.concatenate([terms.rho.reshape(2 * G, 1), np.concatenate([dgyro, dacc], axis=-1)
                                                      .reshape(2 * G, P)], axis=1))
        res_parts.append(whitened[:, 0])
        jac_parts.append(whitened[:, 1:])
    if data.turns is not None:
        w = data.turns
        T = w.dt.shape[1]
        m, force = _motion_inputs(p, w)
        ct = closure_terms(m, w.dt, *_tiled(p, T), sigma=np.broadcast_to(data.sigma_moving, (T, 3)).copy(), force=force)
        assert ct.dK is not None and ct.db is not None and ct.noise is not None
        parts = [ct.dK.reshape(T, 3, 9), ct.db] + ([] if ct.dF is None else [_force_jacobian(ct.dF, p.K)])
        d = np.concatenate(parts + [np.zeros((T, 3, free.size))], axis=-1)
        L = np.linalg.cholesky(ct.noise)
        res_parts.append(np.linalg.solve(L, ct.r[..., None])[..., 0].reshape(-1))
        jac_parts.append(np.linalg.solve(L, d).reshape(-1, P))
    r, j = _rest_residuals(p, data, da, free.size, settling_rate_variance(gravity, data.rests.seconds))
    res_parts.append(r)
    jac_parts.append(j)
    if free.size:  # accelerometer rests: |a| = 1 g
        jmag = np.zeros((mag.size, P))
        jmag[:, ng:] = dmag.T
        res_parts.append(mag)
        jac_parts.append(jmag)
    return np.concatenate(res_parts), np.concatenate(jac_parts)


def _rest_residuals(p: Params, data: Data, da: np.ndarray, n_free: int, settling_var: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Gyro rests, whitened residuals and Jacobian: the mean reading is G a - beta, beta = K^-1 b."""
    ng = p.n_gyro
    P = ng + n_free
    S = data.mean.shape[0]
    Kinv = np.linalg.inv(p.K)
    beta = Kinv @ p.b
    var = data.sigma_slow[None, :] ** 2 / data.count[:, None] + settling_var[:, None]
    w = 1.0 / np.sqrt(var)
    r = data.mean + beta
    dr = np.zeros((S, 3, P))
    for i in range(3):
        for j in range(3):
            dr[:, :, 3 * i + j] = -Kinv[:, i] * beta[j]
    dr[:, :, 9:12] = Kinv
    if p.G is not None:
        a = apply_model(p.xa, data.rests.mean)
        r = r - a @ p.G.T
        for i in range(3):
            dr[:, i, 12 + 3 * i : 15 + 3 * i] = -a
        dr[:, :, ng:] = -np.einsum("ij,fnj->nif", p.G, da) / (2 * FD_STEP)
    return (w * r).reshape(-1), (w[..., None] * dr).reshape(-1, P)
