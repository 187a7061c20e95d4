"""The protocol simulator: the hand's script (protocol), the device's attitude along it (trajectory), the sensor's
readings with its errors and effects (simulate), and many runs at once (batch)."""

from .batch import SimBatch, simulate_batch
from .protocol import (
    EXTENDED_FAST_S,
    EXTENDED_SLOW_S,
    Motion,
    ProtocolScript,
    Segment,
    Still,
    Turn,
    extended_protocol_script,
    paper_protocol_script,
    script_duration_s,
)
from .ranges import ACCEL_NOISE_G, B_RANGE_DPS, GRAVITY_UP, K_RANGE, STILL_S, TILT_RANGE, TURN_DURATION_S, WOBBLE_DEG
from .simulate import SensorParams, Truth, simulate
from .trajectory import build_trajectory, tilted_axis
