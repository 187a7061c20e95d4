"""Protocol simulator: recordings of the calibration protocol with known sensor parameters.

Follows the paper's Section 3: scale factors k ~ U(0.8, 1.2), biases b ~ U(-5, 5) deg/s, each turn's
true axis tilted by U(-0.1, 0.1) per off-axis component, white reading noise N(0, sigma^2), 104 Hz,
3 s rest, 360 deg turns about x, y, z with a random Bezier speed profile, 3 s pauses, a final rest.

The true motion is a sampled attitude trajectory R_0 .. R_n (body to start frame). The true rate of
sample i is g_i = Log(R_i^-1 R_{i+1}) / dt, so the product of Exp(g_i dt) over a turn is exactly the
turn's rotation: a full turn closes to the start pose to rounding error and the simulator adds no
closure error of its own. Readings follow eq. (1) inverted: m = (g - b) / k + noise, so g = K m + b.

Units: rates deg/s, times s, accelerometer g, angles deg (radians only internally).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from .effects import (
    Effect,
    Saturation,
    SensorContext,
    SensorOutput,
    SimulationConfigError,
    Trajectory,
    check_effects,
)
from .recording import Recording, RecordingMeta
from .stage import AXES, Stage

__all__ = [
    "Motion",
    "ProtocolScript",
    "SensorParams",
    "SimBatch",
    "SimulationConfigError",
    "Still",
    "Truth",
    "Turn",
    "build_trajectory",
    "extended_protocol_script",
    "paper_protocol_script",
    "script_duration_s",
    "simulate",
    "simulate_batch",
]

# Paper Section 3 distributions and the protocol of Section 2.3.
K_RANGE = (0.8, 1.2)  # scale factor, dimensionless
B_RANGE_DPS = (-5.0, 5.0)  # bias, deg/s of true rate
TILT_RANGE = 0.1  # off-axis component of a turn's true axis, U(-0.1, 0.1) each
TURN_DURATION_S = (2.5, 5.0)  # hand turn duration, uniform
WOBBLE_DEG = (0.5, 3.0)  # hand wobble amplitude, uniform
STILL_S = 3.0  # rest before, between and after the turns
ACCEL_NOISE_G = 0.002
GRAVITY_UP = np.array([0.0, 0.0, 1.0])  # specific force at rest, start frame, g

_BEZIER_DEGREE = 6  # control points 0, 0, p1, p2, p3, 1, 1: zero rate at both ends
_N_PROFILE = _BEZIER_DEGREE - 3
_WOBBLE_HARMONIC_SCALE = np.array([1.0, 0.5])  # amplitude of sin(pi s), sin(2 pi s)


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


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True, eq=False)
class SensorParams:
    """Parameters of g = K m + b (eq. 1): scale factors ``k`` (3,) and biases ``b`` (3,) in deg/s of true rate."""

    k: np.ndarray
    b: np.ndarray

    def __post_init__(self) -> None:
        k = np.asarray(self.k, dtype=float)
        b = np.asarray(self.b, dtype=float)
        if k.shape != (3,) or not np.all(np.isfinite(k)) or np.any(k <= 0):
            raise SimulationConfigError(f"SensorParams.k must be 3 positive scale factors (x, y, z); got {self.k!r}")
        if b.shape != (3,) or not np.all(np.isfinite(b)):
            raise SimulationConfigError(f"SensorParams.b must be 3 finite biases in deg/s (x, y, z); got {self.b!r}")
        object.__setattr__(self, "k", k)
        object.__setattr__(self, "b", b)

    @classmethod
    def paper_random(cls, rng: np.random.Generator) -> SensorParams:
        """k ~ U(0.8, 1.2), b ~ U(-5, 5) deg/s per axis (paper Section 3)."""
        return cls(rng.uniform(*K_RANGE, 3), rng.uniform(*B_RANGE_DPS, 3))

    def reading(self, rate_dps: np.ndarray) -> np.ndarray:
        """Noise-free readings m = (g - b) / k (deg/s) for true rates g (..., 3)."""
        return (np.asarray(rate_dps) - self.b) / self.k

    def true_rate(self, m: np.ndarray) -> np.ndarray:
        """True rates g = K m + b (deg/s) for readings m (..., 3)."""
        return np.asarray(m) * self.k + self.b


# --------------------------------------------------------------------------- protocol script


def _float(value: Any, what: str, positive: bool = True) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise SimulationConfigError(f"{what} must be a number; got {value!r}") from None
    if not np.isfinite(v) or (positive and v <= 0):
        raise SimulationConfigError(f"{what} must be a {'positive ' if positive else ''}finite number; got {value!r}")
    return v


def _profile(value: Any, what: str) -> np.ndarray | None:
    if value is None:
        return None
    p = np.asarray(value, dtype=float)
    if p.shape != (_N_PROFILE,) or np.any(p < 0) or np.any(p > 1) or np.any(np.diff(p) < 0):
        raise SimulationConfigError(
            f"{what}.profile must be {_N_PROFILE} increasing numbers in [0, 1] (inner Bezier control points); got {value!r}"
        )
    return p


@dataclass(frozen=True, eq=False)
class Still:
    """The device rests for ``duration_s`` seconds."""

    duration_s: float = STILL_S

    def __post_init__(self) -> None:
        object.__setattr__(self, "duration_s", _float(self.duration_s, "Still.duration_s"))


@dataclass(frozen=True, eq=False)
class Turn:
    """A hand turn by ``angle_deg`` (signed, right-handed) about a body axis.

    ``axis``: 'x', 'y', 'z' or a 3-vector (the exact true axis). ``duration_s``: None draws
    U(2.5, 5) s. ``tilt``: for a named axis, the two off-axis components of the true axis
    (x: (y, z), y: (x, z), z: (x, y)); None draws U(-0.1, 0.1) each, 0 means none; for a vector
    axis None means none. ``wobble_deg``: hand wobble about the other axes, zero at both ends; a
    number is an amplitude bound (coefficients drawn), a (2, 2) array gives the coefficients of
    sin(pi s) and sin(2 pi s) (rows) along two axes perpendicular to the turn axis (columns), in deg;
    None draws an amplitude in U(0.5, 3) deg. ``profile``: the 3 inner Bezier control points of the
    angle progress s(tau) (None: random).
    """

    axis: str | ArrayLike = "x"
    angle_deg: float = 360.0
    duration_s: float | None = None
    wobble_deg: float | ArrayLike | None = None
    tilt: float | ArrayLike | None = None
    profile: ArrayLike | None = None

    def __post_init__(self) -> None:
        if isinstance(self.axis, str):
            if self.axis not in AXES:
                raise SimulationConfigError(f"Turn.axis must be 'x', 'y', 'z' or a 3-vector; got {self.axis!r}")
        else:
            a = np.asarray(self.axis, dtype=float)
            if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) < 1e-9:
                raise SimulationConfigError(f"Turn.axis must be 'x', 'y', 'z' or a nonzero 3-vector; got {self.axis!r}")
            object.__setattr__(self, "axis", a / np.linalg.norm(a))
        angle = _float(self.angle_deg, "Turn.angle_deg", positive=False)
        if angle == 0:
            raise SimulationConfigError("Turn.angle_deg must be nonzero (use Still for no motion)")
        object.__setattr__(self, "angle_deg", angle)
        if self.duration_s is not None:
            object.__setattr__(self, "duration_s", _float(self.duration_s, "Turn.duration_s"))
        if self.tilt is not None:
            t = np.asarray(self.tilt, dtype=float)
            if t.shape == () and t == 0:
                t = np.zeros(2)
            if t.shape != (2,) or not np.all(np.isfinite(t)):
                raise SimulationConfigError(
                    f"Turn.tilt must be None (random), 0 (none) or two off-axis components; got {self.tilt!r}"
                )
            object.__setattr__(self, "tilt", t)
        if self.wobble_deg is not None:
            w = np.asarray(self.wobble_deg, dtype=float)
            if not (w.shape in ((), (2, 2)) and np.all(np.isfinite(w)) and (w.shape != () or w >= 0)):
                raise SimulationConfigError(
                    "Turn.wobble_deg must be None, an amplitude >= 0 in deg or a (2, 2) array of coefficients; "
                    f"got {self.wobble_deg!r}"
                )
            object.__setattr__(self, "wobble_deg", float(w) if w.shape == () else w)
        object.__setattr__(self, "profile", _profile(self.profile, "Turn"))


@dataclass(frozen=True, eq=False)
class Motion:
    """A smooth re-orientation by rotation vector ``rotvec_deg`` (body axes, deg) that does not come back.

    Later segments continue from the new pose. ``profile`` as for ``Turn`` (None: random).
    """

    rotvec_deg: ArrayLike = (0.0, 0.0, 90.0)
    duration_s: float = 1.5
    profile: ArrayLike | None = None

    def __post_init__(self) -> None:
        r = np.asarray(self.rotvec_deg, dtype=float)
        if r.shape != (3,) or not np.all(np.isfinite(r)):
            raise SimulationConfigError(f"Motion.rotvec_deg must be 3 finite numbers in deg; got {self.rotvec_deg!r}")
        object.__setattr__(self, "rotvec_deg", r)
        object.__setattr__(self, "duration_s", _float(self.duration_s, "Motion.duration_s"))
        object.__setattr__(self, "profile", _profile(self.profile, "Motion"))


Segment = Still | Turn | Motion


@dataclass(frozen=True, eq=False)
class ProtocolScript:
    """What the hand does, in order: a sequence of ``Still``, ``Turn`` and ``Motion`` segments."""

    segments: tuple[Segment, ...] = ()

    def __post_init__(self) -> None:
        segs = tuple(self.segments)
        if not segs:
            raise SimulationConfigError("ProtocolScript needs at least one segment (Still, Turn or Motion)")
        for s in segs:
            if not isinstance(s, (Still, Turn, Motion)):
                raise SimulationConfigError(
                    f"ProtocolScript segments must be Still, Turn or Motion; got {type(s).__name__}"
                )
        object.__setattr__(self, "segments", segs)

    @property
    def turns(self) -> tuple[Turn, ...]:
        return tuple(s for s in self.segments if isinstance(s, Turn))


def _draw_turn_params(rng: np.random.Generator, m: int) -> dict[str, np.ndarray]:
    """Random hand-turn parameters for m turns (paper Section 3 and Section 2.3)."""
    amp = rng.uniform(*WOBBLE_DEG, m)
    return {
        "duration_s": rng.uniform(*TURN_DURATION_S, m),
        "tilt": rng.uniform(-TILT_RANGE, TILT_RANGE, (m, 2)),
        "wobble_deg": amp[:, None, None] * rng.uniform(-1.0, 1.0, (m, 2, 2)) * _WOBBLE_HARMONIC_SCALE[None, :, None],
        "profile": np.sort(rng.uniform(0.0, 1.0, (m, _N_PROFILE)), axis=1),
    }


def _turn_angles(angle_deg: float | ArrayLike) -> np.ndarray:
    angles = np.asarray(angle_deg, dtype=float)
    if angles.ndim == 0:
        angles = np.full(3, float(angles))
    if angles.shape != (3,) or not np.all(np.isfinite(angles)) or np.any(angles == 0):
        raise SimulationConfigError(f"angle_deg must be one nonzero angle or three (x, y, z turns), in deg; got {angle_deg!r}")
    return angles


def paper_protocol_script(
    rng: np.random.Generator | None = None,
    angle_deg: float | ArrayLike = 360.0,
    still_s: float = STILL_S,
    final_still_s: float = STILL_S,
) -> ProtocolScript:
    """The protocol of Section 2.3: rest, turn x, rest, turn y, rest, turn z, final rest.

    ``angle_deg``: one signed angle for all turns or one per turn (x, y, z). With ``rng`` every
    random choice of the turns (duration, tilt, wobble, speed profile) is drawn now and fixed in the
    script; without, ``simulate`` draws them.
    """
    angles = _turn_angles(angle_deg)
    drawn = _draw_turn_params(rng, 3) if rng is not None else None
    segs: list[Segment] = [Still(still_s)]
    for i, axis in enumerate(AXES):
        if drawn is None:
            segs.append(Turn(axis, float(angles[i])))
        else:
            segs.append(
                Turn(
                    axis,
                    float(angles[i]),
                    duration_s=float(drawn["duration_s"][i]),
                    wobble_deg=drawn["wobble_deg"][i],
                    tilt=drawn["tilt"][i],
                    profile=drawn["profile"][i],
                )
            )
        segs.append(Still(still_s if i < 2 else final_still_s))
    return ProtocolScript(tuple(segs))


EXTENDED_SLOW_S = (6.0, 8.0)  # slow turn duration, s: mean rate 45-60 deg/s
EXTENDED_FAST_S = (1.2, 1.8)  # fast turn duration, s: mean rate 200-300 deg/s, peaks near 500 deg/s


def extended_protocol_script(
    rng: np.random.Generator | None = None,
    still_s: float = STILL_S,
    slow_s: tuple[float, float] = EXTENDED_SLOW_S,
    fast_s: tuple[float, float] = EXTENDED_FAST_S,
) -> ProtocolScript:
    """The paper protocol extended for the effects that need more than one turn per axis.

    Rest, then for each axis x, y, z in turn: +360 deg slow, -360 deg slow, +360 deg fast, -360 deg
    fast, each followed by a rest of ``still_s``. Direction and speed vary independently (2 x 2 per
    axis), so scale asymmetry (direction) and scale nonlinearity (speed) show separately. With
    ``rng`` the durations (uniform in ``slow_s`` / ``fast_s``, s), tilts, wobbles and speed profiles
    are drawn now; without, the durations are the middles of the ranges and ``simulate`` draws the rest.
    """
    for what, (lo, hi) in (("slow_s", slow_s), ("fast_s", fast_s)):
        if not (0 < lo <= hi and np.isfinite(hi)):
            raise SimulationConfigError(f"{what} must be a range (low, high) of positive durations in s; got {(lo, hi)!r}")
    kinds = [(sign, rng_range) for rng_range in (slow_s, fast_s) for sign in (1.0, -1.0)]
    n = 3 * len(kinds)
    drawn = _draw_turn_params(rng, n) if rng is not None else None
    segs: list[Segment] = [Still(still_s)]
    j = 0
    for axis in AXES:
        for sign, (lo, hi) in kinds:
            if drawn is None:
                segs.append(Turn(axis, sign * 360.0, duration_s=0.5 * (lo + hi)))
            else:
                segs.append(
                    Turn(
                        axis,
                        sign * 360.0,
                        duration_s=float(rng.uniform(lo, hi)),
                        wobble_deg=drawn["wobble_deg"][j],
                        tilt=drawn["tilt"][j],
                        profile=drawn["profile"][j],
                    )
                )
            segs.append(Still(still_s))
            j += 1
    return ProtocolScript(tuple(segs))


def script_duration_s(script: ProtocolScript) -> float:
    """Total duration of a script (s) whose durations are all fixed (turns with ``duration_s`` set)."""
    total = 0.0
    for s in script.segments:
        d = s.duration_s
        if d is None:
            raise SimulationConfigError("the script leaves a turn duration open; fix it (duration_s) to know the total")
        total += d
    return total


# --------------------------------------------------------------------------- motion construction


def _perp_basis(axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors u, v (m, 3) with (axis, u, v) right-handed orthonormal, for unit axes (m, 3)."""
    helper = np.eye(3)[np.argmin(np.abs(axes), axis=1)]
    u = helper - np.sum(helper * axes, axis=1, keepdims=True) * axes
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(axes, u)


