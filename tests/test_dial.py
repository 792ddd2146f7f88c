"""The dial indicator (issue 38's third proof): one module and one registry line, its model's
derivatives against central differences, its closed-form start, known-parameter recovery from
three mountings fitted together, its CSV files through the command line, and its own option
(``--dial-point``), which reaches its model and the command line through the registry."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, run
from pkmcal.calibration import calibrate
from pkmcal.instruments.dial import DialModel, dial_data
from pkmcal.instruments.registry import instrument
from pkmcal.io import load_machine
from pkmcal.kinematics import matrix_from_rotvec
from pkmcal.machines.reach import sample_workspace_poses

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _state(model, values):
    state = model.initial()
    state.values[:] = values
    return state


@pytest.mark.parametrize("with_point", [True, False])
def test_derivatives_match_central_differences(with_point):
    rng = np.random.default_rng(1)
    K = 7
    P = rng.normal(size=(K, 3)) * 0.1
    R = matrix_from_rotvec(rng.normal(size=(K, 3)) * 0.2)
    model = DialModel(direction=(0.3, 0.2, 1.0), with_point=with_point)
    values = np.array([0.05, -0.03, 0.01, 0.02, -0.01, 0.03])[:len(model.parameters)]
    state = _state(model, values)
    measured = rng.normal(size=(K, 1)) * 0.01
    e, de_dpose, de_dv = model.residuals(state, P, R, measured, np.zeros(K, int))
    h = 1e-7

    def res(v, P_, R_):
        return model.residuals(_state(model, v), P_, R_, measured, None, False)[0][:, 0]

    for j in range(len(values)):
        step = np.eye(len(values))[j] * h
        fd = (res(values + step, P, R) - res(values - step, P, R)) / (2 * h)
        assert np.max(np.abs(fd - de_dv[:, 0, j])) <= 1e-6 * np.max(np.abs(fd)), j
    for j in range(6):
        dP, w = np.zeros(3), np.zeros(3)
        (dP if j < 3 else w)[j % 3] = h
        fd = (res(values, P + dP, matrix_from_rotvec(w) @ R)
              - res(values, P - dP, matrix_from_rotvec(-w) @ R)) / (2 * h)
        scale = max(np.max(np.abs(fd)), 1e-3)
        assert np.max(np.abs(fd - de_dpose[:, 0, j])) <= 1e-6 * scale, j


def test_closed_form_start_recovers_direction_and_zero():
    rng = np.random.default_rng(2)
    P = rng.uniform(-0.1, 0.1, (20, 3))
    R = np.broadcast_to(np.eye(3), (20, 3, 3))
    d = np.array([0.2, -0.4, 0.9])
    d /= np.linalg.norm(d)
    readings = P @ d + 0.0123
    start = DialModel(with_point=False).start(P, R, readings[:, None], np.zeros(20, int))
    assert np.allclose(start.direction0, d, atol=1e-12)
    assert start.parameters.values[2] == pytest.approx(0.0123, abs=1e-12)
    with pytest.raises(Exception, match="at least 4"):
        DialModel().start(P[:3], R[:3], readings[:3, None], np.zeros(3, int))


def _mountings(machine, true, n, rng, noise=0.0):
    """Three dials (tilted x, y and z) on the true machine at poses the nominal commands."""
    P, R = sample_workspace_poses(machine, n, rng)
    q = machine.ik(P, R)
    fk = true.fk(q, start=(P, R))
    assert fk.converged.all()
    out = []
    for i, d in enumerate(([1.0, 0.05, -0.02], [0.03, 1.0, 0.04], [-0.02, 0.01, 1.0])):
        model = DialModel(direction=d, with_point=machine.rotates)
        values = np.zeros(len(model.parameters))
        values[2] = 0.01 * (i + 1)
        if machine.rotates:
            values[3:6] = [0.004, -0.003, 0.002]
        r = model.predict(_state(model, values), fk.P, fk.R, np.zeros(n, int))[:, 0]
        r = r + noise * rng.standard_normal(n)
        out.append(dial_data(q, r, source=f"dial{i + 1}"))
    return out


@pytest.mark.parametrize("spec", ["delta_default.yaml", "hexaslide_default.yaml"])
def test_three_mountings_fitted_together_recover_the_true_machine(spec):
    """Known-parameter recovery, in what the data see: exact readings of the true machine,
    calibrated together, predict held-out readings exactly, where the nominal model misses by
    micrometres or more."""
    machine = load_machine(EXAMPLES / spec)
    rng = np.random.default_rng(5)
    du = 0.5e-3 * rng.uniform(-1, 1, len(machine.parameters)) * ~machine.parameters.fixed
    true = machine.with_parameters(machine.u + du)
    data = _mountings(machine, true, 60, rng)
    cal = calibrate(machine, data, holdout=0.25, seed=1, noise={i: "0.01um" for i in range(3)})
    for f in cal.report["files"]:
        assert f["measurement"] == "dial"
        held = f["validation"]
        assert held["before_rms"] > 1.0                         # um: the nominal misses
        assert held["after_rms"] < 1e-3 * held["before_rms"], held


def test_noisy_readings_are_weighed_at_their_noise():
    machine = load_machine(EXAMPLES / "delta_default.yaml")
    rng = np.random.default_rng(6)
    du = 0.3e-3 * rng.uniform(-1, 1, len(machine.parameters)) * ~machine.parameters.fixed
    data = _mountings(machine, machine.with_parameters(machine.u + du), 80, rng, noise=2e-6)
    cal = calibrate(machine, data)
    scale = cal.report["residuals"]["noise_scale"]
    assert 0.7 < scale < 1.3, scale                            # the 2 um the dials had


def test_csv_files_through_the_command_line(tmp_path):
    spec = EXAMPLES / "delta_default.yaml"
    proc = run("simulate", spec, "--scenario", "dial", "-o", "dial.csv", "--seed", "3",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    header = (tmp_path / "dial.csv").read_text().splitlines()[0].split(",")
    assert "dial_mm" in header
    proc = run("calibrate", spec, "dial.csv", "-o", "cal.yaml", "--json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert '"measurement": "dial"' in proc.stdout
    lines = (tmp_path / "dial.csv").read_text().splitlines()
    cells = lines[3].split(",")
    cells[header.index("dial_mm")] = "abc"
    lines[3] = ",".join(cells)
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    proc = run("calibrate", spec, "bad.csv", "-o", "bad.yaml", cwd=tmp_path)
    assert_input_error(proc, "bad.csv", "dial_mm")
    assert not (tmp_path / "bad.yaml").exists()


def test_the_dial_is_one_module_and_one_registry_line():
    """The third proof of issue 38: named in its module and the registry's list only."""
    from test_structure import _code_mentions

    mentions = _code_mentions({"DialModel", "dial_data", "instruments.dial", "Dial"})
    assert set(mentions) == {"instruments/dial.py"}, mentions
    from pkmcal.instruments.registry import INSTRUMENT_MODULES

    assert "dial" in INSTRUMENT_MODULES
    assert instrument("dial-indicator").name == "dial"


