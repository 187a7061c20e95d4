"""The paper's simulation study (Section 3, Fig. 7): parameter errors over many simulated runs.

30 parameter sets (k ~ U(0.8, 1.2), b ~ U(-5, 5) deg/s) x 500 runs each, at 0.03 and 0.15 deg/s
noise, each run a simulated recording of the protocol (calib.simulator.simulate_batch). The
estimators get the simulator's known stage bounds: the bench measures the estimators, stage
detection is tested on its own.

Estimators are plugged in as batch functions ``fn(batch) -> (k (R, 3), b (R, 3))`` (optionally a
third item, a dict of per-run arrays such as {"iterations": ...}) with ``calib.estimators.registry.register_batch_method``.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from importlib import import_module
from pathlib import Path
from typing import Any

import numpy as np

from calib.errors import GyrocalError
from calib.estimators.registry import batch_estimator
from calib.simulator.ranges import B_RANGE_DPS, K_RANGE

PARAMS = ("kx", "ky", "kz", "bx", "by", "bz")
# The paper's Fig. 7 statement: "the majority of the estimation error" lies within these bounds.
PAPER_BOUNDS = {0.03: 5.5e-3, 0.15: 2.5e-2}

def _abs_quantile(scales: np.ndarray, q: float = 0.95) -> float:
    """The q-quantile of |e| when each run's error e is N(0, scale^2): the bound's counterpart of |err| p95."""
    from scipy.optimize import brentq
    from scipy.special import erf

    s = scales[np.isfinite(scales) & (scales > 0)]
    if s.size == 0:
        return float("nan")
    return float(brentq(lambda x: np.mean(erf(x / (np.sqrt(2.0) * s))) - q, 0.0, 10.0 * s.max()))


# ---------------------------------------------------------------------------------------------


@dataclass
class BenchReport:
    """Errors (estimate - truth) of each estimator over every simulated run, and their summary."""

    sets: int
    runs_per_set: int
    noise_levels: tuple[float, ...]
    methods: tuple[str, ...]
    seed: int
    fs: float
    workers: int
    wall_s: float
    sim_s: float  # simulation time summed over workers
    method_s: dict[str, float]  # estimator time summed over workers
    errors: dict[tuple[str, float], np.ndarray] = field(repr=False)  # (method, noise) -> (runs, 6)
    method_cpu_s: dict[str, float] = field(default_factory=dict)  # estimator CPU time summed over workers
    iterations: dict[tuple[str, float], np.ndarray] = field(default_factory=dict, repr=False)
    plot_path: str | None = None
    std: dict[tuple[str, float], np.ndarray] = field(default_factory=dict, repr=False)  # reported standard errors
    bound: dict[tuple[str, float], np.ndarray] = field(default_factory=dict, repr=False)  # Cramer-Rao bound per run

    def stats(self, method: str, noise: float) -> dict[str, Any]:
        """Percentiles of the error of each parameter, for one estimator and noise level."""
        err = self.errors[(method, noise)]
        ok = np.all(np.isfinite(err), axis=1)
        e = err[ok]
        bound = PAPER_BOUNDS.get(noise)
        out: dict[str, Any] = {"runs": int(err.shape[0]), "failed": int((~ok).sum()), "params": {}}
        for i, name in enumerate(PARAMS):
            col = e[:, i]
            p5, p25, p50, p75, p95 = np.percentile(col, [5, 25, 50, 75, 95]) if col.size else [np.nan] * 5
            row = {
                "mean": float(col.mean()) if col.size else float("nan"),
                "p5": float(p5),
                "p25": float(p25),
                "median": float(p50),
                "p75": float(p75),
                "p95": float(p95),
                "abs_p95": float(np.percentile(np.abs(col), 95)) if col.size else float("nan"),
            }
            if bound is not None:
                row["within_paper_bound"] = float(np.mean(np.abs(col) <= bound)) if col.size else float("nan")
            if (method, noise) in self.std and col.size:
                z = col / self.std[(method, noise)][ok][:, i]
                row["z_sd"] = float(np.std(z))  # error / reported std: 1 when the uncertainty is honest
                row["z_mean"] = float(np.mean(z))
            if (method, noise) in self.bound:
                row["bound_abs_p95"] = _abs_quantile(self.bound[(method, noise)][:, i])
            out["params"][name] = row
        its = self.iterations.get((method, noise))
        if its is not None and its.size:
            out["iterations"] = {"median": float(np.median(its)), "max": int(its.max()), "mean": float(its.mean())}
        return out

    def table(self) -> str:
        """A text table of the error percentiles per noise level and estimator."""
        lines = [
            f"paper-sim: {self.sets} parameter sets x {self.runs_per_set} runs, fs {self.fs:g} Hz, seed {self.seed}, "
            f"{self.workers} worker(s)",
            f"wall time {self.wall_s:.1f} s (simulation {self.sim_s:.1f} s, "
            + ", ".join(
                f"{m} {s:.1f} s" + (f" [CPU {self.method_cpu_s[m]:.1f} s]" if m in self.method_cpu_s else "")
                for m, s in self.method_s.items()
            )
            + ", summed over workers)",
        ]
        for noise in self.noise_levels:
            bound = PAPER_BOUNDS.get(noise)
            for method in self.methods:
                st = self.stats(method, noise)
                head = f"noise {noise:g} deg/s, method {method}: {st['runs']} runs, {st['failed']} failed"
                if "iterations" in st:
                    it = st["iterations"]
                    head += f"; iterations median {it['median']:g}, max {it['max']}"
                lines += ["", head]
                cols = ["p5", "p25", "median", "p75", "p95", "|err| p95"]
                hdr = f"  {'param':<6}" + "".join(f"{c:>11}" for c in cols)
                if bound is not None:
                    hdr += f"  {'in +-' + format(bound, '.1e'):>12}"
                lines.append(hdr)
                for name in PARAMS:
                    r = st["params"][name]
                    vals = [r["p5"], r["p25"], r["median"], r["p75"], r["p95"], r["abs_p95"]]
                    line = f"  {name:<6}" + "".join(f"{v:>11.2e}" for v in vals)
                    if bound is not None:
                        line += f"  {100 * r['within_paper_bound']:>11.1f}%"
                    lines.append(line)
        lines += self._comparison()
        lines += ["", "errors are estimate - truth; k dimensionless, b in deg/s"]
        return "\n".join(lines)

    def _comparison(self) -> list[str]:
        """|err| p95 of every estimator beside the Cramer-Rao bound's, and the honesty of reported errors."""
        with_bound = [m for m in self.methods if any((m, n) in self.bound for n in self.noise_levels)]
        if not with_bound:
            return []
        lines = ["", "|err| p95 by estimator; bound = |err| p95 of an efficient unbiased estimator (Cramer-Rao, per run);",
                 "err/std sd = spread of error / reported std (1 when the reported uncertainty is honest)"]
        hdr = f"  {'noise':<7}{'param':<7}" + "".join(f"{m:>11}" for m in self.methods) + f"{'bound':>11}"
        hdr += "".join(f"{m + ' err/std sd':>22}" for m in self.methods if any((m, n) in self.std for n in self.noise_levels))
        lines.append(hdr)
        for noise in self.noise_levels:
            st = {m: self.stats(m, noise)["params"] for m in self.methods}
            src = next((m for m in with_bound if (m, noise) in self.bound), None)
            for name in PARAMS:
                line = f"  {noise:<7g}{name:<7}" + "".join(f"{st[m][name]['abs_p95']:>11.2e}" for m in self.methods)
                line += f"{st[src][name]['bound_abs_p95']:>11.2e}" if src else f"{'-':>11}"
                line += "".join(
                    f"{st[m][name].get('z_sd', float('nan')):>22.3f}"
                    for m in self.methods if any((m, n) in self.std for n in self.noise_levels)
                )
                lines.append(line)
        return lines

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no per-run arrays)."""
        return {
            "sets": self.sets,
            "runs_per_set": self.runs_per_set,
            "noise_levels": list(self.noise_levels),
            "methods": list(self.methods),
            "seed": self.seed,
            "fs": self.fs,
            "workers": self.workers,
            "wall_s": round(self.wall_s, 3),
            "sim_s": round(self.sim_s, 3),
            "method_s": {m: round(s, 3) for m, s in self.method_s.items()},
            "method_cpu_s": {m: round(s, 3) for m, s in self.method_cpu_s.items()},
            "paper_bounds": {str(k): v for k, v in PAPER_BOUNDS.items()},
            "results": [
                {"noise": noise, "method": method, **self.stats(method, noise)}
                for noise in self.noise_levels
                for method in self.methods
            ],
            "plot_path": self.plot_path,
        }

    def plot(self, path: str | Path) -> Path:
        """Box plot like the paper's Fig. 7: boxes p25-p75, whiskers p5-p95; k and b panels per noise level."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        path = Path(path)
        n_rows = len(self.noise_levels)
        fig, axes = plt.subplots(n_rows, 2, figsize=(12, 3.6 * n_rows), squeeze=False)
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        width = 0.8 / max(1, len(self.methods))
        groups = (("scale factors k", PARAMS[:3], "estimate - truth"), ("biases b", PARAMS[3:], "estimate - truth (deg/s)"))
        for row, noise in enumerate(self.noise_levels):
            for col, (title, names, ylabel) in enumerate(groups):
                ax = axes[row][col]
                for mi, method in enumerate(self.methods):
                    st = self.stats(method, noise)["params"]
                    boxes = [
                        {"med": r["median"], "q1": r["p25"], "q3": r["p75"], "whislo": r["p5"], "whishi": r["p95"], "fliers": []}
                        for r in (st[name] for name in names)
                    ]
                    pos = np.arange(len(names)) + (mi - (len(self.methods) - 1) / 2) * width
                    art = ax.bxp(boxes, positions=pos, widths=width * 0.85, showfliers=False, patch_artist=True)
                    for box in art["boxes"]:
                        box.set_facecolor(colors[mi % len(colors)])
                        box.set_alpha(0.6)
                    ax.plot([], [], "s", color=colors[mi % len(colors)], alpha=0.6, label=method)
                ax.axhline(0.0, color="0.7", lw=0.8)
                ax.set_xticks(np.arange(len(names)))
                ax.set_xticklabels(names)
                ax.set_title(f"({chr(ord('a') + 2 * row + col)}) {title}, noise {noise:g} deg/s")
                ax.set_ylabel(ylabel)
                ax.ticklabel_format(axis="y", style="sci", scilimits=(-2, 2))
                ax.legend(fontsize=8, loc="upper right")
        bounds = ", ".join(f"+-{PAPER_BOUNDS[n]:g} at {n:g} deg/s" for n in self.noise_levels if n in PAPER_BOUNDS)
        if bounds:
            fig.text(0.5, 0.005, f"The paper's Fig. 7 states errors within {bounds}.", ha="center", fontsize=9)
        fig.suptitle(f"{self.sets} sets x {self.runs_per_set} runs; boxes p25-p75, whiskers p5-p95")
        fig.tight_layout(rect=(0, 0.03, 1, 1))
        from calib.plots import save_figure

        self.plot_path = str(save_figure(fig, path, dpi=110))
        return Path(self.plot_path)


