"""A first Stewart machine file that just works (SPEC 7 "Stewart files", issue 11).

- A leg without ``l0``/``gain`` reads its length (``l0 = 0``, ``gain = 1``): a file with only
  ``base`` and ``platform`` per leg serves ``pkmcal errors``, ``ik`` and ``fk``.
- Without ``readings:`` the data's column suffix is the reading unit: ``q1_rev`` columns with a
  gain in mm per rev work, ``q1_mm`` columns are lengths in mm.
- With a declared reading unit, columns in another unit are refused saying what to change.
- A machine whose reading unit came from the data saves it explicitly: the calibrated file is
  self-contained and round-trips.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, digest, run
from pkmcal.errors import InputError
from pkmcal.io import load_machine, machine_to_text, parse_machine, read_full_pose, read_readings
from pkmcal.kinematics import matrix_from_euler

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
CUBIC = (EXAMPLES / "cubic_6upu.yaml").read_text()
#: examples/cubic_6upu.yaml with only base and platform per leg and no readings: section
FIRST = re.sub(r"(?m)^#.*\n", "", re.sub(r", l0: 0\.0, gain: 1\.0", "", CUBIC)).replace(
    "readings: {unit: mm}\n", "")
#: the same device with motor-driven legs: 300 mm at zero reading, 10 mm per rev, no readings:
REV = re.sub(r"platform: (\[[^]]*\])}", r"platform: \1, l0: 300.0, gain: 10.0}", FIRST)
REV_DECLARED = REV + "readings: {unit: rev}\n"
POSES = np.array([[0, 0, 410, 0, 0, 0], [10, 5, 400, 1, 2, 3], [-20, 10, 420, -2, 1, 0],
                  [5, -15, 395, 0, -3, 2]], float)
POSES_CSV = "x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n" + "".join(
    ",".join(repr(float(v)) for v in row) + "\n" for row in POSES)


def _pose(row):
    return row[..., :3] * 1e-3, matrix_from_euler(np.radians(row[..., 3:]))


def _table(path: Path) -> tuple[list[str], np.ndarray]:
    lines = path.read_text().splitlines()
    return lines[0].split(","), np.array([[float(v) for v in line.split(",")]
                                          for line in lines[1:]])


def _readings_csv(path: Path, q, unit: str) -> Path:
    path.write_text(",".join(f"q{j + 1}_{unit}" for j in range(6)) + "\n" + "".join(
        ",".join(repr(float(v)) for v in row) + "\n" for row in q))
    return path


def test_files_are_what_they_say():
    assert "l0" not in FIRST and "gain" not in FIRST and "readings" not in FIRST
    assert REV.count("l0: 300.0, gain: 10.0") == 6 and "readings" not in REV


# -- API -------------------------------------------------------------------------------------------

def test_a_leg_without_l0_and_gain_reads_its_length():
    m = parse_machine(FIRST, "first.yaml")
    b, p, l0, g = m.legs()
    np.testing.assert_array_equal(l0, 0.0)
    np.testing.assert_array_equal(g, 1.0)
    assert m.reading_unit == "mm" and m.joint_quantity == "length"
    P, R = _pose(POSES[1])
    np.testing.assert_allclose(m.ik(P, R), np.linalg.norm(P + p @ R.T - b, axis=-1),
                               rtol=1e-15)
    # the same machine as the example that states l0: 0, gain: 1 and readings: {unit: mm}
    np.testing.assert_array_equal(m.u, load_machine(EXAMPLES / "cubic_6upu.yaml").u)


def test_undeclared_readings_take_the_column_unit_rev(tmp_path):
    declared = parse_machine(REV_DECLARED, "declared.yaml")
    P, R = _pose(POSES)
    q = declared.ik(P, R)                                   # revs
    path = _readings_csv(tmp_path / "q.csv", q, "rev")
    m = parse_machine(REV, "rev.yaml")
    assert m.reading_unit == "mm" and not m.reading_unit_declared
    back, _ = read_readings(path, m)
    assert m.reading_unit == "rev" and m.reading_unit_from == str(path)
    np.testing.assert_allclose(back, q, rtol=1e-15)
    np.testing.assert_allclose(m.u, declared.u, rtol=1e-15)        # gain 0.01 m per rev
    fk = m.fk(back)
    assert fk.converged.all()
    np.testing.assert_allclose(fk.P, P, atol=1e-12)


def test_undeclared_readings_in_mm_are_lengths(tmp_path):
    m = parse_machine(FIRST, "first.yaml")
    P, R = _pose(POSES)
    L = m.ik(P, R)
    back, _ = read_readings(_readings_csv(tmp_path / "q.csv", L * 1e3, "mm"), m)
    np.testing.assert_allclose(back, L, rtol=1e-14)
    assert m.reading_unit == "mm"
    np.testing.assert_allclose(m.fk(back).P, P, atol=1e-12)


def test_full_pose_data_in_rev_sets_the_unit(tmp_path):
    declared = parse_machine(REV_DECLARED, "declared.yaml")
    P, R = _pose(POSES)
    q = declared.ik(P, R)
    text = "q1_rev,q2_rev,q3_rev,q4_rev,q5_rev,q6_rev,x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n"
    text += "".join(",".join(repr(float(v)) for v in [*qr, *row]) + "\n"
                    for qr, row in zip(q, POSES, strict=True))
    (tmp_path / "pose.csv").write_text(text)
    m = parse_machine(REV, "rev.yaml")
    data = read_full_pose(tmp_path / "pose.csv", m)
    assert m.reading_unit == "rev"
    np.testing.assert_allclose(data.q, q, rtol=1e-15)


def test_a_unit_set_by_data_is_saved_explicitly_and_round_trips(tmp_path):
    m = parse_machine(REV, "rev.yaml")
    read_readings(_readings_csv(tmp_path / "q.csv", np.ones((2, 6)), "rev"), m)
    text = machine_to_text(m)
    assert "readings: {unit: rev}" in text
    assert text.count("gain: 10.0") == 6                   # still mm per rev in the file
    back = parse_machine(text, "saved.yaml")
    assert back.reading_unit == "rev" and back.reading_unit_declared
    np.testing.assert_array_equal(back.u, m.u)
    assert machine_to_text(back) == text
    # a machine never given data saves its default unit explicitly too
    assert "readings: {unit: mm}" in machine_to_text(parse_machine(FIRST, "first.yaml"))


def test_declared_unit_and_columns_that_disagree_say_what_to_change(tmp_path):
    m = parse_machine(REV_DECLARED, "machine.yaml")
    path = _readings_csv(tmp_path / "data.csv", np.ones((2, 6)), "deg")
    with pytest.raises(InputError) as exc:
        read_readings(path, m)
    assert str(exc.value) == (
        f"{path}: columns q1_deg..q6_deg are in deg but machine.yaml declares readings: "
        "{unit: rev}; rename the columns to q1_rev..q6_rev or change readings.unit")
    # lengths where a word was declared, and a word where lengths were declared
    with pytest.raises(InputError, match=r"columns q1_mm..q6_mm are in mm but machine.yaml "
                                         r"declares readings: \{unit: rev\}"):
        read_readings(_readings_csv(tmp_path / "mm.csv", np.ones((2, 6)), "mm"), m)
    mm = parse_machine(CUBIC, "cubic.yaml")
    with pytest.raises(InputError, match=r"columns q1_rev..q6_rev are in rev but cubic.yaml "
                                         r"declares readings: \{unit: mm\} \(leg lengths\); "
                                         r"rename the columns to q1_mm..q6_mm"):
        read_readings(_readings_csv(tmp_path / "rev.csv", np.ones((2, 6)), "rev"), mm)
    # any length suffix still reads when the legs read lengths
    read_readings(_readings_csv(tmp_path / "m.csv", np.full((2, 6), 0.4), "m"), mm)


def test_a_unit_set_by_one_data_file_binds_the_next(tmp_path):
    m = parse_machine(REV, "rev.yaml")
    first = _readings_csv(tmp_path / "a.csv", np.ones((2, 6)), "rev")
    read_readings(first, m)
    with pytest.raises(InputError, match=r"columns q1_deg..q6_deg are in deg but the legs of "
                                         r"rev.yaml read in rev \(the unit of .*a.csv"):
        read_readings(_readings_csv(tmp_path / "b.csv", np.ones((2, 6)), "deg"), m)


def test_undeclared_readings_in_mixed_units_are_refused(tmp_path):
    m = parse_machine(REV, "rev.yaml")
    path = tmp_path / "d.csv"
    path.write_text("q1_rev,q2_rev,q3_mm,q4_rev,q5_rev,q6_rev\n1,1,1,1,1,1\n")
    with pytest.raises(InputError, match="the leg readings must share one unit"):
        read_readings(path, m)
    assert m.reading_unit == "mm"                              # nothing adopted


# -- command line ---------------------------------------------------------------------------------

@pytest.fixture()
def first_dir(tmp_path):
    (tmp_path / "first.yaml").write_text(FIRST)
    (tmp_path / "rev.yaml").write_text(REV)
    (tmp_path / "declared.yaml").write_text(REV_DECLARED)
    (tmp_path / "poses.csv").write_text(POSES_CSV)
    return tmp_path


def test_cli_ik_fk_errors_with_base_and_platform_only(first_dir):
    d = first_dir
    before = digest(d / "first.yaml")
    proc = run("ik", "first.yaml", "poses.csv", "-o", "q.csv", cwd=d)
    assert proc.returncode == 0, proc.stderr
    header, q = _table(d / "q.csv")
    assert header == [f"q{j}_mm" for j in range(1, 7)]
    m = parse_machine(FIRST)
    P, R = _pose(POSES)
    np.testing.assert_allclose(q * 1e-3, m.ik(P, R), rtol=1e-14)    # the leg lengths
    proc = run("fk", "first.yaml", "q.csv", "-o", "back.csv", cwd=d)
    assert proc.returncode == 0, proc.stderr
    header, back = _table(d / "back.csv")
    assert header == ["x_mm", "y_mm", "z_mm", "psi_deg", "theta_deg", "phi_deg"]
    np.testing.assert_allclose(back, POSES, atol=1e-9)
    proc = run("errors", "first.yaml", "--trajectory", "circle", "--radius", "100mm",
               "--height", "410mm", "--samples", "12", "-o", "err.csv", cwd=d)
    assert proc.returncode == 0, proc.stderr
    header, err = _table(d / "err.csv")
    assert header[:7] == ["angle_deg"] + [f"f{i}_N" for i in range(1, 7)]
    assert len(err) == 12 and np.all(np.isfinite(err))
    assert digest(d / "first.yaml") == before


def test_cli_fk_of_rev_columns_without_readings_declared(first_dir):
    d = first_dir
    assert run("ik", "declared.yaml", "poses.csv", "-o", "q.csv", cwd=d).returncode == 0
    assert _table(d / "q.csv")[0] == [f"q{j}_rev" for j in range(1, 7)]
    proc = run("fk", "rev.yaml", "q.csv", "-o", "back.csv", cwd=d)
    assert proc.returncode == 0, proc.stderr
    np.testing.assert_allclose(_table(d / "back.csv")[1], POSES, atol=1e-9)


def test_cli_declared_unit_disagreeing_with_columns(first_dir):
    d = first_dir
    q = parse_machine(REV_DECLARED).ik(*_pose(POSES))
    _readings_csv(d / "data.csv", q, "deg")
    proc = run("fk", "declared.yaml", "data.csv", "-o", "out.csv", cwd=d)
    assert_input_error(proc, "data.csv: columns q1_deg..q6_deg are in deg but declared.yaml "
                             "declares readings: {unit: rev}; rename the columns to "
                             "q1_rev..q6_rev or change readings.unit")
    assert not (d / "out.csv").exists()


def test_cli_calibrated_file_of_rev_data_is_self_contained(first_dir):
    d = first_dir
    proc = run("simulate", "declared.yaml", "--scenario", "pose", "-o", "pose.csv", cwd=d)
    assert proc.returncode == 0, proc.stderr
    assert (d / "pose.csv").read_text().startswith("q1_rev,")
    proc = run("calibrate", "rev.yaml", "pose.csv", "-o", "cal.yaml", cwd=d)
    assert proc.returncode == 0, proc.stderr
    text = (d / "cal.yaml").read_text()
    assert "readings: {unit: rev}" in text
    cal = load_machine(d / "cal.yaml")
    assert cal.reading_unit == "rev" and cal.reading_unit_declared
    gains = cal.legs()[3]
    np.testing.assert_allclose(gains, 0.01, rtol=0.05)             # 10 mm per rev, in m/rev
    # it loads back to the same machine and serves fk of the same data
    again = d / "again.yaml"
    again.write_text(machine_to_text(cal))
    np.testing.assert_array_equal(load_machine(again).u, cal.u)
    proc = run("fk", "cal.yaml", "pose.csv", "-o", "fk.csv", cwd=d)
    assert proc.returncode == 0, proc.stderr
