"""Link throughput: CPU needed to decode and stage-track 20 wearables streaming at 562.5 Hz.

Run: .venv/bin/python bench/link_throughput.py [--devices 20] [--rate 562.5] [--ble --seconds 20]

Default mode: the data packets of N simulated wearables (the protocol at 562.5 Hz, N = 15 samples per
packet, 37.5 notifications/s each) are generated first, then fed one notification at a time,
round-robin in device-time order, to one StreamDecoder and one StageTracker per wearable, exactly as
the link client and the live session do. Reported: CPU seconds per second of stream, i.e. the share of
one core that N wearables need in real time (the target is under half a core).

--ble: the same N wearables served by ``gyrocal mock-device --ble --count N`` in real time, N BleLink
clients in this process (bleak, D-Bus, decoding and stage tracking) for --seconds; reports the CPU
share of this process, of the simulated devices and of the dbus-daemon.
"""

from __future__ import annotations

import argparse
import asyncio
import heapq
import json
import os
import subprocess
import sys
import time

import numpy as np

import wearable_protocol as wp
from calib.stages.detector import StageTracker
from mock_device.sources import ScriptedSource
from server.link import StreamDecoder


def _packets(seed: int, rate: float, seconds: float) -> tuple[wp.DeviceConfig, list[tuple[float, bytes]]]:
    """(device time, notification bytes) of one simulated wearable."""
    n = wp.samples_per_packet(rate)
    fs_true = rate * (1 + 0.004 * ((seed % 5) - 2) / 2)
    src = ScriptedSource(seed=seed)
    src.prepare(fs_true)
    cfg = wp.DeviceConfig(1, rate, 500, 4, n, 65.5, 8192.0)
    out = []
    clock0 = 2**32 - 1_000_000 * (seed + 1)
    for j in range(int(seconds * fs_true) // n):
        blk = src.block(j * n, (j + 1) * n)
        counts, _ = wp.quantize(blk.gyro, blk.accel, 65.5, 8192.0)
        t = j * n / fs_true
        out.append((t, wp.encode_packet(j, clock0 + round(t * 1e6), counts, 0, 1)))
    return cfg, out


def bench_decode(devices: int, rate: float, seconds: float, repeat: int) -> dict[str, float]:
    streams = [_packets(s, rate, seconds) for s in range(devices)]
    order = list(heapq.merge(*[[(t, i, data) for t, data in pk] for i, (_, pk) in enumerate(streams)]))
    notifications = len(order)
    duration = max(pk[-1][0] for _, pk in streams)
    best = float("inf")
    for _ in range(repeat):
        decoders = [StreamDecoder(cfg) for cfg, _ in streams]
        for d in decoders:
            d.begin(new_session=True)
        trackers = [StageTracker(rate) for _ in streams]
        c0 = time.process_time()
        for _, i, data in order:
            b = decoders[i].feed(data)
            if b is not None:
                trackers[i].feed(b.t_device_s, b.gyro_dps, b.seq)
        best = min(best, time.process_time() - c0)
        assert all(d.stats.lost_samples == 0 and d.stats.malformed_packets == 0 for d in decoders)
        stages = [len(t.stages) for t in trackers]
    c0 = time.process_time()
    decoders = [StreamDecoder(cfg) for cfg, _ in streams]
    for _, i, data in order:
        decoders[i].feed(data)
    decode_only = time.process_time() - c0
    return {
        "devices": devices, "rate_hz": rate, "stream_s": duration, "notifications": notifications,
        "cpu_s": best, "cores": best / duration, "decode_only_cores": decode_only / duration,
        "us_per_notification": 1e6 * best / notifications, "stages_found_per_device": float(np.mean(stages)),
    }


def _cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


async def _ble_clients(addresses: list[str], rate: float, seconds: float) -> dict[str, float]:
    from server.link import LinkEvent
    from server.link.ble import BleLink

    links = [BleLink(a) for a in addresses]
    for link in links:
        await link.connect()
        await link.configure(sample_rate_hz=rate)
    trackers = [StageTracker(rate) for _ in links]
    for link in links:
        await link.start()

    async def consume(i: int) -> None:
        async for item in links[i].samples():
            if not isinstance(item, LinkEvent):
                trackers[i].feed(item.t_device_s, item.gyro_dps, item.seq)

    tasks = [asyncio.create_task(consume(i)) for i in range(len(links))]
    await asyncio.sleep(2.0)  # settle
    w0, c0 = time.monotonic(), time.process_time()
    s0 = sum(link.stats.samples for link in links)
    await asyncio.sleep(seconds)
    wall, cpu = time.monotonic() - w0, time.process_time() - c0
    samples = sum(link.stats.samples for link in links) - s0
    for link in links:
        await link.stop()
        await link.disconnect()
    for t in tasks:
        t.cancel()
    return {"wall_s": wall, "client_cores": cpu / wall, "samples_per_s": samples / wall,
            "lost_samples": float(sum(link.stats.lost_samples for link in links)),
            "malformed": float(sum(link.stats.malformed_packets for link in links))}


def bench_ble(devices: int, rate: float, seconds: float) -> dict[str, float]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "calib.cli.main", "mock-device", "--ble", "--count", str(devices), "--rate", str(rate)],
        stdout=subprocess.PIPE, text=True,
    )
    try:
        line = json.loads(proc.stdout.readline())
        os.environ["DBUS_SYSTEM_BUS_ADDRESS"] = line["dbus_address"]
        daemon = int(subprocess.run(["pgrep", "-P", str(proc.pid), "dbus-daemon"], capture_output=True,
                                    text=True).stdout.split()[0])
        addresses = [d["address"] for d in line.get("devices", [line])]
        d0, b0, w0 = _cpu_s(proc.pid), _cpu_s(daemon), time.monotonic()
        result = asyncio.run(_ble_clients(addresses, rate, seconds))
        wall = time.monotonic() - w0
        result["device_process_cores"] = (_cpu_s(proc.pid) - d0) / wall
        result["dbus_daemon_cores"] = (_cpu_s(daemon) - b0) / wall
        result.update(devices=devices, rate_hz=rate)
        return result
    finally:
        proc.terminate()
        proc.wait(15)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--devices", type=int, default=20)
    ap.add_argument("--rate", type=float, default=562.5)
    ap.add_argument("--seconds", type=float, default=30.0, help="stream length (device time; --ble: wall time)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--ble", action="store_true", help="through bleak and the simulated BlueZ, in real time")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if args.ble:
        r = bench_ble(args.devices, args.rate, args.seconds)
        text = (f"{args.devices} wearables at {args.rate:g} Hz over bleak + simulated BlueZ, {r['wall_s']:.0f} s: "
                f"client process {r['client_cores']:.2f} cores (bleak, D-Bus, decoding, stage tracking), "
                f"simulated devices {r['device_process_cores']:.2f}, dbus-daemon {r['dbus_daemon_cores']:.2f}; "
                f"{r['samples_per_s']:.0f} samples/s received, {r['lost_samples']:.0f} lost, {r['malformed']:.0f} malformed")
    else:
        r = bench_decode(args.devices, args.rate, args.seconds, args.repeat)
        text = (f"{args.devices} wearables at {args.rate:g} Hz ({r['notifications']} notifications, {r['stream_s']:.1f} s "
                f"of stream): decoding + live stage detection {r['cores']:.3f} of one core "
                f"(decoding alone {r['decode_only_cores']:.3f}; {r['us_per_notification']:.1f} us per notification)")
    print(json.dumps(r) if args.json else text)


if __name__ == "__main__":
    main()
