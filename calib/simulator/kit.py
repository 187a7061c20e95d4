"""A kit of wearables in one rigid tray, turned together by one hand.

Each wearable sits in its slot with its own small mounting rotation, has its own sensor errors (eq. 1), noise and
clock, and starts and stops recording at its own moment. The tray follows one protocol script; every wearable samples
the tray's motion at its own instants. One wearable may slip in its slot during a turn (``Slip``): from then on its
mounting is another, which no rigid coupling explains. One may lie on the table beside the tray (``out``), switched
on: it reads the table's stillness while the tray turns.

Clocks follow ``calib.effects.timing.ClockError``: wearable d stamps its samples o_d + j / fs on its own clock, which
counts from its own power-up (o_d: what it read at its first sample, up to ``CLOCK_ORIGIN_S``) and runs at (1 + e_d)
times true time, so a calibration fitted on its own stamps returns k / (1 + e_d) and b / (1 + e_d)
(``KitDeviceTruth.k_own``, ``b_own``): the calibration that device should use.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from calib.effects import AxisMisalignment, SimulationConfigError, Trajectory
from calib.recording import Recording, RecordingMeta
from calib.simulator.protocol import ProtocolScript, as_float, paper_protocol_script
from calib.simulator.ranges import ACCEL_NOISE_G, GRAVITY_UP
from calib.simulator.simulate import SensorParams, check_seed
from calib.simulator.trajectory import build_trajectory

MOUNT_DEG = 2.0  # largest mounting rotation of a wearable in its slot, deg (drawn uniform in 0..this)
CLOCK_ERROR = 0.01  # largest clock error of a wearable, fraction (drawn uniform in -this..this)
START_SPREAD_S = 0.5  # wearables start (and stop) recording up to this long apart, s
CLOCK_ORIGIN_S = 600.0  # a wearable's clock reads up to this long (its time since power-up) at its first sample, s
SLIP_S = 0.2  # how long a slip in the slot takes, s
PAUSE_SLIP_AFTER_S = 1.0  # a slip in a pause starts this long after the turn before it ended (the pause is 2 s)
SLIP_WHEN = ("turn", "pause")  # when a simulated wearable slips: during its turn, or in the pause after it (in_pause)
OVERSAMPLE = 4  # the tray's motion is generated at this many times the wearables' rate


@dataclass(frozen=True)
class Slip:
    """Wearable ``device`` (0-based) turns by ``angle_deg`` in its slot during turn ``turn`` (0-based) of the script,
    or with ``in_pause`` in the pause after it, ``PAUSE_SLIP_AFTER_S`` after the tray came to rest (it settles in its
    slot while the tray stays still)."""

    device: int
    angle_deg: float
    turn: int = 1
    in_pause: bool = False

    def __post_init__(self) -> None:
        if self.device < 0 or self.turn < 0:
            raise SimulationConfigError(f"Slip needs a device and a turn index >= 0; got {self.device}, {self.turn}")
        as_float(self.angle_deg, "Slip.angle_deg", positive=False)


def checked_misalignment(value: float) -> float:
    """``value`` as the largest off-diagonal entry of a simulated sensor's K, which must be 0 to 0.5."""
    largest = as_float(value, "misalignment", positive=False)
    if not 0.0 <= largest < 0.5:
        raise SimulationConfigError(f"misalignment is the largest off-diagonal entry of K, 0 to 0.5; got {value!r}")
    return largest


@dataclass(frozen=True)
class TrayFaults:
    """What goes wrong in a simulated tray, each wearable 0-based (None: none): ``loose`` slips in its slot, in a turn
    or with ``loose_in`` "pause" in the pause after it; ``out`` lies on the table beside the tray; ``drop`` goes out of
    its link's range for a moment in a turn (its samples then lost); ``misalignment``: the largest cross-axis entry of
    each sensor's K (0: axes orthogonal). Which turn, how far and how long are the simulator's choices."""

    loose: int | None = None
    loose_in: str = "turn"
    out: int | None = None
    drop: int | None = None
    misalignment: float = 0.0

    def __post_init__(self) -> None:
        if self.loose_in not in SLIP_WHEN:
            raise SimulationConfigError(f"a loose wearable slips in a turn or a pause ({', '.join(SLIP_WHEN)}); "
                                        f"got {self.loose_in!r}")
        checked_misalignment(self.misalignment)
        if self.out is not None and self.out in (self.loose, self.drop):
            raise SimulationConfigError(f"wearable {self.out} lies beside the tray: it cannot slip in a slot or drop "
                                        "its link in a turn")


