"""LinuxCNC genhexkins export (issue 15): the written .hal evaluated by an independent
implementation of genhexkins' inverse kinematics.

The independent side is written from LinuxCNC's source (src/emc/kinematics/genhexkins.c,
posemath's pmRpyMatConvert / pmMatCartMult, src/hal/components/scale.comp), not from pkmcal:
it reads the ``setp`` lines, builds ``R = Rz(C) Ry(B) Rx(A)`` from A, B, C in degrees with
posemath's formulas, takes strut i = ``|t + R a_i - b_i|`` (base and platform z plus
spindle-offset) and turns it into the drive's reading with the ``strut-reading.i`` scale
(``out = in * gain + offset``). The calibrated machine's forward kinematics of those readings
must land on the target (X, Y, Z and the orientation of A, B, C) within 1e-6 mm.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from pkmcal.calibration import calibrate_full_pose
from pkmcal.errors import InputError
from pkmcal.export import export, export_workspace
from pkmcal.export.linuxcnc_hexapod import GenhexkinsFormat, linuxcnc_abc
from pkmcal.instruments.pose import FullPoseNoise, default_measurement_frames, simulate_full_pose
from pkmcal.io import load_machine, parse_machine
from pkmcal.machines import default_hexaslide
from pkmcal.machines.deviations import random_deviations
from pkmcal.units import LENGTH

FMT = GenhexkinsFormat()


# -- the independent genhexkins --------------------------------------------------------------

def hal_pins(text: str) -> dict:
    """``setp PIN VALUE`` lines of a .hal file."""
    pins = {}
    for line in text.splitlines():
        words = line.split("#")[0].split()
        if len(words) == 3 and words[0] == "setp":
            pins[words[1]] = float(words[2])
    return pins


def rpy_matrix(a_deg, b_deg, c_deg) -> np.ndarray:
    """posemath pmRpyMatConvert (roll A, pitch B, yaw C in degrees as genhexkins passes them):
    m.x, m.y, m.z are the matrix's columns."""
    sg, cg = math.sin(math.radians(a_deg)), math.cos(math.radians(a_deg))
    sb, cb = math.sin(math.radians(b_deg)), math.cos(math.radians(b_deg))
    sa, ca = math.sin(math.radians(c_deg)), math.cos(math.radians(c_deg))
    mx = [ca * cb, sa * cb, -sb]
    my = [ca * sb * sg - sa * cg, sa * sb * sg + ca * cg, cb * sg]
    mz = [ca * sb * cg + sa * sg, sa * sb * cg - ca * sg, cb * cg]
    return np.array([mx, my, mz]).T


def genhex_struts(pins: dict, xyz, abc) -> np.ndarray:
    """genhexKinematicsInverse: the six joint values (strut lengths, machine units)."""
    dz = pins.get("genhexkins.spindle-offset", 0.0) + pins.get("genhexkins.tool-offset", 0.0)
    R = rpy_matrix(*abc)
    out = []
    for i in range(6):
        b = np.array([pins[f"genhexkins.base.{i}.{c}"] for c in "xyz"]) + [0, 0, dz]
        a = np.array([pins[f"genhexkins.platform.{i}.{c}"] for c in "xyz"]) + [0, 0, dz]
        out.append(float(np.linalg.norm(np.asarray(xyz) + R @ a - b)))
    return np.array(out)


def scale(pins: dict, instance: str, value):
    """LinuxCNC's scale component: out = in * gain + offset."""
    return value * pins[f"{instance}.gain"] + pins[f"{instance}.offset"]


def grid(machine):
    """X, Y, Z (mm) +/-40 mm around home and A, B, C in {-8, 0, 8} deg: 3^6 poses."""
    home = np.asarray(machine.home[0]) * 1e3
    steps = (-40.0, 0.0, 40.0)
    angles = (-8.0, 0.0, 8.0)
    return [(home + [dx, dy, dz], (a, b, c))
            for dx, dy, dz in itertools.product(steps, repeat=3)
            for a, b, c in itertools.product(angles, repeat=3)]


# -- machines: the example and a 6-6 hexapod read in motor revolutions -------------------------

def hexapod_file() -> str:
    """A 6-6 hexapod (base radius 250 mm, platform 120 mm, joint pairs 20/50 deg apart), legs
    read in motor revolutions: 5 mm of strut per rev, 380 mm at reading 0."""
    legs = []
    for k in range(6):
        pair, side = divmod(k, 2)
        tb = math.radians(120 * pair + (-10 if side == 0 else 10))
        tp = math.radians(120 * pair + 60 + (-25 if side == 1 else 25)) - math.radians(60)
        b = [250 * math.cos(tb), 250 * math.sin(tb), 0.0]
        p = [120 * math.cos(tp), 120 * math.sin(tp), -15.0]
        legs.append(f"  - {{base: {b}, platform: {p}, l0: 380.0, gain: 5.0}}")
    return ("pkmcal: 1\nmachine: stewart\nname: 6-6 hexapod in rev\n"
            "units: {length: mm, angle: deg}\nreadings: {unit: rev}\nlegs:\n"
            + "\n".join(legs) + "\nhome: [0.0, 0.0, 420.0, 0.0, 0.0, 0.0]\n")


