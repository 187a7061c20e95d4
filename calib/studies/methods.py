"""The paper's comparison of calibration methods (Tables 2-3), in simulation: ``gyrocal bench methods``.

The same simulated sensor (k and b as the paper's turntable measured its LSM9DS1 and ICM-20948, Tables 2-3)
is calibrated by six methods, each on a recording of its own protocol:

- turntable: the six-rate method (20, 50, 100 deg/s each way about each axis, 10 s runs, exact rates and
  mounting), ``calib.estimators.rate_table``;
- accelerometer-aided: the device on a plane inclined 0, 30 and 45 deg, turned in 90 deg steps between
  10 s rests (``inclined_script``), gyrocal's maximum-likelihood gravity-direction estimator
  (``calib.estimators.multi_position.estimator``, which fits the accelerometer too);
- servomotor: one rate (25.42 deg/s, the paper's) each way about each axis, 10 s runs; the servo's
  speed is off by up to 0.5 % and the fixture tilts the axis by up to 2 deg (assumed, not measured);
- ferraris: six static poses and three hand turns, Ferraris' closed-form equations (``calib.estimators.ferraris``);
- paper: the paper's protocol, its Algorithm 1 (``calib.estimators.paper``);
- gyrocal: the paper's protocol, gyrocal's closure estimator (``calib.estimators.closure.estimator``).

Hand turns are drawn as in the paper's simulation (axis tilt up to 0.1, wobble 0.5-3 deg); the accelerometer
reads with 5 mg noise through a random error (scale 0.97-1.03, offset +-50 mg, misalignment +-0.01 rad).
The turntable and servo runs start and stop smoothly; their estimator takes each run's mean rate as its
angle over its duration. Errors are against the simulated truth (the paper, lacking it, measured against
its turntable).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from calib.recording import Recording
from calib.result import CalibrationResult
from calib.simulator import SensorParams, Truth, simulate
from calib.simulator.lab_scripts import ferraris_script, inclined_script, rate_table_script, with_accelerometer_error
from calib.simulator.protocol import ProtocolScript, paper_protocol_script

PARAMS = ("kx", "ky", "kz", "bx", "by", "bz")
# The paper's turntable results (Tables 2 and 3), used as the simulated sensors' true parameters.
SENSORS: dict[str, SensorParams] = {
    "LSM9DS1": SensorParams(np.array([1.2619, 1.1966, 1.1536]), np.array([-3.1275, 1.6312, -1.4655])),
    "ICM-20948": SensorParams(np.array([0.9822, 1.0183, 0.9788]), np.array([-0.5169, -1.4402, 1.0502])),
}
# What the paper reports for its real devices: protocol time (s) per method (Tables 2 and 3).
PAPER_TIME_S = {"LSM9DS1": {"paper": 27, "turntable": 1533, "accelerometer-aided": 570, "servomotor": 60},
                "ICM-20948": {"paper": 29, "turntable": 1495, "accelerometer-aided": 565, "servomotor": 60}}
FS = 104.0
TABLE_RATES = (20.0, 50.0, 100.0)
SERVO_RATE = 25.42
RUN_S = 10.0
SERVO_SPEED_ERROR = 0.005
SERVO_TILT = np.sin(np.radians(2.0))


@dataclass(frozen=True)
class Method:
    """One calibration method: its protocol, its estimator, the equipment it needs."""

    name: str
    equipment: str
    run: Callable[[int, SensorParams, float, np.random.Generator], tuple[CalibrationResult, Recording]]


def _table_runs(truth: Truth, rates: Sequence[float], run_s: float) -> list[Any]:
    """The runs as the table's controller knows them: where each starts and stops, and its angle."""
    from calib.estimators.rate_table import RateRun

    turns = [s for s in truth.stages if s.kind == "turn"]
    commanded = [(axis, sign * r * run_s) for axis in "xyz" for r in rates for sign in (1.0, -1.0)]
    return [RateRun(s.start, s.end, axis, angle / ((s.end - s.start) / FS))
            for s, (axis, angle) in zip(turns, commanded, strict=True)]


def _turntable(seed: int, params: SensorParams, noise: float, rng: np.random.Generator) -> tuple[CalibrationResult, Recording]:
    from calib.estimators.rate_table import calibrate_rate_table

    rec, truth = simulate(seed, noise, FS, params, rate_table_script(TABLE_RATES, RUN_S))
    return calibrate_rate_table(rec, _table_runs(truth, TABLE_RATES, RUN_S)), rec


