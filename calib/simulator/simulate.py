"""One simulated recording: a sensor's parameters, its readings along a trajectory, and the truth beside them."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from calib.effects import (
    AxisMisalignment,
    Effect,
    Saturation,
    SensorContext,
    SensorOutput,
    SimulationConfigError,
    Trajectory,
    check_effects,
)
from calib.recording import Recording, RecordingMeta
from calib.simulator.protocol import ProtocolScript, as_float, paper_protocol_script
from calib.simulator.ranges import ACCEL_NOISE_G, B_RANGE_DPS, K_RANGE
from calib.simulator.trajectory import build_trajectory
from calib.stages.stage import AXES, Stage


@dataclass(frozen=True, eq=False)
class SensorParams:
    """Parameters of g = K m + b (eq. 1): scale factors ``k`` (3,), biases ``b`` (3,) in deg/s of true rate, and
    ``off_diagonal`` (K_xy, K_xz, K_yz): the entries above K's diagonal of a sensor whose axes are not orthogonal
    (``calib.effects.AxisMisalignment``; zero: K = diag(k))."""

    k: np.ndarray
    b: np.ndarray
    off_diagonal: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        k = np.asarray(self.k, dtype=float)
        b = np.asarray(self.b, dtype=float)
        if k.shape != (3,) or not np.all(np.isfinite(k)) or np.any(k <= 0):
            raise SimulationConfigError(f"SensorParams.k must be 3 positive scale factors (x, y, z); got {self.k!r}")
        if b.shape != (3,) or not np.all(np.isfinite(b)):
            raise SimulationConfigError(f"SensorParams.b must be 3 finite biases in deg/s (x, y, z); got {self.b!r}")
        object.__setattr__(self, "k", k)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "off_diagonal", AxisMisalignment(self.off_diagonal).off_diagonal)

    @property
    def K(self) -> np.ndarray:
        """K (3, 3): diag(k) with ``off_diagonal`` above it."""
        return AxisMisalignment(self.off_diagonal).matrix(self.k)

    @classmethod
    def paper_random(cls, rng: np.random.Generator) -> SensorParams:
        """k ~ U(0.8, 1.2), b ~ U(-5, 5) deg/s per axis (paper Section 3)."""
        return cls(rng.uniform(*K_RANGE, 3), rng.uniform(*B_RANGE_DPS, 3))

    def reading(self, rate_dps: np.ndarray) -> np.ndarray:
        """Noise-free readings m = K^-1 (g - b) (deg/s) for true rates g (..., 3)."""
        if not np.any(self.off_diagonal):
            return (np.asarray(rate_dps) - self.b) / self.k
        return np.linalg.solve(self.K, (np.asarray(rate_dps) - self.b).T).T

    def true_rate(self, m: np.ndarray) -> np.ndarray:
        """True rates g = K m + b (deg/s) for readings m (..., 3)."""
        return np.asarray(m) @ self.K.T + self.b




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


def check_seed(seed: Any) -> int:
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
    seed = check_seed(seed)
    noise = as_float(noise, "noise", positive=False)
    accel_noise_g = as_float(accel_noise_g, "accel_noise_g", positive=False)
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
        stages.append(replace(st, start=r0, end=r1, flags=tuple(flags), start_s=float(t_dev[st.start]), end_s=float(t_dev[st.end])))
        if st.kind == "turn" and st.axis is not None and np.isnan(turn_axes[AXES.index(st.axis), 0]):
            turn_axes[AXES.index(st.axis)] = ax
    return tuple(stages), turn_axes
