"""``gyrocal noise``: the Allan deviation of a long rest, its noise parameters, a plot, and Kalibr's imu.yaml."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from calib.cli.options import add_reading_arguments, read_recording_args, writable


def add_noise_parser(sub: Any) -> None:
    """Register ``noise`` on the subcommand parsers ``sub``."""
    p = sub.add_parser("noise", help="noise density, bias instability and random walk of each axis from a long rest (Allan "
                       "deviation), with a plot and Kalibr's imu.yaml",
                       description="Read FILE, a recording of the device lying still (an hour shows the random walk; a few "
                       "minutes the noise density), and report each gyroscope and accelerometer axis's overlapping Allan "
                       "deviation with 95 %% bands and the noise parameters read from it, each with its 95 %% interval and "
                       "the averaging time it was read at.")
    add_reading_arguments(p)
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.add_argument("--plot", type=Path, default=None, metavar="PNG",
                   help="the Allan deviation plot (default: FILE's name with .allan.png)")
    p.add_argument("--kalibr", type=Path, default=None, metavar="YAML",
                   help="also write Kalibr's imu.yaml (noise densities and random walks in SI units) to YAML")
    p.add_argument("--topic", default="/imu0", help="with --kalibr: the IMU's ROS topic (default /imu0)")
    p.add_argument("--rate", type=float, default=None, metavar="HZ",
                   help="with --kalibr: the update rate written (default: the recording's)")
    p.set_defaults(func=cmd_noise)


def cmd_noise(args: argparse.Namespace) -> int:
    """Analyse the rest on the command line; print the table or the JSON, write the plot (and Kalibr's file)."""
    from tqdm import tqdm

    from calib.noise.analysis import noise
    from calib.noise.plot import plot_noise

    plot = args.plot or args.file.with_name(args.file.stem + ".allan.png")
    writable(plot, "plot")
    if args.kalibr is not None:
        writable(args.kalibr, "Kalibr file")
    rec = read_recording_args(args).recording
    with tqdm(total=6 if rec.accel is not None else 3, desc="allan", unit="axis", file=sys.stderr,
              disable=not sys.stderr.isatty()) as bar:
        report = noise(rec, progress=bar.update)
    plot_noise(report, plot)
    if args.kalibr is not None:
        from calib.exports.kalibr import kalibr_imu_yaml

        args.kalibr.write_text(kalibr_imu_yaml(report, args.topic, args.rate), encoding="utf-8")
    if args.json:
        print(json.dumps({**report.to_json(), "plot": str(plot), "kalibr": None if args.kalibr is None else str(args.kalibr)}))
        return 0
    print(report.text())
    print(f"plot saved to {plot}" + ("" if args.kalibr is None else f"; Kalibr's imu.yaml written to {args.kalibr}"))
    return 0