def _servomotor(seed: int, params: SensorParams, noise: float, rng: np.random.Generator) -> tuple[CalibrationResult, Recording]:
    from calib.estimators.rate_table import calibrate_rate_table

    true_rate = SERVO_RATE * (1.0 + rng.uniform(-SERVO_SPEED_ERROR, SERVO_SPEED_ERROR))
    tilt = rng.uniform(-SERVO_TILT, SERVO_TILT, (3, 2))
    rec, truth = simulate(seed, noise, FS, params, rate_table_script((true_rate,), RUN_S, tilt=tilt))
    return calibrate_rate_table(rec, _table_runs(truth, (SERVO_RATE,), RUN_S)), rec


def _hand(script: Callable[[np.random.Generator], ProtocolScript], estimator: Callable[[Recording], CalibrationResult]) -> Callable:
    def run(seed: int, params: SensorParams, noise: float, rng: np.random.Generator) -> tuple[CalibrationResult, Recording]:
        rec, _ = simulate(seed, noise, FS, params, script(rng))
        rec, _ = with_accelerometer_error(rec, rng)
        return estimator(rec), rec

    return run


def _estimator(module: str, name: str) -> Callable[[Recording], CalibrationResult]:
    from importlib import import_module

    return lambda rec: getattr(import_module(module), name)(rec)


METHODS: tuple[Method, ...] = (
    Method("turntable", "high-precision turntable", _turntable),
    Method("accelerometer-aided", "accelerometer, inclined plane",
           _hand(inclined_script, _estimator("calib.estimators.multi_position.estimator", "calibrate_multi_position"))),
    Method("servomotor", "servomotor", _servomotor),
    Method("ferraris", "none (a table's edge)", _hand(ferraris_script, _estimator("calib.estimators.ferraris", "calibrate_ferraris"))),
    Method("paper", "none", _hand(paper_protocol_script, _estimator("calib.estimators.paper", "calibrate_paper"))),
    Method("gyrocal", "none", _hand(paper_protocol_script, _estimator("calib.estimators.closure.estimator", "calibrate_closure"))),
)


