"""Machine files (YAML) and data files (CSV): round trips and clear errors (SPEC 6)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from pkmcal.errors import InputError
from pkmcal.io import (
    atomic_write_text,
    load_machine,
    machine_to_text,
    parse_machine,
    read_constraint_link,
    read_joints,
    read_poses,
    read_table,
    save_machine,
    write_joints,
    write_poses,
)
from pkmcal.kinematics import matrix_from_euler, quaternion_from_matrix
from pkmcal.machines import default_hexaslide, paper_table1_deviations

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "hexaslide_default.yaml"


def assert_same_machine(a, b, rtol=4e-16):
    assert a.kind == b.kind
    assert a.parameters.names == b.parameters.names
    np.testing.assert_allclose(a.u, b.u, rtol=rtol, atol=1e-18)
    assert a.constraint_link_length == pytest.approx(b.constraint_link_length, rel=rtol)
    np.testing.assert_allclose(a.home[0], b.home[0], rtol=rtol, atol=1e-17)
    np.testing.assert_allclose(a.home[1], b.home[1], rtol=0, atol=1e-15)


def perturbed_machine():
    m = default_hexaslide()
    rng = np.random.default_rng(7)
    m = m.with_parameters(m.u + paper_table1_deviations(m.parameters)
                          + 1e-4 * rng.standard_normal(len(m.u)))
    m.home = (np.array([0.01, -0.02, 0.29]), matrix_from_euler([0.1, -0.05, 0.2]))
    m.constraint_link_length = 0.30012345678901234
    return m


# -- machine files -------------------------------------------------------------------------


def test_example_file_is_the_default_machine():
    loaded = load_machine(EXAMPLE)
    assert_same_machine(loaded, default_hexaslide())
    assert loaded.name == default_hexaslide().name
    assert loaded.file_units == {"length": "mm", "angle": "deg"}
    assert machine_to_text(default_hexaslide(), loaded.file_units) == EXAMPLE.read_text()


@pytest.mark.parametrize("units", [{"length": "mm", "angle": "deg"},
                                   {"length": "m", "angle": "rad"},
                                   {"length": "mm", "angle": "rad"}])
def test_save_load_round_trip_is_lossless(tmp_path, units):
    m = perturbed_machine()
    path = save_machine(m, tmp_path / "m.yaml", units=units)
    loaded = load_machine(path)
    assert_same_machine(loaded, m, rtol=1e-15)
    assert loaded.file_units == units
    # a second round trip through the loaded machine's own units is stable
    again = load_machine(save_machine(loaded, tmp_path / "m2.yaml"))
    assert_same_machine(again, m, rtol=1e-15)
    assert sorted(os.listdir(tmp_path)) == ["m.yaml", "m2.yaml"]   # no temporary files left


def test_calibration_metadata_and_home_are_written(tmp_path):
    m = default_hexaslide()
    meta = {"method": "ml", "rms_um": np.float64(0.5), "rank": np.int64(48),
            "unidentifiable": ["3 x rotation of the base frame about O"], "ok": np.bool_(True)}
    loaded = load_machine(save_machine(m, tmp_path / "c.yaml", calibration=meta))
    assert loaded.calibration_info == {"method": "ml", "rms_um": 0.5, "rank": 48,
                                       "unidentifiable": ["3 x rotation of the base frame about O"],
                                       "ok": True}
    assert "home:" in (tmp_path / "c.yaml").read_text()


def test_machine_without_optional_keys_loads():
    text = EXAMPLE.read_text()
    text = "\n".join(line for line in text.splitlines()
                     if not line.startswith(("name:", "constraint_link:", "home:")))
    m = parse_machine(text, "x.yaml")
    assert m.constraint_link_length is None and m.name == ""
    assert np.all(np.isfinite(m.ik(*m.home)))


def test_numbers_without_decimal_point_and_exponents_are_read():
    text = EXAMPLE.read_text().replace("l: 450.0}", "l: 4.5e2}", 1).replace(
        "constraint_link: {length: 300.0}", "constraint_link: {length: 300}")
    m = parse_machine(text, "x.yaml")
    assert m.chains()[4][0] == pytest.approx(0.45, rel=1e-15)
    assert m.constraint_link_length == pytest.approx(0.3, rel=1e-15)


BAD_MACHINES = [
    # (description, edit of the example text, words the message must contain)
    ("yaml syntax", lambda t: t.replace("alpha: -80.0,", "alpha: [-80.0,"),
     ["YAML syntax error", "line 9"]),
    ("not a mapping", lambda t: "- 1\n- 2\n", ["expected a mapping"]),
    ("empty", lambda t: "", ["empty"]),
    ("missing key", lambda t: t.replace(", l: 450.0}", "}", 1), ["chains[0].l", "missing key"]),
    ("unknown key", lambda t: t.replace("name:", "nmae:"), ["nmae", "unknown key", "line 3"]),
    ("unknown nested key", lambda t: t.replace("l: 450.0}", "l: 450.0, lenght: 1}", 1),
     ["chains[0].lenght", "unknown key", "a0, alpha, beta, b, l"]),
    ("five chains", lambda t: "\n".join(x for x in t.splitlines() if "alpha: 80.0" not in x),
     ["chains", "exactly 6 chains, got 5"]),
    ("seven chains", lambda t: t.replace("home:", "  - {a0: [0, 0, 0], alpha: 0, beta: 1, "
                                         "b: [0, 0, 0], l: 450}\nhome:"),
     ["chains", "exactly 6 chains, got 7"]),
    ("text number", lambda t: t.replace("alpha: -80.0", "alpha: abc"),
     ["chains[2].alpha", "not a number", "'abc'", "line 9"]),
    ("quoted number", lambda t: t.replace("alpha: -80.0", 'alpha: "280"'),
     ["chains[2].alpha", "not a number"]),
    ("bool", lambda t: t.replace("beta: 70.0", "beta: true", 1), ["chains[0].beta",
                                                                  "not a number"]),
    ("nan", lambda t: t.replace("alpha: -80.0", "alpha: .nan"),
     ["chains[2].alpha", "finite number"]),
    ("inf", lambda t: t.replace("l: 450.0}", "l: .inf}", 1), ["chains[0].l", "finite"]),
    ("negative length", lambda t: t.replace("l: 450.0}", "l: -450.0}", 1),
     ["chains[0].l", "> 0"]),
    ("missing units", lambda t: "\n".join(x for x in t.splitlines()
                                          if not x.startswith("units")),
     ["units", "missing key"]),
    ("unknown length unit", lambda t: t.replace("length: mm", "length: cm"),
     ["units.length", "unknown length unit 'cm'", "mm, m"]),
    ("unknown angle unit", lambda t: t.replace("angle: deg", "angle: grad"),
     ["units.angle", "'grad'"]),
    ("short vector", lambda t: t.replace("b: [84.8528137423857, -84.85281374238569, 0.0]",
                                         "b: [84.85, -84.85]"),
     ["chains[0].b", "expected 3 numbers, got 2"]),
    ("home length", lambda t: t.replace("home: [0.0, 0.0, 300.0,", "home: [0.0, 300.0,"),
     ["home", "6 numbers"]),
    ("version", lambda t: t.replace("pkmcal: 1", "pkmcal: 2"), ["pkmcal", "version 2"]),
    ("no version", lambda t: t.replace("pkmcal: 1\n", ""), ["pkmcal", "missing key"]),
    ("machine type", lambda t: t.replace("machine: hexaslide", "machine: hexapod"),
     ["machine", "unknown machine type 'hexapod'", "hexaslide"]),
    ("duplicate key", lambda t: t.replace("units:", "name: again\nunits:"),
     ["duplicate key 'name'"]),
    ("home unreachable", lambda t: t.replace("home: [0.0, 0.0, 300.0,", "home: [0.0, 0.0, 3000.0,"),
     ["home", "cannot be reached"]),
]


@pytest.mark.parametrize("edit, words", [b[1:] for b in BAD_MACHINES],
                         ids=[b[0] for b in BAD_MACHINES])
def test_bad_machine_file_names_key_and_problem(tmp_path, edit, words):
    path = tmp_path / "bad.yaml"
    text = edit(EXAMPLE.read_text())
    path.write_text(text)
    with pytest.raises(InputError) as info:
        load_machine(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    for w in words:
        assert w in message
    assert path.read_text() == text   # input never modified


def test_missing_machine_file(tmp_path):
    with pytest.raises(InputError, match="machine file not found"):
        load_machine(tmp_path / "nope.yaml")


def test_atomic_write_leaves_old_file_and_no_temporary_on_failure(tmp_path, monkeypatch):
    path = tmp_path / "out.txt"
    atomic_write_text(path, "old\n")

    def boom(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_text(path, "new\n")
    assert path.read_text() == "old\n"
    assert os.listdir(tmp_path) == ["out.txt"]
    with pytest.raises(FileNotFoundError):
        atomic_write_text(tmp_path / "no" / "dir.txt", "x")


# -- data files ----------------------------------------------------------------------------


@pytest.mark.parametrize("unit", ["mm", "m", "um"])
def test_joints_round_trip(tmp_path, unit):
    rng = np.random.default_rng(1)
    q = rng.uniform(0.2, 0.5, (20, 6))
    passive = np.arange(20) % 6
    write_joints(tmp_path / "j.csv", q, unit=unit, extra={"passive": passive + 1})
    q2, rows, extra = read_joints(tmp_path / "j.csv", 6)
    np.testing.assert_allclose(q2, q, rtol=4e-16, atol=0)
    assert rows.tolist() == list(range(2, 22))
    assert extra["passive"][:3] == ["1", "2", "3"]
    m = default_hexaslide()
    data = read_constraint_link(tmp_path / "j.csv", m)
    assert data.passive.tolist() == passive.tolist()
    assert data.link_length == m.constraint_link_length


def test_rows_are_file_lines_with_comments_and_blank_lines(tmp_path):
    path = tmp_path / "j.csv"
    path.write_text("# tracker export\nq1_mm,q2_mm\n1,2\n\n3,4\n")
    q, rows, _ = read_joints(path, 2)
    assert rows.tolist() == [3, 5]
    np.testing.assert_allclose(q, [[1e-3, 2e-3], [3e-3, 4e-3]])
    header, table = read_table(path)
    assert header == ["q1_mm", "q2_mm"] and table[1] == (5, ["3", "4"])


def test_poses_round_trip_euler_and_quaternion(tmp_path):
    rng = np.random.default_rng(2)
    P = rng.uniform(-0.1, 0.1, (15, 3)) + [0, 0, 0.3]
    R = matrix_from_euler(rng.uniform(-0.3, 0.3, (15, 3)))
    write_poses(tmp_path / "p.csv", P, R, "mm", "deg")
    assert read_table(tmp_path / "p.csv")[0] == ["x_mm", "y_mm", "z_mm", "psi_deg",
                                                 "theta_deg", "phi_deg"]
    P2, R2, rows = read_poses(tmp_path / "p.csv")
    np.testing.assert_allclose(P2, P, rtol=1e-15)
    np.testing.assert_allclose(R2, R, atol=1e-15)
    Q = quaternion_from_matrix(R)
    lines = ["x_m,y_m,z_m,qx,qy,qz,qw"] + [",".join(map(repr, [*p, *qq]))
                                          for p, qq in zip(P.tolist(), Q.tolist(), strict=True)]
    (tmp_path / "q.csv").write_text("\n".join(lines) + "\n")
    P3, R3, _ = read_poses(tmp_path / "q.csv")
    np.testing.assert_allclose(P3, P, rtol=0, atol=0)
    np.testing.assert_allclose(R3, R, atol=1e-15)


GOOD = "q1_mm,q2_mm,q3_mm,q4_mm,q5_mm,q6_mm,passive\n1,2,3,4,5,6,1\n1,2,3,4,5,6,2\n"
BAD_CSV = [
    ("missing column", GOOD.replace("q3_mm", "r3_mm"), ["missing column q3_<unit>"]),
    ("unknown unit", GOOD.replace("q2_mm", "q2_in"), ["'q2_in'", "unknown unit suffix 'in'"]),
    ("wrong quantity", GOOD.replace("q2_mm", "q2_deg"), ["'q2_deg'", "angle unit"]),
    ("no unit", GOOD.replace("q2_mm", "q2"), ["'q2'", "no unit suffix", "q2_mm"]),
    ("two columns", GOOD.replace("passive", "q1_m"), ["more than one column for q1"]),
    ("duplicate name", GOOD.replace("passive", "q6_mm"), ["'q6_mm' appears twice"]),
    ("nan", GOOD.replace("1,2,3,4,5,6,2", "1,2,nan,4,5,6,2"),
     ["row 3, column q3_mm", "not a finite number"]),
    ("text", GOOD.replace("1,2,3,4,5,6,2", "1,2,3,4,x5,6,2"),
     ["row 3, column q5_mm", "not a number: 'x5'"]),
    ("empty value", GOOD.replace("1,2,3,4,5,6,2", "1,,3,4,5,6,2"),
     ["row 3, column q2_mm", "empty value"]),
    ("empty file", "", ["empty file"]),
    ("header only", GOOD.splitlines()[0] + "\n", ["no data rows"]),
    ("short row", GOOD.replace("1,2,3,4,5,6,2", "1,2,3,4,5,6"),
     ["row 3", "6 field(s)", "7 columns"]),
    ("passive 0", GOOD.replace("6,1\n", "6,0\n"), ["row 2, column passive", "1..6"]),
    ("passive 7", GOOD.replace("6,2\n", "6,7\n"), ["row 3, column passive", "1..6"]),
    ("passive 1.5", GOOD.replace("6,2\n", "6,1.5\n"), ["row 3, column passive"]),
]


@pytest.mark.parametrize("text, words", [b[1:] for b in BAD_CSV], ids=[b[0] for b in BAD_CSV])
def test_bad_data_file_names_file_row_and_column(tmp_path, text, words):
    path = tmp_path / "data.csv"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        read_constraint_link(path, default_hexaslide())
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    for w in words:
        assert w in message
    assert path.read_text() == text


def test_constraint_link_needs_the_link_length(tmp_path):
    path = tmp_path / "data.csv"
    path.write_text(GOOD)
    m = default_hexaslide()
    m.constraint_link_length = None
    with pytest.raises(InputError, match=r"constraint_link: \{length"):
        read_constraint_link(path, m)


def test_poses_need_an_orientation(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("x_mm,y_mm,z_mm\n0,0,300\n")
    with pytest.raises(InputError, match="missing orientation columns"):
        read_poses(path)
    path.write_text("x_mm,y_mm,z_mm,psi_deg,theta_deg\n0,0,300,0,0\n")
    with pytest.raises(InputError, match="missing column phi"):
        read_poses(path)
    path.write_text("x_mm,y_mm,z_mm,qx,qy,qz,qw\n0,0,300,0,0,0,0\n")
    with pytest.raises(InputError, match="row 2.*quaternion is zero"):
        read_poses(path)
