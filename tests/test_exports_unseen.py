"""Calibrated machines nobody tuned the code on, exported and run in the controllers' own code
(issue 34, its last 'Done when').

Each case draws a machine with a seeded numpy Generator: a nominal geometry that is not an
example's (the example's radii, arm lengths and heights scaled by random factors, tower or leg
angles turned by random offsets, counter-clockwise and clockwise orders for Klipper, the
machine file in mm or in inch), then random deviations of every parameter
(:func:`pkmcal.machines.deviations.random_deviations`, what ``pkmcal simulate`` gives a true
machine); one case of each format (:data:`CALIBRATED`) is instead a real calibrated file
(``pkmcal simulate`` + ``pkmcal calibrate``, its covariance in the report beside it).
``pkmcal export`` (in process) writes the controller's file, which runs in the controller's own
code:

- Klipper (:mod:`klippy_harness`): Klipper's ``configfile`` reads it (main file, ``[include]``
  or the SAVE_CONFIG block of an existing config), its kinematics home (homing's two
  ``set_position`` calls: no NaN) and command the export's workspace (itersolve on its C
  kinematics), its forward kinematics inverts them;
- LinuxCNC's Delta kinematics (Debian's ``lineardeltakins`` / ``rotarydeltakins`` bindings of
  the C code, :mod:`linuxcnc_stack`) with the values and ``HOME_OFFSET`` read back off the
  written configuration directory: the joints for the workspace, the forward map of them, and
  the INI's home joints;
- genhexkins (no Python binding): the written HAL and INI read back for every case, and one
  unseen machine started in LinuxCNC headless (:func:`linuxcnc_stack.run_linuxcnc`): home, the
  first moves, the joints read back.

Asserted: the calibrated machine driven by the controller's commands lands where pkmcal's export
promises (1e-6 mm), the error the export states (RMS, max, rounding included) is the one the
controller then leaves (to a relative 1e-6 or 1e-6 mm, the larger), the controller homes, and an
import of the written file followed by an export gives the controller the same values (the
identity, in the controller's code). Each case prints a row ``unseen | format | seed | stated
RMS/max | controller RMS/max`` (run with ``-s`` to see the table).
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from clitools import run
from pkmcal.export import controller_format, export_workspace, position_errors
from pkmcal.io.machine_file import load_machine, save_machine
from pkmcal.machines.deviations import random_deviations

pytestmark = [
    # klippy's configfile reads with configparser's readfp (Python < 3.12)
    pytest.mark.filterwarnings("ignore:This method will be removed:DeprecationWarning")]

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
#: 1e-6 mm: the agreement asked of the controller with pkmcal's promise
AGREE_M = 1e-9
#: the stated remaining error against the controller's: relative 1e-6 or 1e-6 mm
REL = 1e-6
#: machines per format, seeds of their Generators
SEEDS = {"klipper": [3401, 3402, 3403, 3404, 3405],
         "klipper-rotary-delta": [3411, 3412, 3413, 3414, 3415],
         "linuxcnc-lineardelta": [3421, 3422, 3423, 3424],
         "linuxcnc-rotarydelta": [3431, 3432, 3433, 3434],
         "linuxcnc-genhexkins": [3441, 3442, 3443, 3444]}
#: the seeds whose machine is a real calibrated file (simulate + calibrate), one per format
CALIBRATED = {3401, 3411, 3421, 3431, 3442}


# -- unseen machines --------------------------------------------------------------------------
def _units(rng) -> tuple[str, float]:
    """The machine file's length unit and its size in mm."""
    return ("inch", 25.4) if rng.random() < 0.5 else ("mm", 1.0)


def _ccw_angles(rng, base, jitter: float, clockwise: bool) -> list[float]:
    """Three angles about ``base`` (deg) at 120 deg steps, turned by a random offset, each off
    by up to ``jitter``; clockwise: the order a -> b -> c turns the other way."""
    offset = rng.uniform(-180.0, 180.0)
    step = -120.0 if clockwise else 120.0
    return [float(base + offset + k * step + rng.uniform(-jitter, jitter)) for k in range(3)]


def _near_linuxcnc(rng, hips, jitter: float) -> list[float]:
    """LinuxCNC's three fixed hip/tower angles (deg), in a random order, each off by up to
    ``jitter`` (what LinuxCNC's kinematics cannot hold is the export's remaining error)."""
    return [float(a + rng.uniform(-jitter, jitter)) for a in rng.permutation(hips)]


