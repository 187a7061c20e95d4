"""The firmware-side C99 library (wearable_protocol/c), built here with the system C compiler under strict
warnings: every encoding it makes is bit-exact with the Python protocol on random and edge-case inputs, its
command decoder answers every write as the simulated wearable does, and a host program running its streaming
loop on simulated samples is decoded by the service's own decoder and calibrated to the truth."""

from __future__ import annotations

import ctypes
import math
import shutil
import struct
import subprocess
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_ble_e2e import _assert_matches_truth, _calibrate

import wearable_protocol as wp
from calib.simulator import simulate
from server.link import LinkStats, RecordingBuilder, StreamDecoder
from server.link.base import DeviceInfo
from wearable_protocol import Command, DecodeError, DeviceConfig, HeldCalibration, Opcode, Status

C_DIR = Path(__file__).resolve().parents[2] / "wearable_protocol" / "c"
CFLAGS = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Wconversion", "-Wsign-conversion", "-Wshadow", "-Werror"]


class Config(ctypes.Structure):
    _fields_ = [("config_id", ctypes.c_uint8), ("rate_hz", ctypes.c_float), ("gyro_full_scale_dps", ctypes.c_uint16),
                ("accel_range_g", ctypes.c_uint8), ("samples_per_packet", ctypes.c_uint8),
                ("gyro_lsb_per_dps", ctypes.c_float), ("accel_lsb_per_g", ctypes.c_float), ("state", ctypes.c_uint8)]


class Calibration(ctypes.Structure):
    _fields_ = [("id", ctypes.c_uint32), ("K", ctypes.c_float * 9), ("b", ctypes.c_float * 3)]


class Arg(ctypes.Union):
    _fields_ = [("rate_hz", ctypes.c_float), ("gyro_full_scale_dps", ctypes.c_uint16), ("accel_range_g", ctypes.c_uint8),
                ("identify_s", ctypes.c_uint8), ("calibration", Calibration)]


class CommandC(ctypes.Structure):
    _fields_ = [("opcode", ctypes.c_uint8), ("arg", Arg)]


def _compile(out: Path, *sources: Path, shared: bool = False) -> Path:
    cc = shutil.which("cc")
    assert cc, "no C compiler: install gcc (make system-deps does)"
    cmd = [cc, *CFLAGS, *(["-shared", "-fPIC"] if shared else []), "-o", str(out), *map(str, sources)]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert done.returncode == 0, f"{' '.join(cmd)}\n{done.stderr}"
    return out


@pytest.fixture(scope="module")
def lib(tmp_path_factory: pytest.TempPathFactory) -> ctypes.CDLL:
    so = _compile(tmp_path_factory.mktemp("c") / "libgyrocal_protocol.so", C_DIR / "gyrocal_protocol.c", shared=True)
    lib = ctypes.CDLL(str(so))
    lib.gc_crc32.restype = ctypes.c_uint32
    lib.gc_crc32.argtypes = [ctypes.c_char_p, ctypes.c_size_t]
    lib.gc_samples_per_packet.restype = ctypes.c_uint8
    lib.gc_samples_per_packet.argtypes = [ctypes.c_float, ctypes.c_uint16]
    lib.gc_encode_packet.restype = ctypes.c_size_t
    lib.gc_encode_packet.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_uint8, ctypes.c_uint8, ctypes.c_uint16,
                                     ctypes.c_uint32, ctypes.c_void_p, ctypes.c_uint8]
    lib.gc_decode_command.restype = ctypes.c_uint8
    lib.gc_decode_command.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.POINTER(CommandC)]
    lib.gc_apply_calibration.argtypes = [ctypes.POINTER(Calibration), ctypes.POINTER(ctypes.c_float), ctypes.POINTER(ctypes.c_float)]
    return lib


