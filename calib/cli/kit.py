"""``gyrocal calibrate-kit`` (every wearable of a kit from one motion of the tray) and ``gyrocal simulate-kit``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from calib.cli.summary import fmt_vec


def add_kit_parsers(sub: Any) -> None:
    """Register ``calibrate-kit`` and ``simulate-kit``."""
    from calib.estimators.closure.placement import HEADING_PRIOR_DEG
    from calib.io.inputs import LAYOUTS, PROTOCOLS

    p = sub.add_parser("calibrate-kit", help="calibrate every wearable of a kit, turned together in one tray, from one "
                       "recording each of the same session")
    p.add_argument("files", type=Path, nargs="+", metavar="FILE", help="one recording per wearable (any layout "
                   "`gyrocal calibrate` reads but imu_tk's two files); the reference is the one that lost the fewest samples")
    p.add_argument("--fs", type=float, default=None, help="sample rate in Hz (for files with no time column)")
    p.add_argument("--layout", choices=[v for v in LAYOUTS if v != "imu_tk"], default="auto",
                   help="CSV layout of every file (default: detect from each header)")
    p.add_argument("--gyro-counts-per-dps", type=float, default=None, metavar="C", help="the files hold raw counts")
    p.add_argument("--accel-counts-per-g", type=float, default=None, metavar="C", help="the files hold raw counts")
    p.add_argument("--protocol", choices=[v for v in PROTOCOLS if v != "multi-position"], default="auto",
                   help="the protocol the tray was turned through (default: recognised)")
    p.add_argument("--sections", type=Path, action="append", default=None, metavar="SECTIONS",
                   help="imucal's section list of a recording (JSON), once for each FILE in their order, as the service "
                   "gives a kit wearable's session (GET /sessions/{id}/sections): the kit is calibrated on the turns they "
                   "hold (a try the tray was asked again is none of them); default: every full turn found")
    p.add_argument("--heading-prior-deg", type=float, default=None, metavar="DEG",
                   help=f"how far (1 sigma, deg) the tray's heading may be off after each turn (default {HEADING_PRIOR_DEG:g})")
    p.add_argument("--json", action="store_true", help="print one JSON object: devices (each one's result and "
                   "consistency), kit (the consistency and who departed), warnings")
    p.add_argument("--no-progress", action="store_true", help="no progress on stderr")
    p.set_defaults(func=cmd_calibrate_kit)

    p = sub.add_parser("simulate-kit", help="simulate a kit of wearables in one tray turned through the protocol")
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--devices", type=int, default=3, help="wearables in the tray (default 3)")
    p.add_argument("--noise", type=float, default=0.03, help="white noise std of every gyroscope, deg/s (default 0.03)")
    p.add_argument("--loose", type=int, default=None, metavar="I",
                   help="wearable I (1-based) slips in its slot during the second turn, by --slip-deg")
    p.add_argument("--slip-deg", type=float, default=2.0, help="how far the loose wearable slips, deg (default 2)")
    # calib.simulator.kit.SLIP_WHEN, written out: importing it would load scipy at every start of the command line
    p.add_argument("--slip-in", choices=("turn", "pause"), default="turn",
                   help="the loose wearable slips during the second turn (default), or in the pause after it, the tray resting")
    p.add_argument("--misalignment", type=float, default=0.0, metavar="M", help="each sensor's axes are not orthogonal: "
                   "the off-diagonal entries of its K drawn in +-M (default 0)")
    p.add_argument("-o", "--output", type=Path, required=True, help="folder to write wearable-1.csv, wearable-2.csv, ... in")
    p.add_argument("--truth", action="store_true", help="print the simulated truth as JSON")
    p.set_defaults(func=cmd_simulate_kit)


def cmd_calibrate_kit(args: argparse.Namespace) -> int:
    from calib.cli.options import error_json
    from calib.errors import CalibrationError, GyrocalError, Refusal
    from calib.io.inputs import ReadOptions, file_input, read_input
    from calib.kit.estimator import calibrate_kit
    from calib.kit.turns import labelled_turns
    from calib.pipeline import method_options

    method_options("closure", args.heading_prior_deg)
    if len(args.files) < 2:
        raise GyrocalError("a kit needs at least two recordings, one per wearable, of one motion of the tray; to "
                           "calibrate one wearable use gyrocal calibrate")
    options = ReadOptions(layout=args.layout, fs=args.fs, gyro_counts_per_dps=args.gyro_counts_per_dps,
                          accel_counts_per_g=args.accel_counts_per_g, protocol=args.protocol)
    if args.sections is not None and len(args.sections) != len(args.files):
        raise GyrocalError(f"{len(args.sections)} section lists for {len(args.files)} recordings: give --sections once for "
                           "each recording, in the same order, or not at all")
    recordings, turns_kept = [], []
    for i, path in enumerate(args.files):
        try:
            read = read_input(file_input(path, options, sections_path=None if args.sections is None else args.sections[i]))
        except GyrocalError as exc:
            raise type(exc)(f"{path}: {exc}") from None
        recordings.append(read.recording)
        turns_kept.append(labelled_turns(read.recording, read.sections))
    names = [p.stem if sum(q.stem == p.stem for q in args.files) == 1 else str(p) for p in args.files]
    bar = None if args.no_progress or args.json else _Progress()
    try:
        kit = calibrate_kit(recordings, names, protocol=args.protocol, heading_prior_deg=args.heading_prior_deg,
                            progress=bar, turns_kept=None if all(t is None for t in turns_kept) else [t or [] for t in turns_kept])
    except GyrocalError as exc:
        refusal = CalibrationError(f"the kit was not calibrated: {exc}",
                                   code=exc.code if isinstance(exc, Refusal) else "not_calibrated")
        if args.json:
            print(error_json(refusal, refusal.code, []))
        raise refusal from None
    if bar is not None:
        bar.done()
    if args.json:
        print(json.dumps(kit.to_json()))
    else:
        print(kit_summary(kit))
    return 0


def kit_summary(kit: Any) -> str:
    """A readable summary of a ``KitResult``: one row per wearable, the kit's consistency, the warnings."""
    lines = [f"Kit of {len(kit.members)} wearables, solved in {kit.reference}'s frame and clock", ""]
    for m in kit.members:
        r = m.result
        head = f"{m.name}: " + ("DEPARTED, " if m.departed else "")
        if r is None:
            lines.append(head + f"not calibrated ({m.error})")
            continue
        lines.append(head + f"k = {fmt_vec(r.k, 6)} ± {fmt_vec(r.k_std, 6)}")
        lines.append(" " * len(head) + f"b = {fmt_vec(r.b, 4)} ± {fmt_vec(r.b_std, 4)} deg/s")
        if r.K is not None and r.K_std is not None:
            from calib.kit.members import UPPER

            lines.append(" " * len(head) + f"K_xy, K_xz, K_yz = {fmt_vec(r.K[UPPER], 5)} ± {fmt_vec(r.K_std[UPPER], 5)}")
        clock = m.clock.to_dict()
        extra = [f"clock {clock['rate_ppm']:+.0f} ppm" if clock["rate_ppm"] is not None else "clock unknown"]
        if np.isfinite(m.mount_deg):
            extra.append(f"mounted {m.mount_deg:.2f} deg from {kit.reference}")
        if m.coherence is not None:
            d = m.coherence.departure
            extra.append(f"followed the kit to {d.angle_deg:.3f} deg (noise allows {d.std_deg:.3f})")
            if np.isfinite(d.step_deg):  # measured only across a burst while the tray rested (calib.kit.departure)
                extra.append(f"turned {d.step_deg:.2f} deg in its slot while the tray rested")
            extra.append(f"coupling residual {m.coherence.ratio:.2f}x the noise")
        lines.append(" " * len(head) + "; ".join(extra))
    lines.append("")
    if kit.axes is not None:
        lines.append(f"Axes: {kit.axes['reason']}")
    lines.append("Departed: " + (", ".join(kit.departed) if kit.departed else "none: every wearable followed the tray"))
    for w in kit.warnings:
        lines.append(f"WARNING: {w}")
    return "\n".join(lines)


