"""Many simulated runs of one protocol at once (the paper's simulation study, the diagnosis's null)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from calib.effects import SimulationConfigError
from calib.simulator.protocol import ProtocolScript, Segment, Still, Turn, as_float, draw_turn_params, turn_angles
from calib.simulator.ranges import B_RANGE_DPS, K_RANGE, N_PROFILE, STILL_S
from calib.simulator.simulate import SensorParams, check_seed
from calib.simulator.trajectory import n_samples_of, segment_motion
from calib.stages.stage import AXES
from calib.units import FULL_TURN_DEG


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
    angle_deg: float | ArrayLike = FULL_TURN_DEG,
    still_s: float = STILL_S,
) -> SimBatch:
    """``n_runs`` independent paper-protocol runs, vectorised (same construction as ``simulate``).

    Each run has its own turn durations, tilts, wobbles and Bezier speed profiles; ``params``
    (k, b) with shapes (3,) or (n_runs, 3) fixes the sensor parameters, None draws them per run.
    ``noise`` is the reading white-noise std (deg/s). Deterministic by seed.
    """
    seed = check_seed(seed)
    if isinstance(n_runs, bool) or not isinstance(n_runs, (int, np.integer)) or n_runs < 1:
        raise SimulationConfigError(f"n_runs must be a whole number >= 1; got {n_runs!r}")
    noise = as_float(noise, "noise", positive=False)
    if noise < 0:
        raise SimulationConfigError("noise is a standard deviation and must be >= 0")
    fs = as_float(fs, "fs")
    angles = turn_angles(angle_deg)
    dt = 1.0 / fs
    R = int(n_runs)
    ss_params, ss_motion, ss_noise = np.random.SeedSequence(seed).spawn(3)
    k, b = _batch_params(params, R, np.random.default_rng(ss_params))

    drawn = draw_turn_params(np.random.default_rng(ss_motion), 3 * R)
    n_turn = np.maximum(2, np.round(drawn["duration_s"] * fs).astype(np.int64)).reshape(R, 3)
    tilt = drawn["tilt"].reshape(R, 3, 2)
    axes = np.empty((R, 3, 3))
    for i in range(len(AXES)):
        other = [j for j in range(3) if j != i]
        axes[:, i, i] = 1.0
        axes[:, i, other] = tilt[:, i]
    axes /= np.linalg.norm(axes, axis=2, keepdims=True)

    n0 = n_samples_of(still_s, fs, "still_s", 1)
    starts = n0 + np.concatenate([np.zeros((R, 1), np.int64), np.cumsum(n_turn + n0, axis=1)[:, :2]], axis=1)
    ends = starts + n_turn
    n = int(ends[:, 2].max()) + n0

    rates_flat, _ = segment_motion(
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
        profile=drawn["profile"].reshape(R, 3, N_PROFILE),
    )