def _dial_files(machine, true, n, rng):
    """Three dials (tilted x, y and z) touching the platform origin of the true machine."""
    P, R = sample_workspace_poses(machine, n, rng)
    q = machine.ik(P, R)
    fk = true.fk(q, start=(P, R))
    out = []
    for i, d in enumerate(([1.0, 0.05, -0.02], [0.03, 1.0, 0.04], [-0.02, 0.01, 1.0])):
        model = DialModel(direction=d, with_point=False)
        state = model.initial()
        state.values[2] = 0.01 * (i + 1)
        r = model.predict(state, fk.P, fk.R, np.zeros(n, int))[:, 0]
        out.append(dial_data(q, r, source=f"dial{i + 1}"))
    return out


def test_the_dial_point_option_reaches_the_dial_model():
    """``--dial-point origin`` (the dial's own option, declared in its module) holds the
    touched point: three unknowns fewer per mounting on a platform that rotates, and the true
    machine is recovered where the dial touches the platform origin."""
    machine = load_machine(EXAMPLES / "hexaslide_default.yaml")
    rng = np.random.default_rng(7)
    du = 0.3e-3 * rng.uniform(-1, 1, len(machine.parameters)) * ~machine.parameters.fixed
    data = _dial_files(machine, machine.with_parameters(machine.u + du), 50, rng)
    noise = {i: "0.01um" for i in range(3)}
    held = calibrate(machine, data, noise=noise, holdout=0.2, seed=1, touched_point="origin")
    free = calibrate(machine, data, noise=noise)
    points = [n for n in held.result.parameters.names if n.endswith("point.x")]
    assert points == [], points
    assert len([n for n in free.result.parameters.names if n.endswith("point.x")]) == 3
    for f in held.report["files"]:
        v = f["validation"]
        assert v["after_rms"] < 1e-3 * v["before_rms"], v


def test_the_dial_option_through_the_command_line(tmp_path):
    spec = EXAMPLES / "delta_default.yaml"
    proc = run("simulate", spec, "--scenario", "dial", "-o", "dial.csv", "--seed", "3",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = run("calibrate", spec, "dial.csv", "-o", "cal.yaml", "--dial-point", "origin",
               "--json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert_input_error(run("calibrate", spec, "dial.csv", "-o", "x.yaml", "--dial-point",
                           "tip", cwd=tmp_path), "--dial-point tip", "auto or origin")
    assert_input_error(run("calibrate", spec, "dial.csv", "-o", "x.yaml", "--two-step",
                           cwd=tmp_path), "--two-step: applies to tracker data",
                       "dial.csv has dial readings")
    assert_input_error(run("calibrate", spec, "dial.csv", "-o", "x.yaml", "--dial-point",
                           "origin", "--dial-point", "auto", cwd=tmp_path),
                       "--dial-point: given more than once")
    assert not (tmp_path / "x.yaml").exists()
