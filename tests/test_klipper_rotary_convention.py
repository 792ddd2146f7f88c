"""Klipper rotary_delta: the convention in values, not comments (issue 34), without Klipper's
code (the runs in Klipper's code are tests/test_klipper_klippy.py).

The machine's readings count from the arms' endstops both ways; an import is in Klipper's
frame (the bed at z = 0), or with ``--like`` in the like-file's frame by its shoulder height;
the lines older exports wrote (``# pkmcal bed_z_mm``...) are not read, and import says so;
export says where Klipper's frame is.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from clitools import run
from pkmcal.export import controller_format, export, export_workspace
from pkmcal.io.machine_file import load_machine, save_machine
from pkmcal.machines.delta import Delta, delta_parameters

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "delta_default.yaml"
ROTARY = controller_format("klipper-rotary-delta")

#: a file of an older pkmcal export: its '# pkmcal' lines placed the bed 1100 mm below the
#: shoulders (out of Klipper's reach) and the endstop readings at 0
OLD_EXPORT = """# pkmcal export for a Delta: Klipper rotary_delta
# pkmcal bed_z_mm = -1100.000000000
# pkmcal endstop_reading_a_deg = 0.000000000000
# pkmcal endstop_reading_b_deg = 0.000000000000
# pkmcal endstop_reading_c_deg = 0.000000000000

[printer]
kinematics: rotary_delta
shoulder_radius: 150.000000000
shoulder_height: 1100.000000000

[stepper_a]
position_endstop: 438.669500051
upper_arm_length: 300.000000000
lower_arm_length: 800.000000000
angle: 90.000000000000

[stepper_b]
position_endstop: 438.669500051
upper_arm_length: 300.000000000
lower_arm_length: 800.000000000
angle: 180.000000000000

[stepper_c]
position_endstop: 438.669500051
upper_arm_length: 300.000000000
lower_arm_length: 800.000000000
angle: -90.000000000000
"""


def test_old_export_lines_are_noted_and_not_read(tmp_path):
    """An older export imports: its comment lines are named in a note and not read; the
    machine is Klipper's, in Klipper's frame, reading 0 at the endstops."""
    (tmp_path / "old.cfg").write_text(OLD_EXPORT)
    proc = run("import", "old.cfg", "--from", "klipper-rotary-delta", "-o", "m.yaml",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    out = " ".join(proc.stdout.split())
    assert "the '# pkmcal' lines of an older pkmcal export (bed_z_mm (line 2), " \
           "endstop_reading_a_deg (line 3)" in out and "are not read" in out
    m = load_machine(tmp_path / "m.yaml")
    assert np.allclose(m.fk(np.zeros((1, 3))).P, [[0.0, 0.0, 0.438669500051]], rtol=0,
                       atol=1e-12)
    assert np.allclose(m.legs()[0][:, 2], 1.1, rtol=0, atol=1e-15)      # shoulders, bed 0


def test_import_like_takes_the_like_files_frame(tmp_path):
    """``import --like`` puts the machine in the like-file's frame by a rule on values (its
    shoulder height): a machine Klipper holds exactly comes back as itself, and exported
    again gives Klipper the same values."""
    u = np.zeros((3, 9))
    u[:, 2] = 0.2e-3
    u[:, 3] = [0.002, -0.001, 0.003]
    u[:, 4] = [0.5e-3, -0.2e-3, 0.1e-3]
    m = Delta(0.2, 0.05, 0.3, 0.8, np.radians([90.0, 180.0, -90.0]),
              delta_parameters(u.reshape(-1)), home=(np.array([0.0, 0.0, -0.75]), np.eye(3)),
              name="exact")
    save_machine(m, tmp_path / "m.yaml")
    ws = export_workspace(m)
    res = export(ROTARY, m, ws.P, ws.R)
    assert res.params.as_dict()["bed_z"] < -0.75                  # the workspace's bottom
    (tmp_path / "k.cfg").write_text(res.text)
    proc = run("import", "k.cfg", "--from", "klipper-rotary-delta", "--like", "m.yaml",
               "-o", "back.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    back = load_machine(tmp_path / "back.yaml")
    q = ROTARY.ik(res.params, ws.P)
    assert np.abs(back.fk(q).P - ws.P).max() < 1e-12
    assert np.allclose(back.home[0], m.home[0], rtol=0, atol=0)
    again = export(ROTARY, back, ws.P, ws.R)
    assert np.allclose(again.params.values, res.params.values, rtol=0, atol=1e-12)
    # without --like: Klipper's frame, the bed at z = 0
    proc = run("import", "k.cfg", "--from", "klipper-rotary-delta", "-o", "kf.yaml",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    kf = load_machine(tmp_path / "kf.yaml")
    shift = np.array([0.0, 0.0, res.params.as_dict()["bed_z"]])
    assert np.abs(kf.fk(q).P - (ws.P - shift)).max() < 1e-12


def test_export_says_where_klippers_frame_is(tmp_path):
    """The console and the JSON record say where Klipper's z = 0 is in the machine file."""
    proc = run("export", EXAMPLE, "--to", "klipper-rotary-delta", "-o", "k.cfg", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    record = json.loads((tmp_path / "k.cfg.json").read_text())
    bed = record["values"]["bed_z"]
    frame = [n for n in record["notes"] if n.startswith("Klipper's z = 0 (the bed)")]
    assert frame and f"z = {bed * 1e3:.6f} mm of the machine file" in frame[0]
    assert "note: Klipper's z = 0 (the bed) is at z" in " ".join(proc.stdout.split())
    assert "Klipper's (x, y, z) is the machine file's (x, y, z + " in frame[0]
    # the values table names Klipper's keys with their sections (not eaten as markup)
    assert "[printer] shoulder_radius" in proc.stdout
    assert "[stepper_c] position_endstop" in proc.stdout
    proc = run("export", ROOT / "examples" / "linear_delta.yaml", "--to", "klipper", "-o",
               "p.cfg", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "[printer] delta_radius" in proc.stdout


def test_export_refuses_a_bed_klipper_cannot_home_on(tmp_path):
    """A workspace with no place for Klipper's bed: exit 2, the reason, no file written."""
    (tmp_path / "ws.csv").write_text("x_mm,y_mm,z_mm\n400,0,-400\n400,200,-400\n")
    proc = run("export", EXAMPLE, "--to", "klipper-rotary-delta", "--workspace", "ws.csv",
               "-o", "k.cfg", cwd=tmp_path)
    assert proc.returncode == 2
    err = " ".join(proc.stderr.split())
    assert "Klipper's z = 0 (the bed) must be below every workspace target and reachable " \
           "at the centre" in err and "no arm reaches the centre on the bed" in err, err
    assert not list(tmp_path.glob("k.cfg*"))
