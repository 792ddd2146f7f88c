"""Every LinuxCNC export in LinuxCNC itself, headless (issue 34): ``pkmcal export --to
linuxcnc-genhexkins|lineardelta|rotarydelta -o DIR/`` writes a configuration directory, which
starts here as written (``linuxcnc DIR/machine.ini``: rtapi_app, motion, task, the INI's
``dummy`` display) while :mod:`linuxcnc_driver` drives it through LinuxCNC's ``linuxcnc``
module beside it: estop reset, machine on, home all, MDI ``G53 G0`` to poses of the
workspace, then joint jogs (the forward map). One LinuxCNC start per machine.

What is compared, for each pose: the joints LinuxCNC reads back (feedback equal to command),
turned into the machine's readings as the configuration says (``HOME_OFFSET`` of the INI,
the scale pair of genhexkins, read off the written files), put the calibrated machine where
pkmcal promises (its own IK of the written values, its own FK of the calibrated machine) to
1e-6 mm, and the drive's command pins carry those readings; after each jog, LinuxCNC's world
position (its forward kinematics) is where pkmcal's model of the controller puts those joints.
Skipped with the reason where LinuxCNC is not installed (:mod:`linuxcnc_stack`).
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from clitools import calibrated_file, run
from linuxcnc_stack import run_linuxcnc, stack_missing
from pkmcal.export import controller_format, position_errors
from pkmcal.io.machine_file import load_machine

pytestmark = pytest.mark.skipif(stack_missing() is not None, reason=str(stack_missing()))

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
#: agreement asked of LinuxCNC with pkmcal's promise: 1e-6 mm
AGREE_M = 1e-9




def ini_values(text: str, key: str) -> dict:
    """``[JOINT_n] KEY`` of an INI text -> {n: value}."""
    out, joint = {}, None
    for line in text.splitlines():
        m = re.match(r"^\[JOINT_(\d+)\]", line)
        if m:
            joint = int(m.group(1))
        elif line.startswith("["):
            joint = None
        m = re.match(rf"^{key}\s*=\s*(\S+)", line)
        if m and joint is not None:
            out[joint] = float(m.group(1))
    return out


def _nearest_first(q, start) -> np.ndarray:
    """The order of the joint vectors ``q`` (K, n) that goes each time to the nearest one left
    (largest joint change), from ``start``."""
    left, order, here = list(range(len(q))), [], start
    while left:
        k = left.pop(int(np.argmin([np.abs(q[i] - here).max() for i in left])))
        order.append(k)
        here = q[k]
    return np.array(order)


def _run_export(tmp: Path, cal: Path, name: str, n_poses: int = 5):
    """Export the configuration directory, start it, command poses and jogs; return what
    LinuxCNC did with what pkmcal promises."""
    proc = run("export", cal, "--to", name, "-o", "config/", cwd=tmp)
    assert proc.returncode == 0, proc.stderr
    config = tmp / "config"
    written = {p.name: p.read_bytes() for p in config.iterdir()}
    fmt = controller_format(name)
    machine = load_machine(cal)
    params = fmt.parse((config / "kinematics.hal").read_text(), "kinematics.hal")
    ini = (config / "machine.ini").read_text()
    offsets = ini_values(ini, "HOME_OFFSET")
    assert np.allclose([offsets[j] for j in range(machine.n_joints)], fmt.home_offsets(params),
                       rtol=0, atol=1e-12)
    from pkmcal.export import export_workspace

    # the export's workspace (a printer's own: its print disk and the volume above it)
    own = getattr(machine, "print_workspace", None)
    ws = own(rng=0) if callable(own) else export_workspace(machine)
    pick = np.linspace(0, len(ws.P) - 1, n_poses).astype(int)
    # visited nearest first from home: the same poses, ~35 % less travel at the export's
    # speeds (the moves are most of what a run waits for)
    pick = pick[_nearest_first(machine.ik(ws.P[pick], ws.R[pick]),
                               machine.ik(*(a[None] for a in machine.home))[0])]
    P, R = ws.P[pick], ws.R[pick]
    X = fmt.controller_world(params, P, R)
    _, cmd_pin, _ = fmt.joint_nets(0)
    n = machine.n_joints
    request = {"joints": n, "axes": fmt.coordinates.replace(" ", ""), "poses": X.tolist(),
               "jogs": [[0, 1.0], [n - 1, -1.0]],
               "pins": [cmd_pin.replace(".0.", f".{j}.") for j in range(n)]}
    result = run_linuxcnc(config / "machine.ini", request)
    assert result.get("failed") is None, (result.get("failed"), result["log"][-3000:])
    assert result["exit"] == 0, result["log"][-3000:]
    assert not result["errors"], result["errors"]
    # LinuxCNC's own files beside it (its parameter file) are all it added; nothing edited
    assert {k: v for k, v in written.items()} == {
        p.name: p.read_bytes() for p in config.iterdir() if p.name in written}
    return fmt, machine, params, P, R, request, result


def _check_poses(fmt, machine, params, P, R, request, result):
    J = np.array([r["joints"] for r in result["poses"]])
    assert np.allclose(J, np.array([r["commanded"] for r in result["poses"]]), rtol=1e-12,
                       atol=0)
    q = fmt.machine_readings(params, J)
    fk = machine.fk(q, start=(P, R))
    assert np.all(fk.converged)
    promised = P + position_errors(fmt, params, machine, P, R)
    assert np.linalg.norm(fk.P - promised, axis=1).max() < AGREE_M
    # the drives' pins: the motor positions the configuration's README describes
    pins = np.array([[r["pins"][p] for p in request["pins"]] for r in result["poses"]])
    motor = J - fmt.home_offsets(params)[None]
    return q, pins, motor, fk.P


def _check_jogs(fmt, machine, params, result):
    """After each joint jog: LinuxCNC's world position (its forward kinematics of the joints
    it reads) is where pkmcal's model of the controller puts those joints."""
    for r in result["jogs"]:
        J = np.array([r["joints"]])
        W = np.array([r["world"][:len(fmt.coordinates.split())]])
        Pw, Rw = fmt.calibrated_pose(params, W)
        q_model = fmt.ik(params, Pw, Rw)
        q_read = fmt.machine_readings(params, J)
        a = machine.fk(q_model, start=(Pw, Rw))
        b = machine.fk(q_read, start=(Pw, Rw))
        assert a.converged.all() and b.converged.all()
        assert np.linalg.norm(a.P - b.P) < AGREE_M, (r, a.P, b.P)
    assert len(result["jogs"]) == 2
    # the jogs moved the joints (a jog stops within about 5e-6 of its target)
    j0 = np.array(result["poses"][-1]["joints"])
    j1 = np.array(result["jogs"][0]["joints"])
    assert j1[0] - j0[0] == pytest.approx(1.0, abs=1e-4)


