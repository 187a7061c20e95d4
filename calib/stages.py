"""Stage detection: still segments, full turns and other motions, found from the gyro data alone.

One causal algorithm serves both uses: ``StageTracker`` runs it on a live stream, and
``detect_stages`` feeds a whole recording through a tracker, so the two give identical stages.

1. Noise floor. The recording is cut into blocks of ``floor_block_s``; a block's noise is the RMS over
   axes of std(first differences) / sqrt(2), which ignores the bias and slow drift. The floor is the
   ``floor_rank``-th smallest block noise seen so far (one glitchy block cannot pin it), clipped to
   [min_noise_dps, max_noise_dps]. It settles during the first still; decisions wait for it.
2. Stillness. z = RMS over axes of the standard deviation in a centred window of ``window_s``,
   divided by the floor (about 1 at rest). Hysteresis: still once z < ``enter_ratio``, moving once
   z > ``exit_ratio``. A rotation at a steady rate is as quiet as rest, so the window mean must also
   be at the rest reading: on every axis within tol = max(``rest_tol_dps``, ``rest_tol_floors`` *
   floor) plus ``rest_drift_dps_per_s`` per second between the two (the bias may drift, not jump;
   re-orientation moves it by far less than tol). Entering a still, the reference is the mean reading
   of the last ``min_still_s`` of the previous still segment, dated at the middle of that span; before
   the first still segment there is none, and the window mean must be a plausible zero-rate offset,
   within ``max_zero_rate_dps`` on every axis. During a still, the window mean must stay within that
   tolerance of the window mean at every earlier sample of the same still, so a spin-up too gradual
   for z ends the still once it outpaces the allowed drift.
3. Still segments. A still run loses ``margin_s`` on each side that touches motion (the slow start and
   end of a hand turn) and counts only if at least ``min_still_s`` remain. Everything between two
   still segments is one motion stage; shorter still runs inside it (a regrip half-way through a hand
   turn) stay part of it.
4. Turns. For a motion between two stills, the bias is interpolated linearly in time from the mean
   reading of the ``min_still_s`` of still before the motion to that of the ``min_still_s`` after it.
   The integrated rate vector is theta = sum_j (m_j - bias_j) * dt_j (deg; dt_j = t_j - t_{j-1}). Its
   largest component gives the axis, and ``angle_deg`` is that component, signed. The motion is a turn
   when |angle| lies in [min_turn_deg, max_turn_deg] (a full turn for scale factors 0.75-1.33), the
   other two components together are at most ``max_off_axis`` of it, and it lasts at most
   ``max_turn_s``. Any other motion (re-orientation, fidgeting, a turn stopped short) is ``motion``.

Flags: ``saturated`` when a sample reaches ``full_scale_fraction`` of the gyro's full scale (when it is
known), else when a run of identical readings sits at the largest |value| seen so far on an axis at
or above ``clip_min_dps`` and is longer than noise would make it: a sensor's integer counts repeat
by chance, so with p the share of consecutive readings on that axis so far that are equal, the run
must reach n with p^(n-1) < ``clip_chance`` (at least ``clip_run``; unquantised readings, p = 0,
need ``clip_run``); ``counter_gap`` when the sample counter does not advance by exactly one.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Literal

import numpy as np

from .errors import GyrocalError, ProtocolError, RecordingError
from .recording import Recording
from .stage import AXES, FLAG_COUNTER_GAP, FLAG_SATURATED, Stage


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
    min_turn_deg: float = 360.0 / 1.33
    max_turn_deg: float = 360.0 / 0.75
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
    """The tracker's view of the latest decided sample (about window_s / 2 behind the input)."""

    still_for_s: float  # how long the device has been still (0 while moving)
    moving: bool
    live_angle_deg: np.ndarray  # (3,) bias-compensated angle since the current motion began, else zeros
    noise_floor: float | None  # deg/s, None until the first blocks are in
    t: float | None  # time of the latest decided sample


@dataclass(frozen=True)
class ProtocolStages:
    """The stages the calibration uses: the first still, one turn per axis, and all stills."""

    still0: Stage
    turns: dict[str, Stage]  # keys "x", "y", "z" in that order
    stills: list[Stage]
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return {
            "still0": self.still0.to_dict(),
            "turns": {a: s.to_dict() for a, s in self.turns.items()},
            "stills": [s.to_dict() for s in self.stills],
            "notes": list(self.notes),
        }


