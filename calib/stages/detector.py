"""The streaming stage detector: stills, full turns and other motions as samples arrive (StageTracker), and the
whole-recording convenience detect_stages."""

from __future__ import annotations

import bisect
from collections.abc import Callable

import numpy as np

from calib.errors import GyrocalError, RecordingError
from calib.recording import Recording
from calib.stages.clipping import ClipTracker
from calib.stages.config import LiveState, StageConfig, StageEvent
from calib.stages.prefix_sums import DT, MDT, NCOL, S1, S2, TDT, PrefixStore, spread
from calib.stages.segments import StageBook
from calib.stages.stage import FLAG_COUNTER_GAP, FLAG_SATURATED, Stage


def _positive(value: object) -> bool:
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False
    return bool(np.isfinite(v) and v > 0)


class StageTracker(StageBook):
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
        self._store = PrefixStore(4 * self._keep_back + 4 * self._batch)
        # Input not yet processed.
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]] = []
        self._npending = 0
        # Carries of the per-sample values across batches.
        self._x0: np.ndarray | None = None
        self._t0 = 0.0
        self._last_t: float | None = None
        self._last_seq: int | None = None
        self._has_seq: bool | None = None
        self._clipping = ClipTracker(cfg, full_scale_dps)
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
        self._marked: dict[str, list[int]] = {FLAG_SATURATED: [], FLAG_COUNTER_GAP: []}
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
        """Stillness and time still at the latest decided sample; the angle of the current motion through the newest
        sample in."""
        d = self._next
        if self._state is None or d == 0:
            return LiveState(0.0, False, np.zeros(3), self.noise_floor, None)
        still = bool(self._state)
        angle = np.zeros(3)
        if self._gap_start is not None and self._gap_row is not None:
            # through the newest sample in, not only the decided ones: the gauge follows the hand without the
            # decision's look-ahead (rest samples after the turn add only their noise about the rest reading)
            s = self._store.p[:, self._store.n - self._store.base] - self._gap_row
            if self._bias_before is None:
                angle = s[MDT] + self._x0 * s[DT]
            else:
                angle = s[MDT] - self._bias_before * s[DT]
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
                f"feed() needs t of shape (n,) and gyro of shape (n, 3); got {t_arr.shape} and {np.asarray(gyro).shape}"
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
        # a sum is finite when every value is (the common case, at a fraction of the search's cost)
        not_finite = np.array([], dtype=np.int64) if np.isfinite(t.sum() + x.sum()) else np.flatnonzero(
            ~(np.isfinite(t) & np.all(np.isfinite(x), axis=1)))
        if not_finite.size:
            bad = int(not_finite[0])
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
        xr = x.T - self._x0[:, None]  # axis-major, as the store keeps its sums
        values = np.empty((NCOL, t.size))
        values[S1] = xr
        np.multiply(xr, xr, out=values[S2])
        values[DT] = dt
        np.multiply(xr, dt, out=values[MDT])
        values[TDT] = (t - self._t0) * dt
        first = self._store.n  # the global index of the batch's first sample
        self._marked[FLAG_SATURATED] += (np.flatnonzero(self._clipping.saturated(x)) + first).tolist()
        if seq is not None:
            seq = seq.astype(np.int64)
            step = np.diff(seq, prepend=seq[0] - 1 if self._last_seq is None else self._last_seq)
            self._marked[FLAG_COUNTER_GAP] += (np.flatnonzero(step != 1) + first).tolist()
            self._last_seq = int(seq[-1])
        keep_from = min(self._next, self._blocks * self._nb) - self._keep_back
        self._store.append(t, values, keep_from)
        self._last_t = float(t[-1])

    def _update_floor(self) -> None:
        done = self._store.n // self._nb
        if done <= self._blocks:
            return
        nb, st = self._nb, self._store
        starts = np.arange(self._blocks, done) * nb
        s = st.p[:, starts + nb - st.base] - st.p[:, starts - st.base]
        # the spread about the block's mean, as the stillness window measures it: differences would halve the
        # variance of white noise only, and a sensor's low-pass filter leaves its noise far smoother from sample to
        # sample than it is over a window (a floor a third of the rests' own noise: no rest was found)
        sigma = spread(s, nb)
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
            sig.append(float(spread(st.sums(a, n), n - a)))
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
        # each sample's window: w samples centred on it, moved inside the recording at its ends (all of it when
        # shorter); the windows' starts run through consecutive samples, so their sums come from two slices
        length = min(w, n)
        lo = np.clip(i - h, 0, n - length) if final else np.maximum(i - h, 0)
        hi = lo + length
        first, last = int(lo[0]) - st.base, int(lo[-1]) - st.base + 1
        s = st.p[: S2.stop, first + length : last + length] - st.p[: S2.stop, first:last]  # the S1 and S2 rows only
        if last - first != i.size:  # windows held at the recording's ends: their first and last sums repeated
            lead = int(np.searchsorted(lo, lo[0], side="right")) - 1
            trail = i.size - (last - first) - lead
            s = np.concatenate((np.broadcast_to(s[:, :1], (s.shape[0], lead)), s,
                                np.broadcast_to(s[:, -1:], (s.shape[0], trail))), axis=1)
        level = s[S1] / length  # (3, samples): window mean - x0
        var = np.maximum(s[S2] / length - level**2, 0.0)
        noise = np.sqrt((var[0] + var[1] + var[2]) / 3.0)
        if self._blocks >= self._rank:
            floor = self._floor_after[np.maximum(hi // self._nb, self._rank)]
        else:
            floor = np.full(i.size, self._final_floor())
        z = noise / floor
        cfg = self.config
        quiet = z < cfg.enter_ratio
        loud = z > cfg.exit_ratio
        tol = np.maximum(cfg.rest_tol_dps, cfg.rest_tol_floors * floor)
        drift = cfg.rest_drift_dps_per_s
        t = st.t[i0 - st.base : i1 - st.base]
        low = level - drift * (t - self._t0)
        high = level + drift * (t - self._t0)
        low_out, high_out = low - tol, high + tol  # a sample leaves once these pass the run's envelope
        x0 = self._x0
        assert x0 is not None  # set by the first batch appended

        def enters(a: int, b: int) -> np.ndarray:
            if self._bias_before is None:  # no still yet: only a plausible zero-rate offset
                return quiet[a:b] & (np.abs(level[:, a:b] + x0[:, None]).max(axis=0) <= cfg.max_zero_rate_dps)
            allowed = tol[a:b] + drift * (t[a:b] - self._bias_before_t)
            return quiet[a:b] & np.all(np.abs(level[:, a:b] - self._bias_before[:, None]) <= allowed, axis=0)

        def leaves(a: int, b: int) -> np.ndarray:
            # |level_i - level_j| <= tol + drift (t_i - t_j) for every earlier sample j of the run.
            # Carries the envelope on to b; past a leaving sample it is not used again.
            lo_env = np.minimum(np.minimum.accumulate(low[:, a:b], axis=1), self._env_lo[:, None])
            hi_env = np.maximum(np.maximum.accumulate(high[:, a:b], axis=1), self._env_hi[:, None])
            self._env_lo, self._env_hi = lo_env[:, -1], hi_env[:, -1]
            off = (low_out[:, a:b] > lo_env) | (high_out[:, a:b] < hi_env)
            return loud[a:b] | off[0] | off[1] | off[2]

        # Walk the runs of equal state (few per second), each found by a vectorised search. A run's
        # search depends on the one before: entering compares with the still closed last.
        # Where each search can end is known from the window noise alone: a still run lasts at most to the next loud
        # sample, and a motion cannot end before the next quiet one.
        loud_at, quiet_at = np.flatnonzero(loud), np.flatnonzero(quiet)
        state, a, search = bool(self._state), 0, 0
        while True:
            if state:
                nxt = _next_at(loud_at, search)
                k = _first_true(leaves, search, i.size, None if nxt is None else nxt + 1)
            else:
                nxt = _next_at(quiet_at, search)
                k = None if nxt is None else _first_true(enters, nxt, i.size)
            b = i.size if k is None else k
            if b > a:
                self._set_state(i0 + a, state)
                self._check_qualified(i0 + b)
            if k is None:
                break
            state = not state
            if state:
                self._env_lo, self._env_hi = low[:, k].copy(), high[:, k].copy()
            self._set_state(i0 + k, state)
            a, search = k, k + 1
        self._next = i1


def _next_at(indices: np.ndarray, start: int) -> int | None:
    """The first of the sorted ``indices`` at or after ``start``, else None."""
    j = int(np.searchsorted(indices, start))
    return int(indices[j]) if j < indices.size else None


def _first_true(cond: Callable[[int, int], np.ndarray], start: int, stop: int, first_stop: int | None = None) -> int | None:
    """First index in [start, stop) where cond(a, b) (a bool array for a..b-1) holds, else None.

    Looks ahead in doubling chunks, so finding a change costs about its distance, not stop - start; the first chunk
    ends at ``first_stop`` when given (where cond is known to hold).
    """
    a, step = start, 256
    end = None if first_stop is None else max(first_stop, start + 1)  # the first chunk's end, when known
    while a < stop:
        b = min(stop, a + step if end is None else end)
        end = None
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
