"""A calibration written to the wearable: the payload and its CRC-32, the simulated device's answers, and the
link's write, read-back and verification in process and through the real bleak client on the simulated BlueZ."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_ble_e2e import FAST

import wearable_protocol as wp
from mock_device.sources import ScriptedSource
from mock_device.vendors import WEARABLES
from mock_device.wearable import Wearable
from server.link import InProcessLink, WriteBackError
from server.link.ble import BleLink
from wearable_protocol import Command, DecodeError, HeldCalibration, Opcode, Status, StatusReply
from wearable_protocol.held_calibration import PAYLOAD_SIZE, SLOT_SIZE, crc32

HELD = HeldCalibration.from_parameters(42, [[1.012, 0.003, -0.001], [0.0, 0.987, 0.002], [0.0, 0.0, 1.021]],
                                       [0.31, -0.12, 0.05])


def test_crc32_is_ieee_802_3():
    # The CRC-32 check value: the CRC of the nine ASCII digits "123456789" is 0xCBF43926 (Williams, "A Painless
    # Guide to CRC Error Detection Algorithms", 1993, the CRC-32 entry of its parameter catalogue; also RFC 1952's CRC).
    assert crc32(b"123456789") == 0xCBF43926
    assert crc32(b"") == 0


def test_payload_layout_and_round_trip():
    payload = HELD.payload()
    assert len(payload) == PAYLOAD_SIZE == 56
    cid, *vals, crc = struct.unpack("<I12fI", payload)
    assert cid == 42 and crc == crc32(payload[:52])
    assert vals == list(HELD.K) + list(HELD.b)
    assert HeldCalibration.from_payload(payload) == HELD
    assert wp.decode_slot(wp.encode_slot(HELD)) == HELD and wp.decode_slot(wp.encode_slot(None)) is None
    assert len(wp.encode_slot(None)) == SLOT_SIZE == 58


@given(st.integers(0, PAYLOAD_SIZE - 1), st.integers(1, 255))
def test_any_damaged_byte_is_refused(pos, flip):
    damaged = bytearray(HELD.payload())
    damaged[pos] ^= flip
    with pytest.raises(DecodeError) as e:
        HeldCalibration.from_payload(bytes(damaged))
    assert e.value.reason == "checksum"  # CRC-32 detects every burst of up to 32 bits


def test_nonsense_parameters_are_refused_both_ways():
    with pytest.raises(ValueError, match="finite"):
        HeldCalibration.from_parameters(1, [1.0, float("nan"), 1.0], [0, 0, 0])
    with pytest.raises(ValueError, match="32 bits"):
        HeldCalibration.from_parameters(2**32, [1, 1, 1], [0, 0, 0])
    with pytest.raises(ValueError, match="3x3"):
        HeldCalibration.from_parameters(1, [1, 1], [0, 0, 0])
    singular = HeldCalibration.from_parameters(3, [1.0, 0.0, 1.0], [0, 0, 0])
    with pytest.raises(DecodeError, match="singular"):
        HeldCalibration.from_payload(singular.payload())


def test_applying_it_is_g_equals_k_m_plus_b():
    m = np.array([10.0, -20.0, 30.0])
    K = np.array(HELD.K).reshape(3, 3)
    assert HELD.apply((10.0, -20.0, 30.0)) == pytest.approx(K @ m + np.array(HELD.b), abs=1e-9)


def _answers(w: Wearable, data: bytes) -> StatusReply:
    got: list[bytes] = []

    class Central:
        def notify(self, uuid: str, value: bytes) -> None:
            got.append(value)

        def link_lost(self) -> None:
            pass

    w.connect(Central())
    w.set_notify(wp.IMU_CONTROL_CHAR, True)
    w.write(wp.IMU_CONTROL_CHAR, data)
    w.disconnect()
    return StatusReply.decode(got[-1])


def test_the_simulated_wearable_holds_only_intact_calibrations():
    w = Wearable(ScriptedSource(seed=1), seed=1)
    assert wp.decode_slot(w.read(wp.IMU_CALIBRATION_CHAR)) is None
    damaged = bytearray(Command(Opcode.WRITE_CALIBRATION, HELD.payload()).encode())
    damaged[9] ^= 0x40
    assert _answers(w, bytes(damaged)).status == Status.CHECKSUM and w.held is None
    assert _answers(w, bytes(damaged[:-1])).status == Status.BAD_LENGTH and w.held is None
    singular = HeldCalibration.from_parameters(5, [1.0, 0.0, 1.0], [0, 0, 0])
    assert _answers(w, Command(Opcode.WRITE_CALIBRATION, singular.payload()).encode()).status == Status.INVALID_VALUE
    assert _answers(w, Command(Opcode.WRITE_CALIBRATION, HELD.payload()).encode()).status == Status.OK
    assert wp.decode_slot(w.read(wp.IMU_CALIBRATION_CHAR)) == HELD
    assert _answers(w, Command(Opcode.CLEAR_CALIBRATION).encode()).status == Status.OK and w.held is None


async def test_in_process_write_reads_back_and_verifies():
    w = Wearable(ScriptedSource(seed=2), seed=2)
    link = InProcessLink(w, reconnect=FAST)
    await link.connect()
    assert link.holds_calibrations and await link.held_calibration() is None
    assert await link.write_calibration(HELD) == HELD and w.held == HELD

    w.held = HeldCalibration.from_parameters(7, [1, 1, 1], [0, 0, 0])  # a device that applies something else
    original = Wearable._hold

    def keeps_old(self: Wearable, cmd: Command) -> Status:
        return Status.OK

    Wearable._hold = keeps_old  # type: ignore[method-assign]
    try:
        with pytest.raises(WriteBackError, match="reads back calibration 7"):
            await link.write_calibration(HELD)
    finally:
        Wearable._hold = original  # type: ignore[method-assign]
    await link.disconnect()


@pytest.mark.parametrize("model", ["polar-pmd", "metawear", "thingy52"])
async def test_vendor_devices_say_they_cannot_hold_one(model):
    link = InProcessLink(WEARABLES[model](ScriptedSource(seed=3), seed=3), reconnect=FAST)
    await link.connect()
    assert not link.holds_calibrations
    with pytest.raises(WriteBackError, match="cannot hold a calibration"):
        await link.write_calibration(HELD)
    await link.disconnect()


async def test_write_back_through_bleak_on_the_simulated_bluez(simulated_bluez):
    w = Wearable(ScriptedSource(seed=4), seed=4)
    simulated_bluez([w])
    link = BleLink(w.address, reconnect=FAST)
    await link.connect()
    assert link.holds_calibrations and await link.held_calibration() is None
    assert await link.write_calibration(HELD) == HELD
    await link.disconnect()
    again = BleLink(w.address, reconnect=FAST)
    await again.connect()
    assert await again.held_calibration() == HELD  # the device keeps it across connections
    await again.disconnect()
