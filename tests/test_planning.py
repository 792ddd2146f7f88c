"""Measurement planning (SPEC 3, issue 5 items 1-3): planned problems, predicted accuracy
(Cramer-Rao) against Monte Carlo, pose selection against random sets, and the commands
``pkmcal identifiability`` (planned) and ``pkmcal select-poses``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, digest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
FILES = {"hexaslide": EXAMPLES / "hexaslide_default.yaml",
         "delta": EXAMPLES / "delta_default.yaml",
         "stewart": EXAMPLES / "cubic_6upu.yaml"}


def _machine(kind):
    from pkmcal.io import load_machine

    return load_machine(FILES[kind])


def _other_hexaslide():
    """Not the default: other rail directions and lengths, another link length."""
    from pkmcal.machines import default_hexaslide

    m = default_hexaslide()
    p = m.parameters
    u = p.values.copy()
    rng = np.random.default_rng(11)
    for i in range(6):
        u[p.index(f"chain{i + 1}.beta")] = np.deg2rad(62.0) + rng.uniform(-0.02, 0.02)
        u[p.index(f"chain{i + 1}.l")] = rng.uniform(0.49, 0.52)
    other = m.with_parameters(u)
    other.constraint_link_length = 0.26
    other._home = None
    return other


def _setup(machine, n_candidates, noise=None, seed=1):
    from pkmcal.analysis.accuracy import machine_workspace
    from pkmcal.analysis.prediction import pose_error_operator
    from pkmcal.planning import (
        candidate_poses,
        design_from_problem,
        planned_problem,
        scenario_for,
    )

    kind = scenario_for(machine)
    P, R = candidate_poses(machine, kind, n_candidates, rng=seed)
    problem = planned_problem(machine, kind, P, R, noise)
    design = design_from_problem(problem)
    Pw, Rw = machine_workspace(machine, n=200, rng=seed + 1)
    op = pose_error_operator(machine, design, Pw, Rw, problem.n_machine)
    return P, R, problem, design, op


# -- the design: information per measurement ---------------------------------------------------

@pytest.mark.parametrize("kind,rows,rank", [("hexaslide", 1, 48), ("delta", 3, 21),
                                            ("stewart", 6, 48)])
def test_design_information_is_the_fisher_information(kind, rows, rank):
    from pkmcal.calibration import reduce_local

    _, _, problem, design, _ = _setup(_machine(kind), 80)
    # one row per constraint-link pose (6 readings - 5 pose unknowns), 3 per tracker point,
    # 6 per full pose (the frames are global)
    assert design.F.shape == (80, rows, rank)
    r, Jg, Jl = problem.evaluate(problem.initial_state())
    free = problem.parameters.free
    Jr, _, _ = reduce_local(r, Jg[..., free] * problem.scales[free], Jl)
    V = design.V
    assert np.allclose(V.T @ V, np.eye(rank), atol=1e-12)
    np.testing.assert_allclose(design.information(), V.T @ Jr.T @ Jr @ V,
                               rtol=1e-9, atol=1e-9 * np.abs(Jr).max() ** 2)
    # the null basis completes V and the data do not see it
    assert design.null.shape[1] == free.sum() - rank
    assert np.abs(Jr @ design.null).max() < 1e-6 * np.abs(Jr).max()


@pytest.mark.parametrize("criterion", ["d", "a", "pose"])
def test_rank_updates_match_direct_evaluation(criterion):
    """The vectorised gains of adding or removing a measurement equal the change of the
    criterion computed from scratch."""
    from pkmcal.planning.design import _gains, criterion_value

    rng = np.random.default_rng(0)
    p, r = 7, 2
    F = rng.standard_normal((12, r, p))
    base = rng.standard_normal((30, p))
    M = base.T @ base
    B = rng.standard_normal((p, p))
    A = B @ B.T
    Minv = np.linalg.inv(M)
    add = _gains(F, Minv, criterion, A, +1.0)
    rem = _gains(F, Minv, criterion, A, -1.0)
    c0 = criterion_value(M, criterion, A)
    for k in range(len(F)):
        up = criterion_value(M + F[k].T @ F[k], criterion, A)
        down = criterion_value(M - F[k].T @ F[k], criterion, A)
        assert add[k] == pytest.approx(c0 - up, rel=1e-8, abs=1e-10)
        if np.isfinite(down):
            assert rem[k] == pytest.approx(c0 - down, rel=1e-8, abs=1e-10)


# -- predicted accuracy -----------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["hexaslide", "delta", "stewart"])
def test_pose_sensitivity_matches_finite_differences(kind):
    """dx/du at fixed joints against central differences of the forward kinematics."""
    from pkmcal.analysis.prediction import pose_sensitivity
    from pkmcal.kinematics import rotvec_from_matrix

    machine = _machine(kind)
    P, R, *_ = _setup(machine, 5)
    if machine.pose_dof == 3:
        R = np.broadcast_to(np.eye(3), R.shape)
    S = pose_sensitivity(machine, P, R)
    q = machine.ik(P, R)
    u0 = machine.u
    scales = machine.parameter_scales()
    for j in range(0, len(u0), 5):
        h = 1e-6 * scales[j]
        out = []
        for sgn in (+1, -1):
            u = u0.copy()
            u[j] += sgn * h
            fk = machine.with_parameters(u).fk(q, start=(P, R))
            assert fk.converged.all()
            dpos = fk.P - P
            drot = rotvec_from_matrix(fk.R @ np.swapaxes(R, -1, -2))   # base axes
            out.append(np.concatenate([dpos, drot], -1)[:, :machine.pose_dof])
        fd = (out[0] - out[1]) / (2 * h)
        np.testing.assert_allclose(S[..., j], fd, atol=1e-6 * np.abs(S).max(), rtol=1e-5)


def test_alignment_removes_frame_motions_only():
    from pkmcal.analysis.prediction import align_out, frame_motions
    from pkmcal.kinematics import matrix_from_euler

    rng = np.random.default_rng(4)
    P = rng.standard_normal((20, 3))
    R = matrix_from_euler(rng.uniform(-0.3, 0.3, (20, 3)))
    Fm = frame_motions(P, R)                          # (20, 6, 12)
    w = rng.standard_normal((12, 3))
    E = Fm @ w                                        # pure frame motions
    assert np.abs(align_out(E, Fm)).max() < 1e-12
    # a pose change that is no frame motion keeps a part; aligning twice changes nothing
    X = rng.standard_normal((20, 6, 2))
    once = align_out(X, Fm[..., :3])
    assert np.linalg.norm(once) > 0.5 * np.linalg.norm(X)
    np.testing.assert_allclose(align_out(once, Fm[..., :3]), once, atol=1e-12)


def test_prediction_agrees_with_monte_carlo_constraint_link():
    """Cramer-Rao predicted pose errors vs 60 maximum-likelihood calibrations of noisy
    readings at the same planned poses (gauge-aligned pose errors, SPEC 5)."""
    from pkmcal.analysis.accuracy import pose_errors
    from pkmcal.analysis.prediction import predict_pose_accuracy
    from pkmcal.calibration import calibrate_constraint_link
    from pkmcal.instruments.constraint_link import ConstraintLinkData

    machine = _other_hexaslide()
    sigma = 1e-6
    P, R, problem, design, op = _setup(machine, 120, noise=sigma, seed=7)
    pred = predict_pose_accuracy(machine, design, op.P, op.R, n_machine=problem.n_machine)
    s = pred.summary()
    assert s["unbounded"] == 0
    rng = np.random.default_rng(8)
    q0 = problem.data.q
    dp, dr = [], []
    for _ in range(60):
        data = ConstraintLinkData(q0 + sigma * rng.standard_normal(q0.shape),
                                  machine.constraint_link_length, problem.data.passive)
        res = calibrate_constraint_link(machine, data, sigma_m=sigma)
        assert res.success
        e_p, e_r, ok, _ = pose_errors(machine, res.machine, op.P, op.R)
        assert ok.all()
        dp.append(e_p)
        dr.append(e_r)
    mc_p, mc_r = np.sqrt(np.mean(np.square(dp))), np.sqrt(np.mean(np.square(dr)))
    assert mc_p / s["position"]["rms"] == pytest.approx(1.0, abs=0.15)
    assert mc_r / s["orientation"]["rms"] == pytest.approx(1.0, abs=0.15)
    # and pose by pose: the map has the right shape
    per_pose = np.sqrt(np.mean(np.square(dp), axis=0))
    assert np.corrcoef(per_pose, pred.position)[0, 1] > 0.9


def test_prediction_agrees_with_monte_carlo_tracker():
    from pkmcal.analysis.prediction import predict_pose_accuracy
    from pkmcal.calibration import calibrate_tracker
    from pkmcal.instruments.tracker import TrackerNoise
    from pkmcal.planning import planned_data

    machine = _machine("delta")
    noise = TrackerNoise()
    P, R, problem, design, op = _setup(machine, 27, noise=noise, seed=3)
    pred = predict_pose_accuracy(machine, design, op.P, op.R, n_machine=problem.n_machine)
    rng = np.random.default_rng(5)
    qw = machine.ik(op.P)
    errs = []
    for _ in range(100):
        data = planned_data(machine, "tracker", P, R)
        data.m = data.m + noise.sample(data.m, rng)
        res = calibrate_tracker(machine, data, noise)
        assert res.success
        dx = res.machine.fk(qw).P - op.P
        errs.append(np.linalg.norm(op.align(dx), axis=-1))
    ratio = np.sqrt(np.mean(np.square(errs))) / pred.summary()["position"]["rms"]
    assert ratio == pytest.approx(1.0, abs=0.15)


def test_a_plan_blind_to_a_pose_moving_direction_is_unbounded():
    """Ten constraint-link poses cannot identify 48 directions: the prediction says
    unbounded instead of hiding the blind directions in the gauge alignment."""
    from pkmcal.analysis.prediction import predict_pose_accuracy

    machine = _machine("hexaslide")
    _, _, problem, design, op = _setup(machine, 10)
    assert design.rank == 10
    assert op.unbounded > 0
    pred = predict_pose_accuracy(machine, design, op.P, op.R, n_machine=problem.n_machine)
    assert np.isinf(pred.position).all()


# -- pose selection -----------------------------------------------------------------------------

def test_selection_beats_random_sets_on_the_default_hexaslide():
    """Issue 5 target: predicted RMS pose error at least 2x lower than the median random set
    of equal N (150 poses, the default Hexa Slide)."""
    from pkmcal.planning import criterion_value, random_values, select_poses

    _, _, _, design, op = _setup(_machine("hexaslide"), 1500, noise=2e-6)
    A = op.A
    random_rms = np.sqrt(random_values(design, 150, 60, "pose", A, rng=2))
    for criterion in ("d", "pose"):
        sel = select_poses(design, 150, criterion, A=A)
        assert len(set(sel.index.tolist())) == 150
        rms = np.sqrt(criterion_value(design.information(sel.index), "pose", A))
        assert np.median(random_rms) / rms >= 2.0, criterion
        # the selected set is also better than every random one by its own criterion
        own = criterion_value(design.information(sel.index), criterion, A)
        rand = random_values(design, 150, 20, criterion, A, rng=3)
        assert own < rand.min()


@pytest.mark.parametrize("which", ["other-hexaslide", "delta", "stewart"])
def test_selection_beats_random_sets_elsewhere(which):
    from pkmcal.planning import (
        DEFAULT_PLAN_SIZE,
        criterion_value,
        random_values,
        scenario_for,
        select_poses,
    )

    machine = _other_hexaslide() if which == "other-hexaslide" else _machine(which)
    _, _, problem, design, op = _setup(machine, 600)
    n = 60 if which == "other-hexaslide" else DEFAULT_PLAN_SIZE[scenario_for(machine)]
    sel = select_poses(design, n, "d")
    rms = np.sqrt(criterion_value(design.information(sel.index), "pose", op.A))
    median = np.median(np.sqrt(random_values(design, n, 40, "pose", op.A, rng=1)))
    assert median / rms > 1.3


def test_planned_and_measured_identifiability_agree(tmp_path):
    """A plan gives the identifiability of the noise-free measurements at its poses."""
    from pkmcal.identifiability import identifiability_report
    from pkmcal.planning import planned_problem

    machine = _machine("hexaslide")
    P, R, problem, *_ = _setup(machine, 60)
    rep = identifiability_report(problem)
    assert rep.identifiable == 48
    assert [d.name for d in rep.unidentifiable] == [
        "rotation of the base frame about O", "re-orientation of the platform frame about P"]
    # a hand-made plan rounded to 1 um lands on the sphere; 1 mm off is refused
    rounded = planned_problem(machine, "constraint-link", np.round(P, 6), R)
    assert identifiability_report(rounded).identifiable == 48
    from pkmcal.errors import InputError

    with pytest.raises(InputError, match="constraint-link length"):
        planned_problem(machine, "constraint-link", P * 1.004, R)


# -- command line -------------------------------------------------------------------------------

def test_cli_identifiability_of_random_plan(cli, tmp_path):
    proc = cli("identifiability", "default", "--poses", "60", "--noise", "2um", "--json",
               "--map", tmp_path / "map.png")
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["planned"] and rep["measurements"] == 60 and rep["identifiable"] == 48
    pa = rep["predicted_accuracy"]
    assert pa["unbounded_directions"] == 0
    assert 0 < pa["position_rms_um"] <= pa["position_max_um"]
    assert "2 um" in pa["noise"]
    assert (tmp_path / "map.png").stat().st_size > 10_000
    # the prediction scales with the noise
    proc1 = cli("identifiability", "default", "--poses", "60", "--noise", "1um", "--json")
    pa1 = json.loads(proc1.stdout)["predicted_accuracy"]
    assert pa["position_rms_um"] / pa1["position_rms_um"] == pytest.approx(2.0, rel=1e-6)


@pytest.mark.parametrize("kind", ["hexaslide", "delta", "stewart"])
def test_cli_select_poses_then_identifiability_of_the_plan(kind, cli, tmp_path):
    plan = tmp_path / "plan.csv"
    n = {"hexaslide": "60", "delta": "12", "stewart": "20"}[kind]
    proc = cli("select-poses", FILES[kind], "-n", n, "--candidates", "400", "--random-sets",
               "30", "--json", "-o", plan)
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["selected"] == int(n) and rep["candidates"] == 400
    assert rep["random_sets"]["ratio_median_to_selected"] > 1.0
    header = plan.read_text().splitlines()[0].split(",")
    assert header[:3] == ["x_mm", "y_mm", "z_mm"] and "candidate" in header
    assert any(h.startswith("q1_") for h in header)
    assert len(plan.read_text().splitlines()) == int(n) + 1
    before = digest(plan)
    proc = cli("identifiability", FILES[kind], plan, "--planned", "--json")
    assert proc.returncode == 0, proc.stderr
    again = json.loads(proc.stdout)
    assert again["predicted_accuracy"]["position_rms_um"] == pytest.approx(
        rep["predicted_accuracy"]["position_rms_um"], rel=1e-3)
    assert digest(plan) == before
    # the joint values of the plan are what `pkmcal ik` gives for its poses
    ik = tmp_path / "ik.csv"
    assert cli("ik", FILES[kind], plan, "-o", ik).returncode == 0
    q_plan = np.genfromtxt(plan, delimiter=",", names=True)
    q_ik = np.genfromtxt(ik, delimiter=",", names=True)
    for name in q_ik.dtype.names:
        np.testing.assert_allclose(q_plan[name], q_ik[name], rtol=1e-9, atol=1e-9)


def test_cli_select_poses_summary_and_map(cli, tmp_path):
    proc = cli("select-poses", "default", "-n", "60", "--candidates", "300", "--criterion",
               "pose", "--map", tmp_path / "m.png", "-o", tmp_path / "p.csv")
    assert proc.returncode == 0, proc.stderr
    out = " ".join(proc.stdout.split())
    assert "60 of 300 candidate poses by criterion pose" in out
    assert "random sets" in out and "predicted accuracy" in out
    assert (tmp_path / "m.png").exists()


def test_cli_planning_bad_input(cli, tmp_path):
    plan = tmp_path / "plan.csv"
    assert_input_error(cli("identifiability", "default", "--planned"), "--planned")
    assert_input_error(cli("identifiability", "default", "--poses", "0"), "--poses")
    assert_input_error(cli("identifiability", "default", "--pose-noise", "1um,1urad"),
                       "--pose-noise")
    assert_input_error(cli("identifiability", "default", "--noise", "-1um"), "--noise")
    # a plan off the constraint sphere names the row (file line numbers, header = 1)
    plan.write_text("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n0,0,300,0,0,0\n0,0,310,0,0,0\n")
    assert_input_error(cli("identifiability", "default", plan, "--planned"), "row(s) 3",
                       "plan.csv")
    # an unreachable candidate
    far = tmp_path / "far.csv"
    far.write_text("x_mm,y_mm,z_mm\n0,0,-750\n0,0,-2000\n")
    assert_input_error(cli("select-poses", FILES["delta"], "-n", "1", "--from", far, "-o",
                           tmp_path / "o.csv"), "far.csv", "row(s) 3")
    assert not (tmp_path / "o.csv").exists()
    assert_input_error(cli("select-poses", "default", "-n", "40", "-o", tmp_path / "o.csv"),
                       "at least 48")
    assert_input_error(cli("select-poses", "default", "-n", "50", "--candidates", "20", "-o",
                           tmp_path / "o.csv"), "--candidates")
    # -n is required: a usage error (exit 2) naming it
    proc = cli("select-poses", "default", "-o", tmp_path / "o.csv")
    assert proc.returncode == 2 and "'-n'" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "o.csv").exists()


def test_cli_select_poses_within_joint_limits(cli, tmp_path):
    plan = tmp_path / "plan.csv"
    proc = cli("select-poses", "default", "-n", "60", "--candidates", "600", "--joint-range",
               "250mm,450mm", "--random-sets", "10", "--json", "-o", plan)
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["outside_joint_range"] > 0
    assert rep["candidates"] + rep["outside_joint_range"] == 600
    data = np.genfromtxt(plan, delimiter=",", names=True)
    q = np.array([data[f"q{i}_mm"] for i in range(1, 7)])
    assert q.min() >= 250 and q.max() <= 450
    assert_input_error(cli("select-poses", "default", "-n", "60", "--joint-range",
                           "450mm,250mm", "-o", plan), "--joint-range")
    assert_input_error(cli("select-poses", "default", "-n", "60", "--joint-range",
                           "300mm,301mm", "-o", tmp_path / "x.csv"), "within --joint-range")
