"""A simulated wearable's readings when its clinician follows the session's prompts (mock_device.hand).

``PromptedSource`` is a ``SampleSource`` whose plan grows as the hand decides: it starts at rest on the
table against the block; before each block of readings it asks the hand what it starts by then, and every
``Act`` cuts the rest the plan is in at that moment and appends the act's motion and a rest. Whoever
carries the session's events (a test, a benchmark, ``follower.SessionFollower`` reading the service's
events over HTTP) hands them to ``observe``. The plan is
simulated again from the session's start each time (calib's simulator is deterministic for a seed) and every
sample already produced is kept as it was.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from calib.simulator import ProtocolScript, Segment, Still

from .hand import HANDS, Act, PromptHand
from .scenarios import Scenario
from .sources import Block, ScriptedSource

REST_AHEAD_S = 120.0  # the rest after the latest act, until the hand acts again


class PromptedSource(ScriptedSource):
    """Readings of a device handled by a prompt-following hand; ``perform`` plays the hand's acts."""

    def __init__(self, seed: int = 0, hand: str = "careful", noise_dps: float = 0.03) -> None:
        super().__init__(seed=seed, scenario=Scenario(f"hand:{hand}", HANDS[hand].description, _at_rest), noise_dps=noise_dps)
        self.style = HANDS[hand]
        self.hand = PromptHand(self.style, np.random.default_rng([seed, 0x4A4D]))
        self.segments: list[Segment] = [Still(REST_AHEAD_S)]
        self._delivered = 0  # samples handed out so far: what is past cannot change
        self._lock = threading.Lock()  # the hand sees snapshots on one thread and acts on the streaming one
        self.streaming: Callable[[], None] | None = None  # told when a stream starts (the hand's eyes look then)

    def observe(self, snap: dict[str, Any]) -> None:
        """A snapshot of the session, as the page gets it: the hand reads it (from any thread)."""
        with self._lock:
            self.hand.observe(snap)

    def observe_now(self, snap: dict[str, Any]) -> None:
        """A snapshot that arrived just now over the network: the hand takes it as seen at the latest sample this
        source handed out (the service's device clock runs on across streaming sessions; this source's restarts)."""
        if self._fs is None:
            return
        live = dict(snap.get("live") or {})
        live["t_device_s"] = self._delivered / self._fs
        self.observe({**snap, "live": live})

    def prepare(self, fs_hz: float) -> None:
        super().prepare(fs_hz)
        self.hand = PromptHand(self.style, np.random.default_rng([self.seed, 0x4A4D, self.session]), device_k=self.params.k)
        self.segments = [Still(REST_AHEAD_S)]
        self._delivered = 0
        if self.streaming is not None:
            self.streaming()

    def block(self, start: int, end: int) -> Block:
        if self._fs is not None:
            with self._lock:
                acts = self.hand.due(end / self._fs)
            for act in acts:
                self.perform(act)
        self._delivered = max(self._delivered, end)
        return super().block(start, end)

    def perform(self, act: Act) -> None:
        """Start the act's motion at its device time (s since streaming began; no earlier than the next sample
        not yet handed out), on the rest the plan is in."""
        assert self._fs is not None, "prepare() first"
        at = int(np.ceil(act.at_s * self._fs - 1e-9))
        last_start = int(self.segment_bounds[-2])  # the plan always ends with the rest ahead
        at = max(at, last_start, self._delivered)
        head = self.segments[:-1] + ([Still((at - last_start) / self._fs)] if at > last_start else [])
        old_gyro, old_accel = self._gyro, self._accel
        self.segments = [*head, *act.segments, Still(REST_AHEAD_S)]
        self._play(ProtocolScript(tuple(self.segments)))
        keep = min(at, old_gyro.shape[0])
        self._gyro = np.concatenate([old_gyro[:keep], self._gyro[keep:]])
        self._accel = np.concatenate([old_accel[:keep], self._accel[keep:]])


def _at_rest(rng: np.random.Generator) -> ProtocolScript:
    return ProtocolScript((Still(REST_AHEAD_S),))
