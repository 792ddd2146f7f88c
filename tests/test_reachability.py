"""Reachability as a machine property (issue 28): every pose a command takes as a target or a
workspace is reachable or refused, naming the file and row (or the option), the pose and why
(which joint, by how much past its limit, in the file's units).

An independent catalogue per machine type: a linear Delta printer's carriages cannot rise
above their endstops nor its nozzle go below the bed; every machine's poses need real inverse
kinematics in home's working mode and joint values within the file's ``joint_limits``.
Reachable inputs keep giving what the machine's inverse kinematics gives.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, run
from pkmcal.io import load_machine

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
PRINTER = "linear_delta.yaml"      # mm; position_endstop 285 mm, home 100 mm above the bed
DELTA = "delta_default.yaml"       # Delta robot, home (0, 0, -750) mm
HEXASLIDE = "hexaslide_default.yaml"
STEWART = "cubic_6upu.yaml"



def assert_same_joints(got, want):
    """The joint values written equal the inverse kinematics to rounding, relative to the
    largest of them (the file holds them at full precision)."""
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())


def example(tmp_path: Path, name: str, replace: tuple[str, str] | None = None,
            extra: str = "") -> str:
    """Copy an example machine file into ``tmp_path`` (one text replaced, lines added)."""
    text = (EXAMPLES / name).read_text()
    if replace is not None:
        assert replace[0] in text
        text = text.replace(*replace)
    (tmp_path / name).write_text(text + extra)
    return name


def write(tmp_path: Path, name: str, text: str) -> str:
    (tmp_path / name).write_text(text)
    return name


def column(path: Path, name: str) -> np.ndarray:
    with open(path, newline="") as f:
        return np.array([float(r[name]) for r in csv.DictReader(f)])


def positions(text: str) -> np.ndarray:
    """The x, y, z rows of a CSV text in mm, as m."""
    rows = [line.split(",")[:3] for line in text.strip().splitlines()[1:]]
    return np.array(rows, float) * 1e-3


# -- the machine property ----------------------------------------------------------------------

def test_linear_delta_states_its_endstops_and_bed():
    m = load_machine(EXAMPLES / PRINTER)
    P = np.array([[0, 0, 0.1], [0, 0, 0.4], [0, 0, -0.003], [0, 0, 0.285], [0, 0, 0.0]])
    reach = m.reachability(P)
    assert reach.ok.tolist() == [True, False, False, True, True]
    assert reach.reasons[1].startswith("tower 1's carriage 115 mm above its endstop "
                                       "(q1 = -115 mm)")
    assert reach.reasons[2] == "the nozzle 3 mm below the bed"
    assert set(reach.reasons) == {1, 2}
    # the joint values are the inverse kinematics' own
    assert np.array_equal(reach.q, m.ik(P, np.broadcast_to(np.eye(3), (5, 3, 3))))
    assert m.within_physical_limits(P, None).tolist() == [True, False, False, True, True]


def test_a_calibrated_printers_bed_plane_is_its_floor():
    """The bed of the experiment's set-ups (``bed=``, the machine holds none) is the floor of
    the reachable poses; without it the nominal bed (z = 0) is."""
    m = load_machine(EXAMPLES / PRINTER)
    bed = (0.002, 0.001, 0.0)                   # 2 mm up, tilted along x
    P = m.targets_in_base(np.array([[0.05, 0, 0.0], [0.05, 0, -0.0001], [-0.05, 0, 0.01]]),
                          bed)
    reach = m.reachability(P, bed=bed)
    assert reach.ok.tolist() == [True, False, True]
    assert reach.reasons[1] == "the nozzle 0.1 mm below the bed"
    assert m.within_physical_limits(P, None, bed=bed).tolist() == [True, False, True]
    assert m.reachability(P).ok.tolist() == [True, True, True]       # above z = 0


@pytest.mark.parametrize("name", [DELTA, HEXASLIDE, STEWART])
def test_other_machines_have_no_limits_but_their_kinematics_and_files(name):
    m = load_machine(EXAMPLES / name)
    P0, R0 = m.home
    far = P0 + np.array([0.0, 0.0, -5.0])
    assert m.physical_limits(np.array([P0]), np.array([R0]), m.ik(P0, R0)[None]) == []
    reach = m.reachability(np.array([P0, far]), np.array([R0, R0]))
    assert reach.ok.tolist() == [True, False]
    assert reach.reasons[1]


def test_joint_limits_alone_are_marked():
    m = load_machine(EXAMPLES / HEXASLIDE)
    q0 = m.ik(*m.home)
    m.joint_limits = (np.full(6, q0.min() - 1e-3), np.full(6, q0.max() + 1e-3))
    P = np.array([m.home[0], m.home[0] + [0, 0, 0.05]])
    reach = m.reachability(P, np.array([m.home[1]] * 2))
    assert reach.ok.tolist() == [True, False] and reach.limits_only.tolist() == [False, True]
    assert "above its max" in reach.reasons[1] and "mm" in reach.reasons[1]


# -- linear Delta printer ----------------------------------------------------------------------

TARGETS = "x_mm,y_mm,z_mm\n0,0,100\n0,0,400\n30,-20,50\n"


def test_printer_compensate_refuses_a_target_above_the_endstops(tmp_path):
    m = example(tmp_path, PRINTER)
    t = write(tmp_path, "t.csv", TARGETS)
    proc = run("compensate", m, t, "-o", "c.csv", cwd=tmp_path)
    assert_input_error(proc, "t.csv: 1 target(s) cannot be reached", "row(s) 3",
                       "row 3 at (0, 0, 400) mm",
                       "tower 1's carriage 115 mm above its endstop (q1 = -115 mm)")
    assert not (tmp_path / "c.csv").exists()


def test_printer_compensate_refuses_a_target_below_the_bed(tmp_path):
    m = example(tmp_path, PRINTER)
    t = write(tmp_path, "t.csv", "x_mm,y_mm,z_mm\n0,0,0\n10,10,-2.5\n")
    proc = run("compensate", m, t, "-o", "c.csv", cwd=tmp_path)
    assert_input_error(proc, "t.csv:", "row 3 at (10, 10, -2.5) mm",
                       "the nozzle 2.5 mm below the bed")


def test_printer_compensate_refuses_targets_outside_the_joint_limits(tmp_path):
    m = example(tmp_path, PRINTER, extra="joint_limits: {min: 0, max: 250}\n")
    t = write(tmp_path, "t.csv", "x_mm,y_mm,z_mm\n0,0,100\n0,0,10\n")
    proc = run("compensate", m, t, "-o", "c.csv", cwd=tmp_path)
    assert_input_error(proc, "t.csv: 1 target(s) need joint values outside the joint limits",
                       "row 3: q1 = 275 mm above max 250 mm")


def test_printer_reachable_targets_are_the_inverse_kinematics(tmp_path):
    m = example(tmp_path, PRINTER)
    text = "x_mm,y_mm,z_mm\n0,0,100\n0,0,0\n0,0,285\n30,-20,50\n"
    t = write(tmp_path, "t.csv", text)
    proc = run("compensate", m, t, "-o", "c.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    machine = load_machine(tmp_path / m)
    P = positions(text)
    q = machine.ik(P, np.broadcast_to(np.eye(3), (len(P), 3, 3))) * 1e3
    got = np.column_stack([column(tmp_path / "c.csv", f"q{j}_mm") for j in (1, 2, 3)])
    assert_same_joints(got, q)
    assert abs(got[2]).max() <= 1e-12 * np.abs(q).max()   # at the endstops: q = 0, reachable


def test_printer_ik_refuses_poses_above_the_endstops(tmp_path):
    m = example(tmp_path, PRINTER)
    t = write(tmp_path, "t.csv", TARGETS)
    proc = run("ik", m, t, "-o", "j.csv", cwd=tmp_path)
    assert_input_error(proc, "t.csv: 1 pose(s) cannot be reached", "row 3 at (0, 0, 400) mm",
                       "above its endstop")


@pytest.mark.parametrize("command", [("export", "--to", "klipper", "-o", "k.cfg"),
                                     ("identifiability",)])
def test_printer_workspace_box_below_the_bed_is_refused(tmp_path, command):
    m = example(tmp_path, PRINTER)
    proc = run(command[0], m, *command[1:], "--workspace", "-50,50,-50,50,-10,100mm",
               cwd=tmp_path)
    assert_input_error(proc, "--workspace -50,50,-50,50,-10,100mm:",
                       "of its 500 sampled poses: out of the machine's reach",
                       "mm below the bed")
    assert not (tmp_path / "k.cfg").exists()


@pytest.mark.parametrize("command", [("export", "--to", "klipper", "-o", "k.cfg"),
                                     ("identifiability",)])
def test_printer_workspace_box_above_the_endstops_is_refused(tmp_path, command):
    m = example(tmp_path, PRINTER)
    proc = run(command[0], m, *command[1:], "--workspace", "-50,50,-50,50,1000,2000mm",
               cwd=tmp_path)
    assert_input_error(proc, "--workspace -50,50,-50,50,1000,2000mm:",
                       "500 of its 500 sampled poses", "above its endstop")


def test_printer_workspace_points_name_the_row(tmp_path):
    m = example(tmp_path, PRINTER)
    write(tmp_path, "pts.csv", "x_mm,y_mm,z_mm\n0,0,50\n0,0,300\n")
    proc = run("export", m, "--to", "klipper", "-o", "k.cfg", "--workspace", "pts.csv",
               cwd=tmp_path)
    assert_input_error(proc, "--workspace pts.csv: row(s) 3: out of the machine's reach",
                       "row 3 at (0, 0, 300) mm", "15 mm above its endstop")


def test_printer_reachable_workspace_still_works(tmp_path):
    m = example(tmp_path, PRINTER)
    proc = run("export", m, "--to", "klipper", "-o", "k.cfg", "--workspace",
               "-50,50,-50,50,0,150mm", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "k.cfg").exists()


@pytest.mark.parametrize("home, words", [("900.0", "615 mm above its endstop (q1 = -615 mm)"),
                                         ("-5.0", "the nozzle 5 mm below the bed")])
def test_printer_home_out_of_reach_is_refused_by_simulate(tmp_path, home, words):
    m = example(tmp_path, PRINTER, ("home: [0.0, 0.0, 100.0]", f"home: [0.0, 0.0, {home}]"))
    proc = run("simulate", m, "-o", "d.csv", cwd=tmp_path)
    assert_input_error(proc, f"{m}: home:", words, "(line 9)")
    assert not (tmp_path / "d.csv").exists()


def test_printer_select_poses_candidates_above_the_endstops(tmp_path):
    m = example(tmp_path, PRINTER)
    write(tmp_path, "cand.csv", "x_mm,y_mm,z_mm\n0,0,0\n10,0,0\n0,0,290\n")
    proc = run("select-poses", m, "-n", "2", "--from", "cand.csv", "-o", "p.csv",
               cwd=tmp_path)
    assert_input_error(proc, "cand.csv: 1 candidate pose(s) cannot be reached",
                       "row 4 at (0, 0, 290) mm", "5 mm above its endstop")


def test_printer_simulate_tracker_keeps_above_the_bed(tmp_path):
    m = example(tmp_path, PRINTER, ("home: [0.0, 0.0, 100.0]", "home: [0.0, 0.0, 10.0]"))
    proc = run("simulate", m, "--scenario", "tracker", "--poses", "30", "--noise", "0",
               "-o", "d.csv", "--truth", "true.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    q = np.column_stack([column(tmp_path / "d.csv", f"q{j}_mm") for j in (1, 2, 3)])
    true = load_machine(tmp_path / "true.yaml")
    P = true.fk(q * 1e-3).P
    assert P[:, 2].min() >= -1e-9 and q.min() >= 0


# -- Delta robot -------------------------------------------------------------------------------

def test_delta_compensate_names_the_unreachable_target(tmp_path):
    m = example(tmp_path, DELTA)
    t = write(tmp_path, "t.csv", "x_mm,y_mm,z_mm\n0,0,-750\n0,0,-2500\n")
    proc = run("compensate", m, t, "-o", "c.csv", cwd=tmp_path)
    assert_input_error(proc, "t.csv: 1 target(s) cannot be reached", "row 3 at (0, 0, -2500) "
                       "mm", "no real inverse kinematics (leg(s) 1, 2, 3")


def test_delta_compensate_outside_the_joint_limits(tmp_path):
    m = example(tmp_path, DELTA, extra="joint_limits: {min: [-40, -40, -40], max: [60, 60, 5]}\n")
    t = write(tmp_path, "t.csv", "x_mm,y_mm,z_mm\n0,0,-750\n0,-150,-700\n")
    proc = run("compensate", m, t, "-o", "c.csv", cwd=tmp_path)
    assert_input_error(proc, "t.csv: 1 target(s) need joint values outside the joint limits",
                       "row 3: q3 = 8.21321 deg above max 5 deg")


def test_delta_workspace_partly_out_of_reach(tmp_path):
    m = example(tmp_path, DELTA)
    proc = run("identifiability", m, "--workspace", "-50,50,-50,50,-2500,-700mm",
               cwd=tmp_path)
    assert_input_error(proc, "--workspace -50,50,-50,50,-2500,-700mm:",
                       "of its 500 sampled poses: out of the machine's reach, e.g. at (",
                       "no real inverse kinematics")


def test_delta_home_out_of_reach(tmp_path):
    m = example(tmp_path, DELTA, ("home: [0.0, 0.0, -750.0]", "home: [0.0, 0.0, -3000.0]"))
    proc = run("simulate", m, "-o", "d.csv", cwd=tmp_path)
    assert_input_error(proc, f"{m}: home:", "cannot be reached by leg(s) 1, 2, 3")


def test_delta_reachable_targets_are_the_inverse_kinematics(tmp_path):
    m = example(tmp_path, DELTA)
    text = "x_mm,y_mm,z_mm\n0,0,-750\n50,-20,-800\n"
    t = write(tmp_path, "t.csv", text)
    proc = run("compensate", m, t, "-o", "c.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    machine = load_machine(tmp_path / m)
    P = positions(text)
    q = np.degrees(machine.ik(P, np.broadcast_to(np.eye(3), (2, 3, 3))))
    got = np.column_stack([column(tmp_path / "c.csv", f"q{j}_deg") for j in (1, 2, 3)])
    assert_same_joints(got, q)


# -- Hexa Slide --------------------------------------------------------------------------------

HEX_TARGETS = ("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n0,0,300,0,0,0\n"
               "2000,0,300,0,0,0\n")


def test_hexaslide_compensate_names_the_unreachable_target(tmp_path):
    m = example(tmp_path, HEXASLIDE)
    t = write(tmp_path, "t.csv", HEX_TARGETS)
    proc = run("compensate", m, t, "-o", "c.csv", cwd=tmp_path)
    assert_input_error(proc, "t.csv: 1 target(s) cannot be reached", "row 3 at (2000, 0, 300) "
                       "mm, psi 0 theta 0 phi 0 deg", "no real inverse kinematics")


def test_hexaslide_compensate_outside_the_joint_limits(tmp_path):
    m = example(tmp_path, HEXASLIDE, extra="joint_limits: {min: 0, max: 352}\n")
    t = write(tmp_path, "t.csv", "x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n0,0,300,0,0,0\n"
              "0,0,350,0,0,0\n")
    proc = run("compensate", m, t, "-o", "c.csv", cwd=tmp_path)
    assert_input_error(proc, "t.csv: 1 target(s) need joint values outside the joint limits",
                       "row 3: q1 = 394.247 mm above max 352 mm")


@pytest.mark.parametrize("command", [("identifiability",),
                                     ("select-poses", "-n", "60", "-o", "p.csv")])
def test_hexaslide_workspace_partly_out_of_reach(tmp_path, command):
    m = example(tmp_path, HEXASLIDE)
    proc = run(command[0], m, *command[1:], "--workspace", "-2000,2000,-50,50,250,350mm",
               cwd=tmp_path)
    assert_input_error(proc, "--workspace -2000,2000,-50,50,250,350mm:",
                       "of its 500 sampled poses: out of the machine's reach, e.g. at (",
                       "deg:")


def test_hexaslide_home_out_of_reach(tmp_path):
    m = example(tmp_path, HEXASLIDE, ("home: [0.0, 0.0, 300.0,", "home: [0.0, 0.0, 3000.0,"))
    proc = run("simulate", m, "-o", "d.csv", cwd=tmp_path)
    assert_input_error(proc, f"{m}: home:", "cannot be reached")


def test_hexaslide_reachable_targets_are_the_inverse_kinematics(tmp_path):
    m = example(tmp_path, HEXASLIDE)
    text = "x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n0,0,300,0,0,0\n20,-10,320,0,0,0\n"
    t = write(tmp_path, "t.csv", text)
    proc = run("compensate", m, t, "-o", "c.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    machine = load_machine(tmp_path / m)
    q = machine.ik(positions(text), np.broadcast_to(np.eye(3), (2, 3, 3))) * 1e3
    got = np.column_stack([column(tmp_path / "c.csv", f"q{j}_mm") for j in range(1, 7)])
    assert_same_joints(got, q)


# -- Stewart -----------------------------------------------------------------------------------

def test_stewart_target_too_far_is_named(tmp_path):
    m = example(tmp_path, STEWART)
    t = write(tmp_path, "t.csv", "x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n0,0,410,0,0,0\n"
              "0,0,10000,0,0,0\n")
    proc = run("compensate", m, t, "-o", "c.csv", cwd=tmp_path)
    assert_input_error(proc, "t.csv: 1 target(s) cannot be reached", "row 3 at (0, 0, 10000) "
                       "mm", "farther than 10x the machine's size")



def test_stewart_export_workspace_point_too_far_is_refused(tmp_path):
    m = example(tmp_path, STEWART)
    write(tmp_path, "pts.csv", "x_mm,y_mm,z_mm\n0,0,410\n0,0,3000\n")
    proc = run("export", m, "--to", "linuxcnc-genhexkins", "-o", "h.ini", "--workspace",
               "pts.csv", cwd=tmp_path)
    assert_input_error(proc, "--workspace pts.csv: row(s) 3: out of the machine's reach",
                       "row 3 at (0, 0, 3000) mm", "farther than 10x the machine's size")
    assert not (tmp_path / "h.ini").exists()


def test_delta_export_workspace_partly_out_of_reach(tmp_path):
    m = example(tmp_path, DELTA)
    proc = run("export", m, "--to", "klipper-rotary-delta", "-o", "d.cfg", "--workspace",
               "-50,50,-50,50,-2500,-700mm", cwd=tmp_path)
    assert_input_error(proc, "--workspace -50,50,-50,50,-2500,-700mm:",
                       "no real inverse kinematics (leg(s)")
    assert not (tmp_path / "d.cfg").exists()


# -- planar 3-RPR ------------------------------------------------------------------------------

RPR = """\
pkmcal: 1
machine: planar_3rpr
units: {length: mm, angle: deg}
legs:
  - {base: [0.0, 500.0], platform: [-100.0, 0.0], l0: 300.0, gain: 1.0}
  - {base: [-433.0127, -250.0], platform: [50.0, -86.6025], l0: 300.0}
  - {base: [433.0127, -250.0], platform: [50.0, 86.6025], l0: 300.0, gain: 1.0}
