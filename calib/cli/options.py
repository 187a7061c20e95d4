"""The command line's recording options, shared by ``gyrocal calibrate`` and ``gyrocal diagnose``: how to read
the file (layout, sample rate, raw-count sensitivities), which protocol to take it as, and labelled sections."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from calib.io.section import Section
from calib.pipeline import PROTOCOLS
from calib.recording import Recording


def add_reading_arguments(p: argparse.ArgumentParser) -> None:
    """``file`` and the options that say how to read it (layout, sample rate, raw-count sensitivities)."""
    p.add_argument("file", type=Path, help="native CSV (t,gx,gy,gz,...) or imucal layout (gyr_x,...)")
    p.add_argument("--fs", type=float, default=None, help="sample rate in Hz (required when the file has no time column)")
    p.add_argument("--layout", choices=["auto", "native", "imucal", "imu_tk"], default="auto",
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
    p.add_argument("--protocol", choices=list(PROTOCOLS), default="auto",
                   help="auto (default): the protocol recognised in the recording; paper: rests and full turns about x, y, z; "
                        "ferraris: six static poses and three turns; multi-position: re-orientations between rests, with the "
                        "accelerometer")
    p.add_argument("--sections", type=Path, default=None, metavar="FILE",
                   help="imucal's section list (JSON: {\"x_p\": {\"start\": 540, \"end\": 1271}, ...}, sample positions, end "
                        "exclusive) used instead of stage detection; a file's own 'part' column is used without it")


def read_recording_args(args: argparse.Namespace) -> Recording:
    """The recording named on the command line (``file``, ``--fs``, ``--layout``, ``--accel``, the sensitivities)."""
    from calib.errors import RecordingError, SampleRateUnknownError
    from calib.io.readers import read_recording

    layout = getattr(args, "layout", "auto")
    if getattr(args, "accel", None) is not None and layout != "imu_tk":
        raise RecordingError("--accel FILE names imu_tk's separate accelerometer file: give it with --layout imu_tk, or "
                             "leave it out when FILE holds the accelerometer's columns")
    if layout == "imu_tk":
        from calib.io.imu_tk import read_imu_tk

        if getattr(args, "accel", None) is None:
            raise RecordingError("--layout imu_tk reads the gyroscope FILE and the accelerometer from --accel FILE; give both")
        return read_imu_tk(args.file, args.accel)
    gyro_sens, accel_sens = getattr(args, "gyro_counts_per_dps", None), getattr(args, "accel_counts_per_g", None)
    if gyro_sens is not None or accel_sens is not None:
        layout = "imucal_counts" if layout in ("auto", "imucal") else layout
    try:
        return read_recording(args.file, fs=args.fs, layout=layout, gyro_counts_per_dps=gyro_sens,
                              accel_counts_per_g=accel_sens)
    except SampleRateUnknownError as exc:
        raise SampleRateUnknownError(f"{exc}; on the command line: --fs HZ") from None


def read_sections_arg(args: argparse.Namespace, rec: Recording) -> tuple[Section, ...] | None:
    """The section list of ``--sections FILE`` (None without it)."""
    if getattr(args, "sections", None) is None:
        return None
    from calib.io.sections import read_sections

    return read_sections(args.sections, len(rec))


def error_json(exc: Exception, code: str, stages: list[Any]) -> str:
    """The one JSON object a failed command prints with ``--json``."""
    import json

    return json.dumps({"error": {"code": code, "message": str(exc), "stages": [s.to_dict() for s in stages]}})
