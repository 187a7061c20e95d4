"""The orientation a recording implies, before and after its calibration (the paper's Figs. 2 and 10, for any
recording): estimated with the ``ahrs`` package's Madgwick filter from gyroscope and accelerometer, or by
integrating the gyroscope alone (``ahrs``' AngularRate) when the recording has no accelerometer.

With an accelerometer the filter holds roll and pitch to gravity, so a calibration shows mostly in yaw (heading),
which only the gyroscope tells; without one every axis is the gyroscope's. Angles are the aerospace sequence
(yaw about z, then pitch about y, then roll about x), in degrees; quaternions are scalar-first (w, x, y, z) and turn
the sensor frame into the reference frame of the first sample.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from calib.errors import GyrocalError
from calib.recording import Recording
from calib.units import STANDARD_GRAVITY

MADGWICK_GAIN = 0.033  # ahrs' default for gyroscope + accelerometer (Madgwick 2010)


@dataclass(frozen=True, eq=False)
class Orientation:
    """Orientations of one recording before (raw readings) and after calibration, sample by sample."""

    t: np.ndarray  # (n,) s
    before: np.ndarray  # (n, 4) quaternions w, x, y, z
    after: np.ndarray  # (n, 4)
    method: str  # what estimated them, in words

    @staticmethod
    def _angles(q: np.ndarray) -> np.ndarray:
        """(n, 3) roll, pitch, yaw in degrees."""
        return Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler("ZYX", degrees=True)[:, ::-1]

    @property
    def angles_before(self) -> np.ndarray:
        return self._angles(self.before)

    @property
    def angles_after(self) -> np.ndarray:
        return self._angles(self.after)

    @staticmethod
    def unwrapped(angles: np.ndarray) -> np.ndarray:
        """Angles without the jumps at +-180 degrees (for plots: a full turn reads as 360)."""
        return np.degrees(np.unwrap(np.radians(angles), axis=0))

    @property
    def difference_deg(self) -> np.ndarray:
        """(n,) the angle between the two orientations: how far the calibration moves the estimate."""
        r = Rotation.from_quat(self.before[:, [1, 2, 3, 0]]).inv() * Rotation.from_quat(self.after[:, [1, 2, 3, 0]])
        return np.degrees(r.magnitude())

    def columns(self) -> dict[str, np.ndarray]:
        """Every column of the orientation table: t, quaternions and angles before (``_raw``) and after, difference."""
        out: dict[str, np.ndarray] = {"t": self.t}
        for suffix, q, ang in (("_raw", self.before, self.angles_before), ("", self.after, self.angles_after)):
            out.update({f"q{c}{suffix}": q[:, i] for i, c in enumerate("wxyz")})
            out.update({f"{a}{suffix}": ang[:, i] for i, a in enumerate(("roll", "pitch", "yaw"))})
        out["difference"] = self.difference_deg
        return out

    def to_csv(self) -> str:
        cols = self.columns()
        lines = [",".join(cols)]
        table = np.column_stack(list(cols.values()))
        lines += [",".join(f"{v:.6g}" for v in row) for row in table]
        return "\n".join(lines) + "\n"

    def summary(self, max_points: int = 2000) -> dict[str, Any]:
        """JSON-ready, decimated to at most ``max_points`` samples: t, roll/pitch/yaw before and after, difference."""
        step = max(1, int(np.ceil(len(self.t) / max_points)))
        pick = slice(None, None, step)
        b, a = self.unwrapped(self.angles_before)[pick], self.unwrapped(self.angles_after)[pick]
        names = ("roll", "pitch", "yaw")
        return {
            "method": self.method,
            "t": self.t[pick].tolist(),
            "before": {n: b[:, i].tolist() for i, n in enumerate(names)},
            "after": {n: a[:, i].tolist() for i, n in enumerate(names)},
            "difference_deg": self.difference_deg[pick].tolist(),
            "final_difference_deg": float(self.difference_deg[-1]),
        }


CHUNK = 20_000  # samples per call of the filter: each call goes on from the last orientation of the one before


def _estimate(gyro_dps: np.ndarray, accel_g: np.ndarray | None, fs: float, progress: Callable[[int], None]) -> np.ndarray:
    from ahrs.common.orientation import acc2q
    from ahrs.filters import AngularRate, Madgwick

    gyr = np.radians(np.asarray(gyro_dps, float))
    acc = None if accel_g is None else np.asarray(accel_g, float) * STANDARD_GRAVITY
    q = np.array([1.0, 0.0, 0.0, 0.0])
    if acc is not None:
        q = acc2q(acc[0])
        q = q / np.linalg.norm(q)
    out = [q[None, :]]
    n = len(gyr)
    for start in range(0, n - 1, CHUNK):  # the filter's first row is q0; row i uses sample i, so chunks overlap by one
        part = slice(start, min(n, start + CHUNK + 1))
        if acc is None:
            Q = AngularRate(gyr=gyr[part], frequency=fs, q0=q).Q
        else:
            Q = Madgwick(gyr=gyr[part], acc=acc[part], frequency=fs, gain=MADGWICK_GAIN, q0=q).Q
        out.append(np.asarray(Q)[1:])
        q = out[-1][-1]
        progress(part.stop - 1 - start)
    return np.vstack(out)


def orientation(raw: Recording, calibrated: Recording, progress: Callable[[int], None] | None = None) -> Orientation:
    """The orientation of a recording from its raw readings and from the calibrated ones (same samples); ``progress``
    is told how many samples were done after each chunk (2 (n - 1) in all)."""
    if len(raw) != len(calibrated) or len(raw) < 2:
        raise GyrocalError("an orientation needs the raw and the calibrated recording, the same samples, at least two")
    fs = raw.fs
    accel_raw = raw.accel
    accel_cal = calibrated.accel if calibrated.accel is not None else raw.accel
    if accel_raw is not None and not np.all(np.isfinite(accel_raw)):
        raise GyrocalError("the recording's accelerometer has missing values: fill or cut them before estimating the orientation")
    method = (f"Madgwick filter (ahrs), gyroscope and accelerometer, gain {MADGWICK_GAIN}" if accel_raw is not None
              else "gyroscope integration (ahrs AngularRate), no accelerometer")
    tick = progress or (lambda _n: None)
    return Orientation(raw.t - raw.t[0], _estimate(raw.gyro, accel_raw, fs, tick), _estimate(calibrated.gyro, accel_cal, fs, tick),
                       method)


def plot_orientation(o: Orientation, path: str | Path, title: str = "") -> Path:
    """Roll, pitch and yaw before and after calibration, and the angle between them, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from calib.plots import save_figure

    fig, axes = plt.subplots(4, 1, figsize=(9, 9), sharex=True)
    before, after = o.unwrapped(o.angles_before), o.unwrapped(o.angles_after)
    for i, name in enumerate(("roll", "pitch", "yaw")):
        axes[i].plot(o.t, before[:, i], color="#b0413e", lw=1, label="raw readings")
        axes[i].plot(o.t, after[:, i], color="#1f6f8b", lw=1, label="calibrated")
        axes[i].set_ylabel(f"{name} (°)")
        axes[i].grid(alpha=0.3)
    axes[0].legend(loc="upper left")
    axes[3].plot(o.t, o.difference_deg, color="#333", lw=1)
    axes[3].set_ylabel("difference (°)")
    axes[3].set_xlabel("time (s)")
    axes[3].grid(alpha=0.3)
    fig.suptitle(title or f"Orientation before and after calibration ({o.method})", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)
