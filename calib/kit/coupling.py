"""The rigid coupling of two wearables in one tray: one's readings as a linear map of the other's, at every sample.

Turned together, wearable i and the reference measure one angular velocity in two frames. With g = K m + b (eq. 1)
for each and g_i = R g_ref, the readings satisfy m_i = A m_ref + c with A = K_i^-1 R K_ref and
c = K_i^-1 (R b_ref - b_i): twelve numbers that every sample of the motion constrains. ``couple`` resamples
wearable i onto the reference's clock and fits them, refining the clock map from the same residuals (a sample put
at the wrong time leaves a residual along the rate's derivative).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from calib.errors import GyrocalError
from calib.kit.clocks import ClockMap, activity
from calib.kit.turns import gaps
from calib.recording import Recording

REFINE_PASSES = 3
RUN_SHIFT_FROM = 2  # passes with one clock for the whole recording before each run after a gap gets its own offset
RUN_SHIFT_Z = 3.0  # a run's offset this many of its standard errors from none is kept; a smaller one is taken as none
REST_SHARE = 0.3  # the share of samples with the least motion, where a residual is the readings' noise alone


@dataclass(frozen=True, eq=False)
class LinearMap:
    """One wearable's readings against a reference signal: m = A x + c (deg/s).

    ``cov`` (3, 4, 4): per output axis, the covariance of (A[a, 0], A[a, 1], A[a, 2], c[a]) from the residuals;
    ``bound_cov`` the same from the readings' noise alone (the Cramér-Rao bound of the linear model).
    """

    A: np.ndarray
    c: np.ndarray
    cov: np.ndarray
    bound_cov: np.ndarray
    residual_sd: np.ndarray
    noise_sd: np.ndarray

    def invert(self, m: np.ndarray) -> np.ndarray:
        """Readings m as the reference signal: A^-1 (m - c)."""
        return np.linalg.solve(self.A, (np.asarray(m) - self.c).T).T


IDENTITY_MAP = LinearMap(np.eye(3), np.zeros(3), np.zeros((3, 4, 4)), np.zeros((3, 4, 4)), np.zeros(3), np.zeros(3))


@dataclass(frozen=True, eq=False)
class Coupling:
    """Wearable i against the reference wearable: its clock map, its readings at the reference's sample times (NaN
    where it did not record) and its readings' map from the reference's."""

    clock: ClockMap
    readings: np.ndarray
    map: LinearMap


def fit_map(x: np.ndarray, y: np.ndarray, x_noise: np.ndarray, rest: np.ndarray, y_noise: np.ndarray | None = None) -> LinearMap:
    """y = A x + c by least squares over rows of both, the regressors' noise std ``x_noise`` (per axis) taken out of
    the normal matrix (errors in variables); ``rest``: rows where the residual is the noise alone. Rows either lacks
    (NaN: samples lost) are left out.

    ``y_noise``: y's own noise std per axis. When x is the kit's mean of the other wearables, their noise is in the
    kit's mean too, and it moves the mean's calibration and this map together, in opposite ways, so the wearable's
    calibration carries only its own noise: the map's covariance is then y's own noise (scaled by how far the
    residual exceeds what the noise of both explains), not the residual's."""
    both = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(y), axis=1)
    x, y, rest = x[both], y[both], rest[both]
    A, c, normal = _fit(x, y, x_noise)
    resid = y - x @ A.T - c
    resid_ms = resid.var(axis=0)
    noise_ms = resid[rest].var(axis=0) if rest.sum() > 20 else resid_ms
    inv = np.linalg.inv(normal)
    if y_noise is None:
        return LinearMap(A, c, resid_ms[:, None, None] * inv, noise_ms[:, None, None] * inv, np.sqrt(resid_ms), np.sqrt(noise_ms))
    own = np.asarray(y_noise, dtype=float) ** 2
    expected = own + (A**2) @ (np.asarray(x_noise, dtype=float) ** 2)
    excess = np.maximum(1.0, resid_ms / expected)
    return LinearMap(A, c, (own * excess)[:, None, None] * inv, own[:, None, None] * inv, np.sqrt(resid_ms), np.sqrt(expected))