@dataclass
class MethodsReport:
    """Errors (estimate - truth) of every method on every sensor and noise level."""

    runs: int
    noise_levels: tuple[float, ...]
    errors: dict[tuple[str, str, float], np.ndarray] = field(default_factory=dict)  # (sensor, method, noise) -> (runs, 6)
    duration_s: dict[tuple[str, str, float], float] = field(default_factory=dict)
    failures: dict[tuple[str, str, float], list[str]] = field(default_factory=dict)
    seconds: float = 0.0
    plot_path: str | None = None

    def rows(self) -> list[dict[str, Any]]:
        """One row per (sensor, noise, method): median and p95 |error| per parameter, protocol time, equipment."""
        out = []
        for (sensor, method, noise), err in self.errors.items():
            a = np.abs(err)
            eq = next(m.equipment for m in METHODS if m.name == method)
            out.append({
                "sensor": sensor, "noise_dps": noise, "method": method, "equipment": eq, "runs": int(len(err)),
                "failed": len(self.failures.get((sensor, method, noise), [])),
                "median_abs_error": dict(zip(PARAMS, np.median(a, axis=0).tolist(), strict=True)) if len(a) else None,
                "p95_abs_error": dict(zip(PARAMS, np.percentile(a, 95, axis=0).tolist(), strict=True)) if len(a) else None,
                "protocol_s": self.duration_s.get((sensor, method, noise)),
                "paper_time_s": PAPER_TIME_S.get(sensor, {}).get(method),
            })
        return out

    def table(self) -> str:
        """Tables in the shape of the paper's Tables 2-3: median |error| per parameter, time, equipment."""
        lines = []
        for sensor in SENSORS:
            for noise in self.noise_levels:
                rows = [r for r in self.rows() if r["sensor"] == sensor and r["noise_dps"] == noise]
                if not rows:
                    continue
                lines.append(f"{sensor}-like sensor, noise {noise:g} deg/s: median |estimate - truth| over {self.runs} runs")
                lines.append(f"{'parameter':<12}" + "".join(f"{r['method']:>21}" for r in rows))
                for j, p in enumerate(PARAMS):
                    cells = "".join(f"{(r['median_abs_error'] or {}).get(p, float('nan')):>21.5f}" for r in rows)
                    lines.append(f"{p + (' (deg/s)' if j >= 3 else ''):<12}{cells}")
                lines.append(f"{'time (s)':<12}" + "".join(f"{r['protocol_s'] or float('nan'):>21.0f}" for r in rows))
                lines.append(f"{'paper (s)':<12}" + "".join(f"{r['paper_time_s'] if r['paper_time_s'] else '-':>21}" for r in rows))
                lines.append(f"{'equipment':<12}" + "".join(f"{r['equipment'][:20]:>21}" for r in rows))
                failed = [f"{r['method']}: {r['failed']}" for r in rows if r["failed"]]
                if failed:
                    lines.append("refused runs: " + ", ".join(failed))
                lines.append("")
        lines.append(f"{self.seconds:.0f} s")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready report."""
        return {"runs": self.runs, "noise_levels": list(self.noise_levels), "rows": self.rows(),
                "failures": {f"{s}/{m}/{n:g}": v[:5] for (s, m, n), v in self.failures.items() if v},
                "seconds": self.seconds, "plot": self.plot_path}

    def plot(self, path: str | Path) -> Path:
        """Median |error| per parameter and method (log scale), one panel per sensor and noise level, with each
        method's protocol time in the legend."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        path = Path(path)
        panels = [(s, n) for s in SENSORS for n in self.noise_levels]
        fig, axes = plt.subplots(len(panels), 2, figsize=(13, 3.4 * len(panels)), squeeze=False)
        width = 0.8 / len(METHODS)
        for row, (sensor, noise) in enumerate(panels):
            rows = {r["method"]: r for r in self.rows() if r["sensor"] == sensor and r["noise_dps"] == noise}
            for col, names in enumerate((PARAMS[:3], PARAMS[3:])):
                ax = axes[row][col]
                for mi, m in enumerate(METHODS):
                    r = rows.get(m.name)
                    if not r or not r["median_abs_error"]:
                        continue
                    pos = np.arange(3) + (mi - (len(METHODS) - 1) / 2) * width
                    med = [r["median_abs_error"][p] for p in names]
                    p95 = [r["p95_abs_error"][p] for p in names]
                    ax.bar(pos, med, width * 0.9, label=f"{m.name} ({r['protocol_s']:.0f} s)")
                    ax.plot(pos, p95, "k_", ms=6)
                ax.set_yscale("log")
                ax.set_xticks(np.arange(3))
                ax.set_xticklabels(names)
                ax.set_ylabel("|error|" + (" (deg/s)" if col else ""))
                ax.set_title(f"{sensor}-like, noise {noise:g} deg/s: {'scale factors' if col == 0 else 'biases'}")
        handles, labels = axes[0][0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=8, title="method (protocol duration)")
        fig.suptitle(f"Calibration methods on the same simulated sensors: median |error| (bars) and p95 (ticks), {self.runs} runs")
        fig.tight_layout(rect=(0, 0.05, 1, 1))
        from calib.plots import save_figure

        self.plot_path = str(save_figure(fig, path, dpi=100))
        return Path(self.plot_path)


def compare_methods(runs: int = 20, noise_levels: Sequence[float] = (0.03, 0.15), seed: int = 0, progress: bool = True,
                    plot_path: str | Path | None = None, methods: Sequence[str] | None = None) -> MethodsReport:
    """Run every method ``runs`` times on each sensor and noise level; the same seeds for every method."""
    from tqdm import tqdm

    from calib.errors import GyrocalError

    chosen = [m for m in METHODS if methods is None or m.name in methods]
    report = MethodsReport(runs, tuple(noise_levels))
    t0 = time.perf_counter()
    total = len(SENSORS) * len(noise_levels) * len(chosen) * runs
    with tqdm(total=total, file=sys.stderr, disable=not progress, desc="methods", unit="run") as bar:
        for si, (sensor, params) in enumerate(SENSORS.items()):
            for ni, noise in enumerate(noise_levels):
                for m in chosen:
                    errs, durations, failed = [], [], []
                    for i in range(runs):
                        run_seed = int(np.random.SeedSequence([seed, si, ni, i]).generate_state(1)[0] % 2**31)
                        rng = np.random.default_rng([seed, si, ni, i, 1])
                        try:
                            res, rec = m.run(run_seed, params, noise, rng)
                            errs.append(np.concatenate([res.k - params.k, res.b - params.b]))
                            durations.append(rec.duration_s)
                        except GyrocalError as exc:
                            failed.append(str(exc))
                        bar.update()
                    key = (sensor, m.name, noise)
                    report.errors[key] = np.array(errs).reshape(-1, 6)
                    report.duration_s[key] = float(np.median(durations)) if durations else float("nan")
                    report.failures[key] = failed
    report.seconds = time.perf_counter() - t0
    if plot_path is not None:
        report.plot(plot_path)
    return report
