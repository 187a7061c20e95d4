"""The samples of one guided session and what the streaming stage detector finds in them.

``SessionStream`` keeps every sample received (``SampleBuffer``), a strictly increasing device time
across reconnections, the detector (one per link connection), the stills it closed, and the turn
physics measured on the raw readings (``calib.stages.turn_checks``). It knows nothing of the protocol's
states: the session (server.live.session) asks it questions and decides.
"""

from __future__ import annotations

import copy
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from typing import Any, cast

import numpy as np

from calib.recording import Recording, RecordingMeta
from calib.stages.stage import AXES, Axis, Stage
from calib.stages.turn_checks import gravity_change_deg, rest_after_full_turn, swept_angles

from .buffer import SampleBuffer
from .turn_watch import STOP_DPS, recent_rate_dps
from .turns import TurnRecord

RECENT_S = 10.0  # before any rest has closed, the reading at rest is the median of this much of the newest readings
MOVE_GAP_S = 0.2  # calm readings this long part one move from the motion before it (a knock from the turn it follows)
ARRIVAL_WINDOW_S = 5.0  # how late readings reach the session is its least over this much device time: a while the
# service or one link falls behind passes, the least stays (a clock 1 % off drifts 0.05 s in it)

# a wearable's time stamps may run ahead of the service's clock by this much plus CLOCK_AHEAD_RATE of the time since
# its first reading (the first reading's own delay, and a rate placed from arrival times a few per cent off) and no
# more: a sensor cannot measure faster than real time
CLOCK_AHEAD_SLACK_S = 5.0
CLOCK_AHEAD_RATE = 0.05

TrackerFactory = Callable[[float, float | None], Any]


def default_tracker(fs: float, full_scale_dps: float | None) -> Any:
    """The streaming stage detector of calib, at fs Hz for a gyro range of ``full_scale_dps``."""
    from calib.stages.detector import StageTracker

    return StageTracker(fs, full_scale_dps=full_scale_dps)


