"""Every `gyrocal ...` command the README and the docs show parses as written, its placeholders filled: a command
line in a code block parses whole; a command named in the prose uses only options that exist where it puts them."""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

from calib.cli.main import build_parser

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

# a value for each placeholder the docs write in capitals
PLACEHOLDERS = {
    "N": "3", "X": "2", "S": "1", "HZ": "100", "R": "gyrocal_service", "URL": "sqlite:///gyrocal.sqlite3",
    "NAME": "alice", "FILE": "recording.csv", "ID": "mock-1", "DEVICE": "mock-1", "TIME": "2026-01-01T00:00:00",
    "NAME=VALUE": "bias_drift=0.01", "C": "25", "M": "ICM-20948", "DEG": "0.3",
}
# where an option takes one of a few names, a placeholder after it is the first of them
AFTER_OPTION = {"--model": "gyrocal"}
# what a command named in the prose may leave out (it names the command and an option, not a whole line)
FRAGMENT = ("the following arguments are required", "expected one argument")


def _documented() -> list[tuple[str, str, bool]]:
    """(document, command, whole line?) for each `gyrocal COMMAND ...` in a code block or a prose code span."""
    names = set(build_parser()._subparsers._group_actions[0].choices)  # type: ignore[union-attr]
    found: list[tuple[str, str, bool]] = []
    for doc in DOCS:
        lines = doc.read_text(encoding="utf-8").splitlines()
        i = 0
        while i < len(lines):
            line = lines[i].strip().removeprefix("$ ")
            while line.endswith("\\") and i + 1 < len(lines):
                i += 1
                line = line[:-1] + " " + lines[i].strip()
            i += 1
            for span, whole in [(line, True)] + [(s, False) for s in re.findall(r"`(gyrocal [^`]+)`", line)]:
                words = span.split()
                if len(words) >= 2 and words[0] == "gyrocal" and words[1] in names:
                    found.append((doc.name, span, whole))
    return found


def _as_argv(line: str) -> list[str]:
    """The command with its comment cut, optional parts kept, the first of a|b or (a | b), placeholders filled."""
    line = re.split(r"\s+#\s", line, maxsplit=1)[0].replace("\\|", "|").replace("…", "")
    line = re.sub(r"<[^<>]*>", "URL", line)
    line = re.sub(r"\(([^()|]*)\|[^()]*\)", r"\1", line)
    while "[" in line:
        line = re.sub(r"\[([^\[\]]*)\]", r"\1", line)
    argv: list[str] = []
    for word in shlex.split(line)[1:]:
        if "|" in word and "://" not in word:
            word = word.split("|")[0]
        if word in PLACEHOLDERS:
            word = AFTER_OPTION.get(argv[-1], PLACEHOLDERS[word]) if argv else PLACEHOLDERS[word]
        argv.append(word)
    return argv


CASES = _documented()


@pytest.mark.parametrize(("where", "line", "whole"), CASES, ids=[f"{d}:{ln[:50]}" for d, ln, _ in CASES])
def test_documented_command_parses(where: str, line: str, whole: bool) -> None:
    argv = _as_argv(line)
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            build_parser().parse_args(argv)
    except SystemExit as exc:
        message = err.getvalue().strip().splitlines()[-1] if err.getvalue().strip() else ""
        if whole or not any(f in message for f in FRAGMENT):
            pytest.fail(f"{where}: `{line}`\n  read as {argv}: exit {exc.code}: {message}")
