"""Each turn's closure as one wearable of the kit made it, with its own calibration and on its own samples."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from calib.kit.turns import lost_in
from calib.stages.stage import Stage


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
