"""What to install when a part of gyrocal cannot be imported: the extra that brings the missing module."""

from __future__ import annotations

import argparse
import re
from importlib.metadata import PackageNotFoundError, requires
from typing import Any

from calib.errors import GyrocalError

DISTRIBUTION = "gyrocal"


def _extra_of(module: str) -> str | None:
    """The optional-dependency group of gyrocal that lists the package providing top-level ``module``."""
    try:
        requirements = requires(DISTRIBUTION) or []
    except PackageNotFoundError:
        return None
    wanted = module.split(".")[0].replace("_", "-").lower()
    for requirement in requirements:
        name = re.split(r"[\s\[<>=!~;]", requirement, maxsplit=1)[0].replace("_", "-").lower()
        extra = re.search(r"""extra\s*==\s*["']([^"']+)["']""", requirement)
        if extra and name in (wanted, f"python-{wanted}"):
            return extra.group(1)
    return None


def install_command(exc: ImportError) -> str:
    """The command that installs the module ``exc`` could not import: gyrocal's extra that lists it, else its package."""
    module = exc.name or "?"
    extra = _extra_of(module)
    if extra:
        return f"pip install 'gyrocal[{extra}]' (in a clone: make install)"
    return f"pip install {module.split('.')[0].replace('_', '-')}"  # not one of gyrocal's own dependencies


def install_hint(exc: ImportError) -> str:
    """'the module X could not be imported (...); install it with: ...', for a message that names what failed."""
    return f"the module {exc.name or '?'!r} could not be imported ({exc}); install it with: {install_command(exc)}"


def missing_module(command: str, exc: ImportError) -> str:
    """What to tell a user whose ``gyrocal COMMAND`` stopped on a module that is not installed."""
    return f"'gyrocal {command}' needs the module {exc.name!r}, which could not be imported: install it with: {install_command(exc)}"


def register_unavailable(sub: Any, name: str, exc: ImportError) -> None:
    """A command of ``sub`` (argparse subparsers) whose part of gyrocal cannot be imported: asking for it says which
    module failed and what installs it, whatever arguments follow."""
    message = f"'gyrocal {name}' cannot be loaded: {install_hint(exc)}"

    def unavailable(_args: argparse.Namespace) -> int:
        raise GyrocalError(message)

    # no option prefix: whatever follows the command's name is taken as given, so the message above is what is printed
    p = sub.add_parser(name, help=f"(not installed: {exc.name or exc})", add_help=False, prefix_chars="\x00")
    p.add_argument("rest", nargs="*")
    p.set_defaults(func=unavailable)
