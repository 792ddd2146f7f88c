"""Klipper rotary_delta, LinuxCNC rotarydeltakins and lineardeltakins against independent
kinematics (issue 15).

Each controller's inverse kinematics is written here again from its source, NOT from
``pkmcal.export``'s code or pkmcal's machine models: Klipper ``klippy/chelper/
kin_rotary_delta.c`` / ``klippy/kinematics/rotary_delta.py`` (the elbow in the arm's vertical
plane, ``abs_endstop = IK(0, 0, position_endstop)``), LinuxCNC ``rotarydeltakins-common.h``
as LinuxCNC 2.9 runs it (hips of joints 0, 1, 2 at -90, 30, 150 deg, knee down positive, z up
with the foot below the hips: issue 34) and
``lineardeltakins-common.h`` (towers at 90, 210, 330 deg, joint = carriage height). The
written file is read here with its own small parser; the machine that moves is the calibrated
model (``machine.fk``). Its error must equal what ``export`` reports.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from clitools import calibrated_file, delta_at_linuxcnc_hips
from pkmcal.errors import InputError
from pkmcal.export import controller_format, export, export_workspace
from pkmcal.io.machine_file import load_machine
from pkmcal.machines.delta import Delta, delta_parameters

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


# -- calibrated machines ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def delta_cal(tmp_path_factory):
    """examples/delta_default.yaml (legs at 90, 180, -90 deg) calibrated from tracker data."""
    tmp = tmp_path_factory.mktemp("delta")
    return load_machine(calibrated_file(tmp, EXAMPLES / "delta_default.yaml", "tracker"))


@pytest.fixture(scope="module")
def delta120(tmp_path_factory):
    """The default Delta with its legs at LinuxCNC's hips (150, 30, -90 deg): nominal and
    calibrated from tracker data."""
    tmp = tmp_path_factory.mktemp("delta120")
    nominal = delta_at_linuxcnc_hips(tmp)
    return load_machine(nominal), load_machine(calibrated_file(tmp, nominal, "tracker"))


@pytest.fixture(scope="module")
def linear_cal(tmp_path_factory):
    """examples/linear_delta.yaml calibrated from its bed probe (tilted towers, a bed)."""
    tmp = tmp_path_factory.mktemp("linear")
    return load_machine(calibrated_file(tmp, EXAMPLES / "linear_delta.yaml", "probe"))


# -- independent readers of the written files -------------------------------------------------
def pkmcal_lines(text):
    """``# pkmcal KEY = VALUE`` lines."""
    return {m.group(1): float(m.group(2)) for m in
            re.finditer(r"^#\s*pkmcal\s+(\S+)\s*=\s*(\S+)\s*$", text, re.M)}


def read_cfg(text):
    """Klipper config sections -> {key: float} (kinematic keys only)."""
    out, section = {}, None
    for line in text.splitlines():
        line = line.split("#")[0].strip()
        if line.startswith("["):
            section = out.setdefault(line.strip("[]"), {})
        elif ":" in line and section is not None:
            k, v = (s.strip() for s in line.split(":", 1))
            try:
                section[k] = float(v)
            except ValueError:
                section[k] = v
    return out


def read_setp(text, comp):
    return {m.group(1): float(m.group(2)) for m in
            re.finditer(rf"^setp\s+{comp}\.(\S+)\s+(\S+)\s*$", text, re.M)}


# -- independent kinematics -------------------------------------------------------------------
def arm_angle(radial, height, upper, lower):
    """Angle above the horizontal of an arm of length ``upper`` whose end is ``lower`` from
    the point (radial out, height up) relative to the pivot; the elbow farther out."""
    d = np.hypot(radial, height)
    cos_a = (upper**2 + d**2 - lower**2) / (2 * upper * d)
    base = np.arctan2(height, radial)
    with np.errstate(invalid="ignore"):
        a = np.arccos(cos_a)
    cands = np.stack([base + a, base - a])
    out = np.take_along_axis(cands, np.argmax(np.cos(cands), axis=0)[None], 0)[0]
    return np.where(np.abs(cos_a) <= 1, out, np.nan)