def reading_noise(rec: Recording) -> np.ndarray:
    """Each axis' white-noise std (deg/s) from the second differences of the samples with the least motion."""
    still = resting(rec)
    d2 = rec.gyro[2:] - 2 * rec.gyro[1:-1] + rec.gyro[:-2]
    d2 = d2[still[1:-1]]
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    return 1.4826 * mad / np.sqrt(6.0)


def resting(rec: Recording) -> np.ndarray:
    """The samples in the quietest share of the recording, judged on the motion smoothed over a quarter second (so
    that no sample is chosen for its own noise being small)."""
    width = max(3, int(round(0.25 * rec.fs)))
    smooth = np.convolve(activity(rec), np.ones(width) / width, mode="same")
    return np.asarray(smooth <= np.quantile(smooth, REST_SHARE))


def runs(rec: Recording) -> np.ndarray:
    """Which run of samples without a gap each sample of ``rec`` belongs to (0, 1, ...: a new run after each gap)."""
    return np.concatenate([[0], np.cumsum(gaps(rec.t))])


def resample(rec: Recording, clock: ClockMap, t_ref: np.ndarray, run_shift: np.ndarray | None = None,
             clock_run: np.ndarray | None = None) -> np.ndarray:
    """``rec``'s readings at reference times ``t_ref`` (NaN outside them and across samples it lost, where no reading
    says how it turned): a cubic spline through each run of samples without a gap (one spline across a gap would bend
    the readings beside it). ``run_shift``: a further shift (s) of each clock run's times (a wearable may stamp anew
    after its link came back); ``clock_run``: each sample's clock run (default: a new one after each gap)."""
    t = clock.to_reference(rec.t)
    run = runs(rec)
    if run_shift is not None:
        t = t + run_shift[run if clock_run is None else clock_run]
    out = np.full((t_ref.size, 3), np.nan)
    for r in range(int(run[-1]) + 1):
        seg = np.nonzero(run == r)[0]
        if seg.size < 4:
            continue
        inside = (t_ref >= t[seg[0]]) & (t_ref <= t[seg[-1]])
        out[inside] = CubicSpline(t[seg], rec.gyro[seg], axis=0, extrapolate=False)(t_ref[inside])
    return out


def couple(ref: Recording, rec: Recording, clock: ClockMap, ref_noise: np.ndarray,
           clock_run: np.ndarray | None = None) -> Coupling:
    """Fit ``rec`` = A ``ref`` + c over every sample both hold, refining ``clock`` as it goes (and, after a gap in
    ``rec``, each later run's own offset).

    ``ref_noise``: the reference's noise std per axis (deg/s), which biases a plain least-squares fit of A towards
    zero by noise^2 / rate^2 and is taken out (errors in variables). ``clock_run``: each sample's run of one clock
    offset, when not every gap may start a new one (readings left out for clipping are gaps the wearable's stamps
    ran through: an offset fitted to each run after one would take the scale's information, not a clock's)."""
    run = runs(rec) if clock_run is None else np.unique(clock_run, return_inverse=True)[1]
    n_runs = int(run[-1]) + 1
    shifted = np.arange(n_runs) > 0  # the runs given an offset of their own
    fit = _refine(ref, rec, run, clock, np.zeros(n_runs), shifted, REFINE_PASSES + (RUN_SHIFT_FROM if n_runs > 1 else 0),
                  RUN_SHIFT_FROM, ref_noise)
    while shifted.any():
        z = np.abs(fit.run_shift) / np.sqrt(np.maximum(np.diag(fit.cov)[1:], 1e-30))  # cov: offset, rate, each run's
        kept = shifted & (z >= RUN_SHIFT_Z)
        if (kept == shifted).all():
            break
        # an offset the data cannot tell from none is none: the wearable's clock ran through that gap, and a free
        # offset there would only take what the run tells of the scale
        shifted = kept
        fit.run_shift[~shifted] = 0.0
        fit = _refine(ref, rec, run, fit.clock, fit.run_shift, shifted, REFINE_PASSES, 0, ref_noise)
    clock = ClockMap(fit.clock.offset_s, fit.clock.rate, float(np.sqrt(fit.cov[0, 0])),
                     float(fit.clock.rate * np.sqrt(fit.cov[1, 1])))
    y, keep, x, yk, tk = fit.y, fit.keep, fit.x, fit.yk, fit.tk
    rest = np.interp(tk, clock.to_reference(rec.t), resting(rec).astype(float)) > 0.99
    out = np.full_like(y, np.nan)
    out[keep] = yk
    return Coupling(clock, out, fit_map(x, yk, ref_noise, rest))


