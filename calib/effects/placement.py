"""The hand's error: the device not put back exactly where it was after each turn."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np
from scipy.spatial.transform import Rotation

from calib.effects.base import Effect, SimulationConfigError, Trajectory, numbers_of, positive, register_effect, usage_error
from calib.effects.spec import DrawContext, EffectSpec, MagnitudeRange, log_uniform

_UP = np.array([0.0, 0.0, 1.0])  # specific force at rest in the start frame, g


def _smoothstep(u: np.ndarray) -> np.ndarray:
    return u * u * (3.0 - 2.0 * u)


@register_effect
@dataclass(frozen=True, eq=False)
class PlacementError(Effect):
    """The device is not put back exactly in its starting pose after each turn.

    Turn j ends rotated by the world-frame (start-frame, z up) rotation Exp(e_j) from where a
    closing turn would leave it, e_j = (tilt about x, tilt about y, heading about z) in deg. The
    extra rotation is done smoothly over the last ``ramp_fraction`` of the turn, acts on the true
    motion (so the accelerometer sees the tilt) and stays for the rest of the recording: poses
    after the turn are Exp(e_j) ... Exp(e_1) R(t). Consequences, for a turn starting at true pose
    R_s (body to start frame):

    - the turn no longer closes: the product of Exp(g dt) over it is Exp(R_s^T e_j) (body axes);
    - the accelerometer at rest after the turn reads (Exp(e_j) R_s)^T (0, 0, 1): the tilt
      components of e_j are measurable, the heading component (about the vertical) is not.

    Parameters: ``std_deg`` std of each tilt component, ``heading_std_deg`` std of the heading
    component (None: same as ``std_deg``); ``errors_deg`` (J, 3) fixes e_j for the J turns instead
    of drawing them N(0, diag(std^2, std^2, heading_std^2)). CLI value: ``STD[,HEADING_STD]`` (deg).
    """

    name: ClassVar[str] = "placement_error"
    usage: ClassVar[str] = "STD[,HEADING_STD] (deg per turn)"
    spec: ClassVar[EffectSpec] = EffectSpec(
        rank=7,
        equation="turn j ends rotated by the world-frame Exp(e_j); its closure is Exp(R_s^T e_j)",
        parameters="std of tilt and heading (deg)",
        drawn=MagnitudeRange(
            0.3, 2.0, "deg", "std of each component of the placement rotation per turn",
            "a device turned by hand and put back down by eye: tilt and heading off by 0.3-2 deg",
        ),
        reveal="record the accelerometer: it measures the tilt the device is put back with",
        diagnosis_model="turn j ends rotated by ρ_j; the accelerometer measures its tilt, the heading has a prior of the tilts' size",
        diagnosis_parameters="ρ_j (deg)",
        typical=0.8,  # deg per turn, a device put back by hand
        typical_text="0.8 deg per turn",
        distinguish="the accelerometer, and putting the device back against a fixed stop after each turn",
    )
    std_deg: float = 0.0
    heading_std_deg: float | None = None
    errors_deg: np.ndarray | None = None
    ramp_fraction: float = 0.25

    @classmethod
    def draw(cls, rng: np.random.Generator, ctx: DrawContext) -> tuple[PlacementError, float]:
        mag = log_uniform(rng, cls.spec.drawn.low, cls.spec.drawn.high)
        effect = cls(mag)
        return replace(effect, errors_deg=effect.draw_errors(ctx.turns, rng)), mag
    def __post_init__(self) -> None:
        object.__setattr__(self, "std_deg", positive(self.std_deg, "PlacementError.std_deg", allow_zero=True))
        if self.heading_std_deg is not None:
            object.__setattr__(
                self, "heading_std_deg", positive(self.heading_std_deg, "PlacementError.heading_std_deg", allow_zero=True)
            )
        if self.errors_deg is not None:
            e = np.asarray(self.errors_deg, dtype=float)
            if e.ndim != 2 or e.shape[1] != 3 or not np.all(np.isfinite(e)) or np.any(np.abs(e) > 45):
                raise SimulationConfigError(
                    "PlacementError.errors_deg must be one row (tilt x, tilt y, heading) in deg per turn, each under 45; "
                    f"got {self.errors_deg!r}"
                )
            object.__setattr__(self, "errors_deg", e)
        f = float(self.ramp_fraction)
        if not (0.0 < f <= 1.0):
            raise SimulationConfigError(f"PlacementError.ramp_fraction must be in (0, 1]; got {self.ramp_fraction!r}")
        object.__setattr__(self, "ramp_fraction", f)

    @classmethod
    def from_text(cls, value: str) -> PlacementError:
        v = numbers_of(value, cls)
        if len(v) not in (1, 2):
            raise usage_error(cls, value)
        return cls(std_deg=v[0], heading_std_deg=v[1] if len(v) == 2 else None)

    @property
    def stds_deg(self) -> np.ndarray:
        """Standard deviations of (tilt x, tilt y, heading), deg."""
        h = self.std_deg if self.heading_std_deg is None else self.heading_std_deg
        return np.array([self.std_deg, self.std_deg, h])

    def draw_errors(self, n_turns: int, rng: np.random.Generator) -> np.ndarray:
        """e_j (n_turns, 3) in deg, drawn N(0, diag(stds^2))."""
        return rng.standard_normal((n_turns, 3)) * self.stds_deg

    def on_trajectory(self, traj: Trajectory, rng: np.random.Generator) -> Trajectory:
        turns = [s for s in traj.stages if s.kind == "turn"]
        if not turns:
            return traj
        errs = self.errors_deg if self.errors_deg is not None else self.draw_errors(len(turns), rng)
        if errs.shape[0] != len(turns):
            raise SimulationConfigError(f"PlacementError.errors_deg has {errs.shape[0]} rows but the protocol has {len(turns)} turns")
        n = traj.n
        left = np.tile(Rotation.identity().as_quat(), (n + 1, 1))
        cum = Rotation.identity()
        ramps: list[tuple[int, int]] = []
        for st, e in zip(turns, np.radians(errs), strict=False):
            L = max(1, int(round(self.ramp_fraction * (st.end - st.start))))
            a = st.end - L
            s = _smoothstep(np.arange(L + 1) / L)
            left[a : st.end + 1] = (Rotation.from_rotvec(s[:, None] * e) * cum).as_quat()
            cum = Rotation.from_rotvec(e) * cum
            left[st.end + 1 :] = cum.as_quat()
            ramps.append((a, st.end))
        attitude = Rotation.from_quat(left) * traj.attitude
        rate = traj.rate.copy()
        dt = np.diff(traj.t, append=traj.t[-1] + (traj.t[-1] - traj.t[-2] if n > 1 else traj.dt))
        idx = np.concatenate([np.arange(a, b) for a, b in ramps])
        rel = attitude[idx].inv() * attitude[idx + 1]
        rate[idx] = np.degrees(rel.as_rotvec()) / dt[idx, None]
        accel = attitude[:n].inv().apply(_UP)
        return replace(traj, rate=rate, attitude=attitude, accel=accel)
