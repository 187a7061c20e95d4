"""A new calibration that departs from its device's history is named; one that repeats it is not; with fewer than two
earlier calibrations there is no history to depart from."""

from __future__ import annotations

import numpy as np

from calib.judge.departure import departures
from calib.pipeline import calibrate
from calib.simulator import SensorParams, simulate

SENSOR = SensorParams(k=np.array([1.08, 0.93, 1.12]), b=np.array([1.5, -2.0, 0.7]))


def _cal(seed: int, params: SensorParams = SENSOR) -> dict:
    rec, _ = simulate(seed, noise=0.03, params=params)
    return calibrate(rec).to_dict()


def test_a_dropped_sensor_departs_and_a_healthy_one_does_not() -> None:
    # the same sensor at four power-ups: its biases move by up to 0.3 deg/s from one to the next
    history = [_cal(s, SensorParams(k=SENSOR.k, b=SENSOR.b + 0.3 * np.sin(s))) for s in (1, 2, 3)]
    assert departures(_cal(4), history) == []
    # knocked: the x scale factor 4 % off, the y bias 6 deg/s
    damaged = SensorParams(k=SENSOR.k * np.array([1.04, 1.0, 1.0]), b=SENSOR.b + np.array([0.0, 6.0, 0.0]))
    found = {(d.name, d.axis): d for d in departures(_cal(5, damaged), history)}
    assert set(found) == {("k", "x"), ("b", "y")}, found
    assert found[("k", "x")].z > 4 and "3 earlier calibrations" in found[("k", "x")].to_dict()["text"]


def test_no_history_no_departure() -> None:
    far = SensorParams(k=np.array([0.85, 1.15, 1.0]), b=np.zeros(3))
    assert departures(_cal(6, far), [_cal(7)]) == []
