"""The planning and Monte Carlo workflows called from Python, without the CLI (issue 38 item
3): ``pkmcal.workflows.planning.select_poses`` / ``identifiability`` and
``pkmcal.workflows.montecarlo.montecarlo`` read the user's files, write theirs all or none and
return a :class:`~pkmcal.report.summary.Summary` that says what the CLI prints."""

import csv
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from pkmcal.errors import InputError
from pkmcal.instruments.registry import instrument
from pkmcal.io import load_machine, read_table
from pkmcal.report.summary import RawText, Summary, SummaryTable
from pkmcal.units import format_number, format_um
from pkmcal.workflows.montecarlo import OUTPUT_FILES, montecarlo, parse_vary
from pkmcal.workflows.planning import identifiability, select_poses
from pkmcal.workflows.poses import read_poses_of

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
DELTA = str(EXAMPLES / "delta_default.yaml")


def _json(summary: Summary) -> dict:
    """The JSON report a ``json_output`` summary holds as its one raw block."""
    (block,) = summary.blocks
    assert isinstance(block, RawText)
    return json.loads(block.text)


def _rows(table: SummaryTable) -> dict:
    """A label / value table as a dict (the last row of a label wins)."""
    return {row[0]: row[1] for row in table.rows}


class Recorder:
    """The progress protocol, recording what it was told."""

    def __init__(self):
        self.tasks = []

    def __call__(self, description, total):
        task = SimpleNamespace(description=description, total=total, done=0)
        self.tasks.append(task)

        def advance(n=1, description=None):
            task.done += n

        return advance


UNIT = {"mm": 1e-3, "deg": np.pi / 180}


@pytest.mark.parametrize("spec,options,group", [
    (DELTA, {"scenario": "distance", "setups": 2}, "setup"),
    (str(EXAMPLES / "cubic_6upu.yaml"), {"scenario": "tracker", "targets": 2}, "target"),
])
def test_a_selected_plan_reads_back_and_identifiability_predicts_what_select_poses_said(
        tmp_path, spec, options, group):
    """select-poses writes the chosen poses with the joints that reach them and the group of
    each (a ballbar's two mountings, a tracker's two targets); identifiability of that file,
    read back, predicts the same accuracy and rank as select-poses reported for the poses it
    held in memory."""
    plan = tmp_path / "plan.csv"
    progress = Recorder()
    selected = select_poses(spec, plan, 40, candidates=200, random_sets=3, seed=3,
                            json_output=True, progress=progress, **options)
    assert selected.exit_code == 0 and selected.warnings == []
    chosen = _json(selected)
    assert chosen["command"] == "select-poses" and chosen["output"] == str(plan)
    assert chosen["measurement"] == options["scenario"] and chosen["selected"] == 40
    assert [(t.description, t.total) for t in progress.tasks] == [
        ("select-poses: candidate poses", 5)]
    assert progress.tasks[0].done >= 1

    machine = load_machine(spec)
    P, R, rows = read_poses_of(plan, machine)
    header, table = read_table(plan)
    col = {name: np.array([fields[k] for _, fields in table], dtype=float)
           for k, name in enumerate(header)}
    assert len(P) == 40 and list(rows) == list(range(2, 42))
    assert set(col[group]) == {1.0, 2.0}                  # both mountings / targets planned
    joints = [name for name in header if name.startswith("q")]
    assert len(joints) == machine.n_joints
    q = np.column_stack([col[name] * UNIT[name.split("_")[1]] for name in joints])
    q_ik = machine.ik(P, R)
    assert np.allclose(q, q_ik, rtol=0, atol=1e-9 * np.abs(q_ik).max())

    # the same seed: the same sample of the workspace the accuracy is predicted over
    again = _json(identifiability(spec, plan, planned=True, seed=3, json_output=True,
                                  **options))
    assert again["planned"] and again["data_file"] == str(plan)
    for key in ("identifiable", "weakly_identifiable", "max_std"):
        assert again[key] == chosen[key]
    for key in ("position_rms_um", "position_max_um"):
        assert again["predicted_accuracy"][key] == pytest.approx(
            chosen["predicted_accuracy"][key], rel=1e-6)
    # the observability indices of the same plan, per measured row in both (O1 was sqrt(rows)
    # apart: select-poses divided by no row count)
    for key in ("O1", "O2", "O3", "O4", "O5"):
        assert again["observability"][key] == pytest.approx(chosen["observability"][key],
                                                            rel=1e-6), key


