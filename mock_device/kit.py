"""Simulated wearables riding in one tray (`gyrocal serve --mock N --mock-kit`): one clinician turns the tray through
the protocol, and every wearable in it records that one motion with its own mounting, sensor errors and clock.

Each streaming session of a wearable is one performance of the tray: the wearables whose streams start within
``JOIN_S`` of the first play the same performance, each from the moment its own stream starts (the estimator aligns
their clocks from the motion, as it does for wearables that start recording at different moments). The clinician is
scripted: the paper's protocol with rests long enough for the service's prompts (``KIT_REST_S``); it does not redo a
step after a link loss. The tray's faults (``calib.simulator.kit.TrayFaults``): its ``loose`` wearable slips
``SLIP_DEG`` in its slot during the second turn of every performance (with ``loose_in`` "pause": in the pause after
it); its ``drop`` wearable goes out of range for ``DROP_S`` in the middle of the first turn; its ``out`` wearable lies
on the table beside the tray, switched on: it rests through every performance.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from calib.simulator import SensorParams
from calib.simulator.kit import KitTray, Slip, TrayFaults, misaligned
from calib.simulator.protocol import paper_protocol_script

from .scenarios import LinkFaults
from .sources import Block

FLAT = np.array([0.0, 0.0, 1.0])  # the accelerometer of a wearable lying flat, g
KIT_REST_S = 5.0  # the tray's rests: the first rest and the pauses between turns, s
SLIP_DEG = 2.0  # how far a loose wearable slips, deg
PERFORMANCES_KEPT = 4
DROP_S = 1.5  # how long the dropping wearable is out of range, s
JOIN_S = 3.0  # streams starting this close (wall time, s) to a performance's first join it


def loose_slip(faults: TrayFaults) -> Slip | None:
    """How the tray's loose wearable (None: none is) slips in its slot: ``SLIP_DEG`` in the tray's second turn, or with
    ``loose_in`` "pause" early in the pause after it (the tray resting still)."""
    return None if faults.loose is None else Slip(faults.loose, SLIP_DEG, 1, in_pause=faults.loose_in == "pause")


class Joins:
    """Which performance a stream starting now plays: the current one when it began under ``JOIN_S`` ago, else the
    next (numbered from 1)."""

    def __init__(self) -> None:
        self.number = 0
        self._started: float | None = None

    def now(self) -> tuple[int, bool]:
        """(the performance's number, whether it is a new one)."""
        now = time.monotonic()
        if self._started is None or now - self._started > JOIN_S:
            self._started = now
            self.number += 1
            return self.number, True
        return self.number, False


def tray_sensors(seed: int, n: int, misalignment: float = 0.0) -> list[SensorParams]:
    """The sensors of a simulated tray's ``n`` wearables: the paper's errors, and with ``misalignment`` axes that are
    not orthogonal (K's entries above the diagonal drawn in +-misalignment, ``calib.simulator.kit.misaligned``)."""
    rng = np.random.default_rng([seed, 0x7A4])
    sensors = [SensorParams.paper_random(rng) for _ in range(n)]
    if misalignment > 0:  # drawn apart: a tray without it keeps its sensors
        tilt = np.random.default_rng([seed, 0x0FF])
        sensors = [replace(s, off_diagonal=misaligned(tilt, misalignment)) for s in sensors]
    return sensors


class Tray:
    """The tray the kit's simulated wearables ride in, and its performances (one per streaming session)."""

    def __init__(self, seed: int, n: int, noise_dps: float = 0.03, faults: TrayFaults | None = None) -> None:
        self.seed, self.n, self.noise_dps = int(seed), int(n), float(noise_dps)
        self.faults = faults or TrayFaults()
        self.slip = loose_slip(self.faults)
        self.params = tray_sensors(self.seed, self.n, self.faults.misalignment)  # the same sensors every performance
        self._performances: dict[int, KitTray] = {}
        self._joins = Joins()

    def performance_now(self) -> KitTray:
        """The performance a stream starting now plays (``Joins``)."""
        return self.performance(self._joins.now()[0])

    def performance(self, number: int) -> KitTray:
        """The tray's ``number``-th performance (from 1): the same for every wearable that asks for it."""
        if number not in self._performances:
            if len(self._performances) >= PERFORMANCES_KEPT:
                self._performances.pop(min(self._performances))
            rng = np.random.default_rng([self.seed, number, 0x5C])
            script = paper_protocol_script(rng, still_s=KIT_REST_S, final_still_s=KIT_REST_S)
            self._performances[number] = KitTray(self.seed * 1000 + number, self.n, noise=self.noise_dps, script=script,
                                                 params=self.params, clock_error=0.0, slip=self.slip,
                                                 out=self.faults.out)
        return self._performances[number]


class KitSource:
    """Wearable ``index`` (0-based) of a ``Tray``: its readings in each performance, then rest."""

    fixed_rate_hz = None
    length = None

    def __init__(self, tray: Tray, index: int) -> None:
        self.tray, self.index = tray, int(index)
        self.session = 0
        self.faults = LinkFaults()
        self._gyro = np.zeros((0, 3))
        self._accel = np.zeros((0, 3))
        self._rest = np.zeros(3)
        self._rest_accel = np.array([0.0, 0.0, 1.0])
        params = tray.params[self.index]
        self.truth: dict[str, object] = {"k": params.k.tolist(), "b": params.b.tolist(), "K": params.K.tolist()}
        self._rng = np.random.default_rng([tray.seed, self.index, 0x7A11])

    def prepare(self, fs_hz: float) -> None:
        self.session += 1
        performance = self.tray.performance_now()
        rec, truth = performance.wearable(self.index, fs_hz)
        if self.tray.faults.drop == self.index:
            first = next(st for st in performance.tray.stages if st.kind == "turn")
            self.faults = LinkFaults(drop_at_s=0.5 * (first.start_s + first.end_s), drop_for_s=DROP_S)
        self._gyro, self._accel = rec.gyro, rec.accel if rec.accel is not None else np.zeros_like(rec.gyro)
        self._rest = self.tray.params[self.index].reading(np.zeros(3))
        self._rest_accel = self._accel[-max(1, int(fs_hz * 0.5)):].mean(axis=0) if len(self._accel) else FLAT
        self.truth = {"k": truth.k.tolist(), "b": truth.b.tolist(), "K": truth.K.tolist(), "slip_deg": truth.slip_deg}

    def resumed(self, lost_at: int, at: int) -> None:
        return None  # the tray's clinician goes on with the protocol; the samples while out of range are lost

    def block(self, start: int, end: int) -> Block:
        return resting_after(self._gyro, self._accel, self._rest, self._rest_accel, self.tray.noise_dps, start, end, self._rng)

    def times_s(self, start: int, end: int) -> np.ndarray | None:
        return None


def resting_after(gyro: np.ndarray, accel: np.ndarray, rest: np.ndarray, rest_accel: np.ndarray, noise_dps: float,
                  start: int, end: int, rng: np.random.Generator) -> Block:
    """Readings start..end-1 of a wearable in the tray: its simulated ``gyro`` and ``accel`` rows, then, past their
    end, the tray at rest (``rest`` and ``rest_accel`` with the reading noise)."""
    n = gyro.shape[0]
    out_gyro, out_accel = gyro[min(start, n):min(end, n)], accel[min(start, n):min(end, n)]
    more = end - max(start, n)
    if more > 0:
        out_gyro = np.concatenate([out_gyro, rest + noise_dps * rng.standard_normal((more, 3))])
        out_accel = np.concatenate([out_accel, rest_accel + 0.002 * rng.standard_normal((more, 3))])
    return Block(out_gyro, out_accel)
