"""Export to the printer firmwares (issue 15): Klipper ``delta``, Marlin ``M665``/``M666`` and
RepRapFirmware ``M665``/``M666`` for a linear Delta.

Each format's WRITTEN text is read here with a regular expression and evaluated with an
independent implementation of the firmware's inverse kinematics, written from its source, not
from pkmcal's models:

- Klipper ``klippy/kinematics/delta.py``: towers ``(cos(angle) r, sin(angle) r)``,
  ``abs_endstop = position_endstop + sqrt(arm^2 - r^2)``, carriage height ``sqrt(arm^2 - (tx -
  x)^2 - (ty - y)^2) + z``, steps since the endstop ``(abs_endstop - height) / step_dist``;
- Marlin ``module/delta.cpp`` ``recalc_delta_settings`` (towers at 210 + X, 330 + Y, 90 + Z
  deg, rods ``L + A|B|C``), ``delta.h`` ``DELTA_Z``, ``motion.cpp`` (``homeaxis`` moves each
  carriage ``delta_endstop_adj`` from its endstop, ``set_axis_is_at_home`` declares the nozzle
  at ``(0, 0, H)``);
- RepRapFirmware ``LinearDeltaKinematics.cpp`` ``Recalc`` (``towerX[A] = -(r cos(30 + X))``
  ...), ``homedCarriageHeights = H + sqrt(L^2 - r^2) + adj``, ``Transform`` with the tilts.

The controllers' coordinates are the bed's (pkmcal's convention, see
:mod:`pkmcal.export.klipper`): a target ``(x, y, z)`` of the calibrated frame is ``z - height``
above the bed for Klipper and Marlin and ``z - height - tilt_x x - tilt_y y`` for
RepRapFirmware (whose ``A``, ``B`` hold the bed's tilt).

Figures (examples/linear_delta.yaml simulated with seed 1 and calibrated; grid of 294 targets,
radius 90 mm, z 0 to 150 mm): from tracker data with the ``full`` model (tilted towers,
radius trims) Klipper and Marlin leave 126.0 um RMS / 338.2 um max, RepRapFirmware 115.7 /
287.8 um (the nominal values: 887 / 1930 um); from probe heights with Klipper's parameter set
on a bed tilted against the towers RepRapFirmware leaves 0 (below 1e-9 mm; it holds the tilt)
and Klipper and Marlin what their values cannot fold in of the tilt.
"""

from __future__ import annotations

import math
import re
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from clitools import run
from pkmcal.errors import InputError
from pkmcal.export.fitting import export, position_errors
from pkmcal.export.klipper import KLIPPER
from pkmcal.export.marlin import MARLIN
from pkmcal.export.reprapfirmware import REPRAPFIRMWARE
from pkmcal.instruments.probe import BedSetup, bed_plane
from pkmcal.instruments.setups import Setups
from pkmcal.io.machine_file import load_machine, load_machine_file
from pkmcal.machines import linear_delta

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "linear_delta.yaml"
FORMATS = {"klipper": KLIPPER, "marlin": MARLIN, "reprapfirmware": REPRAPFIRMWARE}
#: what the written digits (1e-6 mm, 1e-9 deg) move a position by, at most, m
DIGITS = 3e-9


def grid() -> np.ndarray:
    """Workspace targets: a 90 mm disk from the bed to 150 mm above it, m."""
    out = []
    for z in np.linspace(0.0, 0.15, 6):
        for x in np.linspace(-0.09, 0.09, 9):
            for y in np.linspace(-0.09, 0.09, 9):
                if x * x + y * y <= 0.09**2 + 1e-12:
                    out.append((x, y, z))
    return np.array(out)


@cache
def calibrated(kind: str):
    """examples/linear_delta.yaml simulated (seed 1) and calibrated: ``tracker`` with the
    ``full`` model, ``probe`` with Klipper's set and the bed's tilt estimated (a bed
    section with a tilt: ``--bed-tilt estimate``; 37 heights fix it only as well as the
    endstops' differences, so ``auto`` takes the bed square). The machine and its set-ups
    (the bed)."""
    import tempfile

    tmp = Path(tempfile.mkdtemp(prefix="pkmcal_export_"))
    scenario, params = {"tracker": ("tracker", "full"), "probe": ("probe", "klipper")}[kind]
    p = run("simulate", EXAMPLE, "--scenario", scenario, "--seed", 1, "-o", "data.csv",
            cwd=tmp)
    assert p.returncode == 0, p.stderr
    tilt = ["--bed-tilt", "estimate"] if kind == "probe" else []
    p = run("calibrate", EXAMPLE, "data.csv", "--parameters", params, *tilt, "-o", "cal.yaml",
            cwd=tmp)
    assert p.returncode == 0, p.stderr
    return load_machine_file(tmp / "cal.yaml")


