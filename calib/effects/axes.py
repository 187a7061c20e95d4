"""Errors of the sensor's axes: misalignment between them, and sensitivity to the specific force (g-sensitivity)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from calib.effects.base import Effect, SensorContext, SimulationConfigError, numbers_of, register_effect, usage_error
from calib.effects.spec import DrawContext, EffectSpec, MagnitudeRange, log_uniform, spread


@register_effect
@dataclass(frozen=True, eq=False)
class AxisMisalignment(Effect):
    """Non-orthogonal sensor axes: an upper-triangular K (the closure estimator's extended model).

    Model: g = K m + b with K = [[k_x, K_xy, K_xz], [0, k_y, K_yz], [0, 0, k_z]];
    ``off_diagonal`` = (K_xy, K_xz, K_yz), absolute entries of K (dimensionless, like k). A general
    cross-axis matrix is a rotation times this form, and the rotation of the sensor frame is not
    observable from the gyro alone, so the lower entries are 0. Readings: m = K^-1 (g - b).
    CLI value: ``KXY,KXZ,KYZ``, e.g. ``axis_misalignment=0.01,0.005,-0.008``.
    """

    name: ClassVar[str] = "axis_misalignment"
    usage: ClassVar[str] = "KXY,KXZ,KYZ (upper off-diagonal entries of K)"
    spec: ClassVar[EffectSpec] = EffectSpec(
        rank=1,
        equation="g = K m + b, K = [[k_x, K_xy, K_xz], [0, k_y, K_yz], [0, 0, k_z]]",
        parameters="K_xy, K_xz, K_yz (entries of K)",
        drawn=MagnitudeRange(
            0.003, 0.02, "", "largest off-diagonal entry of K",
            "cross-axis sensitivity +-1-2 % (MPU-6050, ICM-20948, LSM6DS3 datasheets); 0.0097 in the real imucal recording",
        ),
        reveal="add turns about axes between the sensor axes (e.g. with the device resting on an edge)",
        diagnosis_model="g = (K + U) m + b, U upper off-diagonal",
        diagnosis_parameters="K_xy, K_xz, K_yz",
        typical=0.008,  # cross-axis sensitivity ~1 %
        typical_text="0.8 % cross-axis coupling",
        distinguish="turns about axes between the sensor axes",
        model_params={"axis_misalignment": ("U_xy", "U_xz", "U_yz")},
    )
    off_diagonal: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        u = np.asarray(self.off_diagonal, dtype=float)
        if u.shape != (3,) or not np.all(np.isfinite(u)) or np.any(np.abs(u) >= 0.5):
            raise SimulationConfigError(
                f"AxisMisalignment.off_diagonal must be 3 numbers (K_xy, K_xz, K_yz) smaller than 0.5; got {self.off_diagonal!r}"
            )
        object.__setattr__(self, "off_diagonal", u)

    @classmethod
    def draw(cls, rng: np.random.Generator, ctx: DrawContext) -> tuple[AxisMisalignment, float]:
        mag = log_uniform(rng, cls.spec.drawn.low, cls.spec.drawn.high)
        return cls(spread(rng, mag)), mag

    @classmethod
    def from_text(cls, value: str) -> AxisMisalignment:
        v = numbers_of(value, cls)
        if len(v) != 3:
            raise usage_error(cls, value)
        return cls(np.asarray(v))

    def matrix(self, k: np.ndarray) -> np.ndarray:
        """K (3, 3) for the scale factors k (3,)."""
        K = np.diag(np.asarray(k, dtype=float))
        K[[0, 0, 1], [1, 2, 2]] = self.off_diagonal
        return K

    def on_sensor(self, m: np.ndarray, ctx: SensorContext, rng: np.random.Generator) -> np.ndarray:
        # m enters as diag(k)^-1 (g - b); the readings of the non-orthogonal sensor are K^-1 (g - b).
        return np.linalg.solve(self.matrix(ctx.k), (m * ctx.k).T).T


@register_effect
@dataclass(frozen=True, eq=False)
class GSensitivity(Effect):
    """Linear-acceleration sensitivity of the gyro (needs the accelerometer to be modelled).

    Model: g = K (m - G a) + b, i.e. readings m = K^-1 (g - b) + G a, with a the specific force in g
    (sensor axes; (0, 0, 1) lying flat) and G = ``matrix_dps_per_g`` (3, 3) in (deg/s of reading)/g,
    row = gyro axis, column = acceleration axis. At rest the term adds G a to the still readings,
    which the rest alone cannot tell from b; turns move a through other directions.
    CLI value: ``G`` (G = G I), ``GX,GY,GZ`` (diagonal) or 9 numbers row by row.
    """

    name: ClassVar[str] = "g_sensitivity"
    usage: ClassVar[str] = "G|GX,GY,GZ (diagonal)|9 numbers row-major ((deg/s)/g)"
    spec: ClassVar[EffectSpec] = EffectSpec(
        rank=2,
        equation="g = K (m - G a) + b",
        parameters="G (3x3, (deg/s)/g, row = gyro axis)",
        drawn=MagnitudeRange(
            0.02, 0.15, "(deg/s)/g", "largest entry of G",
            "linear-acceleration sensitivity 0.1 (deg/s)/g typical (MPU-6050/MPU-9250 datasheets); "
            "0.006 (deg/s)/g in the real imucal recording",
        ),
        reveal="record the accelerometer, and turn about horizontal axes and rest in several poses",
        diagnosis_model="g = K (m − G a) + b",
        diagnosis_parameters="G (3×3, (deg/s)/g)",
        typical=0.05,  # datasheets quote 0.1 typical
        typical_text="0.05 (deg/s)/g",
        distinguish="rests in several poses with different axes up, recorded with the accelerometer",
        model_params={"g_sensitivity": tuple(f"G_{a}{b}" for a in "xyz" for b in "xyz")},
    )
    matrix_dps_per_g: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

    @classmethod
    def draw(cls, rng: np.random.Generator, ctx: DrawContext) -> tuple[GSensitivity, float]:
        mag = log_uniform(rng, cls.spec.drawn.low, cls.spec.drawn.high)
        return cls(spread(rng, mag, (3, 3))), mag
    def __post_init__(self) -> None:
        G = np.asarray(self.matrix_dps_per_g, dtype=float)
        if G.shape == ():
            G = np.eye(3) * G
        elif G.shape == (3,):
            G = np.diag(G)
        elif G.shape == (9,):
            G = G.reshape(3, 3)
        if G.shape != (3, 3) or not np.all(np.isfinite(G)):
            raise SimulationConfigError(
                f"GSensitivity.matrix_dps_per_g must be a number, 3 numbers (diagonal) or a 3x3 matrix; got {self.matrix_dps_per_g!r}"
            )
        object.__setattr__(self, "matrix_dps_per_g", G)

    @classmethod
    def from_text(cls, value: str) -> GSensitivity:
        v = numbers_of(value, cls)
        if len(v) not in (1, 3, 9):
            raise usage_error(cls, value)
        return cls(np.asarray(v[0] if len(v) == 1 else v, dtype=float))

    def on_sensor(self, m: np.ndarray, ctx: SensorContext, rng: np.random.Generator) -> np.ndarray:
        return m + ctx.accel @ self.matrix_dps_per_g.T
