"""Every figure of the planning section of docs/integrator.md ("Before measuring: what will the
plan identify, how accurate will it be?", the README's until issue 26) is what the tool
computes (issue 12 item 5).

The figures are parsed from the page, so it cannot drift from the tool: the
``select-poses`` block is compared row by row with the command's console output, the Delta
sentence with ``select-poses --json`` on the default and a 120-degree Delta, and the Monte-Carlo
ratios with 300 noisy calibrations at the standard plans' poses.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DELTA = ROOT / "examples" / "delta_default.yaml"
#: relative tolerance of a README figure (printed to 3 significant digits; other BLAS builds
#: may end the exchanges elsewhere)
RTOL = 0.05
#: Monte-Carlo ratios: the runs are seeded, so the figure is reproduced closely
MC_RTOL = 0.02
NUMBER = re.compile(r"(?<![\w.])-?\d+(?:\.\d+)?")


def _section() -> str:
    text = (ROOT / "docs" / "integrator.md").read_text(encoding="utf-8")
    start = text.index("## Before measuring: what will the plan identify")
    return text[start:text.index("\n## ", start + 10)]


def _prose() -> str:
    """The section without its code blocks, on one line."""
    return " ".join(re.sub(r"```.*?```", " ", _section(), flags=re.S).split())


def _rows(text: str) -> dict[str, str]:
    """``label -> text`` of a console table (``label │ text`` and continuation lines)."""
    rows: dict[str, str] = {}
    label = None
    for line in text.splitlines():
        if "│" not in line:
            continue
        head, _, tail = line.partition("│")
        if head.strip():
            label = head.strip()
            rows[label] = tail.strip()
        elif label is not None:
            rows[label] += " " + tail.strip()
    return rows


def _numbers(text: str) -> list[float]:
    return [float(x) for x in NUMBER.findall(text)]


def _figure(pattern: str, count: int) -> list[float]:
    match = re.search(pattern, _prose())
    assert match, f"README planning section: no sentence matching {pattern!r}"
    values = [float(v) for v in match.groups()]
    assert len(values) == count
    return values


def test_select_poses_block_is_the_tools_output(cli, tmp_path):
    """The README block of ``select-poses default -n 150 --noise 2um`` against the command's
    console output, row by row: the same numbers within RTOL."""
    blocks = re.findall(r"```text\n(pkmcal select-poses: default\n.*?)```", _section(), re.S)
    assert len(blocks) == 1, "README: the select-poses block of the default Hexa Slide"
    readme = _rows(blocks[0])
    proc = cli("select-poses", "default", "-n", "150", "--noise", "2um", "-o", "plan.csv",
               "--map", "plan.png", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    tool = _rows(proc.stdout)
    for label in ("selected", "predicted accuracy", "standard plan", "random sets",
                  "criterion"):
        assert label in readme, f"README block: no row {label!r}"
    for label, text in readme.items():
        assert label in tool, f"README row {label!r} is not in the output"
        want, got = _numbers(text), _numbers(tool[label])
        assert len(want) == len(got), (label, text, tool[label])
        for w, g in zip(want, got, strict=True):
            assert g == pytest.approx(w, rel=RTOL, abs=1e-12), (label, text, tool[label])


def _delta120(tmp_path) -> Path:
    path = tmp_path / "delta120.yaml"
    text = DELTA.read_text(encoding="utf-8")
    assert "leg_angles: [90.0, 180.0, -90.0]" in text
    path.write_text(text.replace("leg_angles: [90.0, 180.0, -90.0]",
                                 "leg_angles: [0.0, 120.0, 240.0]"), encoding="utf-8")
    return path


def test_delta_figures(cli, tmp_path):
    """The Delta sentence: the chosen 27 points, seed 001's 3x3x3 grid (the standard plan; the
    same figure as ``identifiability`` without data) and the median random 27 points, on the
    default and on a 120-degree Delta."""
    default = _figure(r"On the default Delta \(`examples/delta_default\.yaml -n 27`[^)]*\) the "
                      r"chosen points predict ([\d.]+) um, against ([\d.]+) um for seed 001's "
                      r"3x3x3 grid and ([\d.]+) um for the median random 27 points", 3)
    d120 = _figure(r"on a 120-degree Delta \(the same file with `leg_angles: \[0, 120, 240\]`\)"
                   r" ([\d.]+) um, against ([\d.]+) um for the grid and ([\d.]+) um for the "
                   r"median random 27 points", 3)
    for machine, (chosen, grid, median) in ((DELTA, default), (_delta120(tmp_path), d120)):
        proc = cli("select-poses", machine, "-n", "27", "--json", "-o", tmp_path / "p.csv")
        assert proc.returncode == 0, proc.stderr
        rep = json.loads(proc.stdout)
        assert "3x3x3 grid" in rep["standard_plan"]["name"]
        assert rep["predicted_accuracy"]["position_rms_um"] == pytest.approx(chosen, rel=RTOL)
        assert rep["standard_plan"]["position_rms_um"] == pytest.approx(grid, rel=RTOL)
        assert rep["random_sets"]["position_rms_median_um"] == pytest.approx(median, rel=RTOL)
        proc = cli("identifiability", machine, "--json")
        assert proc.returncode == 0, proc.stderr
        pa = json.loads(proc.stdout)["predicted_accuracy"]
        assert pa["position_rms_um"] == pytest.approx(grid, rel=RTOL)
    # the old figure the tool contradicted is gone
    assert "38 um" not in _section()


def _mc_constraint_link(runs: int):
    """Measured / predicted RMS position and orientation error: the default Hexa Slide, its
    standard plan (150 poses), 2 um encoder noise, maximum-likelihood calibrations."""
    from pkmcal.analysis.accuracy import machine_workspace, pose_errors
    from pkmcal.analysis.prediction import pose_error_operator, predict_pose_accuracy
    from pkmcal.calibration import calibrate_constraint_link
    from pkmcal.instruments.constraint_link import ConstraintLinkData
    from pkmcal.machines import default_hexaslide
    from pkmcal.planning import design_from_problem, planned_problem, standard_plan

    machine = default_hexaslide()
    sigma = 2e-6
    plan = standard_plan(machine, "constraint-link", 150, seed=0)
    problem = planned_problem(machine, "constraint-link", plan.P, plan.R, sigma)
    design = design_from_problem(problem)
    Pw, Rw = machine_workspace(machine, 500, 0)
    op = pose_error_operator(machine, design, Pw, Rw, problem.n_machine)
    pred = predict_pose_accuracy(machine, design, Pw, Rw, n_machine=problem.n_machine,
                                 op=op).summary()
    rng = np.random.default_rng(1)
    q0 = problem.data.q
    dp, dr = [], []
    for _ in range(runs):
        data = ConstraintLinkData(q0 + sigma * rng.standard_normal(q0.shape),
                                  machine.constraint_link_length, problem.data.passive)
        res = calibrate_constraint_link(machine, data, sigma_m=sigma)
        assert res.success
        e_p, e_r, ok, _ = pose_errors(machine, res.machine, Pw, Rw)
        assert ok.all()
        dp.append(e_p)
        dr.append(e_r)
    return (np.sqrt(np.mean(np.square(dp))) / pred["position"]["rms"],
            np.sqrt(np.mean(np.square(dr))) / pred["orientation"]["rms"])


def _mc_tracker(runs: int, rng=2):
    """Measured / predicted RMS position error: the default Delta, seed 001's 3x3x3 grid, the
    default tracker noise, joint calibrations."""
    from pkmcal.analysis.accuracy import machine_workspace
    from pkmcal.analysis.prediction import pose_error_operator, predict_pose_accuracy
    from pkmcal.calibration import calibrate_tracker
    from pkmcal.instruments.tracker import TrackerNoise
    from pkmcal.io import load_machine
    from pkmcal.planning import design_from_problem, planned_data, planned_problem, standard_plan

    machine = load_machine(DELTA)
    noise = TrackerNoise()
    plan = standard_plan(machine, "tracker", 27)
    problem = planned_problem(machine, "tracker", plan.P, plan.R, noise)
    design = design_from_problem(problem)
    Pw, Rw = machine_workspace(machine, 500, 0)
    op = pose_error_operator(machine, design, Pw, Rw, problem.n_machine)
    pred = predict_pose_accuracy(machine, design, Pw, Rw, n_machine=problem.n_machine,
                                 op=op).summary()
    rng = np.random.default_rng(rng)
    qw = machine.ik(Pw)
    errs = []
    for _ in range(runs):
        data = planned_data(machine, "tracker", plan.P, plan.R)
        data.m = data.m + noise.sample(data.m, rng)
        res = calibrate_tracker(machine, data, noise)
        assert res.success
        dx = res.machine.fk(qw).P - Pw
        errs.append(np.linalg.norm(op.align(dx), axis=-1))
    return np.sqrt(np.mean(np.square(errs))) / pred["position"]["rms"]


@pytest.mark.study      # a study's figure (make studies): hundreds of runs
def test_monte_carlo_figures():
    """300 noisy calibrations at the standard plans' poses: measured / predicted RMS errors as
    the README states them (and near 1: the prediction is the Cramer-Rao bound)."""
    pos, ori, delta = _figure(
        r"300 noisy calibrations at the standard plan's poses: measured / predicted RMS "
        r"position error ([\d.]+), orientation ([\d.]+) on the default Hexa Slide with 2 um "
        r"encoder noise; ([\d.]+) on the default Delta with the 3x3x3 grid", 3)
    got_pos, got_ori = _mc_constraint_link(300)
    assert got_pos == pytest.approx(pos, rel=MC_RTOL)
    assert got_ori == pytest.approx(ori, rel=MC_RTOL)
    assert _mc_tracker(300) == pytest.approx(delta, rel=MC_RTOL)
    for ratio in (pos, ori, delta):
        assert ratio == pytest.approx(1.0, abs=0.1)