def _tilted_axis(axis: str | np.ndarray, tilt: np.ndarray) -> np.ndarray:
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


def _segment_motion(
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
    label: str | None = None
    angle_deg: float = 0.0
    profile: np.ndarray | None = None
    wobble_deg: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))


def _n_samples(duration_s: float, fs: float, what: str, minimum: int) -> int:
    n = int(round(duration_s * fs))
    if n < minimum:
        raise SimulationConfigError(f"{what} of {duration_s} s is under {minimum} samples at {fs} Hz; make it longer")
    return n


def _resolve(seg: Segment, fs: float, rng: np.random.Generator) -> _Resolved:
    if isinstance(seg, Still):
        return _Resolved("still", _n_samples(seg.duration_s, fs, "Still", 1))
    if isinstance(seg, Motion):
        angle = float(np.linalg.norm(seg.rotvec_deg))
        axis = seg.rotvec_deg / angle if angle > 0 else np.array([1.0, 0.0, 0.0])
        profile = seg.profile if seg.profile is not None else _draw_turn_params(rng, 1)["profile"][0]
        return _Resolved("motion", _n_samples(seg.duration_s, fs, "Motion", 2), axis, None, angle, profile)
    need = seg.duration_s is None or seg.tilt is None or seg.profile is None or not isinstance(seg.wobble_deg, np.ndarray)
    drawn = {k: v[0] for k, v in _draw_turn_params(rng, 1).items()} if need else {}
    duration = seg.duration_s if seg.duration_s is not None else float(drawn["duration_s"])
    if isinstance(seg.axis, str):
        tilt = seg.tilt if seg.tilt is not None else drawn["tilt"]
        label = seg.axis
    else:
        tilt = seg.tilt if seg.tilt is not None else np.zeros(2)
        label = AXES[int(np.argmax(np.abs(seg.axis)))]
    if isinstance(seg.wobble_deg, np.ndarray):
        wobble = seg.wobble_deg
    else:
        wobble = drawn["wobble_deg"]
        if seg.wobble_deg is not None:  # an amplitude: rescale the drawn coefficients to it
            wobble = wobble * (seg.wobble_deg / np.max(np.abs(wobble))) if np.any(wobble) else wobble
    return _Resolved(
        "turn",
        _n_samples(duration, fs, "Turn", 2),
        _tilted_axis(seg.axis, tilt),
        label,
        seg.angle_deg,
        seg.profile if seg.profile is not None else drawn["profile"],
        wobble,
    )


