"""The pose-selection policy and the identifiability analysis from Python (issue 25): the
library functions behind ``pkmcal select-poses`` and ``pkmcal identifiability`` give what the
commands print, and a Python user reaches the standard-plan fallback."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from pkmcal.calibration.run import json_safe
from pkmcal.io import load_machine
from pkmcal.planning import (
    NO_WORSE_RTOL,
    assess_identifiability,
    criterion_value,
    noise_model,
    select_plan,
)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
DELTA = EXAMPLES / "delta_default.yaml"


def _same(a, b, key):
    if isinstance(a, dict):
        assert set(a) == set(b), key
        for k in a:
            _same(a[k], b[k], f"{key}.{k}")
    elif isinstance(a, float):
        assert a == pytest.approx(b, rel=1e-12), key
    else:
        assert a == b, key


def test_select_plan_is_what_select_poses_writes(cli, tmp_path):
    machine = load_machine(DELTA)
    sel = select_plan(machine, None, 27, candidates=200, random_sets=5, seed=2)
    proc = cli("select-poses", str(DELTA), "-n", "27", "--candidates", "200",
               "--random-sets", "5", "--seed", "2", "--json", "-o", "plan.csv")
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    lib = json_safe(sel.as_dict())
    for key in ("measurement", "candidates", "selected", "criterion", "exchanges",
                "identifiable", "weakly_identifiable", "selected_plan", "standard_plan"):
        _same(report[key], lib[key], key)
    with open(tmp_path / "plan.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["candidate"]) for r in rows] == sel.candidate.tolist()
    assert np.allclose([[float(r[f"{c}_mm"]) for c in "xyz"] for r in rows], sel.P * 1e3,
                       atol=1e-6)


def test_select_plan_is_never_worse_than_the_standard_plan():
    """The policy a Python user reaches: the standard plan's poses are candidates and a
    start, and the result is no worse by the criterion nor by the predicted error."""
    machine = load_machine(DELTA)
    sel = select_plan(machine, "tracker", 27, candidates=60, criterion="a", seed=1)
    assert sel.standard.available and sel.standard_poses == 27 and sel.standard_start
    assert sel.value <= sel.standard_value + NO_WORSE_RTOL * max(abs(sel.standard_value), 1)
    assert sel.position_rms <= sel.standard_position_rms * (1 + NO_WORSE_RTOL)
    assert sel.value == pytest.approx(criterion_value(sel.information, "a"))
    assert sel.note is None or "standard plan" in sel.note
    assert sel.P.shape == (27, 3) and sel.q.shape == (27, machine.n_joints)


def test_select_plan_without_a_standard_plan_of_that_size_says_why():
    machine = load_machine(DELTA)
    sel = select_plan(machine, "tracker", 20, candidates=100, seed=0)
    assert not sel.standard.available and sel.standard_poses == 0
    assert "27" in sel.standard.reason and not sel.standard_start
    assert sel.as_dict()["standard_plan"]["available"] is False


def test_assess_identifiability_is_what_identifiability_prints(cli):
    machine = load_machine(DELTA)
    result = assess_identifiability(machine)
    proc = cli("identifiability", str(DELTA), "--json")
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["planned"] is result.planned is True
    assert report["measurement"] == result.scenario == "tracker"
    assert report["measurements"] == result.measurements == 27
    assert report["identifiable"] == result.report.identifiable
    assert np.allclose(report["singular_values"], result.report.singular_values)
    assert report["predicted_accuracy"]["position_rms_um"] == pytest.approx(
        result.prediction["position_rms_um"])
    assert "3x3x3 grid" in result.source


def test_noise_model_asks_the_instrument():
    machine = load_machine(DELTA)
    assert noise_model("constraint-link", "2um") == pytest.approx(2e-6)
    assert noise_model("distance", "3um", machine=machine).sigma == pytest.approx(3e-6)
    assert noise_model("probe", None, machine=machine).sigma == pytest.approx(10e-6)
    with pytest.raises(Exception, match="--pose-noise applies to full-pose"):
        noise_model("tracker", None, "1mm,1mrad", machine)