def calibrated(nominal, seed=0):
    """nominal + random deviations, 60 simulated poses with the default noise, calibrated."""
    true = nominal.with_parameters(nominal.u + random_deviations(
        nominal, np.random.default_rng(seed)))
    data = simulate_full_pose(true, 60, default_measurement_frames(), FullPoseNoise(),
                              np.random.default_rng(seed + 1))
    res = calibrate_full_pose(nominal, data)
    assert res.success
    machine = res.machine
    machine.file_units = {"length": "mm", "angle": "deg"}
    return machine


@pytest.fixture(scope="module", params=["cubic_6upu-mm", "hexapod-rev"])
def case(request):
    if request.param == "cubic_6upu-mm":
        nominal = load_machine("examples/cubic_6upu.yaml")
    else:
        nominal = parse_machine(hexapod_file(), "hexapod.yaml")
    machine = calibrated(nominal)
    ws = export_workspace(machine)
    result = export(FMT, machine, ws.P, ws.R, nominal=nominal, workspace=ws.description)
    return nominal, machine, result


# -- the written values, evaluated independently -----------------------------------------------

def test_independent_genhexkins_lands_on_the_targets(case):
    """Over a grid of poses: the independent strut lengths, through the written command
    scales, are readings that put the calibrated machine on the target within 1e-6 mm (and
    the target's orientation within 1e-9 rad); the feedback scales give the strut back."""
    _, machine, result = case
    pins = hal_pins(result.text)
    factor = LENGTH.get(machine.reading_unit, 1.0)      # the drive's unit -> pkmcal internal
    targets = grid(machine)
    readings, struts = [], []
    for xyz, abc in targets:
        L = genhex_struts(pins, xyz, abc)
        r = np.array([scale(pins, f"strut-reading.{i}", L[i]) for i in range(6)])
        back = np.array([scale(pins, f"strut-length.{i}", r[i]) for i in range(6)])
        np.testing.assert_allclose(back, L, rtol=0, atol=1e-9)
        readings.append(r * factor)
        struts.append(L)
    P = np.array([t[0] for t in targets]) * 1e-3
    R = np.array([rpy_matrix(*t[1]) for t in targets])
    fk = machine.fk(np.array(readings), start=(P, R))
    assert fk.converged.all()
    error_mm = np.linalg.norm(fk.P - P, axis=1) * 1e3
    assert error_mm.max() < 1e-6, error_mm.max()
    rot = np.einsum("kji,kjl->kil", fk.R, R) - np.eye(3)
    assert np.abs(rot).max() < 1e-9
    # pkmcal's own kinematics reads the same strut lengths (m): the format's ik agrees
    np.testing.assert_allclose(FMT.ik(result.params, P, R), np.array(readings),
                               rtol=0, atol=1e-9)
    # the error export reports is that of the file: zero to rounding
    assert result.remaining_max < 1e-9 and result.remaining_rms < 1e-9
    assert result.before_rms > 1e-4          # the nominal's values: mm off


def test_the_file_says_its_units_and_convention(case):
    _, machine, result = case
    text = result.text
    assert "Lengths in mm" in text and "R = Rz(C) Ry(B) Rx(A)" in text
    assert f"# pkmcal: readings {machine.reading_unit}" in text
    pins = hal_pins(text)
    assert pins["genhexkins.spindle-offset"] == 0 and pins["genhexkins.screw-lead"] == 0
    assert {f"genhexkins.base.{i}.x" for i in range(6)} <= set(pins)   # 0-based struts
    assert "genhexkins.base.6.x" not in pins
    b, _, l0, g = machine.legs()
    np.testing.assert_allclose(pins["genhexkins.base.3.z"], b[3, 2] * 1e3, rtol=0, atol=1e-8)
    f = LENGTH.get(machine.reading_unit, 1.0)
    np.testing.assert_allclose(pins["strut-length.2.gain"], g[2] * f * 1e3, rtol=1e-14)
    np.testing.assert_allclose(pins["strut-length.2.offset"], l0[2] * 1e3, rtol=0, atol=1e-8)
    assert "loadrt scale names=strut-length.0," in text
    assert "addf strut-reading.5 servo-thread" in text


def test_linuxcnc_angles_are_the_posemath_convention():
    rng = np.random.default_rng(3)
    for a, b, c in rng.uniform(-60, 60, (20, 3)):
        np.testing.assert_allclose(linuxcnc_abc(rpy_matrix(a, b, c)), [a, b, c], atol=1e-10)


