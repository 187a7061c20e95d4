"""The simulated wearable's power-up and temperature (docs/protocol.md, "Power-up and temperature").

It counts its power-ups as a wearable with non-volatile memory does, and its IMU warms after power-up
(T = T0 + rise (1 - exp(-t / tau)), calib's warm-up model): a session late in a power-up runs warmer
than one just after it.
"""

from __future__ import annotations

from dataclasses import dataclass

import wearable_protocol as wp
from calib.effects import warmup_temperature

WARM_RISE_C = 4.0  # self-heating of a small wearable's board after power-up
WARM_TAU_S = 600.0


@dataclass
class PowerUpState:
    """Boot count (None: the device keeps none) and the IMU's temperature at power-up (None: no sensor)."""

    boot_count: int | None = 1
    temperature0_c: float | None = 24.0

    def temperature_c(self, uptime_s: float) -> float | None:
        if self.temperature0_c is None:
            return None
        return float(warmup_temperature(uptime_s, self.temperature0_c, WARM_RISE_C, WARM_TAU_S))

    def value(self, uptime_s: float) -> bytes:
        """The power-up characteristic's value at ``uptime_s`` seconds after power-up."""
        temp = self.temperature_c(uptime_s)
        return wp.PowerUp(self.boot_count, int(uptime_s), None if temp is None else round(temp, 2)).encode()

    def rebooted(self) -> None:
        if self.boot_count is not None:
            self.boot_count = (self.boot_count + 1) & wp.power_up.UINT32_MAX
