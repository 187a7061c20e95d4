"""The multi-position estimator: re-orientations between rests, the accelerometer as reference."""
