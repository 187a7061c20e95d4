"""The null distribution: the same protocol simulated many times from the fitted model (parametric bootstrap).

The recording's own motion is replayed: the nominal fit's calibrated rates g = K m + b define the
true motion, set to exactly 0 in the stills and corrected in each turn by a constant rate so that
the turn closes exactly (the nominal model's assumption). Readings are regenerated as
m = K^-1 (g - b) plus noise like the recording's own, and the accelerometer as the stills' gravity (the
same across each turn, since the model says the device came back) plus its own noise. A real sensor's
noise is not white (its low-pass filter, flicker, quantisation): at the measured level but white, the
null would make the recording's own noise look like an effect. So each axis' noise is an autoregressive
process fitted to the recording's rests (``NoiseColour``: Yule-Walker on their pooled autocovariance,
less what is slower than ``COLOUR_SLOW_S``, which is the wander's; the order by AIC up to
``COLOUR_ORDER_MAX``; order 0, white noise, for a white sensor). Each replicate is fitted with the
nominal model exactly as the recording was, batched.

``Replay.with_effects`` regenerates the readings with fitted effects switched on (the estimator's
models inverted), so that the recording can be compared with a simulation that includes them.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.linalg import solve_toeplitz
from scipy.ndimage import uniform_filter1d
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation

from calib.diagnosis.data import Inputs, Layout, Problem, build_problem
from calib.diagnosis.engine import closure_pass
from calib.diagnosis.markov import recursion
from calib.diagnosis.models import R0_DPS, Model
from calib.units import DEG

COLOUR_ORDER_MAX = 8  # autoregressive order of the noise model at most (a sensor's low-pass filter needs 1-3)
COLOUR_SLOW_S = 10.0  # slower than this is the wander's (a moving mean over this span), not the noise's


@dataclass(frozen=True)
class NoiseColour:
    """An autoregressive model of each axis' reading noise: x_i = sum_k phi_k x_(i-k) + e_i, e ~ N(0, innovation^2)."""

    phi: np.ndarray  # (3, p) coefficients per axis (p may be 0: white)
    innovation: np.ndarray  # (3,) std of e, in the readings' unit
    burn: int  # samples drawn before each path starts, so that it starts stationary

    @property
    def order(self) -> int:
        return int(self.phi.shape[1])

    def draw(self, rng: np.random.Generator, R: int, n: int) -> np.ndarray:
        """R paths of n samples (R, n, 3); white noise (no burn-in, the same draws) at order 0."""
        if self.order == 0:
            return self.innovation * rng.standard_normal((R, n, 3))
        e = self.innovation * rng.standard_normal((R, n + self.burn, 3))
        for ax in range(3):
            e[..., ax] = lfilter([1.0], np.concatenate(([1.0], -self.phi[ax])), e[..., ax], axis=1)
        return e[:, self.burn :]


def noise_colour(layout: Layout, x: np.ndarray, max_order: int = COLOUR_ORDER_MAX) -> NoiseColour | None:
    """The autoregressive noise model of ``x`` (n, 3) at the layout's rests (one order for all axes, by AIC on their
    pooled autocovariance); None without a rest of more than ``4 * max_order`` samples."""
    slow = max(2, round(COLOUR_SLOW_S * layout.fs))
    rests = [s for s in layout.stills if s.n > 4 * max_order]
    if not rests:
        return None
    acov = np.zeros((max_order + 1, 3))
    total = 0
    for s in rests:
        seg = x[s.start : s.end]
        seg = seg - (seg.mean(axis=0) if s.n <= slow else uniform_filter1d(seg, slow, axis=0, mode="nearest"))
        for k in range(max_order + 1):
            acov[k] += np.einsum("ij,ij->j", seg[: s.n - k], seg[k:])
        total += s.n
    acov /= total  # the biased estimate: a positive definite sequence, so every fitted model is stationary
    if np.any(acov[0] <= 0):
        return None
    best: tuple[float, np.ndarray, np.ndarray] | None = None
    for p in range(max_order + 1):
        phi = np.zeros((3, p))
        for ax in range(3):
            if p:
                phi[ax] = solve_toeplitz(acov[:p, ax], acov[1 : p + 1, ax])
        var = acov[0] - np.einsum("ap,pa->a", phi, acov[1 : p + 1]) if p else acov[0].copy()
        aic = total * float(np.sum(np.log(np.maximum(var, 1e-300)))) + 2.0 * 3 * p
        if best is None or aic < best[0]:
            best = (aic, phi, np.sqrt(np.maximum(var, 0.0)))
    assert best is not None
    _, phi, innovation = best
    return NoiseColour(phi, innovation, _burn_in(phi))


def _burn_in(phi: np.ndarray) -> int:
    """Samples for a path to forget its zero start: five times its slowest root's time constant (at most 20,000)."""
    if phi.shape[1] == 0:
        return 0
    radius = max(float(np.max(np.abs(np.roots(np.concatenate(([1.0], -row)))))) for row in phi)
    return int(min(20_000, np.ceil(5.0 / max(1.0 - radius, 2.5e-4)) + phi.shape[1]))


