"""A calibration and a rest's noise written for the robotics tools: Kalibr's imu.yaml and OpenVINS's IMU intrinsics."""
