"""The link client on the in-process transport, and the stream decoder on synthetic packets."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

import wearable_protocol as wp
from calib.io.readers import write_native_csv
from calib.simulator import simulate
from mock_device.sources import ReplaySource, ScriptedSource
from mock_device.wearable import Wearable
from server.link import (
    CommandError,
    DeviceNotFoundError,
    InProcessLink,
    LinkEvent,
    ReconnectPolicy,
    RecordingBuilder,
    SampleBatch,
    StreamDecoder,
    WearableLink,
)
from server.link.base import ConnectError

FAST = ReconnectPolicy(initial_delay_s=0.02, max_delay_s=0.2, timeout_s=10.0)
CFG = wp.DeviceConfig(1, 104.0, 500, 4, 3, 65.5, 8192.0)


def _wearable(seed: int = 1, scenario: str = "normal", speed: float = 100.0, **kw) -> Wearable:
    return Wearable(ScriptedSource(seed=seed, scenario=scenario), seed=seed, speed=speed, **kw)


async def _collect(link: InProcessLink, until_s: float) -> tuple[list[SampleBatch], list[LinkEvent]]:
    batches, events = [], []
    async for item in link.samples():
        if isinstance(item, LinkEvent):
            events.append(item)
        else:
            batches.append(item)
            if item.t_device_s[-1] >= until_s:
                break
    return batches, events


async def _session(link: InProcessLink, until_s: float) -> tuple[list[SampleBatch], list[LinkEvent]]:
    """Connect, stream until the device's clock passes ``until_s``, stop and disconnect: what arrived."""
    await link.connect()
    await link.start()
    got = await _collect(link, until_s)
    await link.stop()
    await link.disconnect()
    return got


def _packets(n_packets: int, fs_true: float = 104.5, n: int = 3, t0_us: int = 2**32 - 3_000_000,
             seq0: int = 0) -> list[bytes]:
    raw = np.arange(n * 6, dtype=np.int16).reshape(n, 6)
    return [wp.encode_packet(seq0 + j, t0_us + round(j * n * 1e6 / fs_true), raw, 0, CFG.config_id)
            for j in range(n_packets)]


# ---------------------------------------------------------------------------- decoder


def test_decoder_unwraps_the_device_clock_and_estimates_the_rate_from_device_time():
    dec = StreamDecoder(CFG)
    dec.begin(new_session=True)
    batches = [dec.feed(p) for p in _packets(400, fs_true=104.5)]  # the clock wraps after ~3 s
    t = np.concatenate([b.t_device_s for b in batches])
    assert np.all(np.diff(t) > 0) and t[-1] == pytest.approx(1199 / 104.5, abs=2e-5)
    assert dec.fs_hz == pytest.approx(104.5, rel=1e-6)  # not the nominal 104
    seq = np.concatenate([b.seq for b in batches])
    np.testing.assert_array_equal(seq, np.arange(1200))
    assert dec.stats.lost_samples == 0 and dec.stats.malformed_packets == 0


def test_decoder_counts_sequence_gaps_across_the_16_bit_wrap():
    pk = _packets(70000, fs_true=104.0, seq0=0)
    keep = [p for j, p in enumerate(pk) if j not in (10, 65535, 65536, 69000)]
    dec = StreamDecoder(CFG)
    dec.begin(new_session=True)
    fed = [dec.feed(p) for p in keep]
    assert sum(b is None for b in fed) == 3  # the packet after each short gap waits one packet for the missing one
    out = [b for b in fed if b is not None]
    assert dec.stats.lost_samples == 4 * 3 and dec.stats.lost_packets == 4
    assert out[-1].seq[-1] == 70000 * 3 - 1
    assert [b.lost_before for b in out if b.lost_before] == [3, 6, 3]


def test_decoder_resolves_a_gap_longer_than_the_sequence_range_from_device_time():
    pk = _packets(70010)
    dec = StreamDecoder(CFG)
    dec.begin(new_session=True)
    dec.feed(pk[0])
    assert dec.feed(pk[70005]) is None and dec.feed(pk[70006]) is None  # a gap this long waits for confirmation
    b = dec.feed(pk[70007])  # 70004 packets lost: seq alone would say 4468
    assert b is not None and b.lost_before == 70004 * 3 and b.seq[0] == 70005 * 3 and len(b.seq) == 9
    assert dec.stats.malformed_packets == 0 and dec.stats.resyncs == 0


