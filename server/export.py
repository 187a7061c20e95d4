"""An accepted calibration written for other tools: gyrocal's JSON, imucal's calibration file, OpenVINS's IMU
intrinsics (calib.exports.openvins), or CSV."""

from __future__ import annotations

import csv
import io
import json

from calib.apply.correction import Correction

from .store.records import CalibrationRecord


def export_text(cal: CalibrationRecord, fmt: str) -> tuple[str, str, str]:
    """(text, media type, file extension) of ``cal`` in format ``fmt``: gyrocal, imucal, openvins or csv. GyrocalError
    when the calibration cannot be written so (OpenVINS needs the accelerometer's calibration)."""
    record = cal.model_dump(mode="json")
    if fmt == "openvins":
        from calib.exports.openvins import openvins_imu_chain

        comment = f"calibration #{cal.id} of {cal.device_id}, accepted by {cal.operator} at {cal.accepted_at.isoformat()} ({cal.method})"
        return openvins_imu_chain(Correction.from_json(record), comment=comment), "application/yaml", ".kalibr_imu_chain.yaml"
    if fmt == "imucal":
        corr = Correction.from_json(record)
        comment = (f"gyrocal calibration #{cal.id} of {cal.device_id}, accepted by {cal.operator} at {cal.accepted_at.isoformat()} "
                   f"({cal.method}); gyrocal's g = K (m - G a) + b written as imucal's Ferraris model")
        return json.dumps(corr.to_imucal(comment), indent=2), "application/json", ".imucal.json"
    if fmt == "csv":
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        w.writerow(["parameter", "axis", "value", "std", "unit"])
        for name, unit in (("k", ""), ("b", "deg/s")):
            stds = (getattr(cal.uncertainty, name) if cal.uncertainty is not None else None) or [None] * 3
            for axis, v, sd in zip("xyz", getattr(cal, name), stds, strict=True):
                w.writerow([name, axis, repr(float(v)), "" if sd is None else repr(float(sd)), unit])
        for name, matrix, unit in (("K", cal.K, ""), ("G", cal.G, "(deg/s)/g")):
            for i, row in enumerate(matrix or []):
                for j, v in enumerate(row):
                    w.writerow([f"{name}_{'xyz'[i]}{'xyz'[j]}", "", repr(float(v)), "", unit])
        return out.getvalue(), "text/csv", ".csv"
    return json.dumps(record, indent=2), "application/json", ".json"
