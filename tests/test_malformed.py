"""Malformed input (issue 6, item 5): a catalogue of broken machine files and data files, each
with the message it must give (exit 2, one line, no traceback, no output, input unchanged),
and property-based tests of the readers (hypothesis)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clitools import assert_input_error, digest, run

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
MACHINES = {"h": EXAMPLES / "hexaslide_default.yaml", "d": EXAMPLES / "delta_default.yaml",
            "s": EXAMPLES / "cubic_6upu.yaml"}


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """Valid data of each machine (simulated) and the texts of the machine files."""
    d = tmp_path_factory.mktemp("malformed")
    out = {}
    for key, opts in (("h", ["--poses", "60"]), ("d", []), ("s", ["--poses", "20"])):
        path = d / f"{key}.csv"
        proc = run("simulate", MACHINES[key], *opts, "--seed", "1", "-o", path, cwd=d)
        assert proc.returncode == 0, proc.stderr
        out[key] = path.read_text().splitlines()
        out[key + ".yaml"] = MACHINES[key].read_text()
    out["dir"] = d
    return out


def _sub(text, old, new):
    assert old in text, old
    return text.replace(old, new, 1)


def _drop_column(lines, k):
    return [",".join(x for j, x in enumerate(line.split(",")) if j != k) for line in lines]


def _set_first(line, value):
    return value + "," + line.split(",", 1)[1]


def _scale_columns(lines, names, factor):
    """The values of the columns ``names`` times ``factor`` (data written in another unit)."""
    header = lines[0].split(",")
    idx = {header.index(n) for n in names}
    return [lines[0]] + [",".join(repr(float(x) * factor) if j in idx else x
                                  for j, x in enumerate(line.split(","))) for line in lines[1:]]


def _euler_deg_under_rad(lines):
    """The quaternion columns as Euler angles in degrees, under ``*_rad`` columns."""
    from pkmcal.kinematics import euler_from_matrix, matrix_from_quaternion

    rows = [line.split(",") for line in lines]
    k = rows[0].index("qx")
    Q = np.array([[float(x) for x in r[k:k + 4]] for r in rows[1:]])
    angles = np.degrees(euler_from_matrix(matrix_from_quaternion(Q)))
    return [",".join(rows[0][:k] + ["psi_rad", "theta_rad", "phi_rad"])] + [
        ",".join(r[:k] + [repr(float(a)) for a in e]) for r, e in zip(rows[1:], angles,
                                                                       strict=True)]


def _scale_quaternion(lines, row, factor):
    """Row ``row`` (file line number) with its quaternion qx..qw times ``factor``."""
    out = list(lines)
    fields = out[row - 1].split(",")
    fields[-4:] = [repr(float(x) * factor) for x in fields[-4:]]
    out[row - 1] = ",".join(fields)
    return out


def _drop_first_leg(text):
    lines = text.splitlines()
    k = next(i for i, line in enumerate(lines) if line.strip().startswith("- {base"))
    return "\n".join(lines[:k] + lines[k + 1:]) + "\n"


def _drop_chains(text):
    keep = [line for line in text.splitlines()
            if not (line.startswith("  - {a0") or line.startswith("chains"))]
    return "\n".join(keep) + "\n"


# (name, machine, file kind, make(text or lines) -> new content, words the message must have)
YAML_CASES = [
    ("unknown key", "h", lambda t: t + "colour: red\n", ["colour: unknown key", "line 14"]),
    ("five chains", "h", lambda t: "\n".join(
        line for i, line in enumerate(t.splitlines()) if i != 11) + "\n",
     ["chains: expected exactly 6 chains, got 5"]),
    ("text in a number", "h", lambda t: _sub(t, "alpha: 160.0", "alpha: abc"),
     ["chains[0].alpha: not a number: 'abc'", "line 7"]),
    ("missing units", "h", lambda t: _sub(t, "units: {length: mm, angle: deg}\n", ""),
     ["units: missing key"]),
    ("unknown unit", "h", lambda t: _sub(t, "length: mm", "length: furlong"),
     ["units.length: unknown length unit 'furlong'"]),
    ("format version", "h", lambda t: _sub(t, "pkmcal: 1", "pkmcal: 2"),
     ["unsupported file format version 2"]),
    ("unknown machine type", "h", lambda t: _sub(t, "machine: hexaslide", "machine: hexapod9"),
     ["unknown machine type 'hexapod9'", "hexaslide, delta, stewart"]),
    ("vector of two", "h", lambda t: _sub(t, "b: [84.8528137423857, -84.85281374238569, 0.0]",
                                          "b: [84.85, 0.0]"),
     ["chains[0].b: expected 3 numbers, got 2"]),
    ("two leg angles", "d", lambda t: _sub(t, "leg_angles: [90.0, 180.0, -90.0]",
                                           "leg_angles: [90.0, 180.0]"),
     ["leg_angles: expected 3 numbers, got 2"]),
    ("negative forearm", "d", lambda t: _sub(t, "forearm: 800.0", "forearm: -800.0"),
     ["forearm: must be > 0", "line 8"]),
    ("five legs", "s", _drop_first_leg, ["legs: expected exactly 6 legs, got 5"]),
    ("YAML syntax", "h", lambda t: _sub(t, "alpha: 160.0,", "alpha: [160.0,"),
     ["line 7", "YAML syntax error"]),
    ("empty machine file", "h", lambda t: "", ["the file is empty"]),
    ("a list, not a mapping", "h", lambda t: "- 1\n- 2\n", ["expected a mapping of keys"]),
    ("home of five numbers", "h", lambda t: _sub(t, "home: [0.0, 0.0, 300.0, 0.0, 0.0, 0.0]",
                                                 "home: [0.0, 0.0, 300.0, 0.0, 0.0]"),
     ["home: expected 6 numbers"]),
    ("negative link length", "h", lambda t: _sub(t, "{length: 300.0}", "{length: -300.0}"),
     ["constraint_link.length: must be > 0"]),
    ("missing chains", "h", _drop_chains, ["chains: missing key"]),
    ("tracker not a rotation", "d", lambda t: t + "tracker: {rotation: [[1,0,0],[0,2,0],"
                                                  "[0,0,1]], translation: [0, 0, 0]}\n",
     ["tracker.rotation: not a rotation matrix"]),
    ("not UTF-8", "h", lambda t: b"\xff\xfe\x00garbage", ["not a text file"]),
]

CSV_CASES = [
    ("missing column", "h", lambda ls: _drop_column(ls, 5), ["missing column q6_<unit>"]),
    ("unknown unit suffix", "h", lambda ls: [_sub(ls[0], "q1_mm", "q1_furlong")] + ls[1:],
     ["column 'q1_furlong': unknown unit suffix 'furlong'"]),
    ("NaN", "h", lambda ls: ls[:3] + [_set_first(ls[3], "nan")] + ls[4:],
     ["row 4, column q1_mm: not a finite number"]),
    ("text in a number", "h", lambda ls: ls[:2] + [_set_first(ls[2], "12x")] + ls[3:],
     ["row 3, column q1_mm: not a number: '12x'"]),
    ("header only", "h", lambda ls: ls[:1], ["no data rows after the header"]),
    ("duplicate column", "h", lambda ls: [ls[0] + ",q1_mm"] + [x + ",1" for x in ls[1:]],
     ["column 'q1_mm' appears twice"]),
    ("ragged row", "h", lambda ls: ls[:4] + [ls[4].rsplit(",", 2)[0]] + ls[5:],
     ["row 5: 5 field(s), the header (row 1) has 7 columns"]),
    ("passive out of range", "h", lambda ls: ls[:2] + [ls[2].rsplit(",", 1)[0] + ",7"]
     + ls[3:], ["row 3, column passive: must be an actuator number 1..6"]),
    ("readings no pose explains", "h",
     lambda ls: ls[:2] + [",".join(["5000"] * 6) + ",1"] + ls[3:],
     ["no pose on the constraint sphere", "1 row(s): 3"]),
    ("three tracker points", "d", lambda ls: ls[:4],
     ["3 point(s): the tracker registration needs at least 4 points"]),
    ("collinear tracker points", "d", lambda ls: [ls[0]] + [ls[1]] * 5,
     ["lie on one line"]),
    ("zero quaternion", "s", lambda ls: ls[:2] + [ls[2].rsplit(",", 4)[0] + ",0,0,0,0"]
     + ls[3:], ["row 3, columns qx, qy, qz, qw: the quaternion is zero"]),
    ("empty data file", "h", lambda ls: [], ["empty file"]),
    # data in the wrong unit: refused by the readers' plausibility checks (not "did not
    # converge" or advice about the poses)
    ("Delta arm angles in rad under _deg", "d",
     lambda ls: _scale_columns(ls, ["q1_deg", "q2_deg", "q3_deg"], np.pi / 180),
     ["columns q1_deg, q2_deg, q3_deg", "the values look like rad, not deg",
      "rename the columns q1_rad, q2_rad, q3_rad"]),
    ("tracker points in m under _mm", "d",
     lambda ls: _scale_columns(ls, ["mx_mm", "my_mm", "mz_mm"], 1e-3),
     ["columns mx_mm, my_mm, mz_mm", "the tracker points are", "mm apart",
      "the values look like m, not mm", "mx_m, my_m, mz_m"]),
    ("Hexa Slide readings in m under _mm", "h",
     lambda ls: _scale_columns(ls, [f"q{j}_mm" for j in range(1, 7)], 1e-3),
     ["columns q1_mm..q6_mm", "the sliders read about 351 mm at the home pose",
      "the values look like m, not mm", "q1_m..q6_m"]),
    ("Stewart positions in m under _mm", "s",
     lambda ls: _scale_columns(ls, ["x_mm", "y_mm", "z_mm"], 1e-3),
     ["columns x_mm, y_mm, z_mm", "the measured positions are",
      "the values look like m, not mm", "x_m, y_m, z_m"]),
    ("Stewart leg readings in m under _mm", "s",
     lambda ls: _scale_columns(ls, [f"q{j}_mm" for j in range(1, 7)], 1e-3),
     ["columns q1_mm..q6_mm", "the legs read about", "the values look like m, not mm"]),
    ("Euler angles in deg under _rad", "s", _euler_deg_under_rad,
     ["columns psi_rad, theta_rad, phi_rad", "the measured orientations differ by",
      "the values look like deg, not rad", "psi_deg, theta_deg, phi_deg"]),
    ("quaternion not normalised", "s", lambda ls: _scale_quaternion(ls, 4, 1.01),
     ["row 4, columns qx, qy, qz, qw", "the quaternion has norm 1.01, not 1"]),
    ("reading of 1e300", "h", lambda ls: ls[:2] + [_set_first(ls[2], "1e300")] + ls[3:],
     ["row 3, column q1_mm: 1e300 is out of range"]),
    ("semicolon-separated", "h", lambda ls: [x.replace(",", ";") for x in ls],
     ["row 1", "looks semicolon-separated",
      "pkmcal reads comma-separated values with '.' decimals"]),
    ("semicolons and decimal commas", "h",
     lambda ls: [x.replace(",", ";").replace(".", ",") for x in ls],
     ["looks semicolon-separated", "'.' decimals"]),
    ("tab-separated", "h", lambda ls: [x.replace(",", "\t") for x in ls],
     ["looks tab-separated", "comma-separated values"]),
    ("Delta data for a Hexa Slide", "h", lambda ls: None,
     ["column 'q1_deg'", "an angle unit, q1 is a length"]),
]


def test_catalogue_size():
    assert len(YAML_CASES) + len(CSV_CASES) >= 25


@pytest.mark.parametrize("name,machine,make,words", YAML_CASES, ids=[c[0] for c in YAML_CASES])
def test_malformed_machine_file(name, machine, make, words, base, tmp_path):
    content = make(base[machine + ".yaml"])
    path = tmp_path / "machine.yaml"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    data = tmp_path / "data.csv"
    data.write_text("\n".join(base[machine]) + "\n")
    before = digest(path)
    proc = run("fk", path, data, "-o", "out.csv", cwd=tmp_path)
    assert_input_error(proc, "machine.yaml", *words)
    assert digest(path) == before
    assert not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize("name,machine,make,words", CSV_CASES, ids=[c[0] for c in CSV_CASES])
def test_malformed_data_file(name, machine, make, words, base, tmp_path):
    lines = make(list(base[machine]))
    if lines is None:                               # another machine's data
        lines = base["d"]
    path = tmp_path / "data.csv"
    path.write_text("\n".join(lines) + ("\n" if lines else ""))
    before = digest(path)
    proc = run("calibrate", MACHINES[machine], path, "-o", "cal.yaml", cwd=tmp_path)
    assert_input_error(proc, "data.csv", *words)
    assert digest(path) == before
    assert not (tmp_path / "cal.yaml").exists() and not (tmp_path / "cal.json").exists()


# -- property-based tests of the readers --------------------------------------------------------

finite = st.floats(min_value=-1e4, max_value=1e4, allow_nan=False, allow_infinity=False)
FAST = settings(max_examples=40, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture])


@FAST
@given(st.lists(st.lists(finite, min_size=3, max_size=3), min_size=1, max_size=20),
       st.sampled_from(["mm", "m", "um"]))
def test_joints_round_trip(tmp_path, rows, unit):
    from pkmcal.io import read_joints, write_joints

    q = np.array(rows) * 1e-3
    path = tmp_path / "q.csv"
    write_joints(path, q, unit=unit)
    back, lines, _ = read_joints(path, 3)
    np.testing.assert_allclose(back, q, rtol=1e-12, atol=1e-18)
    assert lines.tolist() == list(range(2, len(q) + 2))


@FAST
@given(st.lists(st.tuples(finite, finite, finite,
                          st.floats(-170, 170), st.floats(-80, 80), st.floats(-170, 170)),
                min_size=1, max_size=15),
       st.sampled_from(["deg", "rad"]))
def test_poses_round_trip(tmp_path, rows, angle_unit):
    from pkmcal.io import read_poses, write_poses
    from pkmcal.kinematics import matrix_from_euler

    a = np.array(rows, float)
    P, R = a[:, :3] * 1e-3, matrix_from_euler(np.deg2rad(a[:, 3:]))
    path = tmp_path / "p.csv"
    write_poses(path, P, R, "mm", angle_unit)
    P2, R2, _ = read_poses(path)
    np.testing.assert_allclose(P2, P, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(R2, R, atol=1e-12)


@FAST
@given(st.text(max_size=300))
def test_any_text_as_a_data_file_is_read_or_refused_clearly(tmp_path, text):
    """Whatever the file holds, the readers return data or raise InputError: never another
    exception (which the command line would show as a traceback)."""
    from pkmcal.errors import InputError
    from pkmcal.io import read_joints

    path = tmp_path / "x.csv"
    path.write_text(text, encoding="utf-8")
    try:
        q, _, _ = read_joints(path, 6)
    except InputError:
        return
    assert q.shape[1] == 6 and np.all(np.isfinite(q))


@FAST
@given(st.text(max_size=300))
def test_any_text_as_a_machine_file_is_read_or_refused_clearly(text):
    from pkmcal.errors import InputError
    from pkmcal.io import parse_machine

    try:
        parse_machine(text, "fuzz.yaml")
    except InputError:
        pass


@FAST
@given(st.sampled_from(["alpha", "beta", "l"]),
       st.one_of(st.text(max_size=8), st.floats(allow_nan=True, allow_infinity=True),
                 st.lists(st.integers(), max_size=4), st.none()))
def test_any_value_in_a_chain_is_read_or_refused_clearly(key, value):
    """A mutated field of a valid machine file: loads, or an InputError naming the key."""
    import yaml

    from pkmcal.errors import InputError
    from pkmcal.io import parse_machine

    doc = yaml.safe_load(MACHINES["h"].read_text())
    doc["chains"][2][key] = value
    try:
        parse_machine(yaml.safe_dump(doc), "fuzz.yaml")
    except InputError as exc:
        # the value itself (key path) or what it does to the machine (chain 3 at home)
        assert "chains[2]" in str(exc) or "chain(s) 3" in str(exc), str(exc)