# ---------------------------------------------------------------------------------------------


def _run_set(task: dict[str, Any]) -> dict[str, Any]:
    """Simulate one parameter set at one noise level and run every estimator on it."""
    from calib.simulator import simulate_batch

    runs = task["runs"]
    t0 = time.perf_counter()
    params = (np.tile(task["k"], (runs, 1)), np.tile(task["b"], (runs, 1)))
    batch = simulate_batch(task["sim_seed"], runs, task["noise"], fs=task["fs"], params=params)
    out: dict[str, Any] = {"key": task["key"], "sim_s": time.perf_counter() - t0, "methods": {}}
    truth = np.concatenate((np.asarray(batch.k_true), np.asarray(batch.b_true)), axis=1)
    for name in task["methods"]:
        t1, c1 = time.perf_counter(), time.process_time()
        res = batch_estimator(name)(batch)
        elapsed, cpu = time.perf_counter() - t1, time.process_time() - c1
        k, b = np.asarray(res[0], dtype=float), np.asarray(res[1], dtype=float)
        info = res[2] if len(res) > 2 and res[2] is not None else {}
        out["methods"][name] = {
            "err": np.concatenate((k, b), axis=1) - truth,
            "iterations": None if "iterations" not in info else np.asarray(info["iterations"]),
            "std": None if "std" not in info else np.asarray(info["std"], dtype=float),
            "bound": None if "bound" not in info else np.asarray(info["bound"], dtype=float),
            "s": elapsed,
            "cpu_s": cpu,
        }
    return out


