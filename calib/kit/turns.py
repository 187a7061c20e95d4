"""Each turn's closure as one wearable of the kit made it, with its own calibration and on its own samples."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from calib.io.section import Section
from calib.kit.clocks import gaps
from calib.recording import Recording
from calib.stages.stage import Stage


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


def member_turn_rows(rows: list[dict[str, Any]], stages: list[Stage], attitude: Rotation, mount: np.ndarray,
                     t: np.ndarray) -> list[dict[str, Any]]:
    """The kit's turn rows (``calib.estimators.closure.report``) redone for one wearable: ``stages`` are the kit's on
    its samples ``t`` (s), ``attitude`` its calibrated attitude after each sample, ``mount`` its axes from the
    reference's (which carries the tray's placement, measured in the reference's axes, into its own). A turn in which
    the wearable lost samples cannot be closed on its own: the kit's closure, in its axes, stands (``bridged_by_kit``)."""
    lost = lost_in(stages, t)
    out = []
    for row in rows:
        row = dict(row)
        index = row.get("stage")
        if index is None or not 0 <= int(index) < len(stages):
            out.append(row)
            continue
        st = stages[int(index)]
        if lost[int(index)]:
            kit_closure = mount @ np.asarray(row.get("closure_deg") or np.zeros(3), dtype=float)
            kit_miss = mount @ np.asarray(row.get("misclosure_deg") or np.zeros(3), dtype=float)
            row.update({"start_s": st.start_s, "end_s": st.end_s, "samples": st.n, "bridged_by_kit": True,
                        "closure_deg": [float(v) for v in kit_closure], "misclosure_deg": [float(v) for v in kit_miss],
                        "placement_deg": [float(v) for v in mount @ np.asarray(row.get("placement_deg") or np.zeros(3))]})
            out.append(row)
            continue
        before = attitude[st.start - 1] if st.start > 0 else Rotation.identity()
        closure = np.degrees((before.inv() * attitude[st.end - 1]).as_rotvec())
        placement = mount @ np.asarray(row.get("placement_deg") or np.zeros(3), dtype=float)
        miss = closure - placement
        row.update({
            "start_s": st.start_s, "end_s": st.end_s, "samples": st.n,
            "closure_deg": [float(v) for v in closure], "closure_norm_deg": float(np.linalg.norm(closure)),
            "placement_deg": [float(v) for v in placement],
            "misclosure_deg": [float(v) for v in miss], "misclosure_norm_deg": float(np.linalg.norm(miss)),
        })
        out.append(row)
    return out
