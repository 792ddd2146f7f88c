"""Every command says each thing once (issue 36 item 5).

Warnings were printed before the header and again in the summary; the summary's rows and the
warnings repeated each other verbatim (the residual test's sentence, the model choice of
``--parameters auto``, the list of outlier rows). Each command that prints warnings runs here as
a user runs it (calibrate, with the summary and with ``--json``, of one file and of several;
check; export; compensate; simulate; montecarlo), with a width that wraps nothing, and:

- no warning line appears twice;
- no clause of a warning (a piece between ``;``, ``:`` or ``.`` of 50 characters or more)
  appears in the command's other output;
- the residual test's sentence, which the summary's ``residual test`` row states, is not in
  the warnings (they agree with it: tests/test_verdict_agreement.py).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from clitools import run

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
PRINTER = EXAMPLES / "linear_delta.yaml"
DELTA = EXAMPLES / "delta_default.yaml"

#: a clause of a warning this long found elsewhere is a repetition, not a shared word
CLAUSE = 50


def _warnings(stderr: str) -> list[str]:
    return [line[len("warning: "):] for line in stderr.splitlines()
            if line.startswith("warning: ")]


def _clauses(text: str) -> list[str]:
    return [c.strip() for c in re.split(r"; |: |\. ", text) if len(c.strip()) >= CLAUSE]


def _said_once(proc, what: str, prose: bool = True) -> list[str]:
    """The warnings of a command that said each once (``prose``: its stdout is words, not
    the JSON report, which holds everything)."""
    assert proc.returncode == 0, (what, proc.stderr)
    warned = _warnings(proc.stderr)
    assert len(warned) == len(set(warned)), (what, warned)
    if not prose:
        return warned
    rest = " ".join(" ".join(line.split("│")) for line in proc.stdout.splitlines())
    rest = " ".join(rest.split())
    for w in warned:
        for clause in _clauses(w):
            assert " ".join(clause.split()) not in rest, (what, clause)
    return warned


@pytest.fixture(scope="module")
def d(tmp_path_factory):
    d = tmp_path_factory.mktemp("once")
    steps = [("simulate", PRINTER, "--seed", "1", "--truth", "true.yaml", "-o", "p.csv"),
             ("simulate", PRINTER, "--seed", "1", "--noise", "100um", "-o", "p100.csv"),
             ("simulate", "true.yaml", "--deviations", "none", "--scenario", "distance",
              "--seed", "2", "-o", "bar.csv"),
             ("simulate", DELTA, "--scenario", "tracker", "--outliers", "2", "--seed", "1",
              "-o", "pts.csv")]
    for step in steps:
        proc = run(*step, cwd=d)
        assert proc.returncode == 0, proc.stderr
    (d / "targets.csv").write_text("x_mm,y_mm,z_mm\n0,0,10\n40,-30,0.2\n")
    return d


@pytest.fixture(autouse=True)
def wide(monkeypatch):
    """A width that wraps no table cell and no message (what is compared is the words)."""
    monkeypatch.setenv("COLUMNS", "3000")


#: name -> calibrate arguments (machine, files, options)
CALIBRATIONS = {
    # a failed test, outlier rows, poorly determined parameters, the model choice of
    # --parameters auto: every kind of warning at once
    "probe, 10x the noise told": (PRINTER, ["p100.csv"], ["--noise", "10um"]),
    "tracker with two 1 mm outliers": (DELTA, ["pts.csv"], ["--noise", "leica"]),
    "probe and ballbar together": (PRINTER, ["p.csv", "bar.csv"],
                                   ["--parameters", "klipper"]),
}


@pytest.mark.parametrize("json_output", [False, True], ids=["summary", "json"])
@pytest.mark.parametrize("name", list(CALIBRATIONS))
def test_calibrate_says_each_warning_once(d, name, json_output):
    machine, files, options = CALIBRATIONS[name]
    out = f"c{list(CALIBRATIONS).index(name)}{'j' * json_output}.yaml"
    proc = run("calibrate", machine, *files, *options, "-o", out,
               *(["--json"] if json_output else []), cwd=d)
    warned = _said_once(proc, name, prose=not json_output)
    assert warned, name                     # each case has something to warn of
    report = json.loads((d / out).with_suffix(".json").read_text())
    sentence = report["acceptance"]["residuals"]["sentence"]
    assert sentence not in proc.stderr, name
    if not json_output:
        # the summary states the verdict; the warning of a failed test points to it
        assert sentence in " ".join(proc.stdout.split()), name


def test_check_export_compensate_simulate_montecarlo_say_each_warning_once(d):
    proc = run("calibrate", PRINTER, "p.csv", "--parameters", "klipper", "-o", "cal.yaml",
               cwd=d)
    _said_once(proc, "calibrate")
    commands = {
        "check": ("check", "cal.yaml", "p.csv"),
        "export": ("export", "cal.yaml", "--to", "klipper", "-o", "printer.cfg"),
        # a machine file without its report: the predicted residual error is warned of
        "compensate": ("compensate", PRINTER, "targets.csv", "-o", "carriages.csv"),
        "simulate": ("simulate", PRINTER, "--seed", "3", "-o", "again.csv"),
        "montecarlo": ("montecarlo", PRINTER, "--scenario", "probe", "--vary",
                       "noise=5um,200um", "--runs", "2", "-o", "mc"),
    }
    warned = {}
    for what, args in commands.items():
        warned[what] = _said_once(run(*args, cwd=d), what)
    assert warned["compensate"], warned         # the cases do warn: the check is not idle
