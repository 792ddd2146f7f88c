"""Model adequacy and model extensions chosen by held-out data (issue 16 item 4).

- The six-leg platform's reading curvature (``L = l0 + gain r + curvature r^2``): inverse
  kinematics, every Jacobian against finite differences, forward kinematics, and machine files
  that carry it (files without it unchanged).
- The adequacy checks: trend tests, and on simulated data the leg curvature named when the
  model lacks it, no trend when the model is right.
- The cross-validated choice: adopted on data from curved legs, not on data from straight
  ones; ``calibrate(extensions="none")`` and ``--extensions none`` switch it off.

Machine: the Jugglebot design (examples/jugglebot.yaml, readings in motor revolutions, about
-1..1.6 rev around home) with random deviations; noise 20 um on the legs, 50 um / 200 urad on
the poses.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, run
from pkmcal.calibration import calibrate_full_pose
from pkmcal.calibration.adequacy import model_adequacy, trend_tests
from pkmcal.calibration.extensions import (
    choose_full_pose_extensions,
    cross_validate,
    fold_labels,
)
from pkmcal.calibration.run import calibrate
from pkmcal.errors import InputError
from pkmcal.estimation.acceptance import FAILED_ALARMING, PASSED, residual_verdict
from pkmcal.instruments.pose import FullPoseNoise, simulate_full_pose
from pkmcal.io import load_machine, machine_to_text, parse_machine
from pkmcal.io.csv_io import write_full_pose
from pkmcal.kinematics import matrix_from_rotvec
from pkmcal.machines import cubic_6upu
from pkmcal.machines.deviations import random_deviations

MACHINE = Path(__file__).resolve().parents[1] / "examples" / "jugglebot.yaml"
NOISE = FullPoseNoise(20e-6, 50e-6, 200e-6)
#: a reading curvature the data show clearly: 0.1 mm per rev^2 (0.1 mm at 1 rev from home)
CURVED = 1e-4


@pytest.fixture(scope="module")
def design():
    return load_machine(MACHINE)


def simulated(design, curvature, seed, poses=60):
    """Data of the design with random deviations and legs curved by +-``curvature``."""
    rng = np.random.default_rng(seed)
    true = design.with_parameters(design.u + random_deviations(design, rng))
    true = true.with_curvature(curvature * rng.choice([-1.0, 1.0], 6))
    return true, simulate_full_pose(true, poses, None, NOISE, rng)


# -- the reading curvature of a six-leg platform ------------------------------------------------

def curved_machine(design, seed=1):
    rng = np.random.default_rng(seed)
    m = design.with_curvature()
    u = m.u.copy()
    u[m.parameters.indices([f"leg{i + 1}.curvature" for i in range(6)])] = \
        rng.normal(0, 3e-4, 6)
    return m.with_parameters(u)


def poses_near_home(machine, K=7, seed=2):
    rng = np.random.default_rng(seed)
    P0, _ = machine.home
    return (P0 + rng.normal(0, 0.03, (K, 3)), matrix_from_rotvec(rng.normal(0, 0.08, (K, 3))))


def test_curvature_is_an_extension_that_changes_nothing_at_zero(design):
    [ext] = design.model_extensions()
    assert ext.name == "reading curvature" and len(ext.parameters) == 6
    extended = ext.apply(design)
    assert len(extended.parameters) == 54 and extended.has_curvature
    assert not design.has_curvature and len(design.parameters) == 48
    assert extended.model_extensions() == [] and extended.with_curvature() is extended
    P, R = poses_near_home(design)
    np.testing.assert_array_equal(extended.ik(P, R), design.ik(P, R))
    np.testing.assert_allclose(extended.parameter_scales()[:48], design.parameter_scales())
    # another machine offers none: the estimator and the command line need nothing else
    assert cubic_6upu().with_curvature().model_extensions() == []


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_curved_inverse_kinematics_and_every_jacobian(design, sign):
    machine = curved_machine(design)
    u = machine.u.copy()
    u[machine.parameters.indices([f"leg{i + 1}.gain" for i in range(6)])] *= sign
    machine = machine.with_parameters(u)
    P, R = poses_near_home(machine)
    r, Jx, Ju = machine.ik_jacobians(P, R)
    _, L = machine.leg_vectors(P, R)[1:]
    np.testing.assert_allclose(machine.lengths(r), L, rtol=0,
                               atol=1e-13 * float(np.max(np.abs(L))))   # metre-sized legs
    # parameters: central differences with a step relative to each parameter's scale
    steps = 1e-6 * machine.parameter_scales()
    for j, h in enumerate(steps):
        du = np.zeros(len(u))
        du[j] = h
        num = (machine.ik(P, R, u + du) - machine.ik(P, R, u - du)) / (2 * h)
        np.testing.assert_allclose(Ju[..., j], num, rtol=1e-6, atol=1e-7 * np.abs(Ju).max(),
                                   err_msg=machine.parameters.names[j])
    # pose [dP, dOmega]
    for k in range(6):
        d = np.zeros(6)
        d[k] = 1e-7
        plus = machine.ik(P + d[:3], matrix_from_rotvec(d[3:]) @ R)
        minus = machine.ik(P - d[:3], matrix_from_rotvec(-d[3:]) @ R)
        np.testing.assert_allclose(Jx[..., k], (plus - minus) / 2e-7, rtol=1e-6,
                                   atol=1e-7 * np.abs(Jx).max())


@pytest.mark.parametrize("method", ["ml", "ik"])
def test_full_pose_residual_jacobian_of_the_curvature(design, method):
    """The calibration problems' Jacobian columns of the curvature against finite
    differences (the rest is tested in test_full_pose.py)."""
    from pkmcal.calibration import FullPoseIK, FullPoseML, estimate_frames

    machine = curved_machine(design)
    data = simulate_full_pose(machine, 12, None, NOISE, 3)
    problem = {"ml": FullPoseML, "ik": FullPoseIK}[method](
        machine, data, NOISE, estimate_frames(machine, data))
    state = problem.initial_state()
    _, Jg, _ = problem.evaluate(state)
    n = len(problem.parameters)
    for name in ("leg1.curvature", "leg6.curvature", "leg3.gain"):
        j = problem.parameters.index(name)
        h = 1e-6 * machine.parameter_scales()[j]
        du = np.zeros(n)
        du[j] = h
        plus = problem.evaluate(problem.retract(state, du, np.zeros((len(data), 6))), False)[0]
        minus = problem.evaluate(problem.retract(state, -du, np.zeros((len(data), 6))),
                                 False)[0]
        np.testing.assert_allclose(Jg[..., j], (plus - minus) / (2 * h), rtol=1e-5,
                                   atol=1e-6 * np.abs(Jg[..., j]).max(), err_msg=name)


def test_curved_forward_kinematics_round_trip(design):
    machine = curved_machine(design)
    P, R = poses_near_home(machine)
    fk = machine.fk(machine.ik(P, R))
    assert fk.converged.all()
    np.testing.assert_allclose(fk.P, P, atol=1e-11)
    np.testing.assert_allclose(fk.R, R, atol=1e-11)


def test_machine_files_carry_the_curvature_and_load_it_back(design, tmp_path):
    machine = curved_machine(design)
    units = {"length": "mm", "angle": "deg"}
    text = machine_to_text(machine, units)
    assert text.count("curvature:") == 6
    back = parse_machine(text, "curved.yaml")
    assert back.has_curvature
    np.testing.assert_allclose(back.curvature(), machine.curvature(), rtol=1e-12)
    P, R = poses_near_home(machine)
    np.testing.assert_allclose(back.ik(P, R), machine.ik(P, R), rtol=1e-10, atol=1e-12)
    # in the file's units: mm per rev^2
    c0 = machine.curvature()[0] * 1e3
    assert f"curvature: {c0:.6g}"[:16] in text.replace("'", "")
    # a file without it is the linear model, written as before
    plain = machine_to_text(design, units)
    assert "curvature" not in plain and len(parse_machine(plain, "p.yaml").parameters) == 48
    assert not load_machine(MACHINE).has_curvature
    # one leg with it: the others 0
    one = MACHINE.read_text().replace("gain: 75.69197604500343}",
                                      "gain: 75.69197604500343, curvature: 0.5}")
    m = parse_machine(one, "one.yaml")
    np.testing.assert_allclose(m.curvature() * 1e3, [0.5, 0, 0, 0, 0, 0])


# -- the adequacy checks ------------------------------------------------------------------------

def test_trend_tests_find_a_parabola_and_not_noise():
    rng = np.random.default_rng(0)
    x = np.linspace(-1, 1, 80)
    t = trend_tests(0.5 * x**2 + 0.1 * rng.standard_normal(80), x)
    assert t["quadratic_p"] < 1e-10 and t["explained_quadratic"] > 0.6
    assert t["curvature"] == pytest.approx(0.5, rel=0.1)
    t = trend_tests(0.3 * x + 0.1 * rng.standard_normal(80), x)
    assert t["linear_p"] < 1e-10 and t["slope"] == pytest.approx(0.3, rel=0.1)
    ps = [trend_tests(rng.standard_normal(80), x) for _ in range(200)]
    assert 0.01 < np.mean([p["linear_p"] < 0.05 for p in ps]) < 0.12
    assert np.isnan(trend_tests(rng.standard_normal(80), np.ones(80))["linear_p"])


def test_adequacy_names_the_legs_curvature_the_model_lacks(design):
    _, data = simulated(design, CURVED, seed=4)
    result = calibrate_full_pose(design, data)
    a = model_adequacy(result, 1e-3, np.pi / 180, ("mm", "deg"))
    json.dumps(a)
    assert [g["name"] for g in a["groups"]] == ["leg readings", "measured positions",
                                                 "measured orientations"]
    assert a["far_above_noise"] and a["noise_ratio"] > 3
    assert len(a["columns"]) == 12 and a["columns"][0]["name"] == "leg readings 1"
    assert a["columns"][6]["name"] == "measured positions x"
    assert a["regressors"][:6] == [f"reading {i}" for i in range(1, 7)]
    assert {"position x", "rotation z"} <= set(a["regressors"])
    top = a["trends"][0]
    assert top["shape"] == "quadratic" and top["residual"].startswith("leg readings ")
    assert top["against"] == "reading " + top["residual"].split()[-1]     # its own reading
    assert "strongest systematic pattern" in a["verdict"] and top["residual"] in a["verdict"]


def test_adequacy_finds_nothing_when_the_model_is_right(design):
    _, data = simulated(design, 0.0, seed=5)
    result = calibrate_full_pose(design, data, noise=NOISE, estimate_noise=False)
    a = model_adequacy(result)
    assert not a["far_above_noise"] and a["significant_trends"] == 0
    verdict = residual_verdict(result)
    assert verdict.status == PASSED and a["residual_verdict"] == PASSED
    assert a["verdict"].startswith(f"residual test {verdict.sentence()}")
    assert a["noise_ratio"] == verdict.noise_ratio


def test_adequacy_of_a_method_that_takes_the_poses_as_exact(design):
    """The ik method's residuals are compared with the noise through their whole covariance
    (readings + measured poses, its residual test): the adequacy states that verdict."""
    _, data = simulated(design, CURVED, seed=4)
    result = calibrate_full_pose(design, data, method="ik")
    a = model_adequacy(result)
    verdict = residual_verdict(result)
    assert verdict.status == FAILED_ALARMING and a["far_above_noise"]
    assert a["noise_ratio"] == verdict.noise_ratio
    assert a["verdict"].startswith(f"residual test {verdict.sentence()}")
    assert a["trends"][0]["shape"] == "quadratic"


# -- the cross-validated choice -----------------------------------------------------------------

def test_folds_are_seeded_and_balanced():
    a = fold_labels(23, 5, seed=3)
    np.testing.assert_array_equal(a, fold_labels(23, 5, seed=3))
    assert sorted(np.bincount(a)) == [4, 4, 5, 5, 5]
    assert not np.array_equal(a, fold_labels(23, 5, seed=4))


@pytest.mark.parametrize("curvature, adopted", [(CURVED, True), (0.0, False)])
@pytest.mark.parametrize("method", ["ml", "ik"])
def test_cross_validation_adopts_the_curvature_only_where_the_legs_have_it(design, curvature,
                                                                          adopted, method):
    """Simulated: adopted on curved legs (0.1 mm per rev^2), not on straight ones (measured
    over 10 seeds each, ml: 10/10 and 0/10)."""
    _, data = simulated(design, curvature, seed=6)
    choice = choose_full_pose_extensions(design, data, method, NOISE)
    [trial] = choice.trials
    assert trial.adopted is adopted, choice.lines()
    assert (choice.adopted == ["reading curvature"]) is adopted
    assert choice.machine.has_curvature is adopted
    assert set(trial.figures) == {"leg_length", "position", "orientation"}
    d = choice.as_dict({"position": (1e-3, "mm")})
    json.dumps(d)
    assert d["trials"][0]["held_out_rms"]["position"]["unit"] == "mm"
    if adopted:
        assert trial.gain > trial.se > 0 and trial.loss < choice.plain_loss
        assert trial.figures["leg_length"] < choice.plain_figures["leg_length"]


def test_cross_validation_is_generic():
    """Any machine, any data: the candidates and a fit-and-predict function."""
    from pkmcal.machines.base import ModelExtension

    class Toy:
        """A polynomial with the powers ``terms``; extensions add x^2 or x^3."""

        def __init__(self, terms=(0, 1)):
            self.terms = tuple(sorted(terms))

        def model_extensions(self):
            return [ModelExtension("square", "x^2 term", ("a2",),
                                   lambda m: Toy(m.terms + (2,))),
                    ModelExtension("cube", "x^3 term", ("a3",), lambda m: Toy(m.terms + (3,)))]

    rng = np.random.default_rng(1)      # (seed 0 adopts the cube too: 1 SE lets 6 % pass)
    x = np.linspace(-1, 1, 60)
    y = 1 + x + 0.5 * x**2 + 0.05 * rng.standard_normal(60)

    def fit_and_predict(model, train, test):
        A = x[:, None] ** np.array(model.terms)
        c, *_ = np.linalg.lstsq(A[train], y[train], rcond=None)
        e = y[test] - A[test] @ c
        return e**2, {"error": e}

    choice = cross_validate(Toy(), 60, fit_and_predict)
    assert choice.adopted == ["square"] and choice.machine.terms == (0, 1, 2)
    # round 1: both tried on the line, the square adopted; round 2: the cube on top of it
    assert [(t.name, t.adopted) for t in choice.trials] == [
        ("square", True), ("cube", False), ("cube", False)]
    assert choice.trials[2].baseline == pytest.approx(choice.trials[0].loss)
    # too few rows: nothing tried, said why
    choice = cross_validate(Toy(), 12, fit_and_predict)
    assert choice.trials == [] and "too few" in choice.skipped


def test_calibrate_adopts_by_default_and_reports_it(design):
    _, data = simulated(design, CURVED, seed=7)
    cal = calibrate(design, data)
    ext = cal.report["model_extensions"]
    assert ext["adopted"] == ["reading curvature"] and ext["folds"] == 5
    assert cal.calibrated.has_curvature and len(cal.result.parameters) == 66
    assert cal.metadata["model_extensions"] == ["reading curvature"]
    rows = {p["name"]: p for p in cal.params}
    assert rows["leg1.curvature"]["unit"] == "mm/rev^2" and rows["leg1.curvature"]["nominal"] == 0
    assert "model_adequacy" in cal.report
    # the written report passes the schema `pkmcal report` checks it with
    from pkmcal.report.schema import validate_report

    doc = json.loads(cal.json_text())
    assert validate_report(doc, "cal.json") is doc
    # the HTML report shows what was tried, its held-out losses and the verdict
    from pkmcal.report.html import build_html

    html = build_html(json.loads(cal.json_text()))
    part = html[html.index("<h2>Model extensions</h2>"):]
    assert "reading curvature" in part and "<td>yes</td>" in part
    # the noise levels: the rule that decides estimated/assumed is on the capacity, shown
    levels = html[html.index("<h2>Noise levels</h2>"):html.index("<h2>Model adequacy</h2>")]
    assert "capacity [count]" in levels and "capacity, the group's redundancy" in levels
    off = calibrate(design, data, extensions="none")
    assert not off.calibrated.has_curvature and len(off.result.parameters) == 60
    assert off.report["model_extensions"]["skipped"] == "--extensions none"
    with pytest.raises(InputError, match="--extensions sometimes"):
        calibrate(design, data, extensions="sometimes")


def test_command_line_extensions_option(design, tmp_path):
    _, data = simulated(design, CURVED, seed=7, poses=40)
    write_full_pose(tmp_path / "poses.csv", data, design)
    proc = run("calibrate", MACHINE, "poses.csv", "--extensions", "none", "-o", "plain.yaml",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "model extension" not in proc.stdout and "model adequacy" in proc.stdout
    assert "curvature" not in (tmp_path / "plain.yaml").read_text()
    proc = run("calibrate", MACHINE, "poses.csv", "-o", "curved.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "reading curvature: adopted" in proc.stdout
    assert load_machine(tmp_path / "curved.yaml").has_curvature
    # compensate against the machine file the calibration started from (no curvature)
    (tmp_path / "targets.csv").write_text("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n"
                                          "0,0,560,0,0,0\n20,-10,580,2,1,0\n")
    proc = run("compensate", "curved.yaml", "targets.csv", "--nominal", MACHINE, "-o",
               "commands.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "uncompensated_position_um" in (tmp_path / "commands.csv").read_text()
    proc = run("calibrate", MACHINE, "poses.csv", "--extensions", "x", "-o", "x.yaml",
               cwd=tmp_path)
    assert_input_error(proc, "--extensions x")


def test_extensions_option_is_refused_where_the_data_take_none():
    """Data without model extensions (tracker points here) and fits of several files refuse
    ``--extensions``, as they refuse every option that does not fit them; not giving it is the
    default everywhere."""
    from pkmcal.instruments.tracker import TrackerNoise, grid_points, simulate_tracker
    from pkmcal.machines import default_delta

    delta = default_delta()
    pose = (np.eye(3), np.array([1.5, -2.0, 0.3]))
    data = simulate_tracker(delta, delta, grid_points(delta.home[0]), pose, TrackerNoise(),
                            rng=3)
    for value in ("auto", "none"):
        with pytest.raises(InputError, match="--extensions: applies to pose data"):
            calibrate(delta, data, extensions=value)
        with pytest.raises(InputError, match="--extensions: does not apply to a fit of several"):
            calibrate(delta, [data, data], extensions=value)
    assert "model_extensions" not in calibrate(delta, data).report
