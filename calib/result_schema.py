"""The JSON form of a CalibrationResult, declared once as pydantic models: what ``CalibrationResult.to_json`` writes,
the store keeps, the API publishes in its OpenAPI document and ``CalibrationResult.from_dict`` reads back.

``calib.result.FORMAT_VERSION`` numbers the form. 1: results stored before the number was written (no ``format_version`` key; read
as they are). 2: ``format_version`` added; fields unchanged. A reader takes every older form.

The quality blocks are declared in ``calib.quality`` (TypedDicts, so that a calibration needs no pydantic): the keys
shared by the estimators and each estimator's own diagnostics (its fit's correlation, the re-orientations' residuals,
Ferraris' matrices).
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from calib.quality import Matrix, Number, Quality, Vector


class _Open(BaseModel):
    """A block whose named fields are typed and which may carry further diagnostics."""

    model_config = ConfigDict(extra="allow")


class StageDoc(BaseModel):
    """One stage of the recording (``calib.stages.stage.Stage``)."""

    kind: str = Field(description="still, turn or motion")
    start_s: float
    end_s: float
    axis: str | None = None
    angle_deg: float | None = Field(None, description="a turn's angle about its axis (deg)")
    start: int = Field(description="first sample")
    end: int = Field(description="one past the last sample")
    flags: list[str] = Field(default_factory=list)


class Spread(BaseModel):
    """Per-axis standard deviations (1 sigma) of k and b, and where a Student-t is the honest shape of an interval,
    its degrees of freedom (null: normal)."""

    k: Vector | None = None
    b: Vector | None = None
    k_dof: list[float | None] | None = Field(None, description="degrees of freedom of each k's interval (null: normal)")
    b_dof: list[float | None] | None = Field(None, description="degrees of freedom of each b's interval (null: normal)")
    k_interval_scale: list[float | None] | None = Field(
        None, description="what each k's Student-t quantile is multiplied by for its interval, where that is not its "
        "standard error (null: the standard error): its width drawn from the heading spreads few turns allow")
    b_interval_scale: list[float | None] | None = Field(
        None, description="the same for each b (null: the standard error)")


class TurnResidual(_Open):
    """How one calibrated turn closes (closure estimator)."""

    axis: str | None = None
    angle_deg: Number = None
    raw_angle_deg: Number = None
    revolutions: int | None = None
    closure_norm_deg: Number = None
    misclosure_norm_deg: Number = Field(None, description="the closure less the placement tilt measured, deg")


class StillResidual(_Open):
    """How one rest sits under the calibration (closure estimator): its calibrated mean rate, 0 when all is well."""

    stage: int | None = Field(None, description="its index in stages")
    start_s: Number = None
    end_s: Number = None
    samples: int | None = None
    rate_dps: list[Number] = Field(default_factory=list, description="the calibrated mean rate about x, y, z, deg/s")
    z: list[Number] = Field(default_factory=list, description="the same in standard errors")


class Residuals(_Open):
    """The fit's residuals: each turn's closure, each rest's mean rate."""

    turns: list[TurnResidual] = Field(default_factory=list)
    stills: list[StillResidual] = Field(default_factory=list)
    chi2: Number = None
    dof: int | None = None


class CalibrationParameters(BaseModel):
    """The parameters of g = K (m - G a) + b and their uncertainty: what a calibration is, wherever it is kept."""

    k: list[float] = Field(description="scale factors k_x, k_y, k_z of g = K m + b")
    b: list[float] = Field(description="biases b_x, b_y, b_z in deg/s of true rate")
    K: list[list[float]] | None = Field(None, description="the full 3x3 K of the extended model; None: K = diag(k)")
    G: list[list[float]] | None = Field(None, description="the g-sensitivity of g = K (m - G a) + b, (deg/s)/g; None: not "
                                                          "modelled")
    uncertainty: Spread | None = Field(None, description="1-sigma standard errors of k and b")
    K_std: Matrix | None = Field(None, description="1-sigma standard errors of K's entries, with K")
    G_std: Matrix | None = Field(None, description="1-sigma standard errors of G's entries, with G")
    method: str = Field(description="the estimator: closure, paper, ferraris, multi-position, ...")


class ResultDoc(CalibrationParameters):
    """One calibration result in full (``calib.result.CalibrationResult``); a calibration imported from a file
    carries what its file said beside it (``model``, ``accelerometer``, ``identity``)."""

    model_config = ConfigDict(extra="allow")

    # a result may leave axes undetermined (quality.undetermined_axes: no turn about them); a calibration kept never does
    k: list[Number] = Field(  # type: ignore[assignment]
        description="scale factors k_x, k_y, k_z of g = K m + b; null for an axis not determined")
    b: list[Number] = Field(  # type: ignore[assignment]
        description="biases b_x, b_y, b_z in deg/s of true rate; null for an axis not determined")
    format_version: int = Field(1, description="the form of this object (calib.result.FORMAT_VERSION; 1: stored before "
                                               "it was numbered)")
    stages: list[StageDoc] = Field(default_factory=list)
    quality: Quality = Field(default_factory=lambda: Quality(), description="how well the calibration is determined "
                             "and what it was made from (calib.quality: every key optional; each estimator adds its own)")
    bound: Spread | None = Field(None, description="the Cramer-Rao bound of k and b for the recorded protocol")
    noise_dps: Vector | None = Field(None, description="per-axis white-noise std at rest, deg/s")
    residuals: Residuals = Field(default_factory=Residuals)
    warnings: list[str] = Field(default_factory=list)
    iterations: int | None = None
    sample_rate_hz: float | None = None
    n_samples: int | None = None
