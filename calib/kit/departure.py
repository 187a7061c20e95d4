"""A wearable that departs from its kit: one that moved in its slot, read a wrong range, or lost an axis.

Two signs, either enough: its attitude came apart from the others' at the rests, or its rate came apart from theirs
in a burst (a slip about the axis being turned, during that turn, leaves no angle its own k does not absorb, but
its rate jumps against the others' while it slips).

Rigidly held, every wearable's calibrated rates, turned into the reference's frame, follow one rotation: the attitude
each integrates stays the same as the others', up to the noise's random walk. A wearable that slipped by an angle
ends every later rest turned by that angle against the rest of the kit. ``departures`` measures, for each wearable,
how far its attitude came apart from the others' at the rests, against what the noise allows, and when.

A slip while the tray rests shows less at the rests than it turned: its rate in that rest is read as part of its bias,
whose error then carries it back over the rest of the motion. So a wearable whose rate came apart in a burst while the
tray rested is also measured across the burst alone (its attitude just before against just after, ``step_deg``): how
far it turned in its slot, and when. (Across a burst in a turn, the attitudes of a still uncalibrated wearable and the
kit's drift apart too fast for that; and at the rests, the part of a slip in a turn about the axis being turned is
absorbed by its own k: how far such a slip turned is not known, only that it came apart.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from calib.distributions import chi2_sf
from calib.numerics.attitude import cumulative_attitude
from calib.quality import KitDeparture

DEPARTURE_DEG = 0.2  # a wearable whose attitude comes this far apart from the kit's, beyond the noise, departed
DEPARTURE_ALPHA = 1e-3  # ... and whose angle has under this chance from noise and calibration error alone
MODEL_FLOOR_DEG = 0.02  # what a rigid tray's coupling leaves unexplained beyond the noise (per rest), deg
BURST_WINDOW_S = 0.25  # a wearable moving in its slot shows as a burst of rate against the others' over this long
BURST_DPS = 1.0  # ... departed when its rms is over this (deg/s) and ``BURST_NOISE`` times what the noise gives
BURST_NOISE = 25.0
TRAY_STILL_DPS = 5.0  # the tray rests while the others' rates stay under this (deg/s)


@dataclass(frozen=True)
class Departure:
    """How far a wearable's attitude came apart from the rest of the kit's (deg), its 1-sigma under the noise, the
    chance of an angle this large from noise alone, when it was half-way there (reference clock, s), and the verdict."""

    angle_deg: float
    std_deg: float
    p_value: float
    at_s: float | None
    departed: bool
    burst_dps: float = float("nan")  # the largest rms rate against the others' over BURST_WINDOW_S, deg/s
    step_deg: float = float("nan")  # how far it turned in its slot across that burst, the tray resting (else nan), deg

    def to_dict(self) -> KitDeparture:
        return KitDeparture(angle_deg=self.angle_deg, std_deg=self.std_deg, p_value=self.p_value, at_s=self.at_s,
                            departed=self.departed, burst_dps=self.burst_dps, step_deg=self.step_deg)


NO_DEPARTURE = Departure(float("nan"), float("nan"), float("nan"), None, False)  # one wearable left: nothing to depart from


def departures(rates: np.ndarray, t: np.ndarray, rests: list[tuple[int, int]], noise_dps: np.ndarray) -> list[Departure]:
    """For each wearable, its departure from the mean of the others.

    ``rates`` (N, n, 3): every wearable's calibrated rates in the reference's frame on the reference's clock (deg/s);
    ``t`` (n,) those sample times (s); ``rests`` the kit's rests as sample ranges [start, end); ``noise_dps`` (N, 3)
    each wearable's rate noise in that frame (deg/s)."""
    n_dev = rates.shape[0]
    dt = float(np.median(np.diff(t)))
    out = []
    for i in range(n_dev):
        others = np.delete(np.arange(n_dev), i)
        mean_others = rates[others].mean(axis=0)
        diff_var = noise_dps[i] ** 2 + (noise_dps[others] ** 2).sum(axis=0) / len(others) ** 2
        out.append(_departure(rates[i], mean_others, t, dt, rests, diff_var))
    return out


def _departure(own: np.ndarray, others: np.ndarray, t: np.ndarray, dt: float, rests: list[tuple[int, int]],
               diff_var: np.ndarray) -> Departure:
    apart = cumulative_attitude(others, dt).inv() * cumulative_attitude(own, dt)  # own attitude seen from the others'
    at_rest = [Rotation.from_rotvec(apart[a:b].as_rotvec().mean(axis=0)) for a, b in rests if b > a]
    if len(at_rest) < 2:
        return NO_DEPARTURE
    first = at_rest[0]
    moved = np.array([(first.inv() * r).as_rotvec() for r in at_rest[1:]])
    angles = np.degrees(np.linalg.norm(moved, axis=1))
    worst = int(np.argmax(angles))
    elapsed = t[rests[worst + 1][0]] - t[rests[0][1] - 1]
    std = float(np.sqrt(np.mean(diff_var) * elapsed * dt + MODEL_FLOOR_DEG**2))
    angle = float(angles[worst])
    p = float(chi2_sf((angle / std) ** 2, 3))
    at_s = None
    if angle >= DEPARTURE_DEG:
        along = np.degrees(np.linalg.norm((first.inv() * apart).as_rotvec(), axis=1))
        crossed = np.nonzero(along[rests[0][1]:] > 0.5 * angle)[0]
        at_s = float(t[rests[0][1] + crossed[0]]) if crossed.size else None
    width = max(3, int(round(BURST_WINDOW_S / dt)))
    power = np.convolve(np.sum((own - others) ** 2, axis=1), np.ones(width) / width, mode="same")
    peak = int(np.argmax(power))
    burst = float(np.sqrt(power[peak]))
    burst_out = burst > max(BURST_DPS, BURST_NOISE * float(np.sqrt(np.sum(diff_var))))
    step = _step(apart, others, peak, width) if burst_out else float("nan")
    if burst_out and (at_s is None or np.isfinite(step)):  # a step while the tray rested is the moment it slipped
        at_s = float(t[peak])
    return Departure(angle, std, p, at_s, bool((angle >= DEPARTURE_DEG and p < DEPARTURE_ALPHA) or burst_out), burst,
                     step)


def _step(apart: Rotation, others: np.ndarray, peak: int, width: int) -> float:
    """How far ``apart`` turned across the burst centred on sample ``peak`` (``width`` samples wide), deg: its mean
    over ``width`` samples just before the burst against its mean just after; nan unless the tray (``others``' rate)
    rested throughout, or at an end of the recording."""
    before, after = (peak - 2 * width, peak - width), (peak + width, peak + 2 * width)
    if before[0] < 0 or after[1] > len(apart):
        return float("nan")
    if np.linalg.norm(others[before[0]:after[1]], axis=1).max() > TRAY_STILL_DPS:
        return float("nan")
    mean = [Rotation.from_rotvec(apart[a:b].as_rotvec().mean(axis=0)) for a, b in (before, after)]
    return float(np.degrees(np.linalg.norm((mean[0].inv() * mean[1]).as_rotvec())))