def test_identifiability_summary_table_says_what_its_json_holds():
    """The tables of identifiability (no JSON) carry the figures of its JSON report: the
    predicted RMS and max position error, the rank and the correlated pairs."""
    table = identifiability(DELTA, poses=30, seed=1)
    report = _json(identifiability(DELTA, poses=30, seed=1, json_output=True))
    head = table.blocks[0]
    assert isinstance(head, SummaryTable) and not head.header
    assert head.title.startswith(f"pkmcal identifiability: {DELTA} with ")
    rows = _rows(head)
    assert rows["measurement"].startswith(instrument("tracker").measurement_words)
    assert f"{report['identifiable']} of" in rows["identifiable"]
    section = report["predicted_accuracy"]
    assert (f"position {format_um(section['position_rms_um'], 3)} RMS, "
            f"{format_um(section['position_max_um'], 3)} max") in rows["predicted accuracy"]
    if report["correlated"]:
        pairs = table.blocks[1]
        assert len(pairs.rows) == min(10, len(report["correlated"])) + \
            (len(report["correlated"]) > 10)
    else:
        assert table.blocks[1] == "no parameter pair correlated beyond 0.9 (identifiable part)"


def test_identifiability_refuses_planned_without_a_plan_and_writes_no_map(tmp_path):
    with pytest.raises(InputError, match="--planned: give the plan file"):
        identifiability(DELTA, planned=True, map_path=tmp_path / "m.png")
    assert list(tmp_path.iterdir()) == []


def test_montecarlo_writes_its_files_and_its_summary_states_their_statistics(tmp_path):
    out = tmp_path / "mc"
    progress = Recorder()
    summary = montecarlo("default", "noise=1,2um", out, runs=2, seed=5, workers=1,
                         progress=progress)
    assert summary.exit_code == 0 and summary.errors == []
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES)
    assert [(t.description, t.total, t.done) for t in progress.tasks] == [
        ("calibrations", 4, 4)]

    report = json.loads((out / "summary.json").read_text())
    assert report["values"] == [1.0, 2.0] and report["seed"] == 5
    with open(out / "runs.csv", newline="") as f:
        runs = list(csv.DictReader(f))
    assert len(runs) == 4
    head, stats = (b for b in summary.blocks if isinstance(b, SummaryTable))
    assert head.title == "pkmcal montecarlo"
    assert _rows(head)["runs"].startswith("2 per value x 2 values, seed 5; in-process")
    assert [row[0] for row in stats.rows] == ["1", "2"]
    for i, (row, p) in enumerate(zip(stats.rows, report["summary"], strict=True)):
        mine = [float(r["position_mean_um"]) for r in runs
                if int(r["value_index"]) == i and r["status"] == "ok"]
        assert row[1] == f"{len(mine)}/2" == f"{p['ok']}/{p['runs']}"
        assert p["position_mean"]["mean"] == pytest.approx(np.mean(mine), rel=1e-12)
        assert row[3].startswith(format_number(p["position_mean"]["mean"]) + " +/- ")
        assert row[4] == format_number(np.median(mine), 4)
    assert summary.blocks[-1] == "wrote " + ", ".join(str(out / n) for n in OUTPUT_FILES)

    # the same seed gives the same runs
    montecarlo("default", "noise=1,2um", tmp_path / "again", runs=2, seed=5, workers=1)
    assert (tmp_path / "again" / "runs.csv").read_text() == (out / "runs.csv").read_text()


def test_montecarlo_bad_input_is_named_and_writes_nothing(tmp_path):
    out = tmp_path / "mc"
    with pytest.raises(InputError, match="--vary noise: expected comma-separated values"):
        montecarlo("default", "noise=", out, runs=2, workers=1)
    with pytest.raises(InputError, match="--estimate-lc: applies to"):
        montecarlo("default", "noise=1um", out, runs=2, workers=1, scenario="tracker",
                   estimate_lc=True)
    assert not out.exists()
    assert parse_vary("noise=0.1,1,10um") == ("noise", pytest.approx([1e-7, 1e-6, 1e-5]))


def test_montecarlo_without_an_ok_run_is_an_error_with_exit_code_1(monkeypatch, tmp_path):
    """Every run not converged: the files are still written (the statuses are the answer),
    a warning names the value and the summary's error says there are no statistics."""

    def never(self, run):
        res = SimpleNamespace(success=False, x=np.zeros(3), nit=7, dof=50,
                              message="maximum number of iterations reached",
                              residual_variance=1.0, residuals=np.ones(50))
        return res, {"position_mean": 1e-6, "position_max": 2e-6, "orientation_mean": 1e-6,
                     "orientation_max": 2e-6}

    monkeypatch.setattr(type(instrument("constraint-link")), "montecarlo_run", never)
    summary = montecarlo("default", "noise=1um", tmp_path / "mc", runs=2, workers=1)
    assert summary.exit_code == 1
    assert len(summary.errors) == 1 and summary.errors[0].startswith(
        "no run ok (converged and accepted) at noise 1 um")
    assert len(summary.warnings) == 1 and "2 of 2 runs not ok (2 not converged" in \
        summary.warnings[0]
    assert (tmp_path / "mc" / "summary.csv").exists()
