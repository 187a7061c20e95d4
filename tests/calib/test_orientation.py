"""The orientation before and after a calibration (ahrs' Madgwick filter): the paper's protocol ends where it began,
so with the true calibration the estimated orientation comes back to the start and with the raw readings it does
not (the paper's Fig. 10); the filter run in chunks gives exactly what one run gives."""

from __future__ import annotations

import numpy as np
import pytest

from calib.apply import orientation as orient
from calib.apply.correction import Correction, corrected
from calib.errors import GyrocalError
from calib.recording import Recording
from calib.simulator import simulate


@pytest.fixture(scope="module")
def recording() -> tuple[Recording, Recording]:
    rec, truth = simulate(3, noise=0.03)
    return rec, corrected(rec, Correction(K=np.diag(truth.k), b=np.asarray(truth.b)))


def test_the_calibrated_orientation_comes_back_to_the_start_and_the_raw_one_does_not(recording) -> None:
    raw, cal = recording
    o = orient.orientation(raw, cal)
    assert "Madgwick" in o.method and o.before.shape == o.after.shape == (len(raw), 4)
    assert np.allclose(np.linalg.norm(o.after, axis=1), 1.0)
    # three full turns and back at rest: the calibrated estimate ends within 1 deg of where it began, the raw one does not
    start_to_end = np.degrees(2 * np.arccos(np.clip(np.abs(o.after[0] @ o.after[-1]), 0, 1)))
    raw_start_to_end = np.degrees(2 * np.arccos(np.clip(np.abs(o.before[0] @ o.before[-1]), 0, 1)))
    assert start_to_end < 1.0 < 10.0 < raw_start_to_end, (start_to_end, raw_start_to_end)
    assert o.difference_deg[-1] == pytest.approx(raw_start_to_end, abs=1.5)
    summary = o.summary(max_points=500)
    assert len(summary["t"]) <= 500 and set(summary["before"]) == {"roll", "pitch", "yaw"}
    cols = o.to_csv().splitlines()
    assert cols[0].split(",")[:5] == ["t", "qw_raw", "qx_raw", "qy_raw", "qz_raw"] and len(cols) == len(raw) + 1


def test_without_an_accelerometer_the_gyroscope_alone_is_integrated(recording) -> None:
    raw, cal = recording
    o = orient.orientation(Recording(t=raw.t, gyro=raw.gyro), Recording(t=cal.t, gyro=cal.gyro))
    assert "integration" in o.method
    assert np.abs(o.angles_after[-1]).max() < 1.0 < 10.0 < np.abs(o.angles_before[-1]).max()


def test_chunks_give_what_one_run_gives(recording, monkeypatch: pytest.MonkeyPatch) -> None:
    raw, cal = recording
    whole = orient.orientation(raw, cal)
    monkeypatch.setattr(orient, "CHUNK", 333)
    done: list[int] = []
    parts = orient.orientation(raw, cal, done.append)
    assert np.array_equal(whole.after, parts.after) and np.array_equal(whole.before, parts.before)
    assert sum(done) == 2 * (len(raw) - 1) and len(done) > 10


def test_mismatched_recordings_are_refused(recording) -> None:
    raw, cal = recording
    with pytest.raises(GyrocalError, match="same samples"):
        orient.orientation(raw, cal.slice(0, 100))
