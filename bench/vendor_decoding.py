"""Decoding cost of each vendor's data format: CPU per sample and the share of one core 20 devices need.

Run: .venv/bin/python bench/vendor_decoding.py [--devices 20] [--seconds 30]

For each format the notifications 20 devices would send in --seconds (Polar PMD at 416 Hz in delta-compressed
frames of 36 samples, MetaWear at 800 Hz packed three per notification, Thingy:52 at its highest motion rate,
200 Hz, one per notification) are built from simulated hand turns first, then decoded one notification at a
time into deg/s (gyrocal's own format: bench/link_throughput.py). Reported: microseconds per notification and
per sample, and CPU seconds per second of stream for all devices (the share of one core).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from wearable_protocol.vendors import metawear as mw  # noqa: E402
from wearable_protocol.vendors import polar_pmd as pmd  # noqa: E402
from wearable_protocol.vendors import thingy52 as th  # noqa: E402


def _rates(n: int, fs: float, rng: np.random.Generator) -> np.ndarray:
    """Hand-turn-like gyro rates (deg/s), n samples at fs."""
    t = np.arange(n) / fs
    return 200 * np.sin(2 * np.pi * 0.3 * t)[:, None] * rng.uniform(0.2, 1.0, 3) + rng.normal(0, 0.5, (n, 3))


def _formats(seconds: float, rng: np.random.Generator) -> dict[str, tuple[float, int, list[bytes], Callable[[bytes], np.ndarray]]]:
    out = {}
    factor = 2000 / 32768  # PMD factor at 2000 deg/s
    fs, per = 416.0, 36
    counts = np.round(_rates(int(seconds * fs), fs, rng) / factor).astype(np.int64)
    frames = [pmd.encode_frame(pmd.MeasurementType.GYRO, 10**9 + int(1e9 * (i + per) / fs), counts[i:i + per])
              for i in range(0, len(counts) - per + 1, per)]
    out["polar-pmd (delta frames)"] = (fs, per, frames, lambda d: pmd.decode_frame(d).scaled(factor))
    fs = 800.0
    counts = np.round(_rates(int(seconds * fs), fs, rng) * 16.4).astype(np.int64)
    notes = [mw.encode_notification(mw.Module.GYROSCOPE, counts[i:i + 3]) for i in range(0, len(counts) - 2, 3)]
    out["metawear (packed)"] = (fs, 3, notes, lambda d: mw.gyro_dps(mw.decode_notification(d).counts, 2000))
    fs = 200.0
    rates = _rates(int(seconds * fs), fs, rng)
    notes = [th.encode_raw(np.array([0.0, 0.0, 1.0]), r) for r in rates]
    out["thingy52 (raw)"] = (fs, 1, notes, lambda d: th.decode_raw(d).gyro_dps)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--devices", type=int, default=20)
    ap.add_argument("--seconds", type=float, default=30.0)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    print(f"{'format':28s} {'rate Hz':>8s} {'us/notif':>9s} {'us/sample':>10s} {'core share, ' + str(args.devices) + ' devices':>24s}")
    for name, (fs, per, notes, decode) in _formats(args.seconds, rng).items():
        t0 = time.process_time()
        for d in notes:
            decode(d)
        cpu = time.process_time() - t0
        us_note = 1e6 * cpu / len(notes)
        share = cpu / args.seconds * args.devices
        print(f"{name:28s} {fs:8.0f} {us_note:9.1f} {us_note / per:10.2f} {share:24.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
