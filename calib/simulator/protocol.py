"""The protocol as a script of stills, turns and other motions: the paper's, the extended one, and their
random draws."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from calib.effects import SimulationConfigError
from calib.simulator.ranges import N_PROFILE, STILL_S, TILT_RANGE, TURN_DURATION_S, WOBBLE_DEG, WOBBLE_HARMONIC_SCALE
from calib.stages.stage import AXES
from calib.units import FULL_TURN_DEG


def as_float(value: Any, what: str, positive: bool = True) -> float:
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
    if p.shape != (N_PROFILE,) or np.any(p < 0) or np.any(p > 1) or np.any(np.diff(p) < 0):
        raise SimulationConfigError(
            f"{what}.profile must be {N_PROFILE} increasing numbers in [0, 1] (inner Bezier control points); got {value!r}"
        )
    return p


@dataclass(frozen=True, eq=False)
class Still:
    """The device rests for ``duration_s`` seconds."""

    duration_s: float = STILL_S

    def __post_init__(self) -> None:
        object.__setattr__(self, "duration_s", as_float(self.duration_s, "Still.duration_s"))


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
    angle_deg: float = FULL_TURN_DEG
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
        angle = as_float(self.angle_deg, "Turn.angle_deg", positive=False)
        if angle == 0:
            raise SimulationConfigError("Turn.angle_deg must be nonzero (use Still for no motion)")
        object.__setattr__(self, "angle_deg", angle)
        if self.duration_s is not None:
            object.__setattr__(self, "duration_s", as_float(self.duration_s, "Turn.duration_s"))
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
        object.__setattr__(self, "duration_s", as_float(self.duration_s, "Motion.duration_s"))
        object.__setattr__(self, "profile", _profile(self.profile, "Motion"))


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


Segment = Still | Turn | Motion
EXTENDED_SLOW_S = (6.0, 8.0)  # slow turn duration, s: mean rate 45-60 deg/s
EXTENDED_FAST_S = (1.2, 1.8)  # fast turn duration, s: mean rate 200-300 deg/s, peaks near 500 deg/s


def draw_turn_params(rng: np.random.Generator, m: int) -> dict[str, np.ndarray]:
    """Random hand-turn parameters for m turns (paper Section 3 and Section 2.3)."""
    amp = rng.uniform(*WOBBLE_DEG, m)
    return {
        "duration_s": rng.uniform(*TURN_DURATION_S, m),
        "tilt": rng.uniform(-TILT_RANGE, TILT_RANGE, (m, 2)),
        "wobble_deg": amp[:, None, None] * rng.uniform(-1.0, 1.0, (m, 2, 2)) * WOBBLE_HARMONIC_SCALE[None, :, None],
        "profile": np.sort(rng.uniform(0.0, 1.0, (m, N_PROFILE)), axis=1),
    }


def turn_angles(angle_deg: float | ArrayLike) -> np.ndarray:
    angles = np.asarray(angle_deg, dtype=float)
    if angles.ndim == 0:
        angles = np.full(3, float(angles))
    if angles.shape != (3,) or not np.all(np.isfinite(angles)) or np.any(angles == 0):
        raise SimulationConfigError(f"angle_deg must be one nonzero angle or three (x, y, z turns), in deg; got {angle_deg!r}")
    return angles


def paper_protocol_script(
    rng: np.random.Generator | None = None,
    angle_deg: float | ArrayLike = FULL_TURN_DEG,
    still_s: float = STILL_S,
    final_still_s: float = STILL_S,
) -> ProtocolScript:
    """The protocol of Section 2.3: rest, turn x, rest, turn y, rest, turn z, final rest.

    ``angle_deg``: one signed angle for all turns or one per turn (x, y, z). With ``rng`` every
    random choice of the turns (duration, tilt, wobble, speed profile) is drawn now and fixed in the
    script; without, ``simulate`` draws them.
    """
    angles = turn_angles(angle_deg)
    drawn = draw_turn_params(rng, 3) if rng is not None else None
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
    drawn = draw_turn_params(rng, n) if rng is not None else None
    segs: list[Segment] = [Still(still_s)]
    j = 0
    for axis in AXES:
        for sign, (lo, hi) in kinds:
            if drawn is None or rng is None:
                segs.append(Turn(axis, sign * FULL_TURN_DEG, duration_s=0.5 * (lo + hi)))
            else:
                segs.append(
                    Turn(
                        axis,
                        sign * FULL_TURN_DEG,
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


def extended_script_for_seed(seed: int) -> ProtocolScript:
    """The extended protocol's script of a simulation's ``seed``, its draws from a stream of their own (as
    ``simulate``'s are): the same recording from the command line and the Python API."""
    return extended_protocol_script(np.random.default_rng([seed, 1]))
