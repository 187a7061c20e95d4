"""gyrocal's Python API: the numerics a researcher calls from a notebook, one function per thing to do.

Every function here is also ``calib.<name>`` (``import calib; calib.read(...)``; names that are not those of calib's
packages, so ``calib.noise_report``, not ``calib.noise``), and the results are the types the
command line prints as JSON (``to_json()`` or ``to_dict()`` gives the same fields). Nothing here imports the
service, its database or Bluetooth: a service's calibrations are fetched over its REST API with the standard
library. Units everywhere: rates in deg/s, specific force in g, times in s, the model g = K m + b (docs/method.md).
"""

from __future__ import annotations

import json
import os
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path
from typing import TYPE_CHECKING

from calib.errors import GyrocalError
from calib.recording import Recording

if TYPE_CHECKING:
    from calib.apply.correction import Correction
    from calib.diagnosis.assemble import Diagnosis
    from calib.noise.analysis import NoiseReport
    from calib.result import CalibrationResult
    from calib.simulator.simulate import Truth
    from calib.watch.report import WatchReport

PathLike = str | os.PathLike[str]


def read(path: PathLike, *, layout: str = "auto", fs: float | None = None, accel: PathLike | None = None,
         gyro_counts_per_dps: float | None = None, accel_counts_per_g: float | None = None,
         sections: PathLike | None = None) -> Recording:
    """A recording from disk, in any layout the command line reads (``native``, ``imucal``, ``imu_tk`` with ``accel``
    the accelerometer's file, ``auto`` from the header); raw counts with the sensitivities given; ``sections`` an
    imucal section list (JSON) whose labelled sections replace stage detection. RecordingError says what is wrong
    with a file and how to fix it."""
    from dataclasses import replace

    from calib.io.inputs import ReadOptions, file_input, read_input

    options = ReadOptions(layout=layout, fs=fs, gyro_counts_per_dps=gyro_counts_per_dps, accel_counts_per_g=accel_counts_per_g)
    read = read_input(file_input(path, options, accel, sections))
    return read.recording if read.sections is None else replace(read.recording, meta=replace(read.recording.meta, sections=read.sections))


def calibrate(rec: Recording, *, protocol: str = "auto", method: str | None = None,
              heading_prior_deg: float | None = None) -> CalibrationResult:
    """Calibrate a recording (the paper's protocol, Ferraris', or re-orientations between rests: ``protocol``), as
    ``gyrocal calibrate`` does; a Refusal (a GyrocalError) says why a recording cannot be calibrated."""
    from calib.estimators.registry import DEFAULT_METHOD
    from calib.pipeline import calibrate_protocol

    result, _ = calibrate_protocol(rec, protocol, method or DEFAULT_METHOD, heading_prior_deg=heading_prior_deg)
    return result


def diagnose(rec: Recording, *, protocol: str = "auto") -> Diagnosis:
    """Compare the recording with its simulation and name the physics the model leaves out (``gyrocal diagnose``)."""
    from calib.diagnosis import diagnose as run

    return run(rec, protocol=protocol)


def noise_report(rec: Recording) -> NoiseReport:
    """Each axis's Allan deviation of a long rest and its noise density, bias instability and random walk with 95 %
    intervals (``gyrocal noise``)."""
    from calib.noise.analysis import noise as run

    return run(rec)


def load_calibration(path: PathLike) -> Correction:
    """A calibration file: gyrocal's JSON (a stored calibration, an export, a result's JSON) or imucal's."""
    from calib.apply.correction import read_correction

    return read_correction(path)


def fetch_calibration(service: str, device_id: str, *, token: str | None = None, at: str | None = None,
                      timeout_s: float = 10.0) -> Correction:
    """The calibration in force for ``device_id`` from a gyrocal service's history (``GET /devices/{id}/calibration``,
    at ``at``, ISO 8601, default now); ``token`` when the service asks for one to read."""
    from calib.apply.correction import Correction

    url = f"{service.rstrip('/')}/devices/{urllib.parse.quote(device_id, safe='')}/calibration"
    if at is not None:
        url += "?" + urllib.parse.urlencode({"at": at})
    request = urllib.request.Request(url, headers={"Accept": "application/json",
                                                   **({"Authorization": f"Bearer {token}"} if token else {})})
    try:
        with urllib.request.urlopen(request, timeout=timeout_s) as response:  # noqa: S310 (the user's own service)
            body = json.loads(response.read())
    except urllib.error.HTTPError as exc:
        detail = ""
        try:
            detail = json.loads(exc.read()).get("detail", "")
        except (ValueError, AttributeError):
            pass
        raise GyrocalError(f"the service at {service} answered {exc.code} for {device_id!r}: {detail or exc.reason}") from None
    except (urllib.error.URLError, TimeoutError, OSError) as exc:
        raise GyrocalError(f"cannot reach the service at {service} ({getattr(exc, 'reason', exc)}); is it running?") from None
    return Correction.from_json(body)


def correct(rec: Recording, calibration: Correction | CalibrationResult) -> Recording:
    """The recording corrected by a calibration (a Correction, or a CalibrationResult): rates K (m - G a) + b, and the
    accelerometer's A (r - o) when it was calibrated."""
    from calib.apply.correction import Correction, corrected

    if not isinstance(calibration, Correction):
        calibration = Correction.from_result(calibration)
    return corrected(rec, calibration)


def watch_report(rec: Recording, calibration: Correction, *, temp_cal_c: float | None = None) -> WatchReport:
    """Whether a study recording still agrees with a calibration (``gyrocal watch``)."""
    from calib.watch.run import watch as run

    return run(rec, calibration, temp_cal_c)


def simulate(seed: int, *, noise: float = 0.03, fs: float = 104.0, protocol: str = "paper") -> tuple[Recording, Truth]:
    """A simulated recording of the paper's protocol (or ``extended``) with its truth (``gyrocal simulate``)."""
    from calib.simulator import extended_script_for_seed
    from calib.simulator import simulate as run

    if protocol not in ("paper", "extended"):
        raise GyrocalError(f"unknown protocol {protocol!r}: choose paper or extended")
    script = extended_script_for_seed(seed) if protocol == "extended" else None
    return run(seed, noise=noise, fs=fs, script=script)


def write_csv(rec: Recording, path: PathLike) -> Path:
    """Write a recording as gyrocal's native CSV (t, gx, gy, gz, and ax, ay, az, temp when recorded)."""
    from calib.io.readers import write_native_csv

    write_native_csv(rec, Path(path))
    return Path(path)


def kalibr_imu_yaml(report: NoiseReport, *, topic: str = "/imu0", rate_hz: float | None = None) -> str:
    """Kalibr's imu.yaml from a rest's noise (calib.exports.kalibr)."""
    from calib.exports.kalibr import kalibr_imu_yaml as write

    return write(report, topic, rate_hz)


def openvins_imu_chain(calibration: Correction | CalibrationResult, noise: NoiseReport | None = None, *,
                       topic: str = "/imu0", rate_hz: float | None = None) -> str:
    """OpenVINS's kalibr_imu_chain.yaml with a calibration's intrinsics (calib.exports.openvins)."""
    from calib.apply.correction import Correction
    from calib.exports.openvins import openvins_imu_chain as write

    if not isinstance(calibration, Correction):
        calibration = Correction.from_result(calibration)
    return write(calibration, noise, topic, rate_hz)


__all__ = ["calibrate", "correct", "diagnose", "fetch_calibration", "kalibr_imu_yaml", "load_calibration", "noise_report",
           "openvins_imu_chain", "read", "simulate", "watch_report", "write_csv"]