def test_decoder_drops_duplicates_and_malformed_packets_and_keeps_going():
    pk = _packets(10)
    dec = StreamDecoder(CFG)
    dec.begin(new_session=True)
    bad = [b"", b"\x01" * 5, bytes([9]) + pk[1][1:], pk[1][:-2],
           wp.encode_packet(1, 0, np.zeros((4, 6), np.int16), 0, CFG.config_id),  # N=4, config says 3
           wp.encode_packet(1, 0, np.zeros((3, 6), np.int16), 0, CFG.config_id + 1)]  # stale configuration
    feed = [pk[0], pk[1], pk[1], *bad, pk[2], pk[0], pk[3]]
    out = [dec.feed(p) for p in feed]
    assert sum(b is not None for b in out) == 4
    assert dec.stats.duplicate_packets == 2 and dec.stats.malformed_packets == len(bad)
    assert dec.stats.malformed_reasons == {"short": 2, "version": 1, "length": 1, "n_mismatch": 1, "config_id": 1}
    assert dec.stats.lost_samples == 0


def test_first_packet_of_a_new_session_counts_missing_leading_packets_as_lost():
    pk = _packets(5)
    dec = StreamDecoder(CFG)
    dec.begin(new_session=True)
    assert dec.feed(pk[2]).lost_before == 6
    dec2 = StreamDecoder(CFG)
    dec2.begin(new_session=False)  # joining a running session: nothing before it counts as lost
    assert dec2.feed(pk[2]).lost_before == 0


# ---------------------------------------------------------------------------- link


async def test_a_power_cycle_is_seen_in_the_power_up_the_wearable_reports():
    w = _wearable(seed=12, speed=1)
    link = InProcessLink(w, reconnect=FAST)
    await link.connect()
    first = (await link.read_info()).power_up
    assert first is not None and first.boot_count == 1 and first.temperature_c is not None
    w.power_cycle()  # switched off and on: the link goes, the count steps, the clock and the warm-up start again
    await link.disconnect()
    await link.connect()
    again = await link.read_power_up()
    assert again is not None and again.boot_count == 2 and again.booted_at > first.booted_at
    assert again.temperature_c == pytest.approx(24.0, abs=0.05) and again.temperature_c < first.temperature_c
    await link.disconnect()



async def test_inprocess_link_streams_the_protocol_and_it_calibrates():
    w = _wearable(seed=11, speed=200)
    link = InProcessLink(w, reconnect=FAST)
    assert isinstance(link, WearableLink)
    assert [d.address for d in await link.scan(1.0)] == [w.address]
    await link.connect()
    info = await link.read_info()
    assert info.config.sample_rate_hz == 104.0 and info.config.samples_per_packet == 3
    assert info.model and info.serial == w.serial and info.battery_pct == w.battery_pct
    await link.start()
    rb = RecordingBuilder(info)
    batches, events = await _collect(link, until_s=w.source.script_samples / w.true_rate_hz)
    for b in batches:
        rb.add(b)
    await link.stop()
    rest = [item async for item in link.samples()]  # ends: stop() closed the stream
    assert all(isinstance(x, SampleBatch) for x in rest)  # only what arrived before stop()
    await link.disconnect()
    assert events == [] and link.stats.lost_samples == 0 and link.stats.link_losses == 0
    rec = rb.recording()
    assert rec.fs == pytest.approx(w.true_rate_hz, rel=1e-6)
    assert np.all(np.diff(rec.t) > 0) and np.all(np.diff(rec.seq) == 1)

    from calib.estimators.paper import calibrate_paper

    res = calibrate_paper(rec)
    # The paper reports errors within +-5.5e-3 at this noise (0.03 deg/s); these bounds are twice that.
    np.testing.assert_allclose(res.k, w.truth["k"], atol=0.011)
    np.testing.assert_allclose(res.b, w.truth["b"], atol=0.011)
    assert w.config.state == wp.DeviceState(0)  # the device ended its session


