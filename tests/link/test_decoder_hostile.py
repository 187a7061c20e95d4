"""The stream decoder under hostile streams (property-based): corrupt time stamps and sequence numbers, garbage,
replays. Whatever arrives, it never raises, its time line only moves forward, and a corrupt packet costs at most
its own samples."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import wearable_protocol as wp
from server.link import StreamDecoder

CFG = wp.DeviceConfig(1, 104.0, 500, 4, 3, 65.5, 8192.0)
N = CFG.samples_per_packet
FS = 104.0
RAW = np.zeros((N, 6), np.int16)


def _good(j: int, t0_us: int) -> bytes:
    return wp.encode_packet(j % wp.SEQ_MODULUS, (t0_us + round(j * N * 1e6 / FS)) % wp.CLOCK_MODULUS, RAW, 0, CFG.config_id)


hostile = st.one_of(
    st.tuples(st.just("time"), st.integers(0, wp.CLOCK_MODULUS - 1)),  # the packet's time stamp replaced
    st.tuples(st.just("seq"), st.integers(0, wp.SEQ_MODULUS - 1)),  # its sequence number replaced
    st.tuples(st.just("garbage"), st.binary(max_size=120)),  # bytes instead of it
    st.tuples(st.just("replay"), st.integers(0, 150)),  # an older packet delivered again instead
)


@settings(max_examples=150, deadline=None)
@given(t0_us=st.integers(0, wp.CLOCK_MODULUS - 1),
       faults=st.dictionaries(st.integers(1, 148), hostile, max_size=12).filter(
           lambda f: all(k + 1 not in f for k in f)))  # isolated faults: no two corrupt packets in a row
def test_isolated_corrupt_packets_cost_their_own_samples_and_nothing_more(t0_us: int, faults: dict[int, tuple[str, object]]) -> None:
    stream = []
    for j in range(150):
        kind, value = faults.get(j, ("good", None))
        if kind == "time":
            p = wp.encode_packet(j, int(value), RAW, 0, CFG.config_id)  # type: ignore[arg-type]
        elif kind == "seq":
            p = wp.encode_packet(int(value), (t0_us + round(j * N * 1e6 / FS)) % wp.CLOCK_MODULUS, RAW, 0, CFG.config_id)  # type: ignore[arg-type]
        elif kind == "garbage":
            p = bytes(value)  # type: ignore[arg-type]
        elif kind == "replay":
            p = _good(min(int(value), max(0, j - 1)), t0_us)  # type: ignore[call-overload]
        else:
            p = _good(j, t0_us)
        stream.append(p)
    dec = StreamDecoder(CFG)
    dec.begin(new_session=True)
    out = [b for b in (dec.feed(p) for p in stream) if b is not None]
    t = np.concatenate([b.t_device_s for b in out])
    counter = np.concatenate([b.seq for b in out])
    assert np.all(np.diff(t) > 0) and np.all(np.diff(counter) > 0)
    assert dec.stats.lost_samples <= N * len(faults)  # a corrupt packet is dropped, never the clock or counter moved
    assert counter[-1] == 150 * N - 1 and t[-1] == np.float64(t[-1]) and abs(t[-1] - (150 * N - 1) / FS) < 1e-3
    assert dec.stats.resyncs == 0


@settings(max_examples=100, deadline=None)
@given(st.lists(st.binary(max_size=120), max_size=60))
def test_nothing_but_garbage_is_refused_and_counted(blobs: list[bytes]) -> None:
    dec = StreamDecoder(CFG)
    dec.begin(new_session=True)
    for b in blobs:
        dec.feed(b)
    accepted = dec.stats.packets
    assert dec.stats.malformed_packets + dec.stats.duplicate_packets + accepted == len(blobs)


def _decode(stream: list[bytes]) -> tuple[StreamDecoder, list]:
    dec = StreamDecoder(CFG)
    dec.begin(new_session=True)
    return dec, [b for b in (dec.feed(p) for p in stream) if b is not None]


def test_packets_delivered_out_of_order_are_put_back_in_order_and_nothing_is_lost() -> None:
    """50 pairs of packets swapped on the link (as a BLE stack that retransmits may deliver them): every sample is
    kept, in order; before, the later one of each pair was dropped as stale and 150 samples counted lost."""
    order = list(range(300))
    for j in range(1, 300, 6)[:50]:
        order[j], order[j + 1] = order[j + 1], order[j]
    dec, out = _decode([_good(j, 1000) for j in order])
    counter = np.concatenate([b.seq for b in out])
    assert np.array_equal(counter, np.arange(300 * N)), "every sample, in order"
    assert dec.stats.lost_samples == 0 and sum(b.lost_before for b in out) == 0
    assert dec.stats.duplicate_packets == 0


def test_a_real_gap_after_a_waiting_packet_is_still_counted_lost() -> None:
    stream = [_good(j, 1000) for j in range(100) if j not in (40, 70, 71)]
    dec, out = _decode(stream)
    counter = np.concatenate([b.seq for b in out])
    assert counter[-1] == 100 * N - 1 and counter.size == 97 * N
    assert dec.stats.lost_samples == 3 * N and sum(b.lost_before for b in out) == 3 * N


def test_samples_in_packets_the_wearable_sent_malformed_are_its_own_not_the_radios() -> None:
    """Two packets of every three of the wrong length: refused, and the samples they held are counted as refused
    (the firmware's), none as lost on the radio."""
    stream = [_good(j, 1000) + (b"\0" if j % 3 else b"") for j in range(150)]
    dec, out = _decode(stream)
    assert dec.stats.malformed_reasons == {"length": 100}
    assert dec.stats.lost_samples == 0 and sum(b.lost_before for b in out) == 0
    assert sum(b.refused_before for b in out) == 98 * N  # the last two refused have no packet after them


def test_a_forged_packet_costs_its_own_samples_as_refused() -> None:
    stream = [_good(j, 1000) for j in range(60)]
    stream[30] = wp.encode_packet(30, 999_999_999, RAW, 0, CFG.config_id)  # its time stamp forged
    dec, out = _decode(stream)
    assert dec.stats.malformed_reasons == {"inconsistent": 1}
    assert dec.stats.lost_samples == 0 and sum(b.refused_before for b in out) == N
