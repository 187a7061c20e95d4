"""The query parameters that say how to read an uploaded recording beyond its layout and rate, shared by the upload
routes that calibrate, apply, verify and diagnose it: the protocol, labelled sections, raw-count sensitivities. They
are calib's ``ReadOptions``, the same the command line builds; ``upload_input`` makes the one ``RecordingInput`` every
door reads through."""

from __future__ import annotations

from dataclasses import replace
from typing import Annotated, Literal

from fastapi import Depends, Query

from calib.io.inputs import PROTOCOLS, ReadOptions, RecordingInput

MAX_SECTIONS_TEXT = 4000


def upload_options(
    protocol: Annotated[Literal[PROTOCOLS], Query(  # type: ignore[valid-type]
        description="what the uploaded recording holds: auto (default: the protocol recognised in it), paper (rests and "
                    "full turns about x, y, z), ferraris (six static poses and three turns) or multi-position "
                    "(re-orientations between rests, with the accelerometer)")] = "auto",
    sections: Annotated[str | None, Query(max_length=MAX_SECTIONS_TEXT, description="imucal's section list as JSON text "
                                          '({"x_p": {"start": 540, "end": 1271}, ...}: sample positions, end exclusive), '
                                          "used instead of stage detection")] = None,
    gyro_counts_per_dps: Annotated[float | None, Query(gt=0, le=1e9, description="the CSV holds raw counts: the gyro's "
                                                       "sensitivity in counts per deg/s")] = None,
    accel_counts_per_g: Annotated[float | None, Query(gt=0, le=1e9, description="the CSV holds raw counts: the "
                                                      "accelerometer's sensitivity in counts per g")] = None,
) -> ReadOptions:
    """The upload's options from its query parameters (a blank ``sections`` is none)."""
    return ReadOptions(protocol=protocol, sections=sections if sections and sections.strip() else None,
                       gyro_counts_per_dps=gyro_counts_per_dps, accel_counts_per_g=accel_counts_per_g)


Upload = Annotated[ReadOptions, Depends(upload_options)]


def upload_input(body: bytes, source: str, upload: ReadOptions, fs: float | None, layout: str,
                 accel: bytes | None = None) -> RecordingInput:
    """An uploaded recording as calib's one input: the body (imu_tk: the gyroscope's part, ``accel`` the
    accelerometer's), its rate and layout, and the upload's options."""
    return RecordingInput(body, source, replace(upload, fs=fs, layout=layout), accel, "the sections parameter")
