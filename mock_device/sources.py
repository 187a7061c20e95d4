"""Where the simulated wearable's samples come from: the scripted clinician or a recorded CSV."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from calib.simulator import SensorParams, simulate

from .scenarios import LinkFaults, Scenario, get_scenario

TAIL_BLOCK = 4096  # samples per block of rest generated after the script ends


@dataclass(frozen=True)
class Block:
    """Raw readings for a run of samples: gyro m in deg/s (n, 3), accelerometer in g (n, 3)."""

    gyro: np.ndarray
    accel: np.ndarray


class SampleSource(Protocol):
    """Readings for sample indices of a streaming session."""

    fixed_rate_hz: float | None  # a replay has the rate of its file; None: any supported rate
    length: int | None  # samples available (None: endless)

    def prepare(self, fs_hz: float) -> None:
        """(Re)generate for a session sampled at ``fs_hz`` (the true output data rate)."""

    def block(self, start: int, end: int) -> Block:
        """Readings of samples start..end-1."""

    def times_s(self, start: int, end: int) -> np.ndarray | None:
        """Sample times (s from the first sample) if the source has its own, else None (i / fs)."""


class ScriptedSource:
    """Calib's simulator driven by a scenario's clinician script; rest continues after the script."""

    fixed_rate_hz = None
    length = None

    def __init__(self, seed: int = 0, scenario: str | Scenario = "normal", noise_dps: float = 0.03) -> None:
        self.seed = int(seed)
        self.scenario = get_scenario(scenario) if isinstance(scenario, str) else scenario
        self.noise_dps = float(noise_dps)
        ss_params, ss_script = np.random.SeedSequence([self.seed, 0x5EED]).spawn(2)
        self.params = SensorParams.paper_random(np.random.default_rng(ss_params))
        self.script = self.scenario.script(np.random.default_rng(ss_script))
        self.faults: LinkFaults = self.scenario.link_faults(self.script)
        self._fs: float | None = None
        self._gyro = np.zeros((0, 3))
        self._accel = np.zeros((0, 3))
        self._tail: dict[int, Block] = {}
        self.truth: dict[str, object] = {"k": self.params.k.tolist(), "b": self.params.b.tolist()}

    def prepare(self, fs_hz: float) -> None:
        if self._fs == fs_hz:
            return
        rec, truth = simulate(self.seed, noise=self.noise_dps, fs=fs_hz, params=self.params, script=self.script)
        self._fs = fs_hz
        self._gyro, self._accel = rec.gyro, rec.accel
        self._rest_accel = rec.accel[-max(1, int(fs_hz * 0.5)):].mean(axis=0)
        self._tail.clear()
        self.truth = {"k": truth.k.tolist(), "b": truth.b.tolist()}

    @property
    def script_samples(self) -> int:
        return int(self._gyro.shape[0])

    def _tail_block(self, index: int) -> Block:
        if index not in self._tail:
            rng = np.random.default_rng([self.seed, 0x7A11, index])
            rest = self.params.reading(np.zeros((TAIL_BLOCK, 3)))
            gyro = rest + self.noise_dps * rng.standard_normal((TAIL_BLOCK, 3))
            accel = self._rest_accel + 0.002 * rng.standard_normal((TAIL_BLOCK, 3))
            if len(self._tail) > 8:
                self._tail.clear()
            self._tail[index] = Block(gyro, accel)
        return self._tail[index]

    def block(self, start: int, end: int) -> Block:
        n = self.script_samples
        if end <= n:
            return Block(self._gyro[start:end], self._accel[start:end])
        parts_g, parts_a = [], []
        if start < n:
            parts_g.append(self._gyro[start:n])
            parts_a.append(self._accel[start:n])
        i = max(start, n)
        while i < end:
            b, off = divmod(i - n, TAIL_BLOCK)
            take = min(end - i, TAIL_BLOCK - off)
            tb = self._tail_block(b)
            parts_g.append(tb.gyro[off:off + take])
            parts_a.append(tb.accel[off:off + take])
            i += take
        return Block(np.concatenate(parts_g), np.concatenate(parts_a))

    def times_s(self, start: int, end: int) -> np.ndarray | None:
        return None


class ReplaySource:
    """A recorded CSV replayed at its own rate; the stream ends with the file."""

    def __init__(self, path: str | Path, fs: float | None = None) -> None:
        from calib.io import read_recording  # calib's reader: native CSV or the imucal layout

        rec = read_recording(path, fs=fs)
        self.path = Path(path)
        self.fixed_rate_hz = float(rec.fs)
        self.length = len(rec)
        self._gyro = rec.gyro
        self._accel = rec.accel if rec.accel is not None else np.zeros_like(rec.gyro)
        self._t = rec.t - rec.t[0]
        self.truth = None
        self.faults = LinkFaults()

    def prepare(self, fs_hz: float) -> None:
        return None

    def block(self, start: int, end: int) -> Block:
        return Block(self._gyro[start:end], self._accel[start:end])

    def times_s(self, start: int, end: int) -> np.ndarray | None:
        return self._t[start:end]