@pytest.fixture(scope="module")
def host(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _compile(tmp_path_factory.mktemp("host") / "gyrocal_host", C_DIR / "host" / "gyrocal_host.c", C_DIR / "gyrocal_protocol.c")


def _buf(size: int) -> ctypes.Array[ctypes.c_char]:
    return ctypes.create_string_buffer(size)


# -- the encodings, bit for bit ---------------------------------------------------------------------------
def test_crc32_check_value(lib):
    assert lib.gc_crc32(b"123456789", 9) == 0xCBF43926  # the CRC-32 check value (see test_write_back.py)


@given(st.binary(max_size=300))
def test_crc32_matches_zlib(lib, data):
    assert lib.gc_crc32(data, len(data)) == zlib.crc32(data)


int16 = st.integers(-32768, 32767)


@settings(max_examples=300)
@given(st.integers(1, 19).flatmap(lambda n: st.lists(st.lists(int16, min_size=6, max_size=6), min_size=n, max_size=n)),
       st.integers(0, 0xFFFF), st.integers(0, 0xFFFFFFFF), st.sampled_from([0, 1, 2, 4, 5, 6, 7]), st.integers(0, 255))
def test_packets_are_bit_exact(lib, samples, seq, t_us, flags, config_id):
    raw = np.array(samples, dtype="<i2")
    out = _buf(wp.HEADER_SIZE + 19 * wp.SAMPLE_SIZE)
    size = lib.gc_encode_packet(out, len(out), flags, config_id, seq, t_us, raw.ctypes.data, len(raw))
    expected = wp.encode_packet(seq, t_us, raw, flags, config_id)
    assert out.raw[:size] == expected
    p = wp.decode_packet(expected)
    assert (p.seq, p.t_first_us, int(p.flags), p.config_id) == (seq, t_us, flags, config_id)
    assert np.array_equal(p.raw, raw)


def test_packet_limits(lib):
    raw = np.zeros((20, 6), dtype="<i2")
    out = _buf(400)
    assert lib.gc_encode_packet(out, len(out), 0, 0, 0, 0, raw.ctypes.data, 20) == 0  # more than one MTU-247 packet
    assert lib.gc_encode_packet(out, len(out), 0, 0, 0, 0, raw.ctypes.data, 0) == 0
    assert lib.gc_encode_packet(out, 21, 0, 0, 0, 0, raw.ctypes.data, 1) == 0  # 22 bytes do not fit 21


float32 = st.floats(width=32, allow_nan=False, allow_infinity=False)


@given(st.integers(0, 255), float32, st.integers(0, 0xFFFF), st.integers(0, 255), st.integers(0, 255), float32, float32,
       st.integers(0, 255))
def test_config_is_bit_exact(lib, cid, rate, gfs, arange, n, gsens, asens, state):
    out = _buf(wp.CONFIG_SIZE)
    lib.gc_encode_config(out, ctypes.byref(Config(cid, rate, gfs, arange, n, gsens, asens, state)))
    assert out.raw == DeviceConfig(cid, rate, gfs, arange, n, gsens, asens, wp.DeviceState(state)).encode()


def test_samples_per_packet_follows_the_protocol(lib):
    for mtu in (25, 50, 100, 185, 247, 512):
        for rate in (*wp.SUPPORTED_RATES_HZ, 1.0, 40.0, 40.5, 1000.0):
            # the library's packet buffer holds GC_MAX_SAMPLES = 19 (an MTU of 247): larger MTUs are capped there
            assert lib.gc_samples_per_packet(rate, mtu) == min(19, wp.samples_per_packet(rate, mtu)), (rate, mtu)
    assert lib.gc_samples_per_packet(104.0, 24) == 0
    with pytest.raises(ValueError):
        wp.samples_per_packet(104.0, 24)


# -- control writes: the C decoder answers as the simulated wearable does ------------------------------------
def _python_status(data: bytes) -> Status:
    """The status gyrocal's simulated wearable answers a control write's decoding with."""
    try:
        cmd = Command.decode(data)
    except DecodeError as e:
        return Status.UNKNOWN_OPCODE if e.reason == "opcode" else Status.BAD_LENGTH
    if cmd.opcode == Opcode.IDENTIFY and not 1 <= int(cmd.value) <= wp.IDENTIFY_MAX_S:  # type: ignore[arg-type]
        return Status.INVALID_VALUE
    if cmd.opcode == Opcode.WRITE_CALIBRATION:
        try:
            HeldCalibration.from_payload(bytes(cmd.value))  # type: ignore[arg-type]
        except DecodeError as e:
            return Status.CHECKSUM if e.reason == "checksum" else Status.INVALID_VALUE
    return Status.OK


def _calibration_write(cid: int, values: list[float], crc_ok: bool = True) -> bytes:
    params = struct.pack("<I12f", cid, *values)
    crc = zlib.crc32(params) ^ (0 if crc_ok else 1)
    return bytes([Opcode.WRITE_CALIBRATION]) + params + struct.pack("<I", crc)


def _check_command(lib, data: bytes) -> None:
    cmd = CommandC()
    status = lib.gc_decode_command(data, len(data), ctypes.byref(cmd))
    assert status == _python_status(data), data.hex()
    if status != Status.OK:
        return
    py = Command.decode(data)
    assert cmd.opcode == py.opcode
    if py.opcode == Opcode.SET_RATE:
        assert struct.pack("<f", cmd.arg.rate_hz) == data[1:]
    elif py.opcode == Opcode.SET_GYRO_RANGE:
        assert cmd.arg.gyro_full_scale_dps == py.value
    elif py.opcode == Opcode.SET_ACCEL_RANGE:
        assert cmd.arg.accel_range_g == py.value
    elif py.opcode == Opcode.IDENTIFY:
        assert cmd.arg.identify_s == py.value
    elif py.opcode == Opcode.WRITE_CALIBRATION:
        held = HeldCalibration.from_payload(bytes(py.value))  # type: ignore[arg-type]
        c = cmd.arg.calibration
        assert (c.id, tuple(c.K), tuple(c.b)) == (held.calibration_id, held.K, held.b)


EDGE_VALUES = [0.0, -0.0, 1.0, 1e6, float(np.nextafter(np.float32(1e6), np.float32(np.inf))), -1e6, math.nan, math.inf,
               -math.inf, 1e-30, 3.4e38]


def test_edge_case_commands(lib):
    writes = [b"", b"\x00", b"\x10", b"\xff", *[bytes([op]) + bytes(n) for op in range(1, 9) for n in range(0, 60)]]
    writes += [bytes([Opcode.IDENTIFY, s]) for s in range(256)]  # 1..60 s obeyed, 0 and longer refused
    identity = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.1, -0.2, 0.3]
    for i in range(12):
        for v in EDGE_VALUES:
            values = list(identity)
            values[i] = v
            writes.append(_calibration_write(9, values))
    writes.append(_calibration_write(9, identity, crc_ok=False))
    writes.append(_calibration_write(0xFFFFFFFF, identity))
    writes.append(_calibration_write(1, [1.0, 2.0, 3.0, 2.0, 4.0, 6.0, 0.5, 0.1, 0.2, 0.0, 0.0, 0.0]))  # rank 2
    for det_scale in (1e-3, 1.0e-3 * 1.0001, 0.999e-3):  # det = scale^3 around the 1e-9 threshold
        writes.append(_calibration_write(2, [det_scale, 0, 0, 0, det_scale, 0, 0, 0, det_scale, 0, 0, 0]))
    for data in writes:
        _check_command(lib, data)


