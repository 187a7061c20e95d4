"""A kit of wearables turned together in one tray: their clocks aligned, their rigid coupling fitted, every one
calibrated from the kit's one motion (``calib.kit.estimator.calibrate_kit``)."""
