"""A simulated clinician who follows the session's prompts, as the page shows them.

The hand reads the session's snapshots (the same events the page gets: state, phase, prompt, warnings,
the live gauge), reacts after a human delay, and says what it does next as motion segments of calib's
simulator, from a moment of device time on. Its habits are a ``HandStyle``: careful, hurried (starts some
turns early, some late), sloppy (over- or under-turns some first tries), short (stops its first z turn where the
device reads 296 deg), ends_off (puts the device down 3 deg tilted after its first y turn), stalls (ends_off, then
never makes the turn asked again), fast (spins its first x turn in 0.6 s), wrong_axis (makes its first y turn about z),
bumping
(knocks the device once in the rest after a turn) and gauge-watching (stops each turn where the page's gauge reads a
full turn, when the gauge shows one, then puts it down against the block as the page says; a gauge that has not caught up
with her stop she does not read, and finishes the turn by feel; otherwise it turns back to the block like the others).
A device left off its place is put back against the block before the next turn, whatever prompt comes meanwhile.

The hand is pure logic: ``PromptedSource`` (mock_device.prompted) plays what it decides.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from calib.simulator import Motion, Segment, Still, Turn, paper_protocol_script, tilted_axis

HUMAN_DELAY_S = (0.3, 1.5)  # from a new prompt on the screen to the hand acting on it
GAUGE_LOOK_S = 0.25  # the gauge-watcher's pause to read the gauge before the last part of a turn
GAUGE_WAIT_S = 0.15  # ... longer while the gauge has not yet settled on her stop (a late page); the service takes a
#                      rest of 0.5 s as the turn put down (server.config.Timings.rest_seen_s), so the pause stays below it
GAUGE_STEADY_S = 0.2  # the gauge has settled once the page has shown the device still this long
GAUGE_RATE_DPS = 45.0  # ... and the speed of that last part
GAUGE_OVERSHOOT_DEG = (0.0, 5.0)  # how far past the gauge's 360 deg the hand's reaction carries it
IN_PLACE_DEG = 0.5  # a device put down this close to its place needs no putting back before the next turn
BLOCK_CATCH_DEG = 15.0  # a device put down this close to its place is pushed flush against the block
BUMP_DEG = np.array([4.0, -3.0, 12.0])  # a knock of the device and back (mock_device.scenarios' bump)
# when the knock comes after the hand stops the turn: while the turn is checked (the service sees the rest after
# 0.5 s, server.config.Timings.rest_seen_s) or in the pause once it is recorded (2 s from the stop, Timings.pause_s)
KNOCK_AFTER_STOP_S = (0.8, 1.9)


@dataclass(frozen=True)
class HandStyle:
    """How a simulated clinician follows the prompts (probabilities per session or per turn)."""

    name: str
    description: str
    early: float = 0.0  # per turn: starts it before the count on the screen has ended
    late: float = 0.0  # per turn: waits 2-5 s longer than the human delay
    miss: float = 0.0  # per first try of a turn: turns 30-70 deg too far or too short
    bump: float = 0.0  # per session: knocks the device once, in one of the pauses
    watches_gauge: bool = False  # stops where the gauge reads a full turn, when the gauge shows a target
    old_gauge: bool = False  # reads the raw angle as if 360 deg were its target (the gauge before targets)
    short_z_reads: float | None = None  # the first turn about z stops where the device reads this (deg): short of full
    ends_off_deg: float | None = None  # the first turn about y is put down tilted this much about x (deg)
    stalls: bool = False  # a turn asked again she puts back against the block, then never makes
    fast_first_x_s: float | None = None  # the first turn about x takes this long (s): too fast for the gyroscope
    first_y_about: str | None = None  # the first turn asked about y she makes about this axis instead


HANDS: dict[str, HandStyle] = {
    h.name: h
    for h in (
        HandStyle("careful", "waits for each prompt and turns back to the block"),
        HandStyle("hurried", "starts some turns before the count ends, some late", early=0.3, late=0.2),
        HandStyle("sloppy", "over- or under-turns a third of the first tries by 30-70 deg", miss=1 / 3),
        HandStyle("bumps", "knocks the device once, in one of the pauses", bump=1.0),
        HandStyle("gauge", "stops each turn where the gauge reads 360 deg, when it shows that target", watches_gauge=True),
        HandStyle("old_gauge", "stops where the raw angle reads 360 deg (the gauge without a calibration, as it was)",
                  watches_gauge=True, old_gauge=True),
        HandStyle("short", "stops the first z turn where the device reads 296 deg: it passes the live check, not k's range",
                  short_z_reads=296.0),
        HandStyle("ends_off", "puts the device down 3 deg tilted after its first y turn", ends_off_deg=3.0),
        HandStyle("stalls", "puts the device down 3 deg tilted after its first y turn; asked again, puts it back and "
                  "never turns", ends_off_deg=3.0, stalls=True),
        HandStyle("fast", "spins the first x turn in 0.6 s: the gyroscope saturates", fast_first_x_s=0.6),
        HandStyle("wrong_axis", "makes the first turn asked about y about z", first_y_about="z"),
    )
}


@dataclass(frozen=True)
class Act:
    """Motion the hand starts at device time ``at_s`` (from the end of whatever motion it is in)."""

    at_s: float
    segments: tuple[Segment, ...]


@dataclass
class _Plan:
    at_s: float
    what: str
    axis: str | None = None
    angle_deg: float = 0.0  # a gauge-watcher's turn: the part already made
    true_axis: np.ndarray | None = None  # ... and the true axis it was made about
    prompt: tuple[Any, ...] | None = None  # the prompt a turn answers: (state, axis, attempt)


@dataclass
class PromptHand:
    """Decides the next motion from the session's snapshots; see the module docstring."""

    style: HandStyle
    rng: np.random.Generator
    pending: list[_Plan] = field(default_factory=list)
    tries: dict[str, int] = field(default_factory=dict)  # turns started per axis
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))  # how far the device rests from its place (rotation vector, deg)
    bumped: bool = False
    bump_in: str | None = None  # the rest after a turn (axis) the bumping hand knocks the device in
    last: dict[str, Any] | None = None
    busy_until_s: float = 0.0  # the end of the motion the hand has started
    device_k: np.ndarray | None = None  # the simulated device's scale factors (a short turn stops where it reads short)
    _key: tuple[Any, ...] | None = None
    _params: list[Turn] = field(default_factory=list)
    # the prompts she has answered with a turn (state, axis, attempt), and ("early", axis) for a turn she started before
    # its prompt: a notice beside a prompt she has turned for (the service is late, another wearable's fault) does not
    # ask her to turn again
    answered: set[tuple[Any, ...]] = field(default_factory=set)

    def __post_init__(self) -> None:
        if self.style.bump and self.rng.random() < self.style.bump:
            self.bump_in = str(self.rng.choice(["x", "y", "z"]))

    # -- what the hand sees --------------------------------------------------------------------
    def observe(self, snap: dict[str, Any]) -> None:
        """A snapshot of the session arrived (at its ``live.t_device_s``)."""
        self.last = snap
        key = (snap.get("state"), snap.get("phase"), snap.get("axis"), snap.get("attempt"), len(snap.get("warnings") or ()))
        if key == self._key:
            return
        self._key = key
        # a new prompt: re-decide, but what her hands are already set on (a knock, the end of a turn, putting the
        # device back against the block) she still does
        prompt = _prompt(snap)
        self.pending = [p for p in self.pending
                        if p.what in ("bump", "gauge_finish", "put_back") or (p.prompt is not None and p.prompt == prompt)]
        self._decide(snap, float((snap.get("live") or {}).get("t_device_s") or 0.0))

    def due(self, until_s: float) -> list[Act]:
        """The motions to start before device time ``until_s`` (each once the motion before it has ended)."""
        out: list[Act] = []
        for p in sorted((p for p in self.pending if p.at_s < until_s), key=lambda p: p.at_s):
            if p.what == "gauge_finish" and self._gauge_behind() and until_s < p.at_s + GAUGE_WAIT_S:
                continue  # the gauge has not settled, though the hand has stopped: she waits for it to catch up
            self.pending.remove(p)
            if p.what == "turn" and p.prompt is None and p.axis is not None:
                self.answered.add(("early", p.axis))  # a turn started before its prompt is made once, notices or not
            start = max(p.at_s, self.busy_until_s)
            segs = self._segments(p, start)
            if segs:
                out.append(Act(start, segs))
                self.busy_until_s = start + sum(float(getattr(sg, "duration_s", 0.0) or 0.0) for sg in segs)
                self._plan_knock(p)
        return out

    def _plan_knock(self, done: _Plan) -> None:
        """The knock comes in the rest after the turn about ``bump_in``, timed from the hand's own stop (device time),
        not from when the screen said so: a page or an event late by a second would carry it past the pause."""
        ends_turn = done.what in ("turn", "gauge_finish") and not any(q.what == "gauge_finish" for q in self.pending)
        if ends_turn and done.axis == self.bump_in and not self.bumped:
            self.bumped = True
            self.pending.append(_Plan(self.busy_until_s + float(self.rng.uniform(*KNOCK_AFTER_STOP_S)), "bump"))

    def _gauge_behind(self) -> bool:
        """The last snapshot does not yet show the device still for GAUGE_STEADY_S: the gauge may still be
        moving up to where the hand stopped (the page is late with the stop)."""
        live = (self.last or {}).get("live") or {}
        return bool(live.get("moving", False)) or float(live.get("still_s") or 0.0) < GAUGE_STEADY_S

    # -- decisions ---------------------------------------------------------------------------------
    def _delay(self) -> float:
        return float(self.rng.uniform(*HUMAN_DELAY_S))

    def _decide(self, snap: dict[str, Any], t: float) -> None:
        state, phase, axis = snap.get("state"), snap.get("phase"), snap.get("axis")
        if state == "still" and self._starts_early("x"):
            self.pending.append(_Plan(t + float(self.rng.uniform(1.7, 2.6)), "turn", "x"))
        if not (isinstance(state, str) and state.startswith("turn_")) or axis is None:
            return
        if phase == "ready":
            prompt = _prompt(snap)
            if prompt in self.answered:
                return
            start = t
            if np.linalg.norm(self.offset) > IN_PLACE_DEG:
                # asked again before it was put back (the settle was over at once): back against the block first
                start = self._put_back_at(t + self._delay())
            if self.style.stalls and self.tries.get(axis, 0) >= 1:
                return  # asked again: she waits, whatever the screen says
            wait = self._delay() + (float(self.rng.uniform(2.0, 5.0)) if self.rng.random() < self.style.late else 0.0)
            self.answered.add(prompt)
            self.pending.append(_Plan(start + wait, "turn", axis, prompt=prompt))
        elif phase == "settle" and np.linalg.norm(self.offset) > IN_PLACE_DEG:
            self._put_back_at(t + self._delay())
        elif phase == "pause":
            nxt = {"x": "y", "y": "z"}.get(axis)
            if nxt is not None and self._starts_early(nxt):
                self.pending.append(_Plan(t + float(self.rng.uniform(0.9, 1.5)), "turn", nxt))

    def _starts_early(self, axis: str) -> bool:
        """Her habit decides whether she starts the turn about ``axis`` before it is asked; one she has already started
        early is not started again."""
        return ("early", axis) not in self.answered and self.rng.random() < self.style.early

    def _put_back_at(self, t: float) -> float:
        """Plans putting the device back against the block at ``t`` unless that is already planned; returns when
        it is planned (the next turn starts after it)."""
        planned = [p.at_s for p in self.pending if p.what == "put_back"]
        if planned:
            return min(planned)
        self.pending.append(_Plan(t, "put_back"))
        return t

    # -- motions -----------------------------------------------------------------------------------
    def _turn_shape(self, axis: str) -> Turn:
        """Duration, tilt, wobble and speed profile of one hand turn, drawn as the paper's protocol draws them."""
        if not self._params:
            self._params = list(paper_protocol_script(self.rng).turns)
        t = self._params.pop()
        return replace(t, axis=axis) if isinstance(t.axis, str) else t

    def _segments(self, p: _Plan, start_s: float) -> tuple[Segment, ...]:
        if p.what == "bump":
            return (Motion(BUMP_DEG, 0.4), Motion(-BUMP_DEG, 0.4), Still(0.05))
        if p.what == "put_back":
            if np.linalg.norm(self.offset) <= IN_PLACE_DEG:
                return ()  # already back in its place (the end of a turn set it flush against the block)
            back = -self.offset
            self.offset = np.zeros(3)
            return (Motion(back, 1.0), Still(1.6))  # and hands off a moment before the turn: a rest of its own
        if p.what == "gauge_finish":
            return self._gauge_finish(p)
        assert p.axis is not None
        return self._turn(p.axis, start_s)

    def _turn(self, axis: str, start_s: float) -> tuple[Segment, ...]:
        self.tries[axis] = self.tries.get(axis, 0) + 1
        shape = self._turn_shape(axis)
        first = self.tries[axis] == 1
        if first and axis == "x" and self.style.fast_first_x_s is not None:
            shape = replace(shape, duration_s=self.style.fast_first_x_s)
        if first and axis == "y" and self.style.first_y_about is not None:
            shape = replace(shape, axis=self.style.first_y_about)
        true_axis = tilted_axis(shape.axis if isinstance(shape.axis, str) else axis, np.asarray(shape.tilt, dtype=float))
        live = (self.last or {}).get("live") or {}
        if self.style.watches_gauge and (self.style.old_gauge or live.get("target_deg")):
            # most of the turn at the hand's pace, then a look at the gauge and the rest slowly (gauge_finish)
            first = float(self.rng.uniform(250.0, 290.0))
            seg = replace(shape, angle_deg=first, duration_s=float(shape.duration_s or 3.0) * first / 360.0)
            self.pending.append(_Plan(start_s + float(seg.duration_s or 0.0) + GAUGE_LOOK_S, "gauge_finish", axis, first, true_axis))
            return (seg, Still(GAUGE_LOOK_S))
        angle = 360.0
        if axis == "z" and self.tries[axis] == 1 and self.style.short_z_reads is not None and self.device_k is not None:
            angle = self.style.short_z_reads * float(self.device_k[2])  # g = K m: the true angle that reads that
            # spun flat on the table, about the vertical itself: short, it ends turned on the table, not tilted
            shape = replace(shape, tilt=(0.0, 0.0), wobble_deg=0.0)
            true_axis = tilted_axis(axis, np.zeros(2))
        elif self.tries[axis] == 1 and self.rng.random() < self.style.miss:
            angle += float(self.rng.choice([-1.0, 1.0]) * self.rng.uniform(30.0, 70.0))
        self.offset = self.offset + (angle - 360.0) * true_axis
        if axis == "y" and self.tries[axis] == 1 and self.style.ends_off_deg:
            tilt = np.array([self.style.ends_off_deg, 0.0, 0.0])  # put down on an edge of the block
            self.offset = self.offset + tilt
            return (replace(shape, angle_deg=angle), Motion(tilt, 0.3), Still(0.05))
        return (replace(shape, angle_deg=angle), Still(0.05))

    def _gauge_finish(self, p: _Plan) -> tuple[Segment, ...]:
        """The last part of a gauge-watcher's turn: on until the gauge reads 360 deg, with a reaction's overshoot."""
        live = (self.last or {}).get("live") or {}
        shown = abs(float(live.get("raw_turn_angle_deg" if self.style.old_gauge else "turn_angle_deg") or 0.0))
        # a gauge that has not caught up with her stop is not read: she finishes the turn by feel, as the others do
        total = p.angle_deg * 360.0 / shown if shown > 1.0 and not self._gauge_behind() else 360.0
        rest = max(0.0, total - p.angle_deg) + float(self.rng.uniform(*GAUGE_OVERSHOOT_DEG))
        rest = rest if rest >= 1.0 else 0.0  # too little to be worth a motion of its own
        assert p.true_axis is not None
        self.offset = self.offset + (p.angle_deg + rest - 360.0) * p.true_axis
        # on about the same true axis, so the whole turn is one rotation
        segs: list[Segment] = []
        if rest:
            segs.append(Turn(p.true_axis, rest, duration_s=max(0.4, rest / GAUGE_RATE_DPS), wobble_deg=0.0))
        if 0.0 < np.linalg.norm(self.offset) <= BLOCK_CATCH_DEG:
            # then down "back against the block", as the page says: the block's edge sets it flush
            segs.append(Motion(-self.offset, 0.5))
            self.offset = np.zeros(3)
        return (*segs, Still(0.05))


def _prompt(snap: dict[str, Any]) -> tuple[Any, ...]:
    """Which prompt a snapshot shows: (state, axis, attempt)."""
    return snap.get("state"), snap.get("axis"), snap.get("attempt")
