"""The device's attitude and true rate along a protocol script, sample by sample."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, cast

import numpy as np
from scipy.spatial.transform import Rotation

from calib.effects import SimulationConfigError, Trajectory
from calib.simulator.protocol import Motion, ProtocolScript, Segment, Still, as_float, draw_turn_params
from calib.simulator.ranges import GRAVITY_UP
from calib.stages.stage import AXES, Axis, Stage


def _nd_rotations_supported() -> bool:
    try:
        Rotation.from_rotvec(np.zeros((1, 2, 3)))
    except (ValueError, TypeError):
        return False
    return True


# Stacks of shape (P, 1) take scipy's vectorised backend, several times faster than the 1-D path
# for the ~1e6 rotations of a Monte Carlo batch; they slice along P like a 1-D stack.
_ND_ROTATIONS = _nd_rotations_supported()


def _exp(rotvec: np.ndarray) -> Rotation:
    return Rotation.from_rotvec(rotvec[:, None, :] if _ND_ROTATIONS else rotvec)


def _log(rot: Rotation) -> np.ndarray:
    return rot.as_rotvec().reshape(-1, 3)


def _perp_basis(axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors u, v (m, 3) with (axis, u, v) right-handed orthonormal, for unit axes (m, 3)."""
    helper = np.eye(3)[np.argmin(np.abs(axes), axis=1)]
    u = helper - np.sum(helper * axes, axis=1, keepdims=True) * axes
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(axes, u)


def tilted_axis(axis: str | np.ndarray, tilt: np.ndarray) -> np.ndarray:
    """Unit true axis: a named body axis plus its two off-axis components, or a vector plus tilt in its perpendicular plane."""
    if isinstance(axis, str):
        i = AXES.index(axis)
        a = np.zeros(3)
        a[i] = 1.0
        a[[j for j in range(3) if j != i]] = tilt
    else:
        u, v = _perp_basis(axis[None])
        a = axis + tilt[0] * u[0] + tilt[1] * v[0]
    return a / np.linalg.norm(a)


def _bezier_progress(tau: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """Angle progress s(tau) in [0, 1] of the degree-6 Bezier curve with controls 0, 0, p1, p2, p3, 1, 1.

    ``inner`` (P, 3) holds p1..p3 per point. s' = 0 at tau = 0 and 1 (the hand starts and stops at rest).
    """
    t2 = tau * tau
    o = 1.0 - tau
    o2 = o * o
    return (
        15.0 * t2 * o2 * o2 * inner[:, 0]
        + 20.0 * t2 * tau * o2 * o * inner[:, 1]
        + 15.0 * t2 * t2 * o2 * inner[:, 2]
        + 6.0 * t2 * t2 * tau * o
        + t2 * t2 * t2
    )


def segment_motion(
    lengths: np.ndarray,
    axes: np.ndarray,
    angles_rad: np.ndarray,
    profiles: np.ndarray,
    wobble_rad: np.ndarray,
    dt: float,
    poses: bool = False,
) -> tuple[np.ndarray, np.ndarray | None]:
    """True body rates (deg/s) of m smooth rotations, all at once; optionally their local poses.

    Segment j has ``lengths[j]`` samples and local poses Q(tau) = Exp(theta s(tau) a) Exp(w(s)) for
    tau = 0, 1/N, .., 1, with s the Bezier angle progress (s' = 0 at both ends) and w the wobble
    (zero at both ends). Returns rates (sum N, 3), segment after segment, each Log(Q_i^-1 Q_{i+1})/dt,
    and, if asked, the local poses as quaternions (sum (N + 1), 4).
    """
    lengths = np.asarray(lengths, dtype=np.int64)
    m = lengths.size
    npose = lengths + 1
    seg = np.repeat(np.arange(m), npose)
    j = np.arange(int(npose.sum())) - np.repeat(np.cumsum(npose) - npose, npose)
    u, v = _perp_basis(axes)
    # One gather of everything per-segment: rotation vector of the whole turn (3), wobble direction
    # of sin(pi s) (3) and of sin(2 pi s) (3), inner Bezier controls (3), 1 / N.
    wob_dirs = np.einsum("mhc,mcx->mhx", wobble_rad, np.stack([u, v], axis=1))  # (m, 2, 3)
    table = np.concatenate(
        [axes * angles_rad[:, None], wob_dirs.reshape(m, 6), profiles, 1.0 / lengths[:, None]], axis=1
    )[seg]
    last = j == lengths[seg]
    ends = (j == 0) | last
    s = _bezier_progress(j * table[:, 12], table[:, 9:12])
    s[last] = 1.0  # exact end of the turn, whatever the rounding of the polynomial

    # wobble w(s) = sin(pi s) d1 + sin(2 pi s) d2, exactly zero at both ends
    sin1 = np.sin(np.pi * s)
    sin2 = 2.0 * sin1 * np.cos(np.pi * s)
    sin1[ends] = 0.0
    sin2[ends] = 0.0
    w = sin1[:, None] * table[:, 3:6] + sin2[:, None] * table[:, 6:9]

    # Relative rotation between consecutive poses; the pairs that straddle two segments are
    # computed with a zero step and dropped.
    ds = np.diff(s)
    ds[last[:-1]] = 0.0
    if np.any(np.abs(ds) * np.abs(angles_rad)[seg[:-1]] >= 0.9 * np.pi):
        raise SimulationConfigError("a turn or motion is too fast for the sample rate (over 160 deg per sample); make it longer")
    wob = _exp(w)
    rel = wob[:-1].inv() * _exp(ds[:, None] * table[:-1, 0:3]) * wob[1:]
    rates = np.degrees(_log(rel)[~last[:-1]]) / dt
    quats = None
    if poses:
        quats = (_exp(s[:, None] * table[:, 0:3]) * wob).as_quat().reshape(-1, 4)
    return rates, quats


@dataclass(frozen=True)
class _Resolved:
    kind: Literal["still", "turn", "motion"]
    n: int
    axis: np.ndarray | None = None
    label: Axis | None = None
    angle_deg: float = 0.0
    profile: np.ndarray | None = None
    wobble_deg: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))


