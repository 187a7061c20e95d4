"""A kit session: the wearables of one tray calibrated together (``POST /kits/calibrate``).

Each wearable runs its own guided session (its link, its stream, its stage detector, its spool and its stored row,
as alone). Turned together they move through the protocol together; the kit's snapshot follows the one furthest
along (the tray has been turned that far). One behind (it missed a turn, or asked one again) shows its own step in
its row, and once the others have their recordings it gives its recording as it is (``KIT_LAG_S``).

A wearable's session with its recording waits here instead of calibrating alone. Once every wearable has its
recording or has ended, the kit's recordings are calibrated together (``calib.kit``) in a worker, and each wearable's
session goes on with its own result: judged, shown and accepted as alone. A wearable that came apart from the kit
(moved in its slot) gets no result and says so; one whose link was lost for good ends as alone, and the kit is
calibrated without it.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Generic, Protocol, TypeVar

from calib.kit.turns import turn_spans
from calib.recording import Recording

from ..workers.compute import ComputePool, LiveOutcome, calibrate_live, off_loop
from ..workers.kit import KitOutcome, calibrate_kit_live
from . import guidance as say
from . import kit_guidance as kit_say
from .codes import EndReason
from .events import Broadcaster
from .kit_faults import judge_held, judge_not_turned
from .kit_redo import tray_turns_to_redo
from .kit_snapshot import kit_snapshot, kit_waits_for
from .snapshot_schema import KitOut, SessionOut

if TYPE_CHECKING:
    from calib.stages.stage import Stage

    from ..devices import Device
    from .session import GuidedSession


class Member(Protocol):
    """What the kit uses of a wearable's session (server.live.runner.LiveSession)."""

    device: Device
    machine: GuidedSession
    kit: KitSession | None

    @property
    def streaming(self) -> bool: ...

    def cancel(self, reason: str = ...) -> bool: ...


M = TypeVar("M", bound=Member)

log = logging.getLogger(__name__)
KIT_LAG_S = 4.0  # after the first wearable's recording is in, how long another may stay in a protocol step, s
KIT_EVENT_S = 0.05  # a wearable's snapshot reaches the kit's event stream this late at most (its neighbours' join it)
JUDGE_AGAIN_S = 0.1  # while a wearable's fault waits for the others' verdicts, it is judged again this often


