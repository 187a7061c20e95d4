"""Readers of the robotics tools' files, written from each tool's documented format (not from gyrocal's writers):
Kalibr's imu.yaml (its wiki, "IMU Noise Model", github.com/ethz-asl/kalibr/wiki/IMU-Noise-Model) and OpenVINS's
kalibr_imu_chain.yaml (docs/propagation-analytical.dox, and its loader ov_msckf/src/core/VioManagerOptions.h)."""

from __future__ import annotations

import re

import numpy as np
import yaml


def read_kalibr_imu(text: str) -> dict[str, float | str]:
    """Kalibr's imu.yaml as Kalibr reads it: six keys, the noise in SI units."""
    d = yaml.safe_load(text)
    keys = {"accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density", "gyroscope_random_walk",
            "rostopic", "update_rate"}
    assert keys <= set(d), keys - set(d)
    return d


def read_openvins(text: str) -> dict[str, np.ndarray]:
    """OpenVINS's loader: the %YAML:1.0 directive is OpenCV's (dropped here), Dw = Tw^-1 and Da = Ta^-1 keep only their
    lower triangle for the kalibr model, R_GYROtoIMU = R_IMUtoGYRO^T, R_ACCtoIMU = R_IMUtoACC^T, Tg as it is."""
    assert text.startswith("%YAML:1.0\n")
    imu = yaml.safe_load(text.split("\n", 1)[1])["imu0"]
    assert imu["model"] == "kalibr"
    m = {k: np.asarray(imu[k], float) for k in ("Tw", "R_IMUtoGYRO", "Ta", "R_IMUtoACC", "Tg")}
    biases = re.search(r"b_g = \[([^\]]+)\] rad/s, b_a = \[([^\]]+)\] m/s\^2", text)
    assert biases
    return {"Dw": np.tril(np.linalg.inv(m["Tw"])), "Da": np.tril(np.linalg.inv(m["Ta"])), "R_GYROtoIMU": m["R_IMUtoGYRO"].T,
            "R_ACCtoIMU": m["R_IMUtoACC"].T, "Tg": m["Tg"],
            "b_g": np.array([float(v) for v in biases.group(1).split(",")]),
            "b_a": np.array([float(v) for v in biases.group(2).split(",")])}


def openvins_correct(ov: dict[str, np.ndarray], w_m: np.ndarray, a_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenVINS's correction (rad/s, m/s^2): a = R_ACCtoIMU Da (a_m - b_a), w = R_GYROtoIMU Dw (w_m - b_g - Tg a)."""
    a = (a_m - ov["b_a"]) @ (ov["R_ACCtoIMU"] @ ov["Da"]).T
    w = (w_m - ov["b_g"] - a @ ov["Tg"].T) @ (ov["R_GYROtoIMU"] @ ov["Dw"]).T
    return w, a