def n_samples_of(duration_s: float, fs: float, what: str, minimum: int) -> int:
    n = int(round(duration_s * fs))
    if n < minimum:
        raise SimulationConfigError(f"{what} of {duration_s} s is under {minimum} samples at {fs} Hz; make it longer")
    return n


def _resolve(seg: Segment, fs: float, rng: np.random.Generator) -> _Resolved:
    if isinstance(seg, Still):
        return _Resolved("still", n_samples_of(seg.duration_s, fs, "Still", 1))
    if isinstance(seg, Motion):
        rotvec = np.asarray(seg.rotvec_deg, dtype=float)
        angle = float(np.linalg.norm(rotvec))
        axis = rotvec / angle if angle > 0 else np.array([1.0, 0.0, 0.0])
        profile = np.asarray(seg.profile if seg.profile is not None else draw_turn_params(rng, 1)["profile"][0], dtype=float)
        return _Resolved("motion", n_samples_of(seg.duration_s, fs, "Motion", 2), axis, None, angle, profile)
    need = seg.duration_s is None or seg.tilt is None or seg.profile is None or not isinstance(seg.wobble_deg, np.ndarray)
    drawn = {k: v[0] for k, v in draw_turn_params(rng, 1).items()} if need else {}
    duration = seg.duration_s if seg.duration_s is not None else float(drawn["duration_s"])
    named: str | np.ndarray = seg.axis if isinstance(seg.axis, str) else np.asarray(seg.axis, dtype=float)
    label: Axis
    if isinstance(named, str):
        tilt = np.asarray(seg.tilt if seg.tilt is not None else drawn["tilt"], dtype=float)
        label = cast(Axis, named)
    else:
        tilt = np.asarray(seg.tilt, dtype=float) if seg.tilt is not None else np.zeros(2)
        label = AXES[int(np.argmax(np.abs(named)))]
    if isinstance(seg.wobble_deg, np.ndarray):
        wobble = seg.wobble_deg
    else:
        wobble = drawn["wobble_deg"]
        if seg.wobble_deg is not None:  # an amplitude: rescale the drawn coefficients to it
            wobble = wobble * (seg.wobble_deg / np.max(np.abs(wobble))) if np.any(wobble) else wobble
    return _Resolved(
        "turn",
        n_samples_of(duration, fs, "Turn", 2),
        tilted_axis(named, tilt),
        label,
        seg.angle_deg,
        np.asarray(seg.profile if seg.profile is not None else drawn["profile"], dtype=float),
        np.asarray(wobble, dtype=float),
    )


def build_trajectory(script: ProtocolScript, fs: float, rng: np.random.Generator) -> Trajectory:
    """The true motion of ``script`` sampled at ``fs`` Hz, starting flat (z up) at the identity pose.

    Random choices the script leaves open are drawn from ``rng``.
    """
    if not isinstance(script, ProtocolScript):
        raise SimulationConfigError(f"script must be a ProtocolScript; got {type(script).__name__}")
    fs = as_float(fs, "fs")
    dt = 1.0 / fs
    res = [_resolve(seg, fs, rng) for seg in script.segments]
    moving = [r for r in res if r.kind != "still"]
    rates_flat, quats_flat = np.empty((0, 3)), np.empty((0, 4))
    if moving:
        rates_flat, poses_flat = segment_motion(
            np.array([r.n for r in moving]),
            np.array([r.axis for r in moving]),
            np.radians([r.angle_deg for r in moving]),
            np.array([r.profile for r in moving]),
            np.radians(np.array([r.wobble_deg for r in moving])),
            dt,
            poses=True,
        )
        assert poses_flat is not None  # asked for with poses=True
        quats_flat = poses_flat
    n = sum(r.n for r in res)
    rate = np.zeros((n, 3))
    quats = np.empty((n + 1, 4))
    pose = Rotation.identity()
    pos = rpos = qpos = 0
    stages: list[Stage] = []
    axes: list[np.ndarray | None] = []
    for r in res:
        end = pos + r.n
        if r.kind == "still":
            quats[pos : end + 1] = pose.as_quat()
        else:
            local = Rotation.from_quat(quats_flat[qpos : qpos + r.n + 1])
            track = pose * local
            quats[pos : end + 1] = track.as_quat()
            rate[pos:end] = rates_flat[rpos : rpos + r.n]
            pose = track[-1]
            rpos += r.n
            qpos += r.n + 1
        stages.append(
            Stage(r.kind, pos, end, pos * dt, end * dt, r.label, r.angle_deg if r.kind == "turn" else None)
        )
        axes.append(None if r.axis is None else r.axis.copy())
        pos = end
    attitude = Rotation.from_quat(quats)
    accel = attitude[:n].inv().apply(GRAVITY_UP)
    t = np.arange(n) * dt
    return Trajectory(t, t.copy(), rate, attitude, accel, tuple(stages), tuple(axes), fs)
