"""The verdict on one parameter of the calibration in force: holds (with the margin), moved (by how much +- what,
since when) or cannot tell (and which motion would tell)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from calib.watch.fits import Z_MOVED, Step

# a parameter holds when the recording shows it within this of the calibration (95 % interval inside)
TOLERANCE = {"k": 3e-3, "b": 0.05}
# ... and a change smaller than this is not called a move, however well measured (it is within the calibration's use)
MATTERS = {"k": 1e-3, "b": 0.02}
UNITS = {"k": "", "b": " deg/s"}


@dataclass(frozen=True)
class Since:
    """A move found inside the recording: between ``after_s`` (the last evidence before it) and ``before_s``."""

    after_s: float
    before_s: float


@dataclass(frozen=True)
class ParameterVerdict:
    """``name`` (k_x .. b_z): ``verdict`` holds | moved | cannot tell; ``change`` +- ``std`` the recording's value
    less the calibration's (relative for k, deg/s for b); ``margin`` how far inside the tolerance a holding one is;
    ``since`` where a move was found inside the recording (None: before it began); ``would_tell`` the motion that
    would decide a "cannot tell"; ``evidence`` how many rests or re-orientations spoke to it."""

    name: str
    verdict: str
    change: float | None
    std: float | None
    margin: float | None = None
    since: Since | None = None
    would_tell: str | None = None
    evidence: int = 0

    def to_json(self) -> dict[str, Any]:
        std = self.std if self.std is None or math.isfinite(self.std) else None  # not determined: no std to give
        return {"name": self.name, "verdict": self.verdict, "change": self.change if std is not None else None, "std": std,
                "margin": self.margin,
                "since": None if self.since is None else {"after_s": self.since.after_s, "before_s": self.since.before_s},
                "would_tell": self.would_tell, "evidence": self.evidence}

    def sentence(self) -> str:
        """The verdict in words, e.g. "k_x holds: 0.02 % +- 0.05 % from the calibration (margin 0.18 %)"."""
        kind = self.name[0]
        if self.verdict == "cannot tell":
            return f"{self.name}: cannot tell ({self.would_tell})"
        fmt = _percent if kind == "k" else _dps
        said = f"{fmt(self.change)} ± {fmt(self.std, signed=False)}"
        if self.verdict == "holds":
            return f"{self.name} holds: {said} from the calibration (margin {fmt(self.margin, signed=False)})"
        when = (f"between {self.since.after_s:.0f} s and {self.since.before_s:.0f} s into the recording" if self.since
                else "before the recording began")
        return f"{self.name} moved by {said}, {when}"


def _percent(v: float | None, signed: bool = True) -> str:
    return "—" if v is None else f"{100 * v:{'+' if signed else ''}.2f} %"


def _dps(v: float | None, signed: bool = True) -> str:
    return "—" if v is None else f"{v:{'+' if signed else ''}.3f} deg/s"


def judge(name: str, change: float, std: float, step: Step | None, since: Since | None, evidence: int,
          would_tell: str) -> ParameterVerdict:
    """The verdict from the recording's value (``change`` +- ``std`` against the calibration) and the best step in it."""
    kind = name[0]
    if step is not None and abs(step.size) >= MATTERS[kind]:
        return ParameterVerdict(name, "moved", step.size, step.std, since=since, evidence=evidence)
    if abs(change) > Z_MOVED * std and abs(change) >= MATTERS[kind]:
        return ParameterVerdict(name, "moved", change, std, evidence=evidence)
    reach = abs(change) + 1.96 * std
    if reach <= TOLERANCE[kind]:
        return ParameterVerdict(name, "holds", change, std, margin=TOLERANCE[kind] - reach, evidence=evidence)
    return ParameterVerdict(name, "cannot tell", change, std, would_tell=would_tell, evidence=evidence)