@settings(max_examples=400)
@given(st.one_of(
    st.binary(max_size=64),
    st.builds(lambda cid, vals: _calibration_write(cid, vals), st.integers(0, 0xFFFFFFFF),
              st.lists(st.floats(width=32), min_size=12, max_size=12)),
    st.builds(lambda op, rest: bytes([op]) + rest, st.integers(1, 8), st.binary(max_size=8)),
))
def test_random_commands(lib, data):
    _check_command(lib, data)


@given(st.integers(0, 0xFFFFFFFF), st.lists(st.floats(-1e6, 1e6, width=32), min_size=12, max_size=12),
       st.booleans())
def test_calibration_payload_and_slot_are_bit_exact(lib, cid, values, held):
    cal = Calibration(cid, (ctypes.c_float * 9)(*values[:9]), (ctypes.c_float * 3)(*values[9:]))
    py = HeldCalibration(cid, tuple(values[:9]), (values[9], values[10], values[11]))
    out = _buf(56)
    lib.gc_encode_calibration(out, ctypes.byref(cal))
    assert out.raw == py.payload()
    slot = _buf(58)
    lib.gc_encode_slot(slot, ctypes.byref(cal) if held else None)
    assert slot.raw == wp.encode_slot(py if held else None)


@given(st.one_of(st.none(), st.integers(0, 0xFFFFFFFF)), st.integers(0, 0xFFFFFFFF),
       st.one_of(st.none(), st.integers(-32768, 32767)))
