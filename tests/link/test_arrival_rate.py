"""A wearable that sends no time stamps: its rate comes from when its notifications arrived, and the calibration's
uncertainty carries what that estimate leaves unknown, through every door (the link, the file, the calibration)."""

from __future__ import annotations

import io

import numpy as np
import pytest

from calib.errors import RecordingError
from calib.io.readers import parse_recording_text, write_native_csv
from calib.pipeline import calibrate
from calib.simulator import simulate
from server.link.adapters.arrival import ArrivalTimeline
from server.link.base import LinkStats

TRUE_RATE_HZ = 99.33
NOMINAL_HZ = 100.0
PER_PACKET = 3


def _arrivals(rng: np.random.Generator, duration_s: float, stall: tuple[float, float] | None = None) -> ArrivalTimeline:
    """A stream of ``duration_s``: packets sent every PER_PACKET samples at the true rate and delivered after a delay
    that is never negative (the next connection event of 7.5 ms, retransmissions, a busy central); ``stall``: the
    central does not run from its first to its second time (s) and takes what came in one go."""
    line = ArrivalTimeline(LinkStats(), NOMINAL_HZ)
    sent = np.arange(PER_PACKET, int(duration_s * TRUE_RATE_HZ), PER_PACKET) / TRUE_RATE_HZ
    delay = np.ceil(rng.uniform(0, 1, sent.size) * 2) * 0.0075 + rng.exponential(0.004, sent.size)
    arrival = np.maximum.accumulate(sent + delay)  # in the order they were sent
    if stall is not None:
        arrival = np.where((arrival > stall[0]) & (arrival < stall[1]), stall[1], arrival)
    zeros = np.zeros((PER_PACKET, 3))
    for a in arrival:
        line.place(float(a), zeros, zeros, np.zeros(PER_PACKET, dtype=bool))
    return line


def test_the_rate_from_arrival_times_is_off_by_what_its_standard_error_says() -> None:
    rng = np.random.default_rng(7)
    z = []
    for _ in range(200):
        line = _arrivals(rng, 21.0)
        assert line.fs_rel_std is not None and 0 < line.fs_rel_std < 1e-3
        z.append((line.fs_hz / TRUE_RATE_HZ - 1.0) / line.fs_rel_std)
    # the normalised errors scatter as a standard normal would (200 draws: sd within about 0.1 of 1)
    assert 0.75 < np.std(z) < 1.3 and abs(np.mean(z)) < 0.3, (np.std(z), np.mean(z))


def test_a_stalled_central_widens_the_rate_uncertainty_to_cover_its_error() -> None:
    rng = np.random.default_rng(11)
    calm = _arrivals(rng, 21.0)
    stalled = _arrivals(rng, 21.0, stall=(14.0, 14.6))
    assert calm.fs_rel_std is not None and stalled.fs_rel_std is not None
    assert abs(stalled.fs_hz / TRUE_RATE_HZ - 1.0) < 4 * stalled.fs_rel_std


def test_the_rate_uncertainty_is_in_the_scale_factors_and_survives_the_native_file() -> None:
    rec, truth = simulate(3, noise=0.03)
    rel = 2e-4
    placed = rec.timed_by_counter(rec.fs * (1 + rel), rel)  # the rate estimate off by one standard error
    exact = calibrate(rec)
    result = calibrate(placed)
    assert exact.k_std is not None and result.k_std is not None
    np.testing.assert_allclose(result.k_std, np.hypot(exact.k_std, result.k * rel), rtol=0.05)
    assert result.quality["sample_rate_rel_std"] == rel
    assert np.all(np.abs(result.k - truth.k) < 3 * result.k_std)  # the uncertainty covers the rate's error
    # the file the service keeps for a session says it too, and calibrates the same from the command line
    buf = io.StringIO()
    write_native_csv(placed, buf)
    assert buf.getvalue().startswith(f"# sample_rate_rel_std: {rel!r}\n")
    again = calibrate(parse_recording_text(buf.getvalue(), source="session.csv"))
    assert again.k_std is not None
    np.testing.assert_array_equal(again.k, result.k)
    np.testing.assert_array_equal(again.k_std, result.k_std)


@pytest.mark.parametrize("value", ["abc", "-1e-4", "nan", "2"])
def test_a_bad_rate_uncertainty_comment_says_what_to_write(value: str) -> None:
    rec, _ = simulate(3, noise=0.03)
    buf = io.StringIO()
    write_native_csv(rec, buf)
    with pytest.raises(RecordingError, match=r"session.csv: the comment '# sample_rate_rel_std: .*' needs a relative "
                                             r"standard error from 0 to 1, such as '# sample_rate_rel_std: 2e-05'"):
        parse_recording_text(f"# sample_rate_rel_std: {value}\n" + buf.getvalue(), source="session.csv")


def test_a_multi_position_calibration_carries_the_rate_uncertainty_too() -> None:
    from calib.pipeline import calibrate_protocol
    from calib.simulator.lab_scripts import multi_position_script

    rec, _ = simulate(4, noise=0.05, fs=100.0, script=multi_position_script(np.random.default_rng(4)), accel_noise_g=0.005)
    rel = 2e-4
    exact, _ = calibrate_protocol(rec, "multi-position")
    placed, _ = calibrate_protocol(rec.with_meta(sample_rate_rel_std=rel), "multi-position")
    assert exact.k_std is not None and placed.k_std is not None
    np.testing.assert_allclose(placed.k_std, np.hypot(exact.k_std, placed.k * rel))
    assert placed.quality["sample_rate_rel_std"] == rel


def test_a_gap_is_measured_from_when_the_last_sample_before_it_was_sent_not_from_its_late_arrival() -> None:
    """A link drops for 2 s after 6 s of streaming, and the central was busy just before: the last notification before
    the drop arrived 100 ms late. The gap is measured back to when that sample was sent (the lower envelope of
    arrivals), so it is not 10 samples short."""
    sent = np.arange(PER_PACKET, int(10.0 * TRUE_RATE_HZ), PER_PACKET) / TRUE_RATE_HZ
    rng = np.random.default_rng(5)
    arrival = sent + 0.0075 + rng.exponential(0.002, sent.size)
    drop = (sent > 6.0) & (sent < 8.0)
    last = int(np.flatnonzero(sent <= 6.0)[-1])
    arrival[last] += 0.100  # the central ran late just before the drop
    line = ArrivalTimeline(LinkStats(), NOMINAL_HZ)
    zeros = np.zeros((PER_PACKET, 3))
    gaps = []
    for i in np.flatnonzero(~drop):
        if i == last + 1 + int(drop.sum()):
            line.begin(resume=True)  # the link came back
        batch = line.place(float(arrival[i]), zeros, zeros, np.zeros(PER_PACKET, dtype=bool))
        gaps.append(batch.lost_before)
    truth = int(drop.sum()) * PER_PACKET
    assert [g for g in gaps if g] == [pytest.approx(truth, abs=2)], (sum(gaps), truth)