# Columns of the running (prefix) sums kept per sample, relative to the first reading x0.
_S1 = slice(0, 3)  # x - x0
_S2 = slice(3, 6)  # (x - x0)^2
_D1 = slice(6, 9)  # d = x_i - x_{i-1}
_D2 = slice(9, 12)  # d^2
_DT = 12  # dt_i = t_i - t_{i-1}
_MDT = slice(13, 16)  # (x - x0) dt
_TDT = 16  # (t - t0) dt
_SAT = 17  # saturated samples
_GAP = 18  # counter jumps
_NCOL = 19


class _Store:
    """Recent samples and their running sums, addressed by global sample index."""

    def __init__(self, cap: int) -> None:
        self.base = 0  # global index of row 0
        self.n = 0  # samples received
        self.x = np.empty((cap, 3))
        self.t = np.empty(cap)
        self.p = np.zeros((cap + 1, _NCOL))  # p[r] = sums over samples before global index base + r

    def append(self, x: np.ndarray, t: np.ndarray, values: np.ndarray, keep_from: int) -> None:
        k = t.size
        used = self.n - self.base
        if used + k > self.t.size:
            keep_from = min(max(keep_from, self.base), self.n)
            drop = keep_from - self.base
            if drop > 0:
                kept = used - drop
                self.x[:kept] = self.x[drop:used]
                self.t[:kept] = self.t[drop:used]
                self.p[: kept + 1] = self.p[drop : used + 1]
                self.base, used = keep_from, kept
            if used + k > self.t.size:
                cap = max(2 * self.t.size, used + k)
                self.x = np.concatenate([self.x[:used], np.empty((cap - used, 3))])
                self.t = np.concatenate([self.t[:used], np.empty(cap - used)])
                self.p = np.concatenate([self.p[: used + 1], np.zeros((cap - used, _NCOL))])
        self.x[used : used + k] = x
        self.t[used : used + k] = t
        # Running sums carry over exactly (cumsum adds in sample order), so any batching gives the same bits.
        self.p[used : used + k + 1] = np.cumsum(np.concatenate([self.p[used : used + 1], values]), axis=0)
        self.n += k

    def _local(self, i: int) -> int:
        if i < self.base:
            raise AssertionError(f"sample {i} is no longer kept (oldest kept: {self.base})")
        return i - self.base

    def row(self, i: int) -> np.ndarray:
        return self.p[self._local(i)]

    def sums(self, a: int, b: int) -> np.ndarray:
        return self.p[self._local(b)] - self.p[self._local(a)]

    def time(self, i: int) -> float:
        return float(self.t[self._local(i)])


def _positive(value: object) -> bool:
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False
    return bool(np.isfinite(v) and v > 0)


