"""The simulated wearable: a GATT peripheral that streams protocol packets from a sample source.

It behaves as docs/protocol.md ("Device behaviour") asks of a device: sessions that survive a link loss
(the clinician goes on turning; the source is told when the session resumes so a scripted clinician redoes
the interrupted step), a microsecond clock that starts 2-20 s before its 32-bit wrap (the first session
exercises the central's unwrapping), a true output rate up to +-0.8 % off the nominal one, and its power-up
and temperature (``mock_device.power``). ``speed`` runs the device clock faster than wall time.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable

import numpy as np

import wearable_protocol as wp
from wearable_protocol import (
    Central,
    Command,
    ConnectionDropped,
    DecodeError,
    DeviceConfig,
    DeviceState,
    GattError,
    Opcode,
    PeripheralUnavailable,
    Status,
    StatusReply,
)
from wearable_protocol.models import GYROCAL, DeviceModel

from .device_stats import DeviceStats
from .power import PowerUpState
from .scenarios import LinkFaults
from .sources import SampleSource
from .streaming import CONNECTION_INTERVAL_S, Streaming, WearableSession


def _address(rng: np.random.Generator) -> str:
    b = rng.integers(0, 256, 6)
    b[0] |= 0xC0  # random static address
    return ":".join(f"{int(x):02X}" for x in b)


class Wearable(Streaming):
    """A simulated IMU wearable implementing :class:`wearable_protocol.GattPeripheral`, speaking gyrocal's
    protocol. Vendor devices (``mock_device.vendors``) subclass it: they share its sessions, clock, faults
    and pacing and replace the GATT surface (``services``, ``read``, ``write``, ``set_notify``) and the
    packet encoding (``_send``)."""

    model: DeviceModel = GYROCAL
    data_char: str = wp.IMU_DATA_CHAR  # the characteristic the samples go out on
    gatt_services: tuple[wp.ServiceSpec, ...] = wp.WEARABLE_SERVICES

    def __init__(
        self,
        source: SampleSource,
        *,
        seed: int = 0,
        speed: float = 1.0,
        faults: LinkFaults | None = None,
        name: str | None = None,
        address: str | None = None,
        rate_hz: float | None = None,
        gyro_full_scale_dps: int = wp.DEFAULT_GYRO_FULL_SCALE_DPS,
        accel_range_g: int = wp.DEFAULT_ACCEL_RANGE_G,
        mtu: int = wp.DEFAULT_MTU,
        odr_error: float | None = None,
        clock_start_us: int | None = None,
        session_timeout_s: float = 60.0,
        battery_pct: int | None = None,
        power_up: PowerUpState | None = None,
    ) -> None:
        if not (speed > 0 and math.isfinite(speed)):
            raise ValueError(f"speed must be a positive number (1 = real time), got {speed!r}")
        rng = np.random.default_rng([int(seed), 0xDE71CE])
        self.source = source
        self.seed = int(seed)
        self.speed = float(speed)
        # faults given here hold for every session; otherwise each session has its source's
        self._faults_fixed = faults is not None
        self.faults = faults if faults is not None else getattr(source, "faults", LinkFaults())
        self.address = address or _address(rng)
        self.name = name or self._default_name()
        self.mtu = mtu
        fixed = source.fixed_rate_hz
        self.rate_hz = float(fixed if fixed is not None else (rate_hz or self.model.stream_rate_hz))
        if fixed is None and not self.model.offers_rate(self.rate_hz):
            raise ValueError(f"rate {self.rate_hz:g} Hz is not offered by a {self.model.label}: choose {self.model.rates_text()}")
        self.gyro_full_scale_dps = int(gyro_full_scale_dps)
        self.accel_range_g = int(accel_range_g)
        self.odr_error = float(rng.uniform(-0.008, 0.008) if odr_error is None else odr_error)
        if fixed is not None:
            self.odr_error = 0.0
        self._clock_start_us = int(clock_start_us if clock_start_us is not None
                                   else wp.CLOCK_MODULUS - int(rng.uniform(2e6, 20e6)))
        self._boot_wall = time.monotonic()
        self.session_timeout_s = session_timeout_s
        self.battery_pct = int(battery_pct if battery_pct is not None else rng.integers(60, 100))
        self.serial = f"GC{self.seed:08d}"
        self.config_id = 1
        self.held: wp.HeldCalibration | None = None  # the calibration written to it (lost at power-off)
        self.identify_until = 0.0  # time.monotonic() until which the simulated LED blinks (IDENTIFY)
        self.power = power_up or PowerUpState()
        self.stats = DeviceStats()
        self._central: Central | None = None
        self._notifying: set[str] = set()
        self._session: WearableSession | None = None
        self._task: asyncio.Task[None] | None = None
        self._out_of_range_until = -math.inf
        self._fail_connects = int(self.faults.fail_connects)
        self._corrupt_pending = 0
        # a faulty firmware, for tests: what the wearable sends in place of packet j (none, several, other bytes)
        self.firmware_fault: Callable[[int, bytes], list[bytes]] | None = None
        # a wearable timed by its arrivals is sent packet by packet: its rate is estimated from their lower envelope
        self.connection_interval_s = CONNECTION_INTERVAL_S if self.model.time_stamps == "device" else 0.0
        self._loss_cache: dict[int, np.ndarray] = {}
        self.events: list[tuple[float, str]] = []  # (device time s, what) for logs and tests

    # ------------------------------------------------------------------ clock and configuration

    def _default_name(self) -> str:
        return f"gyrocal-{self.address[-5:].replace(':', '')}"

    def device_time_us(self, wall: float | None = None) -> int:
        """The device clock (unwrapped, microseconds since boot)."""
        wall = time.monotonic() if wall is None else wall
        return self._clock_start_us + int((wall - self._boot_wall) * self.speed * 1e6)

    @property
    def samples_per_packet(self) -> int:
        return wp.samples_per_packet(self.rate_hz, self.mtu)

    @property
    def true_rate_hz(self) -> float:
        return self.rate_hz * (1.0 + self.odr_error)

    @property
    def config(self) -> DeviceConfig:
        state = DeviceState(0)
        if self._session is not None:
            state |= DeviceState.SESSION_ACTIVE
            if self._session.streaming:
                state |= DeviceState.STREAMING
        if self.source.fixed_rate_hz is not None:
            state |= DeviceState.REPLAY
        return DeviceConfig(
            self.config_id, self.rate_hz, self.gyro_full_scale_dps, self.accel_range_g, self.samples_per_packet,
            wp.GYRO_SENSITIVITY_LSB_PER_DPS[self.gyro_full_scale_dps], wp.ACCEL_SENSITIVITY_LSB_PER_G[self.accel_range_g],
            state,
        )

    @property
    def truth(self) -> dict[str, object] | None:
        """The simulated sensor parameters {"k": [...], "b": [...]}, None for a replay."""
        return getattr(self.source, "truth", None)

    # ------------------------------------------------------------------ GattPeripheral

    @property
    def advertising(self) -> bool:
        return self._central is None and time.monotonic() >= self._out_of_range_until

    @property
    def services(self) -> tuple[wp.ServiceSpec, ...]:
        return self.gatt_services

    @property
    def advertised_services(self) -> tuple[str, ...]:
        return self.model.advertised

    def connect(self, central: Central) -> None:
        if self._central is not None:
            raise PeripheralUnavailable(f"{self.name} is already connected to another central")
        if time.monotonic() < self._out_of_range_until:
            raise PeripheralUnavailable(f"{self.name} is out of range")
        if self._fail_connects > 0:
            self._fail_connects -= 1
            self._log("connection dropped during setup")
            raise ConnectionDropped(f"{self.name} dropped the link during connection setup")
        self._central = central
        self._notifying.clear()
        self.stats.connects += 1
        self._log("connected")

    def disconnect(self) -> None:
        if self._central is None:
            return
        self._lose_central()
        self._log("disconnected by the central")

    # Device Information: manufacturer, model number, firmware revision (the serial is the device's own)
    device_information: tuple[bytes, bytes, bytes] = (b"gyrocal", b"GC-1 simulated IMU wearable", b"1.0.0")

    def _readable(self) -> dict[str, Callable[[], bytes]]:
        """The protocol's own readable characteristics (the standard services' are added by ``read``)."""
        return {wp.IMU_CONFIG_CHAR: lambda: self.config.encode(),
                wp.IMU_CALIBRATION_CHAR: lambda: wp.encode_slot(self.held),
                wp.IMU_POWER_UP_CHAR: lambda: self.power.value(self.device_time_us() / 1e6)}

    def read(self, char_uuid: str) -> bytes:
        manufacturer, model_number, firmware = self.device_information
        values = {
            wp.MANUFACTURER_NAME_CHAR: lambda: manufacturer,
            wp.MODEL_NUMBER_CHAR: lambda: model_number,
            wp.SERIAL_NUMBER_CHAR: lambda: self.serial.encode(),
            wp.FIRMWARE_REVISION_CHAR: lambda: firmware,
            wp.BATTERY_LEVEL_CHAR: lambda: bytes([self.battery_pct]),
            **self._readable(),
        }
        if char_uuid not in values:
            raise GattError("not_permitted", "Read not permitted")
        return values[char_uuid]()

    def _set_sensor(self, rate_hz: float | None = None, gyro_full_scale_dps: int | None = None) -> None:
        """A vendor command set the sensor's rate or gyro range: a paused session cannot resume with other
        settings, so a change ends it. A replay keeps its file's rate."""
        new_rate = rate_hz if self.source.fixed_rate_hz is None and rate_hz not in (None, self.rate_hz) else None
        new_range = gyro_full_scale_dps if gyro_full_scale_dps not in (None, self.gyro_full_scale_dps) else None
        if new_rate is not None or new_range is not None:
            self._end_session("settings changed")
        if new_rate is not None:
            self.rate_hz = float(new_rate)
        if new_range is not None:
            self.gyro_full_scale_dps = int(new_range)

    def write(self, char_uuid: str, data: bytes) -> None:
        if char_uuid != wp.IMU_CONTROL_CHAR:
            raise GattError("not_permitted", "Write not permitted")
        try:
            cmd = Command.decode(data)
        except DecodeError as e:
            status = Status.UNKNOWN_OPCODE if e.reason == "opcode" else Status.BAD_LENGTH
            self._reply(data[0] if data else 0, status)
            return
        self._reply(cmd.opcode, self._execute(cmd))

    def set_notify(self, char_uuid: str, enabled: bool) -> None:
        if enabled:
            self._notifying.add(char_uuid)
        else:
            self._notifying.discard(char_uuid)

    # ------------------------------------------------------------------ faults for tests

    def drop_link(self, for_s: float | None = None) -> None:
        """The radio link drops now; the device is out of range for ``for_s`` device seconds."""
        for_s = self.faults.drop_for_s if for_s is None else for_s
        self._out_of_range_until = time.monotonic() + for_s / self.speed
        self.stats.link_drops += 1
        self._log(f"link dropped, out of range for {for_s:g} s")
        if self._central is not None:
            central = self._lose_central()
            central.link_lost()

    def power_cycle(self) -> None:
        """Switched off and on: the link and any session end, the held calibration is lost, the clock restarts
        at 0 and the boot count steps."""
        if self._central is not None:
            self._lose_central().link_lost()
        self._end_session("power cycle")
        self.held = None
        self._clock_start_us, self._boot_wall = 0, time.monotonic()
        self.power.rebooted()

    def corrupt_next_packets(self, count: int) -> None:
        """The next ``count`` data packets go out with a bad version byte (malformed)."""
        self._corrupt_pending += int(count)

    def inject(self, data: bytes) -> bool:
        """Send arbitrary bytes as a data notification now (True if a central received them)."""
        if self._central is None or self.data_char not in self._notifying:
            return False
        self.stats.packets_injected += 1
        self._central.notify(self.data_char, bytes(data))
        return True

    def fail_next_connects(self, count: int) -> None:
        """The next ``count`` connection attempts drop before services are resolved."""
        self._fail_connects += int(count)

    # ------------------------------------------------------------------ commands

    def _execute(self, cmd: Command) -> Status:
        op = cmd.opcode
        if op == Opcode.START:
            self._start()
            return Status.OK
        if op == Opcode.STOP:
            self._end_session("stopped by the central")
            return Status.OK
        if op in (Opcode.WRITE_CALIBRATION, Opcode.CLEAR_CALIBRATION):
            return self._hold(cmd)
        if op == Opcode.IDENTIFY:
            return self._identify(int(cmd.value))
        if self._session is not None and self._session.streaming:
            return Status.BUSY
        if op == Opcode.SET_RATE:
            if self.source.fixed_rate_hz is not None:
                return Status.NOT_SUPPORTED
            if not wp.rate_supported(float(cmd.value)):
                return Status.INVALID_VALUE
            self.rate_hz = next(r for r in wp.SUPPORTED_RATES_HZ if abs(r - float(cmd.value)) < 1e-3)
        elif op == Opcode.SET_GYRO_RANGE:
            if int(cmd.value) not in wp.GYRO_SENSITIVITY_LSB_PER_DPS:
                return Status.INVALID_VALUE
            self.gyro_full_scale_dps = int(cmd.value)
        elif op == Opcode.SET_ACCEL_RANGE:
            if int(cmd.value) not in wp.ACCEL_SENSITIVITY_LSB_PER_G:
                return Status.INVALID_VALUE
            self.accel_range_g = int(cmd.value)
        else:
            return Status.UNKNOWN_OPCODE
        # a new configuration ends a paused session: its samples would not match the new settings
        self._end_session("configuration changed")
        self.config_id = (self.config_id % 255) + 1
        return Status.OK

    def _identify(self, seconds: int) -> Status:
        """Blink (a simulated LED) for ``seconds``; a streaming session goes on."""
        if not 1 <= seconds <= wp.IDENTIFY_MAX_S:
            return Status.INVALID_VALUE
        self.identify_until = time.monotonic() + seconds
        self.stats.identified += 1
        self._log(f"identify: blinking for {seconds} s")
        return Status.OK

    @property
    def identifying(self) -> bool:
        """Whether the simulated LED is blinking now (an IDENTIFY asked for it)."""
        return time.monotonic() < self.identify_until

    def _hold(self, cmd: Command) -> Status:
        """Hold (or forget) a written calibration; the stream stays raw. A corrupt one changes nothing."""
        if cmd.opcode == Opcode.CLEAR_CALIBRATION:
            self.held = None
            return Status.OK
        try:
            self.held = wp.HeldCalibration.from_payload(bytes(cmd.value))  # type: ignore[arg-type]
        except DecodeError as e:
            return Status.CHECKSUM if e.reason == "checksum" else Status.INVALID_VALUE
        self._log(f"holds calibration {self.held.calibration_id}")
        return Status.OK

    def _reply(self, opcode: int, status: Status) -> None:
        if self._central is not None and wp.IMU_CONTROL_CHAR in self._notifying:
            self._central.notify(wp.IMU_CONTROL_CHAR, StatusReply(opcode, status, self.config_id).encode())

    def _start(self) -> None:
        now = time.monotonic()
        s = self._session
        if s is not None and s.disconnected_wall is not None and (now - s.disconnected_wall) * self.speed > self.session_timeout_s:
            self._end_session("session timed out while the link was down")
            s = None
        if s is not None:
            if not s.streaming:
                s.streaming = True
                s.resumed = True
                s.disconnected_wall = None
                self._log("session resumed")
                # the clinician sees the session resume and follows the guidance from here
                self.source.resumed(s.lost_at, s.next_packet * s.n)
            return
        self.source.prepare(self.true_rate_hz)
        if not self._faults_fixed:
            self.faults = getattr(self.source, "faults", self.faults)
        self.stats.sessions += 1
        self.stats.lost_radio_seqs = []
        self._loss_cache.clear()
        s = WearableSession(self.stats.sessions, self.true_rate_hz, self.samples_per_packet, now, self.device_time_us(now),
                     self.config_id)
        self._session = s
        self._log(f"session {s.number} started at {self.rate_hz:g} Hz, N={s.n}")
        self._task = asyncio.get_running_loop().create_task(self._run(s))

    def _end_session(self, why: str) -> None:
        if self._session is None:
            return
        self._session = None
        self._log(f"session ended: {why}")
        if self._task is not None and self._task is not asyncio.current_task():
            self._task.cancel()
        self._task = None

    def _lose_central(self) -> Central:
        central, self._central = self._central, None
        self._notifying.clear()
        if self._session is not None and self._session.streaming:
            self._session.streaming = False
            self._session.disconnected_wall = time.monotonic()
            self._session.lost_at = self._session.next_packet * self._session.n
        assert central is not None
        return central

    def _log(self, what: str) -> None:
        self.events.append(((self.device_time_us() - self._clock_start_us) / 1e6, what))

