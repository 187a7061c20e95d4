"""Reading recordings: CSV layouts, imu_tk's files, labelled sections, plausibility checks."""
