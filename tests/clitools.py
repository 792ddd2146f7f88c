"""Helpers of the command-line tests: the installed ``pkmcal`` script as a subprocess."""

from __future__ import annotations

import hashlib
import signal
import subprocess
import sys
from pathlib import Path

PKMCAL = Path(sys.executable).parent / "pkmcal"


def run(*args, cwd):
    """Run ``pkmcal *args`` in ``cwd``; the CompletedProcess (text output)."""
    return subprocess.run([str(PKMCAL), *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=120)


def _default_sigint():
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def popen(*args, cwd, **kwargs):
    """Start ``pkmcal *args`` in ``cwd`` as a user's shell does, Ctrl-C at its default: a
    process started with SIGINT ignored keeps ignoring it (Python honours an inherited
    ignore, as every Unix program should), and pytest-xdist's workers ignore it - so do a
    non-interactive shell's background jobs. Text output, ``kwargs`` passed on."""
    kwargs.setdefault("text", True)
    return subprocess.Popen([str(PKMCAL), *map(str, args)], cwd=cwd,
                            preexec_fn=_default_sigint, **kwargs)


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
