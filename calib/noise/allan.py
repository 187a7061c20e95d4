"""The overlapping Allan deviation of one axis at rest, with each point's equivalent degrees of freedom and 95 % band.

The deviation itself is allantools' ``oadev`` on the readings as frequency data (rates in deg/s, or specific force in
g), at octave averaging times from ``MIN_M`` samples to a ``MAX_FRACTION`` of the recording. The degrees of freedom
of each point are those of the overlapping estimator for the mix of noises the fit finds there:

- **white and random-walk rate noise, exactly**: the estimator averages the squares of d_i, the difference of two
  adjacent m-sample means, a finite filter h of the readings (of the walk's increments, its running sum g). For
  Gaussian noise var(AVAR) = (1 / (2 M^2)) sum_k (M - |k|) c(k)^2 with c the autocovariance of d, here
  c = s_w c_white + s_rw c_walk (each normalised, s their shares of the point's variance), so
  edf = M^2 (s_w + s_rw)^2 / sum_k (M - |k|) c(k)^2, M = n - 2m + 1. Alone, it is NIST SP 1065's formula for white
  noise (its Table 5, to 6 digits) and within 1-5 % of Greenhall's algorithm for a walk; mixed, it carries their
  cross term, which neither formula has (bounding it by Cauchy-Schwarz made the random walk's intervals too wide:
  97.3 % of them held the truth).
- **flicker** (a Gauss-Markov term near its correlation time) by Greenhall's (2004) algorithm (allantools'
  ``edf_greenhall``), combined with the rest by the Cauchy-Schwarz bound 1/sqrt(e) = sum_i share_i / sqrt(e_i).

The band is the chi-squared interval they give (allantools' ``confidence_interval``).
Averaging times shorter than ``MIN_M`` samples are left out: there the sensor's own anti-alias filter, not its
noise, shapes the curve (adjacent samples of a MEMS sensor sampled near its filter's corner are correlated).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

MIN_M = 4  # shortest averaging time, samples
MAX_FRACTION = 1.0 / 9.0  # longest averaging time, of the recording: at least 9 of them in it
MIN_POINTS = 4  # a curve needs this many averaging times to be read


@dataclass(frozen=True)
class AllanCurve:
    """One axis's overlapping Allan deviation: averaging times (s), deviations (the readings' unit), degrees of
    freedom and 95 % bands."""

    tau_s: np.ndarray
    adev: np.ndarray
    edf: np.ndarray
    lo95: np.ndarray
    hi95: np.ndarray

    @property
    def avar(self) -> np.ndarray:
        """The Allan variance (the deviation squared)."""
        return self.adev**2


def octave_factors(n: int) -> np.ndarray:
    """The averaging factors (samples) read from ``n`` samples: powers of two from ``MIN_M`` to ``MAX_FRACTION`` of n."""
    top = int(np.floor(np.log2(max(n * MAX_FRACTION, 1.0))))
    return 2 ** np.arange(int(np.log2(MIN_M)), top + 1)


def allan_deviation(x: np.ndarray, fs: float, m: np.ndarray) -> np.ndarray:
    """The overlapping Allan deviation of readings ``x`` (one axis, sampled at ``fs`` Hz) at averaging factors ``m``."""
    import allantools

    taus, adev, _, _ = allantools.oadev(np.asarray(x, float), rate=fs, data_type="freq", taus=m / fs)
    if taus.size != m.size:  # allantools drops averaging times it cannot read; ours are all readable by construction
        raise ValueError(f"the Allan deviation was read at {taus.size} of {m.size} averaging times")
    return np.asarray(adev, float)


ALPHAS = (0, -1, -2)  # the noise types whose degrees of freedom are mixed: white, flicker, random-walk rate


@lru_cache(maxsize=512)
def _filter_sums(m: int, n: int) -> tuple[int, float, float, float]:
    """M and sum_k (M - |k|) c_a(k) c_b(k) for (white, white), (white, walk), (walk, walk): c the normalised
    autocovariance of the estimator's difference of m-sample means of n readings (module docstring)."""
    from scipy.signal import fftconvolve

    h = np.concatenate([-np.ones(m), np.ones(m)]) / m
    g = np.cumsum(h[::-1])[::-1]  # the walk's increments see the running sum of h
    cw, cr = fftconvolve(h, h[::-1]), fftconvolve(g, g[::-1])
    cw, cr = cw / cw[2 * m - 1], cr / cr[2 * m - 1]
    M = n - 2 * m + 1
    w = np.maximum(M - np.abs(np.arange(-(2 * m - 1), 2 * m)), 0).astype(float)
    return M, float(w @ cw**2), float(w @ (cw * cr)), float(w @ cr**2)


def white_walk_edf(m: int, n: int, s_white: float, s_walk: float) -> float:
    """The exact degrees of freedom of the overlapping Allan variance at m of n readings whose variance there is
    white rate noise and a rate random walk in shares ``s_white``, ``s_walk``."""
    M, A, B, C = _filter_sums(int(m), int(n))
    return M**2 * (s_white + s_walk) ** 2 / (s_white**2 * A + 2 * s_white * s_walk * B + s_walk**2 * C)


def with_bands(tau_s: np.ndarray, adev: np.ndarray, m: np.ndarray, n: int, shares: np.ndarray) -> AllanCurve:
    """The curve with its degrees of freedom and 95 % bands. ``shares`` (T, 3): the part of each point's variance
    that is of each noise type in ``ALPHAS`` (module docstring)."""
    import allantools

    edf = np.empty(m.size)
    for i, (mm, (s_w, s_f, s_rw)) in enumerate(zip(m, shares, strict=True)):
        parts = []
        if s_w + s_rw > 0:
            parts.append((s_w + s_rw, white_walk_edf(int(mm), n, s_w, s_rw)))
        if s_f > 0:
            parts.append((s_f, allantools.edf_greenhall(-1, 2, int(mm), n + 1, overlapping=True)))
        edf[i] = 1.0 / sum(sh / np.sqrt(e) for sh, e in parts) ** 2
    lo, hi = np.array([allantools.confidence_interval(d, e, ci=0.95) for d, e in zip(adev, edf, strict=True)]).T
    return AllanCurve(tau_s, adev, edf, lo, hi)
