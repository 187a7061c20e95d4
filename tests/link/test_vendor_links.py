"""The link's protocol adapters for commercial wearables, against the simulated Polar, MetaWear and Thingy:52
devices on the in-process transport: negotiation, decoding to deg/s and g, time stamps, loss accounting,
reconnection, and a calibration from what the link delivered."""

from __future__ import annotations

import asyncio
import time
from typing import Any

import numpy as np
import pytest
from test_link_inprocess import _collect, _session

from calib.pipeline import calibrate
from mock_device.sources import ScriptedSource
from mock_device.vendors import WEARABLES
from server.link import CommandError, InProcessLink, ReconnectPolicy, RecordingBuilder
from server.link.base import ConnectError
from wearable_protocol.models import MODELS
from wearable_protocol.vendors import polar_pmd as pmd

FAST = ReconnectPolicy(initial_delay_s=0.02, max_delay_s=0.2, timeout_s=10.0)
VENDORS = ("polar-pmd", "metawear", "thingy52", "movella-dot")


def _device(model: str, seed: int = 1, scenario: str = "normal", speed: float = 20.0, **kw):  # type: ignore[no-untyped-def]
    return WEARABLES[model](ScriptedSource(seed=seed, scenario=scenario), seed=seed, speed=speed, **kw)


def _link(w, **kw) -> InProcessLink:  # type: ignore[no-untyped-def]
    t0 = time.monotonic()
    speed = w.speed
    return InProcessLink(w, reconnect=FAST, clock=lambda: (time.monotonic() - t0) * speed, **kw)


@pytest.mark.parametrize("model", VENDORS)
async def test_each_vendor_streams_a_protocol_that_calibrates_to_the_truth(model):
    w = _device(model, seed=3)
    link = _link(w)
    found = await link.scan(1.0)
    assert [d.model for d in found] == [model]
    await link.connect()
    info = await link.read_info()
    m = MODELS[model]
    assert info.device_model == model and link.model is m
    assert info.config.sample_rate_hz == m.stream_rate_hz and info.config.gyro_full_scale_dps == m.gyro_range_dps
    assert info.battery_pct == w.battery_pct
    await link.start()
    rec = RecordingBuilder(info)
    batches, events = await _collect(link, until_s=27.0)
    await link.stop()
    await link.disconnect()
    assert events == []
    for b in batches:
        rec.add(b)
    r = rec.recording()
    assert np.all(np.diff(r.t) > 0) and np.all(np.diff(r.seq) == 1)
    # a model stamped on arrival has its rate estimated from when packets came: a busy machine delays some (2.7e-4
    # seen beside a full test run); one with its own clock gives the rate to the part in ten thousand
    rel = 1e-3 if m.time_stamps == "arrival" else 2e-4
    assert r.meta.sample_rate_hz == pytest.approx(w.true_rate_hz, rel=rel)
    assert batches[0].arrival_times == (m.time_stamps == "arrival")
    rest = r.accel[: int(2 * r.fs)]
    assert np.linalg.norm(rest.mean(axis=0)) == pytest.approx(1.0, abs=0.02)  # the accelerometer, in g
    result = calibrate(r)
    # within 3e-4, or 4 standard errors where the heading prior (0.1 deg, the z turn spun flat) makes k_z less certain
    assert np.all(np.abs(result.k - np.asarray(w.truth["k"])) < np.maximum(3e-4, 4 * result.k_std)), (result.k, w.truth["k"])
    np.testing.assert_allclose(result.b, w.truth["b"], atol=0.01)
    assert link.stats.malformed_packets == 0 and link.stats.lost_samples == 0


async def test_polar_settings_are_negotiated_and_scaled_by_the_start_replys_factor():
    w = _device("polar-pmd", seed=2)
    link = _link(w)
    await link.connect()
    cfg = link.config
    assert cfg is not None and (cfg.sample_rate_hz, cfg.gyro_full_scale_dps, cfg.accel_range_g) == (208.0, 500, 8)
    with pytest.raises(CommandError, match="offers no rate 100: choose one of 52, 104, 208, 416"):
        await link.configure(sample_rate_hz=100.0)
    cfg = await link.configure(sample_rate_hz=104.0, gyro_full_scale_dps=1000)
    assert (cfg.sample_rate_hz, cfg.gyro_full_scale_dps) == (104.0, 1000)
    await link.start()
    assert link.config is not None and link.config.gyro_lsb_per_dps == pytest.approx(32.768, rel=1e-6)
    assert w.rate_hz == 104.0 and w.gyro_full_scale_dps == 1000
    batches, _ = await _collect(link, until_s=3.0)
    await link.stop()
    still = np.concatenate([b.gyro_dps for b in batches])[: int(2 * 104)]
    # at rest g = K m + b = 0: the readings, in deg/s through the factor, are -b / k
    np.testing.assert_allclose(still.mean(axis=0), -np.asarray(w.truth["b"]) / np.asarray(w.truth["k"]), atol=0.03)
    await link.disconnect()


