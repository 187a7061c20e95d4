"""A long rest with a chosen noise: white noise, a rate random walk and a Gauss-Markov bias on every axis, with the
closed forms of their Allan variance (the truths an Allan analysis is checked against).

Per axis, in the readings' unit u (deg/s for the gyroscope, g for the accelerometer), sampled at fs:

    x[k] = N sqrt(fs) w0[k] + sum_{j<=k} K sqrt(1/fs) w1[j] + g[k],   g[k+1] = e^(-1/(fs Tc)) g[k] + sigma sqrt(1 - e^(-2/(fs Tc))) w2[k]

N the white noise's density (u/sqrt(Hz)), K the random walk's (u/sqrt(s)), g a first-order Gauss-Markov process of
standard deviation sigma and correlation time Tc. Their Allan variances (IEEE Std 952, annex C; the Gauss-Markov's
from its autocorrelation sigma^2 e^(-|t|/Tc)):

    N^2 / tau,    K^2 tau / 3,    (2 sigma^2 Tc / tau) (1 - (Tc / (2 tau)) (3 - 4 e^(-tau/Tc) + e^(-2 tau/Tc)))

The discrete white noise's is exact at every tau that is a whole number of samples; the other two hold for averaging
times of a few samples or more. The device lies flat (z up): its accelerometer reads (0, 0, 1) g plus its noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.recording import Recording, RecordingMeta


@dataclass(frozen=True)
class RestNoise:
    """One sensor's noise: white density, random walk, Gauss-Markov sigma and correlation time (0: none)."""

    density: float = 0.0
    random_walk: float = 0.0
    gm_sigma: float = 0.0
    gm_tc_s: float = 1.0

    def avar(self, tau_s: np.ndarray) -> np.ndarray:
        """The closed-form Allan variance at ``tau_s`` (see the module docstring)."""
        tau = np.asarray(tau_s, float)
        r = tau / self.gm_tc_s
        gm = (2 * self.gm_sigma**2 * self.gm_tc_s / tau) * (1 - (3 - 4 * np.exp(-r) + np.exp(-2 * r)) / (2 * r))
        return self.density**2 / tau + self.random_walk**2 * tau / 3 + gm

    def draw(self, rng: np.random.Generator, n: int, fs: float) -> np.ndarray:
        """(n,) samples of the noise."""
        from scipy.signal import lfilter

        x = self.density * np.sqrt(fs) * rng.standard_normal(n)
        if self.random_walk:
            x += np.cumsum(self.random_walk * np.sqrt(1.0 / fs) * rng.standard_normal(n))
        if self.gm_sigma:
            phi = np.exp(-1.0 / (fs * self.gm_tc_s))
            drive = self.gm_sigma * np.sqrt(1 - phi**2) * rng.standard_normal(n)
            drive[0] = self.gm_sigma * rng.standard_normal()  # start in the stationary distribution
            x += lfilter([1.0], [1.0, -phi], drive)
        return x


def simulate_rest(seed: int, duration_s: float, fs: float, gyro: RestNoise, accel: RestNoise | None = None,
                  gyro_bias_dps: float = 0.0) -> Recording:
    """A rest of ``duration_s`` at ``fs`` Hz with the gyroscope's (and optionally the accelerometer's) noise."""
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * fs))
    g = np.column_stack([gyro.draw(rng, n, fs) for _ in range(3)]) + gyro_bias_dps
    a = None
    if accel is not None:
        a = np.column_stack([accel.draw(rng, n, fs) for _ in range(3)]) + np.array([0.0, 0.0, 1.0])
    return Recording(np.arange(n) / fs, g, a, meta=RecordingMeta(sample_rate_hz=fs, source=f"simulated rest (seed {seed})"))
