"""An independent catalogue of ``pkmcal import`` (issue 28): every problem of a value read
from a controller's file is named in the user's file's terms (the file, the format's letter or
key and the user's line, never a key and line of the machine file written internally), values
that cannot be meant are refused as a machine file's are, ``--like`` carries every field its
help promises, and real-world quirks (comments, CRLF line endings, tabs, the SAVE_CONFIG block,
lowercase letters, letters in another order, host logs) are read as the firmware reads them.

Each case writes one controller file whose lines are known and runs the command in process
(:func:`clitools.run`).
"""

from __future__ import annotations

import re

import pytest

from clitools import assert_input_error, run
from pkmcal.io import load_machine

# -- the files, one value per line where a case changes it -------------------------------------

KLIPPER = """\
# printer.cfg of a Kossel
[printer]
kinematics: delta
delta_radius: 132.5
max_velocity: 300

[stepper_a]
arm_length: 250
position_endstop: 285

[stepper_b]
angle: 330

[stepper_c]
"""
# line numbers of KLIPPER
K_RADIUS, K_ARM, K_ENDSTOP, K_ANGLE_B, K_B_FREE = 4, 8, 9, 12, 13

MARLIN = ("Send: M503\n"
          "Recv: echo:; Delta settings: L<diagonal rod> R<radius> H<height> S<segments/s> "
          "XYZ<tower angle trim> ABC<rod trim>\n") + """\
Recv: echo:  M665 L250.00 R132.50 H285.20 S200.00 X0.00 Y0.00 Z0.00 A0.00 B0.00 C0.00
Recv: echo:; Endstop adjustment:
Recv: echo:  M666 X0.00 Y0.00 Z0.00
Recv: ok
"""
M_M665, M_M666 = 3, 5

RRF = """\
; config-override.g file generated in response to M500
; This is a system-generated file - do not edit
; Delta parameters
M665 L250.000:250.000:250.000 R132.500 H285.200 B120.0 X0.000 Y0.000 Z0.000
M666 X0.000 Y0.000 Z0.000 A0.00 B0.00
M307 H0 A303.0 C233.1 D5.5 S1.00 V24.0 B0
"""
R_M665, R_M666 = 4, 5

LINEAR_HAL = """\
# lineardelta.hal
setp lineardeltakins.R 132.5
setp lineardeltakins.L 250
# [JOINT_0] HOME_OFFSET = 497.1
# [JOINT_1] HOME_OFFSET = 497.1
# [JOINT_2] HOME_OFFSET = 497.1
"""

ROTARY_HAL = """\
# rotarydelta.hal
setp rotarydeltakins.platformradius 200
setp rotarydeltakins.thighlength 300
setp rotarydeltakins.shinlength 800
setp rotarydeltakins.footradius 50
"""

KLIPPER_ROTARY = """\
[printer]
kinematics: rotary_delta
shoulder_radius: 150
shoulder_height: 1100

[stepper_a]
position_endstop: 438.56
upper_arm_length: 300
lower_arm_length: 800
angle: -90

[stepper_b]
angle: 150

[stepper_c]
angle: 30
"""


def _line(text: str, n: int, new: str) -> str:
    """``text`` with its line ``n`` (1-based) replaced."""
    lines = text.split("\n")
    lines[n - 1] = new
    return "\n".join(lines)


def _sub(text: str, n: int, pattern: str, repl: str) -> str:
    """``text`` with ``pattern`` replaced on line ``n`` only."""
    lines = text.split("\n")
    new = re.sub(pattern, repl, lines[n - 1])
    assert new != lines[n - 1], (pattern, lines[n - 1])
    lines[n - 1] = new
    return "\n".join(lines)


def _genhex_text() -> str:
    """A genhexkins ``.hal`` of the cubic example (the export's text of its values)."""
    from pkmcal.export import controller_format

    machine = _cubic()
    fmt = controller_format("linuxcnc-genhexkins")
    return fmt.text(fmt.initial(machine), machine)


def _cubic():
    from pathlib import Path

    return load_machine(Path(__file__).parent.parent / "examples" / "cubic_6upu.yaml")


def _genhex_line(text: str, pin: str) -> int:
    for n, line in enumerate(text.splitlines(), 1):
        if line.split()[:2] == ["setp", pin]:
            return n
    raise AssertionError(pin)


