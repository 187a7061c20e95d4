"""The rules for applying a calibration to a recording: never to another sensor; across a power-up or a temperature
change beyond the limit with a warning; what cannot be compared is said to be unknown, not assumed."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from calib.apply.identity import IdentityError, SensorIdentity, WrongSensor, check_identity, same_power_up

T0 = datetime(2026, 11, 20, 8, 0, tzinfo=UTC)
CAL = SensorIdentity(device_id="ward-3", sensor_model="ICM-20948", serial="A1", firmware="1.2.0", boot_count=7,
                     booted_at=T0, temperature_c=31.0)


def test_the_same_sensor_power_up_and_temperature_pass_without_a_warning() -> None:
    check = check_identity(CAL, SensorIdentity(device_id="ward-3", serial="a1 ", boot_count=7, temperature_c=32.5))
    assert (check.sensor, check.power_up, check.temperature, check.refusal, check.warnings) == ("same", "same", "same", None, ())
    assert check.temperature_change_c == 1.5
    check.raise_if_refused()


@pytest.mark.parametrize("other", [SensorIdentity(serial="B2"), SensorIdentity(device_id="ward-4")])
def test_another_sensor_is_refused_and_says_which(other: SensorIdentity) -> None:
    check = check_identity(CAL, other)
    assert check.sensor == "different" and check.refusal is not None and "another sensor" in check.refusal
    with pytest.raises(WrongSensor, match="calibrate this one"):
        check.raise_if_refused()


def test_another_sensor_model_name_warns_but_is_not_an_identity() -> None:
    check = check_identity(CAL, SensorIdentity(serial="A1", sensor_model="GC-1 wearable"))
    assert check.refusal is None and check.sensor == "same" and "not an identity" in check.warnings[0]


def test_another_power_up_and_a_warmer_recording_warn() -> None:
    check = check_identity(CAL, SensorIdentity(serial="A1", boot_count=8, temperature_c=36.0), max_temperature_change_c=3.0)
    assert check.refusal is None and (check.power_up, check.temperature) == ("different", "different")
    assert "power-up #7" in check.warnings[0] and "power-up #8" in check.warnings[0]
    assert "5.0 degC warmer" in check.warnings[1] and "3 degC limit" in check.warnings[1]
    assert check_identity(CAL, SensorIdentity(temperature_c=27.0), max_temperature_change_c=5.0).warnings == ()


def test_without_a_boot_count_the_power_up_is_told_by_its_start() -> None:
    cal = SensorIdentity(booted_at=T0)
    assert same_power_up(cal, SensorIdentity(booted_at=T0 + timedelta(seconds=2))) is True  # read latency, whole seconds
    assert same_power_up(cal, SensorIdentity(booted_at=T0 + timedelta(minutes=5))) is False
    assert same_power_up(cal, SensorIdentity()) is None
    check = check_identity(SensorIdentity(), SensorIdentity(serial="A1", boot_count=3, temperature_c=20.0))
    assert (check.sensor, check.power_up, check.temperature, check.warnings) == ("unknown", "unknown", "unknown", ())


def test_identity_round_trips_and_bad_fields_are_named() -> None:
    assert SensorIdentity.from_json(CAL.to_json()) == CAL
    assert SensorIdentity.from_json({"booted_at": "2026-11-20T08:00:00"}).booted_at == T0  # naive: UTC
    assert SensorIdentity.from_json(None) == SensorIdentity()
    for bad, field in (({"boot_count": -1}, "boot_count"), ({"boot_count": True}, "boot_count"),
                       ({"temperature_c": "warm"}, "temperature_c"), ({"booted_at": "monday"}, "booted_at"),
                       ({"serial": 12}, "serial")):
        with pytest.raises(IdentityError, match=field):
            SensorIdentity.from_json(bad)
    assert CAL.completed(SensorIdentity(serial="Z", firmware="9")) == CAL
    assert SensorIdentity(serial="A1").completed(CAL) == CAL
