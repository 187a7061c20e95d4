"""Where the simulated wearable's samples come from: the scripted clinician or a recorded CSV."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from calib.simulator import STILL_S, ProtocolScript, SensorParams, Still, simulate

from .scenarios import LinkFaults, Scenario, get_scenario

TAIL_BLOCK = 4096  # samples per block of rest generated after the script ends
REDO_REST_S = 4.0  # rest after a reconnection before the interrupted step is redone: the service's settle and prompt


@dataclass(frozen=True)
class Block:
    """Raw readings for a run of samples: gyro m in deg/s (n, 3), accelerometer in g (n, 3)."""

    gyro: np.ndarray
    accel: np.ndarray


class SampleSource(Protocol):
    """Readings for sample indices of a streaming session."""

    fixed_rate_hz: float | None  # a replay has the rate of its file; None: any supported rate
    length: int | None  # samples available (None: endless)

    def prepare(self, fs_hz: float) -> None:
        """A new streaming session starts, sampled at ``fs_hz`` (the true output data rate): generate it."""

    def block(self, start: int, end: int) -> Block:
        """Readings of samples start..end-1."""

    def times_s(self, start: int, end: int) -> np.ndarray | None:
        """Sample times (s from the first sample) if the source has its own, else None (i / fs)."""

    def resumed(self, lost_at: int, at: int) -> None:
        """The link was lost at sample ``lost_at`` and the session resumed at sample ``at``."""


class ScriptedSource:
    """Calib's simulator driven by a scenario's clinician script; rest continues after the script.

    Every streaming session is a new performance of the scenario by the same hand on the same sensor:
    the first session plays the script drawn from the seed, session n > 1 a fresh draw of the
    scenario (turn durations, tilts, wobble, speed profiles) with fresh noise, drawn from (seed, n).
    The clinician follows the guidance after a link loss: once the link is back (``resumed``) the
    hand finishes the motion it is in, rests REDO_REST_S, redoes the step the loss interrupted (the
    turn or motion in progress; after a rest, the rest itself) and goes on with the rest of the script.
    """

    fixed_rate_hz = None
    length = None

    def __init__(self, seed: int = 0, scenario: str | Scenario = "normal", noise_dps: float = 0.03) -> None:
        self.seed = int(seed)
        self.scenario = get_scenario(scenario) if isinstance(scenario, str) else scenario
        self.noise_dps = float(noise_dps)
        ss_params, ss_script = np.random.SeedSequence([self.seed, 0x5EED]).spawn(2)
        self.params = SensorParams.paper_random(np.random.default_rng(ss_params))
        self.session = 0  # streaming sessions started so far
        self._sim_seed = self.seed
        self._noise_key: tuple[int, ...] = (self.seed,)
        # the script and link faults of the next (or current) session
        self.script: ProtocolScript = self.scenario.script(np.random.default_rng(ss_script))
        self.faults: LinkFaults = self.scenario.link_faults(self.script)
        self.plan: ProtocolScript = self.script  # what the hand does this session (the script, re-planned after a link loss)
        self.replans = 0
        self.segment_bounds = np.zeros(1, dtype=np.int64)  # sample index at which each segment of the plan starts, then its end
        self._fs: float | None = None
        self._gyro = np.zeros((0, 3))
        self._accel = np.zeros((0, 3))
        self._rest_accel = np.array([0.0, 0.0, 1.0])
        self._tail: dict[int, Block] = {}
        self.truth: dict[str, object] = {"k": self.params.k.tolist(), "b": self.params.b.tolist()}

    def prepare(self, fs_hz: float) -> None:
        self.session += 1
        if self.session > 1:
            ss_script, ss_noise = np.random.SeedSequence([self.seed, 0x5EED, self.session]).spawn(2)
            self.script = self.scenario.script(np.random.default_rng(ss_script))
            self.faults = self.scenario.link_faults(self.script)
            self._sim_seed = int(ss_noise.generate_state(1)[0])
            self._noise_key = (self.seed, self.session)
        if self.scenario.damaged_from is not None and self.session == self.scenario.damaged_from:
            self.params = SensorParams(k=self.params.k * np.asarray(self.scenario.damage_k), b=self.params.b)
            self.truth = {"k": self.params.k.tolist(), "b": self.params.b.tolist()}
        self._fs = float(fs_hz)
        self.replans = 0
        self._play(self.script)
        self._tail.clear()

    def _play(self, plan: ProtocolScript) -> None:
        """Simulate ``plan`` from the session's start and use it from now on."""
        assert self._fs is not None
        rec, truth = simulate(self._sim_seed, noise=self.noise_dps, fs=self._fs, params=self.params, script=plan)
        self.plan = plan
        self._gyro, self._accel = rec.gyro, rec.accel
        self._rest_accel = rec.accel[-max(1, int(self._fs * 0.5)):].mean(axis=0)
        self.segment_bounds = np.array([st.start for st in truth.trajectory.stages] + [truth.trajectory.n], dtype=np.int64)
        self.truth = {"k": truth.k.tolist(), "b": truth.b.tolist()}

    def resumed(self, lost_at: int, at: int) -> None:
        """Re-plan the rest of the session after a link loss (see the class docstring); samples
        before ``at`` are unchanged."""
        if self._fs is None:
            return
        segs = list(self.plan.segments)
        n = len(segs)

        def segment_at(i: int) -> int:
            return min(n, int(np.searchsorted(self.segment_bounds, i, side="right")) - 1)

        lost_seg, now_seg = segment_at(lost_at), segment_at(at)
        # finish the motion in hand (a rest is cut where it is), then rest until the step is asked again
        if now_seg < n and not isinstance(segs[now_seg], Still):
            head = segs[: now_seg + 1] + [Still(REDO_REST_S)]
        else:
            head = segs[: min(now_seg, n)] + [Still((at - self.segment_bounds[min(now_seg, n)]) / self._fs + REDO_REST_S)]
        # then the interrupted step again (a turn or motion; a rest has just been redone) and what followed it
        redo_from = lost_seg if lost_seg < n and not isinstance(segs[lost_seg], Still) else lost_seg + 1
        tail = segs[redo_from:]
        if not tail or not isinstance(tail[-1], Still):
            tail.append(Still(STILL_S))
        old_gyro, old_accel = self._gyro, self._accel
        self._play(ProtocolScript(tuple(head + tail)))
        # what was produced before the link came back stays as it was (the new plan moves the same way
        # up to there)
        keep = min(at, old_gyro.shape[0])
        self._gyro = np.concatenate([old_gyro[:keep], self._gyro[keep:]])
        self._accel = np.concatenate([old_accel[:keep], self._accel[keep:]])
        self.replans += 1

    @property
    def script_samples(self) -> int:
        return int(self._gyro.shape[0])

    def _tail_block(self, index: int) -> Block:
        if index not in self._tail:
            rng = np.random.default_rng([*self._noise_key, 0x7A11, index])
            rest = self.params.reading(np.zeros((TAIL_BLOCK, 3)))
            gyro = rest + self.noise_dps * rng.standard_normal((TAIL_BLOCK, 3))
            accel = self._rest_accel + 0.002 * rng.standard_normal((TAIL_BLOCK, 3))
            if len(self._tail) > 8:
                self._tail.clear()
            self._tail[index] = Block(gyro, accel)
        return self._tail[index]

    def block(self, start: int, end: int) -> Block:
        n = self.script_samples
        if end <= n:
            return Block(self._gyro[start:end], self._accel[start:end])
        parts_g, parts_a = [], []
        if start < n:
            parts_g.append(self._gyro[start:n])
            parts_a.append(self._accel[start:n])
        i = max(start, n)
        while i < end:
            b, off = divmod(i - n, TAIL_BLOCK)
            take = min(end - i, TAIL_BLOCK - off)
            tb = self._tail_block(b)
            parts_g.append(tb.gyro[off:off + take])
            parts_a.append(tb.accel[off:off + take])
            i += take
        return Block(np.concatenate(parts_g), np.concatenate(parts_a))

    def times_s(self, start: int, end: int) -> np.ndarray | None:
        return None


class ReplaySource:
    """A recorded CSV replayed at its own rate; the stream ends with the file."""

    def __init__(self, path: str | Path, fs: float | None = None) -> None:
        from calib.io.readers import read_recording  # calib's reader: native CSV or the imucal layout

        rec = read_recording(path, fs=fs)
        self.path = Path(path)
        self.fixed_rate_hz = float(rec.fs)
        self.length = len(rec)
        self._gyro = rec.gyro
        self._accel = rec.accel if rec.accel is not None else np.zeros_like(rec.gyro)
        self._t = rec.t - rec.t[0]
        self.truth = None
        self.faults = LinkFaults()

    def prepare(self, fs_hz: float) -> None:
        return None

    def resumed(self, lost_at: int, at: int) -> None:
        return None  # a recording cannot react to the link

    def block(self, start: int, end: int) -> Block:
        return Block(self._gyro[start:end], self._accel[start:end])

    def times_s(self, start: int, end: int) -> np.ndarray | None:
        return self._t[start:end]