GENHEX = _genhex_text()
G_BASE = _genhex_line(GENHEX, "genhexkins.base.2.x")
G_PLATFORM = _genhex_line(GENHEX, "genhexkins.platform.4.z")


# -- refusals named in the user's terms ---------------------------------------------------------

#: (case id, format, file name, text, words the message must hold: the file's key, the line)
REFUSED = [
    # Klipper printer.cfg
    ("klipper-negative-radius", "klipper", "printer.cfg",
     _line(KLIPPER, K_RADIUS, "delta_radius: -132.5"), ["[printer] delta_radius",
                                                        f"line {K_RADIUS}"]),
    ("klipper-radius-1e308", "klipper", "printer.cfg",
     _line(KLIPPER, K_RADIUS, "delta_radius: 1e308"), ["delta_radius", f"line {K_RADIUS}"]),
    ("klipper-arm-below-radius", "klipper", "printer.cfg",
     _line(KLIPPER, K_ARM, "arm_length: 100"), ["[stepper_a] arm_length", f"line {K_ARM}"]),
    ("klipper-negative-endstop", "klipper", "printer.cfg",
     _line(KLIPPER, K_ENDSTOP, "position_endstop: -285"),
     ["[stepper_a] position_endstop", f"line {K_ENDSTOP}"]),
    ("klipper-arm-of-metres", "klipper", "printer.cfg",
     _line(KLIPPER, K_B_FREE, "arm_length: 2250\n"),
     ["[stepper_b] arm_length", f"line {K_B_FREE}"]),
    ("klipper-endstop-of-metres", "klipper", "printer.cfg",
     _line(KLIPPER, K_B_FREE, "position_endstop: 2285\n"),
     ["[stepper_b] position_endstop", f"line {K_B_FREE}"]),
    ("klipper-angle-1e9", "klipper", "printer.cfg",
     _line(KLIPPER, K_ANGLE_B, "angle: 1e9"), ["[stepper_b] angle", f"line {K_ANGLE_B}"]),
    ("klipper-two-towers-one-angle", "klipper", "printer.cfg",
     _line(KLIPPER, K_ANGLE_B, "angle: 210"), ["[stepper_b] angle", f"line {K_ANGLE_B}"]),
    ("klipper-crlf-tab-comment", "klipper", "printer.cfg",
     _line(KLIPPER, K_ENDSTOP, "position_endstop:\t-285   # measured").replace("\n", "\r\n"),
     ["[stepper_a] position_endstop", f"line {K_ENDSTOP}"]),
    ("klipper-save-config-block", "klipper", "printer.cfg",
     _line(KLIPPER, K_ENDSTOP, "#position_endstop: 285")
     + "\n#*# <---------------------- SAVE_CONFIG ---------------------->\n"
       "#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.\n#*#\n"
       "#*# [stepper_a]\n#*# position_endstop = -2.5\n",
     ["[stepper_a] position_endstop", "line 20", "SAVE_CONFIG"]),
    ("klipper-block-radius", "klipper", "printer.cfg",
     _line(KLIPPER, K_RADIUS, "")
     + "\n#*# <---------------------- SAVE_CONFIG ---------------------->\n"
       "#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.\n#*#\n"
       "#*# [printer]\n#*# delta_radius = -132.5\n",
     ["[printer] delta_radius", "line 20", "SAVE_CONFIG"]),
    # Marlin: an M503 report pasted from a host's terminal
    ("marlin-negative-height", "marlin", "m503.txt",
     _sub(MARLIN, M_M665, r"H285\.20", "H-285.2"), ["M665 H", f"line {M_M665}"]),
    ("marlin-rod-1e308", "marlin", "m503.txt",
     _sub(MARLIN, M_M665, r"L250\.00", "L1e308"), ["M665 L", f"line {M_M665}"]),
    ("marlin-rod-trim-of-metres", "marlin", "m503.txt",
     _sub(MARLIN, M_M665, r"A0\.00", "A2000"), ["M665 A", f"line {M_M665}"]),
    ("marlin-angle-trim-50", "marlin", "m503.txt",
     _sub(MARLIN, M_M665, r"Y0\.00", "Y50"), ["M665 Y", f"line {M_M665}"]),
    ("marlin-adjustment-of-metres", "marlin", "m503.txt",
     _sub(MARLIN, M_M666, r"Z0\.00", "Z-5000"), ["M666 Z", f"line {M_M666}"]),
    ("marlin-negative-radius", "marlin", "m503.txt",
     _sub(MARLIN, M_M665, r"R132\.50", "R-132.5"), ["M665 R", f"line {M_M665}"]),
    ("marlin-radius-beyond-rods", "marlin", "m503.txt",
     _sub(MARLIN, M_M665, r"R132\.50", "R300"), ["M665 L", "M665 R", f"line {M_M665}"]),
    ("marlin-lowercase-other-order", "marlin", "config.gcode",
     "; my printer\nm665 r132.5 h-285.2 l250 ; lowercase\nM666 X0 Y0 Z0\n",
     ["M665 H", "line 2"]),
    ("marlin-crlf-tab", "marlin", "config.gcode",
     "; my printer\r\nM665\tL250\tR132.5\tH285.2\r\nM666 X0 Y-7000 Z0\r\n",
     ["M666 Y", "line 3"]),
    # RepRapFirmware config-override.g
    ("rrf-bed-tilt-50-percent", "reprapfirmware", "config-override.g",
     _sub(RRF, R_M666, r"A0\.00", "A50"), ["M666 A", f"line {R_M666}"]),
    ("rrf-bed-tilt-minus-30", "reprapfirmware", "config-override.g",
     _sub(RRF, R_M666, r"B0\.00", "B-30"), ["M666 B", f"line {R_M666}"]),
    ("rrf-negative-height", "reprapfirmware", "config-override.g",
     _sub(RRF, R_M665, r"H285\.200", "H-285.2"), ["M665 H", f"line {R_M665}"]),
    ("rrf-short-diagonal", "reprapfirmware", "config-override.g",
     _sub(RRF, R_M665, r"L250\.000:250\.000:250\.000", "L250:250:100"),
     ["M665 L", f"line {R_M665}"]),
    ("rrf-adjustment-of-metres", "reprapfirmware", "config-override.g",
     _sub(RRF, R_M666, r"X0\.000", "X-1000"), ["M666 X", f"line {R_M666}"]),
    ("rrf-radius-1e308", "reprapfirmware", "config-override.g",
     _sub(RRF, R_M665, r"R132\.500", "R1e308"), ["M665 R", f"line {R_M665}"]),
    ("rrf-angle-correction-90", "reprapfirmware", "config-override.g",
     _sub(RRF, R_M665, r"Z0\.000", "Z90"), ["M665 Z", f"line {R_M665}"]),
    # LinuxCNC lineardeltakins
    ("lineardelta-low-home-offset", "linuxcnc-lineardelta", "delta.hal",
     _line(LINEAR_HAL, 4, "# [JOINT_0] HOME_OFFSET = 100"),
     ["[JOINT_0] HOME_OFFSET", "line 4"]),
    ("lineardelta-home-offset-of-km", "linuxcnc-lineardelta", "delta.hal",
     _line(LINEAR_HAL, 5, "# [JOINT_1] HOME_OFFSET = -1e6"),
     ["[JOINT_1] HOME_OFFSET", "line 5"]),
    ("lineardelta-negative-R", "linuxcnc-lineardelta", "delta.hal",
     _line(LINEAR_HAL, 2, "setp lineardeltakins.R -132.5"), ["lineardeltakins.R", "line 2"]),
    ("lineardelta-L-1e308", "linuxcnc-lineardelta", "delta.hal",
     _line(LINEAR_HAL, 3, "setp lineardeltakins.L 1e308"), ["lineardeltakins.L", "line 3"]),
    # LinuxCNC rotarydeltakins
    ("rotarydelta-negative-thigh", "linuxcnc-rotarydelta", "rotary.hal",
     _line(ROTARY_HAL, 3, "setp rotarydeltakins.thighlength -300"),
     ["rotarydeltakins.thighlength", "line 3"]),
    ("rotarydelta-shin-1e12", "linuxcnc-rotarydelta", "rotary.hal",
     _line(ROTARY_HAL, 4, "setp rotarydeltakins.shinlength 1e12"),
     ["rotarydeltakins.shinlength", "line 4"]),
    ("rotarydelta-negative-platform", "linuxcnc-rotarydelta", "rotary.hal",
     _line(ROTARY_HAL, 2, "setp rotarydeltakins.platformradius -200"),
     ["rotarydeltakins.platformradius", "line 2"]),
    # Klipper rotary_delta
    ("klipper-rotary-negative-shoulder", "klipper-rotary-delta", "printer.cfg",
     _line(KLIPPER_ROTARY, 3, "shoulder_radius: -150"), ["[printer] shoulder_radius", "line 3"]),
    ("klipper-rotary-arm-1e9", "klipper-rotary-delta", "printer.cfg",
     _line(KLIPPER_ROTARY, 8, "upper_arm_length: 1e9"),
     ["[stepper_a] upper_arm_length", "line 8"]),
    # LinuxCNC genhexkins
    ("genhexkins-joint-1e12", "linuxcnc-genhexkins", "hexapod.hal",
     _line(GENHEX, G_BASE, "setp genhexkins.base.2.x 1e12"),
     ["genhexkins.base.2.x", f"line {G_BASE}"]),
    ("genhexkins-platform-1e12", "linuxcnc-genhexkins", "hexapod.hal",
     _line(GENHEX, G_PLATFORM, "setp genhexkins.platform.4.z -1e12"),
     ["genhexkins.platform.4.z", f"line {G_PLATFORM}"]),
]