class StageTracker:
    """Streaming stage detector: ``feed`` samples in any batch sizes, then ``finish``.

    After the whole recording has been fed, ``stages`` equals ``detect_stages`` of it exactly. Input
    is processed in batches of at least ``config.update_interval_s`` (vectorised); decisions lag the
    input by about window_s / 2 plus that interval.
    """

    def __init__(self, fs: float, config: StageConfig | None = None, full_scale_dps: float | None = None) -> None:
        if not _positive(fs):
            raise RecordingError(f"the sample rate must be a positive number of Hz; got {fs!r}")
        if full_scale_dps is not None and not _positive(full_scale_dps):
            raise RecordingError(f"the gyro full scale must be a positive number of deg/s; got {full_scale_dps!r}")
        self.fs = float(fs)
        full_scale_dps = None if full_scale_dps is None else float(full_scale_dps)
        self.config = cfg = config or StageConfig()
        self.full_scale_dps = full_scale_dps
        self._h = max(1, int(round(cfg.window_s * fs / 2)))
        self._w = 2 * self._h + 1
        self._m = int(round(cfg.margin_s * fs))
        self._min_still = max(2, int(round(cfg.min_still_s * fs)))
        self._nb = max(3, int(round(cfg.floor_block_s * fs)))
        self._rank = int(cfg.floor_rank)
        self._batch = max(1, int(round(cfg.update_interval_s * fs)))
        self._keep_back = 2 * (self._m + self._min_still + self._w) + 8
        self._store = _Store(4 * self._keep_back + 4 * self._batch)
        # Input not yet processed.
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]] = []
        self._npending = 0
        # Carries of the per-sample values across batches.
        self._x0: np.ndarray | None = None
        self._t0 = 0.0
        self._last_x: np.ndarray | None = None
        self._last_t: float | None = None
        self._last_seq: int | None = None
        self._has_seq: bool | None = None
        self._clip_max = np.zeros(3)
        self._clip_len = np.zeros(3, dtype=np.int64)
        self._equal_pairs = np.zeros(3, dtype=np.int64)  # consecutive readings so far that are equal, per axis
        # Noise floor.
        self._blocks = 0
        self._quietest: list[float] = []
        self._floor_after = np.full(64, np.nan)  # floor once c blocks are complete, by c
        # Decisions.
        self._next = 0  # first undecided sample
        self._state: bool | None = None  # hysteresis state of the latest decided sample (True = still)
        self._run_start = 0
        self._still_start: int | None = None  # open still segment
        self._gap_start: int | None = None  # open motion
        self._gap_row: np.ndarray | None = None
        self._gap_t = 0.0
        self._still_row: np.ndarray | None = None
        self._still_t = 0.0
        self._bias_before: np.ndarray | None = None  # mean reading - x0 of the still before the open motion
        self._bias_before_t = 0.0  # time of the middle of the span it averages
        # Over the current still run, min of (window mean - x0 - D t) and max of (window mean - x0 + D t),
        # t since the first sample, D = rest_drift_dps_per_s: the levels a rest reading may still take.
        self._env_lo = np.zeros(3)
        self._env_hi = np.zeros(3)
        self._stages: list[Stage] = []
        self._events: list[StageEvent] = []
        self._finished = False

    # ---- public interface -------------------------------------------------------------------------

    @property
    def stages(self) -> list[Stage]:
        """The stages finalised so far, in time order."""
        return list(self._stages)

    @property
    def noise_floor(self) -> float | None:
        """Current noise-floor estimate (deg/s per axis), None until enough blocks are in."""
        c = self._blocks
        return float(self._floor_after[c]) if c >= self._rank else None

    @property
    def live(self) -> LiveState:
        """Stillness, time still and the angle of the current motion at the latest decided sample."""
        d = self._next
        if self._state is None or d == 0:
            return LiveState(0.0, False, np.zeros(3), self.noise_floor, None)
        still = bool(self._state)
        angle = np.zeros(3)
        if self._gap_start is not None:
            s = self._store.p[d - self._store.base] - self._gap_row
            if self._bias_before is None:
                angle = s[_MDT] + self._x0 * s[_DT]
            else:
                angle = s[_MDT] - self._bias_before * s[_DT]
        return LiveState(
            still_for_s=(d - self._run_start) / self.fs if still else 0.0,
            moving=not still,
            live_angle_deg=angle,
            noise_floor=self.noise_floor,
            t=self._store.time(d - 1),
        )

    def feed(self, t: object, gyro: object, seq: object = None) -> list[StageEvent]:
        """Add samples: t (n,) s, gyro (n, 3) or (3,) deg/s raw readings, seq (n,) counter or None.

        Returns the events of the input processed by this call (input waits until update_interval_s
        of it has arrived). seq must be given with every batch or with none. Times that do not
        increase and values that are not finite raise RecordingError when their batch is processed.
        """
        if self._finished:
            raise GyrocalError("this StageTracker has finished; start a new one for a new recording")
        t_arr = np.atleast_1d(np.asarray(t, dtype=float))
        g_arr = np.asarray(gyro, dtype=float)
        if g_arr.ndim == 1:
            g_arr = g_arr.reshape(1, -1)
        if t_arr.ndim != 1 or g_arr.shape != (t_arr.size, 3):
            raise RecordingError(
                f"feed() needs t of shape (n,) and gyro of shape (n, 3); got {t_arr.shape} and {np.shape(gyro)}"
            )
        s_arr = None
        if self._has_seq is None:
            self._has_seq = seq is not None
        elif self._has_seq != (seq is not None):
            raise RecordingError(
                "seq was given with some batches and not others; give the sample counter with every batch or never"
            )
        if seq is not None:
            s_arr = np.atleast_1d(np.asarray(seq))
            if s_arr.shape != t_arr.shape or not np.issubdtype(s_arr.dtype, np.integer):
                raise RecordingError(f"seq must be whole numbers of shape {t_arr.shape}; got {s_arr.dtype} {s_arr.shape}")
        if t_arr.size == 0:
            return []
        self._pending.append((t_arr, g_arr, s_arr))
        self._npending += t_arr.size
        if self._npending < self._batch:
            return []
        self._process(final=False)
        return self._take_events()

    def finish(self) -> list[StageEvent]:
        """End of input: decide the last samples and close the open stage."""
        if self._finished:
            return []
        self._process(final=True)
        self._finished = True
        n = self._store.n
        if n == 0:
            return self._take_events()
        if self._state:
            if self._still_start is None:
                lead = self._m if self._run_start > 0 else 0
                if n - (self._run_start + lead) >= self._min_still:
                    self._qualify(self._run_start + lead)
            if self._still_start is not None:
                self._close_still(n)
                return self._take_events()
        if self._gap_start is None:
            self._open_gap(0)  # nothing but a too short still
        self._close_gap(n, None)
        return self._take_events()

    # ---- processing -------------------------------------------------------------------------------

    def _take_events(self) -> list[StageEvent]:
        events, self._events = self._events, []
        return events

    def _process(self, final: bool) -> None:
        if self._pending:
            if len(self._pending) == 1:
                t, x, seq = self._pending[0]
            else:
                t = np.concatenate([p[0] for p in self._pending])
                x = np.concatenate([p[1] for p in self._pending])
                seq = np.concatenate([p[2] for p in self._pending]) if self._has_seq else None
            self._pending, self._npending = [], 0
            self._append(t, x, seq)
        self._update_floor()
        self._decide(final)

    def _append(self, t: np.ndarray, x: np.ndarray, seq: np.ndarray | None) -> None:
        if not np.all(np.isfinite(t)) or not np.all(np.isfinite(x)):
            bad = int(np.flatnonzero(~(np.isfinite(t) & np.all(np.isfinite(x), axis=1)))[0])
            raise RecordingError(
                f"sample {self._store.n + bad} (t={t[bad]!r}) has a time or gyro value that is not a finite number; "
                "drop or repair such samples first"
            )
        prev_t = self._last_t if self._last_t is not None else t[0] - 1.0 / self.fs
        dt = np.diff(t, prepend=prev_t)
        if np.any(dt <= 0):
            bad = int(np.flatnonzero(dt <= 0)[0])
            raise RecordingError(
                f"sample times must increase; sample {self._store.n + bad} (t={t[bad]!r}) is not after the one before"
            )
        if self._x0 is None:
            self._x0, self._t0 = x[0].copy(), float(t[0])
            self._last_x = x[0].copy()
        k = t.size
        xr = x - self._x0
        d = np.diff(x, axis=0, prepend=self._last_x[None, :])
        values = np.empty((k, _NCOL))
        values[:, _S1] = xr
        values[:, _S2] = xr * xr
        values[:, _D1] = d
        values[:, _D2] = d * d
        values[:, _DT] = dt
        values[:, _MDT] = xr * dt[:, None]
        values[:, _TDT] = (t - self._t0) * dt
        values[:, _SAT] = self._saturated(x)
        if seq is None:
            values[:, _GAP] = 0.0
        else:
            seq = seq.astype(np.int64)
            step = np.diff(seq, prepend=seq[0] - 1 if self._last_seq is None else self._last_seq)
            values[:, _GAP] = step != 1
            self._last_seq = int(seq[-1])
        keep_from = min(self._next, self._blocks * self._nb) - self._keep_back
        self._store.append(x, t, values, keep_from)
        self._last_x = x[-1].copy()
        self._last_t = float(t[-1])

    def _saturated(self, x: np.ndarray) -> np.ndarray:
        a = np.abs(x)
        cfg = self.config
        if self.full_scale_dps is not None:
            return np.any(a >= cfg.full_scale_fraction * self.full_scale_dps, axis=1)
        # Clipping shows as runs of identical readings at the largest |value| seen so far.
        k = x.shape[0]
        run_max = np.maximum(np.maximum.accumulate(a, axis=0), self._clip_max)
        same = np.empty((k, 3), dtype=bool)
        same[0] = x[0] == self._last_x if self._store.n > 0 else False
        same[1:] = x[1:] == x[:-1]
        idx = np.arange(k)[:, None]
        last_change = np.maximum.accumulate(np.where(same, -1, idx), axis=0)
        run_len = np.where(last_change >= 0, idx - last_change + 1, self._clip_len + idx + 1)
        equal = self._equal_pairs + np.cumsum(same, axis=0)
        pairs = self._store.n + idx[:, 0]  # consecutive pairs up to each sample
        needed = clip_run_needed(equal / np.maximum(pairs, 1)[:, None], cfg.clip_run, cfg.clip_chance)
        self._clip_max = run_max[-1].copy()
        self._clip_len = run_len[-1].copy()
        self._equal_pairs = equal[-1].copy()
        return np.any((run_len >= needed) & (a >= cfg.clip_min_dps) & (a >= run_max), axis=1)

    def _update_floor(self) -> None:
        done = self._store.n // self._nb
        if done <= self._blocks:
            return
        nb, st = self._nb, self._store
        starts = np.arange(self._blocks, done) * nb
        s = st.p[starts + nb - st.base] - st.p[starts + 1 - st.base]
        m = nb - 1
        var = np.maximum(s[:, _D2] / m - (s[:, _D1] / m) ** 2, 0.0)
        sigma = np.sqrt(var.mean(axis=1) / 2.0)
        if self._floor_after.size <= done:
            self._floor_after = np.concatenate([self._floor_after, np.full(self._floor_after.size + done, np.nan)])
        cfg = self.config
        for c, value in enumerate(sigma.tolist(), start=self._blocks + 1):
            if len(self._quietest) < self._rank or value < self._quietest[-1]:
                bisect.insort(self._quietest, value)
                del self._quietest[self._rank :]
            if len(self._quietest) == self._rank:
                self._floor_after[c] = min(max(self._quietest[-1], cfg.min_noise_dps), cfg.max_noise_dps)
        self._blocks = done

    def _final_floor(self) -> float:
        """Floor for a recording too short to have floor_rank blocks: use what there is."""
        st, n, nb = self._store, self._store.n, self._nb
        sig = list(self._quietest)
        a = self._blocks * nb
        if n - a >= 3:
            s = st.sums(a + 1, n)
            m = n - a - 1
            var = np.maximum(s[_D2] / m - (s[_D1] / m) ** 2, 0.0)
            sig.append(float(np.sqrt(var.mean() / 2.0)))
        if not sig:
            return self.config.min_noise_dps
        sig.sort()
        return min(max(sig[min(self._rank, len(sig)) - 1], self.config.min_noise_dps), self.config.max_noise_dps)

    def _decide(self, final: bool) -> None:
        st, h, w, n = self._store, self._h, self._w, self._store.n
        i0 = self._next
        if final:
            i1 = n
        elif self._blocks < self._rank or n < w:
            return
        else:
            i1 = n - h
        if i1 <= i0:
            return
        i = np.arange(i0, i1)
        lo = np.maximum(i - h, 0)
        if final:
            lo = np.minimum(lo, max(0, n - w))
        hi = np.minimum(lo + w, n)
        length = (hi - lo)[:, None]
        s = st.p[hi - st.base] - st.p[lo - st.base]
        level = s[:, _S1] / length  # window mean - x0
        var = np.maximum(s[:, _S2] / length - level**2, 0.0)
        noise = np.sqrt(var.mean(axis=1))
        if self._blocks >= self._rank:
            floor = self._floor_after[np.maximum(hi // self._nb, self._rank)]
        else:
            floor = np.full(i.size, self._final_floor())
        z = noise / floor
        cfg = self.config
        quiet = z < cfg.enter_ratio
        loud = z > cfg.exit_ratio
        tol = np.maximum(cfg.rest_tol_dps, cfg.rest_tol_floors * floor)[:, None]
        drift = cfg.rest_drift_dps_per_s
        t = st.t[i - st.base]
        low = level - drift * (t - self._t0)[:, None]
        high = level + drift * (t - self._t0)[:, None]

        def enters(a: int, b: int) -> np.ndarray:
            if self._bias_before is None:  # no still yet: only a plausible zero-rate offset
                return quiet[a:b] & (np.abs(level[a:b] + self._x0).max(axis=1) <= cfg.max_zero_rate_dps)
            allowed = tol[a:b] + drift * (t[a:b] - self._bias_before_t)[:, None]
            return quiet[a:b] & np.all(np.abs(level[a:b] - self._bias_before) <= allowed, axis=1)

        def leaves(a: int, b: int) -> np.ndarray:
            # |level_i - level_j| <= tol + drift (t_i - t_j) for every earlier sample j of the run.
            # Carries the envelope on to b; past a leaving sample it is not used again.
            lo_env = np.minimum.accumulate(np.vstack([self._env_lo, low[a:b]]), axis=0)[1:]
            hi_env = np.maximum.accumulate(np.vstack([self._env_hi, high[a:b]]), axis=0)[1:]
            self._env_lo, self._env_hi = lo_env[-1], hi_env[-1]
            off = np.any((low[a:b] - tol[a:b] > lo_env) | (high[a:b] + tol[a:b] < hi_env), axis=1)
            return loud[a:b] | off

        # Walk the runs of equal state (few per second), each found by a vectorised search. A run's
        # search depends on the one before: entering compares with the still closed last.
        state, a, search = bool(self._state), 0, 0
        while True:
            k = _first_true(leaves if state else enters, search, i.size)
            b = i.size if k is None else k
            if b > a:
                self._set_state(i0 + a, state)
                self._check_qualified(i0 + b)
            if k is None:
                break
            state = not state
            if state:
                self._env_lo, self._env_hi = low[k].copy(), high[k].copy()
            self._set_state(i0 + k, state)
            a, search = k, k + 1
        self._next = i1

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
        self._gap_row = self._store.row(g).copy()
        self._gap_t = self._store.time(g)
        self._events.append(StageEvent("motion_started", self._gap_t))

    def _qualify(self, start: int) -> None:
        """A still run has become long enough: close the motion before it and open the still."""
        if self._gap_start is not None:
            self._close_gap(start, self._store.sums(start, start + self._min_still)[_S1] / self._min_still)
        self._still_start = start
        self._still_row = self._store.row(start).copy()
        self._still_t = self._store.time(start)
        self._events.append(StageEvent("still_started", self._still_t))

    def _close_still(self, end: int) -> None:
        start = self._still_start
        span = min(self._min_still, end - start)
        self._bias_before = self._store.sums(end - span, end)[_S1] / span
        self._bias_before_t = 0.5 * (self._store.time(end - span) + self._store.time(end - 1))
        self._emit(Stage("still", start, end, self._still_t, self._end_time(end),
                         flags=self._flags(self._still_row, end)))
        self._still_start = None

    def _close_gap(self, end: int, bias_after: np.ndarray | None) -> None:
        """Close the open motion at ``end``; it is a turn if it qualifies and a still follows it."""
        start, row0 = self._gap_start, self._gap_row
        st, cfg = self._store, self.config
        kind, axis, angle = "motion", None, None
        if bias_after is not None and self._bias_before is not None:
            s = st.row(end) - row0
            t_end = st.time(end)
            duration = t_end - self._gap_t
            b0 = self._bias_before
            # sum_j u_j dt_j with u_j = (t_j - t_start) / (t_end - t_start), the interpolation weight.
            u_dt = (s[_TDT] - (self._gap_t - self._t0) * s[_DT]) / duration
            theta = s[_MDT] - b0 * s[_DT] - (bias_after - b0) * u_dt
            k = int(np.argmax(np.abs(theta)))
            main = float(theta[k])
            off = float(np.hypot(*np.delete(theta, k)))
            if (cfg.min_turn_deg <= abs(main) <= cfg.max_turn_deg and off <= cfg.max_off_axis * abs(main)
                    and duration <= cfg.max_turn_s):
                kind, axis, angle = "turn", AXES[k], main
        self._emit(Stage(kind, start, end, self._gap_t, self._end_time(end), axis, angle, self._flags(row0, end)))
        self._gap_start = None

    def _end_time(self, end: int) -> float:
        if end < self._store.n:
            return self._store.time(end)
        return self._store.time(end - 1) + 1.0 / self.fs

    def _flags(self, row0: np.ndarray, end: int) -> tuple[str, ...]:
        s = self._store.row(end) - row0
        flags = []
        if s[_SAT] > 0:
            flags.append(FLAG_SATURATED)
        if s[_GAP] > 0:
            flags.append(FLAG_COUNTER_GAP)
        return tuple(flags)

    def _emit(self, stage: Stage) -> None:
        self._stages.append(stage)
        self._events.append(StageEvent("stage_closed", stage.end_s, stage))


def _first_true(cond: Callable[[int, int], np.ndarray], start: int, stop: int) -> int | None:
    """First index in [start, stop) where cond(a, b) (a bool array for a..b-1) holds, else None.

    Looks ahead in doubling chunks, so finding a change costs about its distance, not stop - start.
    """
    a, step = start, 64
    while a < stop:
        b = min(stop, a + step)
        hit = np.flatnonzero(cond(a, b))
        if hit.size:
            return a + int(hit[0])
        a, step = b, 2 * step
    return None


def detect_stages(rec: Recording, config: StageConfig | None = None) -> list[Stage]:
    """Still segments, turns and other motions of a recording, in time order, covering all of it."""
    tracker = StageTracker(rec.fs, config, full_scale_dps=rec.meta.gyro_full_scale_dps)
    tracker.feed(rec.t, rec.gyro, rec.seq)
    tracker.finish()
    return tracker.stages


_TURN_HOWTO = "keeping it still for about 3 s before and after"


def find_protocol(stages: list[Stage], min_still0_s: float = 1.5) -> ProtocolStages:
    """The protocol's stages: the still before the first turn and the first turn about each axis.

    Raises ProtocolError naming the missing stage and saying how to record it.
    """
    stages = sorted(stages, key=lambda s: s.start)
    turns = [s for s in stages if s.kind == "turn"]
    stills = [s for s in stages if s.kind == "still"]
    chosen: dict[str, Stage] = {}
    notes: list[str] = []
    for s in turns:
        if s.axis in chosen:
            notes.append(
                f"the device was turned about {s.axis} more than once; the first turn "
                f"(at {chosen[s.axis].start_s:.1f} s) is used, not the one at {s.start_s:.1f} s"
            )
        else:
            chosen[s.axis] = s
    missing = [a for a in AXES if a not in chosen]
    if missing:
        found = ", ".join(f"about {s.axis} at {s.start_s:.1f} s" for s in chosen.values())
        n_motion = sum(s.kind == "motion" for s in stages)
        detail = (f" Turns found: {found}." if found else " No full turn was found at all.") + (
            f" {n_motion} other motion(s) were not full turns: a turn counts when it is one full turn"
            f" ({360 / 1.33:.0f}-{360 / 0.75:.0f} degrees as measured) about one device axis, between two pauses."
            if n_motion else ""
        )
        if stages and stages[0].kind == "motion" and stages[0].start == 0:
            detail += (f" The recording begins in motion (0-{stages[0].duration_s:.1f} s), so a turn there has no pause"
                       " before it: start recording with the device at rest.")
        if len(stages) > 1 and stages[-1].kind == "motion":
            detail += (" The recording ends in motion, so a turn there has no pause after it: keep the device still"
                       " for about 3 s after the last turn before stopping.")
        if len(missing) == 1:
            a = missing[0]
            msg = f"no turn about {a} was found: turn the device a full 360 degrees about its {a} axis, {_TURN_HOWTO} the turn."
        else:
            names = " or ".join(missing)
            msg = (f"no turn about {names} was found: turn the device a full 360 degrees about each of its "
                   f"{', '.join(missing)} axes, {_TURN_HOWTO} each turn.")
        raise ProtocolError(msg + detail, code="turn_missing", stages=stages)
    first = min(chosen.values(), key=lambda s: s.start)
    before = [s for s in stills if s.end <= first.start and s.duration_s >= min_still0_s]
    if not before:
        raise ProtocolError(
            f"no still segment of at least {min_still0_s:g} s before the first turn (about {first.axis} at "
            f"{first.start_s:.1f} s) was found: put the device down and keep it still for about 3 s before turning it.",
            code="still_missing", stages=stages,
        )
    still0 = before[-1]
    order = sorted(chosen, key=lambda a: chosen[a].start)
    if order != list(AXES):
        notes.append(f"the turns were made in the order {', '.join(order)} (the protocol order is x, y, z)")
    if stages.index(still0) != stages.index(first) - 1:
        notes.append(
            f"the still just before the first turn is shorter than {min_still0_s:g} s; the still at "
            f"{still0.start_s:.1f}-{still0.end_s:.1f} s is used as the first still"
        )
    for a in AXES:
        if chosen[a].flags:
            notes.append(f"the turn about {a} is flagged: {', '.join(chosen[a].flags)}")
    if still0.flags:
        notes.append(f"the first still is flagged: {', '.join(still0.flags)}")
    return ProtocolStages(still0=still0, turns={a: chosen[a] for a in AXES}, stills=stills, notes=notes)
