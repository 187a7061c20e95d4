"""Commercial wearables' protocols through the real bleak client on the simulated BlueZ: the scan names
each model, and the stream a model's adapter decodes calibrates to the simulated sensor's truth."""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest
from test_ble_e2e import FAST, _assert_matches_truth, _calibrate, _stream

from mock_device.sources import ScriptedSource
from mock_device.vendors import WEARABLES
from mock_device.vendors.thingy52 import IDLE_LED
from mock_device.wearable import Wearable
from server.link import CommandError, RecordingBuilder
from server.link.ble import BleLink
from wearable_protocol.models import MODELS

SPEED = 20.0


def _device_clock(speed: float):  # type: ignore[no-untyped-def]
    """Arrival times on the simulated device's time scale (it runs ``speed`` times faster than the wall)."""
    t0 = time.monotonic()
    return lambda: (time.monotonic() - t0) * speed


async def test_a_scan_names_the_model_of_every_wearable(simulated_bluez):
    devices = [WEARABLES[m](ScriptedSource(seed=i), seed=i, speed=SPEED) for i, m in enumerate(MODELS, start=1)]
    simulated_bluez(devices)
    found = await BleLink().scan(1.5)
    assert {(d.address, d.model) for d in found} == {(w.address, w.model.key) for w in devices}
    polar = await BleLink(model="polar-pmd").scan(1.5)
    assert [d.model for d in polar] == ["polar-pmd"] and polar[0].name.startswith("Polar Sense ")


@pytest.mark.parametrize("model", ["polar-pmd", "metawear", "thingy52", "movella-dot"])
async def test_each_vendor_calibrates_through_bleak(simulated_bluez, model):
    seed = 31
    # arrival-timed models: a wall-clock delivery delay is `speed` times longer on the device's time scale, so they
    # run slower here for their rate fit to reach the estimator's bound (a real device runs at speed 1); at 4x, one
    # full run on a busy machine put MetaWear's k 5.1 of its standard errors off (its rate, from late arrivals), so 2x
    speed = SPEED if MODELS[model].time_stamps == "device" else 2.0
    w: Wearable = WEARABLES[model](ScriptedSource(seed=seed), seed=seed, speed=speed)
    simulated_bluez([w])
    link = BleLink(w.address, reconnect=FAST, clock=_device_clock(speed))
    await link.connect()
    info = await link.read_info()
    assert info.device_model == model and info.config.sample_rate_hz == MODELS[model].stream_rate_hz
    await link.start()
    duration = sum(s.duration_s for s in ScriptedSource(seed=seed).script.segments)
    rb = RecordingBuilder(info)
    _, events = await _stream(link, duration, rb.add)
    await link.stop()
    await link.disconnect()
    assert events == [] and link.stats.malformed_packets == 0
    rec = rb.recording()
    assert np.all(np.diff(rec.seq) == 1) and np.all(np.diff(rec.t) > 0)
    assert rec.fs == pytest.approx(w.true_rate_hz, rel=5e-4)
    _assert_matches_truth(_calibrate(rec), w.truth)


async def test_identify_blinks_each_wearable_whose_protocol_can_and_names_the_one_that_cannot(simulated_bluez):
    """IDENTIFY through the real bleak client, one wearable of each model on one adapter: gyrocal's opcode (while
    streaming), the MetaWear LED module's blink pattern, the Thingy:52's LED characteristic (put back afterwards) and the
    Movella DOT's device control (its own 10 s pattern, a twentieth of it here); Polar's PMD has no such command."""
    wearables = {m: WEARABLES[m](ScriptedSource(seed=5 + i), seed=5 + i, speed=SPEED) for i, m in enumerate(MODELS)}
    simulated_bluez(list(wearables.values()))
    links = {m: BleLink(w.address, reconnect=FAST) for m, w in wearables.items()}
    try:
        for link in links.values():
            await link.connect()
            await link.read_info()
        with pytest.raises(CommandError, match="no command to blink or buzz"):
            await links["polar-pmd"].identify(2)
        await links["gyrocal"].start()  # a streaming wearable blinks too, and streams on
        blinking = [m for m in MODELS if MODELS[m].identify is not None]
        assert blinking == ["gyrocal", "metawear", "thingy52", "movella-dot"] and not any(w.identifying for w in wearables.values())
        for m in blinking:
            await links[m].identify(1)
        deadline = time.monotonic() + 2.0
        while not all(wearables[m].identifying for m in blinking) and time.monotonic() < deadline:
            await asyncio.sleep(0.02)
        assert [m for m in MODELS if wearables[m].identifying] == blinking
        assert all(wearables[m].stats.identified == 1 for m in blinking)
        await asyncio.sleep(1.6)
        assert not any(w.identifying for w in wearables.values())  # one second asked, one given
        assert wearables["thingy52"].led == IDLE_LED  # type: ignore[attr-defined]  # put back as it was
        assert links["gyrocal"].stats.packets > 0
        with pytest.raises(CommandError, match="invalid_value"):
            await links["gyrocal"].identify(61)
    finally:
        for link in links.values():
            await link.disconnect()
