"""Seed 000's own methods on any geometry (issue 27, items 1 and 2).

``--method ik`` and ``--method fk`` start from the maximum-likelihood estimate (the paper's
methods converge only from a start close to the machine; the ml method's global start finds
one on any geometry) and their geometry is tested like an ml fit, every reading noisy, the
poses refitted: a geometry the readings reject is refused, never returned with success.

The study in full is ``benchmarks/paper_methods.py`` (50 random Hexa Slides, 250 poses,
noise-free: 50 / 50 ok for each method, none wrong); ``make test`` runs a few of its runs,
``make studies`` all of them.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from clitools import run
from pkmcal.calibration import calibrate_constraint_link
from pkmcal.errors import ConvergenceError
from pkmcal.estimation.acceptance import MAX_NOISE_FACTOR
from pkmcal.instruments.constraint_link import PAPER_METHOD_START, simulate_constraint_link
from pkmcal.io import write_constraint_link

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "paper_methods.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("paper_methods_bench", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _issue_machine(bench):
    """The issue's own Hexa Slide: rails from radius 520 mm at z = -450 mm, 65 deg, struts
    500 mm, link 340 mm (platform radius 130 mm, pairs +/- 20 deg, joints +/- 40 deg)."""
    return bench.GS.hexaslide(0.52, -0.45, 65.0, 0.50, 0.34, 0.13, 20.0, 40.0)


@pytest.mark.parametrize("method", ["ik", "fk"])
def test_the_paper_methods_land_on_the_truth_on_the_issue_machine(bench, method):
    """Before: 'did not converge (100 iterations)' for ik, 'degenerate (only 40 of 49)' for fk
    on this machine with Table 1 errors."""
    nominal = _issue_machine(bench)
    rng = np.random.default_rng(3)
    true = nominal.with_parameters(nominal.u + bench.GS.table1_sized(nominal, rng, False))
    true.constraint_link_length = nominal.constraint_link_length
    data = simulate_constraint_link(true, 150, 0.0, rng=rng)
    res = calibrate_constraint_link(nominal, data, method=method)
    assert res.success, res.message
    assert res.sections["constraint_link"].start_from == PAPER_METHOD_START
    Pw, Rw = bench._workspace(true)
    dp, _, ok, _ = bench.pose_errors(true, res.machine, Pw, Rw)
    assert ok.all() and dp.max() <= bench.TOLERANCE
    test = res.residual_test
    assert test.passed and test.dof == 150 - res.rank


# seeds of benchmarks/paper_methods.py: 16 is the geometry where the ml start itself kept a
# wrong plain fit (the fit of all rows from an exact subset geometry said "stuck" at rounding)
@pytest.mark.parametrize("seed", [5, 7, 16])
def test_random_geometries_where_the_paper_methods_failed(bench, seed):
    """Runs of the study that failed before (ik and fk 1-8 mm off, refused, or 0.3 mm off
    with success): both land on the truth now."""
    for method in ("ik", "fk"):
        row = bench.one_run(seed, method, poses=250)
        assert row["status"] == "ok", row


@pytest.mark.study
def test_the_paper_methods_study_50_geometries(bench):
    """The issue's Done-when: on 50 random non-default Hexa Slides with Table-1-sized errors
    and 250 poses, noise-free, ik and fk each land on the truth (<= 1e-8 m) in at least 49
    and never return a wrong geometry with success."""
    rows = [bench.one_run(seed, method) for seed in range(50) for method in ("ik", "fk")]
    s = bench.summary(rows)
    for method in ("ik", "fk"):
        assert s[method]["wrong"] == 0, [r for r in rows if r["status"] == "wrong"]
        assert s[method]["ok"] >= 49, s


def test_a_geometry_the_readings_reject_is_refused_with_exit_1(bench, tmp_path):
    """Noise far beyond the assumed one: the ml method estimates it (and says so); the
    paper's methods estimate no noise, so their test fails at the assumed noise and the
    command refuses (exit 1, one line, nothing written) instead of returning a geometry the
    readings reject."""
    from pkmcal.machines import default_hexaslide, paper_table1_deviations

    nominal = default_hexaslide()
    true = nominal.with_parameters(nominal.u + paper_table1_deviations(nominal.parameters))
    true.constraint_link_length = nominal.constraint_link_length
    data = simulate_constraint_link(true, 120, 8e-6, rng=4)
    with pytest.raises(ConvergenceError, match="readings reject"):
        calibrate_constraint_link(nominal, data, method="ik", sigma_m=1e-6)
    path = tmp_path / "link.csv"
    write_constraint_link(path, data, nominal)
    out = tmp_path / "cal.yaml"
    proc = run("calibrate", "default", str(path), "-o", str(out), "--method", "fk",
               "--noise", "1um", cwd=tmp_path)
    assert proc.returncode == 1, proc.stderr
    assert "readings reject" in proc.stderr and "--noise" in proc.stderr
    assert not out.exists() and not out.with_suffix(".json").exists()
    # told the noise, the same method accepts: its test is the ml fit's, at that noise
    proc = run("calibrate", "default", str(path), "-o", str(out), "--method", "fk",
               "--noise", "8um", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["start"] == PAPER_METHOD_START
    residuals = report["acceptance"]["residuals"]
    assert residuals["noise_ratio"] < MAX_NOISE_FACTOR and residuals["verdict"] == "passed"


def test_rows_the_method_itself_cannot_solve_are_reported_left_out(monkeypatch):
    """A row whose forward kinematics fail even from the ml estimate's poses is left out by
    the fk problem: it is named among the dropped rows and in a warning, beside those the ml
    start left out (before, the start's list replaced the method's)."""
    from pkmcal.instruments.constraint_link import problems as cl
    from pkmcal.machines import default_hexaslide, paper_table1_deviations

    nominal = default_hexaslide()
    true = nominal.with_parameters(nominal.u + paper_table1_deviations(nominal.parameters))
    true.constraint_link_length = nominal.constraint_link_length
    data = simulate_constraint_link(true, 80, 0.0, rng=2)
    keep = cl._ImplicitPoseProblem._keep_solved_rows

    def failing_row_3(self, fk):
        fk.converged = fk.converged.copy()
        fk.converged[3] = False
        return keep(self, fk)

    monkeypatch.setattr(cl._ImplicitPoseProblem, "_keep_solved_rows", failing_row_3)
    res = calibrate_constraint_link(nominal, data, method="fk")
    assert res.success
    dropped = res.sections["constraint_link"].dropped_rows
    assert int(data.rows[3]) in set(np.asarray(dropped).tolist())
    assert any("fk method finds no pose" in w and str(int(data.rows[3])) in w
               for w in res.sections["constraint_link"].warnings)
