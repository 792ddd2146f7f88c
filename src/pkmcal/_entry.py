"""Entry point of the ``pkmcal`` console script.

It imports nothing heavy itself, so that Ctrl-C while the command's modules are still being
imported also ends with one line (``error: interrupted``, exit 130) instead of a traceback,
and SIGTERM/SIGHUP then end with one line and 128 + signal instead of the default silent
death; everything else is :func:`pkmcal.cli.main`.
"""

from __future__ import annotations

import sys

from .errors import Terminated, handle_signals, interruption, interruption_exit


def main() -> None:
    """Run ``pkmcal`` (:func:`pkmcal.cli.main`); Ctrl-C at any point exits 130 with one line,
    SIGTERM or SIGHUP 128 + signal."""
    handle_signals()
    try:
        from .cli import main as cli_main

        cli_main(exiting=True)
    except (KeyboardInterrupt, Terminated, Exception) as exc:
        # a signal during an extension module's initialisation is an ImportError caused by it
        # (or another exception where the module swallowed the signal's)
        cause = interruption(exc)
        if cause is None:
            raise
        message, code = interruption_exit(cause)
        sys.stderr.write(f"error: {message}\n")
        raise SystemExit(code) from None
