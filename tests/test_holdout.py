"""Held-out validation (issue 6, item 1): ``pkmcal calibrate --holdout F``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error
from pkmcal.calibration import holdout_split
from pkmcal.cli import _hoist_quiet

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
MACHINES = {
    "hexaslide": (EXAMPLES / "hexaslide_default.yaml", ["--noise", "0"]),
    "delta": (EXAMPLES / "delta_default.yaml", ["--noise", "none"]),
    "stewart": (EXAMPLES / "cubic_6upu.yaml", ["--noise", "0", "--pose-noise", "0,0"]),
}


def test_holdout_split_is_a_seeded_partition():
    train, held = holdout_split(150, 0.2, seed=3)
    assert len(held) == 30 and len(train) == 120
    assert np.array_equal(np.sort(np.concatenate([train, held])), np.arange(150))
    again = holdout_split(150, 0.2, seed=3)
    assert np.array_equal(again[1], held)
    assert not np.array_equal(holdout_split(150, 0.2, seed=4)[1], held)
    assert len(holdout_split(27, 5)[1]) == 5
    for bad in (0.0, -1.0, 1.5, 27.0, float("nan"), 0.001):
        with pytest.raises(ValueError):
            holdout_split(27, bad)


@pytest.mark.parametrize("kind", list(MACHINES))
def test_holdout_noise_free_validates_exactly(kind, cli, tmp_path):
    """Exact data and a complete model: the calibrated geometry predicts the rows it never saw
    exactly, while the machine file's geometry misses them by the simulated errors."""
    machine, noise = MACHINES[kind]
    assert cli("simulate", machine, "--seed", "5", *noise, "-o", "data.csv").returncode == 0
    (tmp_path / "rep").mkdir()
    proc = cli("calibrate", machine, "data.csv", "-o", "cal.yaml", "--holdout", "0.2",
               "--seed", "2", "--report", "rep")
    assert proc.returncode == 0, proc.stderr
    assert "held-out" in proc.stdout
    report = json.loads((tmp_path / "cal.json").read_text())
    v = report["validation"]
    n_rows = len((tmp_path / "data.csv").read_text().strip().splitlines()) - 1
    assert v["held_out"] == len(v["rows"]) == round(0.2 * n_rows)
    assert report["measurements"] == n_rows - v["held_out"]
    assert set(v["rows"]) <= set(range(2, n_rows + 2))          # file line numbers
    # micrometres for the residual kinds, the file length unit (mm) for pose errors
    tiny = 1e-3 if v["unit"] == "um" else 1e-6
    assert v["after_rms"] < tiny and v["before_rms"] > 1000 * tiny
    assert "Held-out validation" in (tmp_path / "rep" / "report.html").read_text()


def test_holdout_with_noise_is_honest(cli, tmp_path):
    """With noise the held-out RMS is above the calibration rows' own (which the fit made
    small), but of the same order: no overfitting of 54 parameters to 120 poses."""
    machine = MACHINES["hexaslide"][0]
    assert cli("simulate", machine, "--seed", "6", "--noise", "1um", "-o", "d.csv").returncode == 0
    proc = cli("calibrate", machine, "d.csv", "-o", "cal.yaml", "--holdout", "30", "--json")
    assert proc.returncode == 0, proc.stderr
    v = json.loads(proc.stdout)["validation"]
    assert 1.0 < v["held_out_over_calibration"] < 2.0
    assert v["after_rms"] < 1e-3 * v["before_rms"]
    # the same seed holds out the same rows
    proc = cli("calibrate", machine, "d.csv", "-o", "cal2.yaml", "--holdout", "30", "--json")
    assert json.loads(proc.stdout)["validation"]["rows"] == v["rows"]


def test_holdout_bad_values(cli, tmp_path):
    machine = MACHINES["hexaslide"][0]
    assert cli("simulate", machine, "--poses", "40", "-o", "d.csv").returncode == 0
    for value in ("0", "abc", "1.5", "100%", "-3"):
        assert_input_error(cli("calibrate", machine, "d.csv", "-o", "c.yaml",
                               f"--holdout={value}"), "--holdout")
    assert_input_error(cli("calibrate", machine, "d.csv", "-o", "c.yaml", "--holdout", "40"),
                       "d.csv", "none to calibrate on")
    assert not (tmp_path / "c.yaml").exists()


def test_quiet_may_follow_the_command():
    assert _hoist_quiet(["simulate", "default", "-q", "-o", "x.csv"]) == \
        ["--quiet", "simulate", "default", "-o", "x.csv"]
    assert _hoist_quiet(["-q", "simulate", "default"]) == ["-q", "simulate", "default"]
    assert _hoist_quiet(["montecarlo", "default", "-q"]) == ["montecarlo", "default", "-q"]
    assert _hoist_quiet(["fk", "default", "--", "-q"]) == ["fk", "default", "--", "-q"]