def klipper_readings(text, P):
    """Klipper rotary_delta: the machine's readings for targets P (m, machine file's frame):
    each arm's turn from its endstop. Where Klipper's frame and steppers are on the machine
    is what the export tells the user (its comment lines, read here as a user reads them)."""
    cfg = read_cfg(text)
    bed = float(re.search(r"Klipper's z = 0 \(the bed\) is at z = (\S+) mm", text).group(1))
    legs = {m.group(1): int(m.group(2)) - 1
            for m in re.finditer(r"^# stepper_([abc]) is leg (\d)", text, re.M)}
    pr = cfg["printer"]
    assert pr["kinematics"] == "rotary_delta"
    R, H = pr["shoulder_radius"], pr["shoulder_height"]
    Pk = np.asarray(P) * 1e3 - [0.0, 0.0, bed]               # Klipper's mm, bed at z = 0
    q = np.empty((len(Pk), 3))
    for t in "abc":
        s = cfg[f"stepper_{t}"]
        ang = np.radians(s["angle"])
        er = np.array([np.cos(ang), np.sin(ang), 0.0])
        et = np.array([-np.sin(ang), np.cos(ang), 0.0])

        def angle(X, s=s, er=er, et=et):
            side = X @ et                                    # off the arm's plane
            lower = np.sqrt(s["lower_arm_length"] ** 2 - side**2)
            return arm_angle(X @ er - R, X[..., 2] - H, s["upper_arm_length"], lower)

        abs_endstop = angle(np.array([0.0, 0.0, s["position_endstop"]]))
        q[:, legs[t]] = angle(Pk) - abs_endstop
    return q


def rotarydelta_forward(j, pfr, tl, sl, fr):
    """rotarydeltakins-common.h kinematics_forward (LinuxCNC 2.9), line by line (joints
    deg)."""
    j0, j1, j2 = np.radians([j[0], j[1], j[2]])
    y1 = -(pfr - fr + tl * np.cos(j0))
    z1 = -tl * np.sin(j0)
    y2 = (pfr - fr + tl * np.cos(j1)) * 0.5
    x2 = y2 * np.sqrt(3)
    z2 = -tl * np.sin(j1)
    y3 = (pfr - fr + tl * np.cos(j2)) * 0.5
    x3 = -y3 * np.sqrt(3)
    z3 = -tl * np.sin(j2)
    denom = x3 * (y2 - y1) - x2 * (y3 - y1)
    w1, w2, w3 = y1**2 + z1**2, x2**2 + y2**2 + z2**2, x3**2 + y3**2 + z3**2
    a1 = (z2 - z1) * (y3 - y1) - (z3 - z1) * (y2 - y1)
    b1 = -((w2 - w1) * (y3 - y1) - (w3 - w1) * (y2 - y1)) / 2.0
    a2 = -(z2 - z1) * x3 + (z3 - z1) * x2
    b2 = ((w2 - w1) * x3 - (w3 - w1) * x2) / 2.0
    a = a1**2 + a2**2 + denom**2
    b = 2 * (a1 * b1 + a2 * (b2 - y1 * denom) - z1 * denom**2)
    c = (b2 - y1 * denom) ** 2 + b1**2 + denom**2 * (z1**2 - sl**2)
    z = (-b - np.sqrt(b * b - 4 * a * c)) / (2 * a)
    return np.array([(a1 * z + b1) / denom, (a2 * z + b2) / denom, z])


def rotarydelta_joints(P_L, pfr, tl, sl, fr):
    """Hip angles (deg, knee down positive) for LinuxCNC world targets: knee i at
    ``(pfr + tl cos j) e_i - tl sin j e_z``, the foot's ankle ``fr e_i`` off the point, z up
    (the foot below the hips at negative z)."""
    out = []
    for hip in (-90.0, 30.0, 150.0):
        e = np.array([np.cos(np.radians(hip)), np.sin(np.radians(hip)), 0.0])
        t = np.array([-e[1], e[0], 0.0])
        side = P_L @ t
        lower = np.sqrt(sl**2 - side**2)
        up = arm_angle(P_L @ e + fr - pfr, P_L[..., 2], tl, lower)
        out.append(-np.degrees(up))
    return np.column_stack(out)


def linuxcnc_rotary_readings(text, P):
    pins, notes = read_setp(text, "rotarydeltakins"), pkmcal_lines(text)
    geo = [pins[k] for k in ("platformradius", "thighlength", "shinlength", "footradius")]
    J = rotarydelta_joints(np.asarray(P) * 1e3, *geo)
    q = []
    for i in range(3):
        j = int(notes[f"reading{i + 1}.joint"])
        q.append(np.radians(notes[f"joint_zero.{j}_deg"] - J[:, j]))
    return np.column_stack(q)