@pytest.mark.parametrize("example", ["cubic_6upu.yaml", "jugglebot.yaml"])
def test_genhexkins_configuration_runs_in_linuxcnc(tmp_path, example):
    """The calibrated hexapod of the docs (examples/cubic_6upu.yaml, full poses; readings in
    mm) and the Jugglebot as designed (readings in motor revolutions: scale gains of 75.7
    mm/rev), their configurations started as written: strut lengths, the drives' readings
    through the scale pairs and the forward map agree with pkmcal."""
    shutil.copy(EXAMPLES / example, tmp_path / "machine.yaml")
    cal = (calibrated_file(tmp_path, tmp_path / "machine.yaml", "pose", "--poses", "60")
           if example == "cubic_6upu.yaml" else tmp_path / "machine.yaml")
    fmt, machine, params, P, R, request, result = _run_export(tmp_path, cal,
                                                              "linuxcnc-genhexkins")
    q, pins, motor, reached = _check_poses(fmt, machine, params, P, R, request, result)
    # genhexkins represents the machine exactly: on the targets
    assert np.linalg.norm(reached - P, axis=1).max() < AGREE_M
    # strut-reading.N.out: the drive's reading (the file's reading unit, mm here)
    from pkmcal.units import LENGTH

    unit = getattr(machine, "reading_unit", "mm")
    assert np.abs(pins * LENGTH.get(unit, 1.0) - q).max() < AGREE_M
    _check_jogs(fmt, machine, params, result)


@pytest.mark.parametrize("name", ["linuxcnc-rotarydelta", "linuxcnc-lineardelta"])
def test_delta_configuration_runs_in_linuxcnc(tmp_path, name):
    """The example Delta robot (legs turned to LinuxCNC's hips, calibrated from tracker data)
    and the example printer (calibrated from its bed probe): configurations started as
    written; the joints, the drives' motor positions (minus the readings) and the forward map
    agree with pkmcal, and the error at each pose is within what the export states."""
    if name == "linuxcnc-rotarydelta":
        text = (EXAMPLES / "delta_default.yaml").read_text().replace(
            "leg_angles: [90.0, 180.0, -90.0]", "leg_angles: [150.0, 30.0, -90.0]")
        (tmp_path / "nominal.yaml").write_text(text)
        cal = calibrated_file(tmp_path, tmp_path / "nominal.yaml", "tracker")
    else:
        cal = calibrated_file(tmp_path, EXAMPLES / "linear_delta.yaml", "probe")
    fmt, machine, params, P, R, request, result = _run_export(tmp_path, cal, name)
    q, pins, motor, reached = _check_poses(fmt, machine, params, P, R, request, result)
    scale = np.degrees(1.0) if fmt.joint_type == "ANGULAR" else 1e3
    assert np.abs(pins - motor).max() < 1e-9
    joint = params.values[fmt._JOINTS].astype(int)
    assert np.abs(motor[:, joint] + q * scale).max() < 1e-9
    import json

    record = json.loads((tmp_path / "config" / "export.json").read_text())
    e = np.linalg.norm(reached - P, axis=1)
    assert e.max() <= record["remaining_max_um"] * 1e-6 * (1 + 1e-9) + AGREE_M
    _check_jogs(fmt, machine, params, result)
