"""Data in the wrong unit (a new-user test): the readers that know the machine compare the
data's scale with the nominal machine and refuse values off by a unit factor with a message
naming the columns and the unit they look like (pkmcal.plausibility). Legitimate data -
pkmcal's own simulations of the example machines and of geometries scaled by 0.5 and 2, data
written in other units, the real Jugglebot measurements - pass. Also: quaternion norms, the
field separator of spreadsheet exports, and no numpy overflow warning for huge readings.

The command-line side (exit 2, one line, no output file) is in the malformed-input catalogue,
tests/test_malformed.py.
"""

from __future__ import annotations

import csv
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

from clitools import run
from pkmcal.errors import InputError
from pkmcal.io import (
    load_machine,
    read_constraint_link,
    read_full_pose,
    read_poses,
    read_table,
    read_tracker,
)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
MACHINES = {"h": EXAMPLES / "hexaslide_default.yaml", "d": EXAMPLES / "delta_default.yaml",
            "s": EXAMPLES / "cubic_6upu.yaml", "j": EXAMPLES / "jugglebot.yaml"}
READERS = {"hexaslide": read_constraint_link, "delta": read_tracker, "stewart": read_full_pose}
JUGGLEBOT = Path(__file__).resolve().parents[2] / "shared" / "data" / "jugglebot"


