"""The effect registry: one EffectSpec per effect drives the generator, the diagnosis, the CLI and the docs."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from calib.diagnosis.models import Model
from calib.diagnosis.select import ADVICE, TYPICAL
from calib.effects import CATALOGUE, EFFECTS, DrawContext, catalogue_specs
from calib.simulator.concealed import RANGES

ROOT = Path(__file__).resolve().parents[2]


def test_every_catalogue_effect_has_a_complete_spec():
    specs = catalogue_specs()
    assert tuple(specs) == CATALOGUE
    assert [s.rank for s in specs.values()] == sorted({s.rank for s in specs.values()}), "ranks must be distinct"
    for name, spec in specs.items():
        assert spec.equation and spec.parameters and spec.reveal and spec.diagnosis_model, name
        assert 0 < spec.drawn.low < spec.drawn.high, name
        if spec.typical is not None:  # a typical size the diagnosis tests with lies in the drawn range
            assert spec.drawn.low <= spec.typical <= spec.drawn.high, name
            assert spec.typical_text, name


@pytest.mark.parametrize("name", CATALOGUE)
def test_each_effect_draws_its_magnitude_in_its_range(name: str):
    spec = EFFECTS[name].spec
    assert spec is not None
    ctx = DrawContext(turns=3, duration_s=30.0, peak_dps=400.0, temperature=None)
    for seed in range(20):
        effect, magnitude = EFFECTS[name].draw(np.random.default_rng(seed), ctx)
        assert isinstance(effect, EFFECTS[name])
        assert spec.drawn.low <= magnitude <= spec.drawn.high, (name, magnitude)


def test_the_diagnosis_reads_names_and_sizes_from_the_specs():
    specs = catalogue_specs()
    assert RANGES == {n: s.drawn for n, s in specs.items()}
    assert ADVICE == {n: s.reveal for n, s in specs.items()}
    assert TYPICAL == {n: s.typical for n, s in specs.items() if s.typical is not None}
    names = Model(effects=("axis_misalignment", "g_sensitivity")).names()
    terms = [*specs["axis_misalignment"].model_params["axis_misalignment"], *specs["g_sensitivity"].model_params["g_sensitivity"]]
    assert names[6:] == terms


def test_the_documentation_tables_are_written_from_the_specs():
    out = subprocess.run([sys.executable, "scripts/effects_tables.py", "--check"], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


# A new effect as a contributor would add it: one module in calib/effects and its import line.
ADDED_MODULE = '''
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from calib.effects.base import Effect, register_effect
from calib.effects.spec import EffectSpec, MagnitudeRange, log_uniform


@register_effect
@dataclass(frozen=True)
class OffsetStep(Effect):
    """A constant offset of the readings."""

    name: ClassVar[str] = "offset_step"
    usage: ClassVar[str] = "OFFSET (deg/s)"
    spec: ClassVar[EffectSpec] = EffectSpec(
        rank=99, equation="m_out = m + o", parameters="o (deg/s)",
        drawn=MagnitudeRange(0.1, 0.5, "deg/s", "offset", "a test range"),
        reveal="rest twice", diagnosis_model="not modelled", diagnosis_parameters="-")
    offset_dps: float = 0.0

    def on_sensor(self, m, ctx, rng):
        return m + self.offset_dps

    @classmethod
    def draw(cls, rng, ctx):
        mag = log_uniform(rng, cls.spec.drawn.low, cls.spec.drawn.high)
        return cls(mag), mag
'''

PROBE = '''
import json
from calib.cli.main import build_parser
from calib.simulator.concealed import EFFECT_NAMES, RANGES, draw_concealed
from calib.diagnosis.select import ADVICE
from calib.effects.tables import models_table

case = draw_concealed(5, "offset_step")
simulate = next(a for a in build_parser()._actions if a.dest == "command").choices["simulate"]
print(json.dumps({
    "catalogue": EFFECT_NAMES[-1] == "offset_step", "range": "offset_step" in RANGES, "advice": ADVICE.get("offset_step"),
    "table": "offset_step" in models_table(), "help": "offset_step=OFFSET" in "".join(simulate.format_help().split()),
    "magnitude": case.magnitude, "truth": case.truth.to_dict()["effects"],
}))
'''


def test_an_effect_added_in_one_place_reaches_the_generator_the_diagnosis_the_cli_and_the_docs(tmp_path: Path):
    shutil.copytree(ROOT / "calib", tmp_path / "calib", ignore=shutil.ignore_patterns("__pycache__"))
    (tmp_path / "calib" / "effects" / "offset.py").write_text(ADDED_MODULE)
    init = tmp_path / "calib" / "effects" / "__init__.py"
    text = init.read_text()
    anchor = "from calib.effects.placement import"
    assert anchor in text
    init.write_text(text.replace(anchor, "from calib.effects.offset import OffsetStep\n" + anchor))
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", PROBE], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert got["catalogue"] and got["range"] and got["table"] and got["help"]
    assert got["advice"] == "rest twice"
    assert 0.1 <= got["magnitude"] <= 0.5
    assert got["truth"] == [{"name": "offset_step", "offset_dps": got["magnitude"]}]
