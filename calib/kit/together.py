"""Whether a kit's wearables turned together, and which one did not.

A wearable left on the table beside the tray, or switched off part-way, records no motion the others' explain: the
rigid coupling finds nothing of the tray's motion in its readings. The kit cannot vouch for it, but neither should it
fail the others: of three or more, the one that follows none of the others is left out and the rest calibrated. Of
two, the kit cannot be calibrated; the one that never turned is named when its readings show it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from calib.errors import KitRefusal
from calib.kit.clocks import activity, coarse_clock
from calib.kit.coupling import Coupling, couple, reading_noise
from calib.recording import Recording

ONE_MOTION_SHARE = 0.99  # the least share of a wearable's motion the coupling must explain for one kit's recordings
TURNED_DPS = 20.0  # a wearable whose rate never reached this (its 99th percentile, deg/s) was not turned at all


def check_one_motion(coupling: Coupling, ref: str, wearable: str) -> None:
    """KitRefusal when ``wearable`` does not follow ``ref``'s motion at all (another session's recording, or a wearable
    left out of the tray): a wearable that slipped in its slot still follows it, to a fraction of a percent of the
    motion."""
    y = coupling.readings[np.all(np.isfinite(coupling.readings), axis=1)]
    explained = 1.0 - float(np.sum(coupling.map.residual_sd**2) / np.sum(y.var(axis=0)))
    if explained < ONE_MOTION_SHARE:
        raise KitRefusal(f"{wearable} does not follow {ref}'s motion (the rigid coupling explains "
                         f"{max(explained, 0.0):.0%} of it): the recordings are not of one kit turned together; give "
                         "one recording per wearable of the same session", wearable=wearable, reference=ref)


def follows(ref: Recording, rec: Recording, names: tuple[str, str], ref_noise: np.ndarray | None = None,
            clock_run: np.ndarray | None = None) -> Coupling:
    """``rec`` coupled to ``ref`` (``names``: theirs, ref's first; ``ref_noise``: ref's reading noise, when known;
    ``clock_run``: as for ``calib.kit.coupling.couple``); KitRefusal when it does not follow ref's motion."""
    noise = reading_noise(ref) if ref_noise is None else ref_noise
    coupling = couple(ref, rec, coarse_clock(ref, rec, names=names), noise, clock_run)
    check_one_motion(coupling, *names)
    return coupling


def turned(rec: Recording) -> bool:
    """Whether the wearable was turned at all: its rate reached ``TURNED_DPS``."""
    return bool(np.percentile(activity(rec), 99) >= TURNED_DPS)


def odd_one_out(recordings: Sequence[Recording], names: Sequence[str], members: Sequence[int],
                refused: KitRefusal) -> int | None:
    """Of ``members`` (three or more), the one that did not turn with the others, given the refusal that named a pair
    (``refused.wearable`` against ``refused.reference``): the named one, unless it follows a third wearable, when the
    one it was compared with is. None when the pair is not known, or fewer than three are left."""
    if len(members) < 3 or refused.wearable not in names or refused.reference not in names:
        return None
    w, r = names.index(refused.wearable), names.index(refused.reference)
    third = next(i for i in members if i not in (w, r))
    try:
        follows(recordings[third], recordings[w], (names[third], names[w]))
    except KitRefusal:
        return w
    return r


def refusal_of_two(recordings: Sequence[Recording], names: Sequence[str], pair: Sequence[int],
                   refused: KitRefusal) -> KitRefusal:
    """Two wearables left of a kit (``pair``) that did not turn together: the one that was not turned at all named,
    when only one was not."""
    still = [i for i in pair if not turned(recordings[i])]
    if len(pair) != 2 or len(still) != 1:
        return refused
    w = still[0]
    r = next(i for i in pair if i != w)
    return KitRefusal(f"{names[w]} was not turned with {names[r]} (its readings show no turn at all): the recordings "
                      "are not of one kit turned together; give one recording per wearable of the same session",
                      wearable=names[w], reference=names[r])
