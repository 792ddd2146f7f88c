"""Terminal output of the CLI (rich): one console for results, one for errors and warnings."""

from __future__ import annotations

import functools
import sys


_QUIET = False


def set_quiet() -> None:
    """``pkmcal --quiet``: the results console prints nothing (errors and warnings still do)."""
    global _QUIET
    _QUIET = True
    console.cache_clear()


def quiet() -> bool:
    return _QUIET


@functools.cache
def console():
    """Console on stdout; 120 columns when not a terminal (pipes, tests); silent with
    ``--quiet``."""
    from rich.console import Console

    return Console(highlight=False, width=None if sys.stdout.isatty() else 120, quiet=_QUIET)


@functools.cache
def err_console():
    from rich.console import Console

    return Console(stderr=True, highlight=False, soft_wrap=True)


def error(message: str) -> None:
    """One red line ``error: ...`` on stderr (the message is not read as markup)."""
    from rich.text import Text

    err_console().print(Text.assemble(("error: ", "bold red"), (message, "red")))


def warning(message: str) -> None:
    """One yellow line ``warning: ...`` on stderr."""
    from rich.text import Text

    err_console().print(Text.assemble(("warning: ", "bold yellow"), message))