def build_trajectory(script: ProtocolScript, fs: float, rng: np.random.Generator) -> Trajectory:
    """The true motion of ``script`` sampled at ``fs`` Hz, starting flat (z up) at the identity pose.

    Random choices the script leaves open are drawn from ``rng``.
    """
    if not isinstance(script, ProtocolScript):
        raise SimulationConfigError(f"script must be a ProtocolScript; got {type(script).__name__}")
    fs = _float(fs, "fs")
    dt = 1.0 / fs
    res = [_resolve(seg, fs, rng) for seg in script.segments]
    moving = [r for r in res if r.kind != "still"]
    if moving:
        rates_flat, quats_flat = _segment_motion(
            np.array([r.n for r in moving]),
            np.array([r.axis for r in moving]),
            np.radians([r.angle_deg for r in moving]),
            np.array([r.profile for r in moving]),
            np.radians(np.array([r.wobble_deg for r in moving])),
            dt,
            poses=True,
        )
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


# --------------------------------------------------------------------------- single recording


@dataclass(frozen=True, eq=False)
class Truth:
    """What really happened in a simulated recording.

    ``k``, ``b``: eq. (1) parameters (b in deg/s of true rate). ``turn_axes``: rows are the true unit
    axes of the first turn about x, y and z (NaN if there is none). ``stages``: the true segments,
    sample indices into the returned recording (after any lost samples), times on the device clock.
    ``rate``: true rate (deg/s) at each row of the recording. ``trajectory``: the full generated motion.
    ``t_true``: the true time of each row (s; differs from the recording's device times under a clock error).
    """

    k: np.ndarray
    b: np.ndarray
    noise_dps: float
    fs: float
    turn_axes: np.ndarray
    stages: tuple[Stage, ...]
    effects: tuple[dict[str, Any], ...]
    seed: int
    accel_noise_g: float
    full_scale_dps: float | None
    segment_axes: tuple[np.ndarray | None, ...]
    rate: np.ndarray
    trajectory: Trajectory
    t_true: np.ndarray | None = None  # (n,) true time of each row of the recording, s

    @property
    def params(self) -> SensorParams:
        return SensorParams(self.k, self.b)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: k, b, noise_dps, fs, turn_axes, stages, effects, seed, accel_noise_g, full_scale_dps."""
        stages = []
        for st, ax in zip(self.stages, self.segment_axes, strict=False):
            d = st.to_dict()
            d["axis_vector"] = None if ax is None else [round(float(v), 12) for v in ax]
            stages.append(d)
        return {
            "k": [float(v) for v in self.k],
            "b": [float(v) for v in self.b],
            "noise_dps": self.noise_dps,
            "fs": self.fs,
            "turn_axes": [[None if np.isnan(v) else float(v) for v in row] for row in self.turn_axes],
            "stages": stages,
            "effects": [dict(e) for e in self.effects],
            "seed": self.seed,
            "accel_noise_g": self.accel_noise_g,
            "full_scale_dps": self.full_scale_dps,
        }


def _check_seed(seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SimulationConfigError(f"seed must be a whole number >= 0; got {seed!r}")
    return int(seed)


def simulate(
    seed: int,
    noise: float = 0.03,
    fs: float = 104.0,
    params: SensorParams | None = None,
    script: ProtocolScript | None = None,
    effects: Sequence[Effect] = (),
    full_scale_dps: float | None = None,
    *,
    resolution_dps: float | None = None,
    accel_noise_g: float = ACCEL_NOISE_G,
) -> tuple[Recording, Truth]:
    """Simulate one recording of ``script`` (default: the paper protocol, random per seed).

    ``noise``: white-noise std of the gyro readings (deg/s). ``fs``: sample rate (Hz). ``params``:
    None draws k ~ U(0.8, 1.2), b ~ U(-5, 5) deg/s. ``full_scale_dps`` (and ``resolution_dps``) add a
    ``Saturation`` effect. The accelerometer reads gravity in body axes (g) plus N(0, accel_noise_g^2).
    Returns the recording (t = i / fs, seq = i, both with gaps if samples are lost) and the truth.
    Same seed and arguments give the same result.
    """
    seed = _check_seed(seed)
    noise = _float(noise, "noise", positive=False)
    accel_noise_g = _float(accel_noise_g, "accel_noise_g", positive=False)
    if noise < 0 or accel_noise_g < 0:
        raise SimulationConfigError("noise and accel_noise_g are standard deviations and must be >= 0")
    if params is not None and not isinstance(params, SensorParams):
        raise SimulationConfigError(f"params must be a SensorParams(k, b) or None; got {type(params).__name__}")
    effects = check_effects(effects)
    if full_scale_dps is not None or resolution_dps is not None:
        if full_scale_dps is None:
            raise SimulationConfigError("resolution_dps needs full_scale_dps (the gyro range in deg/s)")
        effects = effects + (Saturation(full_scale_dps, resolution_dps),)

    ss_params, ss_script, ss_traj, ss_noise, ss_fx = np.random.SeedSequence(seed).spawn(5)
    if params is None:
        params = SensorParams.paper_random(np.random.default_rng(ss_params))
    if script is None:
        script = paper_protocol_script(np.random.default_rng(ss_script))
    fx_rngs = [np.random.default_rng(s) for s in ss_fx.spawn(len(effects))]

    traj = build_trajectory(script, fs, np.random.default_rng(ss_traj))
    for e, r in zip(effects, fx_rngs, strict=False):
        traj = e.on_trajectory(traj, r)

    ctx = SensorContext(traj.t, traj.rate, traj.accel, params.k, params.b, traj.fs, noise)
    m = params.reading(traj.rate)
    for e, r in zip(effects, fx_rngs, strict=False):
        m = e.on_sensor(m, ctx, r)
    noise_rng = np.random.default_rng(ss_noise)
    gyro = m + noise * noise_rng.standard_normal(m.shape)
    accel = traj.accel + accel_noise_g * noise_rng.standard_normal(traj.accel.shape)

    idx = np.arange(traj.n, dtype=np.int64)
    out = SensorOutput(traj.t_device.copy(), gyro, accel, idx.copy(), idx, t_true=traj.t.copy())
    for e, r in zip(effects, fx_rngs, strict=False):
        out = e.on_output(out, r)
    if out.t.size < 2:
        raise SimulationConfigError("the effects left fewer than 2 samples; lose fewer samples")

    stages, turn_axes = _true_stages(traj, out)
    rec = Recording(
        out.t,
        out.gyro,
        out.accel,
        out.seq,
        out.temp,
        RecordingMeta(
            sample_rate_hz=traj.fs,
            device_id=f"sim-{seed}",
            sensor_model="simulated",
            gyro_full_scale_dps=out.full_scale_dps,
            source=f"simulate(seed={seed})",
        ),
    )
    truth = Truth(
        k=params.k.copy(),
        b=params.b.copy(),
        noise_dps=noise,
        fs=traj.fs,
        turn_axes=turn_axes,
        stages=stages,
        effects=tuple(e.to_dict() for e in effects),
        seed=seed,
        accel_noise_g=accel_noise_g,
        full_scale_dps=out.full_scale_dps,
        segment_axes=traj.segment_axes,
        rate=traj.rate[out.index],
        trajectory=traj,
        t_true=traj.t[out.index],
    )
    return rec, truth


def _true_stages(traj: Trajectory, out: SensorOutput) -> tuple[tuple[Stage, ...], np.ndarray]:
    """Stages re-indexed to the delivered rows, on the device clock, with saturation / gap flags."""
    t_dev = np.append(traj.t_device, traj.t_device[-1] + traj.dt if traj.n else 0.0)
    lost = np.ones(traj.n, dtype=bool)
    lost[out.index] = False
    lost_before = np.concatenate([[0], np.cumsum(lost)])
    stages: list[Stage] = []
    turn_axes = np.full((3, 3), np.nan)
    for st, ax in zip(traj.stages, traj.segment_axes, strict=False):
        r0 = int(np.searchsorted(out.index, st.start))
        r1 = int(np.searchsorted(out.index, st.end))
        flags: list[str] = []
        if out.full_scale_dps is not None and r1 > r0 and np.any(np.abs(out.gyro[r0:r1]) >= out.full_scale_dps):
            flags.append("saturated")
        if lost_before[st.end] - lost_before[st.start] > 0:
            flags.append("counter_gap")
        times = {"start_s": float(t_dev[st.start]), "end_s": float(t_dev[st.end])}
        stages.append(replace(st, start=r0, end=r1, flags=tuple(flags), **times))
        if st.kind == "turn" and st.axis is not None and np.isnan(turn_axes[AXES.index(st.axis), 0]):
            turn_axes[AXES.index(st.axis)] = ax
    return tuple(stages), turn_axes


# --------------------------------------------------------------------------- Monte Carlo batch


@dataclass(frozen=True, eq=False)
class SimBatch:
    """Many paper-protocol runs on a common time base, for the Monte Carlo benchmark.

    ``gyro`` (R, n, 3) readings m (deg/s); ``rate`` (R, n, 3) true rates (deg/s); sample bounds
    [start, end): ``still0`` (R, 2), ``turns`` (R, 3, 2) for the x, y, z turns, ``stills`` (R, 4, 2)
    (initial rest, two pauses, final rest up to n; runs are padded at the end with rest).
    ``k_true``, ``b_true`` (R, 3); ``turn_axes`` (R, 3, 3) true unit turn axes (rows x, y, z).
    """

    t: np.ndarray
    gyro: np.ndarray
    rate: np.ndarray
    still0: np.ndarray
    turns: np.ndarray
    stills: np.ndarray
    k_true: np.ndarray
    b_true: np.ndarray
    dt: float
    noise: float
    fs: float
    turn_axes: np.ndarray
    angle_deg: np.ndarray  # (3,) signed turn angles, deg
    tilt: np.ndarray  # (R, 3, 2)
    wobble_deg: np.ndarray  # (R, 3, 2, 2)
    profile: np.ndarray  # (R, 3, 3)

    @property
    def n_runs(self) -> int:
        return int(self.gyro.shape[0])

    def params(self, run: int) -> SensorParams:
        """The sensor parameters of one run."""
        return SensorParams(self.k_true[run], self.b_true[run])

    def script(self, run: int) -> ProtocolScript:
        """A fully fixed ``ProtocolScript`` that makes ``simulate`` reproduce this run's motion."""
        segs: list[Segment] = [Still((self.still0[run, 1] - self.still0[run, 0]) / self.fs)]
        for i, axis in enumerate(AXES):
            a, b = self.turns[run, i]
            segs.append(
                Turn(
                    axis,
                    float(self.angle_deg[i]),
                    duration_s=(b - a) / self.fs,
                    wobble_deg=self.wobble_deg[run, i],
                    tilt=self.tilt[run, i],
                    profile=self.profile[run, i],
                )
            )
            s0, s1 = self.stills[run, i + 1]
            segs.append(Still((s1 - s0) / self.fs))
        return ProtocolScript(tuple(segs))