def scaled_machine_text(path: Path, s: float) -> str:
    """A machine file with every length times ``s`` (another geometry of the same shape)."""
    doc = yaml.safe_load(path.read_text())

    def sc(v):
        return [x * s for x in v] if isinstance(v, list) else v * s

    if doc["machine"] == "hexaslide":
        for c in doc["chains"]:
            for key in ("a0", "b", "l"):
                c[key] = sc(c[key])
        doc["constraint_link"]["length"] *= s
    elif doc["machine"] == "delta":
        for key in ("base_radius", "platform_radius", "upper_arm", "forearm", "smr_offset"):
            doc[key] *= s
        for leg in doc["legs"]:
            for key in ("da", "dl1", "dl2", "db"):
                leg[key] = sc(leg[key])
    else:
        length_readings = doc.get("readings", {}).get("unit", "m") in ("m", "mm", "um")
        for leg in doc["legs"]:
            for key in ("base", "platform", "l0"):
                leg[key] = sc(leg[key])
            if not length_readings:
                leg["gain"] *= s            # length per reading unit
    doc["home"] = [x * s for x in doc["home"][:3]] + doc["home"][3:]
    return yaml.safe_dump(doc)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Simulated data ``(machine file, data file)`` per (machine key, scale)."""
    d = tmp_path_factory.mktemp("units")
    out = {}
    for key in ("h", "d", "s", "j"):
        for s in (1, 0.5, 2):
            machine = d / f"{key}_{s}.yaml"
            machine.write_text(scaled_machine_text(MACHINES[key], s))
            path = d / f"{key}_{s}.csv"
            opts = ["--poses", "60"] if key == "h" else []
            proc = run("simulate", machine, *opts, "--seed", "3", "-o", path, cwd=d)
            assert proc.returncode == 0, proc.stderr
            out[key, s] = (machine, path)
    return out


def _read(machine_path, data_path):
    machine = load_machine(machine_path)
    return READERS[machine.kind](data_path, machine)


def _rewrite(src: Path, dst: Path, change: dict) -> Path:
    """Copy a data file, column ``name`` renamed to ``new`` and its values times ``f`` for
    ``change = {name: (new, f)}``."""
    with open(src, newline="") as f:
        rows = list(csv.reader(f))
    header = rows[0]
    idx = {header.index(n): v for n, v in change.items()}
    out = [[idx[j][0] if j in idx else n for j, n in enumerate(header)]]
    out += [[repr(float(x) * idx[j][1]) if j in idx else x for j, x in enumerate(r)]
            for r in rows[1:]]
    with open(dst, "w", newline="") as f:
        csv.writer(f).writerows(out)
    return dst


# -- legitimate data pass -------------------------------------------------------------------------

@pytest.mark.parametrize("key", ["h", "d", "s", "j"])
@pytest.mark.parametrize("scale", [1, 0.5, 2])
def test_simulated_data_of_scaled_geometries_pass(data, key, scale):
    machine, path = data[key, scale]
    assert len(_read(machine, path)) > 0


def test_calibrate_a_scaled_delta_and_stewart(data, tmp_path):
    """End to end: the command line calibrates data of geometries twice the examples' size."""
    for key in ("d", "s"):
        machine, path = data[key, 2]
        proc = run("calibrate", machine, path, "-o", f"cal_{key}.yaml", cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
        assert (tmp_path / f"cal_{key}.yaml").is_file()


@pytest.mark.parametrize("key,change", [
    ("h", {f"q{j}_mm": (f"q{j}_m", 1e-3) for j in range(1, 7)}),
    ("h", {f"q{j}_mm": (f"q{j}_um", 1e3) for j in range(1, 7)}),
    ("d", {f"q{j}_deg": (f"q{j}_rad", np.pi / 180) for j in range(1, 4)}),
    ("d", {f"m{c}_mm": (f"m{c}_m", 1e-3) for c in "xyz"}),
    ("s", {f"{c}_mm": (f"{c}_m", 1e-3) for c in "xyz"}),
    ("s", {f"q{j}_mm": (f"q{j}_um", 1e3) for j in range(1, 7)}),
], ids=["h m", "h um", "d rad", "d points m", "s positions m", "s readings um"])
def test_data_converted_to_another_unit_pass(data, tmp_path, key, change):
    machine, path = data[key, 1]
    _read(machine, _rewrite(path, tmp_path / "converted.csv", change))


@pytest.mark.skipif(not (JUGGLEBOT / "calibration_108_poses.csv").is_file(),
                    reason=f"the Jugglebot measurements are not at {JUGGLEBOT}")
@pytest.mark.parametrize("name", ["calibration_108_poses.csv", "validation_60_poses.csv"])
def test_real_jugglebot_measurements_pass(tmp_path, name):
    from test_jugglebot import convert

    path = convert(JUGGLEBOT / name, tmp_path / "jugglebot.csv")
    data = read_full_pose(path, load_machine(MACHINES["j"]))
    assert len(data) in (108, 60)
    # the same positions in metres, under _m columns
    metres = _rewrite(path, tmp_path / "metres.csv", {f"{c}_mm": (f"{c}_m", 1e-3) for c in "xyz"})
    read_full_pose(metres, load_machine(MACHINES["j"]))


def test_toy_readings_far_from_home_are_not_called_a_unit_error(tmp_path):
    """Readings of 1..6 mm on a machine whose sliders read 351 mm at home: suspicious, but no
    unit makes them a pose of the machine, so the reader does not blame the unit."""
    path = tmp_path / "toy.csv"
    path.write_text("q1_mm,q2_mm,q3_mm,q4_mm,q5_mm,q6_mm\n1,2,3,4,5,6\n1,2,3,4,5,6\n")
    read_constraint_link(path, load_machine(MACHINES["h"]))


# -- data in the wrong unit are refused -----------------------------------------------------------

WRONG = [
    ("h", {f"q{j}_mm": (f"q{j}_mm", 1e-3) for j in range(1, 7)}, ["look like m, not mm"]),
    ("h", {f"q{j}_mm": (f"q{j}_m", 1.0) for j in range(1, 7)}, ["look like mm, not m"]),
    ("h", {"q3_mm": ("q3_mm", 1e3)}, ["column q3_mm:", "look like um, not mm",
                                      "rename the column q3_um"]),
    ("d", {f"q{j}_deg": (f"q{j}_deg", np.pi / 180) for j in range(1, 4)},
     ["look like rad, not deg"]),
    ("d", {f"q{j}_deg": (f"q{j}_rad", 1.0) for j in range(1, 4)},
     ["look like deg, not rad"]),
    ("d", {f"m{c}_mm": (f"m{c}_mm", 1e3) for c in "xyz"}, ["look like um, not mm"]),
    ("d", {f"m{c}_mm": (f"m{c}_m", 1.0) for c in "xyz"}, ["look like mm, not m"]),
    ("s", {f"{c}_mm": (f"{c}_m", 1.0) for c in "xyz"}, ["look like mm, not m"]),
    ("s", {f"q{j}_mm": (f"q{j}_m", 1.0) for j in range(1, 7)}, ["look like mm, not m"]),
    ("j", {f"{c}_mm": (f"{c}_mm", 1e-3) for c in "xyz"}, ["look like m, not mm"]),
]


@pytest.mark.parametrize("key,change,words", WRONG,
                         ids=[f"{w[0]} {next(iter(w[1]))} {w[2][-1]}" for w in WRONG])
@pytest.mark.parametrize("scale", [1, 2])
def test_wrong_unit_is_refused_with_the_unit_it_looks_like(data, tmp_path, key, change, words,
                                                           scale):
    machine, path = data[key, scale]
    bad = _rewrite(path, tmp_path / "bad.csv", change)
    with pytest.raises(InputError) as info:
        _read(machine, bad)
    message = str(info.value)
    assert message.startswith(f"{bad}: column")
    for w in words:
        assert w in message


@pytest.mark.parametrize("factor,unit", [(180 / np.pi, "deg, not rad"),
                                         (np.pi / 180, "rad, not deg")])
def test_euler_angles_in_the_wrong_unit(data, tmp_path, factor, unit):
    """Euler angles (written from the quaternions) in the wrong angle unit."""
    from pkmcal.io import write_poses

    machine_path, path = data["s", 1]
    machine = load_machine(machine_path)
    good = read_full_pose(path, machine)
    angle_unit = "rad" if factor > 1 else "deg"
    written = write_poses(tmp_path / "poses.csv", good.P, good.R, "mm", angle_unit)
    P, R, _ = read_poses(written)
    # readings + poses: Euler angles multiplied into the other unit, column names kept
    with open(written, newline="") as f:
        poses = list(csv.reader(f))
    with open(path, newline="") as f:
        readings = [r[:6] for r in csv.reader(f)]
    rows = [readings[0] + poses[0]] + [
        q + p[:3] + [repr(float(a) * factor) for a in p[3:]]
        for q, p in zip(readings[1:], poses[1:], strict=True)]
    bad = tmp_path / "bad.csv"
    with open(bad, "w", newline="") as f:
        csv.writer(f).writerows(rows)
    with pytest.raises(InputError, match=f"psi_{angle_unit}.*look like {unit}"):
        read_full_pose(bad, machine)
    # the file as written (right unit) passes
    good_file = tmp_path / "good.csv"
    with open(good_file, "w", newline="") as f:
        csv.writer(f).writerows([readings[0] + poses[0]] + [
            q + p for q, p in zip(readings[1:], poses[1:], strict=True)])
    read_full_pose(good_file, machine)


def test_readings_zero_at_home_or_positions(tmp_path):
    """Legs that read 0 at home (l0 = the leg lengths at home): readings 1000 times too small
    and positions 1000 times too small both shrink the distances between poses; the
    orientations tell which columns are wrong."""
    doc = yaml.safe_load(MACHINES["s"].read_text())
    cubic = load_machine(MACHINES["s"])
    for leg, length in zip(doc["legs"], cubic.ik(*cubic.home), strict=True):
        leg["l0"] = float(length * 1e3)
    machine_path = tmp_path / "relative.yaml"
    machine_path.write_text(yaml.safe_dump(doc))
    path = tmp_path / "relative.csv"
    assert run("simulate", machine_path, "--seed", "2", "-o", path,
               cwd=tmp_path).returncode == 0
    machine = load_machine(machine_path)
    assert np.allclose(machine.ik(*machine.home), 0, atol=1e-12)
    read_full_pose(path, machine)
    readings = _rewrite(path, tmp_path / "q.csv", {f"q{j}_mm": (f"q{j}_mm", 1e-3)
                                                   for j in range(1, 7)})
    with pytest.raises(InputError, match=r"columns q1_mm\.\.q6_mm: .* look like m, not mm"):
        read_full_pose(readings, machine)
    positions = _rewrite(path, tmp_path / "p.csv", {f"{c}_mm": (f"{c}_mm", 1e-3) for c in "xyz"})
    with pytest.raises(InputError, match="columns x_mm, y_mm, z_mm: .* look like m, not mm"):
        read_full_pose(positions, machine)


# -- quaternion norms -----------------------------------------------------------------------------

@pytest.mark.parametrize("factor,ok", [(1 + 1e-6, True), (1 - 5e-4, True), (1 + 2e-3, False),
                                       (0.5, False)])
def test_quaternion_norm_is_checked(tmp_path, factor, ok):
    q = np.array([0.1, -0.2, 0.3, 0.9])
    q /= np.linalg.norm(q)
    path = tmp_path / "poses.csv"
    path.write_text("x_mm,y_mm,z_mm,qx,qy,qz,qw\n0,0,300,0,0,0,1\n"
                    "0,0,300," + ",".join(repr(float(x) * factor) for x in q) + "\n")
    if ok:
        read_poses(path)
        return
    with pytest.raises(InputError, match=r"row 3, columns qx, qy, qz, qw: the quaternion has "
                                         r"norm [0-9.]+, not 1"):
        read_poses(path)


# -- separators and decimal marks -----------------------------------------------------------------

@pytest.mark.parametrize("sep,word", [(";", "semicolon"), ("\t", "tab")])
def test_other_separators_are_named(tmp_path, sep, word):
    path = tmp_path / "excel.csv"
    path.write_text(sep.join(f"q{j}_mm" for j in range(1, 7)) + "\n"
                    + sep.join(["351,2"] * 6) + "\n")
    with pytest.raises(InputError, match=f"row 1: .* looks {word}-separated; pkmcal reads "
                                         "comma-separated values with '.' decimals"):
        read_table(path)


def test_a_quoted_decimal_comma_is_named(tmp_path):
    path = tmp_path / "data.csv"
    path.write_text('q1_mm,q2_mm,q3_mm,q4_mm,q5_mm,q6_mm\n"351,2",351,351,351,351,351\n')
    with pytest.raises(InputError, match=r"row 2, column q1_mm: not a number: '351,2' \(',' "
                                         r"as the decimal mark"):
        read_constraint_link(path, load_machine(MACHINES["h"]))


# -- huge readings: no overflow warning -----------------------------------------------------------

@pytest.mark.parametrize("key", ["h", "s", "j"])
def test_forward_kinematics_of_huge_readings_warns_nothing(key):
    """Readings of 1e300 (a unit the readers cannot bound, such as the Jugglebot's rev) fail
    to converge quietly: the overflow in the step limit is expected, not a warning."""
    machine = load_machine(MACHINES[key])
    q = np.tile(machine.ik(*machine.home), (3, 1))
    q[1, 0] = 1e300
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = machine.fk(q)
    assert result.converged.tolist() == [True, False, True]


def test_huge_values_are_out_of_range(tmp_path):
    path = tmp_path / "d.csv"
    path.write_text("q1_deg,q2_deg,q3_deg,mx_mm,my_mm,mz_mm\n" + "1,2,3,4,5,6\n" * 4
                    + "1e300,2,3,4,5,6\n")
    with pytest.raises(InputError, match="row 6, column q1_deg: 1e300 is out of range"):
        read_tracker(path, load_machine(MACHINES["d"]))


def test_fk_refuses_readings_in_the_wrong_unit(cli, tmp_path):
    """`pkmcal fk` reads joints with the machine's level check too (metres under _mm)."""
    from clitools import assert_input_error

    assert cli("simulate", "default", "--poses", "20", "--noise", "0", "--deviations", "none",
               "-o", "d.csv").returncode == 0
    lines = (tmp_path / "d.csv").read_text().splitlines()
    header = lines[0].split(",")
    scaled = [",".join(str(float(v) / 1000) if name.endswith("_mm") else v
                       for name, v in zip(header, line.split(","), strict=True))
              for line in lines[1:]]
    (tmp_path / "m.csv").write_text("\n".join([lines[0], *scaled]) + "\n")
    assert cli("fk", "default", "d.csv", "-o", "ok.csv").returncode == 0
    assert_input_error(cli("fk", "default", "m.csv", "-o", "p.csv"), "m.csv", "look like m")
    assert not (tmp_path / "p.csv").exists()