def commands(text: str) -> list:
    """The lines of a written file that are not comments."""
    return [x for x in text.splitlines() if x.strip() and x.strip()[0] not in "#;"]


def bed_of(setups):
    bed = bed_plane(setups)
    return (0.0, 0.0, 0.0) if bed is None else bed


# -- independent firmware kinematics, from the written text ------------------------------------
def klipper_ik(text: str, P, bed) -> np.ndarray:
    """Klipper's delta.py on the written printer.cfg fragment; targets above the bed."""
    sections, section = {}, None
    for line in text.splitlines():
        line = line.split("#")[0].strip()
        if m := re.fullmatch(r"\[(\w+)\]", line):
            section = sections.setdefault(m.group(1), {})
        elif m := re.fullmatch(r"(\w+)\s*:\s*(\S+)", line):
            section[m.group(1)] = m.group(2)
    radius = float(sections["printer"]["delta_radius"])
    q = np.empty((len(P), 3))
    for i, t in enumerate("abc"):
        s = sections[f"stepper_{t}"]
        arm, angle = float(s["arm_length"]), float(s["angle"])
        abs_endstop = float(s["position_endstop"]) + math.sqrt(arm**2 - radius**2)
        tx, ty = math.cos(math.radians(angle)) * radius, math.sin(math.radians(angle)) * radius
        for k, (x, y, z) in enumerate(np.asarray(P) * 1e3):
            z -= bed[0] * 1e3 + bed[1] * x + bed[2] * y              # above the bed
            height = math.sqrt(arm**2 - (tx - x) ** 2 - (ty - y) ** 2) + z
            q[k, i] = (abs_endstop - height) * 1e-3
    return q


def gcode(text: str, code: str) -> dict:
    words = {}
    for line in text.splitlines():
        line = line.split(";")[0].strip()
        if line.startswith(code + " "):
            words.update(re.findall(r"([A-Z])([-0-9.:]+)", line[len(code):]))
    return words


def marlin_ik(text: str, P, bed) -> np.ndarray:
    """Marlin's delta.cpp / delta.h / motion.cpp on the written M665 / M666 lines."""
    w, adj = gcode(text, "M665"), gcode(text, "M666")
    H, L, R = float(w["H"]), float(w["L"]), float(w["R"])
    q = np.empty((len(P), 3))
    for i, (base, trim, rod_trim, a) in enumerate(
            zip((210, 330, 90), "XYZ", "ABC", "XYZ", strict=True)):
        tower = (math.cos(math.radians(base + float(w[trim]))) * R,
                 math.sin(math.radians(base + float(w[trim]))) * R)
        rod2 = (L + float(w[rod_trim])) ** 2

        def delta_z(x, y, z, tower=tower, rod2=rod2):
            return z + math.sqrt(rod2 - ((tower[0] - x) ** 2 + (tower[1] - y) ** 2))

        # homing: the carriage leaves the endstop by adj (<= 0: down), then is declared at
        # the IK of (0, 0, H): the endstop is -adj above that
        endstop = delta_z(0.0, 0.0, H) - float(adj[a])
        for k, (x, y, z) in enumerate(np.asarray(P) * 1e3):
            z -= bed[0] * 1e3 + bed[1] * x + bed[2] * y              # above the bed
            q[k, i] = (endstop - delta_z(x, y, z)) * 1e-3
    return q


def rrf_ik(text: str, P, bed) -> np.ndarray:
    """RepRapFirmware's LinearDeltaKinematics.cpp on the written M665 / M666 lines."""
    w, e = gcode(text, "M665"), gcode(text, "M666")
    D = [float(v) for v in w["L"].split(":")]
    r, H = float(w["R"]), float(w["H"])
    X, Y, Z = (float(w[k]) for k in "XYZ")
    xTilt, yTilt = float(e["A"]) * 0.01, float(e["B"]) * 0.01
    rad = math.pi / 180
    towerX = [-(r * math.cos((30 + X) * rad)), +(r * math.cos((30 - Y) * rad)),
              -(r * math.sin(Z * rad))]
    towerY = [-(r * math.sin((30 + X) * rad)), -(r * math.sin((30 - Y) * rad)),
              +(r * math.cos(Z * rad))]
    q = np.empty((len(P), 3))
    for axis, stop in enumerate("XYZ"):
        homed = H + math.sqrt(D[axis] ** 2 - r**2) + float(e[stop])
        for k, (x, y, z) in enumerate(np.asarray(P) * 1e3):
            z = z - bed[0] * 1e3 - bed[1] * x - bed[2] * y          # above the bed
            pos = (math.sqrt(D[axis] ** 2 - (x - towerX[axis]) ** 2 - (y - towerY[axis]) ** 2)
                   + z + x * xTilt + y * yTilt)
            q[k, axis] = (homed - pos) * 1e-3
    return q


