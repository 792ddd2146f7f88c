"""Shared test helpers: the installed ``pkmcal`` console script, run as a subprocess."""

from __future__ import annotations

import os

# one BLAS thread (before numpy loads): many small SVDs, which threads slow down on 2 cores
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
# the commands run as from a plain pipe: pytest-xdist's workers set COLUMNS=80 and LINES=24,
# which the console honours (warnings wrapped to COLUMNS); a test that wants a width sets it
for _var in ("COLUMNS", "LINES"):
    os.environ.pop(_var, None)

import pytest  # noqa: E402

from clitools import run  # noqa: E402


@pytest.fixture
def cli(tmp_path):
    """``cli(*args, cwd=tmp_path) -> CompletedProcess`` running the ``pkmcal`` command."""

    def run_here(*args, cwd=tmp_path):
        return run(*args, cwd=cwd)

    return run_here