@dataclass(frozen=True, eq=False)
class KitDeviceTruth:
    """What really happened to one wearable of a simulated kit."""

    k: np.ndarray  # (3,) eq. (1) scale factors against true time
    b: np.ndarray  # (3,) biases, deg/s of true rate
    clock_error: float  # e: the wearable's clock runs at (1 + e) times true time
    start_s: float  # true time of its first sample, s
    mount: np.ndarray  # (3, 3) device-from-tray rotation before any slip
    slip_deg: float  # how far it slipped in its slot (0: it did not)
    slip_t: float | None  # its own stamp (s) when the slip was half done, None without a slip
    off_diagonal: np.ndarray = field(default_factory=lambda: np.zeros(3))  # (K_xy, K_xz, K_yz) of its K, true time
    clock_origin_s: float = 0.0  # its own stamp of its first sample (its clock counts from its power-up), s

    @property
    def K(self) -> np.ndarray:
        """Its full K (upper-triangular, ``calib.effects.AxisMisalignment``) against true time."""
        return AxisMisalignment(self.off_diagonal).matrix(self.k)

    @property
    def K_own(self) -> np.ndarray:
        """The full K a calibration on the wearable's own stamps should find."""
        return self.K / (1.0 + self.clock_error)

    @property
    def k_own(self) -> np.ndarray:
        """The scale factors a calibration on the wearable's own stamps should find."""
        return self.k / (1.0 + self.clock_error)

    @property
    def b_own(self) -> np.ndarray:
        """The biases a calibration on the wearable's own stamps should find (deg/s)."""
        return self.b / (1.0 + self.clock_error)

    def to_dict(self) -> dict[str, object]:
        return {
            "k": [float(v) for v in self.k_own], "b": [float(v) for v in self.b_own],
            "K": [[float(v) for v in row] for row in self.K_own],
            "clock_error": self.clock_error, "start_s": self.start_s, "clock_origin_s": self.clock_origin_s,
            "mount_deg": float(np.degrees(Rotation.from_matrix(self.mount).magnitude())),
            "slip_deg": self.slip_deg, "slip_t": self.slip_t,
        }


@dataclass(frozen=True, eq=False)
class KitTruth:
    """The tray's motion and every wearable's truth."""

    devices: tuple[KitDeviceTruth, ...]
    tray: Trajectory
    noise_dps: float
    fs: float
    seed: int


