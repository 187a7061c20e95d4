"""A study day, compressed: a wearable on a thigh, from its rest on the table through lying, sitting, standing and
walking bouts, warming on the skin, and optionally knocked once so that its calibration changes.

The sensor follows g = K(T) m + b(T) (eq. 1 at the temperature T), with the calibration's K, b true at ``temp_cal_c``:

    K(T) = diag(1 + s (T - T_cal)) K,    b(T) = b + c (T - T_cal) + w(t),

s the scale's temperature coefficient (per degC), c the bias's ((deg/s)/degC), w the bias's own slow wander (a
Gauss-Markov process). The device rests on the table at room temperature T0 and is then strapped on; from then on it
warms as T(t) = T0 + rise (1 - exp(-(t - t_on) / tau)). An event at ``at_s`` (a drop) multiplies one axis's k by
1 + size, or adds size (deg/s) to one axis's b, from then on.

Ranges (drawn per day unless given): rise 8-12 degC, tau 5-15 min of the compressed day, |c| 0.01-0.05 (deg/s)/degC
and |s| 0.01-0.03 %/degC per axis (MEMS gyroscopes of the ICM-20948, LSM6DS3, LSM9DS1 class: their datasheets' zero-rate
and sensitivity changes over temperature), a bias wander of 0.005 deg/s over 60 s.

The device's axes on the thigh: x along the thigh (up when standing), y across it, z out of the thigh's front.
Postures by the body axis that points up: standing +x, sitting and lying on the back +z, lying on a side +-y, lying
face down -z; each visit a few degrees different. Walking (from standing) swings the thigh about y at a stride's pace.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from calib.effects.base import SimulationConfigError
from calib.recording import Recording, RecordingMeta
from calib.simulator.protocol import Motion, ProtocolScript, Segment, Still
from calib.simulator.ranges import ACCEL_NOISE_G
from calib.simulator.simulate import SensorParams, check_seed
from calib.simulator.trajectory import build_trajectory

TEMP_RESOLUTION_C = 1.0 / 256.0  # the temperature channel's step (256 LSB/degC, a common IMU temperature sensor)
UP = np.array([0.0, 0.0, 1.0])
# posture: the body axis that points up
POSTURES: dict[str, np.ndarray] = {
    "standing": np.array([1.0, 0.0, 0.0]),
    "sitting": np.array([0.0, 0.0, 1.0]),
    "lying on the back": np.array([0.0, 0.0, 1.0]),
    "lying on the left side": np.array([0.0, 1.0, 0.0]),
    "lying on the right side": np.array([0.0, -1.0, 0.0]),
    "lying face down": np.array([0.0, 0.0, -1.0]),
}
# which posture follows which (a day's usual moves; lying on a side is reached from the back or from standing)
NEXT: dict[str, tuple[str, ...]] = {
    "standing": ("sitting", "walking", "walking", "lying on the left side", "lying on the right side"),
    "sitting": ("standing", "standing", "lying on the back"),
    "lying on the back": ("lying on the left side", "lying on the right side", "sitting", "lying face down"),
    "lying on the left side": ("lying on the back", "standing"),
    "lying on the right side": ("lying on the back", "standing"),
    "lying face down": ("lying on the back",),
}
REST_S = {"standing": (15.0, 60.0), "sitting": (30.0, 150.0)}  # lying: LYING_REST_S
LYING_REST_S = (40.0, 200.0)
TABLE_S = (60.0, 180.0)  # on the table before it is strapped on
MOVE_S = (1.2, 3.0)  # a change of posture
WALK_S = (20.0, 90.0)
STRIDE_S = (0.95, 1.15)  # a whole stride: the thigh swings forward and back
SWING_DEG = (25.0, 40.0)  # the thigh's swing about y, each way
VISIT_SPREAD_DEG = 8.0  # how much one visit of a posture differs from the next


@dataclass(frozen=True)
class StudyEvent:
    """A drop at ``at_s``: ``kind`` "k" multiplies axis ``axis``'s k by 1 + ``size``; "b" adds ``size`` deg/s to its b."""

    at_s: float
    kind: str
    axis: int
    size: float

    def to_dict(self) -> dict[str, Any]:
        return {"at_s": self.at_s, "kind": self.kind, "axis": "xyz"[self.axis], "size": self.size}


