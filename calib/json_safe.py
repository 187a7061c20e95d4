"""JSON has no NaN or infinity: one function that makes any result JSON-safe."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def finite(o: Any) -> Any:
    """A copy with NaN and infinities replaced by None and numpy values by plain Python ones."""
    kind = type(o)  # the plain types first, by identity: a live snapshot walks some seventy values twenty times a second
    if kind is str or kind is int or kind is bool or o is None:
        return o
    if kind is float:
        return o if math.isfinite(o) else None
    if kind is dict:
        return {k: finite(v) for k, v in o.items()}
    if kind is list or kind is tuple:
        return [finite(v) for v in o]
    if isinstance(o, np.generic):
        return finite(o.item())
    if isinstance(o, float):
        return o if math.isfinite(o) else None
    if isinstance(o, dict):
        return {k: finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [finite(v) for v in o]
    if isinstance(o, np.ndarray):
        return finite(o.tolist())
    return o
