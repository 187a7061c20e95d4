"""What a calibration result says about how well it is determined: ``CalibrationResult.quality`` and its blocks.

Declared once, as TypedDicts: the estimators build them, mypy checks their keys, and ``calib.result_schema`` publishes
them as the JSON schema of a result's ``quality`` (pydantic reads a TypedDict as it reads a model; these import no
pydantic, so a calibration does not load it). Every key is optional: each estimator fills the blocks it measures.
A block that carries diagnostics beyond its named keys allows them (``__pydantic_config__``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import (
    Any,
    NotRequired,  # on Python 3.11 pydantic reads a TypedDict only from typing_extensions
)

from typing_extensions import TypedDict

Number = float | None  # JSON has no NaN: a value that is not finite is written as null
Vector = list[Number]
Matrix = list[list[Number]]
Numbers = Sequence[Number]  # what an estimator writes as a list of floats: any of them may be NaN, read back as null


class AccelerometerQuality(TypedDict, total=False):
    """The accelerometer's calibration from the rests, a = T S (r - o) (``calib.estimators.accel.AccelCalibration``)."""

    __pydantic_config__ = {"extra": "allow"}  # type: ignore[misc]
    model: str
    scale: Numbers | None
    bias: Numbers | None  # the offset o, g
    misalignment: Numbers | None  # rad
    uncertainty: Mapping[str, Numbers | None]  # scale, bias, misalignment: 1-sigma (null: not identified)
    n_rests: int
    residual_rms_mg: Number
    identified: list[str]
    note: str | None


class Recognition(TypedDict, total=False):
    """Which protocol the recording holds (``calib.stages.recognise.Recognition``)."""

    name: str
    summary: str
    rests: int
    full_turns: list[str]
    poses: list[str]
    reorientations: int


class ProtocolUsed(TypedDict, total=False):
    """The protocol found in the recording, the one used, and how many labelled sections cut it."""

    found: Recognition
    used: str
    sections: int


class ModelChoice(TypedDict, total=False):
    """Why the closure estimator fitted the diagonal or the extended K."""

    asked: bool | None
    reason: str
    offdiag_bound: Numbers  # the standard errors the non-orthogonality terms would have
    likelihood_ratio: Number
    p_value: Number  # of the likelihood ratio: the extended terms significant below 0.05
    extended_fit_p_value: Number  # whether the extended model explains the recording


class TurnPlacement(TypedDict):
    """Where the hand put the device back after one turn: the tilt the accelerometer saw (null: no rest on a side)."""

    axis: str | None
    start_s: Number
    tilt_deg: Number  # the size of the tilt, deg
    tilt_std_deg: Number  # the standard deviation of each of its two components, deg
    rotation_deg: Numbers | None  # the tilt as a rotation from the pose before to the pose after (body axes), deg


class HeadingReport(TypedDict):
    """The heading spread a closure calibration carried and where it came from (``calib.estimators.closure.heading``)."""

    spread_deg: Number  # 1 sigma per turn
    # "estimated" (from the turns that show it), "stated" (asked for), "default" (no turn shows it), "unsettled" (the
    # turns did not settle on one: the default carried), "kit" (a kit's mean recording showed it)
    source: str
    turns: int  # the turns whose closure showed it (estimated)
    spread_sd_deg: Number  # its standard error (estimated), else null
    note: str


class Placement(TypedDict):
    """What the hand did at each turn (``calib.stages.placement``)."""

    measured_by: str | None  # "accelerometer", or null: not measured
    note: str
    turns: list[TurnPlacement]
    tilt_prior_deg: NotRequired[Number]  # the spread of the hand's tilts beyond the accelerometer's noise (closure)
    heading_prior_deg: NotRequired[Number]  # the heading spread the calibration carried (closure; ``heading`` says whence)
    heading: NotRequired[HeadingReport]


class KitDeparture(TypedDict, total=False):
    """How far a wearable's attitude came apart from the rest of its kit's (``calib.kit.departure.Departure``)."""

    angle_deg: Number
    std_deg: Number
    p_value: Number
    at_s: Number  # reference clock, s; null when it did not come apart
    departed: bool
    burst_dps: Number  # the largest rms of its rate against the others' over a quarter second, deg/s
    step_deg: Number  # how far it turned in its slot across that burst, the tray resting; else null


class KitAxesQuality(TypedDict, total=False):
    """The kit's sensor axes (``calib.kit.axes``): the model of every wearable's K and why."""

    model: str  # upper-triangular or diagonal
    chi2: Number
    dof: int
    p_value: Number
    tilt_spread: Number
    reason: str


class KitQuality(TypedDict, total=False):
    """A wearable calibrated with its kit (``calib.kit``): the kit's size, the wearable whose frame and clock it was
    solved in, this one's clock and mounting against it, and how it followed the kit (its departure)."""

    __pydantic_config__ = {"extra": "allow"}  # type: ignore[misc]
    devices: int
    reference: str | None
    clock: Mapping[str, Number]
    mount_deg: Number
    consistency: KitDeparture
    departed: bool
    axes: KitAxesQuality


class Quality(TypedDict, total=False):
    """How well the calibration is determined and what it was made from. The first keys are shared by the estimators;
    the later ones are one estimator's own diagnostics (closure, paper, ferraris, multi-position)."""

    __pydantic_config__ = {"extra": "allow"}  # type: ignore[misc]
    model: str  # diagonal, upper-triangular, ...: the model of K fitted
    parameters: list[str]
    chi2: Number
    dof: int | float | None
    birge_ratio: Number  # sqrt(chi2/dof), at least 1: the factor the uncertainties were scaled by
    p_value: Number
    converged: bool
    protocol: ProtocolUsed
    temperature_c: Number  # the sensor's mean temperature during the recording, degC
    sample_rate_rel_std: Number  # the times were placed at an estimated rate with this relative std, in k_std (K_std)
    accelerometer: AccelerometerQuality | None
    model_choice: ModelChoice
    placement: Placement  # closure: the tilt each turn was put back with
    undetermined_axes: list[str]  # closure: the axes no turn was about, whose k and b are not determined (null)
    kit: KitQuality  # calibrated with its kit: calib.kit
    # closure
    turns: int
    stills: int
    still_s: Number
    turn_s: Numbers | Mapping[str, Number]  # closure: each turn's duration; paper: each axis' turn
    stages_used: list[int]
    function_evaluations: int
    correlation: Matrix
    # paper (Algorithm 1)
    still0_samples: int
    still0_s: Number
    turn_samples: dict[str, int]
    iterations: int
    tolerance: Number
    k_history: Sequence[Numbers]
    stage_notes: list[str]
    # ferraris
    ferraris: dict[str, Any]  # its matrices, as Ferraris et al. write them
    b_g: Vector
    b_a: Vector
    turn_angle_deg: Number
    # multi-position
    constraints: dict[str, int]  # rests, gravity_motions, full_turns
    gravity_residual_deg: Numbers
    gravity_motions_s: Sequence[Numbers]
    gravity_residual_rms_deg: Number
    gravity_z: Numbers
    g_sensitivity: dict[str, Any]  # whether G was fitted, and the fit without it
    settling: dict[str, Any]
    accelerometer_floor: dict[str, Any]
    gyro_motion_noise: dict[str, Any]
    constraint_fit: dict[str, Any]
    # rate table
    runs: int
