"""Shared test helpers: the installed ``pkmcal`` console script, run as a subprocess."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

PKMCAL = Path(sys.executable).parent / "pkmcal"


@pytest.fixture
def cli(tmp_path):
    """``cli(*args, cwd=tmp_path) -> CompletedProcess`` running the ``pkmcal`` command."""

    def run(*args, cwd=tmp_path):
        return subprocess.run([str(PKMCAL), *map(str, args)], cwd=cwd, capture_output=True,
                              text=True, timeout=120)

    return run
