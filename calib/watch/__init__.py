"""Is the calibration still true? Answered from a recording made with it in force: its rests test the bias, its
re-orientations between rests (measured through gravity) test the scale factors, against the sensor's temperature when
the recording carries it."""

from calib.watch.report import WatchReport
from calib.watch.schema import WatchOut
from calib.watch.watch import watch

__all__ = ["WatchOut", "WatchReport", "watch"]
