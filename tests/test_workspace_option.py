"""``--workspace`` of identifiability and select-poses (issue 12 item 7): the predicted accuracy
over the user's box or points instead of the SPEC 5 cube around home, and the report says
which."""

from __future__ import annotations

import json

import numpy as np
import pytest

from clitools import assert_input_error
from pkmcal.analysis.accuracy import box_workspace, machine_workspace
from pkmcal.machines import default_hexaslide


def predicted(proc) -> dict:
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)["predicted_accuracy"]


def test_a_box_equal_to_the_cube_gives_the_default_poses():
    m = default_hexaslide()
    P0, R0 = machine_workspace(m, 500, 3)
    c = m.home[0]
    ws = box_workspace(m, c - 0.05, c + 0.05, 500, 3)
    assert np.allclose(ws.P, P0, rtol=0, atol=1e-15) and np.allclose(ws.R, R0, atol=1e-15)
    assert "orientations within +/-10 deg" in ws.description


def test_box_changes_the_prediction_and_is_reported(cli):
    default = predicted(cli("identifiability", "default", "--noise", "2um", "--json"))
    assert default["workspace"].startswith("0.1 m cube around home")
    same = predicted(cli("identifiability", "default", "--noise", "2um", "--json",
                         "--workspace", "-50mm,50mm,-50mm,50mm,250mm,350mm"))
    assert same["position_rms_um"] == pytest.approx(default["position_rms_um"], rel=1e-9)
    assert same["workspace"] == ("box x -50..50 mm, y -50..50 mm, z 250..350 mm "
                                 "(--workspace), orientations within +/-10 deg")
    # one unit at the end applies to all
    wide = predicted(cli("identifiability", "default", "--noise", "2um", "--json",
                         "--workspace", "-100,100,-100,100,200,300mm"))
    assert wide["workspace"].startswith("box x -100..100 mm, y -100..100 mm, z 200..300 mm")
    assert wide["position_rms_um"] > 1.2 * default["position_rms_um"]
    proc = cli("identifiability", "default", "--noise", "2um", "--workspace",
               "-100,100,-100,100,200,300mm")
    assert "over the box x -100..100 mm" in " ".join(proc.stdout.replace("│", " ").split())


def test_points_file_changes_the_prediction(cli, tmp_path):
    (tmp_path / "pts.csv").write_text("x_mm,y_mm,z_mm\n0,0,300\n40,0,290\n0,-45,320\n")
    section = predicted(cli("identifiability", "default", "--noise", "2um", "--json",
                            "--workspace", "pts.csv"))
    assert section["poses"] == 3
    assert section["workspace"] == ("3 points of pts.csv (--workspace), orientations within "
                                    "+/-10 deg")
    (tmp_path / "poses.csv").write_text("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n"
                                        "0,0,300,0,0,0\n40,0,290,5,0,0\n")
    section = predicted(cli("identifiability", "default", "--noise", "2um", "--json",
                            "--workspace", "poses.csv"))
    assert section["poses"] == 2 and section["workspace"] == "2 poses of poses.csv (--workspace)"


def test_select_poses_uses_and_reports_the_workspace(cli, tmp_path):
    args = ("select-poses", "default", "-n", "60", "--candidates", "300", "--random-sets", "3",
            "--noise", "2um", "--criterion", "pose", "--json")
    default = json.loads(cli(*args, "-o", "a.csv").stdout)
    box = cli(*args, "-o", "b.csv", "--workspace", "-20mm,20mm,-20mm,20mm,330mm,350mm")
    rep = json.loads(box.stdout)
    assert rep["predicted_accuracy"]["workspace"].startswith("box x -20..20 mm")
    assert rep["selected_plan"]["position_rms_um"] != pytest.approx(
        default["selected_plan"]["position_rms_um"], rel=1e-3)
    a = np.loadtxt(tmp_path / "a.csv", delimiter=",", skiprows=1)
    b = np.loadtxt(tmp_path / "b.csv", delimiter=",", skiprows=1)
    assert a.shape == b.shape and not np.array_equal(a, b)


@pytest.mark.parametrize("value, words", [
    ("50mm,-50mm,-50mm,50mm,250mm,350mm", ["--workspace", "X0 must be below X1"]),
    ("-500mm,500mm,-50mm,50mm,250mm,350mm", ["of its 500 sampled poses", "out of the "
                                             "machine's reach"]),
    ("missing.csv", ["--workspace missing.csv: neither a box", "nor an existing points file"]),
    ("-50mm,50mm,-50mm,50mm,250mm,abc", ["--workspace", "abc"]),
])
def test_bad_workspaces_are_refused(cli, value, words):
    proc = cli("identifiability", "default", "--workspace", value, "--map", "m.png")
    assert_input_error(proc, *words)


def test_unreachable_points_are_named_and_nothing_is_written(cli, tmp_path):
    (tmp_path / "pts.csv").write_text("x_mm,y_mm,z_mm\n0,0,300\n2000,0,300\n")
    proc = cli("select-poses", "default", "-n", "60", "--workspace", "pts.csv", "-o", "p.csv")
    assert_input_error(proc, "--workspace pts.csv: row(s) 3: out of the machine's reach")
    assert not (tmp_path / "p.csv").exists()