@dataclass(frozen=True)
class StudyDay:
    """What the simulated day held: the calibration true at ``temp_cal_c`` (``params``), the warm-up, the
    temperature coefficients, the bias wander's size, the event, and the postures visited (label, start s)."""

    params: SensorParams
    temp_cal_c: float
    temp0_c: float
    rise_c: float
    tau_s: float
    on_at_s: float
    bias_tc: np.ndarray  # (3,) (deg/s)/degC
    scale_tc: np.ndarray  # (3,) per degC
    wander_dps: float
    event: StudyEvent | None
    postures: tuple[tuple[str, float], ...] = field(default_factory=tuple)
    noise_dps: float = 0.05
    walks: tuple[tuple[float, float], ...] = ()  # each walking bout's start and end (s)
    rate: np.ndarray | None = field(default=None, repr=False, compare=False)  # the true rates (deg/s), per sample

    def temperature(self, t: np.ndarray) -> np.ndarray:
        """The sensor's temperature (degC) at times ``t`` (s from the recording's start)."""
        on = np.maximum(np.asarray(t, dtype=float) - self.on_at_s, 0.0)
        return self.temp0_c + self.rise_c * -np.expm1(-on / self.tau_s)

    def to_dict(self) -> dict[str, Any]:
        return {"k": self.params.k.tolist(), "b": self.params.b.tolist(), "temp_cal_c": self.temp_cal_c,
                "temp0_c": self.temp0_c, "rise_c": self.rise_c, "tau_s": self.tau_s, "on_at_s": self.on_at_s,
                "bias_tc_dps_per_c": self.bias_tc.tolist(), "scale_tc_per_c": self.scale_tc.tolist(),
                "wander_dps": self.wander_dps, "noise_dps": self.noise_dps,
                "event": None if self.event is None else self.event.to_dict(),
                "postures": [{"posture": p, "at_s": round(t, 2)} for p, t in self.postures],
                "walks": [[round(a, 2), round(b, 2)] for a, b in self.walks]}


def _attitude(up_body: np.ndarray, heading_deg: float, rng: np.random.Generator) -> Rotation:
    """A world-from-body attitude whose body axis ``up_body`` points up (give or take VISIT_SPREAD_DEG), at a heading."""
    align, _ = Rotation.align_vectors(UP[None], up_body[None])
    spread = Rotation.from_rotvec(np.radians(rng.normal(0.0, VISIT_SPREAD_DEG / 2.0, 3)) * np.array([1.0, 1.0, 0.0]))
    return Rotation.from_euler("z", heading_deg, degrees=True) * spread * align


def _move(frm: Rotation, to: Rotation, rng: np.random.Generator) -> Motion:
    """The motion (body axes) from attitude ``frm`` to ``to``."""
    rotvec = np.degrees((frm.inv() * to).as_rotvec())
    return Motion(rotvec, float(rng.uniform(*MOVE_S)))


def _walk(rng: np.random.Generator) -> list[Motion]:
    """Strides: the thigh swings about y forward and back, with a little roll and a change of heading now and then."""
    segs: list[Motion] = []
    left = float(rng.uniform(*WALK_S))
    while left > 0:
        stride = float(rng.uniform(*STRIDE_S))
        swing = float(rng.uniform(*SWING_DEG))
        roll = rng.normal(0.0, 3.0, 2)
        turn = float(rng.normal(0.0, 15.0)) if rng.random() < 0.1 else 0.0  # about the thigh's long axis: a heading change
        segs.append(Motion((roll[0] + turn, swing, roll[1]), stride / 2.0))
        segs.append(Motion((-roll[0], -swing, -roll[1]), stride / 2.0))
        left -= stride
    return segs


def study_day_script(rng: np.random.Generator, duration_s: float
                     ) -> tuple[ProtocolScript, tuple[tuple[str, float], ...], float, tuple[tuple[float, float], ...]]:
    """The day's motion: the table, then postures and walking bouts until ``duration_s``. Returns the script, the
    postures visited (label, start s), when the device was strapped on (s) and the walking bouts (start, end s)."""
    table_s = float(rng.uniform(*TABLE_S))
    segs: list[Segment] = [Still(table_s)]
    att = Rotation.identity()  # flat on the table, z up
    t = table_s
    on_at = t
    posture = "standing"
    heading = float(rng.uniform(0.0, 360.0))
    visited: list[tuple[str, float]] = []
    walks: list[tuple[float, float]] = []
    while t < duration_s:
        nxt = _attitude(POSTURES[posture], heading, rng)
        move = _move(att, nxt, rng)
        segs.append(move)
        t += move.duration_s
        att = nxt
        visited.append((posture, t))
        lo, hi = REST_S.get(posture, LYING_REST_S)
        rest = float(rng.uniform(lo, hi))
        segs.append(Still(rest))
        t += rest
        choice = str(rng.choice(NEXT[posture]))
        if choice == "walking":
            walk = _walk(rng)
            segs += walk
            visited.append(("walking", t))
            walks.append((t, t + sum(seg.duration_s for seg in walk)))
            t = walks[-1][1]
            for seg in walk:  # where the strides left it: near where it began, turned about the vertical
                att = att * Rotation.from_rotvec(np.radians(np.asarray(seg.rotvec_deg)))
            choice = "standing"
        posture = choice
        heading += float(rng.normal(0.0, 30.0))
    return ProtocolScript(tuple(segs)), tuple(visited), on_at, tuple(walks)