def test_power_up_is_bit_exact(lib, boot_count, uptime_s, centi):
    out = _buf(wp.POWER_UP_SIZE)
    lib.gc_encode_power_up(out, ctypes.c_bool(boot_count is not None), ctypes.c_uint32(boot_count or 0),
                           ctypes.c_uint32(uptime_s), ctypes.c_bool(centi is not None), ctypes.c_int16(centi or 0))
    py = wp.PowerUp(boot_count, uptime_s, None if centi is None else centi / 100)
    assert out.raw == py.encode()
    assert wp.PowerUp.decode(out.raw) == py


def test_applying_a_calibration(lib):
    held = HeldCalibration.from_parameters(3, [[1.01, 0.002, -0.003], [0, 0.98, 0.001], [0, 0, 1.03]], [0.5, -0.25, 0.125])
    cal = Calibration(3, (ctypes.c_float * 9)(*held.K), (ctypes.c_float * 3)(*held.b))
    m = (ctypes.c_float * 3)(100.0, -50.0, 25.0)
    g = (ctypes.c_float * 3)()
    lib.gc_apply_calibration(ctypes.byref(cal), m, g)
    assert list(g) == pytest.approx(held.apply((100.0, -50.0, 25.0)), rel=1e-6)


# -- the host program: a firmware's loop, decoded and calibrated by the service ----------------------------
def _frames(out: bytes) -> list[tuple[str, bytes]]:
    frames, i = [], 0
    while i < len(out):
        kind, size = chr(out[i]), int.from_bytes(out[i + 1:i + 3], "little")
        frames.append((kind, out[i + 3:i + 3 + size]))
        i += 3 + size
    assert i == len(out)
    return frames


def _run_host(host: Path, samples: bytes, *writes: bytes, options: tuple[str, ...] = ()) -> list[tuple[str, bytes]]:
    done = subprocess.run([str(host), *options, *(w.hex() for w in writes)], input=samples, capture_output=True,
                          check=False, timeout=60)
    assert done.returncode == 0, done.stderr.decode()
    return _frames(done.stdout)


def _samples(seed: int, t0_us: int) -> tuple[bytes, object, int]:
    rec, truth = simulate(seed, noise=0.03, fs=104.0)
    counts, _ = wp.quantize(rec.gyro, rec.accel, 65.5, 8192.0)
    t_us = (t0_us + np.rint(rec.t * 1e6).astype(np.int64)) % (1 << 32)
    records = np.zeros(len(counts), dtype=[("t", "<u4"), ("v", "<i2", (6,))])
    records["t"], records["v"] = t_us, counts
    return records.tobytes(), truth, len(counts)


