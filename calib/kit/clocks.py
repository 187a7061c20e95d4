"""Every wearable of a kit on one clock: the map from a wearable's own stamps to the reference wearable's.

Each wearable stamps its samples with its own clock, which starts at its own moment (its power-up, minutes apart
from the others') and runs at its own rate. Turned together, the wearables see one motion, so the motion itself
aligns their clocks: ``coarse_clock`` matches the magnitude of the rotation rate (which no mounting rotation changes)
by cross-correlation, first over the whole recording at every lag where the two overlap, then window by window for
the rate; ``calib.kit.coupling`` then refines the map sample by sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import correlate, correlation_lags

from calib.errors import KitRefusal
from calib.kit.turns import gaps
from calib.recording import Recording

WINDOW_S = 4.0  # windows whose lags give the clock rate
MIN_OVERLAP_S = 10.0  # recordings that share less of the motion cannot be a kit's


@dataclass(frozen=True)
class ClockMap:
    """Reference time = ``offset_s`` + ``rate`` * own stamp (s), with 1-sigma uncertainties."""

    offset_s: float
    rate: float
    offset_std_s: float = float("nan")
    rate_std: float = float("nan")

    def to_reference(self, t: np.ndarray) -> np.ndarray:
        """Own stamps (s) as reference times (s)."""
        return self.offset_s + self.rate * np.asarray(t, dtype=float)

    def to_own(self, t_ref: np.ndarray | float) -> np.ndarray:
        """Reference times (s) as own stamps (s)."""
        return (np.asarray(t_ref, dtype=float) - self.offset_s) / self.rate

    def corrected(self, lag_at_zero_s: float, lag_slope: float) -> ClockMap:
        """The map once the samples it put at reference time t were found to belong at t + lag_at_zero + slope t."""
        return ClockMap(self.offset_s * (1.0 + lag_slope) + lag_at_zero_s, self.rate * (1.0 + lag_slope),
                        self.offset_std_s, self.rate_std)

    def to_dict(self) -> dict[str, float | None]:
        def num(v: float) -> float | None:
            return float(v) if np.isfinite(v) else None

        return {"offset_s": num(self.offset_s), "rate_ppm": num((self.rate - 1.0) * 1e6),
                "offset_std_s": num(self.offset_std_s), "rate_std_ppm": num(self.rate_std * 1e6)}


IDENTITY = ClockMap(0.0, 1.0, 0.0, 0.0)


def activity(rec: Recording) -> np.ndarray:
    """How fast the wearable turns at each sample (deg/s): the norm of the readings less their median (the rest
    offset, since each axis is still most of the protocol)."""
    return np.linalg.norm(rec.gyro - np.median(rec.gyro, axis=0), axis=1)


def coarse_clock(ref: Recording, rec: Recording, max_rate_error: float = 0.05,
                 names: tuple[str, str] | None = None) -> ClockMap:
    """The map from ``rec``'s stamps to ``ref``'s, to a fraction of a sample. KitRefusal when the two recordings
    do not share enough of one motion (``names``: the two wearables' names, ref's first, to say which)."""
    dt = float(np.median(np.diff(ref.t)))
    grid = np.arange(ref.t[0], ref.t[-1], dt)
    s_ref = np.interp(grid, ref.t, activity(ref))
    s_rec = activity(rec)
    # each on its own stamps, which may start minutes apart (each clock counts from its own power-up): every lag at
    # which the two recordings overlap is tried
    own = np.arange(rec.t[0], rec.t[-1], dt)
    lag = _best_lag(s_ref, np.interp(own, rec.t, s_rec), dt, max(len(grid), len(own)))
    # rec's sample stamped rec.t[0] + lag + (t - ref.t[0]) happened at reference time t
    clock = ClockMap(ref.t[0] - rec.t[0] - lag, 1.0)
    search = max_rate_error * (grid[-1] - grid[0]) + 4 * dt
    for _ in range(3):
        centres, lags, weights = _window_lags(grid, s_ref, clock.to_own(grid), rec.t, s_rec, dt, search)
        if centres.size < 2:
            break
        slope, at_zero = np.polyfit(centres, -lags, 1, w=np.sqrt(weights))
        clock = clock.corrected(float(at_zero), float(slope))
        search = max(0.25 * search, 4 * dt)
    overlap = min(ref.t[-1], clock.to_reference(rec.t[-1])) - max(ref.t[0], clock.to_reference(rec.t[0]))
    if overlap < MIN_OVERLAP_S:
        ref_name, rec_name = names or (_name(ref), _name(rec))
        raise KitRefusal(f"{rec_name} shares only {max(overlap, 0.0):.1f} s of motion with {ref_name}: a kit's "
                         "recordings must be taken together, of one motion of the tray; check the files belong to one "
                         "session", wearable=rec_name, reference=ref_name)
    return clock


def _name(rec: Recording) -> str:
    return rec.meta.device_id or rec.meta.source or "a recording"


def _best_lag(a: np.ndarray, b: np.ndarray, dt: float, max_lag: int) -> float:
    """The lag L (s) at which b(t + L) best matches a(t), to a fraction of a sample (parabola through the peak)."""
    a0, b0 = a - a.mean(), b - b.mean()
    xc = correlate(b0, a0, mode="full", method="fft")
    lags = correlation_lags(b.size, a.size, mode="full")
    keep = np.abs(lags) <= max_lag
    xc, lags = xc[keep], lags[keep]
    i = int(np.argmax(xc))
    frac = 0.0
    if 0 < i < xc.size - 1:
        den = xc[i - 1] - 2 * xc[i] + xc[i + 1]
        frac = 0.5 * (xc[i - 1] - xc[i + 1]) / den if den < 0 else 0.0
    return float((lags[i] + frac) * dt)


def _matched_lag(template: np.ndarray, signal: np.ndarray) -> float:
    """Where ``template`` best matches a stretch of the longer ``signal``, in samples from its start, to a fraction of
    a sample: the peak of the normalised cross-correlation (which no difference in scale or offset moves)."""
    w = template.size
    a0 = template - template.mean()
    num = correlate(signal, a0, mode="valid", method="fft")
    c1 = np.concatenate([[0.0], np.cumsum(signal)])
    c2 = np.concatenate([[0.0], np.cumsum(signal * signal)])
    sums, squares = c1[w:] - c1[:-w], c2[w:] - c2[:-w]
    spread = np.sqrt(np.maximum(squares - sums * sums / w, 1e-30))
    ncc = num / spread
    i = int(np.argmax(ncc))
    frac = 0.0
    if 0 < i < ncc.size - 1:
        den = ncc[i - 1] - 2 * ncc[i] + ncc[i + 1]
        frac = 0.5 * (ncc[i - 1] - ncc[i + 1]) / den if den < 0 else 0.0
    return i + frac


def _window_lags(grid: np.ndarray, s_ref: np.ndarray, own: np.ndarray, t_rec: np.ndarray, s_rec: np.ndarray, dt: float,
                 search_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lags of ``rec`` (as currently mapped) against ``ref`` in windows that hold motion: centres (s), lags (s), weights."""
    size = int(round(WINDOW_S / dt))
    mapped = np.interp(own, t_rec, s_rec, left=np.nan, right=np.nan)
    for j in np.nonzero(gaps(t_rec))[0]:  # samples lost: no activity to match there
        mapped[(own > t_rec[j]) & (own < t_rec[j + 1])] = np.nan
    max_lag = int(np.ceil(search_s / dt))
    floor = 0.1 * float(np.max(s_ref))
    centres, lags, weights = [], [], []
    for start in range(0, grid.size - size, size // 2):
        a = s_ref[start:start + size]
        lo, hi = start - max_lag, start + size + max_lag
        if lo < 0 or hi > grid.size or np.max(a) < floor:
            continue
        b = mapped[lo:hi]
        if np.isnan(b).any():
            continue
        centres.append(grid[start + size // 2])
        lags.append((_matched_lag(a, b) - max_lag) * dt)
        weights.append(float(np.sum(np.diff(a) ** 2)))
    return np.array(centres), np.array(lags), np.array(weights)
