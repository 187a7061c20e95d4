"""The query parameters that say which sensor, power-up and temperature a recording comes from, shared by the routes
that look up or apply the calibration in force (docs/lifecycle.md, "Identity")."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated

from fastapi import Depends, Query

from calib.apply.identity import SensorIdentity

from .. import schemas as M


def recording_identity(
    serial: Annotated[str | None, Query(min_length=1, max_length=128, pattern=M.SENSOR_TEXT,
                                        description="the serial or chip id of the sensor the recording comes from")] = None,
    sensor_model: Annotated[str | None, Query(min_length=1, max_length=128, pattern=M.SENSOR_TEXT,
                                              description="the recording's sensor model (e.g. ICM-20948)")] = None,
    boot_count: Annotated[int | None, Query(ge=0, le=0xFFFFFFFF, description="the device's power-up count during the "
                                            "recording: a calibration of that power-up is taken first")] = None,
    booted_at: Annotated[datetime | None, Query(description="when the device was switched on before the recording (ISO "
                                                "8601), for a device that keeps no power-up count")] = None,
    temperature_c: Annotated[float | None, Query(ge=-60, le=150, description="the sensor's temperature during the "
                                                 "recording, degC (a recording's temp column gives it too)")] = None,
) -> SensorIdentity:
    """The recording's identity from the query (every field optional)."""
    return SensorIdentity.from_json({"serial": serial, "sensor_model": sensor_model, "boot_count": boot_count,
                                     "booted_at": booted_at, "temperature_c": temperature_c})


RecordingIdentity = Annotated[SensorIdentity, Depends(recording_identity)]
