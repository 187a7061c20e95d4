"""The Movella DOT decoders (wearable_protocol.vendors.movella_dot) against the layouts of Movella's BLE service
specification (XD0506P rev. C): Table 6 (device info, 34 bytes), Table 7 (device control, 32 bytes), Table 13
(measurement control, 3 bytes: type, action, payload mode), Table 15/17 (Rate quantities: u32 time stamp in us,
acceleration in m/s^2 and angular velocity in deg/s as float32, little-endian, the medium characteristic's 40 bytes
zero-filled). Movella publishes no example bytes for these, so the tests build them from the tables."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.link.adapters.movella_dot import DotDecoder
from server.link.base import LinkStats
from wearable_protocol import DecodeError
from wearable_protocol.models import identify
from wearable_protocol.vendors import movella_dot as dot


def test_uuids_and_the_advertised_names():
    assert dot.MEASUREMENT_SERVICE == "15172000-4947-11e9-8646-d663bd873d93"
    assert dot.MEDIUM_PAYLOAD_CHAR == "15172003-4947-11e9-8646-d663bd873d93"
    assert dot.DEVICE_CONTROL_CHAR == "15171002-4947-11e9-8646-d663bd873d93"
    assert identify("Movella DOT", []).key == "movella-dot" and identify("Xsens DOT", []).key == "movella-dot"


def test_measurement_control_starts_rate_quantities():
    assert dot.Control(1, dot.PayloadMode.RATE_QUANTITIES).encode() == bytes([0x01, 0x01, 0x15])
    assert dot.Control(0, dot.PayloadMode.RATE_QUANTITIES).encode() == bytes([0x01, 0x00, 0x15])
    with pytest.raises(DecodeError, match="type 2"):
        dot.Control.decode(bytes([2, 1, 21]))


def test_device_control_layout():
    rate = dot.DeviceControl.set_output_rate(60).encode()
    assert len(rate) == 32 and rate[0] == 0x10  # visit index: b4, output rate
    assert rate[24:26] == struct.pack("<H", 60)  # after 8 one-byte fields and the 16-byte tag
    ident = dot.DeviceControl.identify_now().encode()
    assert ident[0] == 0x01 and ident[1] == 0x01
    back = dot.DeviceControl.decode(dot.DeviceControl(tag="left thigh", output_rate_hz=30).encode())
    assert back.tag == "left thigh" and back.output_rate_hz == 30


def test_device_info_layout():
    info = dot.DeviceInfo(bytes.fromhex("ccbbaacd22d4"), (2, 6, 0), (2023, 7, 1, 12, 0, 0), 0x0103, 1234567, "XS-T02")
    raw = info.encode()
    assert len(raw) == 34 and raw[6:9] == bytes([2, 6, 0]) and raw[9:11] == struct.pack("<H", 2023)
    assert raw[-6:] == b"XS-T02" and raw[20:28] == struct.pack("<Q", 1234567)
    assert dot.DeviceInfo.decode(raw) == info and info.firmware == "2.6.0"


def test_rate_quantities_layout_and_units():
    raw = struct.pack("<I3f3f", 123456, 0.0, 0.0, 9.80665, 10.0, -20.0, 90.0).ljust(40, b"\0")
    s = dot.decode_rate_quantities(raw)
    assert s.timestamp_us == 123456
    np.testing.assert_allclose(s.accel_g, [0, 0, 1], atol=1e-7)
    np.testing.assert_allclose(s.gyro_dps, [10, -20, 90])
    assert dot.decode_rate_quantities(raw[:28]).timestamp_us == 123456  # a stack that trims the zeros
    with pytest.raises(DecodeError, match="not zero"):
        dot.decode_rate_quantities(raw[:39] + b"\x01")
    with pytest.raises(DecodeError, match="28 to 40 bytes"):
        dot.decode_rate_quantities(raw[:20])


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=48))
def test_arbitrary_bytes_only_raise_decode_error(data):
    for decode in (dot.decode_rate_quantities, dot.Control.decode, dot.DeviceControl.decode, dot.DeviceInfo.decode):
        try:
            decode(data)
        except DecodeError:
            pass


def test_the_microsecond_clock_is_unwrapped_and_its_gaps_are_lost_samples():
    stats = LinkStats()
    d = DotDecoder(stats, 60.0)
    period = 1e6 / 60
    start = (1 << 32) - int(10 * period)  # ten samples before the u32 clock wraps
    stamps = [int(round(start + i * period)) for i in range(40) if i not in (15, 16, 17)]  # three lost after the wrap
    batches = [d.feed(dot.encode_rate_quantities(ts & 0xFFFFFFFF, [0, 0, 1], [0, 0, 0])) for ts in stamps]
    assert all(b is not None for b in batches)
    t = np.concatenate([b.t_device_s for b in batches])
    seq = np.concatenate([b.seq for b in batches])
    assert np.all(np.diff(t) > 0) and t[-1] == pytest.approx(39 / 60, abs=1e-5)
    assert stats.lost_samples == 3 and seq.tolist() == [i for i in range(40) if i not in (15, 16, 17)]
    assert d.feed(dot.encode_rate_quantities(stamps[-1] & 0xFFFFFFFF, [0, 0, 1], [0, 0, 0])) is None  # a replay
    assert stats.duplicate_packets == 1
