"""OpenVINS's IMU intrinsics (``kalibr_imu_chain.yaml``: ``Tw``, ``R_IMUtoGYRO``, ``Ta``, ``R_IMUtoACC``, ``Tg``) from a
gyrocal calibration with its accelerometer, and optionally a rest's noise.

OpenVINS corrects its readings as (docs/propagation-analytical.dox, "IMU Intrinsic Models"; the same in
ov_msckf/src/state/Propagator.cpp)

    a = R_ACCtoIMU Da (a_m - b_a),        w = R_GYROtoIMU Dw (w_m - b_g - Tg a),

Dw = Tw^-1 and Da = Ta^-1, R_GYROtoIMU = R_IMUtoGYRO^T, R_ACCtoIMU = R_IMUtoACC^T, rates in rad/s, specific force in
m/s^2. Its loader (ov_msckf/src/core/VioManagerOptions.h) keeps only the lower triangle of Dw and Da for the
"kalibr" model written here (upper for "rpng"), so each matrix must be lower triangular with the rest in the
rotation. gyrocal's model is g = K (m - G a) + b in deg/s with a = A (r - o) in g (calib.apply.correction), so

    R_ACCtoIMU Da = A  (QL: a rotation times a lower-triangular matrix),   b_a = 9.80665 o,
    R_GYROtoIMU Dw = K (QL),   b_g = -K^-1 b (rad/s),   Tg = G (pi/180) / 9.80665  ((rad/s)/(m/s^2)).

OpenVINS's biases are states it estimates online, not file entries: the file carries the matrices, and b_g, b_a
are in the header comment as the initial values to give it. The frames: OpenVINS's IMU frame is gyrocal's (the
frame its K and A map into).
"""

from __future__ import annotations

import numpy as np

from calib.apply.correction import Correction
from calib.errors import GyrocalError
from calib.noise.analysis import NoiseReport
from calib.units import DEG, STANDARD_GRAVITY


def ql(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """M = Q L with Q a rotation and L lower triangular with a positive diagonal (GyrocalError for a reflection)."""
    J = np.eye(3)[::-1]
    q, r = np.linalg.qr(np.asarray(M, float) @ J)
    Q, L = q @ J, J @ r @ J
    D = np.diag(np.sign(np.diag(L)))
    Q, L = Q @ D, D @ L
    if np.linalg.det(Q) < 0:
        raise GyrocalError("this matrix turns a right-handed frame into a left-handed one; OpenVINS's rotation cannot hold it")
    return Q, L


def _matrix(name: str, M: np.ndarray) -> str:
    return f"  {name}:\n" + "".join(f"    - [{', '.join(f'{v:.12g}' for v in row)}]\n" for row in M)


def openvins_imu_chain(correction: Correction, noise: NoiseReport | None = None, topic: str = "/imu0",
                       rate_hz: float | None = None, comment: str = "") -> str:
    """OpenVINS's kalibr_imu_chain.yaml with the calibration's intrinsics (and the rest's noise when given). A
    calibration without the accelerometer's model writes OpenVINS's own default for it (Ta = I, b_a = 0), and says so."""
    accel_calibrated = correction.A is not None and correction.o is not None
    A = correction.A if correction.A is not None else np.eye(3)
    o = correction.o if correction.o is not None and accel_calibrated else np.zeros(3)
    R_gyro_to_imu, Dw = ql(correction.K)
    R_acc_to_imu, Da = ql(A)
    G = np.zeros((3, 3)) if correction.G is None else correction.G
    b_g = -np.linalg.solve(correction.K, correction.b) * DEG
    b_a = o * STANDARD_GRAVITY
    lines = ["%YAML:1.0\n", f"# OpenVINS IMU intrinsics from gyrocal{': ' + comment if comment else ''}\n",
             "# w = R_GYROtoIMU Dw (w_m - b_g - Tg a), a = R_ACCtoIMU Da (a_m - b_a); Dw = Tw^-1, Da = Ta^-1\n",
             f"# initial biases: b_g = [{', '.join(f'{v:.9g}' for v in b_g)}] rad/s, "
             f"b_a = [{', '.join(f'{v:.9g}' for v in b_a)}] m/s^2\n"]
    if not accel_calibrated:
        lines.append("# the accelerometer was not calibrated with this gyroscope: Ta and R_IMUtoACC are OpenVINS's default (I)\n")
    lines += ["imu0:\n", "  T_i_b:\n"]
    lines += [f"    - [{', '.join('1.0' if i == j else '0.0' for j in range(4))}]\n" for i in range(4)]
    if noise is not None:
        from calib.exports.kalibr import kalibr_imu_yaml

        lines += [f"  {line}\n" for line in kalibr_imu_yaml(noise, topic, rate_hz).splitlines()
                  if line.split(":")[0] in ("accelerometer_noise_density", "accelerometer_random_walk",
                                            "gyroscope_noise_density", "gyroscope_random_walk")]
    else:
        lines.append("  # the noise entries (accelerometer_noise_density, ...) come from a rest: gyrocal noise REST.csv\n")
    rate = rate_hz if rate_hz is not None else (noise.sample_rate_hz if noise is not None else None)
    lines += [f"  rostopic: {topic}\n", "  time_offset: 0.0\n"]
    if rate is not None:
        lines.append(f"  update_rate: {rate:g}\n")
    lines.append('  model: "kalibr"\n')
    lines += [_matrix("Tw", np.linalg.inv(Dw)), _matrix("R_IMUtoGYRO", R_gyro_to_imu.T), _matrix("Ta", np.linalg.inv(Da)),
              _matrix("R_IMUtoACC", R_acc_to_imu.T), _matrix("Tg", G * DEG / STANDARD_GRAVITY)]
    return "".join(lines)
