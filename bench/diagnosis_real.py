"""The diagnosis on real noise: catalogued effects put into real third-party readings, beside the same effect in
each recording's simulated twin, and the untouched recordings diagnosed under many bootstrap seeds.

    .venv/bin/python bench/diagnosis_real.py                      # imucal's session, 3 draws per effect and band
    .venv/bin/python bench/diagnosis_real.py --sessions imucal imu_tk --draws 2 --null-seeds 20

Semi-synthetic: each effect acts on the recorded readings through the simulator's own hooks (calib.effects), with
the untouched calibration's g = K m + b as the true rate and the accelerometer as the specific force; nothing in
the recording says so. Effects of the motion itself (placement error, clock error) cannot be put into readings
already taken and are left out. Each effect's magnitude is drawn in its catalogued range (``Effect.draw``);
the band is the lower or upper half of that range on a log scale. The twin is the same protocol simulated at the
recording's rate and measured noise level, with the same effect instance. A case is "named" when the diagnosis
names the effect put in; on the real recordings the session's own effects (those named in the untouched one) are
not counted as false.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import numpy as np

from calib.blas import single_threaded_blas
from calib.diagnosis import diagnose
from calib.effects import CATALOGUE, EFFECTS, DrawContext, Effect
from calib.effects.base import SensorContext, SensorOutput
from calib.pipeline import calibrate_protocol
from calib.recording import Recording
from calib.simulator.lab_scripts import ferraris_script, multi_position_script
from calib.simulator.simulate import simulate

REAL = Path(os.environ.get("GYROCAL_REAL_DATA", Path(__file__).resolve().parents[2] / "shared" / "data" / "real"))
HOOKS = ("on_sensor", "on_output")


def injectable() -> list[str]:
    """The catalogued effects that act on readings (not on the motion)."""
    return [n for n in CATALOGUE if EFFECTS[n].on_trajectory is Effect.on_trajectory]


def load(name: str) -> tuple[Recording, str]:
    if name == "imucal":
        from calib.io.readers import read_recording

        return read_recording(REAL / "imucal" / "example_ferraris_session.csv", fs=102.4), "ferraris"
    from calib.io.imu_tk import read_imu_tk

    return read_imu_tk(REAL / "imu_tk" / "xsens_gyro.mat", REAL / "imu_tk" / "xsens_acc.mat"), "multi-position"


def inject(rec: Recording, k: np.ndarray, b: np.ndarray, effect: Effect, rng: np.random.Generator) -> Recording:
    """``effect`` put into the real readings, the untouched calibration's rate g = k m + b taken as the true one."""
    accel = rec.accel if rec.accel is not None else np.tile([0.0, 0.0, 1.0], (len(rec), 1))
    ctx = SensorContext(rec.t - rec.t[0], rec.gyro * k + b, accel, k, b, rec.fs, 0.0)
    m = effect.on_sensor(rec.gyro.copy(), ctx, rng)
    idx = np.arange(len(rec), dtype=np.int64)
    out = SensorOutput(rec.t.copy(), m, accel, idx.copy(), idx, rec.temp)
    out = effect.on_output(out, rng)
    seq = None if rec.seq is None else rec.seq[out.index]
    t = out.t if rec.seq is not None else rec.t[0] + np.arange(out.t.size) / rec.fs  # no counter: the time column even
    return replace(rec, t=t, gyro=out.gyro, accel=None if rec.accel is None else rec.accel[out.index], seq=seq,
                   temp=out.temp)


def twin(rec: Recording, protocol: str, effect: Effect | None, seed: int, noise: float) -> Recording:
    """The protocol simulated at the recording's rate and noise, with ``effect``."""
    rng = np.random.default_rng(seed)
    script = ferraris_script(rng) if protocol == "ferraris" else multi_position_script(rng, n=37, rest_s=8.0)
    sim, _ = simulate(seed, noise=noise, fs=rec.fs, script=script, effects=() if effect is None else (effect,))
    return sim


def measured_noise(rec: Recording) -> float:
    """The readings' white noise (deg/s) from successive differences within the rests: a wander does not enter it."""
    from calib.stages.detector import detect_stages

    stills = [s for s in detect_stages(rec) if s.kind == "still"]
    parts = [np.diff(rec.gyro[s.start:s.end], axis=0) for s in stills if s.end - s.start > 10]
    return float(np.median(np.concatenate(parts).std(axis=0)) / np.sqrt(2.0))