def _wander(n: int, fs: float, size_dps: float, rng: np.random.Generator, tau_s: float = 60.0) -> np.ndarray:
    """A Gauss-Markov bias wander (n, 3) deg/s of steady-state std ``size_dps`` and correlation time ``tau_s``."""
    a = np.exp(-1.0 / (fs * tau_s))
    drive = size_dps * np.sqrt(1.0 - a * a) * rng.standard_normal((n, 3))
    from scipy.signal import lfilter

    return lfilter([1.0], [1.0, -a], drive, axis=0)


def simulate_study_day(
    seed: int,
    duration_s: float = 3600.0,
    fs: float = 100.0,
    noise: float = 0.05,
    *,
    params: SensorParams | None = None,
    temperature_channel: bool = True,
    event: str | StudyEvent | None = None,
    event_size: float | None = None,
    rise_c: float | None = None,
    bias_tc: np.ndarray | None = None,
    scale_tc: np.ndarray | None = None,
    wander_dps: float = 0.005,
    accel_noise_g: float = ACCEL_NOISE_G,
    temp_cal_c: float | None = None,
) -> tuple[Recording, StudyDay]:
    """Simulate one study day (see the module docstring). ``event``: None, "k", "b" (a drop at a random time in the
    day's second half, on a random axis, of ``event_size`` or a size drawn from 0.2-1 % for k and 0.05-0.5 deg/s for
    b, either sign) or a StudyEvent. ``temperature_channel``: whether the recording carries the temperature (the
    sensor warms either way). ``params``, ``bias_tc``, ``scale_tc``, ``temp_cal_c``: the sensor's, to simulate
    another day of the same one. Same seed and arguments give the same day."""
    seed = check_seed(seed)
    rng = np.random.default_rng([seed, 65])
    params = params or SensorParams.paper_random(rng)
    script, visited, on_at, walks = study_day_script(rng, duration_s)
    traj = build_trajectory(script, fs, rng)
    temp0 = float(rng.uniform(20.0, 26.0))
    day = StudyDay(
        params=params, temp_cal_c=temp0 + float(rng.uniform(-1.0, 1.0)) if temp_cal_c is None else float(temp_cal_c), temp0_c=temp0,
        rise_c=float(rng.uniform(8.0, 12.0)) if rise_c is None else float(rise_c), tau_s=float(rng.uniform(300.0, 900.0)),
        on_at_s=on_at,
        bias_tc=rng.choice([-1.0, 1.0], 3) * rng.uniform(0.01, 0.05, 3) if bias_tc is None else np.asarray(bias_tc, float),
        scale_tc=rng.choice([-1.0, 1.0], 3) * rng.uniform(1e-4, 3e-4, 3) if scale_tc is None else np.asarray(scale_tc, float),
        wander_dps=wander_dps, event=_event(event, event_size, traj.t[-1], rng), postures=visited, noise_dps=noise,
        walks=walks, rate=traj.rate)
    t = traj.t
    temp = day.temperature(t)
    dT = (temp - day.temp_cal_c)[:, None]
    k_t = params.k * (1.0 + day.scale_tc * dT)
    b_t = params.b + day.bias_tc * dT + _wander(t.size, fs, wander_dps, rng)
    if day.event is not None:
        after = t >= day.event.at_s
        if day.event.kind == "k":
            k_t[after, day.event.axis] *= 1.0 + day.event.size
        else:
            b_t[after, day.event.axis] += day.event.size
    gyro = (traj.rate - b_t) / k_t + noise * rng.standard_normal(traj.rate.shape)
    accel = traj.accel + accel_noise_g * rng.standard_normal(traj.accel.shape)
    temp_channel = np.round(temp / TEMP_RESOLUTION_C) * TEMP_RESOLUTION_C if temperature_channel else None
    rec = Recording(t, gyro, accel, np.arange(t.size, dtype=np.int64), temp_channel,
                    RecordingMeta(sample_rate_hz=fs, device_id=f"sim-study-{seed}", sensor_model="simulated",
                                  source=f"simulate_study_day(seed={seed})"))
    return rec, day


def _event(kind: str | StudyEvent | None, size: float | None, end_s: float, rng: np.random.Generator) -> StudyEvent | None:
    if kind is None or isinstance(kind, StudyEvent):
        return kind
    if kind not in ("k", "b"):
        raise SimulationConfigError(f"event must be 'k', 'b' or None; got {kind!r}")
    lo, hi = (2e-3, 1e-2) if kind == "k" else (0.05, 0.5)
    value = float(rng.uniform(lo, hi)) if size is None else float(size)
    return StudyEvent(float(rng.uniform(0.5, 0.85) * end_s), kind, int(rng.integers(3)), float(rng.choice([-1.0, 1.0]) * value))
