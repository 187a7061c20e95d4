"""The query parameters that say how to read an uploaded recording beyond its layout, shared by the upload
routes that calibrate it and those that diagnose it: the protocol, labelled sections, raw-count sensitivities."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import Depends, Query

from ..workers.compute import UploadOptions

MAX_SECTIONS_TEXT = 4000


def upload_options(
    protocol: Annotated[Literal["auto", "paper", "ferraris", "multi-position"], Query(
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
) -> UploadOptions:
    """The upload's options from its query parameters."""
    return UploadOptions(protocol, sections, gyro_counts_per_dps, accel_counts_per_g)


Upload = Annotated[UploadOptions, Depends(upload_options)]
