"""Every estimator, named once: what ``calibrate(method=...)``, the command line's ``--method``, the service's
``method`` and the paper's simulation study (``gyrocal bench paper-sim``) choose from. An estimator is a function
``(recording, stages=None) -> CalibrationResult``; one that can also fit many simulated recordings at once names its
batch function ``(SimBatch) -> (k, b[, {per-run arrays}])``. Each module is imported on first use, so the estimators
stay independent. Adding an estimator: its module in ``calib/estimators/`` and one line here."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from importlib import import_module
from typing import Any

from calib.errors import GyrocalError

BatchFn = Callable[[Any], Any]


@dataclass(frozen=True)
class Estimator:
    """Where an estimator lives: ``module:function`` for one recording, and for many simulated ones at once."""

    one: str
    batch: str | None = None


ESTIMATORS: dict[str, Estimator] = {
    "closure": Estimator("calib.estimators.closure.estimator:calibrate_closure", "calib.estimators.closure.batch:closure_batch"),
    "paper": Estimator("calib.estimators.paper:calibrate_paper", "calib.estimators.paper_batch:paper_batch"),
    "ferraris": Estimator("calib.estimators.ferraris:calibrate_ferraris"),
}
DEFAULT_METHOD = "closure"
_BATCH_ADDED: dict[str, BatchFn] = {}  # batch estimators registered at run time (a study's stand-ins)


def _load(target: str) -> Callable[..., Any]:
    module, name = target.split(":")
    try:
        return getattr(import_module(module), name)
    except ImportError as exc:
        from calib.extras import install_hint

        raise GyrocalError(f"the estimator {target} cannot be loaded: {install_hint(exc)}") from None


def method_names() -> list[str]:
    """The names ``calibrate(method=...)`` accepts."""
    return list(ESTIMATORS)


def check_method(method: str) -> None:
    """GyrocalError naming the choices when no estimator is named ``method``."""
    if method not in ESTIMATORS:
        raise GyrocalError(f"unknown method {method!r}: choose one of {', '.join(ESTIMATORS)}")


def estimator(method: str) -> Callable[..., Any]:
    """The estimator named ``method``; GyrocalError naming the choices for an unknown one."""
    check_method(method)
    return _load(ESTIMATORS[method].one)


def batch_methods() -> list[str]:
    """The names of the estimators that fit many simulated recordings at once."""
    return [n for n, e in ESTIMATORS.items() if e.batch] + list(_BATCH_ADDED)


def register_batch_method(name: str, fn: BatchFn) -> None:
    """Make ``fn(batch) -> (k, b[, info])`` a batch estimator named ``name`` (with several workers the processes are
    forked, so a function registered before the study runs is available in them)."""
    _BATCH_ADDED[name] = fn


def batch_estimator(name: str) -> BatchFn:
    """The batch estimator named ``name``; GyrocalError naming the registered ones for an unknown one."""
    if name in _BATCH_ADDED:
        return _BATCH_ADDED[name]
    entry = ESTIMATORS.get(name)
    if entry is None or entry.batch is None:
        raise GyrocalError(f"unknown bench method {name!r}: registered methods are {', '.join(batch_methods())}")
    return _load(entry.batch)
