"""Using a calibration: correcting recordings, their orientation, which sensor it belongs to."""
