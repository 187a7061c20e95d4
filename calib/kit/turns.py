"""A kit's turns on one wearable's samples: which turns a guidance took or sections label, as spans of its stamps, and
in which of its stages the wearable lost samples."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from calib.io.section import Section
from calib.recording import Recording
from calib.stages.stage import Stage

GAP_STEPS = 1.5  # an interval this many times the usual one is samples lost


def gaps(t: np.ndarray) -> np.ndarray:
    """Which intervals of stamps ``t`` (n - 1 of them) span samples lost."""
    step = np.diff(t)
    return np.asarray(step > GAP_STEPS * np.median(step))


def turn_spans(rec: Recording, stages: Sequence[Stage]) -> list[tuple[float, float]]:
    """The turns among ``stages`` as spans of ``rec``'s stamps (s, first and last sample): the turns a wearable's
    guidance took (or its labelled sections hold), as ``calibrate_kit``'s ``turns_kept`` takes them."""
    return [(float(rec.t[st.start]), float(rec.t[min(st.end, len(rec)) - 1])) for st in stages if st.kind == "turn"]


def labelled_turns(rec: Recording, sections: tuple[Section, ...] | None) -> list[tuple[float, float]] | None:
    """The turns a recording's labelled sections (given, else its own: ``rec.meta.sections``) hold, as spans of its
    stamps; None when it has none."""
    sections = sections if sections is not None else rec.meta.sections
    if not sections:
        return None
    from calib.io.sections import stages_from_sections

    return turn_spans(rec, stages_from_sections(rec, sections))


def lost_in(stages: list[Stage], t: np.ndarray) -> list[bool]:
    """For each stage, whether the wearable whose stamps are ``t`` (s) lost samples within it or right after its last
    sample."""
    lost = gaps(t)
    return [bool(lost[st.start:st.end].any()) for st in stages]