INDEPENDENT = {"klipper": klipper_ik, "marlin": marlin_ik, "reprapfirmware": rrf_ik}


def errors_of_text(name, text, machine, P, setups=None) -> np.ndarray:
    q = INDEPENDENT[name](text, P, bed_of(setups))
    fk = machine.fk(q)
    assert fk.converged.all()
    return np.linalg.norm(fk.P - P, axis=-1)


# -- tests ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", FORMATS)
def test_written_text_leaves_the_reported_error(name):
    """Tracker calibration with the full model (tilted towers, radius trims): the written
    values, through the firmware's own kinematics, leave the RMS and max error that export
    reports; the fitted values beat the values read off the machine and the nominal ones."""
    m, setups = calibrated("tracker")
    P = grid()
    fmt = FORMATS[name]
    r = export(fmt, m, P, nominal=load_machine(EXAMPLE), setups=setups)
    e = errors_of_text(name, r.text, m, P, setups)
    assert abs(math.sqrt(np.mean(e**2)) - r.remaining_rms) <= 1e-6 * r.remaining_rms + DIGITS
    assert abs(e.max() - r.remaining_max) <= 1e-6 * r.remaining_max + DIGITS
    direct = np.linalg.norm(position_errors(fmt, fmt.initial(m, setups), m, P), axis=-1)
    assert r.remaining_rms < math.sqrt(np.mean(direct**2))
    assert r.remaining_rms < 0.2 * r.before_rms
    assert 50e-6 < r.remaining_rms < 200e-6          # the towers' tilt: no firmware holds it


def test_reprapfirmware_tilt_does_at_least_as_well():
    m, setups = calibrated("tracker")
    P = grid()
    rms = {n: export(f, m, P, setups=setups).remaining_rms for n, f in FORMATS.items()}
    assert abs(rms["klipper"] - rms["marlin"]) < 1e-3 * rms["klipper"]
    assert rms["reprapfirmware"] <= rms["klipper"] * (1 + 1e-6)


@pytest.mark.parametrize("name", FORMATS)
def test_probe_calibration_counts_the_bed_tilt(name):
    """Probe heights with Klipper's set (vertical towers, one radius) on a bed tilted against
    the towers (SPEC 8: z = 0 is the bed, its tilt estimated where 37 heights tell it):
    RepRapFirmware holds the tilt (M666 A B) exactly; Klipper and Marlin cannot, so their
    values take what they can of it and the remaining error counts the rest, as their own
    kinematics on the written text show; never the tilt dropped (an error of 0)."""
    m, setups = calibrated("probe")
    bed = bed_plane(setups)
    assert bed is not None and bed[0] == 0 and abs(bed[1]) > 0
    P = grid()
    r = export(FORMATS[name], m, P, setups=setups)
    e = errors_of_text(name, r.text, m, P, setups)
    tilt = np.abs(bed[1] * P[:, 0] + bed[2] * P[:, 1])
    if name == "reprapfirmware":
        # exact but for the rounding of the written values, which the stated error includes
        assert r.remaining_max < DIGITS and e.max() < DIGITS
        assert abs(e.max() - r.remaining_max) <= 1e-6 * r.remaining_max + 1e-15
        return
    assert abs(math.sqrt(np.mean(e**2)) - r.remaining_rms) <= 1e-6 * r.remaining_rms + DIGITS
    assert abs(e.max() - r.remaining_max) <= 1e-6 * r.remaining_max + DIGITS
    # folded, not dropped: less than the tilt's own heights, but not nothing
    assert 0.01 * tilt.max() < r.remaining_max < tilt.max()


def _representable(name):
    """A true machine each format holds: per-tower arms, skewed angles, uneven endstops, a
    raised bed (tilted for RepRapFirmware), and its set-ups (the bed)."""
    m = linear_delta(0.1385, [0.2681, 0.2674, 0.2690], np.deg2rad([210.4, 329.7, 90.3]),
                     (0.2934, 0.2951, 0.2917))
    bed = (4e-4, 2e-3, -1e-3) if name == "reprapfirmware" else (4e-4, 0.0, 0.0)
    return m, Setups({"probe": BedSetup(*bed)})


