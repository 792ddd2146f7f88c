"""Helpers of the command-line tests: the installed ``pkmcal`` script as a subprocess."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

PKMCAL = Path(sys.executable).parent / "pkmcal"


def run(*args, cwd):
    """Run ``pkmcal *args`` in ``cwd``; the CompletedProcess (text output)."""
    return subprocess.run([str(PKMCAL), *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=120)


def digest(path) -> str:
    """SHA-256 of a file: inputs must be unchanged after every command."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def assert_input_error(proc, *words):
    """Exit 2, one line on stderr naming the problem, no traceback."""
    assert proc.returncode == 2, proc.stdout + proc.stderr
    err = proc.stderr.strip()
    assert err.startswith("error: "), err
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, err
