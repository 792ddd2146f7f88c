"""``pkmcal export --to linuxcnc-... -o DIR/``: a LinuxCNC configuration directory (issue 34
item 3), its files and refusals, without LinuxCNC (tests/test_linuxcnc_real.py starts it).
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, run
from pkmcal.export import controller_format
from pkmcal.export.linuxcnc_config import CONFIG_FILES
from pkmcal.io.machine_file import load_machine

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module")
def hexapod(tmp_path_factory):
    """examples/cubic_6upu.yaml with joint limits, simulated (pose scenario) and calibrated."""
    d = tmp_path_factory.mktemp("hexapod")
    text = (EXAMPLES / "cubic_6upu.yaml").read_text()
    (d / "cubic.yaml").write_text(text + "joint_limits: {min: 300.0, max: 520.0}\n")
    proc = run("simulate", "cubic.yaml", "--scenario", "pose", "--poses", "60", "-o",
               "poses.csv", cwd=d)
    assert proc.returncode == 0, proc.stderr
    proc = run("calibrate", "cubic.yaml", "poses.csv", "-o", "cal.yaml", cwd=d)
    assert proc.returncode == 0, proc.stderr
    return d


def sections(text: str) -> dict:
    """INI sections -> list of (key, value) (keys may repeat: HALFILE)."""
    out, name = {}, None
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        m = re.match(r"^\[(.+)\]$", line)
        if m:
            name = m.group(1)
            assert name not in out, f"section [{name}] twice"
            out[name] = []
        else:
            k, v = (w.strip() for w in line.split("=", 1))
            out[name].append((k, v))
    return out


def test_configuration_directory_files_and_values(hexapod, tmp_path):
    for name in ("cubic.yaml", "cal.yaml", "cal.json"):
        shutil.copy(hexapod / name, tmp_path / name)
    proc = run("export", "cal.yaml", "--to", "linuxcnc-genhexkins", "-o", "hexapod/",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    config = tmp_path / "hexapod"
    assert sorted(p.name for p in config.iterdir()) == sorted([*CONFIG_FILES, "export.json"])
    # the kinematics are the file of -o FILE.hal, byte for byte
    proc = run("export", "cal.yaml", "--to", "linuxcnc-genhexkins", "-o", "single.hal",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert (config / "kinematics.hal").read_text() == (tmp_path / "single.hal").read_text()
    ini = sections((config / "machine.ini").read_text())
    for s in ("EMC", "DISPLAY", "TASK", "RS274NGC", "EMCMOT", "EMCIO", "HAL", "KINS", "TRAJ"):
        assert s in ini, s
    assert dict(ini["EMC"])["VERSION"] == "1.1"
    assert dict(ini["KINS"]) == {"KINEMATICS": "genhexkins", "JOINTS": "6"}
    assert [v for k, v in ini["HAL"] if k == "HALFILE"] == ["machine.hal", "kinematics.hal",
                                                           "drives.hal"]
    traj = dict(ini["TRAJ"])
    assert traj["COORDINATES"] == "X Y Z A B C" and traj["LINEAR_UNITS"] == "mm"
    assert traj["ANGULAR_UNITS"] == "degree"
    cal = load_machine(tmp_path / "cal.yaml")
    home = [float(v) for v in traj["HOME"].split()]
    assert np.allclose(home[:3], cal.home[0] * 1e3, atol=1e-6)
    fmt = controller_format("linuxcnc-genhexkins")
    params = fmt.parse((config / "kinematics.hal").read_text(), "kinematics.hal")
    # joint limits: the machine file's (readings 300..520 mm), as strut lengths
    _, _, l0, g = params.legs()
    for j in range(6):
        joint = dict(ini[f"JOINT_{j}"])
        assert joint["TYPE"] == "LINEAR"
        lo, hi = sorted([(l0[j] + g[j] * 0.300) * 1e3, (l0[j] + g[j] * 0.520) * 1e3])
        assert float(joint["MIN_LIMIT"]) == pytest.approx(lo, abs=1e-6)
        assert float(joint["MAX_LIMIT"]) == pytest.approx(hi, abs=1e-6)
        assert float(joint["HOME_OFFSET"]) == 0.0
        # HOME: the strut at the home pose, inside the limits
        L = fmt.controller_joints(params, fmt.ik(params, cal.home[0][None], cal.home[1][None]))
        assert float(joint["HOME"]) == pytest.approx(L[0, j], abs=1e-9)
        assert lo <= float(joint["HOME"]) <= hi
    for c in "XYZABC":
        axis = dict(ini[f"AXIS_{c}"])
        assert float(axis["MIN_LIMIT"]) < float(axis["MAX_LIMIT"])
    drives = (config / "drives.hal").read_text()
    assert "YOUR DRIVES GO HERE" in drives
    assert all(f"net j{j}-drive strut-reading.{j}.out => strut-length.{j}.in" in drives
               for j in range(6))
    # the joints' path to the drives comes after the scale pair is loaded (kinematics.hal)
    assert "strut-reading" not in (config / "machine.hal").read_text()
    assert "README" not in drives and "linuxcnc machine.ini" in (config / "README.md").read_text()
    # the directory's kinematics import back as the same machine values
    proc = run("import", "hexapod/kinematics.hal", "--from", "linuxcnc-genhexkins", "--like",
               "cal.yaml", "-o", "back.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    back = load_machine(tmp_path / "back.yaml")
    assert np.allclose(back.legs()[0], cal.legs()[0], rtol=0, atol=1e-10)


def test_existing_directory_is_a_configuration_directory(hexapod, tmp_path):
    shutil.copy(hexapod / "cal.yaml", tmp_path / "cal.yaml")
    shutil.copy(hexapod / "cal.json", tmp_path / "cal.json")
    (tmp_path / "cfg").mkdir()
    proc = run("export", "cal.yaml", "--to", "linuxcnc-genhexkins", "-o", "cfg", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "cfg" / "machine.ini").is_file()


def test_configuration_directory_refusals(tmp_path, cli):
    """A directory for a format that writes one file, and a machine the kinematics cannot
    hold: exit 2, one message, nothing written."""
    shutil.copy(EXAMPLES / "linear_delta.yaml", tmp_path / "printer.yaml")
    shutil.copy(EXAMPLES / "delta_default.yaml", tmp_path / "delta.yaml")
    cli_run = cli
    out = cli_run("export", "printer.yaml", "--to", "klipper", "-o", "cfg/")
    assert_input_error(out, "-o cfg/", "klipper writes one file")
    out = cli_run("export", "delta.yaml", "--to", "linuxcnc-rotarydelta", "-o", "cfg/")
    assert_input_error(out, "-90, 30 and 150")
    assert not (tmp_path / "cfg").exists()


@pytest.mark.parametrize("name,machine", [("linuxcnc-lineardelta", "linear_delta.yaml")])
def test_delta_configuration_joints(tmp_path, name, machine):
    """A linear Delta's joints: HOME_OFFSET the carriage heights at the endstops (the
    calibration's joint zero, as in the .hal's pkmcal lines), HOME at the home pose."""
    shutil.copy(EXAMPLES / machine, tmp_path / "m.yaml")
    proc = run("export", "m.yaml", "--to", name, "-o", "cfg/", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    ini = sections((tmp_path / "cfg" / "machine.ini").read_text())
    fmt = controller_format(name)
    params = fmt.parse((tmp_path / "cfg" / "kinematics.hal").read_text(), "k.hal")
    m = load_machine(tmp_path / "m.yaml")
    for j in range(3):
        joint = dict(ini[f"JOINT_{j}"])
        assert float(joint["HOME_OFFSET"]) == pytest.approx(fmt.home_offsets(params)[j],
                                                           abs=1e-9)
    pe, _, r, L, _, _ = m.towers()
    assert fmt.home_offsets(params) == pytest.approx((pe + np.sqrt(L**2 - r**2)) * 1e3)


def _delta120(tmp: Path) -> Path:
    """The default Delta with its legs at LinuxCNC's hips (in another order) and actuator
    offsets."""
    text = (EXAMPLES / "delta_default.yaml").read_text().replace(
        "leg_angles: [90.0, 180.0, -90.0]", "leg_angles: [150.0, 30.0, -90.0]")
    text = text.replace("dtheta: 0.0", "dtheta: 0.2", 1)
    (tmp / "d120.yaml").write_text(text)
    return tmp / "d120.yaml"


@pytest.mark.parametrize("name", ["linuxcnc-rotarydelta", "linuxcnc-lineardelta",
                                  "linuxcnc-genhexkins"])
def test_configuration_import_then_export_is_the_identity(tmp_path, name):
    """Issue 34: import of what export wrote, exported again, is the same configuration:
    every file LinuxCNC reads, byte for byte (the INI's HOME_OFFSET, HOME and name read
    back from the INI, not from comments)."""
    machine = {"linuxcnc-rotarydelta": _delta120(tmp_path),
               "linuxcnc-lineardelta": EXAMPLES / "linear_delta.yaml",
               "linuxcnc-genhexkins": EXAMPLES / "cubic_6upu.yaml"}[name]
    proc = run("export", machine, "--to", name, "-o", "a/", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = run("import", "a", "--from", name, "-o", "imported.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = run("export", "imported.yaml", "--to", name, "-o", "b/", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    for f in ("machine.ini", "machine.hal", "kinematics.hal", "drives.hal"):
        assert (tmp_path / "a" / f).read_text() == (tmp_path / "b" / f).read_text(), f


def test_configuration_import_takes_the_joint_zero_from_the_ini(tmp_path):
    """The INI is what LinuxCNC runs: a HOME_OFFSET changed there is the joint's zero of the
    import (the kinematics.hal's pkmcal lines are not the convention's only home); a
    lineardeltakins file without any HOME_OFFSET notes imports from its configuration."""
    proc = run("export", _delta120(tmp_path), "--to", "linuxcnc-rotarydelta", "-o", "rd/",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    ini = tmp_path / "rd" / "machine.ini"
    text = ini.read_text()
    old = re.search(r"\[JOINT_2\][^\[]*?HOME_OFFSET = (\S+)", text)
    ini.write_text(text[:old.start(1)] + "1.5" + text[old.end(1):])
    proc = run("import", "rd/machine.ini", "--from", "linuxcnc-rotarydelta", "-o", "m.yaml",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    m = load_machine(tmp_path / "m.yaml")
    leg = int(np.argmin(np.abs(np.degrees(m.leg_angles) - 150.0)))     # joint 2's hip
    assert np.degrees(m.legs()[1][leg]) == pytest.approx(-1.5, abs=1e-12)

    proc = run("export", EXAMPLES / "linear_delta.yaml", "--to", "linuxcnc-lineardelta", "-o",
               "ld/", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    hal = tmp_path / "ld" / "kinematics.hal"
    hal.write_text("".join(line for line in hal.read_text().splitlines(keepends=True)
                           if not line.startswith("#")))
    proc = run("import", "ld", "--from", "linuxcnc-lineardelta", "-o", "p.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    p = load_machine(tmp_path / "p.yaml")
    ref = load_machine(EXAMPLES / "linear_delta.yaml")
    assert p.towers()[0] == pytest.approx(ref.towers()[0], abs=1e-12)


def test_configuration_import_errors_name_the_ini_line(tmp_path, cli):
    proc = run("export", EXAMPLES / "linear_delta.yaml", "--to", "linuxcnc-lineardelta", "-o",
               "ld/", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    out = cli("import", "ld", "--from", "linuxcnc-rotarydelta", "-o", "m.yaml")
    assert_input_error(out, "machine.ini: line", "[KINS] KINEMATICS = lineardeltakins",
                       "rotarydeltakins")
    ini = tmp_path / "ld" / "machine.ini"
    ini.write_text(re.sub(r"(\[JOINT_1\][^\[]*?HOME_OFFSET = )\S+", r"\g<1>x", ini.read_text()))
    out = cli("import", "ld/machine.ini", "--from", "linuxcnc-lineardelta", "-o", "m.yaml")
    assert_input_error(out, "machine.ini: line", "[JOINT_1] HOME_OFFSET", "'x'")
    assert not (tmp_path / "m.yaml").exists()


def test_configuration_refuses_a_home_the_controller_cannot_command():
    """[TRAJ] HOME and the joints' HOME come from the machine file's home pose: one that
    rotarydeltakins cannot reach is refused by name, not written as nan."""
    from pkmcal.errors import InputError
    from pkmcal.export import export, export_workspace
    from pkmcal.export.linuxcnc_config import configuration

    text = (EXAMPLES / "delta_default.yaml").read_text().replace(
        "leg_angles: [90.0, 180.0, -90.0]", "leg_angles: [-90.0, 30.0, 150.0]")
    from pkmcal.io.machine_file import parse_machine

    m = parse_machine(text, "d.yaml")
    fmt = controller_format("linuxcnc-rotarydelta")
    ws = export_workspace(m)
    res = export(fmt, m, ws.P)
    assert "HOME = 0 0 -750" in configuration(fmt, res, m, ws)["machine.ini"]
    m.home = (np.array([0.0, 0.0, -5.0]), np.eye(3))          # 5 m below the hips
    with pytest.raises(InputError, match="home pose cannot be commanded"):
        configuration(fmt, res, m, ws)