@pytest.mark.parametrize("name", FORMATS)
def test_a_representable_machine_exports_exactly(name):
    m, setups = _representable(name)
    P = grid()
    fmt = FORMATS[name]
    e0 = np.linalg.norm(position_errors(fmt, fmt.initial(m, setups), m, P), axis=-1)
    assert e0.max() < 1e-12                               # initial() reads it exactly
    r = export(fmt, m, P, setups=setups)
    assert r.remaining_max < 1e-12
    assert errors_of_text(name, r.text, m, P, setups).max() < 1e-9


@pytest.mark.parametrize("name", FORMATS)
@pytest.mark.parametrize("kind", ["tracker", "probe"])
def test_round_trips(name, kind):
    """export -> parse -> text is the same text; import to a LinearDelta -> initial -> text
    writes the same values; the imported machine moves as the controller commands."""
    m, setups = calibrated(kind)
    P = grid()
    fmt = FORMATS[name]
    r = export(fmt, m, P, setups=setups)
    parsed = fmt.parse(r.text, "out")
    assert fmt.text(parsed, m, setups) == r.text
    np.testing.assert_allclose(fmt.ik(parsed, P), fmt.ik(r.params, P), rtol=0, atol=DIGITS)
    imported, imported_setups = fmt.to_machine(parsed, like=m), fmt.imported_setups(parsed)
    assert imported.kind == "linear_delta" and imported.geometry_problems() == []
    # the same G-code (RepRapFirmware's import takes A, B as the bed's slopes, so its
    # ``pkmcal bed`` comment names the imported frame)
    assert commands(fmt.text(fmt.initial(imported, imported_setups), m)) == commands(r.text)
    values = fmt.initial(imported, imported_setups)
    assert np.nanmax(np.abs(position_errors(fmt, values, imported, P))) < 1e-12
    again = export(fmt, imported, P, setups=imported_setups)
    assert again.remaining_max < 1e-12


def test_degenerate_values_are_fixed_and_normalised():
    m, _ = calibrated("tracker")
    P = grid()
    fixed = {n: [k for k, f in zip(fmt.initial(m).names, fmt.initial(m).fixed, strict=True)
                 if f] for n, fmt in FORMATS.items()}
    assert fixed["klipper"] == ["bed.z", "bed.tilt_x", "bed.tilt_y", "stepper_a.tower",
                                "stepper_b.tower", "stepper_c.tower"]
    assert fixed["marlin"][:2] == ["delta_height", "delta_diagonal_rod"]
    assert fixed["reprapfirmware"][0] == "homed_height"
    adj = [float(v) for v in gcode(export(MARLIN, m, P).text, "M666").values()]
    assert max(adj) == 0.0 and min(adj) < 0                # Marlin: <= 0, largest 0 (G33)
    e = gcode(export(REPRAPFIRMWARE, m, P).text, "M666")
    assert abs(sum(float(e[k]) for k in "XYZ")) < 5e-6    # RepRapFirmware: mean 0


def test_klipper_defaults_and_save_config_block():
    """Klipper's defaults (b, c take a's arm and endstop; angles 210, 330, 90) and its
    precedence (klippy/configfile.py ``_strip_duplicates``): the SAVE_CONFIG block gives what
    the sections above it do not define; where both define an option the sections win."""
    text = """[printer]
kinematics: delta
delta_radius: 140
[stepper_a]
arm_length: 270
position_endstop: 300
[stepper_b]
[stepper_c]
angle = 91.5

#*# <---------------------- SAVE_CONFIG ---------------------->
#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.
#*#
#*# [stepper_a]
#*# position_endstop = 299.5
#*#
#*# [stepper_b]
#*# position_endstop = 301.25
"""
    p = KLIPPER.parse(text, "printer.cfg").as_dict()
    assert p["arm_length_c"] == pytest.approx(0.27) and p["angle_a"] == pytest.approx(
        math.radians(210)) and p["angle_c"] == pytest.approx(math.radians(91.5))
    assert p["position_endstop_a"] == pytest.approx(0.3)          # the body wins
    assert p["position_endstop_b"] == pytest.approx(0.30125)      # the block fills in
    assert p["position_endstop_c"] == pytest.approx(0.3)          # a's, the default