class _Refined:
    """One refinement of a coupling's clock: the clock, each run's further offset (s), and the last pass's samples
    (``y`` resampled, the rows ``keep`` both hold, and those rows' reference readings, readings and times) and the
    covariance of the clock's offset, rate and the runs' offsets."""

    def __init__(self, clock: ClockMap, run_shift: np.ndarray) -> None:
        self.clock, self.run_shift = clock, run_shift
        empty: np.ndarray = np.empty(0)
        self.y, self.x, self.yk, self.tk, self.cov = empty, empty, empty, empty, empty
        self.keep: np.ndarray = np.empty(0, dtype=bool)


def _refine(ref: Recording, rec: Recording, run: np.ndarray, clock: ClockMap, run_shift: np.ndarray, shifted: np.ndarray,
            passes: int, shift_from: int, ref_noise: np.ndarray) -> _Refined:
    """``passes`` refinements of ``clock`` and, from pass ``shift_from``, of the ``shifted`` runs' offsets (before it,
    one clock for the whole recording)."""
    run_shift = run_shift.copy()
    out = _Refined(clock, run_shift)
    n_runs = run_shift.size
    for pass_ in range(passes):
        y = resample(rec, clock, ref.t, run_shift, run)
        keep = np.all(np.isfinite(y), axis=1)
        if keep.sum() < 50:
            raise GyrocalError(f"{rec.meta.source or 'a recording'} shares too few samples with the reference to be coupled")
        x, yk, tk = ref.gyro[keep], y[keep], ref.t[keep]
        A, c, _ = _fit(x, yk, ref_noise)
        fitted = x @ A.T + c
        slope = np.gradient(fitted, tk, axis=0)
        resid = yk - fitted
        columns = [slope, slope * tk[:, None]]
        free = [r for r in range(1, n_runs) if shifted[r]] if pass_ >= shift_from else []
        if free:  # which run each reference time falls in
            starts = clock.to_reference(rec.t[np.searchsorted(run, np.arange(n_runs))]) + run_shift
            row_run = np.searchsorted(starts, tk, side="right") - 1
            columns += [slope * (row_run == r)[:, None] for r in free]
        design = np.stack([col.ravel() for col in columns], axis=1)
        shift, *_ = np.linalg.lstsq(design, resid.ravel(), rcond=None)
        clock = clock.corrected(float(shift[0]), float(shift[1]))
        run_shift[free] += shift[2:]
        # pinv: a run too short to be resampled (a sample or two between clipped readings) leaves its shift's column
        # empty; lstsq gave it no shift, and it takes nothing from the clock's own uncertainty
        cov = np.zeros((n_runs + 1, n_runs + 1))
        idx = [0, 1, *[r + 1 for r in free]]
        cov[np.ix_(idx, idx)] = np.linalg.pinv(design.T @ design) * float(resid.var())
        out.clock, out.y, out.keep, out.x, out.yk, out.tk, out.cov = clock, y, keep, x, yk, tk, cov
    return out


def _fit(x: np.ndarray, y: np.ndarray, x_noise: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A, c of y = A x + c by least squares with the regressors' noise taken out of the normal matrix."""
    X = np.column_stack([x, np.ones(len(x))])
    normal = X.T @ X
    normal[:3, :3] -= len(x) * np.diag(np.asarray(x_noise, dtype=float) ** 2)
    theta = np.linalg.solve(normal, X.T @ y)  # (4, 3)
    return theta[:3].T, theta[3], normal
