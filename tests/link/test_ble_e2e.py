"""End to end through the real, unmodified bleak client on the simulated BlueZ (private dbus-daemon)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

import wearable_protocol as wp
from calib.result import CalibrationResult
from mock_device.sources import ScriptedSource
from mock_device.wearable import Wearable
from server.link import LinkEvent, ReconnectPolicy, RecordingBuilder, SampleBatch
from server.link.base import ConnectError, DeviceNotFoundError
from server.link.ble import BleLink

FAST = ReconnectPolicy(initial_delay_s=0.05, max_delay_s=0.5, timeout_s=20.0)
SPEED = 20.0


def _calibrate(rec) -> CalibrationResult:
    """The library's default estimator when it is installed, else the paper's method."""
    from calib.pipeline import calibrate

    try:
        return calibrate(rec)
    except ImportError:
        return calibrate(rec, method="paper")


def _assert_matches_truth(res: CalibrationResult, truth: dict) -> None:
    k_true, b_true = np.asarray(truth["k"]), np.asarray(truth["b"])
    if res.k_std is not None:
        # Five standard errors (a Gaussian error passes 5 sigma once in ~1.7 million). The int16
        # quantisation (0.015 deg/s per count, dithered by the 0.03 deg/s noise) adds ~2 % to the noise
        # variance, well inside that margin.
        k_tol = 5 * np.asarray(res.k_std)
        b_tol = 5 * np.asarray(res.b_std)
    else:
        # No uncertainty from this estimator: the paper reports errors within +-5.5e-3 at 0.03 deg/s
        # noise (Fig. 7a); twice that.
        k_tol = b_tol = np.full(3, 0.011)
    assert np.all(np.abs(np.asarray(res.k) - k_true) <= k_tol), (res.k, k_true, k_tol)
    assert np.all(np.abs(np.asarray(res.b) - b_true) <= b_tol), (res.b, b_true, b_tol)


async def _stream(link: BleLink, until_s: float, on_batch=None) -> tuple[list[SampleBatch], list[LinkEvent]]:
    batches, events = [], []
    async for item in link.samples():
        if isinstance(item, LinkEvent):
            events.append(item)
            continue
        batches.append(item)
        if on_batch is not None:
            on_batch(item)
        if item.t_device_s[-1] >= until_s:
            break
    return batches, events


async def test_cli_wearable_streams_the_protocol_through_bleak_and_calibrates(dbus_bus, monkeypatch):
    """gyrocal mock-device --ble on its own bus; scan, connect, read, stream at 20x, decode, calibrate."""
    seed = 21
    proc = subprocess.Popen(
        [sys.executable, "-m", "calib.cli.main", "mock-device", "--ble", "--seed", str(seed), "--speed", str(SPEED), "--boot-count", "41",
         "--temperature", "19.5"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        line = json.loads(proc.stdout.readline())
        assert set(line) >= {"dbus_address", "address", "name", "simulated_truth"}
        monkeypatch.setenv("DBUS_SYSTEM_BUS_ADDRESS", line["dbus_address"])
        link = BleLink(reconnect=FAST)
        found = await link.scan(1.0)
        assert [(d.address, d.name) for d in found] == [(line["address"], line["name"])]
        link = BleLink(line["address"], reconnect=FAST)
        await link.connect()
        info = await link.read_info()
        assert info.config.sample_rate_hz == wp.DEFAULT_RATE_HZ and info.config.gyro_full_scale_dps == 500
        assert info.manufacturer == "gyrocal" and info.model and info.serial and info.firmware
        assert 0 < info.battery_pct <= 100
        # the power-up characteristic: count as set, warmed from 19.5 degC (4 degC at most), started before the read
        assert info.power_up is not None and info.power_up.boot_count == 41 and 19.5 <= info.power_up.temperature_c <= 23.5
        assert info.power_up.booted_at <= info.power_up.read_at
        await link.start()
        protocol_s = ScriptedSource(seed=seed).script.segments
        duration = sum(s.duration_s for s in protocol_s)
        rb = RecordingBuilder(info)
        batches, events = await _stream(link, duration, rb.add)
        await link.stop()
        await link.disconnect()
        assert events == [] and link.stats.lost_samples == 0 and link.stats.malformed_packets == 0
        rec = rb.recording()
        assert np.all(np.diff(rec.seq) == 1) and np.all(np.diff(rec.t) > 0)
        assert rec.fs != wp.DEFAULT_RATE_HZ and abs(rec.fs / wp.DEFAULT_RATE_HZ - 1) < 0.01  # device-time estimate
        _assert_matches_truth(_calibrate(rec), line["simulated_truth"])
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=15)
    assert proc.returncode == 0, err
    assert "mock device stopped" in err
    socket_dir = line["dbus_address"].split("unix:path=")[1].split(",")[0].rsplit("/", 1)[0]
    assert not os.path.exists(socket_dir)  # the private daemon and its files are gone


async def test_link_drop_mid_turn_reconnects_and_reports_the_gap(simulated_bluez):
    w = Wearable(ScriptedSource(seed=4, scenario="link_drop"), seed=4, speed=SPEED)
    th = simulated_bluez([w])
    link = BleLink(w.address, reconnect=FAST, scan_timeout_s=2.0)
    await link.connect()
    await link.start()
    batches, events = await _stream(link, w.faults.drop_at_s + 5.0)
    await link.stop()
    await link.disconnect()
    stats = th.call(lambda: w.stats)
    assert [e.kind for e in events] == ["link_lost", "link_restored"]
    restored = events[1]
    assert restored.gap_samples == stats.packets_lost_link * w.samples_per_packet > 0
    assert restored.gap_s >= w.faults.drop_for_s and restored.attempts >= 1
    seq = np.concatenate([b.seq for b in batches])
    assert np.sum(np.diff(seq) - 1) == restored.gap_samples == link.stats.lost_samples
    assert link.stats.link_losses == 1 and link.stats.reconnects == 1


async def test_packet_loss_and_malformed_packets_are_counted_exactly(simulated_bluez):
    w = Wearable(ScriptedSource(seed=8, scenario="packet_loss"), seed=8, speed=SPEED)
    th = simulated_bluez([w])
    link = BleLink(w.address, reconnect=FAST)
    await link.connect()
    await link.start()
    injected = []

    def inject(batch: SampleBatch) -> None:
        if not injected and batch.t_device_s[-1] > 3.0:
            injected.extend(th.call(w.inject, data) for data in (b"", b"\x01\x00\x03", bytes(60)))
            th.call(w.corrupt_next_packets, 2)

    batches, events = await _stream(link, 15.0, inject)
    await link.stop()
    await link.disconnect()
    assert injected == [True, True, True] and events == []
    stats = th.call(lambda: w.stats)
    n = w.samples_per_packet
    last_packet = batches[-1].seq[-1] // n
    radio = [j for j in stats.lost_radio_seqs if j < last_packet]
    assert len(radio) > 2
    assert link.stats.malformed_packets == 3 + stats.packets_corrupted == 5
    # the radio's losses are lost; the corrupted packets arrived and were refused: the firmware's, not the radio's
    assert link.stats.lost_samples == len(radio) * n
    assert sum(b.refused_before for b in batches) == stats.packets_corrupted * n


async def test_device_not_found_is_a_clear_error(simulated_bluez):
    simulated_bluez([])
    link = BleLink("C0:FF:EE:00:00:01", scan_timeout_s=0.5)
    assert await link.scan(0.3) == []
    with pytest.raises(DeviceNotFoundError, match="C0:FF:EE:00:00:01 was not found within 0.5 s"):
        await link.connect()
    with pytest.raises(DeviceNotFoundError, match="no supported wearable was found"):
        await BleLink(scan_timeout_s=0.3).connect()


async def test_disconnect_during_connect_is_retried_then_reported(simulated_bluez):
    w1 = Wearable(ScriptedSource(seed=1), seed=1, speed=SPEED)
    w2 = Wearable(ScriptedSource(seed=2), seed=2, speed=SPEED)
    th = simulated_bluez([w1, w2])
    th.call(w1.fail_next_connects, 1)
    link = BleLink(w1.address, reconnect=FAST)
    await link.connect()  # bleak sees Connected go back to False before ServicesResolved, the retry works
    assert link.connected and th.call(lambda: w1.stats.connects) == 1
    await link.disconnect()
    assert th.call(lambda: w1.advertising)  # the device is free again
    th.call(w2.fail_next_connects, 10)
    with pytest.raises(ConnectError, match="after 3 attempts"):
        await BleLink(w2.address, reconnect=FAST).connect()


async def test_device_information_and_battery_are_optional(simulated_bluez):
    w = Wearable(ScriptedSource(seed=3), seed=3, speed=SPEED)
    th = simulated_bluez([w], hide_services=(wp.DEVICE_INFORMATION_SERVICE, wp.BATTERY_SERVICE))
    link = BleLink(w.address, reconnect=FAST)
    await link.connect()
    info = await link.read_info()
    assert info.config.samples_per_packet == 3
    assert (info.manufacturer, info.model, info.serial, info.firmware, info.battery_pct) == (None,) * 5
    await link.start()
    batches, _ = await _stream(link, 1.0)
    assert batches and link.stats.lost_samples == 0
    await link.stop()
    await link.disconnect()
    assert th.call(lambda: (w.config.state, w.advertising)) == (wp.DeviceState(0), True)  # session over, free


def test_mock_device_cli_refuses_bad_arguments_with_a_message(capsys):
    from calib.cli.main import main

    assert main(["mock-device"]) == 2
    assert "add --ble" in capsys.readouterr().err
    assert main(["mock-device", "--ble", "--speed", "0"]) == 2
    assert "--speed must be a positive number" in capsys.readouterr().err
    assert main(["mock-device", "--ble", "--rate", "100"]) == 2
    assert "--rate 100 is not offered" in capsys.readouterr().err


async def test_an_adapter_out_of_connection_slots_is_said_plainly(simulated_bluez):
    from server.link.slots import AdapterSlots, OutOfConnectionSlots

    w1, w2 = (Wearable(ScriptedSource(seed=s), seed=s, speed=SPEED) for s in (5, 6))
    th = simulated_bluez([w1, w2])
    slots = AdapterSlots(("hci0",), slots_per_adapter=1)  # as a BlueZ adapter whose controller holds one link
    first = BleLink(w1.address, reconnect=FAST, slots=slots)
    await first.connect()
    second = BleLink(w2.address, reconnect=FAST, slots=slots)
    with pytest.raises(OutOfConnectionSlots, match=f"using its 1 connection slots \\(hci0: {w1.address}\\); end a session"):
        await second.connect()
    assert th.call(lambda: w2.stats.connects) == 0  # refused before BlueZ was asked: nothing to clean up
    await first.disconnect()
    await second.connect()  # the slot is free again
    assert second.connected and second.adapter == "hci0"
    await second.disconnect()


async def test_several_adapters_an_unplugged_one_is_skipped(simulated_bluez):
    from server.devices import DeviceManager
    from server.link.slots import AdapterSlots, OutOfConnectionSlots

    w1, w2 = (Wearable(ScriptedSource(seed=s), seed=s, speed=SPEED) for s in (7, 8))
    simulated_bluez([w1, w2])  # the simulated BlueZ has hci0 only: hci1 stands for an unplugged adapter
    manager = DeviceManager(ble=True, ble_adapters=("hci1", "hci0"), ble_slots=1)
    assert {d.address for d in await manager.scan(1.0)} == {w1.address, w2.address}  # hci0's scan is enough
    slots = AdapterSlots(("hci1", "hci0"), slots_per_adapter=1)
    first = BleLink(w1.address, reconnect=FAST, slots=slots, scan_timeout_s=1.0)
    await first.connect()
    assert first.adapter == "hci0"
    with pytest.raises(OutOfConnectionSlots, match=f"hci1: none; hci0: {w1.address}"):
        await BleLink(w2.address, reconnect=FAST, slots=slots, scan_timeout_s=1.0).connect()
    await first.disconnect()
