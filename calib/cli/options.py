"""The command line's recording options, shared by ``gyrocal calibrate``, ``diagnose``, ``apply`` and ``verify``: the
file, how to read it (layout, sample rate, raw-count sensitivities), which protocol to take it as, and labelled
sections. They become one ``calib.io.inputs.RecordingInput``, read as every other door reads it."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

from calib.io.inputs import LAYOUTS, PROTOCOLS, ReadOptions, ReadRecording, RecordingInput


def add_reading_arguments(p: argparse.ArgumentParser) -> None:
    """``file`` and the options that say how to read it (layout, sample rate, raw-count sensitivities)."""
    p.add_argument("file", type=Path, help="native CSV (t,gx,gy,gz,...) or imucal layout (gyr_x,...)")
    p.add_argument("--fs", type=float, default=None, help="sample rate in Hz (required when the file has no time column)")
    p.add_argument("--layout", choices=LAYOUTS, default="auto",
                   help="CSV layout (default: detect from header); imu_tk: FILE is imu_tk's gyroscope file, --accel its "
                        "accelerometer file")
    p.add_argument("--accel", type=Path, default=None, help="with --layout imu_tk: the accelerometer file")
    p.add_argument("--gyro-counts-per-dps", type=float, default=None, metavar="C",
                   help="the file holds raw counts: the gyro's sensitivity in counts per deg/s (e.g. 16.4 at +-2000 deg/s)")
    p.add_argument("--accel-counts-per-g", type=float, default=None, metavar="C",
                   help="the file holds raw counts: the accelerometer's sensitivity in counts per g (e.g. 2048 at +-16 g)")


def add_recording_arguments(p: argparse.ArgumentParser) -> None:
    """``file``, how to read it, and what protocol it holds."""
    add_reading_arguments(p)
    p.add_argument("--protocol", choices=PROTOCOLS, default="auto",
                   help="auto (default): the protocol recognised in the recording; paper: rests and full turns about x, y, z; "
                        "ferraris: six static poses and three turns; multi-position: re-orientations between rests, with the "
                        "accelerometer")
    p.add_argument("--sections", type=Path, default=None, metavar="FILE",
                   help="imucal's section list (JSON: {\"x_p\": {\"start\": 540, \"end\": 1271}, ...}, sample positions, end "
                        "exclusive) used instead of stage detection; a file's own 'part' column is used without it")


def recording_input(args: argparse.Namespace) -> RecordingInput:
    """The recording named on the command line as one input (its file, ``--accel``, ``--sections`` read from disk)."""
    from calib.errors import RecordingError
    from calib.io.inputs import file_input

    layout = getattr(args, "layout", "auto")
    accel = getattr(args, "accel", None)
    if accel is not None and layout != "imu_tk":
        raise RecordingError("--accel FILE names imu_tk's separate accelerometer file: give it with --layout imu_tk, or "
                             "leave it out when FILE holds the accelerometer's columns")
    if layout == "imu_tk" and accel is None:
        raise RecordingError("--layout imu_tk reads the gyroscope FILE and the accelerometer from --accel FILE; give both")
    options = ReadOptions(layout=layout, fs=args.fs, gyro_counts_per_dps=getattr(args, "gyro_counts_per_dps", None),
                          accel_counts_per_g=getattr(args, "accel_counts_per_g", None),
                          protocol=getattr(args, "protocol", "auto"))
    return file_input(args.file, options, accel, getattr(args, "sections", None))


def read_recording_args(args: argparse.Namespace) -> ReadRecording:
    """The recording named on the command line, read (``file``, ``--fs``, ``--layout``, ``--accel``, the
    sensitivities, ``--protocol``, ``--sections``)."""
    from calib.errors import SampleRateUnknownError
    from calib.io.inputs import read_input

    try:
        return read_input(recording_input(args))
    except SampleRateUnknownError as exc:
        raise SampleRateUnknownError(f"{exc}; on the command line: --fs HZ") from None


def error_json(exc: Exception, code: str, stages: list[Any]) -> str:
    """The one JSON object a failed command prints with ``--json``."""
    return json.dumps({"error": {"code": code, "message": str(exc), "stages": [s.to_dict() for s in stages]}})


def writable(path: Path, what: str) -> Path:
    """``path`` if a file can be written there, else OutputError saying why (checked before any work is done)."""
    from calib.errors import OutputError

    folder = path.expanduser().resolve().parent
    if not folder.is_dir():
        raise OutputError(f"cannot write the {what} to {path}: the folder {folder} does not exist; create it or choose another path")
    if not os.access(folder, os.W_OK):
        raise OutputError(f"cannot write the {what} to {path}: the folder {folder} is not writable")
    if path.is_dir():
        raise OutputError(f"cannot write the {what} to {path}: that is a folder; give a file name such as {path / 'plot.png'}")
    return path
