"""Help texts with a part filled in only when the help is shown: listing that part (every effect, every scenario)
imports much that a command which shows no help need not pay for at its start."""

from __future__ import annotations

import argparse
from collections.abc import Callable


def lazy_help(placeholder: str, fill: Callable[[], str],
              base: type[argparse.HelpFormatter] = argparse.HelpFormatter) -> type[argparse.HelpFormatter]:
    """A help formatter (``formatter_class``) that replaces ``placeholder`` in an argument's help by ``fill()``."""

    class LazyHelp(base):  # type: ignore[valid-type,misc]
        def _get_help_string(self, action: argparse.Action) -> str | None:
            text = super()._get_help_string(action)
            if text is None or placeholder not in text:
                return text
            return text.replace(placeholder, fill().replace("%", "%%"))

    return LazyHelp
