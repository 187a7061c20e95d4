"""The rotation clipped readings hid, as the diagnosis fits it: each plateau (calib.stages.plateaus) topped by a
parabolic cap, m = FS + h (1 - u^2), u in [-1, 1] across the plateau, whose height h the fit estimates from the
prior the plateau's edges give."""

from __future__ import annotations

import numpy as np

from calib.stages.plateaus import Plateau


def plateau_caps(n: int, t: np.ndarray, plateaus: list[Plateau]) -> np.ndarray:
    """(n, C) signed cap shapes: reading change per unit of cap height, nonzero on each plateau."""
    caps = np.zeros((n, len(plateaus)))
    tt = t - t[0]
    dt = float(np.median(np.diff(tt))) if n > 1 else 1.0
    for c, p in enumerate(plateaus):
        a, b = p.start, p.end
        centre = 0.5 * (tt[a] + tt[b - 1])
        half = 0.5 * (float(tt[b - 1] - tt[a]) + dt)
        u = (tt[a:b] - centre) / half
        caps[a:b, c] = p.sign * (1.0 - u * u)
    return caps