def linuxcnc_linear_readings(text, P):
    pins, notes = read_setp(text, "lineardeltakins"), pkmcal_lines(text)
    home = {int(m.group(1)): float(m.group(2)) for m in
            re.finditer(r"^#\s*\[JOINT_(\d)\]\s*HOME_OFFSET\s*=\s*(\S+)\s*$", text, re.M)}
    R, L = pins["R"], pins["L"]
    towers = [(0.0, R), (-np.sin(np.pi / 3) * R, -0.5 * R), (np.sin(np.pi / 3) * R, -0.5 * R)]
    X = np.asarray(P) * 1e3 - [0.0, 0.0, notes["bed_z_mm"]]
    q = []
    for i in range(3):
        j = int(notes[f"reading{i + 1}.joint"])
        tx, ty = towers[j]
        height = X[:, 2] + np.sqrt(L * L - (tx - X[:, 0]) ** 2 - (ty - X[:, 1]) ** 2)
        q.append((home[j] - height) * 1e-3)
    return np.column_stack(q)


INDEPENDENT = {"klipper-rotary-delta": klipper_readings,
               "linuxcnc-rotarydelta": linuxcnc_rotary_readings,
               "linuxcnc-lineardelta": linuxcnc_linear_readings}


def independent_error(name, text, machine, P):
    q = INDEPENDENT[name](text, P)
    fk = machine.fk(q)
    assert np.all(fk.converged)
    e = np.linalg.norm(fk.P - P, axis=1)
    return float(np.sqrt(np.mean(e**2))), float(np.max(e))


def _check_export(name, machine, nominal=None):
    fmt = controller_format(name)
    ws = export_workspace(machine)
    res = export(fmt, machine, ws.P, ws.R, nominal=nominal, workspace=ws.description)
    rms, mx = independent_error(name, res.text, machine, ws.P)
    assert rms == pytest.approx(res.remaining_rms, rel=1e-6)
    assert mx == pytest.approx(res.remaining_max, rel=1e-6)
    if nominal is not None:
        assert res.remaining_rms <= res.before_rms
    return fmt, res, ws


# -- the source transcriptions agree with each other ------------------------------------------
def test_rotarydelta_test_ik_inverts_linuxcnc_forward():
    """The test's geometric IK (knee down positive, z = depth) is the inverse of the FK
    transcribed from rotarydeltakins-common.h."""
    geo = (200.0, 300.0, 800.0, 50.0)
    rng = np.random.default_rng(3)
    for _ in range(20):
        P_L = np.array([*rng.uniform(-100, 100, 2), rng.uniform(-800, -650)])
        J = rotarydelta_joints(P_L[None], *geo)[0]
        assert np.allclose(rotarydelta_forward(J, *geo), P_L, atol=1e-9)


# -- Klipper rotary_delta ---------------------------------------------------------------------
def test_klipper_rotary_calibrated_example(delta_cal):
    nominal = load_machine(EXAMPLES / "delta_default.yaml")
    fmt, res, ws = _check_export("klipper-rotary-delta", delta_cal, nominal)
    assert res.remaining_rms < 0.2 * res.before_rms
    # export -> parse -> export: the values Klipper reads, the frame and legs pkmcal's own
    back = fmt.parse(res.text, "printer.cfg")
    v = res.params.values[:14]
    assert np.allclose(back.values[:14], v, rtol=0, atol=1e-10 * np.max(np.abs(v)))
    assert back.values[14] == 0.0 and list(back.values[15:]) == [1, 2, 3]
    # import -> machine -> values: Klipper's written values come back (the machine is in
    # Klipper's frame, bed at z = 0)
    imported = fmt.to_machine(back)
    again = fmt.initial(imported)
    assert again.values[14] == 0.0
    assert np.allclose(again.values[:14], back.values[:14], rtol=0, atol=1e-12)
    shift = np.array([0.0, 0.0, res.params.values[14]])
    q = fmt.ik(res.params, ws.P)
    assert np.allclose(imported.fk(q).P, ws.P - shift, atol=1e-10)