async def test_link_drop_is_reported_with_the_exact_gap_and_the_stream_resumes():
    w = _wearable(seed=4, scenario="link_drop", speed=100)
    link = InProcessLink(w, reconnect=FAST)
    batches, events = await _session(link, until_s=w.faults.drop_at_s + 6.0)
    assert [e.kind for e in events] == ["link_lost", "link_restored"]
    lost, restored = events
    assert lost.t_device_s == pytest.approx(w.faults.drop_at_s, abs=0.05)
    n = w.samples_per_packet
    assert restored.gap_samples == w.stats.packets_lost_link * n > 0
    assert restored.gap_s >= w.faults.drop_for_s
    after = next(b for b in batches if b.lost_before)
    assert after.lost_before == restored.gap_samples and after.t_device_s[0] == restored.t_device_s
    seq = np.concatenate([b.seq for b in batches])
    assert np.sum(np.diff(seq) - 1) == restored.gap_samples
    assert link.stats.reconnects == 1 and link.stats.link_losses == 1


async def test_link_failed_when_the_device_never_comes_back():
    w = _wearable(seed=2, speed=10)
    link = InProcessLink(w, reconnect=ReconnectPolicy(initial_delay_s=0.02, max_delay_s=0.05, timeout_s=0.3),
                         scan_timeout_s=0.05)
    await link.connect()
    await link.start()
    events = []
    async for item in link.samples():
        if isinstance(item, SampleBatch) and not events and item.t_device_s[-1] > 1.0:
            w.drop_link(1e6)
        if isinstance(item, LinkEvent):
            events.append(item)
    assert [e.kind for e in events] == ["link_lost", "link_failed"]
    assert "did not come back" in events[-1].message and events[-1].attempts >= 2


async def test_packet_loss_is_counted_exactly():
    w = _wearable(seed=8, scenario="packet_loss", speed=100)
    link = InProcessLink(w, reconnect=FAST)
    await link.connect()
    await link.start()
    batches, _ = await _collect(link, until_s=25.0)
    await link.stop()
    # packets decoded after the last one collected (before stop) count too: every packet position the decoder
    # passed is one it received or one it counted as lost
    passed = link.stats.packets + link.stats.lost_packets
    lost = [j for j in w.stats.lost_radio_seqs if j < passed]
    assert len(lost) > 5
    assert link.stats.lost_samples == len(lost) * w.samples_per_packet
    collected = batches[-1].seq[-1] // w.samples_per_packet
    assert sum(b.lost_before for b in batches) == w.samples_per_packet * sum(j < collected for j in w.stats.lost_radio_seqs)


async def test_configure_changes_rate_and_packet_size_and_refuses_bad_values():
    w = _wearable(seed=3, speed=20)
    link = InProcessLink(w, reconnect=FAST)
    await link.connect()
    cfg = await link.configure(sample_rate_hz=562.5, gyro_full_scale_dps=1000, accel_range_g=8)
    assert (cfg.sample_rate_hz, cfg.samples_per_packet, cfg.gyro_lsb_per_dps, cfg.accel_lsb_per_g) == (562.5, 15, 32.8, 4096.0)
    with pytest.raises(CommandError, match="invalid_value"):
        await link.configure(sample_rate_hz=100.0)
    await link.start()
    with pytest.raises(CommandError, match="while streaming"):
        await link.configure(sample_rate_hz=104.0)
    batches, _ = await _collect(link, until_s=2.0)
    assert all(len(b) % 15 == 0 for b in batches)
    assert batches[-1].fs_hz == pytest.approx(w.true_rate_hz, rel=1e-5)
    await link.stop()
    await link.disconnect()