@pytest.mark.parametrize("model", VENDORS)
async def test_a_link_drop_is_bridged_and_its_gap_measured(model):
    speed = 20.0 if MODELS[model].time_stamps == "device" else 5.0  # arrival times carry the event loop's jitter x speed
    w = _device(model, seed=4, scenario="link_drop", speed=speed)
    batches, events = await _session(_link(w), until_s=w.faults.drop_at_s + 6.0)
    assert [e.kind for e in events] == ["link_lost", "link_restored"]
    restored = events[1]
    truth = w.stats.packets_lost_link * w.samples_per_packet
    if MODELS[model].time_stamps == "device":  # from the time stamps: exact
        assert restored.gap_samples == truth
    else:  # from arrival times: the wall-clock gap, to within the event loop's scheduling jitter (in device time): a
        # few ms on an idle machine, 15 ms seen on a busy two-core one; 40 ms allowed
        assert restored.gap_samples == pytest.approx(truth, abs=3 + 0.040 * speed * w.true_rate_hz)
    after = next(b for b in batches if b.lost_before)
    assert after.lost_before == restored.gap_samples and restored.gap_s >= w.faults.drop_for_s * 0.95
    seq = np.concatenate([b.seq for b in batches])
    assert np.sum(np.diff(seq) - 1) == restored.gap_samples


async def test_readings_that_come_while_the_stream_is_started_again_carry_the_gap(monkeypatch):
    # the wearable streams again as soon as it is told to, while the link still sends it the rest of its commands: the
    # first readings after the gap came before the link had marked the gap, and the link said it lost 0 samples (162
    # lost), in one full run of the suite on a busy two-core machine
    from server.link.adapters.metawear import MetaWearAdapter

    send = MetaWearAdapter._send

    async def slow_send(self, *commands: bytes) -> None:  # noqa: ANN001
        await send(self, *commands)
        await asyncio.sleep(0.3)  # the resumed readings come meanwhile

    monkeypatch.setattr(MetaWearAdapter, "_send", slow_send)
    w = _device("metawear", seed=4, scenario="link_drop", speed=5.0)
    batches, events = await _session(_link(w), until_s=w.faults.drop_at_s + 6.0)
    assert [e.kind for e in events] == ["link_lost", "link_restored"]
    after = next(b for b in batches if b.lost_before)
    assert events[1].gap_samples == after.lost_before > 0


async def test_dot_samples_lost_on_the_radio_are_found_from_the_time_stamps():
    w = _device("movella-dot", seed=8, scenario="packet_loss", speed=20.0)
    link = _link(w)
    batches, _ = await _session(link, until_s=25.0)
    last = batches[-1].seq[-1]
    lost = [j for j in w.stats.lost_radio_seqs if j < last]
    assert len(lost) >= 2
    assert link.stats.lost_samples == len(lost)
    t = np.concatenate([b.t_device_s for b in batches])
    seq = np.concatenate([b.seq for b in batches])
    np.testing.assert_allclose(np.diff(t) * w.true_rate_hz, np.diff(seq), atol=0.02)
    assert sorted(set(range(int(seq[0]), int(last) + 1)) - set(seq.tolist())) == lost


async def test_polar_frames_lost_on_the_radio_are_found_from_the_time_stamps():
    w = _device("polar-pmd", seed=8, scenario="packet_loss", speed=20.0)
    link = _link(w)
    batches, _ = await _session(link, until_s=25.0)
    n = w.samples_per_packet
    last_packet = batches[-1].seq[-1] // n
    lost = [j for j in w.stats.lost_radio_seqs if j < last_packet]
    assert len(lost) >= 2
    assert link.stats.lost_samples == len(lost) * n
    t = np.concatenate([b.t_device_s for b in batches])
    seq = np.concatenate([b.seq for b in batches])
    # the samples after each gap sit where the device took them: time and counter agree throughout
    np.testing.assert_allclose(np.diff(t) * w.true_rate_hz, np.diff(seq), atol=0.02)


@pytest.mark.parametrize("model", VENDORS)
async def test_malformed_notifications_are_counted_and_dropped(model):
    w = _device(model, seed=5)
    link = _link(w)
    await link.connect()
    await link.start()
    batches, _ = await _collect(link, until_s=1.0)
    w.corrupt_next_packets(2)
    more, _ = await _collect(link, until_s=3.0)
    await link.stop()
    await link.disconnect()
    assert link.stats.malformed_packets == 2
    assert sum(len(b) for b in more) > 0


async def test_a_device_of_another_model_is_refused_with_a_plain_message():
    w = _device("metawear", seed=6)
    link = _link(w, model="polar-pmd")
    with pytest.raises(ConnectError, match="no PMD control point; is it a Polar sensor"):
        await link.connect()


