"""What a simulated wearable did, counted for tests and the CLI."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class DeviceStats:
    """What the device did, for tests and the CLI: packets per fate and link events."""

    sessions: int = 0
    packets_sent: int = 0
    packets_lost_radio: int = 0  # dropped by the packet-loss fault
    packets_lost_link: int = 0  # produced while no central was receiving
    packets_corrupted: int = 0
    packets_injected: int = 0
    link_drops: int = 0
    identified: int = 0  # IDENTIFY commands obeyed (the LED blinked)
    connects: int = 0
    lost_radio_seqs: list[int] = field(default_factory=list)  # session packet indices of the current session
