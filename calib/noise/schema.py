"""A noise report as typed data (the JSON of ``NoiseReport.to_json``, published in the service's OpenAPI)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class ReadingOut(BaseModel):
    """One noise parameter: its value and 95 % interval where the curve shows its term, else an upper bound."""

    model_config = ConfigDict(frozen=True)
    seen: bool
    value: float | None = Field(description="the parameter (null: not seen)")
    ci95: list[float] | None = Field(description="its 95 % interval [low, high] (null: not seen)")
    upper95: float | None = Field(description="not seen: the least 95 % upper bound the curve sets on it")
    tau_s: float = Field(description="the averaging time it was read at, s")
    tau_range_s: list[float] | None = Field(description="where its term dominates the curve [from, to], s")


class GaussMarkovOut(BaseModel):
    model_config = ConfigDict(frozen=True)
    tc_s: float
    sigma: float


class FitOut(BaseModel):
    """The terms fitted to the curve (the readings' units)."""

    model_config = ConfigDict(frozen=True)
    white: float
    random_walk: float
    ramp: float
    gauss_markov: list[GaussMarkovOut]


class CurveOut(BaseModel):
    """The overlapping Allan deviation with its 95 % band, degrees of freedom and the fitted curve."""

    model_config = ConfigDict(frozen=True)
    tau_s: list[float]
    adev: list[float]
    lo95: list[float]
    hi95: list[float]
    edf: list[float]
    fit_adev: list[float]


class AxisNoiseOut(BaseModel):
    model_config = ConfigDict(frozen=True)
    axis: str
    noise_density: ReadingOut
    bias_instability: ReadingOut
    random_walk: ReadingOut
    fit: FitOut
    curve: CurveOut


class NoiseOut(BaseModel):
    """A rest's noise per gyroscope and accelerometer axis (docs/method.md, "Noise from a long rest")."""

    model_config = ConfigDict(frozen=True)
    source: str | None
    sample_rate_hz: float
    duration_s: float
    lost_samples: int = Field(0, description="samples missing (counter or time-stamp gaps): the curve reads the rest as evenly spaced")
    units: dict[str, dict[str, str]] = Field(description="each parameter's unit, per sensor")
    gyro: list[AxisNoiseOut]
    accel: list[AxisNoiseOut] | None = Field(description="null: the recording has no accelerometer columns")
    kalibr_yaml: str | None = Field(None, description="Kalibr's imu.yaml for this sensor (null without an accelerometer)")
