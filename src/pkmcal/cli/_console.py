"""Terminal output of the CLI (rich): one console for results, one for errors and warnings."""

from __future__ import annotations

import functools
import sys

from ..errors import stop_if_signalled

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


class progress_tasks:
    """Rich progress bars on stderr (done / total, elapsed, ETA); silent when stderr is not a
    terminal, with ``pkmcal --quiet`` or ``quiet``. Entering gives
    ``new(description, total) -> advance(n=1, description=None)`` (a new description names
    the stage now running)."""

    def __init__(self, quiet: bool = False):
        self.quiet = quiet
        self.bar = None

    def __enter__(self):
        stream = err_console()
        if self.quiet or _QUIET or not stream.is_terminal:
            return lambda description, total: (lambda n=1, description=None:
                                                stop_if_signalled())
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                            TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
                            console=stream, transient=True)
        self.bar.start()

        def new(description: str, total: int):
            task = self.bar.add_task(description, total=total)

            def advance(n=1, description=None):
                stop_if_signalled()
                self.bar.update(task, advance=n, description=description)

            return advance

        return new

    def __exit__(self, *exc):
        if self.bar is not None:
            self.bar.stop()
        return False
