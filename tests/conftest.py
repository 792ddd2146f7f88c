"""Shared test helpers: the installed ``pkmcal`` console script, run as a subprocess."""

from __future__ import annotations

import pytest

from clitools import run


@pytest.fixture
def cli(tmp_path):
    """``cli(*args, cwd=tmp_path) -> CompletedProcess`` running the ``pkmcal`` command."""

    def run_here(*args, cwd=tmp_path):
        return run(*args, cwd=cwd)

    return run_here
