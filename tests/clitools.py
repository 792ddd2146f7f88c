"""Helpers of the command-line tests: the ``pkmcal`` command, run in this process (what a
test of a command's outputs, messages and exit code needs) or as the installed script in a
subprocess (where the process is what is tested: signals, kill -9, start-up)."""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import signal
import subprocess
import sys
import warnings
from pathlib import Path

PKMCAL = Path(sys.executable).parent / "pkmcal"

#: PKMCAL_TEST_SUBPROCESS=1 runs every command of the tests as a subprocess (slower: ~0.5 s
#: of start-up each; the in-process runner must give the same outputs, which this checks)
SUBPROCESS = os.environ.get("PKMCAL_TEST_SUBPROCESS", "") not in ("", "0")


def run(*args, cwd):
    """Run ``pkmcal *args`` in ``cwd``; the CompletedProcess (text output)."""
    if SUBPROCESS:
        return run_process(*args, cwd=cwd)
    return run_in_process(*args, cwd=cwd)


def run_process(*args, cwd, **kwargs):
    """``pkmcal *args`` in ``cwd`` as a subprocess of the installed script."""
    return subprocess.run([str(PKMCAL), *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=kwargs.pop("timeout", 120), **kwargs)


def run_in_process(*args, cwd):
    """``pkmcal *args`` in ``cwd`` through :func:`pkmcal.cli.main`, as the console script
    runs it, in this process: stdout and stderr captured, the exit code from its
    ``SystemExit``; the working directory, ``sys.argv``, the warning filters, numpy's error
    state and the console's ``--quiet`` are put back afterwards."""
    import numpy as np

    from pkmcal.cli import _console, main

    args = [str(a) for a in args]
    out, err = io.StringIO(), io.StringIO()
    here, argv, np_err = os.getcwd(), sys.argv, np.geterr()
    code = 0
    try:
        os.chdir(cwd)
        sys.argv = ["pkmcal", *args]
        with warnings.catch_warnings(), contextlib.redirect_stdout(out), \
                contextlib.redirect_stderr(err):
            try:
                main(args)
            except SystemExit as exc:
                code = exc.code
                if code is None:
                    code = 0
                elif not isinstance(code, int):
                    err.write(f"{code}\n")
                    code = 1
    finally:
        os.chdir(here)
        sys.argv = argv
        np.seterr(**np_err)
        _console._QUIET = False
        _console.console.cache_clear()
        _console.err_console.cache_clear()
    return subprocess.CompletedProcess(["pkmcal", *args], code, out.getvalue(), err.getvalue())


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


def wait_at_most(proc, seconds: float) -> None:
    """Sleep ``seconds`` before signalling ``proc``, or less when it ends first: a signal
    after its end is not sent (:meth:`subprocess.Popen.send_signal`), so the outcome is the
    one after the whole delay, without the idle rest of it."""
    try:
        proc.wait(timeout=seconds)
    except subprocess.TimeoutExpired:
        pass


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


def console_rows(text: str) -> dict[str, str]:
    """The rows ``label │ text`` of a command's summary table, continuation lines joined and
    spaces normalised (a label printed twice: its texts joined by ``" | "``)."""
    rows: list[list[str]] = []
    for line in text.splitlines():
        if "│" not in line:
            continue
        head, _, tail = line.partition("│")
        if head.strip() or not rows:
            rows.append([head.strip(), tail.strip()])
        else:
            rows[-1][1] += " " + tail.strip()
    out: dict[str, str] = {}
    for label, body in rows:
        body = " ".join(body.split())
        out[label] = f"{out[label]} | {body}" if label in out else body
    return out


def calibrated_file(tmp: Path, machine_file, scenario: str, *extra) -> Path:
    """``pkmcal simulate MACHINE --scenario SCENARIO --seed 1 *extra`` then ``pkmcal calibrate``
    of its data, in ``tmp`` (asserting both succeed): the calibrated machine file."""
    data, cal = tmp / "data.csv", tmp / "cal.yaml"
    proc = run("simulate", machine_file, "--scenario", scenario, "--seed", "1", *extra, "-o",
               data, cwd=tmp)
    assert proc.returncode == 0, proc.stderr
    proc = run("calibrate", machine_file, data, "-o", cal, cwd=tmp)
    assert proc.returncode == 0, proc.stderr
    return cal


def delta_at_linuxcnc_hips(tmp: Path) -> Path:
    """examples/delta_default.yaml with its legs turned to 150, 30, -90 deg (rotarydeltakins'
    hips, in another order than its joints), written to ``tmp``: the machine file."""
    examples = Path(__file__).resolve().parents[1] / "examples"
    text = (examples / "delta_default.yaml").read_text().replace(
        "leg_angles: [90.0, 180.0, -90.0]", "leg_angles: [150.0, 30.0, -90.0]")
    assert "150.0, 30.0" in text
    path = tmp / "nominal.yaml"
    path.write_text(text)
    return path
