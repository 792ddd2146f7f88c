"""Faults found by the independent catalogue of the instrument, printer and export commands,
each fixed at its cause (exit 2 and one line naming the file, row, column, key or option; no
file written; inputs never overwritten)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from clitools import assert_input_error, digest, run

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
PRINTER = EXAMPLES / "linear_delta.yaml"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("faults")
    for args in (["simulate", PRINTER, "--seed", "1", "-o", "probe.csv"],
                 ["simulate", PRINTER, "--scenario", "distance", "--seed", "2", "-o",
                  "bar.csv"],
                 ["simulate", EXAMPLES / "cubic_6upu.yaml", "--scenario", "points", "--seed",
                  "2", "-o", "cp.csv"],
                 ["simulate", EXAMPLES / "cubic_6upu.yaml", "--scenario", "distance",
                  "--seed", "3", "-o", "cb.csv"],
                 ["simulate", EXAMPLES / "hexaslide_default.yaml", "--scenario", "distance",
                  "-o", "hbar.csv"],
                 ["calibrate", PRINTER, "probe.csv", "-o", "cal.yaml"]):
        proc = run(*args, cwd=d)
        assert proc.returncode == 0, proc.stderr
    return d


def _case(files, tmp_path):
    for f in files.iterdir():
        shutil.copy(f, tmp_path / f.name)
    return tmp_path


def test_a_file_with_two_kinds_of_measurement(files, tmp_path):
    d = _case(files, tmp_path)
    lines = (d / "probe.csv").read_text().splitlines()
    (d / "mix.csv").write_text("\n".join([lines[0] + ",d_mm"] + [x + ",100" for x in lines[1:]])
                               + "\n")
    assert_input_error(run("calibrate", PRINTER, "mix.csv", "-o", "o.yaml", cwd=d),
                       "mix.csv", "2 kinds of measurement")
    assert not (d / "o.yaml").exists()


def test_readings_of_a_machine_with_more_joints(files, tmp_path):
    d = _case(files, tmp_path)
    assert_input_error(run("calibrate", PRINTER, "hbar.csv", "-o", "o.yaml", cwd=d),
                       "hbar.csv", "column q4_mm", "3 joints")


@pytest.mark.parametrize("data", ["probe.csv", "bar.csv"])
def test_copies_of_one_row(files, tmp_path, data):
    d = _case(files, tmp_path)
    lines = (d / data).read_text().splitlines()
    # a row of setup 1 when the file has setups (a copied row of setup 2 alone leaves a gap)
    row = next(x for x in lines[1:] if "setup" not in lines[0] or x.endswith(",1"))
    (d / "dup.csv").write_text("\n".join([lines[0]] + [row] * 40) + "\n")
    assert_input_error(run("calibrate", PRINTER, "dup.csv", "-o", "o.yaml", cwd=d),
                       "dup.csv", "1 distinct")


def test_the_same_file_through_a_link(files, tmp_path):
    d = _case(files, tmp_path)
    (d / "link.csv").symlink_to(d / "probe.csv")
    assert_input_error(run("calibrate", PRINTER, "probe.csv", "link.csv", "-o", "o.yaml",
                           cwd=d), "the same data file is given twice")


@pytest.mark.parametrize("edit, words", [
    (("position_endstop: [285.0, 285.0, 285.0]", "position_endstop: [-285, 285, 285]"),
     ["position_endstop[0]", "> 0"]),
    (("home: [0.0, 0.0, 100.0]", "home: [0.0, 0.0, 100.0]\nbed: {height: 0, tilt_x: 1e9}"),
     ["bed.tilt_x"]),
])
def test_absurd_printer_files(tmp_path, edit, words):
    text = PRINTER.read_text()
    assert edit[0] in text
    (tmp_path / "m.yaml").write_text(text.replace(*edit))
    assert_input_error(run("simulate", "m.yaml", "-o", "o.csv", cwd=tmp_path), "m.yaml",
                       *words)


def test_joint_fit_keeps_the_probes_bed_and_compensate_reads_joint_frames(files, tmp_path):
    d = _case(files, tmp_path)
    proc = run("calibrate", PRINTER, "probe.csv", "bar.csv", "-o", "j.yaml", cwd=d)
    assert proc.returncode == 0, proc.stderr
    assert "\nbed:" in (d / "j.yaml").read_text()
    proc = run("calibrate", EXAMPLES / "cubic_6upu.yaml", "cp.csv", "cb.csv", "-o", "c.yaml",
               cwd=d)
    assert proc.returncode == 0, proc.stderr
    (d / "t.csv").write_text("x_mm,y_mm,z_mm\n2480,0,1800\n")
    proc = run("compensate", "c.yaml", "t.csv", "--frame", "instrument", "--instrument",
               "tracker", "-o", "cmd.csv", cwd=d)
    assert proc.returncode == 0, proc.stderr


def test_renamed_instrument_columns(files, tmp_path):
    d = _case(files, tmp_path)
    text = (d / "bar.csv").read_text().replace("d_mm", "length", 1)
    (d / "b3.csv").write_text(text)
    proc = run("calibrate", PRINTER, "b3.csv", "--columns", "d_mm=length", "-o", "o.yaml",
               cwd=d)
    assert proc.returncode == 0, proc.stderr


def test_export_protects_the_calibrations_report(files, tmp_path):
    d = _case(files, tmp_path)
    before = digest(d / "cal.json")
    for name in ("cal", "cal.json"):
        assert_input_error(run("export", "cal.yaml", "--to", "klipper", "-o", name, cwd=d),
                           "cal.json")
    assert digest(d / "cal.json") == before


def test_export_to_a_stream_writes_nothing_beside_it(files, tmp_path):
    d = _case(files, tmp_path)
    existed = Path("/dev/null.json").exists()
    proc = run("export", "cal.yaml", "--to", "klipper", "-o", "/dev/null", cwd=d)
    assert proc.returncode == 0, proc.stderr
    assert Path("/dev/null.json").exists() == existed


@pytest.mark.parametrize("text, args, words", [
    ("[printer]\nkinematics: cartesian\ndelta_radius: 130\n[stepper_a]\narm_length: 250\n"
     "position_endstop: 280\n", ["--from", "klipper"], ["in.cfg", "line 2", "kinematics"]),
    ("M665 H285 L250 R132.5 X0 Y0 Z0\nM666 X0 Y-0.3 Z-1e9\n", ["--from", "marlin"],
     ["in.cfg", "M666 Z", "line 2", "cannot be meant"]),      # the user's letter (issue 28)
    ("[printer]\nkinematics: delta\ndelta_radius: 130\n[stepper_a]\narm_length: 250\n"
     "position_endstop: 280\n", ["--from", "klipper", "--like",
                                 str(EXAMPLES / "cubic_6upu.yaml")], ["--like", "stewart"]),
])
def test_import_refusals_name_the_input(tmp_path, text, args, words):
    (tmp_path / "in.cfg").write_text(text)
    assert_input_error(run("import", "in.cfg", *args, "-o", "m.yaml", cwd=tmp_path), *words)
    assert not (tmp_path / "m.yaml").exists()


@pytest.mark.parametrize("text, fmt, words", [
    ("M665 H285 L250 R132.5 R140 X0 Y0 Z0\n", "marlin", ["line 1", "M665 R", "twice"]),
    ("M665 L250:251 R132.5 H285\n", "reprapfirmware", ["line 1", "2 diagonals"]),
])
def test_gcode_refusals(tmp_path, text, fmt, words):
    (tmp_path / "in.g").write_text(text)
    assert_input_error(run("import", "in.g", "--from", fmt, "-o", "m.yaml", cwd=tmp_path),
                       "in.g", *words)


def test_gcode_words_without_spaces(tmp_path):
    """Marlin reads ``M665H285L250R132.5``: so does import."""
    (tmp_path / "a.g").write_text("M665 H285 L250 R132.5 X0 Y0 Z0\nM666 X0 Y-0.3 Z-0.5\n")
    (tmp_path / "b.g").write_text("M665H285L250R132.5X0Y0Z0\nM666X0Y-0.3Z-0.5\n")
    for name in ("a", "b"):
        proc = run("import", f"{name}.g", "--from", "marlin", "-o", f"{name}.yaml",
                   cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
    strip = (lambda t: "\n".join(x for x in t.splitlines() if not x.startswith("name")))  # noqa: E731
    assert strip((tmp_path / "a.yaml").read_text()) == strip((tmp_path / "b.yaml").read_text())
