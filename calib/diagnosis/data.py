"""The evidence a recording holds, arranged for the diagnosis fits.

``Layout`` fixes where things are (turn windows, still blocks, the stills on either side of each
turn) and is shared by a recording and every bootstrap replicate of it. ``Problem`` holds the data
of R recordings with that layout, time-first for the turns like ``calib.estimators.closure.fit``:

- turn samples: readings m (L, R*J, 3), intervals dt, times t, specific force a, temperature;
- still blocks: each still is cut into blocks of about ``BLOCK_S``; a block's mean reading, time,
  specific force and temperature, and its number of samples. Block means carry both the still
  means (the zero-rate output over time) and, within each still, whether the noise is white;
- accelerometer tilt across each turn: the rotation between the gravity directions of the stills
  before and after it (0 when the device came back to its pose).

A window is either a full turn (it closes to the identity) or a **re-orientation** between two rests
(``REORIENTATION`` in its stage's flags): the device ends in a new pose, and its closing rotation is
taken against a reference rotation ``ref`` (the motion as a first calibration integrates it), so that
only the gravity it carries can be compared with the accelerometer (engine.py).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from calib.noise.rests import INTERPOLATED_LAGS, recordings_colours
from calib.numerics.tilt import tilt_across
from calib.recording import Recording
from calib.stages.stage import AXES, Stage

BLOCK_S = 0.5  # still block length, s
REORIENTATION = "reorientation"  # the flag of a motion between two rests that ends in a new pose


@dataclass(frozen=True)
class Layout:
    """Stage geometry of a recording, shared by its bootstrap replicates."""

    n: int
    t: np.ndarray  # (n,) s since the first sample
    dt: np.ndarray  # (n,) interval each sample is held, s
    fs: float
    turns: tuple[Stage, ...]
    stills: tuple[Stage, ...]
    stages: tuple[Stage, ...]
    turn_bounds: np.ndarray  # (J, 2)
    block_bounds: np.ndarray  # (NB, 2)
    block_still: np.ndarray  # (NB,) still index of each block
    neighbours: np.ndarray  # (J, 2) index of the still before and after each turn, -1 if none
    ref: np.ndarray | None = None  # (J, 4) reference rotation of each window (x, y, z, w); None: all identity

    @property
    def J(self) -> int:
        return len(self.turns)

    @property
    def moves(self) -> np.ndarray:
        """(J,) True for the re-orientations (windows that end in a new pose), False for full turns."""
        return np.array([REORIENTATION in s.flags for s in self.turns], dtype=bool)

    def ref_quats(self) -> np.ndarray:
        """(J, 4) reference rotation of each window, identity for full turns."""
        if self.ref is None:
            return np.tile([0.0, 0.0, 0.0, 1.0], (self.J, 1))
        return self.ref

    @property
    def NB(self) -> int:
        return int(self.block_bounds.shape[0])

    @property
    def S(self) -> int:
        return len(self.stills)

    def block_n(self) -> np.ndarray:
        return (self.block_bounds[:, 1] - self.block_bounds[:, 0]).astype(float)

    def turn_axis(self) -> np.ndarray:
        """(J,) index 0-2 of each turn's labelled axis."""
        return np.array([AXES.index(s.axis) if s.axis in AXES else 0 for s in self.turns], dtype=np.int64)

    def turn_sign(self) -> np.ndarray:
        """(J,) +1 for counter-clockwise (positive) turns, -1 for clockwise."""
        return np.array([1.0 if (s.angle_deg or 1.0) > 0 else -1.0 for s in self.turns])



