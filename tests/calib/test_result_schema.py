"""The result's JSON form, declared once (calib.result_schema): every form gyrocal has written reads back."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from pydantic import ValidationError

from calib.result import FORMAT_VERSION, CalibrationResult
from calib.result_schema import ResultDoc

# CalibrationResult.to_json() of each estimator as gyrocal wrote it at 4e49e98, before the form was numbered
OLD = json.loads((Path(__file__).parent / "data" / "results_4e49e98.json").read_text())


@pytest.mark.parametrize("name", sorted(OLD))
def test_a_result_stored_before_the_form_was_numbered_reads_back_whole(name: str) -> None:
    old = OLD[name]
    assert "format_version" not in old
    assert ResultDoc.model_validate(old).format_version == 1
    back = CalibrationResult.from_dict(old)
    assert back.to_json() == {"format_version": FORMAT_VERSION, **old}
    assert back.to_doc().model_dump(mode="json", exclude_unset=True) == back.to_json()


def test_the_quality_blocks_every_estimator_shares_are_typed() -> None:
    doc = ResultDoc.model_validate(OLD["multi-position"])
    protocol, accel = doc.quality.get("protocol"), doc.quality.get("accelerometer")
    assert protocol is not None and protocol["used"] == "multi-position" and protocol["found"]["name"] == "multi-position"
    assert accel is not None and len(accel["scale"] or []) == 3
    closure = ResultDoc.model_validate(OLD["paper-closure"])
    assert closure.quality.get("model_choice") is not None and closure.quality.get("model") == "diagonal"
    assert closure.residuals.turns and all(t.closure_norm_deg is not None for t in closure.residuals.turns)
    for name, stored in OLD.items():  # every estimator's own keys, as results stored by 4e49e98 hold them
        assert ResultDoc.model_validate(stored).quality == stored["quality"], name
    with pytest.raises(ValidationError, match="turns"):
        ResultDoc.model_validate({**OLD["paper-closure"], "quality": {"turns": "three"}})
    schema = ResultDoc.model_json_schema()
    assert {"k", "b", "K", "G", "uncertainty", "quality", "format_version"} <= set(schema["properties"])
    assert {"protocol", "accelerometer", "temperature_c", "birge_ratio"} <= set(schema["$defs"]["Quality"]["properties"])


def _floats_as_null(x: object) -> object:
    if isinstance(x, float):
        return None
    if isinstance(x, dict):
        return {k: _floats_as_null(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_floats_as_null(v) for v in x]
    return x


@pytest.mark.parametrize("name", sorted(OLD))
def test_a_value_that_is_not_finite_anywhere_in_quality_reads_back(name: str) -> None:
    """An estimator's float may be NaN (an accelerometer parameter the rests do not identify, a fit that did not
    converge): JSON writes it as null, and every quality block still reads back."""
    stored = {**OLD[name], "quality": _floats_as_null(OLD[name]["quality"])}
    assert ResultDoc.model_validate(stored).quality == stored["quality"]

