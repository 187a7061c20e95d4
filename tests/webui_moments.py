"""The page's moments as the recorder sampled them (``Wizard.record``'s ``samples``), read against what a clinician
must be able to rely on at every one of them."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from webui_fixtures import assert_done_never_undone

RETRY_MARK = "Attempt "  # a notice that asks a turn again starts "Attempt n of m:"


@dataclass(frozen=True)
class RetryReason:
    """One reason for a turn asked again, as the page showed it: for the turn state ``state``, from ``shown_ms`` for
    ``on_screen_ms`` (until it first left the screen), owed until ``owed_ms`` (the next turn started, or the session
    moved on), and ``gap_ms``: when it was gone before then (None: never)."""

    state: str
    text: str
    shown_ms: int
    on_screen_ms: int
    owed_ms: int
    gap_ms: int | None


def retry_reasons(samples: list[list[Any]]) -> list[RetryReason]:
    """Each retry reason in ``samples`` and how long it stayed: it is owed from the moment it appears until the turn it
    asks for starts (the page shows that state turning, on to the device put down, not back to the prompt) or the
    session leaves that state (a reconnection aside)."""
    out: list[RetryReason] = []
    i = 0
    while i < len(samples):
        t0, sp, box = samples[i][0], samples[i][1], samples[i][2]
        state = sp.split(":", 1)[0]
        if not (state.startswith("turn_") and box.startswith(RETRY_MARK)):
            i += 1
            continue
        reason = box
        owed, gap, left = None, None, None
        j = i + 1
        while j < len(samples):
            t, sp_j, box_j = samples[j][0], samples[j][1], samples[j][2]
            state_j = sp_j.split(":", 1)[0]
            if (sp_j == f"{state}:turning" and _turn_follows(samples, j, state)) or (
                    state_j != state and state_j != "reconnecting"):
                owed = t
                break
            if box_j.startswith(RETRY_MARK) and not box_j.startswith(reason[:40]):
                owed = t  # a new reason takes its place: that one is owed from now
                break
            if reason[:40] not in box_j:
                left = t if left is None else left
                gap = t if gap is None else gap
            j += 1
        end = samples[-1][0] if owed is None else owed
        out.append(RetryReason(state, reason, t0, (left if left is not None else end) - t0, end - t0,
                               None if gap is None else gap - t0))
        # on to the first moment after this reason's obligation
        while i < len(samples) and samples[i][0] < end:
            i += 1
    return out


def _turn_follows(samples: list[list[Any]], j: int, state: str) -> bool:
    """Whether the turning shown from sample ``j`` is the turn itself: through the device put down, it goes on to the
    turn checked, not back to the prompt (a device put back against the block, shown as turning by a page that cannot
    tell)."""
    for sample in samples[j:]:
        if sample[1] not in (f"{state}:turning", f"{state}:placing"):
            return sample[1] not in (f"{state}:ready", f"{state}:returning")
    return True


def assert_retry_reasons_stay(samples: list[list[Any]], at_least: int = 1, save: Path | None = None) -> list[RetryReason]:
    """Every retry reason the page showed stayed on screen until the turn it asks for started; returns them (and
    writes them to ``save``, a JSON file, first: how long each was on screen is a figure worth keeping)."""
    reasons = retry_reasons(samples)
    if save is not None:
        save.parent.mkdir(parents=True, exist_ok=True)
        save.write_text(json.dumps([asdict(r) for r in reasons], indent=1))
    assert len(reasons) >= at_least, [s for s in samples if s[2]][:20]
    gone = [(r.state, r.text[:90], r.gap_ms, r.owed_ms) for r in reasons if r.gap_ms is not None]
    assert not gone, f"a retry's reason left the screen before its turn started (state, reason, gone at, owed until ms): {gone}"
    return reasons


FIRST_CALM_S = 0.5  # device time the service may take to see the first calm readings as such
RING_SLACK = 10.0  # percent: a ring drawn from a snapshot a moment older than the event the page last handled
# a page that started a session shows its first rest at five moments at least, unless the rest passed in under this
# much of the page's time, or the page's 100 ms sampler stood still this long in it (ms)
BURST_MS = 500.0
STARVED_MS = 1000.0


def first_rest_began(samples: list[list[Any]]) -> float | None:
    """The device time of the first event a page handled while it showed the first hold-still (None: it showed none)."""
    still = _first_rest(samples)
    return still[0][0] if still else None


def _page_could_not_sample(samples: list[list[Any]]) -> bool:
    """Whether the page could not have shown its first rest at five moments: the rest passed in under ``BURST_MS`` of
    the page's own clock (a starved service catching up delivers it in a burst), or the page's sampler, every 100 ms,
    did not run for ``STARVED_MS`` while the rest was on (the browser itself was starved)."""
    shown = [i for i, s in enumerate(samples) if s[1].startswith("still:")]
    if not shown:
        return False
    page_ms = [s[0] for s in samples[max(0, shown[0] - 1): shown[-1] + 2]]
    return (samples[shown[-1]][0] - samples[shown[0]][0] < BURST_MS
            or max((b - a for a, b in zip(page_ms, page_ms[1:], strict=False)), default=0) >= STARVED_MS)


def _first_rest(samples: list[list[Any]]) -> list[tuple[float, int]]:
    """(device time of the event last handled, ring percent) at each sample showing a hold-still and an event."""
    return [(s[6], s[5]) for s in samples if s[1].startswith("still:") and s[5] is not None and s[6] is not None]


def assert_first_rest_counts_without_a_jump(samples: list[list[Any]], rest_s: float = 3.0,
                                            began: float | None = None) -> None:
    """The first hold-still's ring counts from the device's first readings as its time passes: read against the device
    time of the event the page last handled (each sample's last value), it is never behind the time since the rest
    began by more than the first calm readings take (it stood at 0 for 1.1-1.4 s of device time, waiting for the stage
    detector, then jumped to 46 %), and never moves further than the device time since the sample before it allows
    (``rest_s``: the rest asked for), until it first drops (a moving device restarts it).

    ``began``: for a page that followed the session from its address, the rest's beginning as the page that started
    it saw it (``first_rest_began``): a follower may join mid-rest or after it (a second tablet opened late), and is
    held from then on to the rest's own time, not to the moment it joined (a ring that started again from 0 there
    would stand behind). Without it the page watched from the start and must have shown the rest at five moments,
    unless it could not have (``_page_could_not_sample``)."""
    still = _first_rest(samples)
    if began is None and len(still) < 5:
        assert _page_could_not_sample(samples), (
            "the first rest shown at too few moments, the page sampling every 100 ms all along (page ms, state:phase, "
            f"notice, device s, %): {[(s[0], s[1], s[2][:40], s[6], s[5]) for s in samples if s[1].startswith('still:')]}")
    if not still:
        return
    t0 = still[0][0] if began is None else min(began, still[0][0])
    shown = []
    for (t_before, p_before), (t, p) in zip([still[0]] + still, still, strict=False):
        if p < p_before:
            break
        shown.append((round(t - t0, 2), p))
        behind = min(100.0, 100.0 * (t - t0 - FIRST_CALM_S) / rest_s) - p
        assert behind <= RING_SLACK, f"the first rest's ring stood behind the device's time: {shown[-30:]} (device s, %)"
        jump = p - p_before - 100.0 * (t - t_before) / rest_s
        assert jump <= RING_SLACK, f"the first rest's ring jumped: {shown[-30:]} (device s, %)"


def assert_rests_after_turns_count_from_the_stop(samples: list[list[Any]], at_least: int = 3) -> None:
    """After each turn the rest's ring appears as the device is put down and counts from its stop: the first value
    each rest's ring shows is a small one (it appeared 39-45 % full once the turn was being checked, the device put
    down 1.2-1.4 s of device time before)."""
    firsts: list[tuple[str, int]] = []
    before = None
    for s in samples:
        state, _, phase = s[1].partition(":")
        resting = state.startswith("turn_") and phase in ("placing", "checking", "pause") and s[5] is not None
        if resting and before != state:
            firsts.append((s[1], s[5]))
        before = state if resting else None
    assert len(firsts) >= at_least, firsts
    late = [f for f in firsts if f[1] > 25]
    assert not late, f"a rest's ring first appeared well along (state:phase, %): {late} of {firsts}"


def assert_every_moment_held(seen: dict[str, Any], phone: bool, turns: int = 3, rest_began: float | None = None) -> None:
    """The page's moments as a clinician must be able to rely on them, at every sample of a whole session
    (``Wizard.record``'s ``seen``; ``phone``: a 390x844 screen; ``turns``: rests after a turn at least): every retry
    reason stays until its turn starts, the rings count from the device's first reading and from each turn's stop
    without a jump, a turn shown done is taken back only by a result that asks it again and says so on its tile
    ("again"), and on a phone Cancel, the ring or gauge and the tiles are on the first screen. ``rest_began``: for a
    page that followed the session, when its first rest began (``assert_first_rest_counts_without_a_jump``)."""
    samples = seen["samples"]
    assert_retry_reasons_stay(samples, at_least=0)
    assert_first_rest_counts_without_a_jump(samples, began=rest_began)
    assert_rests_after_turns_count_from_the_stop(samples, at_least=turns)
    assert_done_never_undone(seen["done"], again=seen["again"])
    if phone:
        assert seen["offScreen"] == [], seen["offScreen"]