def make_layout(rec: Recording, stages: list[Stage], dt: np.ndarray | None = None) -> Layout:
    """The layout of ``rec`` from its stages: every full turn, every re-orientation and every still of at least 2 samples."""
    t = rec.t - rec.t[0]
    dt = rec.intervals_s if dt is None else dt
    stages = sorted(stages, key=lambda s: s.start)
    turns = tuple(s for s in stages if (s.kind == "turn" or REORIENTATION in s.flags) and s.n >= 2)
    stills = tuple(s for s in stages if s.kind == "still" and s.n >= 2)
    blocks, owner = [], []
    for i, s in enumerate(stills):
        dur = float(t[s.end - 1] - t[s.start]) + float(dt[s.end - 1])
        nb = max(1, round(dur / BLOCK_S))
        nb = min(nb, s.n // 2) if s.n >= 4 else 1
        edges = np.linspace(s.start, s.end, nb + 1).round().astype(np.int64)
        for a, b in itertools.pairwise(edges):
            blocks.append((a, b))
            owner.append(i)
    neighbours = np.full((len(turns), 2), -1, dtype=np.int64)
    for j, tr in enumerate(turns):
        before = [i for i, s in enumerate(stills) if s.end <= tr.start]
        after = [i for i, s in enumerate(stills) if s.start >= tr.end]
        if before:
            neighbours[j, 0] = before[-1]
        if after:
            neighbours[j, 1] = after[0]
        # only the stills that touch the turn (no other motion in between) show the pose it left and found
        between = [s for s in stages if s.kind != "still" and s.start >= (stills[before[-1]].end if before else 0)
                   and s.end <= (stills[after[0]].start if after else rec.t.size) and s is not tr]
        if between:
            neighbours[j] = -1
    return Layout(
        n=len(rec),
        t=t,
        dt=dt,
        fs=rec.fs,
        turns=turns,
        stills=stills,
        stages=tuple(stages),
        turn_bounds=np.array([[s.start, s.end] for s in turns], dtype=np.int64).reshape(-1, 2),
        block_bounds=np.array(blocks, dtype=np.int64).reshape(-1, 2),
        block_still=np.array(owner, dtype=np.int64),
        neighbours=neighbours,
    )


@dataclass
class Inputs:
    """What the rate model reads, at turn samples (L, B) or still blocks (R, NB)."""

    m: np.ndarray  # (..., 3) readings, deg/s
    t: np.ndarray  # (...) s since the first sample
    a: np.ndarray | None = None  # (..., 3) specific force, g
    temp: np.ndarray | None = None  # (...) degC
    cap: np.ndarray | None = None  # (..., C) clipped-plateau shapes (signed, reading units per unit height)
    offset: np.ndarray | None = None  # (..., 3) a rate added to the model (deg/s): the expected bias wander
    doffset: np.ndarray | None = None  # (..., 3, Pr) its derivative with respect to the rate parameters

    def take(self, cols: slice) -> Inputs:
        """The turn columns ``cols`` (axis 1) of time-first inputs."""
        pick = lambda x: None if x is None else x[:, cols]
        return Inputs(self.m[:, cols], self.t[:, cols], pick(self.a), pick(self.temp), pick(self.cap),
                      pick(self.offset), pick(self.doffset))

    def turn_first(self, cols: np.ndarray | slice, length: int) -> Inputs:
        """The turn columns ``cols`` of time-first inputs through sample ``length``, turn first (B, L, ...): views for
        a slice, copies for indices."""
        def rows(x: np.ndarray) -> np.ndarray:
            return np.swapaxes(x[:length], 0, 1)[cols]

        pick = lambda x: None if x is None else rows(x)
        return Inputs(rows(self.m), rows(self.t), pick(self.a), pick(self.temp), pick(self.cap), pick(self.offset),
                      pick(self.doffset))


@dataclass(frozen=True)
class Tilts:
    """The tilt across each turn as the accelerometer measures it (R recordings, J turns)."""

    tilt: np.ndarray  # (R, J, 2) deg, in the basis below
    basis: np.ndarray  # (R, J, 2, 3) unit vectors perpendicular to gravity
    up: np.ndarray  # (R, J, 3) unit gravity direction (body frame)
    sd: np.ndarray  # (R, J) standard deviation of each tilt component, deg


@dataclass
class Problem:
    """The data of R recordings sharing one layout."""

    layout: Layout
    R: int
    turn: Inputs  # (L, R*J)
    dt: np.ndarray  # (L, R*J), 0 past each turn's end
    block: Inputs  # (R, NB)
    block_n: np.ndarray  # (NB,)
    sigma: np.ndarray  # (R, 3) reading noise std, deg/s
    within: np.ndarray  # (R, 3) within-block sum of squared deviations, for the noise estimate
    tilt: np.ndarray | None = None  # (R, J, 2) tilt across each turn in the basis below, deg
    tilt_basis: np.ndarray | None = None  # (R, J, 2, 3) unit vectors perpendicular to gravity
    up: np.ndarray | None = None  # (R, J, 3) unit gravity direction (body frame) at each turn
    tilt_sd: np.ndarray | None = None  # (R, J) standard deviation of each tilt component, deg
    accel_sigma: np.ndarray | None = None  # (R,) accelerometer noise, g

    def tilts(self) -> Tilts:
        """The accelerometer's tilt measurements; only for problems that have them (``tilt is not None``)."""
        if self.tilt is None or self.tilt_basis is None or self.up is None or self.tilt_sd is None:
            raise ValueError("this recording has no accelerometer tilts across its turns")
        return Tilts(self.tilt, self.tilt_basis, self.up, self.tilt_sd)

    @property
    def J(self) -> int:
        return self.layout.J

    @property
    def NB(self) -> int:
        return self.layout.NB

    def runs(self, idx: np.ndarray) -> Problem:
        """The data of a subset of the recordings."""
        idx = np.asarray(idx, dtype=np.int64)
        J = self.J
        cols = (idx[:, None] * J + np.arange(J)).ravel()
        pick_t = lambda x: None if x is None else x[:, cols]
        pick_r = lambda x: None if x is None else x[idx]
        turn = Inputs(self.turn.m[:, cols], self.turn.t[:, cols], pick_t(self.turn.a), pick_t(self.turn.temp),
                      pick_t(self.turn.cap))
        block = Inputs(self.block.m[idx], self.block.t[idx], pick_r(self.block.a), pick_r(self.block.temp),
                       pick_r(self.block.cap))
        return replace(self, R=int(idx.size), turn=turn, dt=self.dt[:, cols], block=block, sigma=self.sigma[idx],
                       within=self.within[idx], tilt=pick_r(self.tilt), tilt_basis=pick_r(self.tilt_basis),
                       up=pick_r(self.up), tilt_sd=pick_r(self.tilt_sd), accel_sigma=pick_r(self.accel_sigma))


def _windows(x: np.ndarray, bounds: np.ndarray, L: int) -> tuple[np.ndarray, np.ndarray]:
    """x (R, n, ...) stacked over the windows (J, 2): (L, R*J, ...) and the inside mask (L, R*J)."""
    R, n = x.shape[:2]
    J = bounds.shape[0]
    lengths = bounds[:, 1] - bounds[:, 0]
    offs = np.arange(L)
    idx = np.minimum(bounds[:, 0, None] + offs, n - 1)  # (J, L)
    inside = offs[None, :] < lengths[:, None]
    out = x[:, idx]  # (R, J, L, ...)
    out = np.where(inside.reshape((1, J, L) + (1,) * (x.ndim - 2)), out, 0.0)
    out = np.moveaxis(out.reshape((R * J, L) + x.shape[2:]), 1, 0)
    return np.ascontiguousarray(out), np.ascontiguousarray(np.tile(inside, (R, 1)).T)


def _block_means(x: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Means of x (R, n, ...) over the blocks (NB, 2): (R, NB, ...)."""
    if bounds.shape[0] == 0:
        return np.zeros((x.shape[0], 0) + x.shape[2:])
    # one pass of sums between consecutive bounds (start, end, start, end, ...); every other one is a block
    edges = bounds.ravel()
    tail = edges[-1] >= x.shape[1]
    sums = np.add.reduceat(x, edges[:-1] if tail else edges, axis=1)[:, ::2]
    n = (bounds[:, 1] - bounds[:, 0]).reshape((1, -1) + (1,) * (x.ndim - 2))
    return sums / n


def build_problem(
    layout: Layout,
    gyro: np.ndarray,
    accel: np.ndarray | None = None,
    temp: np.ndarray | None = None,
    caps: np.ndarray | None = None,
    a_design: np.ndarray | None = None,
) -> Problem:
    """The Problem of R recordings: gyro (R, n, 3), accel (R, n, 3) or None, temp (n,) or None.

    ``caps`` (n, C): the shapes of clipped plateaus (see models.plateau_caps), shared by all runs.
    ``a_design`` (n, 3): a specific force for the rate model when no accelerometer was recorded
    (gravity_proxy); it informs the g-sensitivity columns only, never the tilt evidence.
    """
    R = gyro.shape[0]
    J, bb = layout.J, layout.block_bounds
    L = int((layout.turn_bounds[:, 1] - layout.turn_bounds[:, 0]).max()) if J else 1
    tb = layout.turn_bounds if J else np.zeros((0, 2), np.int64)
    m, _ = _windows(gyro, tb, L)
    dt, _ = _windows(np.broadcast_to(layout.dt, (R, layout.n)), tb, L)
    tt, _ = _windows(np.broadcast_to(layout.t, (R, layout.n)), tb, L)
    a = _windows(accel, tb, L)[0] if accel is not None else None
    tp = _windows(np.broadcast_to(temp, (R, layout.n)), tb, L)[0] if temp is not None else None
    cp = _windows(np.broadcast_to(caps, (R,) + caps.shape), tb, L)[0] if caps is not None else None
    turn = Inputs(m, tt, a, tp, cp)

    # block statistics: means, and squared deviations about each block's own mean for the noise
    ref = gyro[:, :1]
    x = gyro - ref
    bm = _block_means(x, bb)
    b2 = _block_means(x * x, bb)
    bn = layout.block_n()
    ss = np.maximum(b2 - bm * bm, 0.0) * bn[None, :, None]  # (R, NB, 3)
    within = ss.sum(axis=1)
    dof = max(1.0, float((bn - 1).sum()))
    sigma = np.maximum(np.sqrt(within / dof), 1e-6)
    block = Inputs(
        bm + ref,
        _block_means(np.broadcast_to(layout.t, (R, layout.n))[..., None], bb)[..., 0],
        _block_means(accel, bb) if accel is not None else None,
        _block_means(np.broadcast_to(temp, (R, layout.n))[..., None], bb)[..., 0] if temp is not None else None,
        np.zeros((R, layout.NB, caps.shape[1])) if caps is not None else None,
    )
    prob = Problem(layout, R, turn, dt, block, bn, sigma, within)
    if accel is not None:
        _add_tilt(prob, accel)
    elif a_design is not None:
        set_design_accel(prob, a_design)
    return prob


def set_design_accel(prob: Problem, a: np.ndarray) -> None:
    """Use a (n, 3) as the specific force of the rate model (same for every recording of ``prob``)."""
    lay = prob.layout
    L = prob.dt.shape[0]
    tb = lay.turn_bounds if lay.J else np.zeros((0, 2), np.int64)
    prob.turn.a = _windows(np.broadcast_to(a, (prob.R, lay.n, 3)), tb, L)[0]
    prob.block.a = np.broadcast_to(_block_means(a[None], lay.block_bounds), (prob.R, lay.NB, 3)).copy()


def gravity_proxy(layout: Layout, rate_dps: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """Specific force (n, 3) in g for a recording without accelerometer, assuming gravity along ``up`` in
    the body frame at the start (the device resting flat) and following the calibrated rates after that."""
    from calib.numerics.attitude import cumulative_attitude

    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=float)
    att = cumulative_attitude(rate_dps, layout.dt)
    # the attitude before each sample: identity, then the running product
    before = np.vstack([up[None, :], att[:-1].inv().apply(up)])
    return before


def _add_tilt(prob: Problem, accel: np.ndarray) -> None:
    """Tilt across each turn from the mean specific force of the stills on either side."""
    lay = prob.layout
    R, J = prob.R, lay.J
    # accelerometer noise from the blocks: pooled within-block std, all axes
    bb = lay.block_bounds
    am = _block_means(accel, bb)
    a2 = _block_means(accel * accel, bb)
    bn = lay.block_n()
    ss = (np.maximum(a2 - am * am, 0.0) * bn[None, :, None]).sum(axis=(1, 2))
    sig_a = np.sqrt(ss / max(1.0, 3.0 * float((bn - 1).sum())))
    prob.accel_sigma = np.maximum(sig_a, 1e-6)
    if J == 0:
        return
    # a pose's mean scatters as the readings' spread times their colour (an accelerometer filtered, or interpolated
    # from a slower channel, as Polar's): the tilts say how well they are known, the fit weighs them by it
    mean_sigma = prob.accel_sigma * np.sqrt(recordings_colours(accel, [(st.start, st.end) for st in lay.stills],
                                                               INTERPOLATED_LAGS))
    still_mean = np.zeros((R, lay.S, 3))
    still_n = np.zeros(lay.S)
    for s, st in enumerate(lay.stills):
        still_mean[:, s] = accel[:, st.start : st.end].mean(axis=1)
        still_n[s] = st.n
    ref = Rotation.from_quat(lay.ref) if lay.ref is not None and J else None
    tilt = np.zeros((R, J, 2))
    basis = np.zeros((R, J, 2, 3))
    up = np.zeros((R, J, 3))
    sd = np.full((R, J), np.inf)
    for j in range(J):
        i0, i1 = lay.neighbours[j]
        if i0 < 0 or i1 < 0:
            # no clean pose before and after: a free direction with no information
            up[:, j] = [0.0, 0.0, 1.0]
            basis[:, j] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
            continue
        a0, a1 = still_mean[:, i0], still_mean[:, i1]
        if ref is not None:
            a0 = ref[j].inv().apply(a0)  # the pose before, carried into the pose after by the reference rotation
        across = tilt_across(a0, a1, still_n[i0], still_n[i1], mean_sigma)
        rho, u = across.rho_deg, across.up
        e1 = np.cross(u, np.eye(3)[np.argmin(np.abs(u), axis=1)])
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        e2 = np.cross(u, e1)
        basis[:, j, 0], basis[:, j, 1] = e1, e2
        tilt[:, j, 0] = np.einsum("ri,ri->r", rho, e1)
        tilt[:, j, 1] = np.einsum("ri,ri->r", rho, e2)
        up[:, j] = u
        sd[:, j] = across.sd_deg
    prob.tilt, prob.tilt_basis, prob.up, prob.tilt_sd = tilt, basis, up, sd
