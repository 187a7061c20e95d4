"""The wearable models gyrocal speaks: what each one's protocol offers and what it cannot tell.

One :class:`DeviceModel` per protocol: how a scan recognises it (advertised service, name), the rates and
ranges it offers, the settings gyrocal streams with (the highest rate it streams reliably, the smallest
gyro range a brisk hand turn does not clip), where sample times come from and whether lost samples can
be detected. The client's adapters (``server.link.adapters``) and the simulated devices
(``mock_device.vendors``) both read these facts from here, and the page shows them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from .sensor import ACCEL_SENSITIVITY_LSB_PER_G, GYRO_SENSITIVITY_LSB_PER_DPS, SUPPORTED_RATES_HZ
from .uuids import IMU_SERVICE
from .vendors import metawear, movella_dot, polar_pmd, thingy52

# Simulated brisk hand turns peak at 150-330 deg/s (docs/protocol.md): the smallest full scale at or above
# this leaves a third of headroom. Finer ranges clip a fast turn; coarser ones only cost resolution.
HAND_TURN_RANGE_DPS = 450
HAND_MOTION_RANGE_G = 4

def _smallest_at_least(offered: tuple[int, ...] | list[int], floor: int) -> int:
    return min((r for r in offered if r >= floor), default=max(offered))


def hand_turn_range(offered: tuple[int, ...] | list[int]) -> int:
    """The smallest offered gyro range (deg/s) that a brisk hand turn does not clip, else the widest."""
    return _smallest_at_least(offered, HAND_TURN_RANGE_DPS)


def hand_motion_accel_range(offered: tuple[int, ...] | list[int]) -> int:
    """The smallest offered accelerometer range (g) of 4 g or more, else the widest: rests read 1 g and hand
    turns little more."""
    return _smallest_at_least(offered, HAND_MOTION_RANGE_G)


TimeStamps = Literal["device", "arrival"]
LossDetection = Literal["counter", "time_stamps", "none"]


CANNOT_HOLD = "cannot hold a calibration: apply it to its recordings instead"
CANNOT_IDENTIFY = "has no command to blink or buzz: tell it from the others by its name or serial number"
IDENTIFY_DEFAULT_S = 5  # how long a wearable blinks when asked which one it is


@dataclass(frozen=True)
class DeviceModel:
    """One wearable protocol as gyrocal uses it."""

    key: str  # "gyrocal", "polar-pmd", "metawear", "thingy52", "movella-dot": the CLI's --model and the API's "model"
    label: str
    service: str  # the primary service that carries the IMU data
    advertised: tuple[str, ...]  # service UUIDs in its advertisement
    name_prefix: str | None  # local-name prefix that identifies it when it advertises no known service
    rates_hz: tuple[float, ...]
    stream_rate_hz: float  # the rate gyrocal asks for
    gyro_ranges_dps: tuple[int, ...]
    accel_ranges_g: tuple[int, ...]
    accel_rate_hz: float | None  # None: the accelerometer runs at the gyro's rate
    time_stamps: TimeStamps  # "device": from the device's clock; "arrival": the central's arrival times
    loss_detection: LossDetection
    write_back: bool  # can hold a calibration written to it
    whole_rates_hz: tuple[int, int] | None = None  # offers every whole rate in this range (rates_hz: typical ones)
    identify: str | None = None  # what the device does when asked which one it is ("blinks its LED"); None: no command
    other_names: tuple[str, ...] = ()  # further local-name prefixes it advertises under (an earlier firmware's)
    identify_s: int | None = None  # how long it blinks whatever it is asked (its own pattern); None: as long as asked

    def offers_rate(self, rate_hz: float) -> bool:
        """Whether the device offers this output data rate."""
        if self.whole_rates_hz is not None:
            return rate_hz == int(rate_hz) and self.whole_rates_hz[0] <= rate_hz <= self.whole_rates_hz[1]
        return any(abs(rate_hz - r) < 1e-6 for r in self.rates_hz)

    def rates_text(self) -> str:
        """The offered rates, for messages."""
        if self.whole_rates_hz is not None:
            return f"a whole number of Hz from {self.whole_rates_hz[0]} to {self.whole_rates_hz[1]}"
        return "one of " + ", ".join(f"{r:g}" for r in self.rates_hz) + " Hz"

    @property
    def gyro_range_dps(self) -> int:
        """The gyro range gyrocal asks for (see :func:`hand_turn_range`)."""
        return hand_turn_range(self.gyro_ranges_dps)

    @property
    def accel_range_g(self) -> int:
        """The accelerometer range gyrocal asks for (see :func:`hand_motion_accel_range`)."""
        return hand_motion_accel_range(self.accel_ranges_g)

    def limitations(self) -> tuple[str, ...]:
        """What this protocol cannot tell, in the words the page shows."""
        out = []
        if self.loss_detection == "none":
            out.append("This device sends no sample counter or time stamp: lost samples cannot be detected.")
        elif self.loss_detection == "time_stamps":
            out.append("This device sends no sample counter: lost samples are found from gaps in its time stamps.")
        if self.time_stamps == "arrival":
            out.append("Sample times are the times the samples arrived, not the device's clock.")
        if not self.write_back:
            out.append(f"This device {CANNOT_HOLD}.")
        if self.identify is None:
            out.append(f"This device {CANNOT_IDENTIFY}.")
        return tuple(out)

    def to_dict(self) -> dict[str, Any]:
        return {
            "model": self.key, "label": self.label, "rates_hz": list(self.rates_hz), "stream_rate_hz": self.stream_rate_hz,
            "gyro_ranges_dps": list(self.gyro_ranges_dps), "gyro_range_dps": self.gyro_range_dps,
            "accel_ranges_g": list(self.accel_ranges_g), "time_stamps": self.time_stamps,
            "loss_detection": self.loss_detection, "write_back": self.write_back, "identify": self.identify,
            "limitations": list(self.limitations()),
        }


GYROCAL = DeviceModel(
    "gyrocal", "gyrocal protocol wearable", IMU_SERVICE, (IMU_SERVICE,), None, SUPPORTED_RATES_HZ, 104.0,
    tuple(GYRO_SENSITIVITY_LSB_PER_DPS), tuple(ACCEL_SENSITIVITY_LSB_PER_G), None, "device", "counter", True,
    identify="blinks its light",
)
# Polar Verity Sense: gyroscope 52/104/208/416 Hz, +-250..2000 deg/s; accelerometer 52 Hz, +-8 g (Polar BLE SDK,
# documentation/products/PolarVeritySense.md). Frames carry the device's time stamps, no counter. Its measurement
# protocol (PMD) has no command to blink or buzz: it cannot be asked which one it is.
POLAR_PMD = DeviceModel(
    "polar-pmd", "Polar Verity Sense / OH1 (PMD)", polar_pmd.PMD_SERVICE, (polar_pmd.PMD_SERVICE,), "Polar ",
    (52.0, 104.0, 208.0, 416.0), 208.0, (250, 500, 1000, 2000), (8,), 52.0, "device", "time_stamps", False,
)
# MetaMotion (BMI160): streaming over BLE keeps up with gyroscope and accelerometer at 100 Hz each (MbientLab's
# guidance for streaming two sensors; faster rates are for logging to the device's flash).
METAWEAR = DeviceModel(
    "metawear", "MbientLab MetaMotion (MetaWear)", metawear.METAWEAR_SERVICE, (metawear.METAWEAR_SERVICE,), "MetaWear",
    tuple(metawear.GYRO_ODR), 100.0, tuple(sorted(metawear.GYRO_RANGES)), tuple(metawear.ACC_RANGES), None,
    "arrival", "none", False, identify="blinks its LED green",
)
# Thingy:52: motion processing 1-200 Hz, one notification per sample; gyroscope fixed at +-2000 deg/s and the
# accelerometer at +-2 g (the InvenSense motion driver's defaults, which the firmware keeps).
THINGY52 = DeviceModel(
    "thingy52", "Nordic Thingy:52 (Motion service)", thingy52.MOTION_SERVICE, (thingy52.CONFIGURATION_SERVICE,), "Thingy",
    (25.0, 50.0, 100.0, 200.0), 100.0, (thingy52.GYRO_FULL_SCALE_DPS,), (2,), None, "arrival", "none", False,
    (thingy52.MOTION_FREQ_MIN_HZ, thingy52.MOTION_FREQ_MAX_HZ), identify="breathes its LED green",
)

# Movella DOT (XD0506P): real-time streaming at 1-60 Hz, one sample per notification stamped by the sensor's clock
# in microseconds, no counter; the gyroscope at +-2000 deg/s and the accelerometer at +-16 g, not settable over BLE.
# It advertises its name ("Movella DOT"; "Xsens DOT" before firmware 2.x), not its services.
MOVELLA_DOT = DeviceModel(
    "movella-dot", "Movella DOT (Xsens DOT)", movella_dot.MEASUREMENT_SERVICE, (), movella_dot.NAME,
    tuple(float(r) for r in movella_dot.STREAMING_RATES_HZ), 60.0, (movella_dot.GYRO_FULL_SCALE_DPS,),
    (movella_dot.ACCEL_RANGE_G,), None, "device", "time_stamps", False, identify="blinks its LED red",
    other_names=(movella_dot.OLD_NAME,), identify_s=movella_dot.IDENTIFY_S,
)

MODELS: dict[str, DeviceModel] = {m.key: m for m in (GYROCAL, POLAR_PMD, METAWEAR, THINGY52, MOVELLA_DOT)}


def model(key: str) -> DeviceModel:
    """The model called ``key``; ValueError naming the known ones otherwise."""
    try:
        return MODELS[key]
    except KeyError:
        raise ValueError(f"unknown wearable model {key!r}: choose one of {', '.join(MODELS)}") from None


def identify(name: str | None, service_uuids: list[str] | tuple[str, ...]) -> DeviceModel | None:
    """The model an advertisement belongs to (by advertised service, then by name), or None."""
    uuids = {u.lower() for u in service_uuids}
    for m in MODELS.values():
        if uuids & set(m.advertised):
            return m
    for m in MODELS.values():
        if name and any(name.startswith(p) for p in (m.name_prefix, *m.other_names) if p):
            return m
    return None