@dataclass
class Replay:
    """A noise-free version of the recording under a fitted model, and the noise to add."""

    layout: Layout
    g: np.ndarray  # (n, 3) true rate, deg/s
    m: np.ndarray  # (n, 3) noise-free readings, deg/s
    a: np.ndarray | None  # (n, 3) noise-free specific force, g
    temp: np.ndarray | None
    sigma: np.ndarray  # (3,) reading noise, deg/s
    accel_sigma: float
    k: np.ndarray
    b: np.ndarray
    gm: tuple[np.ndarray, float] | None = None  # Gauss-Markov bias (sigma (3,), tau) to add per replicate
    extra: dict = field(default_factory=dict)
    colour: NoiseColour | None = None  # the gyro's noise; None: white of sigma
    accel_colour: NoiseColour | None = None  # the accelerometer's; None: white of accel_sigma

    def replicates(self, rng: np.random.Generator, R: int) -> tuple[np.ndarray, np.ndarray | None]:
        """R replicates: gyro (R, n, 3), accel (R, n, 3) or None."""
        n = self.m.shape[0]
        gyro = self.m[None] + _noise(self.colour, self.sigma, rng, R, n)
        if self.gm is not None:
            sig, tau = self.gm
            gyro -= gauss_markov(rng, R, self.layout.t, sig, tau) / self.k
        clip = self.extra.get("full_scale")
        if clip is not None:
            np.clip(gyro, -clip, clip, out=gyro)
        accel = None
        if self.a is not None:
            accel = self.a[None] + _noise(self.accel_colour, self.accel_sigma, rng, R, n)
        return gyro, accel


def _noise(colour: NoiseColour | None, sigma: np.ndarray | float, rng: np.random.Generator, R: int, n: int) -> np.ndarray:
    """R noise paths of n samples (R, n, 3): ``colour``'s, or white of ``sigma`` without one."""
    return colour.draw(rng, R, n) if colour is not None else sigma * rng.standard_normal((R, n, 3))


def gauss_markov(rng: np.random.Generator, R: int, t: np.ndarray, sigma: np.ndarray, tau: float) -> np.ndarray:
    """R stationary first-order Gauss-Markov paths (R, n, 3) with std sigma (3,) and time constant tau (s)."""
    n = t.size
    dt = np.diff(t, prepend=t[0])
    phi = np.exp(-dt / tau)
    drive = np.sqrt(np.maximum(1.0 - phi**2, 0.0))
    eps = rng.standard_normal((R, n, 3))
    drive[0] = 1.0
    # x_i = phi_i x_{i-1} + drive_i eps_i, every path at once
    x = recursion(phi[1:], drive[:, None, None] * eps.transpose(1, 0, 2)).transpose(1, 0, 2)
    return x * sigma


def _close_turns(layout: Layout, g: np.ndarray, target: np.ndarray | None = None) -> np.ndarray:
    """Subtract from each turn's rate the constant that makes it close exactly (or end at ``target`` (J, 3), deg)."""
    J = layout.J
    if J == 0:
        return g
    g = g.copy()
    model = Model((), J)
    one = np.array([[1.0, 1.0, 1.0, 0.0, 0.0, 0.0]])
    prob = build_problem(layout, g[None])
    c = np.zeros((J, 3))
    goal = np.zeros((J, 3)) if target is None else target
    moves = layout.moves
    for _ in range(4):
        psi = np.repeat(one, J, axis=0)
        psi[:, 3:6] = -c
        cl = closure_pass(model, psi, prob, np.full((J, 3), 1e-3))
        err = np.where(moves[:, None], 0.0, cl.r - goal)  # a re-orientation ends wherever the motion took it
        if np.max(np.abs(err)) < 1e-9:
            break
        dr_db = cl.jac[:, :, 3:6]  # deg per (deg/s) of constant rate
        c += np.linalg.solve(dr_db, err[..., None])[..., 0]
    for j, (a, b) in enumerate(layout.turn_bounds):
        g[a:b] -= c[j]
    return g


def window_rotations(layout: Layout, g: np.ndarray) -> Rotation:
    """The rotation (J,) the true rate g (n, 3) makes over each window: end pose into start pose."""
    model = Model((), layout.J)
    psi = np.repeat(np.array([[1.0, 1.0, 1.0, 0.0, 0.0, 0.0]]), layout.J, axis=0)
    cl = closure_pass(model, psi, build_problem(layout, g[None]), np.full((layout.J, 3), 1e-3), jacobian=False)
    return Rotation.from_quat(layout.ref_quats()) * Rotation.from_rotvec(cl.r * DEG)


def closure_targets(model: Model, psi: np.ndarray, J: int) -> np.ndarray | None:
    """Where each turn ends under the model (deg rotation vectors, (J, 3)): its free closure offsets."""
    offsets = model.closure_offsets()
    if not offsets:
        return None
    target = np.zeros((J, 3))
    for j, s, B in offsets:
        target[j] += B @ psi[s : s + B.shape[1]]
    return target


