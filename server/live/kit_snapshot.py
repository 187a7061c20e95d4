"""A kit session's snapshot, composed from its wearables' own snapshots: the one rule for a running kit
(server.live.kit_session) and for a kit as the store keeps it (after the service restarted)."""

from __future__ import annotations

from datetime import datetime
from typing import TYPE_CHECKING, Protocol

from . import kit_guidance as say
from .codes import END_STATES, STEPS, EndReason, Phase, State
from .snapshot import stored_snapshot
from .snapshot_schema import KitDeviceOut, KitOut, SessionOut, SessionWarning

if TYPE_CHECKING:
    from ..store.records import StoredKit, StoredSession

NAMED = ("kit_closed_turn", "kit_moved_alone", "kit_not_turned")  # a wearable's own warnings that name it already
# a wearable's own warnings (its link, its data, its samples, its result): named by it. Every other warning is the
# tray's: each wearable sees the same bump, the same turn, the same late service, and the kit says it once, of the tray
OWN_WARNINGS = frozenset({"link_lost", "link_restored", "no_data", "data_resumed", "kit_ahead", *NAMED, EndReason.SAMPLE_LOSS,
                          EndReason.UNREADABLE_DATA, EndReason.SENSOR_FAULT, EndReason.OUT_OF_TOLERANCE})
PHASES = list(Phase)  # in protocol order
SAME_EVENT_S = 2.0  # the tray's warnings of one code from two wearables this close together are one event


class _Following(Protocol):
    """A wearable as the kit follows it: a live session (server.live.session) or its snapshot."""

    @property
    def state(self) -> State: ...

    @property
    def silent(self) -> bool | None: ...


def kit_waits_for(w: _Following) -> bool:
    """Whether the kit keeps its tray still for wearable ``w``: its link is lost (the kit waits for it to reconnect), or
    no data comes on a link that is up. The one rule for the kit's prompt and for its others' time limits, which do not
    run meanwhile (server.live.kit_session)."""
    return w.state == State.RECONNECTING or (bool(w.silent) and w.state not in END_STATES)


def kit_snapshot(kit_id: str, snaps: list[SessionOut], kit: KitOut, *, operator: str | None, started_at: str | None,
                 cancelled: bool) -> SessionOut:
    """The kit's state: the step of the wearable furthest along, its prompt said of the tray and its warnings named as
    its, and every wearable's own state.
    ``snaps``: the wearables' own snapshots, in the kit's order; ``cancelled``: the kit was cancelled."""
    state, lead = _state(snaps, cancelled)
    devices = [KitDeviceOut(
        device_id=s.device_id, session_id=s.session_id, state=s.state, phase=s.phase,
        prompt=say.of_the_tray(s.prompt) if s.prompt else None, reason_code=s.reason_code,
        reason=say.of_the_tray(s.reason) if s.reason else None, result=s.result, passed=s.passed, checks=s.checks,
        accuracy=s.accuracy, departures=s.departures, decision=s.decision, calibration_id=s.calibration_id,
        samples=s.samples, lost_samples=s.lost_samples, departed=s.device_id in kit.departed,
    ) for s in snaps]
    decision = "accepted" if any(d.decision == "accepted" for d in devices) else None
    return lead.model_copy(update={
        "session_id": kit_id, "kit_id": None, "device_id": ",".join(s.device_id for s in snaps), "kind": "kit",
        "state": state,
        "prompt": _prompt(state, lead, snaps),
        "warnings": kit_warnings(snaps),
        "devices": devices, "kit": kit.model_copy(update={"refusal": say.of_the_tray(kit.refusal)}) if kit.refusal else kit,
        "operator": operator, "started_at": started_at,
        "result": None, "passed": any(d.passed for d in devices) if state == State.DONE else None,
        "checks": [], "departures": [], "accuracy": None, "decision": decision, "calibration_id": None,
        "reason_code": None if state != State.FAILED else lead.reason_code,
        "reason": _reason(snaps),
    })