async def test_replayed_csv_streams_the_file_and_ends(tmp_path):
    rec, _ = simulate(5, fs=104.0)
    path = tmp_path / "rec.csv"
    write_native_csv(rec, path)
    w = Wearable(ReplaySource(path), seed=5, speed=200)
    link = InProcessLink(w, reconnect=FAST)
    await link.connect()
    info = await link.read_info()
    assert info.config.state & wp.DeviceState.REPLAY
    with pytest.raises(CommandError, match="not_supported"):
        await link.configure(sample_rate_hz=208.0)
    await link.start()
    items = [item async for item in link.samples()]
    assert isinstance(items[-1], LinkEvent) and items[-1].kind == "stream_ended"
    got = SampleBatch.concat([b for b in items if isinstance(b, SampleBatch)])
    n = len(rec) // info.config.samples_per_packet * info.config.samples_per_packet
    assert len(got) == n
    np.testing.assert_allclose(got.gyro_dps, rec.gyro[:n], atol=0.5 / 65.5 + 1e-9)
    np.testing.assert_allclose(got.t_device_s, rec.t[:n] - rec.t[0], atol=2e-6)
    await link.disconnect()


async def test_connect_errors_are_clear():
    w = _wearable()
    w.drop_link(1e6)  # out of range
    link = InProcessLink(w, scan_timeout_s=0.1)
    with pytest.raises(DeviceNotFoundError, match=w.address):
        await link.connect()
    w2 = _wearable(seed=9)
    w2.fail_next_connects(1)
    link2 = InProcessLink(w2, reconnect=FAST)
    await link2.connect()  # the first attempt drops during setup; the second succeeds
    assert link2.connected and w2.stats.connects == 1
    await link2.disconnect()
    w3 = _wearable(seed=10)
    w3.fail_next_connects(5)
    with pytest.raises(ConnectError, match="after 3 attempts"):
        await InProcessLink(w3, reconnect=FAST).connect()


async def test_disconnect_ends_the_stream_without_reconnecting():
    w = _wearable(seed=6, speed=20)
    link = InProcessLink(w, reconnect=FAST)
    await link.connect()
    await link.start()
    it = link.samples().__aiter__()
    assert isinstance(await it.__anext__(), SampleBatch)
    await link.disconnect()
    rest = [item async for item in it]
    assert all(isinstance(x, SampleBatch) for x in rest)
    await asyncio.sleep(0.1)
    assert link.stats.link_losses == 0 and link.stats.reconnects == 0 and w.stats.connects == 1


# ---------------------------------------------------------------------------- scenarios


def test_every_scenario_builds_and_unknown_names_are_refused():
    from calib.errors import GyrocalError
    from calib.simulator import Motion, Turn
    from mock_device.scenarios import SCENARIOS, get_scenario

    assert set(SCENARIOS) == {"normal", "moved_during_still", "wrong_axis", "too_fast", "stops_short", "link_drop",
                              "packet_loss", "dropped"}
    turns = {name: [s for s in ScriptedSource(seed=1, scenario=name).script.segments if isinstance(s, Turn)]
             for name in SCENARIOS}
    assert [t.axis for t in turns["normal"]] == ["x", "y", "z"]
    assert [t.axis for t in turns["wrong_axis"]] == ["x", "z", "z"]
    assert [t.angle_deg for t in turns["stops_short"]] == [360.0, 360.0, 320.0]
    assert all(t.duration_s == 0.6 for t in turns["too_fast"])
    assert any(isinstance(s, Motion) for s in ScriptedSource(seed=1, scenario="moved_during_still").script.segments)
    link_drop = ScriptedSource(seed=1, scenario="link_drop")
    t_y = sum(s.duration_s for s in link_drop.script.segments[:3])
    assert t_y < link_drop.faults.drop_at_s < t_y + link_drop.script.segments[3].duration_s
    with pytest.raises(GyrocalError, match="choose one of normal"):
        get_scenario("sideways")
    # dropped: the same sensor for two sessions, then its x scale factor 4 % higher
    dropped = ScriptedSource(seed=1, scenario="dropped")
    ks = []
    for _ in range(4):
        dropped.prepare(104.0)
        ks.append(dropped.params.k.copy())
    assert np.array_equal(ks[0], ks[1]) and np.allclose(ks[2], ks[0] * [1.04, 1.0, 1.0]) and np.array_equal(ks[2], ks[3])


