"""Joint limits in machine files (issue 12 item 7): ``joint_limits: {min, max}`` in the file's
units of the joint values, honoured by ik, compensate, select-poses and simulate."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, run
from pkmcal.errors import InputError
from pkmcal.instruments.constraint_link import sample_sphere_poses
from pkmcal.instruments.pose import sample_platform_poses
from pkmcal.io import load_machine, parse_machine, save_machine
from pkmcal.io.machine_file import machine_to_text

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
HEXASLIDE = (EXAMPLES / "hexaslide_default.yaml").read_text()
DELTA = (EXAMPLES / "delta_default.yaml").read_text()
STEWART = (EXAMPLES / "jugglebot.yaml").read_text()


def with_limits(text: str, limits: str) -> str:
    """A machine file's text with a ``joint_limits`` line before ``home`` (or at the end)."""
    line = f"joint_limits: {limits}\n"
    if "\nhome:" in text:
        return text.replace("\nhome:", "\n" + line + "home:", 1)
    return text + line


def write(tmp_path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def column(path, name) -> np.ndarray:
    with open(path, newline="") as f:
        return np.array([float(r[name]) for r in csv.DictReader(f)])


# -- the file ------------------------------------------------------------------------------


def test_single_pair_and_lists_are_read_in_the_files_units():
    m = parse_machine(with_limits(HEXASLIDE, "{min: 250, max: 420}"))
    lo, hi = m.joint_limits
    assert np.allclose(lo, 0.25) and np.allclose(hi, 0.42) and lo.shape == (6,)
    d = parse_machine(with_limits(DELTA, "{min: [-20, -30, -40], max: [60, 70, 80]}"))
    assert np.allclose(np.degrees(d.joint_limits[0]), [-20, -30, -40])
    assert np.allclose(np.degrees(d.joint_limits[1]), [60, 70, 80])
    s = parse_machine(with_limits(STEWART, "{min: -0.6, max: 0.6}"))
    assert np.allclose(s.joint_limits[1], 0.6)          # revolutions are kept as read
    assert parse_machine(HEXASLIDE).joint_limits is None


def test_limits_are_saved_back(tmp_path):
    m = parse_machine(with_limits(DELTA, "{min: [-20, -30, -40], max: 60}"))
    text = machine_to_text(m)
    assert "joint_limits: {min: [-20.0, -30.0, -40.0], max: 60.0}" in text
    back = parse_machine(text)
    for a, b in zip(back.joint_limits, m.joint_limits, strict=True):
        assert np.allclose(a, b, rtol=1e-14, atol=0)
    # in other units: the same limits
    in_m = parse_machine(machine_to_text(m, units={"length": "m", "angle": "rad"}))
    assert np.allclose(in_m.joint_limits[0], m.joint_limits[0], rtol=1e-14)
    saved = save_machine(m.with_parameters(m.u), tmp_path / "copy.yaml")
    assert np.allclose(load_machine(saved).joint_limits[1], m.joint_limits[1])


@pytest.mark.parametrize("limits, words", [
    ("{min: 400, max: 100}", ["joint_limits.min", "q1: min 400 mm must be below max 100 mm"]),
    ("{min: [0, 0, 0, 500, 0, 0], max: 420}", ["joint_limits.min[3]", "q4: min 500 mm"]),
    ("{min: [0, 0, 0], max: 420}", ["joint_limits.min", "expected one number or a list of 6"]),
    ("{min: 0}", ["joint_limits", "missing key max"]),
    ("{min: 0, max: 400, stop: 3}", ["joint_limits.stop", "unknown key"]),
    ("{min: 0, max: abc}", ["joint_limits.max", "not a number"]),
    ("{min: [0, 0, 0, 0, 0, .nan], max: 400}", ["joint_limits.min[5]", "finite"]),
    ("[0, 400]", ["joint_limits", "expected a mapping"]),
])
def test_bad_limits_are_refused_with_the_key_path(limits, words):
    with pytest.raises(InputError) as exc:
        parse_machine(with_limits(HEXASLIDE, limits), "m.yaml")
    message = str(exc.value)
    assert message.startswith("m.yaml: ")
    assert "(line " in message
    for w in words:
        assert w in message, message


def test_machine_methods():
    m = parse_machine(with_limits(HEXASLIDE, "{min: 250, max: 420}"))
    q = np.array([[0.3] * 6, [0.3, 0.43, 0.3, 0.3, 0.3, 0.2], [np.nan] * 6])
    assert m.within_limits(q).tolist() == [True, False, False]
    assert m.limit_violations(q)[1].tolist() == [False, True, False, False, False, True]
    text = m.limit_violation_text(q, rows=[2, 3, 4])
    assert text == "row 3: q2 = 430 mm above max 420 mm, q6 = 200 mm below min 250 mm"
    assert m.joint_limits_text() == "q1..q6 within 250..420 mm"
    free = parse_machine(HEXASLIDE)
    assert free.within_limits(q).tolist() == [True, True, False]


# -- samplers (simulate, candidates) ---------------------------------------------------------


def test_samplers_draw_within_the_limits():
    m = parse_machine(with_limits(HEXASLIDE, "{min: 300, max: 380}"))
    P, R = sample_sphere_poses(m, m.constraint_link_length, 100, rng=1)
    q = m.ik(P, R)
    assert q.min() >= 0.3 and q.max() <= 0.38
    s = parse_machine(with_limits(STEWART, "{min: -0.3, max: 0.4}"))
    P, R = sample_platform_poses(s, 50, rng=2)
    q = s.ik(P, R)
    assert q.min() >= -0.3 and q.max() <= 0.4


def test_no_pose_within_the_limits_is_said_so():
    m = parse_machine(with_limits(HEXASLIDE, "{min: 500, max: 600}"), "far.yaml")
    with pytest.raises(InputError) as exc:
        sample_sphere_poses(m, m.constraint_link_length, 20, rng=0)
    message = str(exc.value)
    assert "far.yaml: no pose within the joint limits (q1..q6 within 500..600 mm)" in message
    assert "joint values at home (q1 = 351.224" in message


# -- commands --------------------------------------------------------------------------------

TARGETS = ("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n0,0,300,0,0,0\n10,0,300,0,0,0\n"
           "0,0,380,0,0,0\n0,0,250,0,0,0\n")


def test_ik_refuses_targets_outside_naming_rows_and_joints(tmp_path):
    machine = write(tmp_path, "m.yaml", with_limits(HEXASLIDE, "{min: 0, max: 400}"))
    write(tmp_path, "t.csv", TARGETS)
    proc = run("ik", "m.yaml", "t.csv", "-o", "j.csv", cwd=tmp_path)
    assert_input_error(proc, "t.csv: 1 pose(s) need joint values outside the joint limits of "
                       "m.yaml (q1..q6 within 0..400 mm): row 4: q1 = 420.398 mm above max "
                       "400 mm")
    assert not (tmp_path / "j.csv").exists()
    ok = write(tmp_path, "ok.csv", "\n".join(TARGETS.splitlines()[:3]) + "\n")
    assert run("ik", machine, ok, "-o", "j.csv", cwd=tmp_path).returncode == 0
    assert column(tmp_path / "j.csv", "q1_mm").max() <= 400


def test_compensate_refuses_targets_outside(tmp_path):
    write(tmp_path, "m.yaml", with_limits(HEXASLIDE, "{min: 320, max: 360}"))
    write(tmp_path, "t.csv", TARGETS)
    proc = run("compensate", "m.yaml", "t.csv", "-o", "c.csv", cwd=tmp_path)
    assert_input_error(proc, "t.csv: 2 target(s) need joint values outside the joint limits of "
                       "m.yaml (q1..q6 within 320..360 mm): row 4: q1 = 420.398 mm above max "
                       "360 mm", "; row 5: q1 = 308.919 mm below min 320 mm")
    assert not (tmp_path / "c.csv").exists()


def test_delta_ik_names_the_arm(tmp_path):
    write(tmp_path, "d.yaml", with_limits(DELTA, "{min: [-40, -40, -40], max: [60, 60, 5]}"))
    # a point on the -y side lifts arm 3 (leg at -90 deg) to 8.2 deg
    write(tmp_path, "p.csv", "x_mm,y_mm,z_mm\n0,0,-750\n0,-150,-700\n")
    proc = run("ik", "d.yaml", "p.csv", "-o", "a.csv", cwd=tmp_path)
    assert_input_error(proc, "p.csv: 1 pose(s) need joint values outside the joint limits of "
                       "d.yaml (q1 within -40..60 deg, q2 within -40..60 deg, q3 within -40..5 "
                       "deg): row 3: q3 = 8.21321 deg above max 5 deg")
    assert not (tmp_path / "a.csv").exists()


def test_simulate_stays_within_the_limits(tmp_path):
    machine = write(tmp_path, "m.yaml", with_limits(HEXASLIDE, "{min: 300, max: 380}"))
    proc = run("simulate", machine, "--poses", "80", "--truth", "true.yaml", "-o", "d.csv",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    q = np.column_stack([column(tmp_path / "d.csv", f"q{j}_mm") for j in range(1, 7)])
    assert q.min() >= 300 - 0.01 and q.max() <= 380 + 0.01      # 2 um encoder noise
    assert "joint_limits: {min: 300.0, max: 380.0}" in (tmp_path / "true.yaml").read_text()
    stewart = write(tmp_path, "s.yaml", with_limits(STEWART, "{min: -0.4, max: 0.5}"))
    proc = run("simulate", stewart, "--poses", "40", "--noise", "0", "--pose-noise", "0,0",
               "-o", "p.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    q = np.column_stack([column(tmp_path / "p.csv", f"q{j}_rev") for j in range(1, 7)])
    assert q.min() >= -0.4 and q.max() <= 0.5


def test_simulate_says_when_no_pose_fits(tmp_path):
    write(tmp_path, "m.yaml", with_limits(HEXASLIDE, "{min: 500, max: 600}"))
    proc = run("simulate", "m.yaml", "--poses", "20", "-o", "d.csv", cwd=tmp_path)
    assert_input_error(proc, "m.yaml: no pose within the joint limits (q1..q6 within 500..600 "
                       "mm) could be drawn")
    assert not (tmp_path / "d.csv").exists()
    write(tmp_path, "d.yaml", with_limits(DELTA, "{min: -10, max: 10}"))
    proc = run("simulate", "d.yaml", "--scenario", "tracker", "-o", "t.csv", cwd=tmp_path)
    assert_input_error(proc, "--grid 3x3x3:", "grid point(s) (rows of the data file) need "
                       "joint values outside the joint limits of d.yaml")
    assert not (tmp_path / "t.csv").exists()


def test_select_poses_keeps_within_file_limits_and_joint_range(tmp_path):
    write(tmp_path, "m.yaml", with_limits(HEXASLIDE, "{min: 250, max: 420}"))
    machine = "m.yaml"
    proc = run("select-poses", machine, "-n", "60", "--candidates", "400", "--random-sets",
               "3", "--joint-range", "0mm,400mm", "--json", "-o", "plan.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["outside_joint_range"] > 0
    assert "joint limits of m.yaml" in rep["joint_limits"] and "--joint-range" in \
        rep["joint_limits"]
    q = np.column_stack([column(tmp_path / "plan.csv", f"q{j}_mm") for j in range(1, 7)])
    assert q.min() >= 250 and q.max() <= 400
    delta = write(tmp_path, "d.yaml", with_limits(DELTA, "{min: -20, max: 60}"))
    proc = run("select-poses", delta, "-n", "27", "--random-sets", "3", "-o", "dplan.csv",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    q = np.column_stack([column(tmp_path / "dplan.csv", f"q{j}_deg") for j in range(1, 4)])
    assert q.min() >= -20 and q.max() <= 60
    # an empty intersection
    proc = run("select-poses", machine, "-n", "60", "--joint-range", "430mm,500mm", "-o",
               "x.csv", cwd=tmp_path)
    assert_input_error(proc, "--joint-range 430mm,500mm: no value of q1, q2, q3, q4, q5, q6")
    assert not (tmp_path / "x.csv").exists()


def test_calibrated_file_keeps_the_limits(tmp_path):
    write(tmp_path, "d.yaml", with_limits(DELTA, "{min: -60, max: 60}"))
    proc = run("simulate", "d.yaml", "--scenario", "tracker", "-o", "t.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = run("calibrate", "d.yaml", "t.csv", "-o", "cal.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert np.allclose(np.degrees(load_machine(tmp_path / "cal.yaml").joint_limits),
                       [[-60] * 3, [60] * 3])
    assert "joint_limits: {min: -60.0, max: 60.0}" in (tmp_path / "cal.yaml").read_text()