@pytest.mark.parametrize("fmt, name, text, words", [c[1:] for c in REFUSED],
                         ids=[c[0] for c in REFUSED])
def test_refused_in_the_users_terms(tmp_path, fmt, name, text, words):
    """Exit 2, one line naming the user's file, the format's key and the user's line; never
    the machine file's own key with a line of the generated YAML, no output written."""
    (tmp_path / name).write_bytes(text.encode())
    proc = run("import", name, "--from", fmt, "-o", "m.yaml", cwd=tmp_path)
    assert_input_error(proc, name, *words)
    err = proc.stderr
    # the first place named is the user's file
    assert err.startswith(f"error: {name}: "), err
    assert "m.yaml" not in err and not (tmp_path / "m.yaml").exists(), err


def test_catalogue_covers_every_format():
    """Every importer has its cases (a new format needs its own)."""
    from pkmcal.export import load_formats

    assert {c[1] for c in REFUSED} == set(load_formats())


# -- quirks read as the firmware reads them ------------------------------------------------------


def _imported(tmp_path, name, text, fmt, *extra):
    (tmp_path / name).write_bytes(text.encode())
    proc = run("import", name, "--from", fmt, "-o", "m.yaml", *extra, cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return load_machine(tmp_path / "m.yaml")


QUIRKS = [
    ("klipper-crlf-tabs-comments", "klipper", "printer.cfg",
     KLIPPER.replace("arm_length: 250", "arm_length:\t250   ; rods").replace("\n", "\r\n"),
     {"arm_length": 0.25, "delta_radius": 0.1325, "position_endstop": 0.285}),
    ("klipper-save-config-wins-below", "klipper", "printer.cfg",
     _line(KLIPPER, K_ENDSTOP, "#position_endstop: 285")
     + "\n#*# <---------------------- SAVE_CONFIG ---------------------->\n"
       "#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.\n#*#\n"
       "#*# [stepper_a]\n#*# position_endstop = 290.5\n",
     {"position_endstop": 0.2905}),
    ("klipper-body-wins-over-block", "klipper", "printer.cfg",
     KLIPPER + "\n#*# <---------------------- SAVE_CONFIG ---------------------->\n"
               "#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.\n#*#\n"
               "#*# [printer]\n#*# delta_radius = -5\n",
     {"delta_radius": 0.1325}),
    ("marlin-lowercase-other-order", "marlin", "config.gcode",
     "m665 r132.5 h285.2 l250 ; lowercase, any order\nm666 x-1 y0 z0\n",
     {"arm_length": 0.25, "delta_radius": 0.1325}),
    ("marlin-host-log-crlf", "marlin", "serial.log",
     MARLIN.replace("\n", "\r\n"), {"arm_length": 0.25, "delta_radius": 0.1325}),
    ("rrf-comments-tabs", "reprapfirmware", "config.g",
     "; Delta\nM665\tL250 R132.5 H285.2 ; rods\n\nM666 X0 Y0 Z0 A0.1 B-0.1 ; tilt\n",
     {"arm_length": 0.25, "delta_radius": 0.1325}),
]


@pytest.mark.parametrize("fmt, name, text, expected", [c[1:] for c in QUIRKS],
                         ids=[c[0] for c in QUIRKS])
def test_quirks_read_as_the_firmware_reads_them(tmp_path, fmt, name, text, expected):
    """Real-world files import, with the values the firmware would use."""
    import numpy as np

    m = _imported(tmp_path, name, text, fmt)
    values = m.firmware_values()
    got = {"arm_length": float(np.mean(values["arm_length"])),
           "delta_radius": float(np.mean(values["radius"]))}
    pe = np.asarray(values["position_endstop"], float)
    got["position_endstop"] = float(pe[0])
    scale = max(abs(v) for v in expected.values())
    for key, want in expected.items():
        assert abs(got[key] - want) <= 1e-12 * scale, (key, got[key], want)


# -- --like carries every field it documents ------------------------------------------------------

LIKE_LINEAR = """\
pkmcal: 1
machine: linear_delta
name: the like file's name
units: {length: m, angle: rad}
delta_radius: 0.1325
arm_length: 0.25
tower_angles: [3.665191429188092, 5.759586531581287, 1.5707963267948966]
position_endstop: [0.285, 0.285, 0.285]
joint_limits: {min: -0.005, max: 0.25}
home: [0.0, 0.0, 0.09]
"""

LIKE_DELTA = """\
pkmcal: 1
machine: delta
name: the like file's name
units: {length: m, angle: rad}
base_radius: 0.2
platform_radius: 0.05
upper_arm: 0.3
forearm: 0.8
leg_angles: [-1.5707963267948966, 2.6179938779914944, 0.5235987755982988]
smr_offset: 0.03
joint_limits: {min: -1.0, max: 1.4}
home: [0.0, 0.0, -0.7]
"""


def _like_stewart() -> str:
    from pathlib import Path

    text = (Path(__file__).parent.parent / "examples" / "cubic_6upu.yaml").read_text()
    text = re.sub(r"(?m)^name: .*$", "name: the like file's name", text)
    return re.sub(r"(?m)^home:", "joint_limits: {min: 100.0, max: 600.0}\n"
                  "tracker: {rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]], translation: [0, 0, "
                  "0], targets: [[10.0, 20.0, 30.0], [-10.0, 5.0, 0.0]]}\nhome:", text)


#: format -> (file name, text, --like text, home expected (m), joint limits expected (SI))
LIKE = {
    "klipper": ("printer.cfg", KLIPPER, LIKE_LINEAR, (0, 0, 0.09), (-0.005, 0.25)),
    "marlin": ("m503.txt", MARLIN, LIKE_LINEAR, (0, 0, 0.09), (-0.005, 0.25)),
    "reprapfirmware": ("config.g", RRF, LIKE_LINEAR, (0, 0, 0.09), (-0.005, 0.25)),
    "linuxcnc-lineardelta": ("delta.hal", LINEAR_HAL, LIKE_LINEAR, (0, 0, 0.09),
                             (-0.005, 0.25)),
    "linuxcnc-rotarydelta": ("rotary.hal", ROTARY_HAL, LIKE_DELTA, (0, 0, -0.7), (-1.0, 1.4)),
    # --like moves the import into the like's frame (its shoulder height): its home as is
    "klipper-rotary-delta": ("printer.cfg", KLIPPER_ROTARY, LIKE_DELTA, None, (-1.0, 1.4)),
    "linuxcnc-genhexkins": ("hexapod.hal", GENHEX, None, None, (0.1, 0.6)),
}


def test_like_cases_cover_every_format():
    from pkmcal.export import load_formats

    assert set(LIKE) == set(load_formats())


@pytest.mark.parametrize("fmt", sorted(LIKE))
def test_like_carries_every_documented_field(tmp_path, fmt):
    """``import --help``: --like gives "name, home, units, joint limits, effector offsets";
    each is in the written machine file, for every format."""
    import numpy as np

    help_text = run("import", "--help", cwd=tmp_path).stdout
    assert all(w in " ".join(help_text.split()) for w in
               ("name, home, units,", "joint limits, effector offsets")), help_text
    name, text, like_text, home, limits = LIKE[fmt]
    (tmp_path / "like.yaml").write_text(like_text if like_text is not None
                                        else _like_stewart())
    like = load_machine(tmp_path / "like.yaml")
    m = _imported(tmp_path, name, text, fmt, "--like", "like.yaml")
    written = (tmp_path / "m.yaml").read_text()
    assert m.name == "the like file's name"
    assert m.file_units == like.file_units, written
    assert m.joint_limits is not None, written
    # to rounding, relative to the machine's size (m)
    tol = dict(rtol=1e-12, atol=1e-12 * like.characteristic_length())
    np.testing.assert_allclose(m.joint_limits[0], limits[0], **tol)
    np.testing.assert_allclose(m.joint_limits[1], limits[1], **tol)
    if home is not None:             # the like's home in the controller's frame
        np.testing.assert_allclose(m.home[0], home, **tol)
    else:
        np.testing.assert_allclose(m.home[0], like.home[0], **tol)
    if like.kind == "delta":                  # the effector offset of a Delta robot
        assert m.smr_offset == pytest.approx(0.03), written
    if like.kind == "stewart":                # the targets' places on the platform
        from pkmcal.io import load_machine_file

        tracker = load_machine_file(tmp_path / "m.yaml")[1]["tracker"]
        np.testing.assert_allclose(tracker.targets, [[0.01, 0.02, 0.03], [-0.01, 0.005, 0]],
                                   **tol)
        like_tracker = load_machine_file(tmp_path / "like.yaml")[1]["tracker"]
        for a, b in zip(tracker.base_from_tracker, like_tracker.base_from_tracker,
                        strict=True):
            np.testing.assert_allclose(a, b, **tol)


def test_like_keeps_compensate_checking_limits(tmp_path):
    """The carried joint limits are the machine's: a target beyond them is refused."""
    (tmp_path / "like.yaml").write_text(LIKE_LINEAR.replace("max: 0.25", "max: 0.01"))
    _imported(tmp_path, "printer.cfg", KLIPPER, "klipper", "--like", "like.yaml")
    (tmp_path / "t.csv").write_text("x_mm,y_mm,z_mm\n0,0,20\n")
    proc = run("compensate", "m.yaml", "t.csv", "-o", "q.csv", cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "limit" in proc.stderr, proc.stderr


# -- every number of every file replaced by one that cannot be meant ------------------------------

#: format -> (file name, text)
FILES = {fmt: (v[0], v[1]) for fmt, v in LIKE.items()}


def _numbers(text: str, every: int = 1):
    found = list(re.finditer(r"(?<=[A-Za-z: =])-?\d+(?:\.\d+)?(?=[\s:]|$)", text))
    return found[::every]


GENERATED = [(fmt, k, value) for fmt, (_, text) in sorted(FILES.items())
             for k, _ in enumerate(_numbers(text, 7 if fmt == "linuxcnc-genhexkins" else 1))
             for value in ("1e300", "-1e300")]


@pytest.mark.parametrize("fmt, k, value", GENERATED,
                         ids=[f"{f}-{k}-{v}" for f, k, v in GENERATED])
def test_every_number_absurd(tmp_path, fmt, k, value):
    """Any number of any file replaced by +/-1e300: imported (a value the firmware ignores)
    or refused in one line naming the file and a line; never an internal error."""
    name, text = FILES[fmt]
    m = _numbers(text, 7 if fmt == "linuxcnc-genhexkins" else 1)[k]
    (tmp_path / name).write_text(text[:m.start()] + value + text[m.end():])
    proc = run("import", name, "--from", fmt, "-o", "m.yaml", cwd=tmp_path)
    if proc.returncode != 0:
        assert_input_error(proc, name, "line ")


def test_included_file_named(tmp_path):
    """A value of an ``[include]`` file is named by that file and its own line."""
    (tmp_path / "kinematics.cfg").write_text("# towers\n[printer]\ndelta_radius: 100\n"
                                             "\n[stepper_b]\narm_length: 9000\n")
    (tmp_path / "printer.cfg").write_text("[include kinematics.cfg]\n" + KLIPPER.replace(
        "delta_radius: 132.5\n", ""))
    proc = run("import", "printer.cfg", "--from", "klipper", "-o", "m.yaml", cwd=tmp_path)
    assert_input_error(proc, "kinematics.cfg", "[stepper_b] arm_length", "line 6")
