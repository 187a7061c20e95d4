"""Samples lost from a real recording that carries no sample counter (imucal's Ferraris session, 3 % of its rows
dropped in runs of 6-15, the time column written as an even grid afterwards, as a logger numbering what it
received does). The turns read short and k_x rose by 4.5 % in silence. The turns are about the vertical, so the
accelerometer cannot check them, and a jump in a hand turn's rate at 102 Hz does not tell a lost run from the
hand's own jerk: the loss cannot be found in this recording, and the diagnosis says so and why, and calibrate warns,
instead of saying nothing."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from calib.diagnosis import diagnose
from calib.io.readers import read_recording
from calib.pipeline import LOSS_UNSEEN, calibrate_protocol


def _lose(rec, share: float, seed: int):
    rng = np.random.default_rng(seed)
    keep = np.ones(len(rec), dtype=bool)
    while (~keep).sum() < share * len(rec):
        start = int(rng.integers(1, len(rec) - 20))
        keep[start:start + int(rng.integers(6, 16))] = False
    t = rec.t[0] + np.arange(int(keep.sum())) / rec.fs
    return dataclasses.replace(rec, t=t, gyro=rec.gyro[keep], accel=rec.accel[keep], seq=None)


def test_diagnose_says_lost_samples_cannot_be_seen_without_a_counter(real_data: Path) -> None:
    rec = read_recording(real_data / "imucal" / "example_ferraris_session.csv", fs=102.4)
    found = diagnose(_lose(rec, 0.03, 0), n_boot=20)
    reasons = {n["name"]: n["reason"] for n in found.not_identifiable}
    assert "sample_loss" in reasons, reasons
    assert "no sample counter" in reasons["sample_loss"] and "raising its scale factor" in reasons["sample_loss"]
    assert "record the device's sample counter" in reasons["sample_loss"]
    # the session as recorded counts its samples: there the question does not arise
    assert "sample_loss" not in {n["name"] for n in diagnose(rec, n_boot=20).not_identifiable}


def test_calibrate_warns_that_lost_samples_would_pass_unseen_without_a_counter(real_data: Path) -> None:
    """The calibration moves with the loss and nothing in the file can show it: calibrate says so, through the one
    entry point every door calibrates by; with the session's own counter kept it has nothing to say."""
    rec = read_recording(real_data / "imucal" / "example_ferraris_session.csv", fs=102.4)
    lost, _ = calibrate_protocol(_lose(rec, 0.03, 0))
    assert LOSS_UNSEEN in lost.warnings, lost.warnings
    counted, _ = calibrate_protocol(rec)
    assert LOSS_UNSEEN not in counted.warnings
    # stamped times (a device's or a host's clock) show a gap where rows are missing: nothing to warn of
    stamped = dataclasses.replace(rec, seq=None, t=rec.t + np.random.default_rng(1).normal(0, 1e-4, len(rec)))
    assert LOSS_UNSEEN not in calibrate_protocol(stamped)[0].warnings
