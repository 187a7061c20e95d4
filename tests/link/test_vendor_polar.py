"""The Polar PMD decoders (wearable_protocol.vendors.polar_pmd) against the byte sequences of Polar's own SDK
unit tests (github.com/polarofficial/polar-ble-sdk, sources/Android/android-communications/library/src/test/
java/com/polar/androidcommunications/api/ble/model/gatt/client/pmd/...), then round trips of our encoders."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wearable_protocol import DecodeError
from wearable_protocol.vendors import polar_pmd as pmd


def _f32(bits: int) -> float:
    return float(np.array([bits & 0xFFFFFFFF], np.uint32).view(np.float32)[0])


def test_gyro_compressed_type_0_from_polars_gyrdatatest():
    # model/GyrDataTest.kt, "process gyro compressed data type 0"
    header = bytes([0x05, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x7F, 0x80])
    content = bytes([0xEA, 0xFF, 0x08, 0x00, 0x0D, 0x00, 0x03, 0x01, 0xDF, 0x00])
    frame = pmd.decode_frame(header + content)
    assert frame.measurement == pmd.MeasurementType.GYRO and frame.compressed and frame.frame_type == 0
    assert frame.timestamp_ns == 9223372036854775807
    assert frame.values.tolist() == [[-22, 8, 13], [-23, 11, 16]]


def test_gyro_compressed_type_1_float_from_polars_gyrdatatest():
    # model/GyrDataTest.kt, "process gyro compressed data type 1" (and "... with factor", factor 0.5)
    header = bytes([0x05, 0x00, 0x94, 0x35, 0x77, 0x00, 0x00, 0x00, 0x00, 0x81])
    content = bytes([0x00, 0x00, 0x80, 0x3F, 0x00, 0x00, 0x20, 0x41, 0x00, 0x00, 0xA0, 0x41, 0x1C, 0x01,
                     0x00, 0x00, 0xA0, 0x01, 0x00, 0x00, 0x08, 0xCD, 0xCC, 0xEC, 0x0D])
    frame = pmd.decode_frame(header + content)
    assert frame.timestamp_ns == 2000000000 and frame.frame_type == 1
    expected = [[_f32(0x3F800000), _f32(0x41200000), _f32(0x41A00000)],
                [_f32(0x3F800000 + 0x1A00000), _f32(0x41200000 + 0x0800000), _f32(0x41A00000 + 0xFDECCCCD)]]
    assert frame.values.tolist() == expected
    assert np.array_equal(frame.scaled(0.5), 0.5 * np.array(expected))


def test_settings_from_polars_pmdsettingtest():
    # PmdSettingTest.kt, testPmdSettingsWithRange: 52 Hz, 16 bits, ranges 245/500/1000/2000, 3 channels
    data = bytes([0x00, 0x01, 0x34, 0x00, 0x01, 0x01, 0x10, 0x00, 0x02, 0x04, 0xF5, 0x00, 0xF4, 0x01,
                  0xE8, 0x03, 0xD0, 0x07, 0x04, 0x01, 0x03])
    s = pmd.parse_settings(data)
    assert s == {pmd.SettingType.SAMPLE_RATE: (52,), pmd.SettingType.RESOLUTION: (16,),
                 pmd.SettingType.RANGE: (245, 500, 1000, 2000), pmd.SettingType.CHANNELS: (3,)}
    # testPmdSettingWithRangeMilliUnit: two 4-byte values (-1 and 0xFF), then resolution 14
    data = bytes([0x03, 0x02, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x00, 0x00, 0x00, 0x01, 0x01, 0x0E, 0x00])
    assert pmd.parse_settings(data) == {pmd.SettingType.RANGE_MILLIUNIT: (-1, 0xFF), pmd.SettingType.RESOLUTION: (14,)}
    assert pmd.encode_settings({pmd.SettingType.SAMPLE_RATE: 52, pmd.SettingType.RESOLUTION: 16,
                                pmd.SettingType.RANGE: (245, 500, 1000, 2000), pmd.SettingType.CHANNELS: 3}) == bytes(
        [0x00, 0x01, 0x34, 0x00, 0x01, 0x01, 0x10, 0x00, 0x02, 0x04, 0xF5, 0x00, 0xF4, 0x01, 0xE8, 0x03, 0xD0, 0x07, 0x04, 0x01, 0x03])


def test_control_point_replies_from_polars_responsetest():
    # BlePmdClientControlPointResponseTest.kt: a success with 3 parameter bytes, and an error without
    ok = pmd.ControlResponse.decode(bytes([0xF0, 0x01, 0x02, 0x00, 0x00, 0xFF, 0xFF, 0xFF]))
    assert (ok.opcode, ok.measurement, ok.status, ok.more, ok.parameters) == (1, 2, 0, False, b"\xff\xff\xff")
    err = pmd.ControlResponse.decode(bytes([0xF0, 0x01, 0x06, 0x07, 0x00]))
    assert (err.measurement, err.status, err.parameters, err.status_name) == (6, 7, b"", "invalid_resolution")
    assert pmd.ControlResponse.decode(ok.encode()) == ok


def test_sample_times_follow_polars_rule():
    # PmdTimeStampUtils.kt: the frame's stamp is its last sample's; a first frame is spaced by the rate
    t = pmd.sample_times_ns(0, 1_000_000_000, 4, 100.0)
    assert t.tolist() == [970_000_000, 980_000_000, 990_000_000, 1_000_000_000]
    t = pmd.sample_times_ns(1_000_000_000, 1_040_000_000, 4, 100.0)
    assert t.tolist() == [1_010_000_000, 1_020_000_000, 1_030_000_000, 1_040_000_000]
    with pytest.raises(DecodeError, match="clock"):
        pmd.sample_times_ns(1_040_000_000, 1_040_000_000, 4, 100.0)


def test_factor_is_a_floats_bits_and_features_round_trip():
    assert pmd.factor_value(pmd.factor_bits(0.0305)) == pytest.approx(0.0305, rel=1e-7)
    assert pmd.factor_bits(1.0) == 0x3F800000
    types = {pmd.MeasurementType.GYRO, pmd.MeasurementType.ACC}
    assert pmd.parse_features(pmd.encode_features(types)) == types


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(*[st.integers(-32768, 32767)] * 3), min_size=1, max_size=60), st.booleans(),
       st.integers(1, 2**63 - 1))
def test_frames_round_trip(samples, compressed, ts):
    v = np.array(samples, dtype=np.int64)
    data = pmd.encode_frame(pmd.MeasurementType.GYRO, ts, v, compressed=compressed)
    frame = pmd.decode_frame(data)
    assert frame.timestamp_ns == ts and frame.compressed == compressed
    assert np.array_equal(frame.values, v)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=80))
def test_arbitrary_bytes_only_raise_decode_error(data):
    for decode in (pmd.decode_frame, pmd.parse_settings, pmd.ControlResponse.decode, pmd.parse_features):
        try:
            decode(data)
        except DecodeError:
            pass


def test_accelerometer_frame_sizes_follow_the_sdk():
    # AccData.kt: compressed type 1 is int16 per axis, type 0 int8, type 2 int24
    ref = struct.pack("<hhh", -1000, 5, 1000)
    frame = pmd.decode_frame(struct.pack("<BQB", 2, 10, 0x81) + ref)
    assert frame.values.tolist() == [[-1000, 5, 1000]]
    raw24 = b"".join(v.to_bytes(3, "little", signed=True) for v in (-70000, 1, 70000))
    assert pmd.decode_frame(struct.pack("<BQB", 2, 10, 0x02) + raw24).values.tolist() == [[-70000, 1, 70000]]
