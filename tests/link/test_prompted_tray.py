"""The tray a prompt-following clinician turns (mock_device.prompted_kit): every wearable in it records the one motion
the hand decides from the kit's prompts, and what a wearable has streamed never changes when the hand acts later."""

from __future__ import annotations

import numpy as np

from calib.simulator import Still, Turn
from mock_device.hand import Act
from mock_device.prompted_kit import PromptedKitSource, PromptedTray

FS = 104.0
BATCH = 4  # samples per block, as a packet carries them


def _ready(axis: str) -> dict:
    return {"state": f"turn_{axis}", "phase": "ready", "axis": axis, "attempt": 1, "warnings": []}


def _stream(sources: list[PromptedKitSource], start: int, end: int) -> list[np.ndarray]:
    """Each wearable's gyro for samples start..end-1, streamed block by block in turn, as their links would."""
    out: list[list[np.ndarray]] = [[] for _ in sources]
    for i in range(start, end, BATCH):
        for d, src in enumerate(sources):
            out[d].append(src.block(i, min(i + BATCH, end)).gyro)
    return [np.concatenate(o) for o in out]


def test_every_wearable_records_the_turn_the_hand_makes_when_prompted_and_keeps_what_it_streamed() -> None:
    tray = PromptedTray(seed=7, n=3, hand="careful")
    sources = [PromptedKitSource(tray, d) for d in range(3)]
    for src in sources:
        src.prepare(FS)
    rest = _stream(sources, 0, int(3 * FS))  # 3 s at rest: nothing asked, nothing done
    for d, gyro in enumerate(rest):
        rate = tray.params[d].k * gyro + tray.params[d].b  # g = K m + b
        assert np.abs(rate).max() < 0.5, d
    tray.observe(_ready("x"))
    turned = _stream(sources, int(3 * FS), int(12 * FS))
    for d, gyro in enumerate(turned):
        angle = (tray.params[d].k * gyro + tray.params[d].b).sum(axis=0) / FS
        assert abs(abs(angle[0]) - 360.0) < 25.0 and np.abs(angle[1:]).max() < 40.0, (d, angle)
    # the hand turns again when asked: what every wearable streamed before stays what it reads for those samples
    tray.observe(_ready("y"))
    later = _stream(sources, int(12 * FS), int(20 * FS))
    assert all(np.abs(g).max() > 50.0 for g in later)
    assert tray.performance is not None
    for d in range(3):
        again = tray.performance.block(d, FS, 0, int(12 * FS)).gyro
        np.testing.assert_array_equal(again, np.concatenate([rest[d], turned[d]]))
    # one motion: the wearables' true rates agree in size at every instant (each through its own mounting)
    sizes = [np.linalg.norm(tray.params[d].k * g + tray.params[d].b, axis=1) for d, g in enumerate(turned)]
    moving = sizes[0] > 50.0
    assert moving.sum() > FS  # a second of the turn at least
    for d in (1, 2):
        lag = np.median(np.abs(sizes[d][moving] - sizes[0][moving]))
        assert lag < 25.0, (d, lag)  # their clocks start up to 0.5 s apart, so the same instant is not the same sample


def test_an_act_due_a_fraction_of_a_sample_into_the_rest_starts_on_the_next_sample_of_the_motion() -> None:
    # the hand's next act was due as its last one ended, which on the tray's motion (in whole samples) was 77 us
    # earlier: the plan took a rest of 0.03 samples between them, which the simulator refuses, and the wearable's
    # stream stopped there (the kit then waited 60 s for its data, and failed)
    tray = PromptedTray(seed=7, n=2, hand="careful")
    sources = [PromptedKitSource(tray, d) for d in range(2)]
    for src in sources:
        src.prepare(FS)
    _stream(sources, 0, int(2 * FS))
    performance = tray.performance
    assert performance is not None
    performance._perform(Act(2.5, (Turn("x", 360.0, duration_s=2.0), Still(0.05))))
    rest = performance._tray.tray.stages[-1]
    performance._perform(Act(rest.start_s + 7.7e-5, (Turn("y", 360.0, duration_s=2.0), Still(0.05))))
    turns = [st for st in performance._tray.tray.stages if st.kind == "turn"]
    assert len(turns) == 2 and 0 < turns[1].start_s - rest.start_s <= 1.0 / performance._tray.tray.fs + 1e-9
    moved = _stream(sources, int(2 * FS), int(9 * FS))
    for gyro in moved:
        assert np.abs(gyro[:, 0]).max() > 50.0 and np.abs(gyro[:, 1]).max() > 50.0
