"""Inches (``in``, ``inch``) in machine files, CSV columns and on the command line, and the
``--columns`` map for data files from other tools (issue 12 item 7)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, digest
from pkmcal.errors import InputError
from pkmcal.io import load_machine, parse_machine, read_joints, read_poses
from pkmcal.io.csv_io import column_map, parse_column_map, read_table
from pkmcal.io.machine_file import machine_to_text
from pkmcal.units import parse_quantity

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "jugglebot"
JUGGLEBOT_COLUMNS = ",".join([f"q{j}_rev=leg_length_{j}" for j in range(1, 7)]
                             + [f"{c}_mm=position_{c}" for c in "xyz"]
                             + [f"q{c}=orientation_{c}" for c in "xyzw"])


def relative_close(a, b, rtol=1e-12) -> bool:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return bool(np.all(np.abs(a - b) <= rtol * np.maximum(np.abs(b), np.max(np.abs(b)))))


# -- inches ----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["hexaslide_default.yaml", "delta_default.yaml",
                                  "cubic_6upu.yaml"])
@pytest.mark.parametrize("word", ["in", "inch"])
def test_a_file_in_inches_is_the_same_machine(name, word):
    mm = load_machine(EXAMPLES / name)
    text = machine_to_text(mm, units={"length": word, "angle": "deg"})
    assert "units: {length: in, angle: deg}" in text
    inches = parse_machine(text.replace("length: in,", f"length: {word},"))
    assert inches.file_units == {"length": "in", "angle": "deg"}
    assert relative_close(inches.u, mm.u)
    assert relative_close(inches.home[0], mm.home[0])
    # positions of the two machines for the same joints
    q = mm.ik(*mm.home)[None] * np.linspace(0.98, 1.02, 5)[:, None]
    a, b = inches.fk(q), mm.fk(q)
    assert a.converged.all() and b.converged.all()
    assert relative_close(a.P, b.P)


def test_numbers_and_columns_in_inches(tmp_path):
    assert parse_quantity("2in", "length") == pytest.approx(0.0508, rel=1e-15)
    assert parse_quantity("1inch", "length") == 0.0254
    path = tmp_path / "j.csv"
    path.write_text("q1_in,q2_in,q3_in,q4_in,q5_in,q6_in\n10,10,10,10,10,12\n")
    q, _, _ = read_joints(path, 6, "length")
    assert np.allclose(q, [[0.254] * 5 + [0.3048]], rtol=1e-15)
    path.write_text("x_in,y_in,z_in,psi_deg,theta_deg,phi_deg\n1,2,12,0,0,0\n")
    P, _, _ = read_poses(path)
    assert np.allclose(P, [[0.0254, 0.0508, 0.3048]], rtol=1e-15)


def test_commands_write_and_read_inches(cli, tmp_path):
    m = load_machine(EXAMPLES / "delta_default.yaml")
    (tmp_path / "m.yaml").write_text(machine_to_text(m, units={"length": "in",
                                                                "angle": "deg"}))
    proc = cli("simulate", "m.yaml", "--scenario", "tracker", "--noise", "0.0004in", "-o",
               "t.csv")
    assert proc.returncode == 0, proc.stderr
    with open(tmp_path / "t.csv") as f:
        assert next(csv.reader(f)) == ["q1_deg", "q2_deg", "q3_deg", "mx_in", "my_in", "mz_in"]
    proc = cli("calibrate", "m.yaml", "t.csv", "-o", "cal.yaml", "--noise", "10um")
    assert proc.returncode == 0, proc.stderr
    assert "units: {length: in, angle: deg}" in (tmp_path / "cal.yaml").read_text()
    assert cli("fk", "cal.yaml", "t.csv", "-o", "points.csv").returncode == 0
    with open(tmp_path / "points.csv") as f:
        assert next(csv.reader(f)) == ["x_in", "y_in", "z_in"]
    assert cli("ik", "cal.yaml", "points.csv", "-o", "q.csv").returncode == 0
    back = np.loadtxt(tmp_path / "q.csv", delimiter=",", skiprows=1)
    read = np.loadtxt(tmp_path / "t.csv", delimiter=",", skiprows=1)[:, :3]
    assert np.allclose(back, read, atol=1e-9)


def test_other_length_words_stay_refused():
    text = (EXAMPLES / "hexaslide_default.yaml").read_text()
    with pytest.raises(InputError) as exc:
        parse_machine(text.replace("length: mm", "length: ft"), "m.yaml")
    assert "units.length" in str(exc.value) and "accepted: mm, m, in" in str(exc.value)


# -- --columns -------------------------------------------------------------------------------


def test_the_map_renames_and_is_checked(tmp_path):
    path = tmp_path / "other.csv"
    path.write_text("a,b,c\n1,2,3\n")
    mapping = parse_column_map("q1_mm=a, passive=c")
    assert mapping == {"q1_mm": "a", "passive": "c"}
    with column_map(mapping):
        header, rows = read_table(path)
    assert header == ["q1_mm", "b", "passive"] and rows == [(2, ["1", "2", "3"])]
    assert read_table(path)[0] == ["a", "b", "c"]            # only inside the block
    with column_map({"q1_mm": "zz"}), pytest.raises(InputError) as exc:
        read_table(path)
    assert str(exc.value).startswith(f"{path}: row 1: --columns names column(s) this file "
                                     "does not have: zz")
    with column_map({"b": "a"}), pytest.raises(InputError) as exc:  # parse_column_map refuses b
        read_table(path)
    assert "already has a column b" in str(exc.value)


@pytest.mark.parametrize("text, words", [
    ("foo=a", ["'foo' is not a column pkmcal reads"]),
    ("x=a", ["'x' needs a unit suffix (x_m, x_mm, x_um, x_in)"]),
    ("q1=a", ["'q1' needs a unit suffix"]),
    ("x_deg=a", ["'x_deg': unknown length unit 'deg'"]),
    ("qx_mm=a", ["'qx_mm': qx takes no unit suffix"]),
    ("q1_mm", ["expected PKMCAL=FILE pairs"]),
    ("q1_mm=a,q1_mm=b", ["q1_mm is given twice"]),
    ("q1_mm=a,q2_mm=a", ["the file's column a is mapped twice"]),
])
def test_unknown_names_are_refused(text, words):
    with pytest.raises(InputError) as exc:
        parse_column_map(text)
    message = str(exc.value)
    assert message.startswith("--columns: ")
    for w in words:
        assert w in message, message


def test_columns_on_the_command_line(cli, tmp_path):
    (tmp_path / "t.csv").write_text("X,Y,Z,A,B,C\n0,0,300,0,0,0\n10,0,300,0,2,0\n")
    before = digest(tmp_path / "t.csv")
    columns = "x_mm=X,y_mm=Y,z_mm=Z,psi_deg=A,theta_deg=B,phi_deg=C"
    assert cli("ik", "default", "t.csv", "-o", "q.csv", "--columns", columns).returncode == 0
    assert cli("compensate", "default", "t.csv", "-o", "c.csv",
               "--columns", columns).returncode == 0
    assert cli("select-poses", "default", "-n", "2", "--from", "t.csv", "--random-sets", "0",
               "--columns", columns, "-o", "p.csv").returncode in (0, 2)
    assert digest(tmp_path / "t.csv") == before
    proc = cli("ik", "default", "t.csv", "-o", "q2.csv", "--columns", "x_mm=X,w_mm=Y")
    assert_input_error(proc, "--columns: unknown pkmcal column name(s): 'w_mm'")
    proc = cli("ik", "default", "t.csv", "-o", "q2.csv", "--columns", columns + ",passive=P")
    assert_input_error(proc, "t.csv: row 1: --columns names column(s) this file does not have: "
                       "P")
    assert not (tmp_path / "q2.csv").exists()
    # without --columns the file's own names do not read
    assert_input_error(cli("ik", "default", "t.csv", "-o", "q2.csv"), "missing column x_<unit>")


@pytest.mark.skipif(not (DATA / "calibration_108_poses.csv").is_file(),
                    reason=f"the Jugglebot measurements are not at {DATA}")
def test_jugglebot_files_read_with_columns(cli):
    machine = EXAMPLES / "jugglebot.yaml"
    data = DATA / "calibration_108_poses.csv"
    proc = cli("calibrate", machine, data, "--method", "ik", "--columns", JUGGLEBOT_COLUMNS,
               "-o", "cal.yaml")
    assert proc.returncode in (0, 1), proc.stderr
    proc = cli("fk", "cal.yaml", DATA / "validation_60_poses.csv", "--columns",
               JUGGLEBOT_COLUMNS, "-o", "poses.csv")
    assert proc.returncode == 0, proc.stderr
    proc = cli("identifiability", machine, data, "--columns", JUGGLEBOT_COLUMNS, "--json")
    assert proc.returncode == 0, proc.stderr
    assert_input_error(cli("calibrate", machine, data, "-o", "x.yaml"),
                       "cannot tell the measurement type")
