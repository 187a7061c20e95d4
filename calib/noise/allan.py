"""The overlapping Allan deviation of one axis at rest, with each point's equivalent degrees of freedom and 95 % band.

The deviation itself is allantools' ``oadev`` on the readings as frequency data (rates in deg/s, or specific force in
g), at octave averaging times from ``MIN_M`` samples to a ``MAX_FRACTION`` of the recording. The degrees of freedom
are those of the overlapping estimator for the noise type that dominates at each averaging time: for white rate
noise NIST SP 1065's formula (its Table 5, allantools' ``edf_simple``), for the others Greenhall's (2004) algorithm
(``edf_greenhall``). Each is the one that matches the estimator's spread measured on 300 simulated hours (within 2 %
for white noise at 4 to 8192 samples, where Greenhall's is 13 % low at 4 samples; within 5 % for a random walk,
where SP 1065's is 10 % high). The band is the chi-squared interval they give (allantools' ``confidence_interval``).
Averaging times shorter than ``MIN_M`` samples are left out: there the sensor's own anti-alias filter, not its
noise, shapes the curve (adjacent samples of a MEMS sensor sampled near its filter's corner are correlated).
"""

from __future__ import annotations

from dataclasses import dataclass

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


def with_bands(tau_s: np.ndarray, adev: np.ndarray, m: np.ndarray, n: int, shares: np.ndarray) -> AllanCurve:
    """The curve with its degrees of freedom and 95 % bands. ``shares`` (T, 3): the part of each point's variance
    that is of each noise type in ``ALPHAS``. Where several types share a point its degrees of freedom e are mixed as
    1/sqrt(e) = sum(share_i / sqrt(e_i)), the variance of a sum of independent noises bounded by Cauchy-Schwarz."""
    import allantools

    per_type = np.array([[allantools.edf_simple(n + 1, int(mm), 0) if a == 0 else
                          allantools.edf_greenhall(a, 2, int(mm), n + 1, overlapping=True) for a in ALPHAS] for mm in m])
    edf = 1.0 / np.sum(shares / np.sqrt(per_type), axis=1) ** 2
    lo, hi = np.array([allantools.confidence_interval(d, e, ci=0.95) for d, e in zip(adev, edf, strict=True)]).T
    return AllanCurve(tau_s, adev, edf, lo, hi)
