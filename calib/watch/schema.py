"""A watch's report as typed data (the JSON of ``WatchReport.to_json``, published in the service's OpenAPI)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

Verdict = Literal["holds", "moved", "cannot tell"]


class SinceOut(BaseModel):
    model_config = ConfigDict(frozen=True)
    after_s: float = Field(description="the last evidence before the move, s into the recording")
    before_s: float = Field(description="the first evidence after it")


class ParameterOut(BaseModel):
    """One parameter of the calibration in force against the recording."""

    model_config = ConfigDict(frozen=True)
    name: Literal["k_x", "k_y", "k_z", "b_x", "b_y", "b_z"]
    verdict: Verdict
    change: float | None = Field(description="the recording's value less the calibration's: relative for k, deg/s for b")
    std: float | None = Field(description="its standard deviation (null: not determined)")
    margin: float | None = Field(description="holds: how far inside the tolerance (0.3 % for k, 0.05 deg/s for b)")
    since: SinceOut | None = Field(description="moved: when, inside the recording (null: before it began)")
    would_tell: str | None = Field(description="cannot tell: the motion that would tell")
    evidence: int = Field(description="the rests (b) or re-orientations exercising the axis (k) that spoke to it")


class LeftOutOut(BaseModel):
    model_config = ConfigDict(frozen=True)
    motions: int
    seconds: float
    fraction: float = Field(description="of the recording's duration")
    why: str


class EvidenceOut(BaseModel):
    model_config = ConfigDict(frozen=True)
    duration_s: float
    rests: int
    rest_s: float
    reorientations: int
    left_out: LeftOutOut


class BiasOut(BaseModel):
    """How the bias followed the sensor's warmth."""

    model_config = ConfigDict(frozen=True)
    reference: str = Field(description="what the bias is compared at: the calibration's temperature, or the first rest")
    temperature_coeff_dps_per_c: list[float] | None
    temperature_coeff_std: list[float] | None
    warmth_change_dps: list[float] | None = Field(description="without a temperature column: the warm-up's change")
    warmth_change_std: list[float] | None
    warmth_tau_s: float | None
    wander_dps: list[float] | None = Field(description="the rests' own wander beyond their means' noise")


class ScaleOut(BaseModel):
    model_config = ConfigDict(frozen=True)
    reorientations_used: int
    exercised: dict[str, int] = Field(description="re-orientations that exercised each axis")
    temperature_coeff_per_c: list[float] | None
    temperature_coeff_std: list[float] | None


class WatchOut(BaseModel):
    """Whether a calibration still holds on a recording made with it in force (docs/lifecycle.md)."""

    model_config = ConfigDict(frozen=True)
    verdict: Verdict = Field(description="moved when any parameter moved, holds when every one holds, else cannot tell")
    parameters: list[ParameterOut]
    evidence: EvidenceOut
    temperature_c: list[float] | None = Field(description="the rests' coldest and warmest (degC); null without a column")
    bias: BiasOut
    scale: ScaleOut
    warnings: list[str]


class TemperatureModelOut(BaseModel):
    """A device's scale factors and biases against its temperature, from its watches (calib.apply.temperature), about
    its current calibration's temperature: K(T) = diag(1 + s (T - T_ref)) K, b(T) = b + c (T - T_ref)."""

    model_config = ConfigDict(frozen=True)
    calibration_id: int
    temp_ref_c: float = Field(description="the current calibration's temperature, degC")
    bias_tc_dps_per_c: list[float] = Field(description="c, (deg/s)/degC per axis")
    bias_tc_std: list[float]
    scale_tc_per_c: list[float] = Field(description="s, per degC per axis (0 where no watch could tell)")
    scale_tc_std: list[float] | None
    watches: int = Field(description="the watches with a temperature column it pools")
    calibrations: int = Field(0, description="the calibrations of the current one's power-up, at different temperatures, "
                                             "it pools (0: none told)")
    watched_c: list[float] = Field(description="the coldest and warmest temperature its watches saw and its calibrations "
                                                "were made at, degC")