@pytest.mark.parametrize("name, text, words", [
    ("klipper", "[printer]\ndelta_radius: 14o\n[stepper_a]\narm_length: 270\n"
     "position_endstop: 300\n", ["line 2", "[printer] delta_radius", "14o"]),
    ("klipper", "[printer]\ndelta_radius: 140\n", ["[stepper_a] arm_length", "missing"]),
    ("klipper", "[printer]\ndelta_radius: 140\n[stepper_a]\narm_length: 120\n"
     "position_endstop: 300\n", ["line 4", "arm_length"]),
    ("marlin", "M665 H280 L250 R130\nM666 X0 Y0.5 Z0\n", ["line 2", "M666 Y", "<= 0"]),
    ("marlin", "M665 H280 Lx R130\n", ["line 1", "M665 L"]),
    ("marlin", "M665 H280 R130\n", ["M665 L", "missing"]),
    ("reprapfirmware", "M665 L250:250:x R130 H280\n", ["line 1", "M665 L"]),
    ("reprapfirmware", "M665 L250:250:250:250 R130 H280\n", ["line 1", "4 diagonals"]),
    ("reprapfirmware", "M665 L250 R130\nM666 A1 B0\n", ["M665 H", "missing"]),
    ("reprapfirmware", "M665 L250 R130 H280\nM666 A1 Bnan\n", ["line 2", "M666 B"]),
])
def test_bad_input_names_the_line_and_key(name, text, words):
    with pytest.raises(InputError) as err:
        FORMATS[name].parse(text, "in.txt")
    for w in words:
        assert w in str(err.value), str(err.value)


def test_firmware_reports_are_read():
    """Marlin's M503 report and RepRapFirmware's config-override.g as they write them."""
    marlin = ("echo:; Delta settings: L<diagonal rod> R<radius> H<height> S<segments/s>\n"
              "echo:  M665 L250.00 R130.00 H280.00 S200.00 X0.10 Y-0.20 Z0.00 A0.00 B0.50 "
              "C0.00\necho:  M666 X-0.50 Y0.00 Z-0.25\n")
    p = MARLIN.parse(marlin, "m503").as_dict()
    assert p["delta_diagonal_rod_trim_b"] == pytest.approx(5e-4)
    assert p["delta_endstop_adj_c"] == pytest.approx(-2.5e-4)
    m = MARLIN.to_machine(MARLIN.parse(marlin, "m503"))
    assert m.firmware_values()["position_endstop"] == pytest.approx([0.2805, 0.28, 0.28025])
    rrf = ("; Delta parameters\nM665 L250.000:250.100:249.900 R130.000 H280.000 B85.0 "
           "X0.100 Y-0.200 Z0.000\nM666 X0.100 Y-0.050 Z-0.050 A0.20 B-0.10\n")
    p = REPRAPFIRMWARE.parse(rrf, "config-override.g").as_dict()
    assert p["diagonal_y"] == pytest.approx(0.2501) and p["x_tilt"] == pytest.approx(0.002)
    values = REPRAPFIRMWARE.parse(rrf, "config-override.g")
    m = REPRAPFIRMWARE.to_machine(values)
    assert bed_plane(REPRAPFIRMWARE.imported_setups(values)) == pytest.approx((0.0, 0.002,
                                                                                -0.001))
    assert not hasattr(m, "probe_bed")              # the bed is a set-up beside the machine
    assert m.firmware_values()["position_endstop"] == pytest.approx([0.2801, 0.27995,
                                                                     0.27995])


@pytest.mark.parametrize("name, kinematics, other", [
    ("klipper", "delta", "Delta"),                  # delta: the kinematics' case folded
    ("klipper-rotary-delta", "rotary_delta", None),
])
def test_klipper_update_refuses_a_config_of_other_kinematics(name, kinematics, other):
    """Both Klipper formats refuse to save into a printer.cfg of other (or no) kinematics,
    naming the file and the kinematics they write (one check, export.klipper.config_to_update)."""
    from pkmcal.export import controller_format

    fmt = controller_format(name, "--to")
    for text in ("[printer]\nkinematics: cartesian\n", "[stepper_a]\nstep_pin: PA0\n"):
        with pytest.raises(InputError, match=rf"^p\.cfg: exists and is not a Klipper .*"
                           rf"\(\[printer\] kinematics: {kinematics}\); choose another"):
            fmt.update(text, None, None, "p.cfg")
    from pkmcal.export.klipper import config_to_update

    cfg = config_to_update(f"[printer]\nkinematics: {kinematics}\n", "p.cfg", kinematics, "x")
    assert cfg.entry("printer", "kinematics").value.strip() == kinematics
    if other is not None:
        config_to_update(f"[printer]\nkinematics: {other}\n", "p.cfg", kinematics, "x",
                         fold_case=True)