class KitTray:
    """One performance of the tray: its motion, drawn once, and each wearable in it, drawn on demand at its own rate
    (the draws of one wearable depend on the seed and its place only, so wearables of one tray may be asked for at
    different moments and rates)."""

    def __init__(self, seed: int, n_devices: int, *, noise: float = 0.03, script: ProtocolScript | None = None,
                 params: list[SensorParams] | None = None, mount_deg: float = MOUNT_DEG,
                 clock_error: float = CLOCK_ERROR, start_spread_s: float = START_SPREAD_S, slip: Slip | None = None,
                 motion_fs: float = 104.0, misalignment: float = 0.0, clock_origin_s: float = CLOCK_ORIGIN_S,
                 out: int | None = None) -> None:
        self.seed = check_seed(seed)
        if not isinstance(n_devices, int) or n_devices < 1:
            raise SimulationConfigError(f"a kit needs a whole number of wearables >= 1; got {n_devices!r}")
        if params is not None and len(params) != n_devices:
            raise SimulationConfigError(f"params holds {len(params)} sensors for {n_devices} wearables")
        if slip is not None and slip.device >= n_devices:
            raise SimulationConfigError(f"the slipping wearable {slip.device} is not one of the {n_devices} (0-based)")
        if out is not None and not 0 <= out < n_devices:
            raise SimulationConfigError(f"the wearable beside the tray, {out}, is not one of the {n_devices} (0-based)")
        if out is not None and slip is not None and slip.device == out:
            raise SimulationConfigError(f"wearable {out} lies beside the tray: it cannot slip in a slot")
        self.n_devices, self.noise, self.params, self.slip, self.out = n_devices, float(noise), params, slip, out
        self.mount_deg, self.clock_error, self.start_spread_s = mount_deg, clock_error, start_spread_s
        self.clock_origin_s = as_float(clock_origin_s, "clock_origin_s", positive=False)
        self.misalignment = checked_misalignment(misalignment)
        ss_script, ss_traj, *self._ss_dev = np.random.SeedSequence(self.seed).spawn(2 + n_devices)
        if script is None:
            script = paper_protocol_script(np.random.default_rng(ss_script))
        self.tray = build_trajectory(script, as_float(motion_fs, "fs") * OVERSAMPLE, np.random.default_rng(ss_traj))
        self._tray_t = np.arange(self.tray.n + 1) / self.tray.fs
        self._pose = Slerp(self._tray_t, self.tray.attitude)
        self._slip_window = _slip_window(self.tray, slip) if slip is not None else None

    def wearable(self, d: int, fs: float) -> tuple[Recording, KitDeviceTruth]:
        """Wearable ``d`` (0-based) of the tray sampled at ``fs`` Hz on its own clock: its recording and truth."""
        fs = as_float(fs, "fs")
        rng = np.random.default_rng(self._ss_dev[d])
        sensor = self.params[d] if self.params is not None else SensorParams.paper_random(rng)
        e = float(rng.uniform(-self.clock_error, self.clock_error))
        start = float(rng.uniform(0.0, self.start_spread_s))
        end = self._tray_t[-1] - float(rng.uniform(0.0, self.start_spread_s))
        n = int(np.floor((end - start) * fs * (1.0 + e)))
        tau = start + np.arange(n + 1) / (fs * (1.0 + e))  # true instants of its samples (and the end of the last)
        mount = Rotation.from_rotvec(_unit(rng) * np.radians(rng.uniform(0.0, self.mount_deg)))
        # drawn apart, so that a kit's other draws stay as they were without it
        origin = float(np.random.default_rng([self.seed, d, 0xC10C]).uniform(0.0, self.clock_origin_s))
        in_tray = mount.inv()  # the device's axes in tray axes
        slip_deg, slip_t = 0.0, None
        if self._slip_window is not None and self.slip is not None and self.slip.device == d:
            t0, t1 = self._slip_window
            progress = np.clip((tau - t0) / (t1 - t0), 0.0, 1.0)
            progress = progress * progress * (3.0 - 2.0 * progress)  # a smooth step
            in_tray = Rotation.from_rotvec(np.outer(progress, _unit(rng)) * np.radians(self.slip.angle_deg)) * in_tray
            slip_deg, slip_t = float(self.slip.angle_deg), float(origin + (0.5 * (t0 + t1) - start) * (1.0 + e))
        # beside the tray it lies as the tray did at its first sample: still, whatever the tray does
        pose = self._pose(np.full_like(tau, tau[0]) if d == self.out else tau) * in_tray
        rate = np.degrees((pose[:-1].inv() * pose[1:]).as_rotvec()) * (fs * (1.0 + e))
        accel = pose[:-1].inv().apply(GRAVITY_UP)
        if self.params is None and self.misalignment > 0:  # drawn apart from the rest: a kit without it stays as it was
            sensor = replace(sensor, off_diagonal=misaligned(np.random.default_rng([self.seed, d, 1]), self.misalignment))
        gyro = sensor.reading(rate) + self.noise * rng.standard_normal(rate.shape)
        accel = accel + ACCEL_NOISE_G * rng.standard_normal(accel.shape)
        seq = np.arange(n, dtype=np.int64)
        rec = Recording(origin + seq / fs, gyro, accel, seq,
                        meta=RecordingMeta(sample_rate_hz=fs, device_id=f"kit-{self.seed}-{d + 1}", sensor_model="simulated",
                                           source=f"simulate_kit(seed={self.seed}) wearable {d + 1}"))
        return rec, KitDeviceTruth(sensor.k.copy(), sensor.b.copy(), e, start, mount.as_matrix(), slip_deg, slip_t,
                                   sensor.off_diagonal.copy(), origin)


