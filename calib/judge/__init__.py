"""Judging a calibration: the tolerances, the device's history, a verification turn."""
