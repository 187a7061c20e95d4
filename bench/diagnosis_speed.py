"""Time of a full diagnosis (bootstrap included) of protocol recordings, one after another in one process.

    .venv/bin/python bench/diagnosis_speed.py --recordings 20
    .venv/bin/python bench/diagnosis_speed.py --large      # recordings of about 100,000 samples, every protocol shape

The paper protocol recordings last 21-27 s; the extended protocol ones about 90 s; the real imucal
session 101 s; imu_tk's session (37 re-orientations between rests) 512 s. One BLAS thread, as `gyrocal` runs
(calib.blas: a second one only spins on matrices this small; timed with two, imu_tk's session took 56-60 s for
its 20-28 s). The target is at most 10 s per 30 s recording on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from calib.blas import single_threaded_blas
from calib.diagnosis import diagnose
from calib.simulator.concealed import EFFECT_NAMES, draw_concealed

REAL = Path(os.environ.get("GYROCAL_REAL_DATA", Path(__file__).resolve().parents[2] / "shared" / "data" / "real"))


def measure(recordings: int, protocol: str = "paper", n_boot: int = 200) -> list[str]:
    """Diagnose ``recordings`` concealed-effect recordings one after another; lines of results."""
    rng = np.random.default_rng(0)
    times, durations = [], []
    for i in range(recordings):
        effect = None if i % 3 == 0 else str(rng.choice(EFFECT_NAMES))
        case = draw_concealed(20_000 + i, effect, protocol=protocol, with_accel=bool(i % 2), with_seq=bool(i % 4 < 2))
        t0 = time.perf_counter()
        diagnose(case.recording, n_boot=n_boot)
        times.append(time.perf_counter() - t0)
        durations.append(case.recording.duration_s)
    times = np.array(times)
    lines = [(f"{protocol} protocol, {recordings} recordings of {min(durations):.0f}-{max(durations):.0f} s, {n_boot} "
             f"replicates, {os.cpu_count()} cores: median {np.median(times):.2f} s, 90 % {np.quantile(times, 0.9):.2f} s, "
             f"max {times.max():.2f} s per diagnosis")]
    real = REAL / "imucal" / "example_ferraris_session.csv"
    if real.is_file():
        from calib.io.readers import read_recording

        rec = read_recording(real, fs=102.4)
        t0 = time.perf_counter()
        diagnose(rec, n_boot=n_boot)
        lines.append(f"real imucal session ({rec.duration_s:.0f} s, 13 rests): {time.perf_counter() - t0:.2f} s")
    gyro, acc = REAL / "imu_tk" / "xsens_gyro.mat", REAL / "imu_tk" / "xsens_acc.mat"
    if gyro.is_file() and acc.is_file():
        from calib.io.imu_tk import read_imu_tk

        rec = read_imu_tk(gyro, acc)
        t0 = time.perf_counter()
        d = diagnose(rec, n_boot=n_boot)
        named = ", ".join(e["name"] for e in d.effects) or "nothing"
        lines.append(f"real imu_tk session ({rec.duration_s:.0f} s, {len(rec)} samples, re-orientations): "
                     f"{time.perf_counter() - t0:.1f} s, names {named}")
    return lines


def large_shapes() -> list[tuple[str, object]]:
    """Recordings of about 100,000 samples (the most the service accepts), each with a wandering bias (0.01 deg/s,
    20 s) as every real gyroscope has: (description, script and rate)."""
    from calib.simulator.lab_scripts import multi_position_script
    from calib.simulator.protocol import ProtocolScript, Still, Turn

    rng = np.random.default_rng(5)
    paper = ProtocolScript((Still(20.0), Turn("x", 360.0), Still(8.0), Turn("y", 360.0), Still(8.0), Turn("z", 360.0),
                            Still(8.0)))
    long_rests = ProtocolScript((Still(300.0), Turn("x", 360.0), Still(300.0), Turn("y", 360.0), Still(300.0),
                                 Turn("z", 360.0), Still(80.0)))
    many: list = [Still(20.0)]
    for i in range(60):
        many += [Turn("xyz"[i % 3], 360.0), Still(8.0)]
    return [
        ("paper protocol at 1.8 kHz (54 s)", (paper, 1800.0)),
        ("paper protocol with 300 s rests at 100 Hz (990 s)", (long_rests, 100.0)),
        ("60 full turns at 150 Hz (727 s)", (ProtocolScript(tuple(many)), 150.0)),
        ("multi-position, 100 re-orientations at 100 Hz (973 s)",
         (multi_position_script(rng, n=100, first_rest_s=50.0, rest_s=7.0), 100.0)),
        ("multi-position, 20 re-orientations at 400 Hz (234 s)",
         (multi_position_script(rng, n=20, first_rest_s=30.0, rest_s=8.0), 400.0)),
    ]


def measure_large(n_boot: int = 200) -> list[str]:
    """Diagnose each large shape once: lines of seconds and what was named."""
    from calib.effects.drift import BiasInstability
    from calib.simulator.simulate import simulate

    lines = []
    for what, (script, fs) in large_shapes():
        rec, _ = simulate(3, noise=0.05, fs=fs, script=script, effects=(BiasInstability(0.01, 20.0),))
        t0 = time.perf_counter()
        d = diagnose(rec, n_boot=n_boot)
        named = ", ".join(e["name"] for e in d.effects) or "nothing"
        lines.append(f"{what}, {len(rec)} samples: {time.perf_counter() - t0:.1f} s, names {named}")
        print(lines[-1], flush=True)
    return lines


def main() -> int:
    single_threaded_blas()  # as the command line runs: one BLAS thread (calib.blas)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recordings", type=int, default=20)
    ap.add_argument("--protocol", default="paper", choices=["paper", "extended"])
    ap.add_argument("--n-boot", type=int, default=200)
    ap.add_argument("--large", action="store_true", help="recordings of about 100,000 samples instead")
    args = ap.parse_args()
    if args.large:
        measure_large(args.n_boot)
        return 0
    for line in measure(args.recordings, args.protocol, args.n_boot):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
