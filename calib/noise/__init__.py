"""The sensor's noise as the recording shows it: at rest, while moving, the accelerometer's floor."""