def linear_delta_text(rng, fmt: str) -> tuple[str, str]:
    """A linear Delta printer's machine file (scaled Kossel), and its words."""
    unit, mm = _units(rng)
    radius = 132.5 * rng.uniform(0.6, 1.6)
    arm = radius * rng.uniform(1.7, 2.3)
    endstop = arm * rng.uniform(1.05, 1.45) + rng.uniform(-3, 3, 3)
    clockwise = bool(rng.random() < 0.5) if fmt == "klipper" else False
    angles = (_ccw_angles(rng, 210.0, 2.0, clockwise) if fmt == "klipper"
              else _near_linuxcnc(rng, [90.0, 210.0, 330.0], 1.0))
    f = lambda v: ", ".join(f"{x / mm:.9g}" for x in np.atleast_1d(v))  # noqa: E731
    text = (f"pkmcal: 1\nmachine: linear_delta\nname: unseen printer\n"
            f"units: {{length: {unit}, angle: deg}}\n"
            f"delta_radius: {radius / mm:.9g}\narm_length: {arm / mm:.9g}\n"
            f"tower_angles: [{', '.join(f'{a:.9g}' for a in angles)}]\n"
            f"position_endstop: [{f(endstop)}]\n"
            f"home: [0.0, 0.0, {0.35 * endstop.min() / mm:.9g}]\n")
    words = (f"R {radius:.1f} L {arm:.1f} mm, towers {np.round(angles, 1).tolist()} deg"
             f"{' cw' if clockwise else ''}, {unit}")
    return text, words


def rotary_delta_text(rng, fmt: str) -> tuple[str, str]:
    """A rotary Delta robot's machine file (scaled seed 001 Delta), and its words."""
    unit, mm = _units(rng)
    s = rng.uniform(0.8, 1.5)
    base, platform = 200.0 * s * rng.uniform(0.8, 1.2), 50.0 * s * rng.uniform(0.7, 1.3)
    upper = 300.0 * s * rng.uniform(0.85, 1.15)
    forearm = upper * rng.uniform(2.3, 3.0)
    depth = np.sqrt(forearm**2 - (base - platform) ** 2) * rng.uniform(0.88, 0.95)
    clockwise = bool(rng.random() < 0.5) if fmt == "klipper-rotary-delta" else False
    angles = (_ccw_angles(rng, 90.0, 3.0, clockwise) if fmt == "klipper-rotary-delta"
              else _near_linuxcnc(rng, [150.0, 30.0, -90.0], 1.0))
    text = (f"pkmcal: 1\nmachine: delta\nname: unseen Delta robot\n"
            f"units: {{length: {unit}, angle: deg}}\n"
            f"base_radius: {base / mm:.9g}\nplatform_radius: {platform / mm:.9g}\n"
            f"upper_arm: {upper / mm:.9g}\nforearm: {forearm / mm:.9g}\n"
            f"leg_angles: [{', '.join(f'{a:.9g}' for a in angles)}]\n"
            f"smr_offset: {30.0 * s / mm:.9g}\n"
            f"home: [0.0, 0.0, {-depth / mm:.9g}]\n")
    words = (f"a {base:.0f} b {platform:.0f} arms {upper:.0f}/{forearm:.0f} mm, legs "
             f"{np.round(angles, 1).tolist()} deg{' cw' if clockwise else ''}, {unit}")
    return text, words


