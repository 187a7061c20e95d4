"""The wearable protocol's encodings: round trips (property-based) and rejection of bad bytes."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import wearable_protocol as wp

raw_samples = st.integers(1, wp.max_samples_per_packet()).flatmap(
    lambda n: arrays(np.int16, (n, 6), elements=st.integers(-32768, 32767)))


@settings(max_examples=200, deadline=None)
@given(raw=raw_samples, seq=st.integers(0, 2**20), t_us=st.integers(0, 2**40),
       flags=st.sampled_from([0, 1, 2, 4, 5, 6, 7]), cid=st.integers(0, 255))
def test_packet_round_trip(raw, seq, t_us, flags, cid):
    data = wp.encode_packet(seq, t_us, raw, flags, cid)
    assert len(data) == wp.HEADER_SIZE + wp.SAMPLE_SIZE * raw.shape[0]
    p = wp.decode_packet(data)
    assert p.seq == seq % 65536 and p.t_first_us == t_us % 2**32
    assert int(p.flags) == flags and p.config_id == cid and p.version == wp.PROTOCOL_VERSION
    np.testing.assert_array_equal(p.raw, raw)


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=300))
def test_decoding_arbitrary_bytes_never_raises_anything_but_decode_error(data):
    try:
        p = wp.decode_packet(data)
    except wp.DecodeError as e:
        assert e.reason in {"short", "version", "length", "flags"}
    else:
        assert len(data) == wp.HEADER_SIZE + 12 * p.n


def test_packet_fits_the_mtu_at_every_rate_and_notification_rate_is_25_to_40_per_s():
    for rate in wp.SUPPORTED_RATES_HZ:
        n = wp.samples_per_packet(rate)
        assert wp.HEADER_SIZE + 12 * n <= wp.DEFAULT_MTU - 3
        if 104 <= rate <= 562.5:
            assert 25 <= rate / n <= 40, (rate, n)
    with pytest.raises(ValueError, match="MTU"):
        wp.samples_per_packet(104, mtu=23)


@pytest.mark.parametrize("mutate, reason", [
    (lambda b: b[:-1], "length"),
    (lambda b: b[:5], "short"),
    (lambda b: bytes([2]) + b[1:], "version"),
    (lambda b: b[:2] + bytes([4]) + b[3:], "length"),
    (lambda b: b[:1] + bytes([0x80]) + b[2:], "flags"),
])
def test_malformed_packets_are_rejected_with_a_reason(mutate, reason):
    good = wp.encode_packet(1, 2, np.zeros((3, 6), np.int16))
    with pytest.raises(wp.DecodeError) as e:
        wp.decode_packet(mutate(good))
    assert e.value.reason == reason


def test_expected_n_is_checked():
    data = wp.encode_packet(1, 2, np.zeros((3, 6), np.int16))
    with pytest.raises(wp.DecodeError, match="n_mismatch"):
        wp.decode_packet(data, expected_n=4)


def test_quantize_saturates_like_a_sensor_and_flags_clipping():
    gyro = np.array([[0.0, 100.0, -100.0], [600.0, 0.0, 0.0], [0.0, -501.0, 0.0]])
    accel = np.array([[0.0, 0.0, 1.0]] * 3)
    counts, clipped = wp.quantize(gyro, accel, 65.5, 8192.0)
    assert counts.dtype == np.int16
    assert counts[0].tolist() == [0, 6550, -6550, 0, 0, 8192]
    assert counts[1, 0] == 32767 and counts[2, 1] == -32768
    assert clipped.tolist() == [False, True, True]


@settings(max_examples=100, deadline=None)
@given(rate=st.sampled_from(wp.SUPPORTED_RATES_HZ), gfs=st.sampled_from(sorted(wp.GYRO_SENSITIVITY_LSB_PER_DPS)),
       ag=st.sampled_from(sorted(wp.ACCEL_SENSITIVITY_LSB_PER_G)), cid=st.integers(0, 255),
       state=st.integers(0, 7))
def test_config_round_trip(rate, gfs, ag, cid, state):
    c = wp.DeviceConfig(cid, rate, gfs, ag, wp.samples_per_packet(rate), wp.GYRO_SENSITIVITY_LSB_PER_DPS[gfs],
                        wp.ACCEL_SENSITIVITY_LSB_PER_G[ag], wp.DeviceState(state))
    data = c.encode()
    assert len(data) == wp.CONFIG_SIZE
    d = wp.DeviceConfig.decode(data)
    assert d.config_id == cid and d.sample_rate_hz == pytest.approx(rate) and d.gyro_full_scale_dps == gfs
    assert d.accel_range_g == ag and d.samples_per_packet == c.samples_per_packet and int(d.state) == state
    assert d.gyro_lsb_per_dps == pytest.approx(c.gyro_lsb_per_dps, rel=1e-6)


def test_config_rejects_wrong_size_and_version():
    good = wp.DeviceConfig(1, 104.0, 500, 4, 3, 65.5, 8192.0).encode()
    with pytest.raises(wp.DecodeError, match="length"):
        wp.DeviceConfig.decode(good[:-1])
    with pytest.raises(wp.DecodeError, match="version"):
        wp.DeviceConfig.decode(bytes([9]) + good[1:])


@pytest.mark.parametrize("cmd", [
    wp.Command(wp.Opcode.START), wp.Command(wp.Opcode.STOP), wp.Command(wp.Opcode.SET_RATE, 562.5),
    wp.Command(wp.Opcode.SET_GYRO_RANGE, 2000), wp.Command(wp.Opcode.SET_ACCEL_RANGE, 16),
])
def test_command_round_trip(cmd):
    assert wp.Command.decode(cmd.encode()) == cmd


def test_command_errors():
    with pytest.raises(wp.DecodeError, match="opcode"):
        wp.Command.decode(b"\x7f")
    with pytest.raises(wp.DecodeError, match="length"):
        wp.Command.decode(bytes([wp.Opcode.SET_RATE]) + struct.pack("<H", 3))
    with pytest.raises(wp.DecodeError, match="length"):
        wp.Command.decode(b"")


@given(op=st.integers(0, 255), status=st.sampled_from(list(wp.Status)), cid=st.integers(0, 255))
def test_status_round_trip(op, status, cid):
    r = wp.StatusReply(op, status, cid)
    assert wp.StatusReply.decode(r.encode()) == r


def test_power_up_layout_and_errors():
    # 12 bytes: version 1, flags (boot count | temperature), boot count 7, uptime 3600 s, 31.25 degC as 3125
    data = wp.PowerUp(7, 3600, 31.25).encode()
    assert data == bytes([1, 3]) + struct.pack("<IIh", 7, 3600, 3125)
    assert wp.PowerUp.decode(bytes([1, 0]) + struct.pack("<IIh", 9, 5, 77)) == wp.PowerUp(None, 5, None)
    assert wp.PowerUp.decode(wp.PowerUp(0, 0, -40.0).encode()) == wp.PowerUp(0, 0, -40.0)
    for bad, reason in ((data[:-1], "length"), (bytes([2]) + data[1:], "version"), (data[:1] + bytes([4]) + data[2:], "flags")):
        with pytest.raises(wp.DecodeError, match=reason):
            wp.PowerUp.decode(bad)
    with pytest.raises(ValueError, match="32 bits"):
        wp.PowerUp(2**32, 0).encode()
    with pytest.raises(ValueError, match="temperature"):
        wp.PowerUp(1, 0, float("nan")).encode()