class _Progress:
    """A one-line progress bar on stderr."""

    def __call__(self, fraction: float, stage: str) -> None:
        width = 30
        filled = int(round(width * min(max(fraction, 0.0), 1.0)))
        print(f"\r[{'#' * filled}{'.' * (width - filled)}] {stage:<50}", end="", file=sys.stderr, flush=True)

    def done(self) -> None:
        print(file=sys.stderr)


def cmd_simulate_kit(args: argparse.Namespace) -> int:
    from calib.errors import GyrocalError
    from calib.io.readers import write_native_csv
    from calib.simulator.kit import Slip, simulate_kit

    slip = None
    if args.slip_in != "turn" and args.loose is None:
        raise GyrocalError("--slip-in says when the wearable of --loose slips: give --loose I too")
    if args.loose is not None:
        if not 1 <= args.loose <= args.devices:
            raise GyrocalError(f"--loose names a wearable from 1 to {args.devices}; got {args.loose}")
        slip = Slip(args.loose - 1, args.slip_deg, in_pause=args.slip_in == "pause")
    recordings, truth = simulate_kit(args.seed, args.devices, noise=args.noise, slip=slip, misalignment=args.misalignment)
    args.output.mkdir(parents=True, exist_ok=True)
    for i, rec in enumerate(recordings):
        write_native_csv(rec, args.output / f"wearable-{i + 1}.csv")
    if args.truth:
        print(json.dumps({"devices": [d.to_dict() for d in truth.devices], "seed": truth.seed, "noise_dps": truth.noise_dps}))
    else:
        print(f"wrote {len(recordings)} recordings to {args.output}", file=sys.stderr)
    return 0