async def test_too_fast_turns_arrive_saturated_and_flagged():
    w = _wearable(seed=5, scenario="too_fast", speed=200)
    link = InProcessLink(w, reconnect=FAST)
    await link.connect()
    await link.start()
    batches, _ = await _collect(link, until_s=w.source.script_samples / w.true_rate_hz)
    await link.stop()
    got = SampleBatch.concat(batches)
    assert got.saturated.sum() > 20
    assert np.abs(got.gyro_dps[got.saturated]).max() == pytest.approx(32767 / 65.5, abs=0.02)
    assert np.abs(got.gyro_dps[~got.saturated]).max() < 500.26


def _stage_axes(gyro: np.ndarray, fs: float) -> list:
    from calib.recording import Recording, RecordingMeta
    from calib.stages.detector import detect_stages

    n = gyro.shape[0]
    rec = Recording(np.arange(n) / fs, gyro, seq=np.arange(n), meta=RecordingMeta(sample_rate_hz=fs))
    return [(s.kind, s.axis, s.start, s.end) for s in detect_stages(rec) if s.kind != "still"]


def test_the_scripted_clinician_redoes_the_interrupted_turn_after_a_link_loss():
    from mock_device.sources import REDO_REST_S

    fs = 104.3
    src = ScriptedSource(seed=4, scenario="link_drop")
    src.prepare(fs)
    before = src.block(0, src.script_samples).gyro.copy()
    assert [a for _, a, _, _ in _stage_axes(before, fs)] == ["x", "y", "z"]
    for back_after_s in (0.5, 3.0):  # back while the hand is still turning, or after the turn ended
        src.prepare(fs)  # a new session: a fresh draw of the scenario, which drops mid y too
        lost_at = int(src.faults.drop_at_s * fs)  # halfway through the y turn
        y_end = int(src.segment_bounds[4])
        at = lost_at + int(back_after_s * fs)
        old = src.block(0, src.script_samples).gyro.copy()
        src.resumed(lost_at, at)
        new = src.block(0, src.script_samples).gyro
        np.testing.assert_array_equal(new[:at], old[:at])  # what was already produced is unchanged
        motions = _stage_axes(new, fs)
        assert [a for _, a, _, _ in motions] == ["x", "y", "y", "z"]
        (_, _, _, y1_end), (_, _, y2_start, _) = motions[1], motions[2]
        assert y1_end == pytest.approx(y_end, abs=0.3 * fs)  # the interrupted turn was finished
        # the redo starts only after a rest long enough for the service to ask for it again
        assert (y2_start - max(at, y1_end)) / fs > REDO_REST_S - 0.5
    assert before.shape[0] < new.shape[0] and src.replans == 1


def test_a_link_loss_during_a_rest_only_lengthens_the_rest():
    fs = 104.0
    src = ScriptedSource(seed=6)
    src.prepare(fs)
    x_end = int(src.segment_bounds[2])
    src.resumed(x_end + int(0.5 * fs), x_end + int(1.5 * fs))  # lost and back in the pause after x
    motions = _stage_axes(src.block(0, src.script_samples).gyro, fs)
    assert [a for _, a, _, _ in motions] == ["x", "y", "z"]
    assert (motions[1][2] - x_end) / fs > 1.5 + 3.0


async def test_every_session_on_a_wearable_performs_the_protocol_again():
    """START after STOP: a new session, a fresh performance by the same hand on the same sensor; the
    device clock and the link's sample times go on from the first session."""
    from server.config import Settings
    from server.live.session import GuidedSession

    w = _wearable(seed=12, speed=200)
    link = InProcessLink(w, reconnect=FAST)
    await link.connect()
    info = await link.read_info()
    truth = dict(w.truth)
    got = []
    for _ in range(2):
        await link.start()
        session = GuidedSession("s", "dev", Settings(db_url="sqlite://"))
        session.connected(info.config.sample_rate_hz, {}, float(info.config.gyro_full_scale_dps))
        batches = []
        async for item in link.samples():
            assert isinstance(item, SampleBatch)
            batches.append(item)
            session.feed(item.t_device_s, item.gyro_dps, item.accel_g, item.seq, item.lost_before)
            if session.state == "computing" or session.finished:
                break
        await link.stop()
        assert session.state == "computing", session.reason
        assert session.warnings == [] and session.lost_samples == 0
        got.append(SampleBatch.concat(batches))
    await link.disconnect()
    first, second = got
    assert second.t_device_s[0] > first.t_device_s[-1]  # the device clock went on
    assert w.stats.sessions == 2 and w.source.session == 2 and w.truth == truth
    for b in got:
        assert [a for _, a, _, _ in _stage_axes(b.gyro_dps, w.true_rate_hz)] == ["x", "y", "z"]
    n = min(len(first), len(second))
    assert not np.allclose(first.gyro_dps[:n], second.gyro_dps[:n])  # a new recording, not a replay