def hexapod_text(rng, fmt: str) -> tuple[str, str]:
    """A six-leg platform's machine file (joint pairs on two circles, random sizes, twist and
    turn), readings in the file's length unit or in motor revolutions, and its words."""
    unit, mm = _units(rng)
    rb = rng.uniform(150.0, 450.0)
    rp = rb * rng.uniform(0.4, 0.8)
    gap_b, gap_p = rng.uniform(10.0, 40.0), rng.uniform(10.0, 40.0)
    turn = rng.uniform(-180.0, 180.0)
    height = rb * rng.uniform(1.0, 1.6)
    base, plat = [], []
    for i in range(6):
        k, side = i // 2, (-1) ** i
        a = np.radians(turn + 120.0 * k + side * gap_b / 2)
        p = np.radians(turn + 120.0 * k + side * (60.0 - gap_p / 2))
        base.append([rb * np.cos(a), rb * np.sin(a), rng.uniform(-5, 5)])
        plat.append([rp * np.cos(p), rp * np.sin(p), rng.uniform(-5, 5)])
    base, plat = np.array(base), np.array(plat)
    home = np.array([0.0, 0.0, height])
    lengths = np.linalg.norm(home + plat - base, axis=1)
    rev = bool(rng.random() < 0.5)
    if rev:         # motor revolutions: length = l0 + gain * reading, gain mm per rev
        gains = rng.uniform(50.0, 100.0, 6)
        l0 = lengths
        readings = "readings: {unit: rev}\n"
    else:
        gains, l0, readings = np.ones(6), np.zeros(6), ""
    v = lambda x: "[" + ", ".join(f"{c / mm:.9g}" for c in x) + "]"  # noqa: E731
    legs = "".join(f"  - {{base: {v(b)}, platform: {v(p)}, l0: {l0[i] / mm:.9g}, "
                   f"gain: {gains[i] / (mm if rev else 1.0):.9g}}}\n"
                   for i, (b, p) in enumerate(zip(base, plat, strict=True)))
    text = (f"pkmcal: 1\nmachine: stewart\nname: unseen hexapod\n"
            f"units: {{length: {unit}, angle: deg}}\n{readings}legs:\n{legs}"
            f"home: [0.0, 0.0, {height / mm:.9g}, 0.0, 0.0, 0.0]\n")
    words = (f"base r {rb:.0f} platform r {rp:.0f} height {height:.0f} mm, turn {turn:.0f} "
             f"deg, readings {'rev' if rev else unit}, {unit}")
    return text, words


MACHINES = {"klipper": linear_delta_text, "linuxcnc-lineardelta": linear_delta_text,
            "klipper-rotary-delta": rotary_delta_text,
            "linuxcnc-rotarydelta": rotary_delta_text,
            "linuxcnc-genhexkins": hexapod_text}
SCENARIO = {"klipper": "probe", "linuxcnc-lineardelta": "probe",
            "klipper-rotary-delta": "tracker", "linuxcnc-rotarydelta": "tracker",
            "linuxcnc-genhexkins": "pose"}


def unseen(tmp: Path, fmt: str, seed: int) -> tuple[Path, Path, str]:
    """The nominal and the calibrated machine file of case ``seed`` (the file's own units).

    Returns
    -------
    nominal, calibrated : Path
        The machine files.
    words : str
        The machine in words.
    """
    rng = np.random.default_rng(seed)
    text, words = MACHINES[fmt](rng, fmt)
    nominal = tmp / "nominal.yaml"
    nominal.write_text(text)
    m = load_machine(nominal)
    cal = tmp / "cal.yaml"
    if seed in CALIBRATED:          # a real calibrated file: simulate, calibrate
        proc = run("simulate", nominal, "--scenario", SCENARIO[fmt], "--seed", str(seed),
                   "--truth", "true.yaml", "-o", "data.csv", cwd=tmp)
        assert proc.returncode == 0, proc.stderr
        proc = run("calibrate", nominal, "data.csv", "-o", cal, cwd=tmp)
        assert proc.returncode == 0, proc.stderr
        assert "report: cal.json" in cal.read_text()      # its covariance beside it
        assert json.loads((tmp / "cal.json").read_text())["covariance"]
        return nominal, cal, words + ", calibrated"
    true = m.with_parameters(m.u + random_deviations(m, rng))
    true.file_units = m.file_units
    save_machine(true, cal, units=m.file_units)
    return nominal, cal, words + ", random deviations"


def workspace(machine):
    """The workspace ``pkmcal export`` fits and states its error over (its default)."""
    own = getattr(machine, "print_workspace", None)
    return own(rng=0) if callable(own) else export_workspace(machine)


def agree(actual: float, stated: float) -> bool:
    """The controller's error equals the stated one (relative 1e-6 or 1e-6 mm)."""
    return abs(actual - stated) <= max(REL * abs(stated), AGREE_M)


def report(fmt: str, seed: int, words: str, record: dict, e: np.ndarray) -> None:
    """Check and print one row of the table: stated error against the controller's."""
    stated = (record["remaining_rms_um"] * 1e-6, record["remaining_max_um"] * 1e-6)
    actual = (float(np.sqrt(np.mean(e**2))), float(e.max()))
    ok = agree(actual[0], stated[0]) and agree(actual[1], stated[1])
    print(f"\nunseen | {fmt} | {seed} | {stated[0] * 1e3:.6g} / {stated[1] * 1e3:.6g} mm | "
          f"{actual[0] * 1e3:.6g} / {actual[1] * 1e3:.6g} mm | "
          f"{'agree' if ok else 'DIFFER'} | {words}")
    assert ok, (stated, actual)