def test_klipper_rotary_exact_machine():
    """Per-leg arms, actuator offsets, one radius and height: Klipper holds it exactly."""
    u = np.zeros((3, 9))
    u[:, 0] = 0.4e-3                       # one radius for all legs
    u[:, 2] = -0.3e-3                      # one height
    u[:, 3] = [0.002, -0.001, 0.003]
    u[:, 4] = [0.5e-3, -0.2e-3, 0.1e-3]
    u[:, 5] = [-0.4e-3, 0.3e-3, 0.6e-3]
    m = Delta(0.2, 0.05, 0.3, 0.8, np.radians([90.0, 180.0, -90.0]),
              delta_parameters(u.reshape(-1)), home=(np.array([0.0, 0.0, -0.75]), np.eye(3)))
    fmt = controller_format("klipper-rotary-delta")
    ws = export_workspace(m)
    res = export(fmt, m, ws.P, ws.R)
    assert res.remaining_max < 1e-9
    rms, mx = independent_error("klipper-rotary-delta", res.text, m, ws.P)
    assert mx < 1e-9


def test_klipper_rotary_foreign_config_reads_readings_from_the_endstops():
    """A printer's own config (no pkmcal lines): Klipper's defaults for b/c and angles, the
    machine's readings counted from the endstops (reading 0: the arm at its endstop,
    ``dtheta`` = Klipper's abs_endstop), the bed at z = 0."""
    text = ("[printer]\nkinematics: rotary_delta\nshoulder_radius: 33.9\nshoulder_height: 412.9"
            "\n\n[stepper_a]\nposition_endstop: 252\nupper_arm_length: 170.0\n"
            "lower_arm_length: 320.0\n\n[stepper_b]\n\n[stepper_c]\n")
    fmt = controller_format("klipper-rotary-delta")
    p = fmt.parse(text, "printer.cfg")
    d = p.as_dict()
    assert np.degrees([d["angle_a"], d["angle_b"], d["angle_c"]]) == pytest.approx([30, 150, 270])
    assert d["upper_arm_length_c"] == pytest.approx(0.170)
    assert d["position_endstop_b"] == pytest.approx(0.252)
    assert d["bed_z"] == 0.0
    m = fmt.to_machine(p)
    P = np.array([[0.01, -0.02, 0.1], [0.0, 0.0, 0.2], [-0.03, 0.01, 0.05]])
    assert np.allclose(m.fk(fmt.ik(p, P)).P, P, atol=1e-12)
    # reading 0 is the arm at its endstop: the effector at the centre at position_endstop
    assert np.allclose(m.fk(np.zeros((1, 3))).P, [[0.0, 0.0, 0.252]], rtol=0, atol=1e-11 * 0.252)
    assert np.allclose(m.legs()[1], fmt.abs_endstops(p), rtol=0, atol=1e-15)
    assert np.allclose(fmt.ik(p, P), m.ik(P), atol=1e-12)


@pytest.mark.parametrize("line, key", [("shoulder_radius: 3x", "shoulder_radius"),
                                       ("shoulder_height: nan", "shoulder_height")])
def test_klipper_rotary_parse_errors_name_line_and_key(line, key):
    # the last value of an option is the one Klipper uses (configparser, strict=False)
    text = (f"[printer]\nkinematics: rotary_delta\nshoulder_radius: 30\n"
            f"shoulder_height: 400\n{line}\n[stepper_a]\nposition_endstop: 250\n"
            "upper_arm_length: 170\nlower_arm_length: 320\n")
    with pytest.raises(InputError, match=rf"cfg: line 5: \[printer\] {key}"):
        controller_format("klipper-rotary-delta").parse(text, "printer.cfg")
    with pytest.raises(InputError, match=r"\[stepper_a\] lower_arm_length is missing"):
        controller_format("klipper-rotary-delta").parse(
            "[printer]\nshoulder_radius: 30\nshoulder_height: 400\n[stepper_a]\n"
            "position_endstop: 250\nupper_arm_length: 170\n", "printer.cfg")


# -- LinuxCNC rotarydeltakins -----------------------------------------------------------------
def test_linuxcnc_rotarydelta_refuses_the_90_degree_delta(delta_cal):
    fmt = controller_format("linuxcnc-rotarydelta")
    why = fmt.applies(delta_cal)
    assert "-90, 30 and 150" in why and "90, 180, -90" in why
    with pytest.raises(InputError, match="linuxcnc-rotarydelta"):
        ws = export_workspace(delta_cal)
        export(fmt, delta_cal, ws.P)


def test_linuxcnc_rotarydelta_calibrated(delta120):
    nominal, cal = delta120
    fmt, res, ws = _check_export("linuxcnc-rotarydelta", cal, nominal)
    back = fmt.parse(res.text, "rotarydelta.hal")
    assert np.allclose(back.values, res.params.values, rtol=0, atol=1e-11)
    assert fmt.text(back, cal) == res.text
    imported = fmt.to_machine(back, cal)
    assert np.allclose(fmt.initial(imported).values, back.values, rtol=0, atol=1e-12)
    assert np.allclose(imported.fk(fmt.ik(back, ws.P)).P, ws.P, atol=1e-10)


