"""Entry point of the ``pkmcal`` console script.

It imports nothing heavy itself, so that Ctrl-C while the command's modules are still being
imported also ends with one line (``error: interrupted``, exit 130) instead of a traceback;
everything else is :func:`pkmcal.cli.main`.
"""

from __future__ import annotations

import sys


def main() -> None:
    """Run ``pkmcal`` (:func:`pkmcal.cli.main`); Ctrl-C at any point exits 130 with one line."""
    try:
        from .cli import main as cli_main

        cli_main()
    except KeyboardInterrupt:
        sys.stderr.write("error: interrupted\n")
        raise SystemExit(130) from None
