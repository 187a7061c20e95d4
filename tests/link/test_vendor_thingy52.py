"""The Thingy:52 Motion service decoders (wearable_protocol.vendors.thingy52). Nordic publishes no example
bytes for the raw data, so these are built from the firmware's packed structs (Nordic-Thingy52-FW,
include/ble_services/ble_tms.h: ble_tms_raw_t = int16 accel x y z, gyro x y z, compass x y z;
ble_tms_config_t = u16 u16 u16 u16 u8) and its fixed-point formats (include/drivers/drv_motion.h:
accelerometer 10, gyroscope 5, compass 4 fraction bits)."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wearable_protocol import DecodeError
from wearable_protocol.vendors import thingy52 as th


def test_raw_data_layout_and_fixed_point():
    # 1 g on z (1024 counts), -0.5 g on x; 90 deg/s about y (2880 counts); compass 16 uT on x (256 counts)
    data = struct.pack("<9h", -512, 0, 1024, 0, 2880, -32, 256, 0, 0)
    s = th.decode_raw(data)
    assert s.accel_g.tolist() == [-0.5, 0.0, 1.0]
    assert s.gyro_dps.tolist() == [0.0, 90.0, -1.0]
    assert s.compass_ut.tolist() == [16.0, 0.0, 0.0]
    assert th.encode_raw(s.accel_g, s.gyro_dps, s.compass_ut) == data


def test_configuration_layout_and_limits():
    cfg = th.MotionConfig(200, 500, 1000, 100, 0)
    assert cfg.encode() == bytes([0xC8, 0x00, 0xF4, 0x01, 0xE8, 0x03, 0x64, 0x00, 0x00])
    assert th.MotionConfig.decode(cfg.encode()) == cfg
    with pytest.raises(DecodeError, match="out of range"):
        th.MotionConfig.decode(struct.pack("<HHHHB", 100, 100, 100, 201, 0))
    assert th.MOTION_SERVICE == "ef680400-9b35-4933-9b10-52ffa9740042"
    assert th.RAW_DATA_CHAR == "ef680406-9b35-4933-9b10-52ffa9740042"


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(-32768, 32767), min_size=9, max_size=9))
def test_raw_round_trip(counts):
    data = struct.pack("<9h", *counts)
    s = th.decode_raw(data)
    assert th.encode_raw(s.accel_g, s.gyro_dps, s.compass_ut) == data


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=24))
def test_arbitrary_bytes_only_raise_decode_error(data):
    for decode in (th.decode_raw, th.MotionConfig.decode):
        try:
            decode(data)
        except DecodeError:
            pass


def test_gyro_resolution_is_a_32nd_of_a_degree_per_second():
    assert np.allclose(th.decode_raw(th.encode_raw([0, 0, 1], [0.03125, -0.03125, 1000.0])).gyro_dps, [0.03125, -0.03125, 1000.0])