def test_linuxcnc_rotarydelta_exact_machine(delta120):
    nominal, _ = delta120
    u = np.zeros((3, 9))
    u[:, 3] = [0.002, -0.001, 0.003]       # actuator offsets: the joints' zero
    m = Delta(nominal.a, nominal.b, nominal.l1, nominal.l2, nominal.leg_angles,
              delta_parameters(u.reshape(-1)), home=nominal.home)
    fmt = controller_format("linuxcnc-rotarydelta")
    ws = export_workspace(m)
    res = export(fmt, m, ws.P)
    assert res.remaining_max < 1e-9
    assert independent_error("linuxcnc-rotarydelta", res.text, m, ws.P)[1] < 1e-9


def test_linuxcnc_rotarydelta_parse_errors():
    fmt = controller_format("linuxcnc-rotarydelta")
    text = ("setp rotarydeltakins.platformradius 200\nsetp rotarydeltakins.thighlength x3\n"
            "setp rotarydeltakins.shinlength 800\nsetp rotarydeltakins.footradius 50\n")
    with pytest.raises(InputError, match=r"hal: line 2: rotarydeltakins.thighlength"):
        fmt.parse(text, "rd.hal")
    with pytest.raises(InputError, match="rotarydeltakins.footradius is missing"):
        fmt.parse(text.replace("x3", "300").replace("setp rotarydeltakins.footradius 50\n", ""),
                  "rd.hal")
    # a foreign file: reading i is joint i, the readings LinuxCNC's joints (sign changed)
    p = fmt.parse(text.replace("x3", "300"), "rd.hal")
    m = fmt.to_machine(p)
    assert np.degrees(m.leg_angles) == pytest.approx([-90, 30, 150])
    P = np.array([[0.01, 0.02, -0.7]])
    assert np.allclose(fmt.ik(p, P), m.ik(P), atol=1e-12)


# -- LinuxCNC lineardeltakins -----------------------------------------------------------------
def test_linuxcnc_lineardelta_calibrated_example(linear_cal):
    nominal = load_machine(EXAMPLES / "linear_delta.yaml")
    fmt, res, ws = _check_export("linuxcnc-lineardelta", linear_cal, nominal)
    back = fmt.parse(res.text, "lineardelta.hal")
    assert np.allclose(back.values, res.params.values, rtol=0, atol=1e-11)
    assert fmt.text(back, linear_cal) == res.text
    imported = fmt.to_machine(back, linear_cal)
    assert np.allclose(fmt.initial(imported).values, back.values, rtol=0, atol=1e-12)
    assert np.allclose(imported.fk(fmt.ik(back, ws.P)).P, ws.P, atol=1e-10)


def test_linuxcnc_lineardelta_exact_machine():
    nominal = load_machine(EXAMPLES / "linear_delta.yaml")
    m = load_machine(EXAMPLES / "linear_delta.yaml")
    p = m.parameters
    u = m.u.copy()
    for i, e in enumerate((0.3e-3, -0.2e-3, 0.5e-3)):
        u[p.index(f"tower{i + 1}.endstop")] += e
    m.parameters = p.with_values(u)
    fmt, res, ws = _check_export("linuxcnc-lineardelta", m, nominal)
    assert res.remaining_max < 1e-9


def test_linuxcnc_lineardelta_parse_needs_the_home_offsets():
    fmt = controller_format("linuxcnc-lineardelta")
    text = "setp lineardeltakins.R 132.5\nsetp lineardeltakins.L 250\n"
    with pytest.raises(InputError, match=r"\[JOINT_0\] HOME_OFFSET is missing"):
        fmt.parse(text, "ld.hal")
    text += "".join(f"# [JOINT_{j}] HOME_OFFSET = {500 + j}\n" for j in range(3))
    p = fmt.parse(text, "ld.hal")
    m = fmt.to_machine(p)
    assert np.degrees(m.towers()[1]) == pytest.approx([90, 210, 330])
    P = np.array([[0.01, 0.02, 0.05]])
    assert np.allclose(fmt.ik(p, P), m.ik(P), atol=1e-12)
    with pytest.raises(InputError, match=r"line 2: lineardeltakins.L"):
        fmt.parse(text.replace("L 250", "L 2,5"), "ld.hal")