def make_replay(
    layout: Layout,
    gyro: np.ndarray,
    accel: np.ndarray | None,
    temp: np.ndarray | None,
    model: Model,
    psi: np.ndarray,
    sigma: np.ndarray,
    accel_sigma: float | None,
    caps: np.ndarray | None = None,
    full_scale: float | None = None,
) -> Replay:
    """The noise-free replay of a recording under a fit of ``model`` at psi (P,).

    The model's calibrated rate is the true motion (with clipped plateaus rebuilt when the model has
    them); the replicates are clipped again at ``full_scale``.
    """
    k, b = psi[0:3], psi[3:6]
    g, _ = model.rate(psi, Inputs(gyro, layout.t, accel, temp, caps), jacobian=False)
    for s in layout.stills:
        g[s.start : s.end] = 0.0
    g = _close_turns(layout, g, closure_targets(model, psi, layout.J))
    m = (g - b) / k
    a = None
    if accel is not None:
        a = accel.copy()
        means = [accel[s.start : s.end].mean(axis=0) for s in layout.stills]
        # the device comes back after each turn: the still after it has the pose of the still before; after a
        # re-orientation, the pose the true motion took it to
        moves = layout.moves
        turned = window_rotations(layout, g) if moves.any() else None
        for j in range(layout.J):
            i0, i1 = layout.neighbours[j]
            if i0 >= 0 and i1 >= 0:
                means[i1] = turned[j].inv().apply(means[i0]) if turned is not None and moves[j] else means[i0]
        for s, mu in zip(layout.stills, means, strict=False):
            a[s.start : s.end] = mu
    extra = {"full_scale": full_scale} if full_scale is not None else {}
    return Replay(layout, g, m, a, temp, np.asarray(sigma, float), float(accel_sigma or 0.0), k.copy(), b.copy(),
                  extra=extra, colour=_coloured(noise_colour(layout, gyro)),
                  accel_colour=None if accel is None else _coloured(noise_colour(layout, accel)))


def _coloured(model: NoiseColour | None) -> NoiseColour | None:
    """The model where the noise has colour; None for white noise, which the replay draws at its measured level."""
    return model if model is not None and model.order > 0 else None


def with_effects(replay: Replay, model: Model, psi: np.ndarray, gm: tuple[np.ndarray, float] | None = None,
                 a_design: np.ndarray | None = None) -> Replay:
    """The replay with the effects of ``model`` at parameters psi (P,) switched on.

    Clipped plateaus are already rebuilt in the replay's motion and clipped again in its replicates.
    """
    sl = model.slices
    lay = replay.layout
    k, b = psi[0:3], psi[3:6]
    g = replay.g
    a = replay.a
    if "placement_error" in sl and lay.J:
        rho = psi[sl["placement_error"]].reshape(lay.J, 3)
        g = _close_turns(lay, g, target=closure_targets(model, psi, lay.J))
        if a is not None:
            a = a.copy()
            for j in range(lay.J):
                i0, i1 = lay.neighbours[j]
                if i0 < 0 or i1 < 0:
                    continue
                s0, s1 = lay.stills[i0], lay.stills[i1]
                # gravity after = R(rho)^T gravity before, for every still that follows until the pose changes
                a[s1.start : s1.end] = Rotation.from_rotvec(rho[j] * DEG).inv().apply(a[s0.start])
    # invert the rate model: g = f(g0), g0 = (K + U)(m - G a) + b + d t
    g0 = g
    if "scale_nonlinearity" in sl:
        n = psi[sl["scale_nonlinearity"]]
        x = np.abs(g0)
        # |g0| (1 + n |g0| / r0) = |g|
        with np.errstate(divide="ignore", invalid="ignore"):
            root = np.where(np.abs(n) > 1e-12, (-1.0 + np.sqrt(np.maximum(1.0 + 4.0 * n * x / R0_DPS, 0.0))) / (2.0 * n / R0_DPS), x)
        g0 = np.sign(g0) * root
    if "scale_asymmetry" in sl:
        s = psi[sl["scale_asymmetry"]]
        g0 = g0 / (1.0 + s * np.sign(g0))
    rest = g0 - b
    if "bias_drift" in sl:
        rest = rest - psi[sl["bias_drift"]] * lay.t[:, None]
    if "bias_drift_temp" in sl and replay.temp is not None:
        rest = rest - psi[sl["bias_drift_temp"]] * replay.temp[:, None]
    Kmat = np.diag(k)
    if "axis_misalignment" in sl:
        U = psi[sl["axis_misalignment"]]
        Kmat[0, 1], Kmat[0, 2], Kmat[1, 2] = U
    m = np.linalg.solve(Kmat, rest.T).T
    a_g = a if a is not None else a_design
    if "g_sensitivity" in sl and a_g is not None:
        m = m + a_g @ psi[sl["g_sensitivity"]].reshape(3, 3).T
    return replace(replay, g=g, m=m, a=a, gm=gm)


def replicate_problems(replay: Replay, rng: np.random.Generator, R: int, caps: np.ndarray | None = None,
                       a_design: np.ndarray | None = None) -> Problem:
    """R simulated recordings from the replay, as a Problem with the recording's layout."""
    gyro, accel = replay.replicates(rng, R)
    return build_problem(replay.layout, gyro, accel, replay.temp, caps, a_design)