def _sim_seed(seed: int, noise_index: int, set_index: int) -> int:
    return int(np.random.SeedSequence(seed, spawn_key=(1 + noise_index, set_index)).generate_state(1)[0])


def paper_sim(
    sets: int = 30,
    runs_per_set: int = 500,
    noise_levels: tuple[float, ...] = (0.03, 0.15),
    methods: tuple[str, ...] = ("paper",),
    seed: int = 0,
    progress: bool = True,
    plot_path: str | Path | None = None,
    workers: int | None = None,
    fs: float = 104.0,
) -> BenchReport:
    """Reproduce the paper's simulation study; returns the error statistics (and saves Fig. 7).

    The same ``sets`` parameter sets (drawn from ``seed``) are used at every noise level; each set
    is simulated ``runs_per_set`` times with independent motion and noise. ``workers`` processes
    (default: all cores) share the sets.
    """
    if sets < 1 or runs_per_set < 1:
        raise GyrocalError(f"sets and runs_per_set must be at least 1, got {sets} and {runs_per_set}")
    noise_levels = tuple(float(n) for n in noise_levels)
    methods = tuple(methods)
    if not methods or not noise_levels:
        raise GyrocalError("give at least one method and one noise level")
    for name in methods:
        batch_estimator(name)
    import_module("calib.simulator")  # fail early, in this process, if the simulator is missing
    workers = max(1, int(workers if workers is not None else (os.cpu_count() or 1)))

    rng = np.random.default_rng(np.random.SeedSequence(seed))
    k_sets = rng.uniform(*K_RANGE, size=(sets, 3))
    b_sets = rng.uniform(*B_RANGE_DPS, size=(sets, 3))
    tasks = [
        {
            "key": (ni, si),
            "noise": noise,
            "sim_seed": _sim_seed(seed, ni, si),
            "k": k_sets[si],
            "b": b_sets[si],
            "runs": runs_per_set,
            "fs": fs,
            "methods": methods,
        }
        for ni, noise in enumerate(noise_levels)
        for si in range(sets)
    ]

    from tqdm import tqdm

    t0 = time.perf_counter()
    results: list[dict[str, Any]] = []
    with tqdm(total=len(tasks), file=sys.stderr, disable=not progress, desc="paper-sim", unit="set") as bar:
        if workers == 1:
            for task in tasks:
                results.append(_run_set(task))
                bar.update()
        else:
            methods_ctx = multiprocessing.get_all_start_methods()
            ctx = multiprocessing.get_context("fork" if "fork" in methods_ctx else None)
            with ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=ctx) as pool:
                for fut in as_completed([pool.submit(_run_set, task) for task in tasks]):
                    results.append(fut.result())
                    bar.update()
    wall = time.perf_counter() - t0

    results.sort(key=lambda r: r["key"])
    errors: dict[tuple[str, float], np.ndarray] = {}
    iterations: dict[tuple[str, float], np.ndarray] = {}
    extra: dict[str, dict[tuple[str, float], np.ndarray]] = {"std": {}, "bound": {}}
    for ni, noise in enumerate(noise_levels):
        mine = [r for r in results if r["key"][0] == ni]
        for name in methods:
            errors[(name, noise)] = np.concatenate([r["methods"][name]["err"] for r in mine])
            its = [r["methods"][name]["iterations"] for r in mine]
            if all(i is not None for i in its):
                iterations[(name, noise)] = np.concatenate(its)
            for key, store in extra.items():
                parts = [r["methods"][name].get(key) for r in mine]
                if all(p is not None for p in parts):
                    store[(name, noise)] = np.concatenate(parts)
    report = BenchReport(
        sets=sets,
        runs_per_set=runs_per_set,
        noise_levels=noise_levels,
        methods=methods,
        seed=seed,
        fs=fs,
        workers=workers,
        wall_s=wall,
        sim_s=float(sum(r["sim_s"] for r in results)),
        method_s={m: float(sum(r["methods"][m]["s"] for r in results)) for m in methods},
        method_cpu_s={m: float(sum(r["methods"][m]["cpu_s"] for r in results)) for m in methods},
        errors=errors,
        iterations=iterations,
        std=extra["std"],
        bound=extra["bound"],
    )
    if plot_path is not None:
        report.plot(plot_path)
    return report