def export_file(tmp: Path, cal: Path, nominal: Path, fmt, out: str) -> dict:
    """``pkmcal export CAL --to FMT --nominal NOMINAL -o OUT``; its JSON record."""
    proc = run("export", cal, "--to", fmt.name, "--nominal", nominal, "-o", out, cwd=tmp)
    assert proc.returncode == 0, proc.stderr
    record = (tmp / out / "export.json" if out.endswith("/")
              else tmp / (out + ".json"))
    return json.loads(record.read_text())


# -- Klipper ----------------------------------------------------------------------------------
def _klippy():
    from klippy_harness import KLIPPY_MISSING

    if KLIPPY_MISSING is not None:
        pytest.skip(KLIPPY_MISSING)


@pytest.mark.parametrize("name,seed", [(f, s) for f in ("klipper", "klipper-rotary-delta")
                                       for s in SEEDS[f]])
def test_unseen_machine_in_klipper(tmp_path, name, seed):
    """An unseen calibrated Delta exported for Klipper (main file, ``[include]`` or onto an
    existing config through SAVE_CONFIG, by turns): Klipper homes without NaN, the machine
    goes where pkmcal promises, the stated error is Klipper's, and import + export gives
    Klipper the same values and steppers."""
    _klippy()
    from klippy_harness import Klippy, hardware
    from test_klipper_klippy import Written, klipper_targets, machine_readings

    fmt = controller_format(name)
    kin = "rotary_delta" if name == "klipper-rotary-delta" else "delta"
    nominal, cal, words = unseen(tmp_path, name, seed)
    machine = load_machine(cal)
    mode = ["main", "include", "save_config"][seed % 3]
    config = tmp_path / "printer.cfg"
    if mode == "save_config":       # the nominal machine's values first, then SAVE_CONFIG
        proc = run("export", nominal, "--to", name, "-o", "start.cfg", cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
        config.write_text(hardware(kin) + "\n" + (tmp_path / "start.cfg").read_text())
        record = export_file(tmp_path, cal, nominal, fmt, "printer.cfg")
        assert "#*# [printer]" in config.read_text()
    else:
        record = export_file(tmp_path, cal, nominal, fmt, "kinematics.cfg")
        fragment = (tmp_path / "kinematics.cfg").read_text()
        config.write_text(hardware(kin) + "\n" + (fragment if mode == "main"
                                                  else "[include kinematics.cfg]\n"))
    words += f", {mode}"
    res = Written(fmt, machine, record, config.read_text())
    ws = workspace(machine)
    P = ws.P
    k = Klippy(config)
    home = k.home()                                    # G28: raises on NaN steps
    assert np.all(np.isfinite(home)) and np.all(np.isfinite(k.homed))
    Pk = klipper_targets(fmt, res, machine, P)
    assert np.all(Pk[:, 2] >= -1e-9), "a target below Klipper's bed"
    q = machine_readings(fmt, res, k, Pk)
    assert np.all(np.isfinite(q))
    fk = machine.fk(q, start=(P, None))
    assert np.all(fk.converged)
    promised = P + position_errors(fmt, res.params, machine, P)
    assert np.abs(fk.P - promised).max() < AGREE_M
    # Klipper's forward kinematics inverts its inverse (a -> b -> c counter-clockwise)
    assert np.abs(k.position(k.stepper_positions(Pk)) - Pk).max() < AGREE_M * 1e3
    report(name, seed, words, record, np.linalg.norm(fk.P - P, axis=1))
    # import, export: the same values and steppers in Klipper
    proc = run("import", config, "--from", name, "-o", "imported.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    again = tmp_path / "again"
    again.mkdir()
    proc = run("export", tmp_path / "imported.yaml", "--to", name, "-o",
               again / "kinematics.cfg", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    (again / "printer.cfg").write_text(hardware(kin) + "\n[include kinematics.cfg]\n")
    k2 = Klippy(again / "printer.cfg")
    options = ([("printer", "shoulder_radius"), ("printer", "shoulder_height")]
               + [(f"stepper_{t}", o) for t in "abc" for o in
                  ("position_endstop", "upper_arm_length", "lower_arm_length", "angle")]
               if kin == "rotary_delta" else
               [("printer", "delta_radius")]
               + [(f"stepper_{t}", o) for t in "abc" for o in
                  ("position_endstop", "arm_length", "angle")])
    for sec, opt in options:
        assert k2.value(sec, opt) == pytest.approx(k.value(sec, opt), rel=0, abs=1e-9), \
            (sec, opt)
    assert np.abs(k2.home() - home).max() < AGREE_M * 1e3
    assert np.abs(k2.readings(Pk) - k.readings(Pk)).max() < 1e-12


# -- LinuxCNC: Delta kinematics through Debian's bindings -------------------------------------
def _setp(text: str, comp: str) -> dict:
    return {m.group(1): float(m.group(2)) for m in
            re.finditer(rf"^setp\s+{comp}\.(\S+)\s+(\S+)\s*$", text, re.M)}


def _ini(text: str, section: str, key: str) -> str | None:
    current = None
    for line in text.splitlines():
        m = re.match(r"^\[(.+)\]", line.strip())
        if m:
            current = m.group(1)
        elif current == section:
            m = re.match(rf"^{key}\s*=\s*(.*?)\s*$", line)
            if m:
                return m.group(1)
    return None


def read_config(fmt, config: Path):
    """The written configuration read back: the values (kinematics.hal with the INI's
    ``HOME_OFFSET``), the kinematics' pins and the INI."""
    hal = (config / "kinematics.hal").read_text()
    ini = (config / "machine.ini").read_text()
    params = fmt.parse(hal, "kinematics.hal")
    offsets = [float(_ini(ini, f"JOINT_{j}", "HOME_OFFSET")) for j in range(fmt.kins_joints)]
    assert np.allclose(offsets, fmt.home_offsets(params), rtol=0, atol=1e-12)
    assert _ini(ini, "KINS", "KINEMATICS").split()[0] == fmt.kins_module
    return params, _setp(hal, fmt.kins_module), ini


def imported_again(tmp_path: Path, fmt):
    """``pkmcal import config/`` then ``pkmcal export -o again/`` of what it imported: the
    configuration written again, read back (:func:`read_config`)."""
    proc = run("import", "config/", "--from", fmt.name, "-o", "imported.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = run("export", "imported.yaml", "--to", fmt.name, "-o", "again/", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    return read_config(fmt, tmp_path / "again")


GEOMETRY = {"rotarydeltakins": ("platformradius", "thighlength", "shinlength", "footradius"),
            "lineardeltakins": ("R", "L")}


@pytest.mark.parametrize("name,seed", [(f, s) for f in ("linuxcnc-lineardelta",
                                                        "linuxcnc-rotarydelta")
                                       for s in SEEDS[f]])
def test_unseen_delta_in_linuxcnc_kinematics(tmp_path, name, seed):
    """An unseen calibrated Delta exported as a LinuxCNC configuration directory: LinuxCNC's
    own kinematics (Debian's bindings) with the values read back off it command joints that
    put the machine where pkmcal promises, the stated error is LinuxCNC's, the INI's home is a
    pose LinuxCNC's kinematics accept, and import + export writes the same values."""
    from linuxcnc_stack import debian_kins, kins_missing

    if kins_missing() is not None:
        pytest.skip(kins_missing())
    fmt = controller_format(name)
    nominal, cal, words = unseen(tmp_path, name, seed)
    machine = load_machine(cal)
    record = export_file(tmp_path, cal, nominal, fmt, "config/")
    params, pins, ini = read_config(fmt, tmp_path / "config")
    geometry = [pins[g] for g in GEOMETRY[fmt.kins_module]]
    ws = workspace(machine)
    P = ws.P
    X = fmt.controller_world(params, P)
    # the home: the INI's HOME joints, LinuxCNC's forward map of them, then the first move
    home_j = [float(_ini(ini, f"JOINT_{j}", "HOME")) for j in range(3)]
    out = debian_kins(fmt.kins_module, geometry, inverse=X, forward=[home_j])
    assert out["geometry"] == pytest.approx(geometry, rel=1e-15)
    assert out["forward"][0] is not None and np.all(np.isfinite(out["forward"][0]))
    assert all(j is not None for j in out["inverse"])
    J = np.array(out["inverse"])
    back = np.array(debian_kins(fmt.kins_module, geometry, forward=J)["forward"])
    assert np.abs(back - X).max() < AGREE_M * 1e3
    q = fmt.machine_readings(params, J)
    fk = machine.fk(q, start=(P, None))
    assert np.all(fk.converged)
    promised = P + position_errors(fmt, params, machine, P)
    assert np.abs(fk.P - promised).max() < AGREE_M
    report(name, seed, words, record, np.linalg.norm(fk.P - P, axis=1))
    # import DIR/, export: the same pins, HOME_OFFSETs and joints
    params2, pins2, ini2 = imported_again(tmp_path, fmt)
    assert pins2 == pytest.approx(pins, rel=0, abs=1e-9)
    assert np.allclose(fmt.home_offsets(params2), fmt.home_offsets(params), rtol=0, atol=1e-9)
    J2 = np.array(debian_kins(fmt.kins_module, [pins2[g] for g in GEOMETRY[fmt.kins_module]],
                              inverse=fmt.controller_world(params2, P))["inverse"])
    assert np.abs(fmt.machine_readings(params2, J2) - q).max() < 1e-12 * max(
        1.0, np.abs(q).max())


# -- LinuxCNC: genhexkins ---------------------------------------------------------------------
def strut_lengths(params, P, R) -> np.ndarray:
    """genhexkins' inverse restated: each strut from its base joint to its platform joint."""
    base, plat, _, _ = params.legs()
    tips = P[:, None, :] + np.einsum("kij,lj->kli", R, plat)
    return np.linalg.norm(tips - base[None], axis=-1)


@pytest.mark.parametrize("seed", SEEDS["linuxcnc-genhexkins"])
def test_unseen_hexapod_genhexkins(tmp_path, seed):
    """An unseen calibrated hexapod exported as a LinuxCNC configuration directory, read back:
    genhexkins' strut lengths of the written joints, through the written scale pairs, put the
    machine where pkmcal promises; the stated error is that; import + export writes the same
    values. The first case also starts in LinuxCNC headless (home, the first moves)."""
    name = "linuxcnc-genhexkins"
    fmt = controller_format(name)
    nominal, cal, words = unseen(tmp_path, name, seed)
    machine = load_machine(cal)
    record = export_file(tmp_path, cal, nominal, fmt, "config/")
    params, pins, ini = read_config(fmt, tmp_path / "config")
    ws = workspace(machine)
    P, R = ws.P, ws.R
    L = strut_lengths(params, P, R)
    assert np.abs(L / 1e-3 - fmt.controller_joints(params, fmt.ik(params, P, R))).max() < 1e-9
    q = fmt.machine_readings(params, L / 1e-3)
    fk = machine.fk(q, start=(P, R))
    assert np.all(fk.converged)
    promised = P + position_errors(fmt, params, machine, P, R)
    assert np.abs(fk.P - promised).max() < AGREE_M
    report(name, seed, words, record, np.linalg.norm(fk.P - P, axis=1))
    params2, pins2, _ = imported_again(tmp_path, fmt)
    assert pins2 == pytest.approx(pins, rel=0, abs=1e-9)
    assert np.allclose(params2.values, params.values, rtol=1e-12, atol=1e-12)
    if seed == SEEDS[name][0]:
        _start_genhexkins(tmp_path / "config", fmt, params, machine, P, R)


def _start_genhexkins(config: Path, fmt, params, machine, P, R):
    """Start the configuration in LinuxCNC headless: home, MDI moves to workspace poses, the
    joints read back; the machine, driven with them, is on the targets."""
    from linuxcnc_stack import run_linuxcnc, stack_missing

    if stack_missing() is not None:
        pytest.skip(stack_missing())
    pick = np.linspace(0, len(P) - 1, 4).astype(int)
    X = fmt.controller_world(params, P[pick], R[pick])
    request = {"joints": 6, "axes": fmt.coordinates.replace(" ", ""), "poses": X.tolist()}
    result = run_linuxcnc(config / "machine.ini", request)
    assert result.get("failed") is None, (result.get("failed"), result["log"][-3000:])
    assert not result["errors"], result["errors"]
    J = np.array([r["joints"] for r in result["poses"]])
    assert np.abs(J - strut_lengths(params, P[pick], R[pick]) / 1e-3).max() < 1e-9
    fk = machine.fk(fmt.machine_readings(params, J), start=(P[pick], R[pick]))
    promised = P[pick] + position_errors(fmt, params, machine, P[pick], R[pick])
    assert np.abs(fk.P - promised).max() < AGREE_M
    shutil.rmtree(config, ignore_errors=True)


# -- defects these machines found -------------------------------------------------------------
#: a rotary Delta's Klipper config with its endstops low (80 mm above the bed at the centre)
LOW_ENDSTOPS = """
[printer]
kinematics: rotary_delta
shoulder_radius: 154.234949321
shoulder_height: 707.424470513

[stepper_a]
position_endstop: 85.507710326
upper_arm_length: 263.169271542
lower_arm_length: 749.368495312
angle: 62.855246994730

[stepper_b]
position_endstop: 80.802551865
upper_arm_length: 261.724472415
lower_arm_length: 750.072333067
angle: 182.510665599946

[stepper_c]
position_endstop: 87.088638021
upper_arm_length: 263.022846152
lower_arm_length: 748.893076108
angle: 304.085096685003
"""


def test_klipper_rotary_import_with_low_endstops_exports_the_same_values(tmp_path):
    """Defect (found by seed 3415): a Klipper rotary config whose lowest endstop is less than
    100 mm above the bed, imported and exported, came back with shoulder_height 726.59 for
    707.42 mm: the import put home 50 mm below the lowest endstop, the default 0.1 m cube
    around it reached below Klipper's bed, and the export moved the bed to the cube's lowest
    point. Now the same values come back (and Klipper runs them the same)."""
    fmt = controller_format("klipper-rotary-delta")
    (tmp_path / "printer.cfg").write_text(LOW_ENDSTOPS)
    proc = run("import", "printer.cfg", "--from", fmt.name, "-o", "m.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = run("export", "m.yaml", "--to", fmt.name, "-o", "back.cfg", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    before = fmt.parse(LOW_ENDSTOPS, "printer.cfg").as_dict()
    after = fmt.parse((tmp_path / "back.cfg").read_text(), "back.cfg").as_dict()
    for key in ("shoulder_radius", "shoulder_height", "angle_a", "position_endstop_b",
                "upper_arm_length_c", "lower_arm_length_a"):
        assert after[key] == pytest.approx(before[key], rel=0, abs=1e-12), key
    record = json.loads((tmp_path / "back.cfg.json").read_text())
    assert record["values"]["bed_z"] == 0.0
    from klippy_harness import KLIPPY_MISSING

    if KLIPPY_MISSING is None:
        from klippy_harness import Klippy, hardware

        (tmp_path / "a.cfg").write_text(hardware("rotary_delta") + LOW_ENDSTOPS)
        (tmp_path / "b.cfg").write_text(hardware("rotary_delta")
                                        + (tmp_path / "back.cfg").read_text())
        ka, kb = Klippy(tmp_path / "a.cfg"), Klippy(tmp_path / "b.cfg")
        assert np.abs(ka.home() - kb.home()).max() < 1e-9
        Pk = np.array([[0.0, 0.0, 10.0], [40.0, -30.0, 60.0], [-80.0, 20.0, 5.0]])
        assert np.abs(ka.readings(Pk) - kb.readings(Pk)).max() < 1e-12


def test_hexapod_file_in_inch_without_readings_reads_back(tmp_path):
    """Defect (found by seed 3443): a six-leg platform's file with ``units: {length: inch}``
    and no ``readings:`` was written back (``simulate --truth``, ``calibrate``, any save) with
    ``readings: {unit: inch}``, which the reader refuses ('inch' is a length unit the data
    files do not use): pkmcal could not read its own file."""
    text = (EXAMPLES / "cubic_6upu.yaml").read_text().replace("length: mm", "length: inch")
    text = text.replace("readings: {unit: mm}\n", "")
    (tmp_path / "m.yaml").write_text(text)
    m = load_machine(tmp_path / "m.yaml")
    save_machine(m, tmp_path / "back.yaml", units=m.file_units)
    back = load_machine(tmp_path / "back.yaml")
    assert np.array_equal(back.u, m.u)
    proc = run("simulate", "m.yaml", "--scenario", "pose", "--poses", "20", "--truth",
               "true.yaml", "-o", "d.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert load_machine(tmp_path / "true.yaml").reading_unit == m.reading_unit
