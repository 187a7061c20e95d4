"""The model check's published shapes: what POST /diagnose and GET /sessions/{id}/diagnosis answer (the JSON of
``gyrocal diagnose --json``, docs/diagnosis.md), and a session's diagnosis progress."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field


class Mismatch(BaseModel):
    """A residual feature of the recording outside what its simulations produce."""

    model_config = ConfigDict(extra="allow")
    where: str = Field(description="stage, axis and time, e.g. 'still 2 (6.8-9.3 s), axis x'")
    statistic: str
    observed: float | None
    simulated_range: list[float | None] = Field(description="the simulations' 95 % range [low, high]")
    p_value: float | None


class EffectFit(BaseModel):
    before: float | None = Field(description="deviance without the effect (lower is better)")
    after: float | None = Field(description="deviance with the effect modelled")


class Effect(BaseModel):
    """A physical effect the recording shows, fitted."""

    model_config = ConfigDict(extra="allow")
    name: str = Field(description="bias_drift, axis_misalignment, g_sensitivity, scale_asymmetry, scale_nonlinearity, "
                                  "saturation, sample_loss, placement_error, clock_error or bias_instability")
    parameters: dict[str, Any]
    uncertainty: dict[str, Any] | None = None
    fit: EffectFit
    evidence: dict[str, Any] = Field(description="summary (one line), statistic, p_value, information_criterion, held_out, "
                                                 "simulate (the gyrocal simulate --effect value that reproduces it), ...")


class Unexplained(BaseModel):
    """A clear departure no catalogued effect explains (or that several explain equally well)."""

    model_config = ConfigDict(extra="allow")
    where: str | list[str] | None = None
    statistic: str | None = None
    description: str


class NotIdentifiable(BaseModel):
    name: str
    reason: str = Field(description="why this recording cannot show the effect, and which motion or channel would")


class NominalFit(BaseModel):
    """The nominal model g = K m + b fitted to the recording."""

    model_config = ConfigDict(extra="allow")
    k: list[float | None]
    b: list[float | None] = Field(description="deg/s of true rate")
    deviance: float | None
    dof: float | None
    p_value: float | None = Field(description="the chance of a deviance this large if the nominal model were all")
    turns: int
    stills: int


class KB(BaseModel):
    k: list[float | None]
    b: list[float | None]


class KBStd(KB):
    k_std: list[float | None]
    b_std: list[float | None]


class Recalibration(KBStd):
    """The calibration with the found effects modelled, and how far it moved from the nominal one."""

    model_config = ConfigDict(extra="allow")
    nominal: KBStd
    shift: KB
    shift_sigma: KB = Field(description="the shift in units of the nominal calibration's std")
    model: list[str] = Field(description="the effects and variance terms modelled")
    notes: list[str]


class SimulationCheck(BaseModel):
    """How many of the recording's features lie outside their simulations' range, before and after the effects."""

    features: int
    threshold: float = Field(description="the p-value below which a feature is outside (Bonferroni over the features)")
    outside_before: int
    worst_p_before: float | None
    outside_after: int | None
    worst_p_after: float | None


class DiagnosisTest(BaseModel):
    statistic: float | None
    p_value: float | None
    threshold: float
    typical_noncentrality: float | None


class DiagnosisInfo(BaseModel):
    """What the diagnosis was run on."""

    model_config = ConfigDict(extra="allow")
    n_boot: int = Field(description="simulations the recording was compared with")
    samples: int
    duration_s: float
    sample_rate_hz: float
    gyro_full_scale_dps: float | None
    channels: dict[str, bool] = Field(description="which channels the recording has: accelerometer, sample_counter, "
                                                  "temperature")
    tests: dict[str, DiagnosisTest] = Field(description="each effect's test, by name")
    timebase: dict[str, Any] = Field(description="how the time base was read (free-form: it depends on the clock "
                                                 "the recording carries)")


class DiagnosisOut(BaseModel):
    """`gyrocal diagnose --json`: the recording against its simulation (docs/diagnosis.md)."""

    model_config = ConfigDict(extra="allow")
    mismatches: list[Mismatch]
    effects: list[Effect] = Field(description="named effects, the largest fit improvement first; empty when the nominal "
                                              "model g = K m + b explains the recording")
    unexplained: list[Unexplained]
    not_identifiable: list[NotIdentifiable]
    recalibration: Recalibration | None
    nominal: NominalFit
    simulation_check: SimulationCheck
    info: DiagnosisInfo


class DiagnosisProgress(BaseModel):
    """Where a session's model check is: not started, waiting for a worker, running, or done (kept)."""

    state: Literal["idle", "queued", "running", "done"]
    fraction: float | None = Field(None, description="0-1 while running")
    stage: str | None = None
    elapsed_s: float | None = None
