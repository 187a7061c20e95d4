"""How long the orientation before and after a calibration takes (calib.apply.orientation: ahrs' Madgwick filter), per
sample and for an hour of a 100 Hz recording, with and without an accelerometer.

Run: .venv/bin/python bench/orientation_speed.py [--repeat 14]

A simulated paper-protocol recording is repeated ``--repeat`` times end to end; both estimates (raw and calibrated)
are timed. Reported: samples, seconds, microseconds per sample per estimate, and the time for one hour at 100 Hz.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from calib.apply.correction import Correction, corrected
from calib.apply.orientation import orientation
from calib.recording import Recording
from calib.simulator import simulate


def measure(repeat: int) -> list[str]:
    rec, truth = simulate(3, noise=0.03)
    n = len(rec) * repeat
    lines = ["| input | samples | s (both estimates) | µs per sample per estimate | one hour at 100 Hz |",
             "| --- | --- | --- | --- | --- |"]
    inputs = (("gyroscope + accelerometer (Madgwick)", np.tile(rec.accel, (repeat, 1))), ("gyroscope only (AngularRate)", None))
    for label, accel in inputs:
        big = Recording(t=np.arange(n) / rec.fs, gyro=np.tile(rec.gyro, (repeat, 1)), accel=accel)
        cal = corrected(big, Correction(K=np.diag(truth.k), b=np.asarray(truth.b)))
        t0 = time.perf_counter()
        orientation(big, cal)
        dt = time.perf_counter() - t0
        per = dt / (2 * n)
        lines.append(f"| {label} | {n} | {dt:.2f} | {per * 1e6:.1f} | {per * 2 * 360_000:.0f} s |")
    return lines


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=14)
    print("\n".join(measure(p.parse_args().repeat)))


if __name__ == "__main__":
    main()
