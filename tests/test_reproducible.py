"""The same inputs and seed give byte-identical outputs; the date, the one field that varies,
is pinned by SOURCE_DATE_EPOCH as reproducible-build tools do (issue 11, item 6)."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from clitools import PKMCAL, assert_input_error, run
from pkmcal.errors import InputError
from pkmcal.report.provenance import run_date


def _run(*args, cwd, epoch):
    env = dict(os.environ)
    env.pop("SOURCE_DATE_EPOCH", None)
    if epoch is not None:
        env["SOURCE_DATE_EPOCH"] = epoch
    return subprocess.run([str(PKMCAL), *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("scenario,machine", [("constraint-link", "default"),
                                              ("tracker", "delta")])
def test_two_runs_give_byte_identical_files(tmp_path, scenario, machine):
    examples = Path(__file__).resolve().parents[1] / "examples"
    spec = "default" if machine == "default" else str(examples / "delta_default.yaml")
    runs = []
    for name in ("a", "b"):
        d = tmp_path / name
        d.mkdir()
        assert _run("simulate", spec, "--scenario", scenario, "--seed", "4", "-o", "d.csv",
                    cwd=d, epoch="1700000000").returncode == 0
        proc = _run("calibrate", spec, "d.csv", "-o", "cal.yaml", "--report", "rep", "-q",
                    cwd=d, epoch="1700000000")
        assert proc.returncode == 0, proc.stderr
        runs.append(d)
    a, b = runs
    for rel in ("d.csv", "cal.yaml", "cal.json", "rep/report.json", "rep/report.html"):
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    assert "2023-11-14T22:13:20+00:00" in (a / "cal.yaml").read_text()


def test_without_the_variable_the_date_is_now(monkeypatch):
    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)
    assert run_date()[:4].isdigit() and run_date().endswith("+00:00")
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "0")
    assert run_date() == "1970-01-01T00:00:00+00:00"


@pytest.mark.parametrize("value", ["yesterday", "-5", "1.5", "", "99999999999999999999"])
def test_a_malformed_epoch_is_refused(monkeypatch, tmp_path, value):
    # the commands in this process (clitools.run): the variable is read at each run's start
    d = tmp_path
    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)
    assert run("simulate", "default", "--scenario", "constraint-link", "--poses", "60",
               "-o", "d.csv", cwd=d).returncode == 0
    monkeypatch.setenv("SOURCE_DATE_EPOCH", value)
    with pytest.raises(InputError, match="SOURCE_DATE_EPOCH"):
        run_date()
    proc = run("calibrate", "default", "d.csv", "-o", "cal.yaml", cwd=d)
    assert_input_error(proc, "SOURCE_DATE_EPOCH")
    assert sorted(p.name for p in d.iterdir()) == ["d.csv"]
