"""A recording turned about some of the device's axes only (calib.estimators.closure.partial): the axes turned are
calibrated as well as a full recording would, the others are named as not determined (k and b null), the result
fails its checks on them with that reason, and the command line says INCOMPLETE."""

from __future__ import annotations

import json

import numpy as np
import pytest

from calib.cli.main import main as gyrocal
from calib.io.readers import write_native_csv
from calib.judge.acceptance import Tolerances, evaluate
from calib.pipeline import calibrate_protocol
from calib.simulator import ProtocolScript, Still, Turn, simulate


def _turned(*axes: str) -> ProtocolScript:
    segs: list = [Still(3.0)]
    for a in axes:
        segs += [Turn(a, 360.0), Still(3.0)]
    return ProtocolScript(tuple(segs))


@pytest.mark.parametrize(("axes", "missing"), [(("y", "y"), ["x", "z"]), (("x", "z"), ["y"])])
def test_the_axes_turned_are_calibrated_and_the_others_named(axes: tuple[str, ...], missing: list[str]) -> None:
    zs = []
    for seed in range(6):
        rec, truth = simulate(seed, noise=0.05, script=_turned(*axes))
        result, used = calibrate_protocol(rec)
        assert used == "paper" and result.quality["undetermined_axes"] == missing
        held = np.array([a in missing for a in "xyz"])
        assert np.all(np.isnan(result.k[held])) and np.all(np.isnan(result.b[held])) and np.all(np.isnan(result.k_std[held]))
        zs.append(np.concatenate(((result.k - truth.k)[~held] / result.k_std[~held], (result.b - truth.b)[~held] / result.b_std[~held])))
        assert np.all(result.k_std[~held] < 5e-4)  # a turn about the vertical carries the heading prior (0.1 deg)
        assert any(w.startswith(f"no usable full turn about {' and '.join(missing)}") for w in result.warnings)
        checks = evaluate(result, Tolerances())
        failed = [c for c in checks if not c.ok]
        assert [(c.name, c.axis) for c in failed] == [("k", a) for a in missing]
        assert all(f"no usable full turn about {c.axis}" in c.text for c in failed)
    z = np.concatenate(zs)
    assert np.all(np.abs(z) < 4.5) and 0.5 < np.std(z) < 1.5, z


def test_a_recording_turned_about_no_axis_at_all_is_still_refused() -> None:
    from calib import ProtocolError

    rec, _ = simulate(2, noise=0.05, script=ProtocolScript((Still(3.0), Still(3.0))))
    with pytest.raises(ProtocolError) as err:
        calibrate_protocol(rec)
    assert err.value.code == "turn_missing"


def test_the_command_line_says_incomplete_and_names_what_is_missing(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    rec, truth = simulate(4, noise=0.03, script=_turned("y", "y"))
    path = tmp_path / "y.csv"
    write_native_csv(rec, path)
    assert gyrocal(["calibrate", str(path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)  # strict JSON: no NaN
    assert doc["k"][0] is None and doc["k"][2] is None and doc["b"][0] is None and doc["uncertainty"]["k"][0] is None
    assert abs(doc["k"][1] - truth.k[1]) < 5 * doc["uncertainty"]["k"][1]
    assert gyrocal(["calibrate", str(path)]) == 0
    text = capsys.readouterr().out
    assert "INCOMPLETE: no usable full turn about x and z, so their k and b are not determined" in text
    assert text.count("not determined") == 6  # the headline, the four rows of k_x, k_z, b_x, b_z, the warning
