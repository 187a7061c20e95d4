"""The CalibrationResult type: everything a user needs to judge and use one calibration."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from calib.json_safe import finite
from calib.quality import Quality
from calib.stages.stage import Stage

if TYPE_CHECKING:
    from calib.result_schema import ResultDoc


def _list(a: np.ndarray | None, digits: int = 9) -> list[float] | None:
    return None if a is None else [round(float(v), digits) for v in np.ravel(a)]


FORMAT_VERSION = 2  # the form of to_dict(): calib.result_schema.ResultDoc says what each number meant


def _nullable_lists(convert: Callable[[float], float], **arrays: np.ndarray | None) -> dict[str, list[float | None]]:
    """The arrays given, each as a list of ``convert``-ed values with null where a value is not finite (a normal
    interval's infinite degrees of freedom, or a scale that is the standard error)."""
    return {name: [None if not np.isfinite(v) else convert(float(v)) for v in a] for name, a in arrays.items()
            if a is not None}


def _from_nullable(values: Any, missing: float) -> np.ndarray | None:
    """A list of ``_nullable_lists`` back as an array, ``missing`` where it holds null."""
    return None if values is None else np.array([missing if v is None else float(v) for v in values])


@dataclass
class CalibrationResult:
    """Parameters of g = K m + b (K diagonal, or upper-triangular in the extended model).

    ``k`` are the scale factors (diagonal of K), ``b`` the biases in deg/s of true rate. ``G``, when the
    method fitted it, is the g-sensitivity of g = K (m - G a) + b ((deg/s)/g of reading, a the specific force).
    ``k_std``/``b_std`` are 1-sigma standard errors; ``k_bound``/``b_bound`` the Cramer-Rao
    bound for the recorded protocol, when the method provides them.
    """

    k: np.ndarray
    b: np.ndarray
    method: str
    stages: list[Stage]
    quality: Quality = field(default_factory=lambda: Quality())
    k_std: np.ndarray | None = None
    b_std: np.ndarray | None = None
    k_bound: np.ndarray | None = None
    b_bound: np.ndarray | None = None
    K: np.ndarray | None = None  # full 3x3 calibration matrix (extended model); None means diag(k)
    K_std: np.ndarray | None = None
    noise_dps: np.ndarray | None = None  # per-axis white-noise std estimated from the stills (deg/s)
    residuals: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    iterations: int | None = None
    sample_rate_hz: float | None = None  # of the recording it was computed from
    n_samples: int | None = None
    G: np.ndarray | None = None  # g-sensitivity (3, 3), (deg/s)/g; None: not part of the model
    G_std: np.ndarray | None = None
    # degrees of freedom of each k's and b's Student-t interval, where a variance rests on a spread learned from few
    # turns (the closure's heading); inf: normal. None: normal throughout
    k_dof: np.ndarray | None = None
    b_dof: np.ndarray | None = None
    # the scale of each k's and b's Student-t interval where it is not its standard error: where that interval's width
    # is drawn from the heading spreads few turns allow (calib.estimators.closure.fiducial); NaN or None: the std
    k_interval_scale: np.ndarray | None = None
    b_interval_scale: np.ndarray | None = None

    def interval(self, level: float = 0.95) -> tuple[np.ndarray, np.ndarray] | None:
        """The (3, 2) intervals of k and of b holding the truth with probability ``level``: value ± the Student-t
        quantile of each one's degrees of freedom (normal where none is given) times its interval's scale (its
        standard error where none is given)."""
        if self.k_std is None or self.b_std is None:
            return None
        from calib.distributions import t_isf

        def around(value: np.ndarray, std: np.ndarray, dof: np.ndarray | None, scale: np.ndarray | None) -> np.ndarray:
            q = t_isf((1.0 - level) / 2.0, np.full(3, np.inf) if dof is None else dof)
            s = std if scale is None else np.where(np.isfinite(scale), scale, std)
            return np.stack((value - q * s, value + q * s), axis=-1)

        return (around(self.k, self.k_std, self.k_dof, self.k_interval_scale),
                around(self.b, self.b_std, self.b_dof, self.b_interval_scale))

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 calibration matrix K of g = K m + b."""
        return np.diag(self.k) if self.K is None else self.K

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CalibrationResult:
        """The result back from its ``to_dict()`` form (as the store keeps it), of this format version or any older one
        (``calib.result_schema``): ``from_dict(r.to_dict())`` gives the same ``to_dict()``. Unknown keys are ignored."""

        def arr(v: Any) -> np.ndarray | None:
            return None if v is None else np.asarray(v, dtype=float)

        unc, bound = d.get("uncertainty") or {}, d.get("bound") or {}
        K, K_std = d.get("K"), d.get("K_std")
        return cls(
            k=np.asarray(d["k"], dtype=float),
            b=np.asarray(d["b"], dtype=float),
            method=str(d.get("method") or ""),
            stages=[Stage.from_dict(s) for s in d.get("stages") or []],
            quality=cast(Quality, dict(d.get("quality") or {})),  # as stored: every key optional, further keys kept
            k_std=arr(unc.get("k")),
            b_std=arr(unc.get("b")),
            k_bound=arr(bound.get("k")),
            b_bound=arr(bound.get("b")),
            K=arr(K),
            K_std=arr(K_std),
            noise_dps=arr(d.get("noise_dps")),
            residuals=dict(d.get("residuals") or {}),
            warnings=list(d.get("warnings") or []),
            iterations=d.get("iterations"),
            sample_rate_hz=d.get("sample_rate_hz"),
            n_samples=d.get("n_samples"),
            G=arr(d.get("G")),
            G_std=arr(d.get("G_std")),
            k_dof=_from_nullable(unc.get("k_dof"), np.inf),
            b_dof=_from_nullable(unc.get("b_dof"), np.inf),
            k_interval_scale=_from_nullable(unc.get("k_interval_scale"), np.nan),
            b_interval_scale=_from_nullable(unc.get("b_interval_scale"), np.nan),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form with keys k, b, method, stages, quality, uncertainty, bound, ..."""
        out: dict[str, Any] = {
            "format_version": FORMAT_VERSION,
            "k": _list(self.k),
            "b": _list(self.b),
            "method": self.method,
            "stages": [s.to_dict() for s in self.stages],
            "quality": self.quality,
            "uncertainty": None if self.k_std is None else {"k": _list(self.k_std, 12), "b": _list(self.b_std, 12),
                                                            **_nullable_lists(lambda v: round(v, 3), k_dof=self.k_dof,
                                                                              b_dof=self.b_dof),
                                                            **_nullable_lists(lambda v: float(f"{v:.12g}"),
                                                                              k_interval_scale=self.k_interval_scale,
                                                                              b_interval_scale=self.b_interval_scale)},
            "bound": None if self.k_bound is None else {"k": _list(self.k_bound, 12), "b": _list(self.b_bound, 12)},
            "noise_dps": _list(self.noise_dps),
            "residuals": self.residuals,
            "warnings": list(self.warnings),
            "iterations": self.iterations,
        }
        if self.K is not None:
            out["K"] = [_list(row) for row in self.K]
            out["K_std"] = None if self.K_std is None else [_list(row, 12) for row in self.K_std]
        if self.G is not None:
            out["G"] = [_list(row) for row in self.G]
            out["G_std"] = None if self.G_std is None else [_list(row, 12) for row in self.G_std]
        if self.sample_rate_hz is not None:
            out["sample_rate_hz"] = float(self.sample_rate_hz)
        if self.n_samples is not None:
            out["n_samples"] = int(self.n_samples)
        return out

    def to_json(self) -> dict[str, Any]:
        """``to_dict()`` made JSON-safe (NaN and infinities as null): the form the service shows and stores."""
        return finite(self.to_dict())

    def to_doc(self) -> ResultDoc:
        """The JSON form as its typed schema (``calib.result_schema.ResultDoc``)."""
        from calib.result_schema import ResultDoc

        return ResultDoc.model_validate(self.to_json())
