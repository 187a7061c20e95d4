"""A tray of simulated wearables turned by a clinician who follows the kit's prompts (`gyrocal serve --mock N
--mock-kit --mock-scenario hand:<style>`).

One ``PromptHand`` (mock_device.hand) reads the kit session's snapshots as the kit page shows them
(``follower.KitFollower``) and decides the tray's motion; every wearable in the tray records that one motion with its
own mounting, sensor errors and clock (calib.simulator.kit.KitTray). The tray's plan grows as the hand acts, as
``PromptedSource``'s plan does for one wearable: it rests until the hand acts; each act cuts that rest at the latest
moment any wearable has streamed and appends the act's motion and a rest. The tray is simulated again from its start
after each act (calib's simulator is deterministic for a seed, so what was streamed stays as it was), and a wearable
past the simulated rest rests on.

Each streaming session of a wearable joins a performance of the tray, as with the scripted clinician
(mock_device.kit): the wearables whose streams start within ``JOIN_S`` of the first play the same performance.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from calib.recording import Recording
from calib.simulator import ProtocolScript, Segment, SensorParams, Still, Turn
from calib.simulator.kit import KitDeviceTruth, KitTray, Slip, TrayFaults

from .hand import HANDS, Act, PromptHand
from .kit import Joins, loose_slip, resting_after, tray_sensors
from .scenarios import LinkFaults
from .sources import Block

REST_AHEAD_S = 20.0  # the rest simulated after the hand's latest act, s (past it a wearable rests on)


class TrayPerformance:
    """One performance of a prompted tray: the hand's plan so far, and each wearable's readings of it."""

    def __init__(self, seed: int, params: list[SensorParams], hand: PromptHand, noise_dps: float, slip: Slip | None,
                 out: int | None = None) -> None:
        self.seed, self.params, self.hand, self.noise_dps, self.slip = seed, params, hand, float(noise_dps), slip
        self.out = out  # lies on the table beside the tray (calib.simulator.kit.KitTray)
        self.segments: list[Segment] = [Still(REST_AHEAD_S)]
        self.now_s = 0.0  # the latest moment of the tray (true time, s) any wearable has streamed
        self._lock = threading.Lock()  # the hand sees snapshots on the follower's thread and acts on the streaming one
        self._tray = self._build()
        self._drawn: dict[tuple[int, float], tuple[Recording, KitDeviceTruth]] = {}
        self._rng = np.random.default_rng([seed, 0x7A12])

    def _build(self) -> KitTray:
        turns = sum(isinstance(s, Turn) for s in self.segments)
        slip = self.slip if self.slip is not None and turns > self.slip.turn else None  # once its turn is played
        return KitTray(self.seed, len(self.params), noise=self.noise_dps, script=ProtocolScript(tuple(self.segments)),
                       params=self.params, clock_error=0.0, slip=slip, out=self.out)

    def observe(self, snap: dict[str, Any]) -> None:
        """A snapshot of the kit, just read: the hand takes it as seen at the tray's latest streamed moment."""
        with self._lock:
            live = dict(snap.get("live") or {})
            live["t_device_s"] = self.now_s
            self.hand.observe({**snap, "live": live})

    def truth(self, d: int, fs: float) -> KitDeviceTruth:
        with self._lock:
            return self._wearable(d, fs)[1]

    def block(self, d: int, fs: float, start: int, end: int) -> Block:
        """Wearable ``d``'s readings of samples start..end-1 at ``fs`` Hz; the hand's acts due by then are played first."""
        with self._lock:
            _, truth = self._wearable(d, fs)
            until_s = truth.start_s + end / fs
            acts = self.hand.due(until_s)
            for act in acts:
                self._perform(act)
            self.now_s = max(self.now_s, until_s)
            rec, _ = self._wearable(d, fs)
        return _with_rest(rec, self.params[d], self.noise_dps, start, end, self._rng)

    def _wearable(self, d: int, fs: float) -> tuple[Recording, KitDeviceTruth]:
        key = (d, float(fs))
        if key not in self._drawn:
            self._drawn[key] = self._tray.wearable(d, fs)
        return self._drawn[key]

    def _perform(self, act: Act) -> None:
        """Start the act's motion at its moment (no earlier than what has been streamed), on the rest the plan is in."""
        rest = self._tray.tray.stages[-1]  # the plan always ends with the rest ahead
        at = max(act.at_s, self.now_s, rest.start_s)
        # the rest before the act in whole samples of the tray's motion, rounded up: a rest of a fraction of one (the
        # act due just as the rest began) is no segment the simulator takes, and rounding down could start the act
        # before what a wearable has streamed
        grid = self._tray.tray.fs
        steps = int(np.ceil((at - rest.start_s) * grid - 1e-6))
        head = self.segments[:-1] + ([Still(steps / grid)] if steps > 0 else [])
        self.segments = [*head, *act.segments, Still(REST_AHEAD_S)]
        self._tray = self._build()
        self._drawn.clear()