def simulate_kit(
    seed: int,
    n_devices: int,
    *,
    noise: float = 0.03,
    fs: float = 104.0,
    script: ProtocolScript | None = None,
    params: list[SensorParams] | None = None,
    mount_deg: float = MOUNT_DEG,
    clock_error: float = CLOCK_ERROR,
    start_spread_s: float = START_SPREAD_S,
    slip: Slip | None = None,
    misalignment: float = 0.0,
    clock_origin_s: float = CLOCK_ORIGIN_S,
    out: int | None = None,
) -> tuple[list[Recording], KitTruth]:
    """Simulate ``n_devices`` wearables in one tray following ``script`` (default: the paper protocol, drawn per seed).

    ``params``: each wearable's sensor (default: the paper's ranges, drawn). ``noise``: white-noise std of every
    gyroscope (deg/s). ``mount_deg``, ``clock_error``, ``start_spread_s``: the largest mounting rotation (deg), clock
    error (fraction) and difference in start and stop (s) drawn; ``misalignment``: the largest off-diagonal entry of
    each sensor's (upper-triangular) K, drawn uniform in +-this per entry (``calib.effects.AxisMisalignment``);
    ``clock_origin_s``: the longest a wearable's clock has counted since its power-up at its first sample (s);
    ``out`` (0-based): that wearable lies on the table beside the tray, switched on (it turns with nothing).
    Returns one recording per wearable (its own stamps t = o + j / fs, o drawn in 0..clock_origin_s, and its sample
    counter) and the truth. Same seed and
    arguments give the same kit.
    """
    tray = KitTray(seed, n_devices, noise=noise, script=script, params=params, mount_deg=mount_deg,
                   clock_error=clock_error, start_spread_s=start_spread_s, slip=slip, motion_fs=fs,
                   misalignment=misalignment, clock_origin_s=clock_origin_s, out=out)
    drawn = [tray.wearable(d, fs) for d in range(n_devices)]
    return [r for r, _ in drawn], KitTruth(tuple(t for _, t in drawn), tray.tray, float(noise), float(fs), tray.seed)


def misaligned(rng: np.random.Generator, largest: float) -> np.ndarray:
    """A sensor's non-orthogonality: the entries above its K's diagonal (K_xy, K_xz, K_yz), each uniform in +-largest."""
    return rng.uniform(-1.0, 1.0, 3) * largest


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


def _slip_window(tray: Trajectory, slip: Slip) -> tuple[float, float]:
    """When the slip happens (true time, s): in the middle of the turn it is asked for, or early in the pause after it
    (a pause that fixed time after the turn: a plan that grows after it does not move it)."""
    turns = [s for s in tray.stages if s.kind == "turn"]
    if slip.turn >= len(turns):
        raise SimulationConfigError(f"the script has {len(turns)} turns; a slip in turn {slip.turn} (0-based) cannot happen")
    turn = turns[slip.turn]
    if slip.in_pause:
        start = turn.end_s + PAUSE_SLIP_AFTER_S
        after = [s for s in tray.stages if s.start_s >= turn.end_s - 1e-9 and s.kind != "still"]
        if after and after[0].start_s < start + SLIP_S:
            raise SimulationConfigError(f"the pause after turn {slip.turn} (0-based) lasts {after[0].start_s - turn.end_s:.2f} s: "
                                        f"a slip {PAUSE_SLIP_AFTER_S:g} s into it needs {PAUSE_SLIP_AFTER_S + SLIP_S:g} s")
        return start, start + SLIP_S
    middle = 0.5 * (turn.start_s + turn.end_s)
    return middle - 0.5 * SLIP_S, middle + 0.5 * SLIP_S
