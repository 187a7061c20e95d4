"""A recording's stages resolved once, the same way for every estimator and the diagnosis: given (a protocol, or
a list of stages) or detected, checked against the recording, and the protocol found in them."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from calib.errors import ProtocolError
from calib.recording import Recording
from calib.stages.detector import detect_stages
from calib.stages.hints import find_protocol_in
from calib.stages.protocol import ProtocolStages
from calib.stages.stage import Stage


@dataclass(frozen=True)
class ResolvedStages:
    """Every stage of a recording in time order, and the protocol (the first still and a turn per axis) in them."""

    stages: list[Stage]
    protocol: ProtocolStages


def resolve_stages(rec: Recording, stages: ProtocolStages | Sequence[Stage] | None = None) -> ResolvedStages:
    """The stages to calibrate ``rec`` with: a ProtocolStages as given, a list of Stage objects (sorted), or the
    detector's when None. Raises ProtocolError when a stage lies outside the recording or the protocol is not
    in the stages (naming what is missing and why, calib.stages.hints)."""
    if isinstance(stages, ProtocolStages):
        proto = stages
        seen: dict[tuple[str, int, int], Stage] = {}
        for s in (proto.still0, *proto.turns.values(), *proto.stills):
            seen.setdefault((s.kind, s.start, s.end), s)
        stage_list = sorted(seen.values(), key=lambda s: s.start)
    else:
        if stages is None:
            stage_list = detect_stages(rec)
        else:
            stage_list = list(stages)
            for s in stage_list:
                if not isinstance(s, Stage):
                    raise ProtocolError(f"stages must be Stage objects (from calib.stages.detect_stages); got {type(s).__name__}")
            stage_list.sort(key=lambda s: s.start)
        proto = find_protocol_in(rec, stage_list)
    check_stages_inside(rec, stage_list)
    return ResolvedStages(stage_list, proto)


def check_stages_inside(rec: Recording, stages: Sequence[Stage]) -> None:
    """ProtocolError when a stage lies outside the recording's samples."""
    n = len(rec)
    for s in stages:
        if not 0 <= s.start < s.end <= n:
            raise ProtocolError(f"{s.kind} stage [{s.start}, {s.end}) lies outside the recording's {n} samples")
