"""`gyrocal watch FILE (--device ID | --calibration FILE)`: whether the calibration in force when a study recording was
made still holds, from the recording itself (calib.watch; plugged into calib's CLI)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from .calibration_cli import add_moment_arguments, in_force_of
from .cli import EXIT_OK, ServiceError
from .config import DB_URL_HELP

EXIT_MOVED = 4  # a parameter of the calibration moved: calibrate again


def register_watch(sub: Any) -> None:
    """Add `gyrocal watch`."""
    from calib.cli.options import add_reading_arguments

    p = sub.add_parser(
        "watch",
        help="whether a calibration still holds, from a recording made with it in force (its rests and re-orientations)",
        description="Test the calibration in force on a study recording: its rests test each axis's bias, the "
        "re-orientations between two rests (measured through the accelerometer's gravity) test the scale factors; with a "
        "temperature column both are fitted against the temperature. Each of k_x..k_z, b_x..b_z holds (with its margin), "
        "moved (by how much, since when) or cannot tell (and which motion would tell). Motion too long to measure "
        "(walking) is left out and counted. Exit 4 when a parameter moved.",
    )
    add_reading_arguments(p)
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--device", default=None, metavar="ID", help="the device whose calibration in force is watched")
    which.add_argument("--calibration", type=Path, default=None, metavar="FILE", help="gyrocal's calibration JSON or imucal's")
    add_moment_arguments(p, "with --device: when the recording was made (ISO 8601; default now)", "with --device: " + DB_URL_HELP,
                         max_age=False)
    p.add_argument("--calibration-temperature", type=float, default=None, metavar="DEGC",
                   help="the temperature the calibration was made at (default: the calibration's own record of it)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=cmd_watch)


def cmd_watch(args: argparse.Namespace) -> int:
    from calib.apply.correction import Correction, read_correction
    from calib.cli.options import read_recording_args
    from calib.watch import watch

    from .lifecycle import none_in_force

    rec = read_recording_args(args).recording
    used: dict[str, Any]
    if args.calibration is not None:
        correction = read_correction(args.calibration)
        used = {"file": str(args.calibration)}
    else:
        cal = in_force_of(args, temperature_c=rec.mean_temperature_c)
        if cal is None:
            raise ServiceError(f"{none_in_force(args.device, args.at)}: calibrate it first, or give --calibration FILE")
        correction = Correction.from_json(cal.model_dump(mode="json"))
        used = {"calibration_id": cal.id, "device_id": cal.device_id, "accepted_at": cal.accepted_at.isoformat()}
    report = watch(rec, correction, args.calibration_temperature)
    if args.json:
        print(json.dumps({"recording": str(args.file), "calibration": used, **report.to_json()}, indent=2))
    else:
        print(f"{args.file}: against {used.get('file') or 'calibration #' + str(used.get('calibration_id'))}")
        for line in report.lines():
            print(line)
    return EXIT_MOVED if report.verdict == "moved" else EXIT_OK
