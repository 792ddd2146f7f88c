"""Machine files (YAML) and data files (CSV): round trips and clear errors (SPEC 6)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from pkmcal.errors import InputError
from pkmcal.instruments.setups import Setups
from pkmcal.instruments.tracker import TrackerSetup
from pkmcal.io import (
    atomic_write_text,
    load_machine,
    load_machine_file,
    machine_to_text,
    parse_machine,
    parse_machine_file,
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
    # numbers: decimal text and unit factors, each one correctly rounded operation (IEEE, the
    # same on every CPU): 2 ulps. The home rotation goes through sin/cos (libm, CPU): 1e-13.
    assert a.kind == b.kind
    assert a.parameters.names == b.parameters.names
    np.testing.assert_allclose(a.u, b.u, rtol=rtol, atol=1e-18)
    assert a.constraint_link_length == pytest.approx(b.constraint_link_length, rel=rtol)
    np.testing.assert_allclose(a.home[0], b.home[0], rtol=rtol, atol=1e-17)
    np.testing.assert_allclose(a.home[1], b.home[1], rtol=0, atol=1e-13)


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


def assert_bad_machine_file(tmp_path, example, edit, words):
    """An edited example file: InputError naming the file and ``words``; input unchanged."""
    path = tmp_path / "bad.yaml"
    text = edit(example.read_text())
    assert text != example.read_text(), "the edit did not apply"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        load_machine(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    for w in words:
        assert w in message, message
    assert path.read_text() == text   # input never modified


@pytest.mark.parametrize("edit, words", [b[1:] for b in BAD_MACHINES],
                         ids=[b[0] for b in BAD_MACHINES])
def test_bad_machine_file_names_key_and_problem(tmp_path, edit, words):
    assert_bad_machine_file(tmp_path, EXAMPLE, edit, words)


def test_missing_machine_file(tmp_path):
    with pytest.raises(InputError, match="machine file not found"):
        load_machine(tmp_path / "nope.yaml")


def test_atomic_write_leaves_old_file_and_no_temporary_on_failure(tmp_path, monkeypatch):
    path = tmp_path / "out.txt"
    atomic_write_text(path, "old\n")

    def boom(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(InputError, match=r"out\.txt: cannot write: disk full"):
        atomic_write_text(path, "new\n")
    assert path.read_text() == "old\n"
    assert os.listdir(tmp_path) == ["out.txt"]
    with pytest.raises(InputError, match="does not exist"):
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
    np.testing.assert_allclose(P2, P, rtol=1e-15)              # decimal text: IEEE, exact-ish
    np.testing.assert_allclose(R2, R, atol=1e-13)              # via Euler angles: sin/cos
    Q = quaternion_from_matrix(R)
    lines = ["x_m,y_m,z_m,qx,qy,qz,qw"] + [",".join(map(repr, [*p, *qq]))
                                          for p, qq in zip(P.tolist(), Q.tolist(), strict=True)]
    (tmp_path / "q.csv").write_text("\n".join(lines) + "\n")
    P3, R3, _ = read_poses(tmp_path / "q.csv")
    np.testing.assert_allclose(P3, P, rtol=0, atol=0)
    np.testing.assert_allclose(R3, R, atol=1e-13)              # via a quaternion


GOOD = "q1_mm,q2_mm,q3_mm,q4_mm,q5_mm,q6_mm,passive\n1,2,3,4,5,6,1\n1,2,3,4,5,6,2\n"
BAD_CSV = [
    ("missing column", GOOD.replace("q3_mm", "r3_mm"), ["missing column q3_<unit>"]),
    ("unknown unit", GOOD.replace("q2_mm", "q2_ft"), ["'q2_ft'", "unknown unit suffix 'ft'"]),
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


# -- Delta machine files and laser-tracker data (SPEC 2.2, 6) --------------------------------

DELTA_EXAMPLE = EXAMPLE.parent / "delta_default.yaml"


def perturbed_delta():
    from pkmcal.kinematics import matrix_from_rotvec
    from pkmcal.machines import default_delta

    m = default_delta()
    rng = np.random.default_rng(11)
    m = m.with_parameters(m.u + 1e-3 * rng.standard_normal(len(m.u)))
    m.home = (np.array([0.012, -0.034, -0.7612345678901234]), np.eye(3))
    return m, Setups({"tracker": TrackerSetup((matrix_from_rotvec([0.1, -0.2, 2.3]),
                                               np.array([2.1, -1.3, -1.41])))})


def assert_same_delta(a, b, rtol=1e-14, sa=None, sb=None):
    """Two Delta robots (and their tracker frames) the same to ``rtol`` of each quantity's
    scale."""
    assert a.kind == b.kind == "delta"
    assert a.parameters.names == b.parameters.names

    def close(x, y):
        x, y = np.asarray(x, float), np.asarray(y, float)
        scale = max(np.abs(x).max(initial=0.0), np.abs(y).max(initial=0.0))
        np.testing.assert_allclose(x, y, rtol=rtol, atol=rtol * scale)

    close(a.u, b.u)
    for attr in ("a", "b", "l1", "l2", "smr_offset"):
        close(getattr(a, attr), getattr(b, attr))
    close(a.leg_angles, b.leg_angles)
    close(a.home[0], b.home[0])
    ta, tb = ((None if s is None or "tracker" not in s else s["tracker"].base_from_tracker)
              for s in (sa, sb))
    assert (ta is None) == (tb is None)
    if ta is not None:
        close(ta[0], tb[0])
        close(ta[1], tb[1])


def test_delta_example_file_is_the_default_delta():
    from pkmcal.machines import default_delta

    loaded, setups = load_machine_file(DELTA_EXAMPLE)
    default = default_delta()
    assert_same_delta(loaded, default, rtol=1e-15, sa=setups, sb=Setups())
    assert loaded.name == default.name and loaded.file_units == {"length": "mm", "angle": "deg"}
    assert machine_to_text(default_delta(), loaded.file_units) == DELTA_EXAMPLE.read_text()
    np.testing.assert_allclose(loaded.fk(loaded.ik(loaded.home[0])).P[0], [0, 0, -0.75],
                               atol=1e-12)


@pytest.mark.parametrize("units", [{"length": "mm", "angle": "deg"},
                                   {"length": "m", "angle": "rad"}])
def test_delta_save_load_round_trip_is_lossless(tmp_path, units):
    m, setups = perturbed_delta()
    loaded, back = load_machine_file(save_machine(m, tmp_path / "d.yaml", units=units,
                                                  calibration={"method": "tracker-joint"},
                                                  setups=setups))
    assert_same_delta(loaded, m, sa=back, sb=setups)
    assert loaded.calibration_info == {"method": "tracker-joint"}
    text = (tmp_path / "d.yaml").read_text()
    assert "tracker: {rotation: [[" in text and "home: [" in text and "# x, y, z\n" in text
    again, twice = load_machine_file(save_machine(loaded, tmp_path / "d2.yaml", setups=back))
    assert_same_delta(again, m, sa=twice, sb=setups)
    assert sorted(os.listdir(tmp_path)) == ["d.yaml", "d2.yaml"]


def test_delta_optional_keys():
    text = "\n".join(line for line in DELTA_EXAMPLE.read_text().splitlines()
                     if not line.startswith(("legs:", "  - ", "smr_offset", "home", "name")))
    m, setups = parse_machine_file(text, "d.yaml")
    assert m.smr_offset == 0.0 and "tracker" not in setups and not np.any(m.u)
    assert np.all(np.isfinite(m.ik(m.home[0])))
    # every key of a leg is optional; a six-number home with zero angles is accepted
    m = parse_machine(DELTA_EXAMPLE.read_text().replace(
        "{da: [0.0, 0.0, 0.0], dtheta: 0.0,", "{dtheta: 0.5,", 1).replace(
        "home: [0.0, 0.0, -750.0]", "home: [0.0, 0.0, -740.0, 0, 0, 0]"), "d.yaml")
    assert m.u[3] == pytest.approx(np.deg2rad(0.5)) and m.home[0][2] == pytest.approx(-0.74)
    # a rotation with 6 digits is accepted and made orthonormal
    m, setups = parse_machine_file(DELTA_EXAMPLE.read_text() + "tracker: {rotation: [[0.866025, "
                                   "-0.5, 0], [0.5, 0.866025, 0], [0, 0, 1]], translation: "
                                   "[2000, 0, 0]}\n", "d.yaml")
    R, t = setups["tracker"].base_from_tracker
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-13)
    np.testing.assert_allclose(t, [2.0, 0, 0])


TRACKER_LINE = "tracker: {rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]], translation: [2000, 0, 0]}"
LEG0 = "  - {da: [0.0, 0.0, 0.0], dtheta: 0.0, dl1: 0.0, dl2: 0.0, db: [0.0, 0.0, 0.0]}\n"
BAD_DELTAS = [
    ("two legs", lambda t: t.replace(LEG0, "", 1), ["legs", "exactly 3 legs, got 2", "line 11"]),
    ("four legs", lambda t: t.replace(LEG0, LEG0 + LEG0, 1), ["exactly 3 legs, got 4"]),
    ("text dtheta", lambda t: t.replace("dtheta: 0.0", "dtheta: abc", 2),
     ["legs[0].dtheta", "not a number: 'abc'", "line 12", "legs[1].dtheta"]),
    ("unknown leg key", lambda t: t.replace("dl2: 0.0,", "dl3: 0.0,", 1),
     ["legs[0].dl3", "unknown key", "da, dtheta, dl1, dl2, db"]),
    ("short da", lambda t: t.replace("da: [0.0, 0.0, 0.0]", "da: [0.0, 0.0]", 1),
     ["legs[0].da", "expected 3 numbers, got 2"]),
    ("missing forearm", lambda t: t.replace("forearm: 800.0\n", ""),
     ["forearm", "missing key", "l2"]),
    ("negative arm", lambda t: t.replace("upper_arm: 300.0", "upper_arm: -300.0"),
     ["upper_arm", "> 0", "line 7"]),
    ("nan radius", lambda t: t.replace("base_radius: 200.0", "base_radius: .nan"),
     ["base_radius", "finite"]),
    ("two leg angles", lambda t: t.replace("[90.0, 180.0, -90.0]", "[90.0, 180.0]"),
     ["leg_angles", "expected 3 numbers, got 2"]),
    ("quoted smr offset", lambda t: t.replace("smr_offset: 30.0", "smr_offset: '30'"),
     ["smr_offset", "not a number"]),
    ("home with rotation", lambda t: t.replace("-750.0]", "-750.0, 1.0, 0, 0]"),
     ["home", "does not rotate", "line 15"]),
    ("home of 4", lambda t: t.replace("-750.0]", "-750.0, 0]"),
     ["home", "expected 3 numbers [x, y, z]", "got 4"]),
    ("home unreachable", lambda t: t.replace("-750.0]", "-2750.0]"),
     ["home", "cannot be reached by leg(s) 1, 2, 3"]),
    ("not a rotation", lambda t: t + TRACKER_LINE.replace("[0, 1, 0]", "[0, 2, 0]") + "\n",
     ["tracker.rotation", "not a rotation matrix", "line 16"]),
    ("reflection", lambda t: t + TRACKER_LINE.replace("[0, 0, 1]]", "[0, 0, -1]]") + "\n",
     ["tracker.rotation", "determinant +1"]),
    ("two rows", lambda t: t + TRACKER_LINE.replace(", [0, 0, 1]]", "]") + "\n",
     ["tracker.rotation", "3x3 matrix", "got 2 rows"]),
    ("no translation", lambda t: t + TRACKER_LINE.replace(", translation: [2000, 0, 0]", "")
     + "\n", ["tracker.translation", "missing key"]),
    ("hexaslide key", lambda t: t.replace("legs:", "chains:"), ["chains", "unknown key"]),
    ("unknown unit", lambda t: t.replace("angle: deg", "angle: grad"),
     ["units.angle", "'grad'"]),
]


@pytest.mark.parametrize("edit, words", [b[1:] for b in BAD_DELTAS],
                         ids=[b[0] for b in BAD_DELTAS])
def test_bad_delta_file_names_key_and_problem(tmp_path, edit, words):
    assert_bad_machine_file(tmp_path, DELTA_EXAMPLE, edit, words)


@pytest.mark.parametrize("units", [("deg", "mm"), ("rad", "m"), ("urad", "um")])
def test_tracker_data_round_trip(tmp_path, units):
    from pkmcal.io import joint_quantity, read_tracker, write_tracker
    from pkmcal.machines import default_delta

    m = default_delta()
    assert joint_quantity(m) == "angle" and joint_quantity(default_hexaslide()) == "length"
    rng = np.random.default_rng(3)
    q = rng.uniform(-0.5, 0.5, (12, 3))
    pts = rng.uniform(-3, 3, (12, 3))
    write_tracker(tmp_path / "t.csv", q, pts, *units)
    header = read_table(tmp_path / "t.csv")[0]
    assert header == [f"q{i}_{units[0]}" for i in (1, 2, 3)] + \
        [f"m{c}_{units[1]}" for c in "xyz"]
    data = read_tracker(tmp_path / "t.csv", m)
    np.testing.assert_allclose(data.q, q, rtol=1e-15)
    np.testing.assert_allclose(data.m, pts, rtol=1e-15)
    assert data.rows.tolist() == list(range(2, 14)) and data.source == str(tmp_path / "t.csv")


def test_positions_for_a_platform_that_does_not_rotate(tmp_path):
    from pkmcal.io import read_positions, write_positions

    P = np.array([[0.1, -0.2, -0.75], [0.0, 0.05, -0.7]])
    write_positions(tmp_path / "p.csv", P, "mm")
    assert (tmp_path / "p.csv").read_text().startswith("x_mm,y_mm,z_mm\n")
    P2, rows = read_positions(tmp_path / "p.csv")
    np.testing.assert_allclose(P2, P, rtol=1e-15)
    assert rows.tolist() == [2, 3]
    write_poses(tmp_path / "z.csv", P, np.broadcast_to(np.eye(3), (2, 3, 3)))
    np.testing.assert_allclose(read_positions(tmp_path / "z.csv")[0], P, rtol=1e-15)
    write_poses(tmp_path / "r.csv", P, matrix_from_euler([[0, 0, 0], [0.1, 0, 0]]))
    with pytest.raises(InputError, match=r"r.csv: row 3: .*does not rotate"):
        read_positions(tmp_path / "r.csv")


TRACKER_GOOD = ("q1_deg,q2_deg,q3_deg,mx_mm,my_mm,mz_mm\n"
                "-10,-20,-30,2500,200,600\n-11,-21,-31,2510,210,610\n")
BAD_TRACKER_CSV = [
    ("missing mx", TRACKER_GOOD.replace("mx_mm", "nx_mm"), ["missing column mx_<unit>",
                                                           "mx_mm"]),
    ("unknown unit", TRACKER_GOOD.replace("mz_mm", "mz_ft"), ["'mz_ft'", "unknown unit"]),
    ("length unit for an arm", TRACKER_GOOD.replace("q2_deg", "q2_mm"),
     ["'q2_mm'", "length unit", "q2 is an angle"]),
    ("angle unit for a point", TRACKER_GOOD.replace("my_mm", "my_deg"),
     ["'my_deg'", "angle unit"]),
    ("no unit", TRACKER_GOOD.replace("q3_deg", "q3"), ["'q3'", "no unit suffix", "q3_rad"]),
    ("nan", TRACKER_GOOD.replace("2510", "nan"), ["row 3, column mx_mm", "not a finite"]),
    ("text", TRACKER_GOOD.replace("-21", "x"), ["row 3, column q2_deg", "not a number: 'x'"]),
    ("empty value", TRACKER_GOOD.replace(",610", ","), ["row 3, column mz_mm", "empty value"]),
    ("short row", TRACKER_GOOD.replace(",210,610", ""), ["row 3", "4 field(s)", "6 columns"]),
]


@pytest.mark.parametrize("text, words", [b[1:] for b in BAD_TRACKER_CSV],
                         ids=[b[0] for b in BAD_TRACKER_CSV])
def test_bad_tracker_file_names_file_row_and_column(tmp_path, text, words):
    from pkmcal.io import read_tracker
    from pkmcal.machines import default_delta

    path = tmp_path / "t.csv"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        read_tracker(path, default_delta())
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    for w in words:
        assert w in message, message
    assert path.read_text() == text
