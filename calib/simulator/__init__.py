"""The protocol simulator: the hand's script (protocol), the device's attitude along it (trajectory), the sensor's
readings with its errors and effects (simulate), and many runs at once (batch)."""

from calib.simulator.batch import SimBatch, simulate_batch
from calib.simulator.protocol import (
    EXTENDED_FAST_S,
    EXTENDED_SLOW_S,
    Motion,
    ProtocolScript,
    Segment,
    Still,
    Turn,
    extended_protocol_script,
    extended_script_for_seed,
    paper_protocol_script,
    script_duration_s,
)
from calib.simulator.ranges import ACCEL_NOISE_G, B_RANGE_DPS, GRAVITY_UP, K_RANGE, STILL_S, TILT_RANGE, TURN_DURATION_S, WOBBLE_DEG
from calib.simulator.simulate import SensorParams, Truth, simulate
from calib.simulator.trajectory import build_trajectory, tilted_axis