@pytest.mark.parametrize(("model", "kwargs", "message"), [
    ("metawear", {"sample_rate_hz": 104.0}, "share no rate 104 Hz"),
    ("metawear", {"gyro_full_scale_dps": 300}, "no gyro range 300"),
    ("thingy52", {"gyro_full_scale_dps": 500}, "fixed at 2000 deg/s"),
    ("thingy52", {"sample_rate_hz": 250.0}, "from 1 to 200"),
    ("movella-dot", {"sample_rate_hz": 120.0}, "streams at one of 1, 4, 10, 12, 15, 20, 30, 60 Hz"),
    ("movella-dot", {"gyro_full_scale_dps": 1000}, "fixed at 2000 deg/s"),
    ("movella-dot", {"accel_range_g": 8}, "fixed at 16 g"),
])
async def test_settings_a_device_does_not_offer_are_refused(model, kwargs, message):
    link = _link(_device(model, seed=7))
    await link.connect()
    with pytest.raises(CommandError, match=message):
        await link.configure(**kwargs)
    await link.disconnect()


def test_polar_decoder_interpolates_the_slower_accelerometer_onto_the_gyro_times():
    from server.link.adapters.polar import PolarDecoder
    from server.link.base import LinkStats

    dec = PolarDecoder(LinkStats(), 208.0, 500 / 32768, 52.0, 1.0)
    t_ns = 10**15
    out = []
    for f in range(4):  # frames of 36 gyro samples and 9 accelerometer samples, accelerometer ramping in x
        last = t_ns + int((f * 36 + 35) * 1e9 / 208)
        acc_idx = np.arange(f * 9, f * 9 + 9)
        acc = np.column_stack([acc_idx * 10, np.zeros(9), np.full(9, 1000)])  # mG
        out += dec.feed(pmd.encode_frame(pmd.MeasurementType.GYRO, last, np.zeros((36, 3))))
        out += dec.feed(pmd.encode_frame(pmd.MeasurementType.ACC, t_ns + int(acc_idx[-1] * 4 * 1e9 / 208), acc))
    assert len(out) == 3  # the last gyro frame waits for accelerometer samples after it
    accel = np.concatenate([b.accel_g for b in out])
    expected_x = np.arange(accel.shape[0]) / 4 * 10 / 1000  # one accelerometer sample every 4 gyro samples
    np.testing.assert_allclose(accel[:, 0], expected_x, atol=1e-6)
    np.testing.assert_allclose(accel[:, 2], 1.0)


def _polar_stream(frames: int, stamp: dict[int, int] | None = None) -> tuple[list[Any], Any]:
    """Gyro and accelerometer frames of a Polar stream at 208 / 52 Hz; ``stamp`` replaces gyro frames' time stamps."""
    from server.link.adapters.polar import PolarDecoder
    from server.link.base import LinkStats

    dec = PolarDecoder(LinkStats(), 208.0, 500 / 32768, 52.0, 1.0)
    t_ns, out = 10**15, []
    for f in range(frames):
        last = (stamp or {}).get(f, t_ns + int((f * 36 + 35) * 1e9 / 208))
        acc_idx = np.arange(f * 9, f * 9 + 9)
        acc = np.column_stack([np.zeros(9), np.zeros(9), np.full(9, 1000)])
        out += dec.feed(pmd.encode_frame(pmd.MeasurementType.GYRO, last, np.zeros((36, 3))))
        out += dec.feed(pmd.encode_frame(pmd.MeasurementType.ACC, t_ns + int(acc_idx[-1] * 4 * 1e9 / 208), acc))
    return out, dec


def test_a_polar_frame_stamped_2000_s_ahead_costs_that_frame_only():
    out, dec = _polar_stream(40, stamp={20: 10**15 + 2000 * 10**9})
    t = np.concatenate([b.t_device_s for b in out])
    assert dec.stats.lost_samples == 36 and dec.stats.malformed_reasons == {"inconsistent": 1}
    assert dec.stats.duplicate_packets == 0 and np.all(np.diff(t) > 0) and t[-1] < 8.0  # no 2000 s in the time line


def test_a_long_polar_gap_confirmed_by_the_frames_after_it_is_a_real_loss():
    gap_ns = 60 * 10**9  # the device out of reach for a minute: every frame from the 20th on is later by that
    out, dec = _polar_stream(40, stamp={f: 10**15 + gap_ns + int((f * 36 + 35) * 1e9 / 208) for f in range(20, 40)})
    t = np.concatenate([b.t_device_s for b in out])
    assert dec.stats.malformed_packets == 0 and dec.stats.lost_samples == round(60 * 208)
    assert np.all(np.diff(t) > 0) and float(np.diff(t).max()) == pytest.approx(60 + 1 / 208, abs=1e-3)