def _retimed(seq: int, t_us: int, n: int = 3) -> bytes:
    return wp.encode_packet(seq % wp.SEQ_MODULUS, t_us % wp.CLOCK_MODULUS, np.zeros((n, 6), np.int16), 0, CFG.config_id)


def test_one_packet_stamped_2000_s_ahead_is_dropped_not_trusted_as_the_clock():
    pk = _packets(200, fs_true=104.0, t0_us=0)
    pk[50] = _retimed(50, round(50 * 3e6 / 104.0) + 2_000_000_000)
    dec = StreamDecoder(CFG)
    dec.begin(new_session=True)
    out = [b for b in (dec.feed(p) for p in pk) if b is not None]
    t = np.concatenate([b.t_device_s for b in out])
    assert len(out) == 199 and np.all(np.diff(t) > 0) and t[-1] == pytest.approx(599 / 104.0, abs=1e-4)
    assert dec.stats.malformed_reasons == {"inconsistent": 1}
    assert dec.stats.lost_samples == 0 and sum(b.refused_before for b in out) == 3  # its own samples only, refused


def test_one_packet_with_its_sequence_number_30000_ahead_is_dropped():
    pk = _packets(200, fs_true=104.0, t0_us=0)
    pk[50] = _retimed(50 + 30_000, round(50 * 3e6 / 104.0))
    dec = StreamDecoder(CFG)
    dec.begin(new_session=True)
    out = [b for b in (dec.feed(p) for p in pk) if b is not None]
    assert len(out) == 199 and sum(b.refused_before for b in out) == 3 and out[-1].seq[-1] == 599
    assert dec.stats.lost_samples == 0
    assert dec.stats.malformed_reasons == {"inconsistent": 1} and dec.stats.resyncs == 0


def test_a_clock_that_jumps_and_stays_is_followed_after_three_packets_with_a_continuous_time_line():
    fs = 104.0
    pk = _packets(50, fs_true=fs, t0_us=0) + [_retimed(j, round(j * 3e6 / fs) + 700_000_000) for j in range(50, 200)]
    dec = StreamDecoder(CFG)
    dec.begin(new_session=True)
    out = [b for b in (dec.feed(p) for p in pk) if b is not None]
    t = np.concatenate([b.t_device_s for b in out])
    assert dec.stats.resyncs == 1 and dec.stats.malformed_reasons == {}  # held back, then delivered: none dropped
    assert dec.stats.lost_samples == 0 and out[-1].seq[-1] == 599 and len(t) == 600
    assert np.all(np.diff(t) > 0) and float(np.diff(t).max()) == pytest.approx(1 / fs, rel=1e-3)  # no jump in time
    assert t[-1] == pytest.approx(599 / fs, abs=1e-3) and dec.fs_hz == pytest.approx(fs, rel=1e-4)


def test_a_corrupt_first_packet_does_not_hold_the_stream_hostage():
    pk = _packets(100, fs_true=104.0, t0_us=0)
    pk[0] = _retimed(0, 123_456_789)
    dec = StreamDecoder(CFG)
    dec.begin(new_session=True)
    out = [b for b in (dec.feed(p) for p in pk) if b is not None]
    t = np.concatenate([b.t_device_s for b in out])
    assert dec.stats.resyncs == 1 and out[-1].seq[-1] == 299 and len(t) == 300 and np.all(np.diff(t) > 0)