home: [10.0, -5.0, 3.0]
"""
RPR_TARGETS = "x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n10,-5,0,0,0,3\n9000,0,0,0,0,0\n"


def test_planar_target_too_far_is_named(tmp_path):
    m = write(tmp_path, "rpr.yaml", RPR)
    t = write(tmp_path, "t.csv", RPR_TARGETS)
    proc = run("compensate", m, t, "-o", "c.csv", cwd=tmp_path)
    assert_input_error(proc, "t.csv: 1 target(s) cannot be reached", "row 3 at (9000, 0, 0) "
                       "mm", "8990 mm from home, farther than 10x the machine's size")


def test_planar_targets_outside_the_joint_limits(tmp_path):
    m = write(tmp_path, "rpr.yaml", RPR + "joint_limits: {min: 150, max: 250}\n")
    t = write(tmp_path, "t.csv", "x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n10,-5,0,0,0,3\n"
              "10,-5,0,0,0,60\n")
    proc = run("compensate", m, t, "-o", "c.csv", cwd=tmp_path)
    assert_input_error(proc, "t.csv: 1 target(s) need joint values outside the joint limits",
                       "row 3: q1 = 292.953 mm above max 250 mm")


def test_planar_reachable_targets_still_work(tmp_path):
    m = write(tmp_path, "rpr.yaml", RPR)
    t = write(tmp_path, "t.csv", "x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n10,-5,0,0,0,3\n"
              "30,5,0,0,0,-2\n")
    proc = run("compensate", m, t, "-o", "c.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert len(column(tmp_path / "c.csv", "q1_mm")) == 2


def test_stewart_errors_trajectory_outside_the_joint_limits(tmp_path):
    m = example(tmp_path, STEWART, extra="joint_limits: {min: 380, max: 420}\n")
    proc = run("errors", m, "-o", "e.csv", cwd=tmp_path)
    assert_input_error(proc, "the circle has 360 pose(s) the machine cannot take",
                       "sample 0 at (100, 0, 410) mm, psi 0 theta 0 phi 0 deg",
                       "q1 = 422.019 mm, 2.01896 mm above its max 420 mm",
                       "change --radius or --height")
    assert not (tmp_path / "e.csv").exists()