def stored_kit_snapshot(kit: StoredKit, sessions: list[StoredSession]) -> SessionOut:
    """A kit as the store keeps it: its wearables' stored sessions, and how they followed the tray."""
    snaps = [stored_snapshot(row) for row in sessions]
    out = KitOut(consistency=kit["consistency"], departed=kit["departed"], refusal=kit["refusal"])
    cancelled = any(s.state == State.CANCELLED for s in snaps)
    return kit_snapshot(kit["id"], snaps, out, operator=kit["operator"], started_at=kit["started_at"], cancelled=cancelled)


def _state(snaps: list[SessionOut], cancelled: bool) -> tuple[State, SessionOut]:
    if all(s.state in END_STATES for s in snaps):
        if cancelled and not any(s.state == State.DONE for s in snaps):
            return State.CANCELLED, snaps[0]
        done = [s for s in snaps if s.state == State.DONE]
        return (State.DONE, done[0]) if done else (State.FAILED, snaps[0])
    running = [s for s in snaps if s.state not in END_STATES]
    lost = [s for s in running if s.state == State.RECONNECTING]
    if lost:
        return State.RECONNECTING, lost[0]
    # furthest along by step, then by phase within it: a wearable that asks a turn again (settle) while the others rest
    # after it (pause) does not lead the tray, which is not turned again for one wearable
    along = max(running, key=lambda s: (STEPS.index(s.state) if s.state in STEPS else 0, PHASES.index(s.phase) if s.phase else -1))
    return State(along.state), along


def _prompt(state: State, lead: SessionOut, snaps: list[SessionOut]) -> str | None:
    """What the clinician holding the tray is asked to do now (an ended kit's outcome is its wearables')."""
    if state in END_STATES:
        return None
    if state == State.CONNECTING:
        return say.KIT_CONNECTING
    waited_for = [s for s in snaps if kit_waits_for(s)]
    if lost := [s.device_id for s in waited_for if s.state == State.RECONNECTING]:
        return say.kit_link_lost(lost)
    if waited_for:
        return say.kit_no_data([s.device_id for s in waited_for])
    return say.of_the_tray(lead.prompt) if lead.prompt else None


def _reason(snaps: list[SessionOut]) -> str | None:
    ended = [f"{s.device_id}: {say.of_the_tray(s.reason)}" for s in snaps if s.state in (State.FAILED, State.CANCELLED) and s.reason]
    return " ".join(ended) or None


def kit_warnings(snaps: list[SessionOut]) -> list[SessionWarning]:
    """The kit's warnings, in the order they came: a wearable's own named by it (one back on its link, or that lost
    samples in a turn, is told the kit goes on: the tray is not turned again for one wearable); the tray's said once,
    of the tray (the first wearable to see it says it). Each new warning of any wearable comes last, so the list only
    grows while the kit runs."""
    merged = sorted(((datetime.fromisoformat(w.at), s.device_id, w) for s in snaps for w in s.warnings),
                    key=lambda e: e[0])
    out: list[SessionWarning] = []
    said: list[tuple[datetime, str, str]] = []  # the tray's warnings kept: when, which code, by which wearable
    for at, device_id, w in merged:
        if w.code in OWN_WARNINGS:
            message = (say.kit_link_restored(device_id) if w.code == "link_restored"
                       else say.kit_sample_loss(device_id) if w.code == EndReason.SAMPLE_LOSS
                       else w.message if w.code in NAMED
                       else f"{device_id}: {say.of_the_tray(w.message)}")
            out.append(w.model_copy(update={"message": message, "device_id": device_id}))
        elif not any(code == w.code and by != device_id and abs((at - t).total_seconds()) <= SAME_EVENT_S
                     for t, code, by in said):
            said.append((at, w.code, device_id))
            out.append(w.model_copy(update={"message": say.of_the_tray(w.message)}))
    return out