@pytest.mark.parametrize("loss", [None, (1200, 1300)])
def test_the_firmware_loop_is_decoded_and_calibrated_end_to_end(host, loss):
    samples, truth, n = _samples(seed=8, t0_us=(1 << 32) - 20_000_000)  # the device clock wraps 20 s in
    held = HeldCalibration.from_parameters(17, [1.01, 0.99, 1.02], [0.2, -0.1, 0.05])
    damaged = bytearray(Command(Opcode.WRITE_CALIBRATION, held.payload()).encode())
    damaged[20] ^= 0x01
    writes = (Command(Opcode.SET_RATE, 104.0).encode(), Command(Opcode.SET_GYRO_RANGE, 500).encode(),
              Command(Opcode.WRITE_CALIBRATION, held.payload()).encode(), bytes(damaged), Command(Opcode.START).encode(),
              Command(Opcode.SET_RATE, 208.0).encode())
    options = ("--link-loss", f"{loss[0]}:{loss[1]}") if loss else ()
    frames = _run_host(host, samples, *writes, options=options)
    statuses = [wp.StatusReply.decode(v) for k, v in frames if k == "S"]
    assert [s.status for s in statuses] == [Status.OK, Status.OK, Status.OK, Status.CHECKSUM, Status.OK, Status.BUSY,
                                            Status.OK]
    assert statuses[-1].opcode == Opcode.STREAM_END
    assert wp.decode_slot(next(v for k, v in frames if k == "H")) == held  # the damaged write changed nothing

    cfg = DeviceConfig.decode(next(v for k, v in frames if k == "C"))
    assert (cfg.sample_rate_hz, cfg.samples_per_packet, cfg.gyro_lsb_per_dps) == (104.0, 3, 65.5)
    stats = LinkStats()
    decoder = StreamDecoder(cfg, stats)
    decoder.begin(new_session=True)
    rb = RecordingBuilder(DeviceInfo("host", "gyrocal_host", cfg, "gyrocal", "host", None, "1.0", None, "gyrocal"))
    for kind, value in frames:
        if kind == "P":
            batch = decoder.feed(value)
            assert batch is not None
            rb.add(batch)
    assert stats.malformed_packets == 0 and stats.duplicate_packets == 0
    sent = n - n % 3
    if loss is None:
        assert stats.samples == sent and stats.lost_samples == 0
    else:  # every sample of a packet completed while nobody listened is counted lost, exactly
        lost = 3 * sum(loss[0] <= 3 * j + 2 < loss[1] for j in range(n // 3))  # packets completed in the window
        assert stats.lost_samples == lost == 99 and stats.samples == sent - lost
    rec = rb.recording()
    assert rec.fs == pytest.approx(104.0, rel=1e-4)
    assert np.array_equal(np.diff(rec.seq)[np.diff(rec.seq) != 1], [] if loss is None else [100])
    if loss is None:  # a second lost mid-turn spoils that turn's angle: the service has the clinician redo it
        _assert_matches_truth(_calibrate(rec), {"k": truth.k, "b": truth.b})  # type: ignore[attr-defined]


def test_the_streaming_loop_is_bit_exact_with_the_protocol(host):
    rng = np.random.default_rng(4)
    n = 301
    counts = rng.integers(-32768, 32768, size=(n, 6)).astype("<i2")
    counts[:, :3] = np.clip(counts[:, :3], -32767, 32766)
    counts[[10, 11, 200], [0, 2, 1]] = [32767, -32768, 32767]  # saturated gyro values flag their packets
    t_us = ((1 << 32) - 1_000_000 + np.cumsum(rng.integers(9000, 10500, n))) % (1 << 32)
    records = np.zeros(n, dtype=[("t", "<u4"), ("v", "<i2", (6,))])
    records["t"], records["v"] = t_us, counts
    frames = _run_host(host, records.tobytes(), Command(Opcode.SET_RATE, 208.0).encode(), Command(Opcode.START).encode())
    cfg = DeviceConfig.decode(next(v for k, v in frames if k == "C"))
    assert (cfg.sample_rate_hz, cfg.samples_per_packet, cfg.config_id) == (208.0, 6, 2)
    packets = [v for k, v in frames if k == "P"]
    _, clipped = wp.quantize(counts[:, :3] / 65.5, counts[:, 3:] / 8192.0, 65.5, 8192.0)
    expected = [wp.encode_packet(j, int(t_us[6 * j]), counts[6 * j:6 * j + 6],
                                 (wp.PacketFlags.SESSION_START if j == 0 else 0)
                                 | (wp.PacketFlags.GYRO_CLIPPED if clipped[6 * j:6 * j + 6].any() else 0), cfg.config_id)
                for j in range(n // 6)]
    assert packets == expected and sum(bool(p[1] & wp.PacketFlags.GYRO_CLIPPED) for p in packets) == 2
