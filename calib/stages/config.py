"""The stage detector's settings and what it reports as it goes (events, the live state)."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Literal

import numpy as np

from calib.errors import GyrocalError
from calib.stages.stage import Stage
from calib.units import FULL_TURN_DEG


class StageConfigError(GyrocalError, ValueError):
    """A stage-detection setting is invalid; the message names it and what is accepted."""


def clip_run_needed(p_equal: np.ndarray | float, min_run: int, chance: float) -> np.ndarray:
    """Shortest run of identical readings that counts as clipping when consecutive readings are equal
    by chance with probability ``p_equal``: p^(n-1) < ``chance``, and at least ``min_run``."""
    p = np.clip(np.asarray(p_equal, dtype=float), 0.0, 1.0)
    with np.errstate(divide="ignore"):
        n = 1.0 + np.ceil(np.log(chance) / np.log(np.where((p > 0) & (p < 1), p, 0.5)))
    never = 2.0**40  # readings that always repeat: no run is evidence of clipping
    n = np.where(p <= 0, min_run, np.where(p >= 1, never, np.minimum(np.maximum(n, min_run), never)))
    return n.astype(np.int64)


@dataclass(frozen=True)
class StageConfig:
    """Settings of the stage detector (times in s, rates in deg/s, angles in deg)."""

    window_s: float = 0.25  # centred window of the stillness statistic
    enter_ratio: float = 2.0  # still once the window noise is below this many noise floors
    exit_ratio: float = 3.0  # moving once it is above this many
    rest_tol_dps: float = 0.5  # a still's window mean stays this close to the rest reading, at least
    rest_tol_floors: float = 3.0  # ... or this many noise floors, when that is more
    rest_drift_dps_per_s: float = 0.25  # ... plus this much per second since the reference was taken
    max_zero_rate_dps: float = 50.0  # before the first still: largest |window mean| taken as a zero-rate offset
    margin_s: float = 0.1  # trimmed from each side of a still that touches motion
    min_still_s: float = 1.0  # shortest still segment; also the span averaged for a turn's bias
    floor_block_s: float = 0.5
    floor_rank: int = 3  # the floor is the floor_rank-th quietest block
    min_noise_dps: float = 0.005
    max_noise_dps: float = 1.0  # moving blocks at the start cannot raise the floor above this
    min_turn_deg: float = FULL_TURN_DEG / 1.33  # a full turn as read by a gyro whose k is up to 1.33
    max_turn_deg: float = FULL_TURN_DEG / 0.75  # ... or down to 0.75
    max_off_axis: float = 0.35  # off-axis rotation allowed in a turn, as a fraction of its angle
    max_turn_s: float = 30.0
    full_scale_fraction: float = 0.995
    clip_run: int = 3
    clip_chance: float = 1e-6  # chance that noise alone repeats a count along a run taken as clipped
    clip_min_dps: float = 100.0
    update_interval_s: float = 0.1  # the tracker processes input at least this much at a time

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            zero_ok = f.name in ("margin_s", "rest_drift_dps_per_s")
            if not (isinstance(value, (int, float)) and np.isfinite(value) and (value >= 0 if zero_ok else value > 0)):
                kind = "a number >= 0" if zero_ok else "a positive number"
                raise StageConfigError(f"StageConfig.{f.name} must be {kind}; got {value!r}")
        if self.exit_ratio < self.enter_ratio:
            raise StageConfigError(
                f"StageConfig.exit_ratio ({self.exit_ratio}) must be at least enter_ratio ({self.enter_ratio})"
            )
        if self.max_noise_dps < self.min_noise_dps:
            raise StageConfigError("StageConfig.max_noise_dps must be at least min_noise_dps")
        if self.max_turn_deg <= self.min_turn_deg:
            raise StageConfigError("StageConfig.max_turn_deg must be larger than min_turn_deg")
        if int(self.floor_rank) != self.floor_rank or int(self.clip_run) != self.clip_run:
            raise StageConfigError("StageConfig.floor_rank and clip_run must be whole numbers")
        if self.full_scale_fraction > 1:
            raise StageConfigError("StageConfig.full_scale_fraction must be in (0, 1]")
        if self.clip_chance >= 1:
            raise StageConfigError("StageConfig.clip_chance must be in (0, 1)")


@dataclass(frozen=True)
class StageEvent:
    """Something the tracker found: a still began, a motion began, or a stage was finalised.

    ``t`` is the time of the sample where it happened: the still's or motion's first sample, or the
    closed stage's end.
    """

    kind: Literal["still_started", "motion_started", "stage_closed"]
    t: float
    stage: Stage | None = None


@dataclass(frozen=True)
class LiveState:
    """The tracker's view of the latest decided sample (about window_s / 2 behind the input); the open motion's angle
    runs on to the newest sample in."""

    still_for_s: float  # how long the device has been still (0 while moving)
    moving: bool
    live_angle_deg: np.ndarray  # (3,) bias-compensated angle since the current motion began, to the newest sample, else zeros
    noise_floor: float | None  # deg/s, None until the first blocks are in
    t: float | None  # time of the latest decided sample
