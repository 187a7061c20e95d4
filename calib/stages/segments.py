"""The stage detector's book of stages: opening and closing stills and motions where the decided state changes,
their flags (saturated, counter gaps) and the events they raise. ``StageTracker`` decides the state of each sample;
this keeps the stages that follow from it."""

from __future__ import annotations

import bisect
import math

import numpy as np

from calib.stages.config import StageConfig, StageEvent
from calib.stages.prefix_sums import DT, MDT, S1, TDT, PrefixStore
from calib.stages.stage import AXES, FLAG_COUNTER_GAP, FLAG_SATURATED, Axis, Stage, StageKind


class StageBook:
    """The stages so far and the open still or motion (the state ``StageTracker`` sets up and decides)."""

    fs: float
    config: StageConfig
    _store: PrefixStore
    _m: int
    _min_still: int
    _t0: float
    _state: bool | None
    _run_start: int
    _still_start: int | None
    _gap_start: int | None
    _gap_row: np.ndarray | None
    _gap_t: float
    _marked: dict[str, list[int]]  # the samples (global indices, in order) that give a stage each flag
    _still_t: float
    _bias_before: np.ndarray | None
    _bias_before_t: float
    _stages: list[Stage]
    _events: list[StageEvent]

    def _set_state(self, g: int, state: bool) -> None:
        """Sample g has ``state`` (True = still): open or close stages where the state changes."""
        if self._state is not None and state == self._state:
            return
        if state:
            self._run_start = g
        elif self._still_start is not None:
            self._close_still(g - self._m)
            self._open_gap(g - self._m)
        elif self._gap_start is None:
            self._open_gap(0)  # the recording starts with motion or a too short still
        self._state = state

    def _check_qualified(self, end: int) -> None:
        """The still run has lasted up to sample ``end`` (exclusive): open a still once it is long enough."""
        if self._state and self._still_start is None:
            lead = self._m if self._run_start > 0 else 0
            qualified_at = self._run_start + lead + self._min_still + self._m - 1
            if qualified_at < end:
                self._qualify(self._run_start + lead)

    def _open_gap(self, g: int) -> None:
        self._gap_start = g
        self._gap_row = self._store.row(g)
        self._gap_t = self._store.time(g)
        self._events.append(StageEvent("motion_started", self._gap_t))

    def _qualify(self, start: int) -> None:
        """A still run has become long enough: close the motion before it and open the still."""
        if self._gap_start is not None:
            self._close_gap(start, self._store.sums(start, start + self._min_still)[S1] / self._min_still)
        self._still_start = start
        self._still_t = self._store.time(start)
        self._events.append(StageEvent("still_started", self._still_t))

    def _close_still(self, end: int) -> None:
        start = self._still_start
        assert start is not None  # only an open still is closed
        span = min(self._min_still, end - start)
        self._bias_before = self._store.sums(end - span, end)[S1] / span
        self._bias_before_t = 0.5 * (self._store.time(end - span) + self._store.time(end - 1))
        self._emit(Stage("still", start, end, self._still_t, self._end_time(end),
                         flags=self._flags(start, end)))
        self._still_start = None

    def _close_gap(self, end: int, bias_after: np.ndarray | None) -> None:
        """Close the open motion at ``end``; it is a turn if it qualifies and a still follows it."""
        start, row0 = self._gap_start, self._gap_row
        assert start is not None and row0 is not None  # only an open motion is closed
        st, cfg = self._store, self.config
        kind: StageKind = "motion"
        axis: Axis | None = None
        angle: float | None = None
        if bias_after is not None and self._bias_before is not None:
            s = st.row(end) - row0
            t_end = st.time(end)
            duration = t_end - self._gap_t
            b0 = self._bias_before
            # sum_j u_j dt_j with u_j = (t_j - t_start) / (t_end - t_start), the interpolation weight.
            u_dt = (s[TDT] - (self._gap_t - self._t0) * s[DT]) / duration
            theta = s[MDT] - b0 * s[DT] - (bias_after - b0) * u_dt
            angles = theta.tolist()
            k = max(range(3), key=lambda j: abs(angles[j]))
            main = angles[k]
            off = math.hypot(*(v for j, v in enumerate(angles) if j != k))
            if (cfg.min_turn_deg <= abs(main) <= cfg.max_turn_deg and off <= cfg.max_off_axis * abs(main)
                    and duration <= cfg.max_turn_s):
                kind, axis, angle = "turn", AXES[k], main
        self._emit(Stage(kind, start, end, self._gap_t, self._end_time(end), axis, angle, self._flags(start, end)))
        self._gap_start = None

    def _end_time(self, end: int) -> float:
        if end < self._store.n:
            return self._store.time(end)
        return self._store.time(end - 1) + 1.0 / self.fs

    def _flags(self, start: int, end: int) -> tuple[str, ...]:
        """The flags of samples [start, end): those with a marked sample among them."""
        flags = []
        for flag in (FLAG_SATURATED, FLAG_COUNTER_GAP):
            at = self._marked[flag]
            i = bisect.bisect_left(at, start)
            if i < len(at) and at[i] < end:
                flags.append(flag)
        return tuple(flags)

    def _emit(self, stage: Stage) -> None:
        for at in self._marked.values():  # no later stage reaches back before this one's end
            del at[: bisect.bisect_left(at, stage.end)]
        self._stages.append(stage)
        self._events.append(StageEvent("stage_closed", stage.end_s, stage))