def _batch_params(params: Any, n_runs: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    if params is None:
        return rng.uniform(*K_RANGE, (n_runs, 3)), rng.uniform(*B_RANGE_DPS, (n_runs, 3))
    if isinstance(params, SensorParams):
        k, b = params.k, params.b
    else:
        try:
            k, b = params
        except (TypeError, ValueError):
            raise SimulationConfigError(
                "params must be None, a SensorParams or a pair (k, b) of (3,) or (n_runs, 3) arrays"
            ) from None
    try:
        k = np.broadcast_to(np.asarray(k, dtype=float), (n_runs, 3)).copy()
        b = np.broadcast_to(np.asarray(b, dtype=float), (n_runs, 3)).copy()
    except ValueError:
        raise SimulationConfigError(f"params k and b must have shape (3,) or ({n_runs}, 3)") from None
    if not (np.all(np.isfinite(k)) and np.all(k > 0) and np.all(np.isfinite(b))):
        raise SimulationConfigError("params k must be positive and finite, b finite (deg/s)")
    return k, b


def simulate_batch(
    seed: int,
    n_runs: int,
    noise: float,
    fs: float = 104.0,
    params: tuple[ArrayLike, ArrayLike] | SensorParams | None = None,
    *,
    angle_deg: float | ArrayLike = 360.0,
    still_s: float = STILL_S,
) -> SimBatch:
    """``n_runs`` independent paper-protocol runs, vectorised (same construction as ``simulate``).

    Each run has its own turn durations, tilts, wobbles and Bezier speed profiles; ``params``
    (k, b) with shapes (3,) or (n_runs, 3) fixes the sensor parameters, None draws them per run.
    ``noise`` is the reading white-noise std (deg/s). Deterministic by seed.
    """
    seed = _check_seed(seed)
    if isinstance(n_runs, bool) or not isinstance(n_runs, (int, np.integer)) or n_runs < 1:
        raise SimulationConfigError(f"n_runs must be a whole number >= 1; got {n_runs!r}")
    noise = _float(noise, "noise", positive=False)
    if noise < 0:
        raise SimulationConfigError("noise is a standard deviation and must be >= 0")
    fs = _float(fs, "fs")
    angles = _turn_angles(angle_deg)
    dt = 1.0 / fs
    R = int(n_runs)
    ss_params, ss_motion, ss_noise = np.random.SeedSequence(seed).spawn(3)
    k, b = _batch_params(params, R, np.random.default_rng(ss_params))

    drawn = _draw_turn_params(np.random.default_rng(ss_motion), 3 * R)
    n_turn = np.maximum(2, np.round(drawn["duration_s"] * fs).astype(np.int64)).reshape(R, 3)
    tilt = drawn["tilt"].reshape(R, 3, 2)
    axes = np.empty((R, 3, 3))
    for i in range(len(AXES)):
        other = [j for j in range(3) if j != i]
        axes[:, i, i] = 1.0
        axes[:, i, other] = tilt[:, i]
    axes /= np.linalg.norm(axes, axis=2, keepdims=True)

    n0 = _n_samples(still_s, fs, "still_s", 1)
    starts = n0 + np.concatenate([np.zeros((R, 1), np.int64), np.cumsum(n_turn + n0, axis=1)[:, :2]], axis=1)
    ends = starts + n_turn
    n = int(ends[:, 2].max()) + n0

    rates_flat, _ = _segment_motion(
        n_turn.ravel(),
        axes.reshape(-1, 3),
        np.tile(np.radians(angles), R),
        drawn["profile"],
        np.radians(drawn["wobble_deg"]),
        dt,
    )
    lengths = n_turn.ravel()
    first = (np.arange(R)[:, None] * n + starts).ravel()
    within = np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    flat = np.repeat(first, lengths) + within
    rate = np.zeros((R, n, 3))
    rate.reshape(-1, 3)[flat] = rates_flat

    # m = (g - b) / k + noise, with g = 0 outside the turns
    gyro = np.random.default_rng(ss_noise).standard_normal((R, n, 3))
    gyro *= noise
    gyro += (-b / k)[:, None, :]
    gyro.reshape(-1, 3)[flat] += rates_flat / np.repeat(k, n_turn.sum(axis=1), axis=0)

    still0 = np.column_stack([np.zeros(R, np.int64), np.full(R, n0)])
    pauses = [np.stack([ends[:, i], starts[:, i + 1]], axis=1) for i in range(2)]
    final = np.stack([ends[:, 2], np.full(R, n)], axis=1)
    stills = np.stack([still0, *pauses, final], axis=1)
    return SimBatch(
        t=np.arange(n) * dt,
        gyro=gyro,
        rate=rate,
        still0=still0,
        turns=np.stack([starts, ends], axis=2),
        stills=stills,
        k_true=k,
        b_true=b,
        dt=dt,
        noise=noise,
        fs=fs,
        turn_axes=axes,
        angle_deg=angles,
        tilt=tilt,
        wobble_deg=drawn["wobble_deg"].reshape(R, 3, 2, 2),
        profile=drawn["profile"].reshape(R, 3, _N_PROFILE),
    )
