"""One way in for every recording: the file (or upload) and everything said about how to read it, whichever door it
comes through (``gyrocal calibrate``/``diagnose``, the service's upload routes, the page's upload, which posts to
them). ``read_input`` is the only function that turns such an input into a Recording, its labelled sections and the
protocol to take it as; every door builds a ``RecordingInput`` and calls it.

Layouts a user chooses (``LAYOUTS``): ``auto`` (from the header), ``native``, ``imucal`` (raw counts when the
sensitivities are given) and ``imu_tk`` (two files: the gyroscope's, then the accelerometer's). The sensitivities
apply to every raw-count layout the same way: imu_tk's files without them are read with the Xsens test data's.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

from calib.errors import RecordingError
from calib.io.section import Section
from calib.recording import Recording
from calib.units import DEG

LAYOUTS = ("auto", "native", "imucal", "imu_tk")
PROTOCOLS = ("auto", "paper", "ferraris", "multi-position")


@dataclass(frozen=True)
class ReadOptions:
    """How to read a recording and what to take it as, beyond its bytes: the layout, the sample rate (for a file
    without a time column), raw-count sensitivities, the protocol, and imucal's section list (JSON text)."""

    layout: str = "auto"
    fs: float | None = None
    gyro_counts_per_dps: float | None = None
    accel_counts_per_g: float | None = None
    protocol: str = "auto"
    sections: str | None = None

    def check(self) -> None:
        """RecordingError naming the choices when the layout or the protocol is not one gyrocal knows."""
        if self.layout not in LAYOUTS:
            raise RecordingError(f"unknown layout {self.layout!r}: choose one of {', '.join(LAYOUTS)}")
        if self.protocol not in PROTOCOLS:
            raise RecordingError(f"unknown protocol {self.protocol!r}: choose one of {', '.join(PROTOCOLS)}")

    @property
    def counts(self) -> bool:
        """Whether the file holds raw counts (a sensitivity was given)."""
        return self.gyro_counts_per_dps is not None or self.accel_counts_per_g is not None


@dataclass(frozen=True)
class RecordingInput:
    """One recording as it arrives: its bytes, its name in messages, how to read it, and for imu_tk's layout the
    accelerometer's file (``data`` then being the gyroscope's)."""

    data: bytes
    source: str
    options: ReadOptions = ReadOptions()
    accel_data: bytes | None = None
    sections_where: str = "the section list"  # how messages name the section list (its file, or the parameter)


@dataclass(frozen=True)
class ReadRecording:
    """A recording read, with the labelled sections it is to be cut by (None: detect the stages) and the protocol
    asked for."""

    recording: Recording
    sections: tuple[Section, ...] | None
    protocol: str


def read_input(inp: RecordingInput) -> ReadRecording:
    """The recording ``inp`` holds, its sections and protocol; RecordingError saying what is wrong and how to fix it."""
    from calib.io.sections import parse_sections

    opts = inp.options
    opts.check()
    if opts.layout == "imu_tk":
        rec = _imu_tk(inp)
    else:
        from calib.io.readers import parse_recording_text

        layout = "imucal_counts" if opts.counts and opts.layout in ("auto", "imucal") else opts.layout
        rec = parse_recording_text(inp.data, opts.fs, layout, inp.source, gyro_counts_per_dps=opts.gyro_counts_per_dps,
                                   accel_counts_per_g=opts.accel_counts_per_g)
    sections = None if opts.sections is None else parse_sections(opts.sections, len(rec), inp.sections_where)
    return ReadRecording(rec, sections, opts.protocol)


def _imu_tk(inp: RecordingInput) -> Recording:
    """imu_tk's gyroscope and accelerometer files, with the sensitivities given (else the Xsens test data's)."""
    from calib.io.imu_tk import XSENS_ACCEL_COUNTS_PER_G, XSENS_GYRO_COUNTS_PER_RAD_S, parse_imu_tk

    if inp.accel_data is None:
        raise RecordingError("imu_tk's layout is two files: give the accelerometer's file with the gyroscope's")
    opts = inp.options
    counts_per_rad_s = XSENS_GYRO_COUNTS_PER_RAD_S if opts.gyro_counts_per_dps is None else opts.gyro_counts_per_dps / DEG
    return parse_imu_tk(_text(inp.data, "gyroscope"), _text(inp.accel_data, "accelerometer"), inp.source, counts_per_rad_s,
                        XSENS_ACCEL_COUNTS_PER_G if opts.accel_counts_per_g is None else opts.accel_counts_per_g)


def _text(data: bytes, what: str) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise RecordingError(f"the {what} file is not text: imu_tk's files are rows 't x y z' of numbers") from None


def file_input(path: str | os.PathLike[str], options: ReadOptions = ReadOptions(),
               accel_path: str | os.PathLike[str] | None = None,
               sections_path: str | os.PathLike[str] | None = None) -> RecordingInput:
    """The input of a recording on disk (imu_tk: ``path`` the gyroscope's file, ``accel_path`` the accelerometer's),
    with an imucal section list file."""
    from calib.io.readers import read_file_bytes

    p = Path(path)
    source = p.name if accel_path is None else f"{p.name} + {Path(accel_path).name}"
    accel = None if accel_path is None else read_file_bytes(accel_path, "accelerometer file")
    where = "the section list"
    if sections_path is not None:
        from calib.io.sections import section_list_text

        where = f"the section list {sections_path}"
        options = replace(options, sections=section_list_text(sections_path))
    return RecordingInput(read_file_bytes(p), source, options, accel, where)