class SessionStream:
    """One session's samples, device time, stage detector and stills."""

    def __init__(self, tracker_factory: TrackerFactory | None = None) -> None:
        self._tracker_factory = tracker_factory or default_tracker
        self.fs: float | None = None
        self.full_scale: float | None = None
        self.buf = SampleBuffer()
        self.tracker: Any = None
        self.stills: list[Stage] = []
        self.last_still: Stage | None = None
        self._offset = 0  # global index of the current tracker's sample 0
        self._last_t: float | None = None
        self._t_shift = 0.0
        self._pending: tuple[np.ndarray, np.ndarray, np.ndarray | None] | None = None
        self._arrivals: deque[tuple[float, float]] = deque()  # (device time, wall time it was read at minus it), s
        self._first_arrival: tuple[float, float] | None = None  # (wall time, wall minus device time) of the first
        self._ahead: tuple[float, float] = (0.0, 0.0)  # (how far device time ran ahead of wall time, over how long), s
        # link-clock seconds per real second: a simulated wearable's clock runs ``speed`` times real time, and so do the
        # first reading's delay and the service's own lateness when they are read on it
        self.time_scale = 1.0
        self._rest_key: tuple[int, int] | None = None  # the still ``_rest`` is the mean reading of
        self._rest: np.ndarray = np.zeros(3)

    def start(self, fs: float, full_scale_dps: float | None) -> None:
        """The link streams at fs Hz: start a detector."""
        self.fs = float(fs)
        self.full_scale = float(full_scale_dps) if full_scale_dps else None
        self.new_tracker()

    def new_tracker(self) -> None:
        """A fresh detector from the next sample on, keeping the stills the previous one closed."""
        assert self.fs is not None
        if self.tracker is not None:
            try:
                for ev in self.tracker.finish():
                    if getattr(ev, "kind", None) == "stage_closed" and ev.stage.kind == "still":
                        self.stills.append(self.globalise(ev.stage))
            except Exception:  # a tracker cut short by a link loss may have nothing sensible to close
                pass
        self.tracker = self._tracker_factory(self.fs, self.full_scale)
        self._offset = self.buf.n
        self.last_still = None

    def monotonic_time(self, t: np.ndarray) -> np.ndarray:
        """Device times shifted so the session's time stays strictly increasing (a reconnected device may restart its clock)."""
        t = t + self._t_shift
        if self._last_t is not None and t[0] <= self._last_t:
            dt = 1.0 / self.fs if self.fs else 1e-3
            shift = self._last_t + dt - t[0]
            self._t_shift += shift
            t = t + shift
        self._last_t = float(t[-1])
        return t

    def receive(self, t: np.ndarray, gyro: np.ndarray, accel: np.ndarray | None, seq: np.ndarray | None) -> np.ndarray | None:
        """Keep one batch (device time s, gyro deg/s, accel g, sample counter); its session times, None if it is empty."""
        t = np.asarray(t, dtype=float).reshape(-1)
        if t.size == 0:
            return None
        gyro = np.asarray(gyro, dtype=float).reshape(-1, 3)
        accel = None if accel is None else np.asarray(accel, dtype=float).reshape(-1, 3)
        seq = None if seq is None else np.asarray(seq, dtype=np.int64).reshape(-1)
        t = self.monotonic_time(t)
        self.buf.append(t, gyro, accel, seq)
        self._pending = (t, gyro, seq)
        return t

    def arrived(self, t_last: float, received_at: float) -> None:
        """The batch whose last reading is at device time ``t_last`` reached the session at wall time ``received_at``
        (s)."""
        self._arrivals.append((t_last, received_at - t_last))
        while self._arrivals[0][0] < t_last - ARRIVAL_WINDOW_S:
            self._arrivals.popleft()
        if self._first_arrival is None:
            self._first_arrival = (received_at, received_at - t_last)
        else:
            self._ahead = (self._first_arrival[1] - (received_at - t_last), received_at - self._first_arrival[0])

    def clock_ahead(self, excused_s: float = 0.0) -> tuple[float, float] | None:
        """(how far, over how long) the wearable's time stamps ran ahead of the wall clock since its first reading, in s,
        when that is more than a clock's drift and the first reading's delay allow (``excused_s``: time the service
        itself did not run, real seconds; both allowances are read on the link's clock, ``time_scale``); else None."""
        ahead, over = self._ahead
        allowed = (CLOCK_AHEAD_SLACK_S + excused_s) * self.time_scale + CLOCK_AHEAD_RATE * over
        return (ahead, over) if ahead > allowed else None

    def missing_samples(self, st: Stage) -> int:
        """Samples missing within a stage by the sample counter (0 without one)."""
        if not self.buf.has_seq or st.end - st.start < 2:
            return 0
        steps = np.diff(self.buf.seq[st.start : st.end])
        return int(np.clip(steps - 1, 0, None).sum())

    def wall_offset(self) -> float | None:
        """Wall time minus device time of the readings that reached the session soonest lately (s), so that one moment
        on two wearables' clocks is found though the service read one of them late; None before any reading."""
        return min(off for _, off in self._arrivals) if self._arrivals else None

    def detect(self) -> list[Any]:
        """The detector's events for the batch received last."""
        if self._pending is None:
            return []
        t, gyro, seq = self._pending
        self._pending = None
        return list(self.tracker.feed(t, gyro, seq))

    def globalise(self, st: Stage) -> Stage:
        """A stage of the current detector, in sample indices of the whole session."""
        if self._offset == 0:
            return st
        return replace(st, start=st.start + self._offset, end=st.end + self._offset)

    def closed_still(self, st: Stage) -> None:
        """The detector closed a still (session indices)."""
        self.stills.append(st)
        self.last_still = st

    def live(self) -> tuple[float, bool, np.ndarray]:
        """(rest so far in s, moving, live angle (3,) in deg) as the detector reports them now."""
        live = self.tracker.live
        moving = bool(getattr(live, "moving", False))
        still_s = 0.0 if moving else float(getattr(live, "still_for_s", 0.0) or 0.0)
        angle = np.asarray(getattr(live, "live_angle_deg", np.zeros(3)), dtype=float).reshape(-1)
        if angle.size != 3 or not np.all(np.isfinite(angle)):
            angle = np.zeros(3)
        return still_s, moving, angle

    def recent_rate(self, window_s: float) -> float:
        """The largest rate (deg/s, rest reading removed) over the last ``window_s`` of readings."""
        k = max(1, int(round(window_s * self.fs))) if self.fs else 1
        n = self.buf.n
        return recent_rate_dps(self.buf.gyro[max(0, n - k):n], self._rest_up_to(n), k)

    def _rest_up_to(self, hi: int) -> np.ndarray | float:
        """The reading at rest as of reading ``hi``: the last still's mean. Before any still closed (a wearable that has
        not moved yet: the first rest of a session, or one left beside its kit's tray), the median of its last 10 s of
        readings, not 0, which its bias alone (up to 5 deg/s an axis) would read as moving: the ring of the first rest
        then counts from its first readings, not from the detector's decision 1.4 s later."""
        if self.last_still is not None or hi < 1:
            return self.rest_reading()
        return np.median(self.buf.gyro[self._recent_from(hi):hi], axis=0)

    def _recent_from(self, hi: int) -> int:
        """The first of the readings up to ``hi`` in the last ``RECENT_S``."""
        return max(0, hi - int(RECENT_S * (self.fs or 100.0)))

    def _moving(self, lo: int, hi: int) -> np.ndarray:
        """Whether each reading lo..hi-1 moved: away from the rest reading (``_rest_up_to``) by more than a stopped
        device reads."""
        g = self.buf.gyro[lo:hi] - self._rest_up_to(hi)
        return np.asarray(np.sqrt((g * g).sum(axis=1)) > STOP_DPS)

    def calm_since(self) -> float | None:
        """Device time of the first reading of the calm that goes on to now (within the last ``RECENT_S``): where the rest the
        ring counts began. None when the newest reading moves."""
        n = self.buf.n
        lo = self._recent_from(n)
        moved = np.flatnonzero(self._moving(lo, n))
        first = lo + (int(moved[-1]) + 1 if moved.size else 0)
        return float(self.buf.t[first]) if first < n else None

    def clipped_motion(self, since_t: float) -> float | None:
        """How long (s) the motion since device time ``since_t`` took, if its readings reached the gyro's stated range
        (a turn too fast: known the moment it stops); None if they did not, or the range is not known."""
        n = self.buf.n
        t = self.buf.t[:n]
        lo = int(np.searchsorted(t, since_t))
        if self.full_scale is None or n - lo < 2 or float(np.abs(self.buf.gyro[lo:n]).max()) < 0.995 * self.full_scale:
            return None
        moving = np.flatnonzero(self._moving(lo, n))
        return float(t[lo + moving[-1]] - t[lo + moving[0]]) if moving.size else None

    def still_between(self, t0: float, t1: float) -> bool:
        """Whether the readings from device time ``t0`` to ``t1`` (s) are there and none of them moved."""
        t = self.buf.t[:self.buf.n]
        lo, hi = int(np.searchsorted(t, t0)), int(np.searchsorted(t, t1, side="right"))
        if self.fs is None or hi - lo < 0.9 * (t1 - t0) * self.fs:
            return False
        return not self._moving(lo, hi).any()

    def move_span(self, at_t: float, within_s: float) -> tuple[float, float] | None:
        """The span (device time, s) of the move under way at ``at_t``: the run of moving readings nearest to it
        within ``within_s``, bounded by calm readings ``MOVE_GAP_S`` long (so the turn before a knock is not part of
        the knock); None when no reading moved that near."""
        t = self.buf.t[:self.buf.n]
        lo, hi = int(np.searchsorted(t, at_t - within_s)), int(np.searchsorted(t, at_t + within_s, side="right"))
        moving = np.flatnonzero(self._moving(lo, hi)) + lo
        if moving.size == 0:
            return None
        run = np.cumsum(np.concatenate([[0], np.diff(t[moving]) > MOVE_GAP_S]))  # which run each moving reading is in
        nearest = run[np.argmin(np.abs(t[moving] - at_t))]
        span = t[moving[run == nearest]]
        return float(span[0]), float(span[-1])

    def moved_between(self, t0: float, t1: float) -> bool:
        """Whether any reading from device time ``t0`` to ``t1`` (s) moved."""
        t = self.buf.t[:self.buf.n]
        return bool(self._moving(int(np.searchsorted(t, t0)), int(np.searchsorted(t, t1, side="right"))).any())

    def rest_before(self, t_motion: float) -> float:
        """How long the device rested before a motion that began at t_motion (s of device time).

        Taken from the still the detector closed at that instant, so it does not depend on how the
        samples were batched; 0 when the rest was too short to be a still segment.
        """
        still = self.last_still
        if still is None or abs(still.end_s - t_motion) > 1e-6:
            return 0.0
        return float(still.end_s - still.start_s)

    # -- a closed motion, measured ----------------------------------------------------------------
    def rest_reading(self) -> np.ndarray | float:
        """The raw reading at rest (deg/s): the mean of the last still, 0 before there is one."""
        still = self.last_still
        if still is None or still.end <= still.start:
            return 0.0
        key = (still.start, still.end)
        if self._rest_key != key:  # asked at every batch, of a still that changes a few times a session
            self._rest_key, self._rest = key, self.buf.gyro[still.start : still.end].mean(axis=0)
        return self._rest

    def turn_angles(self, st: Stage) -> np.ndarray:
        """Integrated raw angle (deg) about x, y, z over the stage, bias from the last still."""
        return swept_angles(self.buf.t[st.start : st.end], self.buf.gyro[st.start : st.end], self.rest_reading())

    def rest_after_full_turn(self, st: Stage, k: int, rest_s: float, min_angle_deg: float) -> bool:
        """Whether the motion holds a rest of ``rest_s`` after a full turn about axis k, then moves on."""
        if self.fs is None:
            return False
        floor = getattr(self.tracker.live, "noise_floor", None) if self.tracker is not None else None
        return rest_after_full_turn(self.buf.t[st.start : st.end], self.buf.gyro[st.start : st.end], self.rest_reading(), k, floor,
                                    rest_s, min_angle_deg)

    def gravity_change_deg(self, st: Stage) -> float | None:
        """Angle (deg) between gravity in the rest before the motion and in the rest after it."""
        acc = self.buf.accel if self.buf.has_accel else None
        still = self.last_still
        if acc is None or still is None or self.fs is None:
            return None
        span = max(2, int(0.5 * self.fs))
        return gravity_change_deg(acc[max(still.start, still.end - span) : still.end], acc[st.end : min(self.buf.n, st.end + span)])

    def saturated(self, st: Stage) -> bool:
        """Whether the motion reached the gyro's range (the detector's flag, or readings at the stated full scale)."""
        m = self.buf.gyro[st.start : st.end]
        return "saturated" in st.flags or (self.full_scale is not None and m.size > 0 and float(np.abs(m).max()) >= 0.995 * self.full_scale)

    # -- the hand-over to the estimator -----------------------------------------------------------
    def recording(self, meta: RecordingMeta) -> Recording:
        """Everything received so far as a Recording (device time, raw readings)."""
        return self.buf.recording(meta)

    def protocol_stages(self, turns: list[TurnRecord]) -> list[Stage]:
        """The stages the estimator gets: every still, and the given turns (those that passed their checks)."""
        stages = list(self.stills)
        if self.tracker is not None:
            # the open rest, closed on a copy: the session's detector goes on (a turn may be asked again)
            for st in copy.deepcopy(self.tracker).finish():
                if getattr(st, "kind", None) == "stage_closed":
                    st = st.stage
                if isinstance(st, Stage) and st.kind == "still":
                    stages.append(self.globalise(st))
        turn_stages = [
            Stage("turn", tr.start, tr.end, tr.start_s, tr.end_s, cast(Axis, tr.axis), float(tr.angle_deg[AXES.index(tr.axis)]), tr.flags)
            for tr in turns
        ]
        stills = _dedupe([s for s in stages if s.kind == "still"])
        # a still must not overlap an accepted turn
        stills = [s for s in stills if not any(s.start < tr.end and tr.start < s.end for tr in turn_stages)]
        return sorted(stills + turn_stages, key=lambda s: s.start)


def _dedupe(stages: list[Stage]) -> list[Stage]:
    seen: set[tuple[int, int]] = set()
    out = []
    for s in stages:
        key = (s.start, s.end)
        if key not in seen:
            seen.add(key)
            out.append(s)
    return out