# -- import and round trip ------------------------------------------------------------------------

def test_export_import_export_round_trip(case):
    nominal, machine, result = case
    params = FMT.parse(result.text, "written.hal")
    np.testing.assert_array_equal(params.values, result.params.values)
    assert params.reading_unit == machine.reading_unit
    imported = FMT.to_machine(params, like=nominal)
    assert imported.kind == "stewart" and imported.reading_unit == machine.reading_unit
    np.testing.assert_allclose(imported.u, machine.u, rtol=1e-11, atol=1e-14)
    np.testing.assert_allclose(imported.home[0], nominal.home[0])
    again = export(FMT, imported, result_ws(machine).P, result_ws(machine).R)
    assert again.text == result.text


def result_ws(machine):
    return export_workspace(machine)


def test_import_of_a_plain_genhexkins_file():
    """LinuxCNC's sample kinematics.hal style: joints only; the readings are strut lengths."""
    lines = []
    base = [(-22.95, 13.25), (22.95, 13.25), (22.95, 13.25), (0, -26.5), (0, -26.5),
            (-22.95, 13.25)]
    plat = [(-1, 11.5), (1, 11.5), (10.459, -4.884), (9.459, -6.616), (-9.459, -6.616),
            (-10.459, -4.884)]
    for i, (x, y) in enumerate(base):
        lines += [f"setp genhexkins.base.{i}.x {x}", f"setp genhexkins.base.{i}.y {y}",
                  f"setp genhexkins.base.{i}.z 0.000"]
    for i, (x, y) in enumerate(plat):
        lines += [f"setp genhexkins.platform.{i}.x  {x}   # comment",
                  f"setp genhexkins.platform.{i}.y {y}", f"setp genhexkins.platform.{i}.z 0"]
    lines.append("setp genhexkins.convergence-criterion 1e-9")
    text = "\n".join(lines) + "\n"
    params = FMT.parse(text, "kinematics.hal")
    m = FMT.to_machine(params)
    b, p, l0, g = m.legs()
    np.testing.assert_allclose(b[3], [0, -0.0265, 0])
    np.testing.assert_allclose(p[2], [0.010459, -0.004884, 0])
    assert m.reading_unit == "mm"
    np.testing.assert_array_equal(g, 1.0)
    np.testing.assert_array_equal(l0, 0.0)
    # a spindle offset moves every joint's z
    shifted = FMT.parse(text + "setp genhexkins.spindle-offset 10\n", "k.hal")
    bs, ps, _, _ = FMT.to_machine(shifted).legs()
    np.testing.assert_allclose(bs[:, 2], 0.010)
    np.testing.assert_allclose(ps[:, 2], 0.010)


# -- what the format refuses -------------------------------------------------------------------

def test_a_hexa_slide_is_refused_with_the_reason():
    why = FMT.applies(default_hexaslide())
    assert "Hexa Slide" in why and "strut" in why
    ws = export_workspace(default_hexaslide())
    with pytest.raises(InputError, match="linuxcnc-genhexkins: a Hexa Slide"):
        export(FMT, default_hexaslide(), ws.P, ws.R)
    assert "delta" in FMT.applies(load_machine("examples/delta_default.yaml"))


@pytest.fixture(scope="module")
def written():
    m = load_machine("examples/cubic_6upu.yaml")
    return FMT.text(FMT.initial(m), m)


@pytest.mark.parametrize("edit, words", [
    (lambda t: t.replace("setp genhexkins.base.4.y", "# setp genhexkins.base.4.y"),
     "genhexkins.base.4.y is not set"),
    (lambda t: t.replace("setp genhexkins.platform.0.z 0", "setp genhexkins.platform.0.z x1"),
     "genhexkins.platform.0.z: expected a number, got 'x1'"),
    (lambda t: t.replace("setp genhexkins.screw-lead 0", "setp genhexkins.screw-lead 5"),
     "screw-lead 5"),
    (lambda t: t.replace("setp strut-reading.1.gain 1", "setp strut-reading.1.gain 1.01"),
     "strut-reading.1 (gain 1.01"),
    (lambda t: t + "setp genhexkins.base.6.x 1\n", "genhexkins has struts 0..5"),
    (lambda t: t + "setp strut-length.3.gain 0\n", "strut-length.3.gain: must not be 0"),
    (lambda t: t + "setp genhexkins.base.0.x\n", "expected 'setp PIN VALUE'"),
])
def test_malformed_files_are_refused_naming_line_and_pin(written, edit, words):
    with pytest.raises(InputError) as err:
        FMT.parse(edit(written), "bad.hal")
    assert str(err.value).startswith("bad.hal: ") and words in str(err.value), str(err.value)
