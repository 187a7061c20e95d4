"""The MetaWear encoders and decoders (wearable_protocol.vendors.metawear) against the bytes of MbientLab's own
SDK unit tests (github.com/mbientlab/MetaWear-SDK-Cpp, test/test_gyro_bmi160.py and
test/test_accelerometer_bmi160.py), then round trips of our encoders."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wearable_protocol import DecodeError
from wearable_protocol.vendors import metawear as mw


def test_gyro_commands_from_mbientlabs_tests():
    # TestGyroBmi160Config: 200 Hz at the default 2000 deg/s; 250 deg/s at the default 100 Hz; 50 Hz and 125 deg/s
    assert list(mw.gyro_config(200, 2000)) == [0x13, 0x03, 0x29, 0x00]
    assert list(mw.gyro_config(100, 250)) == [0x13, 0x03, 0x28, 0x03]
    assert list(mw.gyro_config(50, 125)) == [0x13, 0x03, 0x27, 0x04]
    assert list(mw.power(mw.Module.GYROSCOPE, True)) == [0x13, 0x01, 0x01]
    assert list(mw.power(mw.Module.GYROSCOPE, False)) == [0x13, 0x01, 0x00]
    assert list(mw.data_enable(mw.Module.GYROSCOPE, True)) == [0x13, 0x02, 0x01, 0x00]
    assert list(mw.data_enable(mw.Module.GYROSCOPE, False)) == [0x13, 0x02, 0x00, 0x01]
    assert list(mw.subscribe(mw.Module.GYROSCOPE, mw.Register.GYRO_DATA)) == [0x13, 0x05, 0x01]
    assert list(mw.subscribe(mw.Module.GYROSCOPE, mw.Register.GYRO_DATA, False)) == [0x13, 0x05, 0x00]
    assert list(mw.subscribe(mw.Module.GYROSCOPE, mw.Register.GYRO_PACKED)) == [0x13, 0x07, 0x01]
    assert mw.parse_config(bytes([0x13, 0x03, 0x27, 0x04])) == (mw.Module.GYROSCOPE, 50.0, 125)


def test_accelerometer_commands_from_mbientlabs_tests():
    # TestAccBmi160Config: odr codes 12.5-1600 Hz at the default 2 g; 16 g at 100 Hz; 200 Hz and 8 g
    for rate, code in [(12.5, 0x25), (25, 0x26), (50, 0x27), (100, 0x28), (200, 0x29), (400, 0x2A), (800, 0x2B), (1600, 0x2C)]:
        assert list(mw.accel_config(rate, 2)) == [0x03, 0x03, code, 0x03]
    assert list(mw.accel_config(100, 16)) == [0x03, 0x03, 0x28, 0x0C]
    assert list(mw.accel_config(200, 8)) == [0x03, 0x03, 0x29, 0x08]
    assert list(mw.data_enable(mw.Module.ACCELEROMETER, True)) == [0x03, 0x02, 0x01, 0x00]
    assert list(mw.subscribe(mw.Module.ACCELEROMETER, mw.Register.ACC_DATA)) == [0x03, 0x04, 0x01]
    assert list(mw.subscribe(mw.Module.ACCELEROMETER, mw.Register.ACC_PACKED)) == [0x03, 0x1C, 0x01]


def test_gyro_data_from_mbientlabs_tests():
    # TestGyroBmi160DataHandler: 500 deg/s -> (262.409, 499.497, -499.512)
    n = mw.decode_notification(b"\x13\x05\x3e\x43\xff\x7f\x00\x80")
    assert n.module == mw.Module.GYROSCOPE
    assert np.allclose(mw.gyro_dps(n.counts, 500), [[262.409, 499.497, -499.512]], atol=0.0005)
    # TestGyroBmi160HighFreqDataHandler: packed, 1000 deg/s
    n = mw.decode_notification(b"\x13\x07\x09\x15\xad\x26\x08\xde\x8a\x1a\x0d\x26\x65\xe4\x8d\x20\xac\x27\x73\xec")
    expected = [[164.177, 301.860, -265.122], [207.134, 296.982, -215.457], [254.055, 309.634, -152.591]]
    assert np.allclose(mw.gyro_dps(n.counts, 1000), expected, atol=0.0005)


def test_accelerometer_data_from_mbientlabs_tests():
    # TestBmi160AccelerationData: 4 g -> (-1.872, -2.919, -1.495)
    n = mw.decode_notification(b"\x03\x04\x16\xc4\x94\xa2\x2a\xd0")
    assert np.allclose(mw.accel_g(n.counts, 4), [[-1.872, -2.919, -1.495]], atol=0.0005)
    # TestBmi160HighFreqAccData: packed, 8 g
    n = mw.decode_notification(b"\x03\x1c\x62\xb7\x53\x0d\xe9\xfd\x16\xd0\x4d\x0e\x57\x02\x8a\xff\xa1\x05\x0a\x01")
    expected = [[-4.539, 0.833, -0.131], [-2.995, 0.894, 0.146], [-0.029, 0.352, 0.065]]
    assert np.allclose(mw.accel_g(n.counts, 8), expected, atol=0.0005)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from([mw.Module.GYROSCOPE, mw.Module.ACCELEROMETER]), st.sampled_from([1, 3]),
       st.lists(st.integers(-32768, 32767), min_size=9, max_size=9))
def test_notifications_round_trip(module, n, values):
    counts = np.array(values[: 3 * n]).reshape(n, 3)
    decoded = mw.decode_notification(mw.encode_notification(module, counts))
    assert decoded.module == module and np.array_equal(decoded.counts, counts)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=30))
def test_arbitrary_bytes_only_raise_decode_error(data):
    for decode in (mw.decode_notification, mw.parse_config):
        try:
            decode(data)
        except DecodeError:
            pass


def test_unsupported_settings_are_refused():
    with pytest.raises(KeyError):
        mw.gyro_config(104, 500)  # the BMI160 has no 104 Hz
    with pytest.raises(DecodeError, match="length"):
        mw.decode_notification(b"\x13\x05\x00\x00")