class KitSession(Generic[M]):
    """The wearables' guided sessions of one kit, and their calibration together."""

    def __init__(self, kit_id: str, members: list[M], pool: ComputePool | None, compute_timeout_s: float,
                 operator: str, on_end: Callable[[KitSession[M]], None] | None = None,
                 keep_outcome: Callable[[str, KitOutcome], None] | None = None,
                 heading_prior_deg: float | None = None) -> None:
        """``keep_outcome(kit_id, outcome)``: stores how the wearables followed the tray (run in a thread);
        ``heading_prior_deg``: the site's stated heading spread of the tray (None: learned from the kit's turns)."""
        self.id = kit_id
        self.members = members
        self.pool = pool
        self.compute_timeout_s = compute_timeout_s
        self.heading_prior_deg = heading_prior_deg
        self.operator = operator
        self.on_end = on_end
        self.keep_outcome = keep_outcome
        self.started_at = datetime.now(UTC).isoformat()
        self.outcome: KitOutcome | None = None
        self.cancelled = False
        self._arrived: dict[str, tuple[Recording, list[Stage], str]] = {}
        self._waiting: dict[str, asyncio.Future[LiveOutcome | None]] = {}
        self._task: asyncio.Task[None] | None = None
        self._lagging: asyncio.TimerHandle | None = None
        self.lag_s = KIT_LAG_S
        self.broadcaster = Broadcaster()
        self._publishing: asyncio.TimerHandle | None = None
        self._judging: asyncio.Handle | None = None
        self._judge_soon = False
        self._asked_again: set[str] = set()  # the tray's turns the kit's calibration asked again (once each)
        for m in members:
            m.kit = self
            m.machine.kit_id = kit_id

    @property
    def device_ids(self) -> list[str]:
        return [m.device.id for m in self.members]

    @property
    def finished(self) -> bool:
        return all(m.machine.finished for m in self.members)

    async def outcome_for(self, live: Member, rec: Recording, stages: list[Stage]) -> LiveOutcome | None:
        """A member's recording is in: wait for the kit's calibration and return this member's outcome (None: the
        calibration asked the tray a turn again, which this member's guidance now asks)."""
        loop = asyncio.get_running_loop()
        future: asyncio.Future[LiveOutcome | None] = loop.create_future()
        self._waiting[live.device.id] = future
        self._arrived[live.device.id] = (rec, stages, live.machine.method)
        self._maybe_compute()
        if self._task is None and self._lagging is None:
            self._lagging = loop.call_later(self.lag_s, self._take_lagging)
        return await future

    def _take_lagging(self) -> None:
        """The kit's other wearables have their recordings: one whose own guidance still waits for a step (it asked a
        turn again, which the tray will not be turned for) gives its recording as it is."""
        self._lagging = None
        arrived = ", ".join(self._arrived)
        for m in self.members:
            if m.device.id not in self._arrived:
                m.machine.take_recording(f"The rest of the kit ({arrived}) has been turned through the protocol: this "
                                         "wearable's recording is calibrated with theirs as it is.")

    def member_ended(self, live: Member) -> None:
        """A member's session ended (perhaps without a recording: its link lost for good, cancelled)."""
        self._maybe_compute()
        if self.finished and self.on_end is not None:
            self.on_end(self)

    def left(self, live: Member) -> None:
        """A member was cancelled while it waited for the kit's calibration: it waits no longer."""
        future = self._waiting.get(live.device.id)
        if future is not None and not future.done():
            future.set_result(LiveOutcome(None, "Cancelled.", None, b"", EndReason.CANCELLED))

    def cancel(self, reason: str = "Cancelled by the operator.") -> bool:
        done = [m.cancel(reason) for m in self.members if not m.machine.finished]
        self.cancelled = self.cancelled or any(done)
        return any(done)

    def _maybe_compute(self) -> None:
        if self._task is not None:
            return
        if all(m.device.id in self._arrived or m.machine.finished for m in self.members):
            if self._lagging is not None:
                self._lagging.cancel()
                self._lagging = None
            self._task = asyncio.get_running_loop().create_task(self._compute(), name=f"kit-{self.id}")

    async def _compute(self) -> None:
        names = [n for n in self.device_ids if n in self._arrived]
        try:
            if len(names) == 1:  # the others ended without a recording: this one is calibrated alone
                rec, stages, method = self._arrived[names[0]]
                alone = await asyncio.wait_for(off_loop(self.pool, calibrate_live, rec, method, stages, self.heading_prior_deg),
                                               self.compute_timeout_s)
                self.outcome = KitOutcome({names[0]: alone}, refusal=None)
            elif names:
                recs = [self._arrived[n][0] for n in names]
                kept = [turn_spans(*self._arrived[n][:2]) for n in names]
                self.outcome = await asyncio.wait_for(off_loop(self.pool, calibrate_kit_live, recs, names, kept,
                                                               self.heading_prior_deg), self.compute_timeout_s)
        except TimeoutError:
            why = say.compute_timeout(self.compute_timeout_s, "the kit's calibration")
            self.outcome = KitOutcome({n: LiveOutcome(None, why, None, b"", EndReason.SERVICE_OVERLOADED) for n in names}, refusal=why)
        except Exception as exc:  # the last line of defence: every waiting member gets an answer
            log.exception("kit %s could not be calibrated", self.id)
            why = say.internal_error(f"calibrating the kit: {type(exc).__name__}")
            self.outcome = KitOutcome({n: LiveOutcome(None, why, None, b"", EndReason.INTERNAL_ERROR) for n in names}, refusal=why)
        assert self.outcome is not None
        if self._turns_again(names):
            return
        if self.keep_outcome is not None:
            try:
                await asyncio.to_thread(self.keep_outcome, self.id, self.outcome)
            except Exception as exc:  # each wearable's own session keeps its result whatever this says
                log.warning("kit %s: how its wearables followed the tray could not be stored: %s", self.id, exc)
        for name, future in self._waiting.items():
            if not future.done():
                future.set_result(self.outcome.outcomes[name])

    def _turns_again(self, names: list[str]) -> bool:
        """The wearables' results point to turns of the tray that were most likely not full ones (server.live.kit_redo):
        the tray is asked them again, once each, while every wearable still streams; the kit then waits for its
        wearables' recordings again."""
        assert self.outcome is not None
        members = [m for m in self.members if m.device.id in names]
        if len(members) < 2 or not all(m.streaming and m.machine.max_attempts > 1 for m in members):
            return False
        axes, by = tray_turns_to_redo({n: self.outcome.outcomes[n] for n in names},
                                      {m.device.id: m.machine.tol for m in members}, self._asked_again)
        if not axes:
            return False
        self._asked_again.update(axes)
        said = kit_say.kit_turn_again(axes, by)
        for m in members:
            m.machine.turn_again_with_kit(axes, said)
        waiting, self._waiting, self._arrived, self.outcome, self._task = self._waiting, {}, {}, None, None
        for future in waiting.values():
            if not future.done():
                future.set_result(None)
        return True

    # -- what the page and the API see ---------------------------------------------------------
    def member_changed(self) -> None:
        """A wearable published a snapshot: the kit's follows within KIT_EVENT_S, one for all that changed meanwhile;
        a fault a wearable holds for the kit is judged at once (server.live.kit_faults)."""
        loop = asyncio.get_running_loop()
        if self._publishing is None and not self.broadcaster.closed:
            self._publishing = loop.call_later(KIT_EVENT_S, self.publish)
        judge_not_turned([m.machine for m in self.members])
        waited_for = [m for m in self.members if kit_waits_for(m.machine)]
        if waited_for:  # the tray is kept still meanwhile: its prompt says so
            for m in self.members:
                if m not in waited_for:
                    m.machine.wait_with_kit()
        if not self._judge_soon and any(m.machine.held_fault or m.machine.held_move for m in self.members):
            if self._judging is not None:
                self._judging.cancel()
            self._judging, self._judge_soon = loop.call_soon(self._judge), True

    def _judge(self) -> None:
        self._judging, self._judge_soon = None, False
        if judge_held([m.machine for m in self.members]):  # some wait for the others' verdicts: again, even if none changes
            self._judging = asyncio.get_running_loop().call_later(JUDGE_AGAIN_S, self._judge)

    def publish(self) -> None:
        """Send the kit's snapshot to its event stream now."""
        if self._publishing is not None:
            self._publishing.cancel()
            self._publishing = None
        if not self.broadcaster.closed:
            self.broadcaster.publish("state", self.snapshot())

    def close_stream(self) -> None:
        """The kit is decided (or forgotten): its last snapshot out, its stream's clients let go."""
        self.publish()
        self.broadcaster.close()

    def snapshot(self) -> SessionOut:
        """The kit's state (server.live.kit_snapshot), from its wearables' live snapshots."""
        out = self.outcome
        kit = KitOut(consistency=None if out is None else out.consistency, departed=[] if out is None else out.departed,
                     refusal=None if out is None else out.refusal)
        return kit_snapshot(self.id, [m.machine.snapshot("state") for m in self.members], kit, operator=self.operator,
                            started_at=self.started_at, cancelled=self.cancelled)
