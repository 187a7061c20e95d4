"""Is the calibration still true? Answered from a recording made with it in force: its rests test the bias, its
re-orientations between rests (measured through gravity) test the scale factors, against the sensor's temperature when
the recording carries it.

``watch`` and ``WatchReport`` are imported on first use: the service reads ``calib.watch.schema`` (pydantic only) at
start, and must not pull the numerics (scipy) in with it."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from calib.watch.schema import WatchOut

if TYPE_CHECKING:
    from calib.watch.report import WatchReport
    from calib.watch.run import watch

__all__ = ["WatchOut", "WatchReport", "watch"]


def __getattr__(name: str) -> Any:
    if name == "watch":
        from calib.watch.run import watch

        return watch
    if name == "WatchReport":
        from calib.watch.report import WatchReport

        return WatchReport
    raise AttributeError(f"module 'calib.watch' has no attribute {name!r}")