def band_of(effect_name: str, magnitude: float) -> str:
    r = EFFECTS[effect_name].spec.drawn
    mid = np.sqrt(r.low * r.high) if r.low > 0 else 0.5 * (r.low + r.high)
    return "low" if abs(magnitude) < mid else "high"


def names(rec: Recording, seed: int = 0, n_boot: int = 200) -> set[str] | None:
    try:
        return {e["name"] for e in diagnose(rec, n_boot=n_boot, seed=seed).effects}
    except Exception as exc:  # a refusal is a result too: counted as not named
        print(f"    refused: {str(exc)[:120]}", flush=True)
        return None


def run(session: str, draws: int, null_seeds: int, n_boot: int) -> list[str]:
    rec, protocol = load(session)
    noise = measured_noise(rec)
    own = names(rec, 0, n_boot) or set()
    print(f"{session}: {len(rec)} samples at {rec.fs:g} Hz, noise {noise:.3f} deg/s; its own effects: {sorted(own)}",
          flush=True)
    lines = [f"### {session} ({protocol}, {len(rec)} samples, white noise {noise:.3f} deg/s; own: "
             f"{', '.join(sorted(own)) or 'none'})", "",
             "| effect | band | named on the real readings | named on the twin | false effects real / twin |",
             "| --- | --- | --- | --- | --- |"]
    result, _ = calibrate_protocol(rec)
    k, b = np.nan_to_num(np.asarray(result.k, dtype=float), nan=1.0), np.asarray(result.b, dtype=float)
    peak = float(np.abs(rec.gyro).max() * np.nanmax(result.k))
    tally: dict[tuple[str, str], list[int]] = defaultdict(lambda: [0, 0, 0, 0, 0])
    null_twins: dict[int, set[str] | None] = {}  # what each draw's twin names with no effect put in
    for name in injectable():
        for d in range(draws):
            rng = np.random.default_rng([CATALOGUE.index(name), d])
            ctx = DrawContext(3, rec.duration_s, peak, None)
            effect, magnitude = EFFECTS[name].draw(rng, ctx)
            band = band_of(name, magnitude)
            t0 = time.perf_counter()
            real = names(inject(rec, k, b, effect, np.random.default_rng(d)), d, n_boot)
            sim = names(twin(rec, protocol, effect, 1000 + d, noise), d, n_boot)
            if d not in null_twins:
                null_twins[d] = names(twin(rec, protocol, None, 1000 + d, noise), d, n_boot)
            sim_null = null_twins[d]
            row = tally[(name, band)]
            row[0] += 1
            row[1] += int(real is not None and name in real)
            row[2] += int(sim is not None and name in sim)
            row[3] += int(real is not None and bool(real - own - {name}))
            row[4] += int(sim is not None and bool(sim - (sim_null or set()) - {name}))
            print(f"  {name} {band} {magnitude:.3g}: real {sorted(real or [])}, twin {sorted(sim or [])} "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)
    for (name, band), (n, real, sim, fr, fs) in sorted(tally.items()):
        lines.append(f"| {name} | {band} | {real} of {n} | {sim} of {n} | {fr} / {fs} |")
    if null_seeds:
        extra = defaultdict(int)
        for s in range(1, null_seeds + 1):
            for e in (names(rec, s, n_boot) or set()) - own:
                extra[e] += 1
        said = ", ".join(f"{k} in {v}" for k, v in sorted(extra.items())) or "none"
        lines += ["", f"Untouched, {null_seeds} bootstrap seeds: effects beyond its own named: {said}."]
    return lines


def main() -> int:
    single_threaded_blas()  # as the command line runs: one BLAS thread (calib.blas)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", nargs="+", default=["imucal"], choices=["imucal", "imu_tk"])
    ap.add_argument("--draws", type=int, default=3, help="magnitudes drawn per effect")
    ap.add_argument("--null-seeds", type=int, default=20)
    ap.add_argument("--n-boot", type=int, default=200)
    args = ap.parse_args()
    for s in args.sessions:
        print("\n".join(run(s, args.draws, args.null_seeds, args.n_boot)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