class PromptedTray:
    """The tray the kit's simulated wearables ride in, turned by one prompt-following hand of style ``hand``."""

    def __init__(self, seed: int, n: int, hand: str, noise_dps: float = 0.03, faults: TrayFaults | None = None) -> None:
        """``faults``: its loose, out and misalignment (``drop`` plays with the scripted clinician only)."""
        self.seed, self.n, self.style, self.noise_dps = int(seed), int(n), HANDS[hand], float(noise_dps)
        self.faults = faults or TrayFaults()
        self.slip = loose_slip(self.faults)
        self.params = tray_sensors(self.seed, self.n, self.faults.misalignment)  # the same sensors every performance
        self.performance: TrayPerformance | None = None
        self._joins = Joins()

    def performance_now(self) -> TrayPerformance:
        """The performance a stream starting now plays (``mock_device.kit.Joins``)."""
        number, new = self._joins.now()
        if new or self.performance is None:
            # a hand that stops a turn where the device reads short reads the tray's first wearable
            hand = PromptHand(self.style, np.random.default_rng([self.seed, number, 0x4A4D]), device_k=self.params[0].k)
            self.performance = TrayPerformance(self.seed * 1000 + number, self.params, hand, self.noise_dps, self.slip,
                                               self.faults.out)
        return self.performance

    def observe(self, snap: dict[str, Any]) -> None:
        """A snapshot of the kit session (from ``follower.KitFollower``), handed to the current performance's hand."""
        if self.performance is not None:
            self.performance.observe(snap)


class PromptedKitSource:
    """Wearable ``index`` (0-based) of a ``PromptedTray``: its readings of the performance its stream joined."""

    fixed_rate_hz = None
    length = None

    def __init__(self, tray: PromptedTray, index: int) -> None:
        self.tray, self.index = tray, int(index)
        self.session = 0
        self.faults = LinkFaults()
        self._performance: TrayPerformance | None = None
        self._fs = 0.0
        params = tray.params[self.index]
        self.truth: dict[str, object] = {"k": params.k.tolist(), "b": params.b.tolist()}
        self.streaming: Callable[[], None] | None = None  # told when a stream starts (the hand's eyes look then)

    def prepare(self, fs_hz: float) -> None:
        self.session += 1
        self._performance, self._fs = self.tray.performance_now(), float(fs_hz)
        params = self.tray.params[self.index]
        self.truth = {"k": params.k.tolist(), "b": params.b.tolist(), "K": params.K.tolist(), "slip_deg": 0.0}
        if self.streaming is not None:
            self.streaming()

    def block(self, start: int, end: int) -> Block:
        assert self._performance is not None, "prepare() first"
        blk = self._performance.block(self.index, self._fs, start, end)
        if self.tray.faults.loose == self.index:
            self.truth["slip_deg"] = self._performance.truth(self.index, self._fs).slip_deg
        return blk

    def resumed(self, lost_at: int, at: int) -> None:
        return None  # the tray's clinician follows the kit's prompts: a lost wearable's samples meanwhile are lost

    def times_s(self, start: int, end: int) -> np.ndarray | None:
        return None


def _with_rest(rec: Recording, params: SensorParams, noise_dps: float, start: int, end: int,
               rng: np.random.Generator) -> Block:
    """Samples start..end-1 of ``rec``, and rest readings past its end (the tray waits for the hand's next act)."""
    n = len(rec)
    accel = rec.accel if rec.accel is not None else np.zeros_like(rec.gyro)
    rest_accel = accel[-max(1, min(n, 50)):].mean(axis=0) if n else np.array([0.0, 0.0, 1.0])
    return resting_after(rec.gyro, accel, params.reading(np.zeros(3)), rest_accel, noise_dps, start, end, rng)
