"""Expensive inputs several test files read, made once per test run.

Under pytest-xdist each worker is a process of its own, so a session fixture is made once per
worker, and a module fixture once per file: the same calibrations (the docs' reports, say)
were computed by every file that reads them. :func:`once` makes a directory once for the
whole run, in the temporary directory the workers share; the first worker that asks builds it
while the others wait on a lock, then every file reads the same files. Readers must not write
there (copy it first).
"""

from __future__ import annotations

import fcntl
import os
import shutil
from collections.abc import Callable
from pathlib import Path


def once(tmp_path_factory, name: str, build: Callable[[Path], object]) -> Path:
    """The directory ``build(directory)`` filled, built once per test run (once per worker
    process's run when not under pytest-xdist). A failed build leaves nothing marked done: the
    next file asking builds again (and fails the same way, with its own message)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent                  # the run's directory, shared by its workers
    target = root / f"once-{name}"
    done = root / f"once-{name}.done"
    with open(root / f"once-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not done.exists():
                if target.exists():
                    shutil.rmtree(target)
                target.mkdir()
                build(target)
                done.write_text("")
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    return target
