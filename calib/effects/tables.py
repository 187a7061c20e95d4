"""The catalogue as text: the CLI's ``--effect`` help and the documentation's tables, written from the specs.

``scripts/effects_tables.py`` puts the tables into docs/effects.md and docs/diagnosis.md (between
``<!-- effects-table: NAME -->`` and ``<!-- /effects-table -->``); a test checks they are current.
"""

from __future__ import annotations

from calib.effects.base import EFFECTS, catalogue_specs, registered


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(_cell(c) for c in cells) + " |"


def effect_value_help() -> str:
    """Every registered effect's ``NAME=VALUE`` syntax, catalogue first (the ``--effect`` help)."""
    return "; ".join(f"{name}={EFFECTS[name].usage}" for name in registered())


def models_table() -> str:
    """The simulator's model of each effect, its parameters and its ``--effect`` value."""
    lines = [_row(["name", "model", "parameters", "`--effect` value"]), "|---|---|---|---|"]
    for name, spec in catalogue_specs().items():
        lines.append(_row([f"`{name}`", spec.equation, spec.parameters, f"`{EFFECTS[name].usage}`"]))
    return "\n".join(lines)


def ranges_table() -> str:
    """What the concealed-effect generator draws for each effect, and where the range comes from."""
    lines = [_row(["effect", "magnitude", "range", "typical of"]), "|---|---|---|---|"]
    for name, spec in catalogue_specs().items():
        r = spec.drawn
        lines.append(_row([name, r.what, r.text(), r.why]))
    return "\n".join(lines)


def diagnosis_table() -> str:
    """How the diagnosis models each effect, what reveals it, and its typical size."""
    lines = [_row(["effect", "model", "parameters", "typical size", "revealed by"]), "| --- | --- | --- | --- | --- |"]
    for name, spec in catalogue_specs().items():
        lines.append(_row([name, spec.diagnosis_model, spec.diagnosis_parameters, spec.typical_text or "-", spec.reveal]))
    return "\n".join(lines)


TABLES = {"models": models_table, "ranges": ranges_table, "diagnosis": diagnosis_table}
