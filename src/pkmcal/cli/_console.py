"""Terminal output of the CLI (rich): one console for results, one for errors and warnings."""

from __future__ import annotations

import functools
import os
import sys

from ..errors import stop_if_signalled
from ..paths import path_text, undecodable_escaped

_QUIET = False


def set_quiet() -> None:
    """``pkmcal --quiet``: the results console prints nothing (errors and warnings still do)."""
    global _QUIET
    _QUIET = True
    console.cache_clear()


def quiet() -> bool:
    return _QUIET


class _Escaping:
    """A text stream whose writes have file names' undecodable bytes written ``\\xNN``
    (:func:`pkmcal.paths.undecodable_escaped`): a name that is not UTF-8 in a table or a
    "wrote ..." line cannot end a run in UnicodeEncodeError."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> int:
        return self._stream.write(undecodable_escaped(text))

    def __getattr__(self, name):
        return getattr(self._stream, name)


@functools.cache
def _console_class():
    from rich.console import Console

    class EscapingConsole(Console):
        """rich's Console writing through :class:`_Escaping` (its stream is looked up at
        each write, as rich does: sys.stdout may be redirected)."""

        @property
        def file(self):
            return _Escaping(Console.file.fget(self))

        @file.setter
        def file(self, new_file) -> None:
            Console.file.fset(self, new_file)

    return EscapingConsole


def _columns() -> int | None:
    """``COLUMNS`` when it is set to a width (the user's terminal width for a pipe)."""
    text = os.environ.get("COLUMNS", "").strip()
    return int(text) if text.isdigit() and int(text) > 0 else None


@functools.cache
def console():
    """Console on stdout: the terminal's width; piped, ``COLUMNS`` when set, else 120 columns
    (pipes, tests); silent with ``--quiet``."""
    width = None if sys.stdout.isatty() else (_columns() or 120)
    return _console_class()(highlight=False, width=width, quiet=_QUIET)


@functools.cache
def err_console():
    """Console on stderr: messages wrapped to the terminal's width, or to ``COLUMNS`` when
    piped; piped without ``COLUMNS``, one line per message (for programs and logs)."""
    width = None if sys.stderr.isatty() else _columns()
    return _console_class()(stderr=True, highlight=False, width=width,
                            soft_wrap=width is None and not sys.stderr.isatty())


def error(message: str) -> None:
    """One red line ``error: ...`` on stderr, never broken by the console (the one-message
    contract: a program reading stderr gets one line; a terminal folds it as it shows it);
    the message is not read as markup; file names in it rendered by
    :func:`pkmcal.paths.path_text`: bytes that are not UTF-8 and control characters as
    ``\\xNN``."""
    from rich.text import Text

    err_console().print(Text.assemble(("error: ", "bold red"), (path_text(message), "red")),
                        soft_wrap=True)


def warning(message: str) -> None:
    """One yellow line ``warning: ...`` on stderr (rendered as :func:`error` renders)."""
    from rich.text import Text

    err_console().print(Text.assemble(("warning: ", "bold yellow"), path_text(message)))


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

        # redrawn as the work advances, not by a thread of its own: a process running no
        # other thread can fork its workers (pkmcal montecarlo, issue 37)
        self.bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                            TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
                            console=stream, transient=True, auto_refresh=False)
        self.bar.start()

        def new(description: str, total: int):
            task = self.bar.add_task(description, total=total)
            self.bar.refresh()

            def advance(n=1, description=None):
                stop_if_signalled()
                self.bar.update(task, advance=n, description=description)
                self.bar.refresh()

            return advance

        return new

    def __exit__(self, *exc):
        if self.bar is not None:
            self.bar.stop()
        return False


def print_summary(summary) -> int:
    """Print a :class:`~pkmcal.report.summary.Summary` (its lines and tables on stdout, raw
    text as it is, then each warning once on stderr); returns its exit code. With ``pkmcal
    --quiet`` only the raw text (a ``--json`` document) and the warnings are printed."""
    import sys as _sys

    from rich.table import Table
    from rich.text import Text

    from ..report.summary import RawText, SummaryTable

    out = console()
    for block in summary.blocks:
        if out.quiet and not isinstance(block, RawText):
            continue            # a quiet console drops it: not rendered for nothing
        if isinstance(block, SummaryTable):
            # titles and headings are plain text as the cells are ("changes side at [deg]")
            title = None if block.title is None else Text(block.title, style="table.title")
            table = Table(title=title, title_justify="left", show_edge=False,
                          pad_edge=False, show_header=block.header)
            for i, col in enumerate(block.columns):
                table.add_column(Text(col), justify=block.justify.get(i, "left"))
            for row in block.rows:
                table.add_row(*(Text(c) if isinstance(c, str) else Text(c[0], style=c[1])
                                for c in row))
            out.print(table)
        elif isinstance(block, RawText):        # printed with --quiet too (--json output)
            _sys.stdout.write(block.text)
            _sys.stdout.flush()
        else:
            out.print(block, markup=False)
    for text in summary.warnings:
        warning(text)
    for text in summary.errors:     # why a run that wrote its outputs failed (exit 1)
        error(text)
    return summary.exit_code
