"""The LinuxCNC Delta exports run in LinuxCNC's own kinematics code (issue 34): Debian's
``linuxcnc-uspace`` 2.9 Python bindings ``rotarydeltakins`` and ``lineardeltakins`` of the C
code the controller loads (:mod:`linuxcnc_stack`; skipped where they are missing).

What pkmcal promises for an export: the calibrated machine, driven with the joints the
controller commands for a target, lands where ``pkmcal.export.position_errors`` says, and the
error it states (RMS and max over the workspace, the values as written) is that error.
Here the controller's joints come from LinuxCNC's code with the values read off the written
file, and the calibrated machine's own forward kinematics says where they put it.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from clitools import calibrated_file, delta_at_linuxcnc_hips, run
from linuxcnc_stack import debian_kins, kins_missing
from pkmcal.export import controller_format, export, export_workspace, position_errors
from pkmcal.io.machine_file import load_machine

pytestmark = pytest.mark.skipif(kins_missing() is not None, reason=str(kins_missing()))

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
#: agreement asked of LinuxCNC's code with pkmcal's promise: 1e-6 mm
AGREE_M = 1e-9




@pytest.fixture(scope="module")
def rotary(tmp_path_factory):
    """examples/delta_default.yaml with its legs turned to 150, 30, -90 deg (LinuxCNC's hips,
    in another order than its joints), calibrated from tracker data."""
    tmp = tmp_path_factory.mktemp("rotary")
    nominal = delta_at_linuxcnc_hips(tmp)
    return load_machine(nominal), load_machine(calibrated_file(tmp, nominal, "tracker"))


@pytest.fixture(scope="module")
def linear(tmp_path_factory):
    """examples/linear_delta.yaml calibrated from its bed probe (towers and bed off)."""
    tmp = tmp_path_factory.mktemp("linear")
    return load_machine(calibrated_file(tmp, EXAMPLES / "linear_delta.yaml", "probe"))


def setp(text: str, comp: str) -> dict:
    return {m.group(1): float(m.group(2)) for m in
            re.finditer(rf"^setp\s+{comp}\.(\S+)\s+(\S+)\s*$", text, re.M)}


def _through_linuxcnc(fmt, res, machine, ws, module, geometry):
    """LinuxCNC's joints for the workspace (its code, the written values), the machine's
    readings of them, where the calibrated machine goes; and LinuxCNC's forward map of
    its own joints."""
    params = fmt.parse(res.text, "written.hal")            # the file as written
    X = fmt.controller_world(params, ws.P)
    out = debian_kins(module, geometry, inverse=X)
    assert out["geometry"] == pytest.approx(geometry, rel=1e-15)
    assert all(j is not None for j in out["inverse"])
    J = np.array(out["inverse"])
    back = debian_kins(module, geometry, forward=J)["forward"]
    q = fmt.machine_readings(params, J)
    fk = machine.fk(q)
    assert np.all(fk.converged)
    return params, X, J, np.array(back), fk.P


def _check(fmt, res, machine, ws, module, geometry):
    params, X, J, X_back, P = _through_linuxcnc(fmt, res, machine, ws, module, geometry)
    # LinuxCNC's forward kinematics inverts its inverse kinematics
    assert np.abs(X_back - X).max() < AGREE_M * 1e3
    # the joints are those pkmcal computes for the file's values
    J_pkmcal = fmt.controller_joints(params, fmt.ik(params, ws.P))
    promised = ws.P + position_errors(fmt, params, machine, ws.P)
    assert np.linalg.norm(P - promised, axis=1).max() < AGREE_M
    e = np.linalg.norm(P - ws.P, axis=1)
    # the stated loss is what LinuxCNC's code then does (the values as written)
    assert np.sqrt(np.mean(e**2)) == pytest.approx(res.remaining_rms, rel=1e-6, abs=AGREE_M)
    assert e.max() == pytest.approx(res.remaining_max, rel=1e-6, abs=AGREE_M)
    return J, J_pkmcal, e


def test_rotarydelta_export_is_what_linuxcnc_29_runs(rotary):
    """Issue 34: the export followed rotarydeltakins of 2013 (hips at -90, 150, 30 deg and
    LinuxCNC's z = -z); LinuxCNC 2.9's code put the platform tens of mm off."""
    nominal, cal = rotary
    fmt = controller_format("linuxcnc-rotarydelta")
    ws = export_workspace(cal)
    res = export(fmt, cal, ws.P, ws.R, nominal=nominal, workspace=ws.description)
    pins = setp(res.text, "rotarydeltakins")
    geometry = [pins[k] for k in ("platformradius", "thighlength", "shinlength", "footradius")]
    J, J_pkmcal, e = _check(fmt, res, cal, ws, "rotarydeltakins", geometry)
    assert np.abs(J - J_pkmcal).max() < 1e-9                  # deg
    assert res.remaining_rms < res.before_rms
    # the readings of legs 1, 2, 3 (at 150, 30, -90 deg) drive joints 2, 1, 0
    assert [int(v) for v in res.params.as_dict().values()][-3:] == [2, 1, 0]


def test_rotarydelta_exact_machine_is_exact_in_linuxcnc(rotary):
    """A Delta that rotarydeltakins holds exactly (actuator offsets only): LinuxCNC's code
    puts it on the targets to the rounding of the written values."""
    nominal, _ = rotary
    from pkmcal.machines.delta import Delta, delta_parameters

    u = np.zeros((3, 9))
    u[:, 3] = [0.002, -0.001, 0.003]
    m = Delta(nominal.a, nominal.b, nominal.l1, nominal.l2, nominal.leg_angles,
              delta_parameters(u.reshape(-1)), home=nominal.home)
    fmt = controller_format("linuxcnc-rotarydelta")
    ws = export_workspace(m)
    res = export(fmt, m, ws.P)
    pins = setp(res.text, "rotarydeltakins")
    geometry = [pins[k] for k in ("platformradius", "thighlength", "shinlength", "footradius")]
    _, _, e = _check(fmt, res, m, ws, "rotarydeltakins", geometry)
    assert e.max() < 1e-6 * m.characteristic_length()


def test_rotarydelta_linuxcnc_file_imported_then_exported_is_the_identity(tmp_path):
    """A rotarydeltakins file as LinuxCNC users have it (pins only): the imported machine's
    readings are LinuxCNC's joints (deg, sign changed: arm up positive), the export of the
    imported machine writes the same values, and LinuxCNC's code with both files commands
    the same joints."""
    text = ("setp rotarydeltakins.platformradius 210.5\nsetp rotarydeltakins.thighlength 290\n"
            "setp rotarydeltakins.shinlength 810.25\nsetp rotarydeltakins.footradius 45\n")
    (tmp_path / "rd.hal").write_text(text)
    proc = run("import", "rd.hal", "--from", "linuxcnc-rotarydelta", "-o", "imported.yaml",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = run("export", "imported.yaml", "--to", "linuxcnc-rotarydelta", "-o", "back.hal",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    back = (tmp_path / "back.hal").read_text()
    assert setp(back, "rotarydeltakins") == setp(text, "rotarydeltakins")
    m = load_machine(tmp_path / "imported.yaml")
    ws = export_workspace(m)
    geometry = [210.5, 290.0, 810.25, 45.0]
    J = np.array(debian_kins("rotarydeltakins", geometry, inverse=ws.P * 1e3)["inverse"])
    assert np.abs(np.radians(-J) - m.ik(ws.P)).max() < 1e-12
    fmt = controller_format("linuxcnc-rotarydelta")
    params = fmt.parse(back, "back.hal")
    assert np.abs(fmt.controller_joints(params, m.ik(ws.P)) - J).max() < 1e-9


def test_lineardelta_export_is_what_linuxcnc_runs(linear):
    nominal = load_machine(EXAMPLES / "linear_delta.yaml")
    fmt = controller_format("linuxcnc-lineardelta")
    ws = export_workspace(linear)
    res = export(fmt, linear, ws.P, ws.R, nominal=nominal, workspace=ws.description)
    pins = setp(res.text, "lineardeltakins")
    J, J_pkmcal, e = _check(fmt, res, linear, ws, "lineardeltakins", [pins["R"], pins["L"]])
    assert np.abs(J - J_pkmcal).max() < 1e-9                  # mm
    assert res.remaining_rms < res.before_rms


def test_stated_error_includes_the_rounding_of_the_written_values(rotary):
    """Issue 34: the remaining error was computed before rounding. It is now that of the
    values read back from the file: equal to the error of the parsed file's values."""
    _, cal = rotary
    for name in ("linuxcnc-rotarydelta", "linuxcnc-lineardelta"):
        fmt = controller_format(name)
        m = cal if fmt.applies(cal) is None else load_machine(EXAMPLES / "linear_delta.yaml")
        ws = export_workspace(m)
        res = export(fmt, m, ws.P)
        params = fmt.parse(res.text, "written.hal")
        assert np.array_equal(params.values, res.params.values)
        e = np.linalg.norm(position_errors(fmt, params, m, ws.P), axis=1)
        assert res.remaining_max == e.max()


def test_pkmcal_rotarydeltakins_is_linuxcncs():
    """Issue 34: pkmcal's restatement of rotarydeltakins' inverse kinematics gives the joints
    LinuxCNC's code gives (it followed the 2013 code: joints 1 and 2 swapped, z mirrored),
    for several geometries and targets below the hips."""
    from pkmcal.export.linuxcnc_delta import rotarydelta_joints

    rng = np.random.default_rng(34)
    for geometry in ([200.0, 300.0, 800.0, 50.0], [10.0, 10.0, 14.0, 6.0],
                     [150.0, 120.0, 400.0, 30.0]):
        pfr, tl, sl, fr = geometry
        depth = np.sqrt(sl**2 - (pfr - fr) ** 2)
        X = np.column_stack([rng.uniform(-0.1, 0.1, (20, 2)) * sl,
                             -depth * rng.uniform(0.9, 1.1, 20)])
        J = np.array(debian_kins("rotarydeltakins", geometry, inverse=X)["inverse"])
        assert np.abs(rotarydelta_joints(*geometry, X) - J).max() < 1e-9
