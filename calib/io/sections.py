"""Labelled sections: the user's own segmentation of a recording, used instead of stage detection.

Two sources, both imucal's (github.com/mad-lab-fau/imucal):
- a section list, JSON ``{"x_p": {"start": 540, "end": 1271}, ...}``: sample positions in the recording,
  ``start`` inclusive and ``end`` exclusive (pandas ``iloc[start:end]``, as imucal slices them); a list of
  ``{"label", "start", "end"}`` objects is read too;
- the ``part`` column of imucal's annotated sessions (``calib.io.readers`` turns its runs into sections).

Labels: ``x_p``, ``x_a``, ``y_p``, ``y_a``, ``z_p``, ``z_a`` (Ferraris' six static poses: the axis pointing
up, then down), ``still``/``rest``/``static`` (any rest), ``x_rot``, ``y_rot``, ``z_rot`` (one full turn about
that axis), and ``motion`` (anything else; not used). A suffix after ``_`` or ``-`` is allowed on rests,
motions and turns (``still_2``, ``x_rot-b``) so that a protocol may hold several.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from calib.errors import RecordingError, SectionsError
from calib.io.section import LABELS_HELP, Section, label_kind
from calib.recording import Recording, sample_intervals
from calib.stages.stage import Stage


def sections_from_labels(labels: np.ndarray) -> tuple[Section, ...]:
    """The runs of equal labels (in recording order) as sections."""
    labels = np.asarray(labels)
    if labels.size == 0:
        return ()
    change = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    starts = np.concatenate(([0], change))
    ends = np.concatenate((change, [labels.size]))
    out = tuple(Section(str(labels[a]).strip(), int(a), int(b)) for a, b in zip(starts, ends, strict=True))
    for s in out:
        label_kind(s.label)
    return out


def read_sections(path: str | os.PathLike[str], n_samples: int) -> tuple[Section, ...]:
    """Sections from an imucal-style section list file (JSON); checked against a recording of ``n_samples``."""
    return parse_sections(section_list_text(path), n_samples, f"the section list {path}")


def section_list_text(path: str | os.PathLike[str]) -> str:
    """The text of a section list file; SectionsError saying why it cannot be read."""
    p = Path(path)
    try:
        return p.read_text(encoding="utf-8")
    except OSError as exc:
        raise SectionsError(f"cannot read the section list {p}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise SectionsError(f"the section list {p} is not UTF-8 text; save it as a JSON file") from None


_EXAMPLE = '{"x_p": {"start": 540, "end": 1271}, ...} or [{"label": "x_p", "start": 540, "end": 1271}, ...]'


def parse_sections(text: str, n_samples: int, where: str = "the section list") -> tuple[Section, ...]:
    """Sections from the JSON text of a section list; SectionsError naming the section at fault."""
    try:
        raw = json.loads(text)
    except json.JSONDecodeError as exc:
        raise SectionsError(f"{where} is not valid JSON ({exc}); expected {_EXAMPLE}") from None
    if isinstance(raw, dict):
        items = list(raw.items())
    elif isinstance(raw, list):
        items = [(v.get("label") if isinstance(v, dict) else None, v) for v in raw]
    else:
        items = []
    if not items:
        raise SectionsError(f"{where} holds no sections; expected {_EXAMPLE}")
    out = []
    for label, v in items:
        if not isinstance(label, str) or not label.strip():
            raise SectionsError(f"{where}: every section needs a label ({LABELS_HELP})")
        at = f"{where}, section {label!r}"
        if not isinstance(v, dict) or not all(isinstance(v.get(k), int) and not isinstance(v.get(k), bool) for k in ("start", "end")):
            raise SectionsError(f"{at}: give start and end as whole sample positions, e.g. {{\"start\": 540, \"end\": 1271}}")
        start, end = int(v["start"]), int(v["end"])
        if not 0 <= start < end <= n_samples:
            raise SectionsError(f"{at}: samples {start} to {end} are not inside the recording's {n_samples} samples "
                                 "(positions count from 0, end exclusive)")
        try:
            label_kind(label.strip())
        except RecordingError as exc:
            raise SectionsError(str(exc)) from None
        out.append(Section(label.strip(), start, end))
    out.sort(key=lambda s: s.start)
    for a, b in zip(out, out[1:], strict=False):
        if b.start < a.end:
            raise SectionsError(f"{where}: sections {a.label!r} and {b.label!r} overlap "
                                 f"(samples {b.start} to {min(a.end, b.end)}); each sample belongs to one section at most")
    return tuple(out)


def stages_from_sections(rec: Recording, sections: tuple[Section, ...]) -> list[Stage]:
    """The labelled sections as stages, in recording order; a turn's angle is measured as the detector
    does (integrated reading minus the mean of the rests, about its labelled axis)."""
    if not sections:
        raise RecordingError("no labelled sections were given")
    t = rec.t
    rests = [s for s in sections if s.kind == "still"]
    offset = (np.concatenate([rec.gyro[s.start:s.end] for s in rests]).mean(axis=0) if rests else np.zeros(3))
    dt = sample_intervals(t)
    out = []
    for s in sections:
        angle = None
        if s.kind == "turn" and s.axis is not None:
            i = "xyz".index(s.axis)
            angle = float(((rec.gyro[s.start:s.end, i] - offset[i]) * dt[s.start:s.end]).sum())
        end_s = float(t[s.end]) if s.end < len(t) else float(t[-1] + dt[-1])
        out.append(Stage(s.kind, s.start, s.end, float(t[s.start]), end_s, s.axis, angle))
    return out


def section_list(stages: Sequence[Stage]) -> list[dict[str, str | int]]:
    """``stages`` as imucal's section list (``[{"label", "start", "end"}, ...]``, sample positions, end exclusive),
    which ``parse_sections`` reads back: the rests ``still_1``, ``still_2``, ...; the turns ``x_rot`` (a second turn
    about x ``x_rot_2``); motions are left out, as the estimators leave them."""
    out: list[dict[str, str | int]] = []
    counts: dict[str, int] = {}
    for st in sorted(stages, key=lambda s: s.start):
        if st.kind == "still":
            base = "still"
        elif st.kind == "turn" and st.axis is not None:
            base = f"{st.axis}_rot"
        else:
            continue
        counts[base] = counts.get(base, 0) + 1
        label = f"{base}_{counts[base]}" if base == "still" or counts[base] > 1 else base
        out.append({"label": label, "start": int(st.start), "end": int(st.end)})
    return out
