"""Cases of the independent fault catalogue (issue 11) that had failed, by cause: each is
refused with exit 2 and one line naming the option, file or link, leaves no file, and
changes no input."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from clitools import PKMCAL, assert_input_error, digest, run

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
DELTA = str(EXAMPLES / "delta_default.yaml")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("inputs")
    (d / "poses.csv").write_text("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n"
                                 "0,0,300,0,0,0\n10,5,310,1,2,3\n")
    assert run("ik", "default", "poses.csv", "-o", "j.csv", cwd=d).returncode == 0
    assert run("simulate", "default", "--scenario", "constraint-link", "--poses", "60",
               "-o", "d.csv", cwd=d).returncode == 0
    return {p.name: p.read_bytes() for p in d.iterdir()}


#: (arguments, words of the message); every case runs in a directory holding the inputs
CASES = {
    "empty option value": (["simulate", "default", "--noise", "", "-o", "s.csv"],
                           ["--noise", "empty value"]),
    "empty option with =": (["simulate", "default", "--noise=", "-o", "s.csv"],
                            ["--noise", "empty value"]),
    "empty machine argument": (["fk", "", "j.csv", "-o", "p.csv"], ["empty value"]),
    "empty output": (["fk", "default", "j.csv", "-o", ""], ["-o", "empty value"]),
    "noise 1e-300 calibrate": (["calibrate", "default", "d.csv", "--noise", "1e-300", "-o",
                                "c.yaml"], ["--noise", "below 1e-12"]),
    "noise 1e-300 tracker": (["simulate", DELTA, "--scenario", "tracker", "--noise", "1e-300",
                              "-o", "t.csv"], ["--noise", "below 1e-12"]),
    "grid of 1e9 points": (["simulate", DELTA, "--scenario", "tracker", "--grid",
                            "1000x1000x1000", "-o", "t.csv"], ["--grid", "1000000000 points"]),
    "grid of one point": (["simulate", DELTA, "--scenario", "tracker", "--grid", "1x1x1", "-o",
                           "t.csv"], ["--grid", "at least 4"]),
    "-n above candidates": (["select-poses", "default", "-n", "5000", "-o", "p.csv"],
                            ["-n/--poses 5000", "--candidates"]),
    "output with a slash": (["fk", "default", "j.csv", "-o", "p.csv/"], ["-o", "ends with '/'"]),
    "truth with a slash": (["simulate", "default", "--truth", "t.yaml/", "-o", "s.csv"],
                           ["--truth", "ends with '/'"]),
    "data from /dev/zero": (["calibrate", "default", "/dev/zero", "-o", "c.yaml"],
                            ["/dev/zero", "NUL bytes"]),
    "binary data file": (["calibrate", "default", "bin.csv", "-o", "c.yaml"],
                         ["bin.csv", "not a text file"]),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_refused_naming_the_cause(tmp_path, files, name):
    args, words = CASES[name]
    for fname, data in files.items():
        (tmp_path / fname).write_bytes(data)
    (tmp_path / "bin.csv").write_bytes(b"q1_mm,q2_mm\x00\x01\x02\n1,2\n")
    before = {p.name: digest(p) for p in tmp_path.iterdir()}
    proc = run(*args, cwd=tmp_path)
    assert_input_error(proc, *words)
    assert "Warning" not in proc.stderr
    assert {p.name: digest(p) for p in tmp_path.iterdir()} == before


@pytest.mark.parametrize("layout", ["self", "pair"])
def test_a_symbolic_link_loop_is_refused_never_replaced(tmp_path, files, layout):
    (tmp_path / "j.csv").write_bytes(files["j.csv"])
    if layout == "self":
        os.symlink("loop.csv", tmp_path / "loop.csv")
    else:
        os.symlink("b.csv", tmp_path / "loop.csv")
        os.symlink("loop.csv", tmp_path / "b.csv")
    proc = run("fk", "default", "j.csv", "-o", "loop.csv", cwd=tmp_path)
    assert_input_error(proc, "loop.csv", "symbolic link")
    assert (tmp_path / "loop.csv").is_symlink()


def test_a_pipe_is_read_once_for_all_its_uses(tmp_path, files):
    """`calibrate default <(cat d.csv)`: the data are read for their kind and again for the
    rows; a pipe gives its text once, so it is kept."""
    (tmp_path / "d.csv").write_bytes(files["d.csv"])
    proc = subprocess.run(["bash", "-c", f"'{PKMCAL}' calibrate default <(cat d.csv) -o c.yaml"
                           " -q"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "c.yaml").exists() and (tmp_path / "c.json").exists()


#: poses no joint command can reach from the working mode: mirrored through the base, or far
FAR_POSES = ("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n0,0,410,0,0,0\n0,0,-410,0,0,0\n"
             "0,0,9000,0,0,0\n")


@pytest.mark.parametrize("command", ["ik", "compensate"])
def test_poses_outside_the_working_mode_are_refused_naming_rows(tmp_path, command):
    (tmp_path / "far.csv").write_text(FAR_POSES)
    proc = run(command, EXAMPLES / "cubic_6upu.yaml", "far.csv", "-o", "q.csv", cwd=tmp_path)
    assert_input_error(proc, "far.csv", "row(s) 3, 4")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["far.csv"]


def test_a_trajectory_outside_the_working_mode_is_refused(tmp_path):
    proc = run("errors", "cubic", "--height", "-410mm", "-o", "e.csv", cwd=tmp_path)
    assert_input_error(proc, "working mode", "--height")
    assert list(tmp_path.iterdir()) == []


def test_the_working_mode_holds_over_each_machines_workspace():
    from pkmcal.analysis.accuracy import machine_workspace
    from pkmcal.io import load_machine
    from pkmcal.machines import cubic_6upu, default_hexaslide

    for machine in (default_hexaslide(), cubic_6upu(), load_machine(DELTA),
                    load_machine(EXAMPLES / "jugglebot.yaml")):
        P, R = machine_workspace(machine, n=500)
        assert machine.working_mode(P, R).all(), machine.name


@pytest.mark.parametrize("example,old,new,words", [
    ("cubic_6upu.yaml", "readings: {unit: mm}", "readings: {unit: kg}",
     ["readings.unit", "unit of mass"]),
    ("hexaslide_default.yaml", "constraint_link: {length: 300.0}",
     "constraint_link: {length: 1e-308}", ["constraint_link.length", "less than 1e-06"]),
    ("delta_default.yaml", "base_radius: 200.0", "base_radius: 1e-308",
     ["base_radius", "less than 1e-06"]),
])
def test_machine_file_values_that_cannot_be_meant(tmp_path, example, old, new, words):
    text = (EXAMPLES / example).read_text()
    assert old in text
    (tmp_path / "m.yaml").write_text(text.replace(old, new))
    proc = run("simulate", "m.yaml", "-o", "x.csv", cwd=tmp_path)
    assert_input_error(proc, "m.yaml", *words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.yaml"]
