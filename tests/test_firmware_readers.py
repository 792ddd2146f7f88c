"""Reading what people paste from Marlin and RepRapFirmware: M503 reports, terminal logs,
config-override.g, and probe reports (pkmcal.export.marlin / reprapfirmware parse,
pkmcal.export.firmware_reports)."""

import numpy as np
import pytest

from pkmcal.errors import InputError
from pkmcal.export.firmware_reports import ProbeReport, read_probe_report
from pkmcal.export.marlin import MARLIN, host_line, marlin_m665_letters
from pkmcal.export.reprapfirmware import REPRAPFIRMWARE

# Marlin 1.1.9's M503 (configuration_store.cpp): B is the calibration radius
MARLIN_119 = """\
echo:; Steps per unit:
echo:  M92 X80.00 Y80.00 Z80.00 E93.00
echo:; Endstop adjustment:
echo:  M666 X-0.31 Y0.00 Z-0.54
echo:; Delta settings: L<diagonal_rod> R<radius> H<height> S<segments_per_s> B<calibration \
radius> XYZ<tower angle corrections>
echo:  M665 L215.00 R105.20 H250.55 S160.00 B70.00 X-0.11 Y0.20 Z0.00
echo:; Z-Probe Offset (mm):
echo:  M851 Z-0.50
"""

# Marlin 2.1's M503 (settings.cpp / M665_report): A B C are the rod trims
MARLIN_21 = """\
echo:; Endstop adjustment:
echo:  M666 X0.00 Y-0.55 Z-0.46
echo:; Delta settings: L<diagonal rod> R<radius> H<height> S<segments per sec> XYZ<tower \
angle trim> ABC<rod trim>
echo:  M665 L196.00 R94.00 H195.00 S160.00 X0.70 Y0.05 Z-0.74 A0.00 B0.20 C-0.10
"""

# OctoPrint's terminal tab (and serial.log with time stamps): Send lines are the host's
OCTOPRINT = """\
Send: N3 M503*33
Recv: echo:; Endstop adjustment:
Recv: echo:  M666 X0.0000 Y-2.7082 Z-3.1732
Recv: echo:; Delta settings: L<diagonal rod> R<radius> H<height> S<segments per sec> XYZ<tower \
angle trim> ABC<rod trim>
Recv: echo:  M665 L280.0000 R141.9439 H354.3339 S200.0000 X0.0353 Y0.2565 Z-0.2919 A0.0000 \
B0.0000 C0.0000
Recv: ok
2024-05-01 12:00:01,123 - Send: M665 L999 R1 H1
2024-05-01 12:00:01,180 - Recv: ok
"""

# RepRapFirmware's config-override.g (M500, LinearDeltaKinematics::WriteCalibrationParameters)
RRF_OVERRIDE = """\
; config-override.g file generated in response to M500 at 2024-03-02 10:12
; This is a system-generated file - do not edit
; Heater model parameters
M307 H0 R0.357 K0.456:0.000 D3.72 E1.35 S1.00 B0
M307 H1 R2.432 K0.560:0.000 D5.50 E1.35 S1.00 B0 V24.0
; Delta parameters
M665 L360.100:360.200:359.900 R195.000 H417.100 B150.0 X0.120 Y-0.050 Z0.000
M666 X0.250 Y-0.100 Z-0.150 A0.10 B-0.05
; Workplace coordinates
G10 L2 P1 X0.00 Y0.00 Z0.00
G31 P500 X0.0 Y0.0 Z-0.120
"""


def test_marlin_119_b_is_the_calibration_radius_not_a_rod_trim():
    p = MARLIN.parse(MARLIN_119, "m503.txt")
    v = p.as_dict()
    assert [v[f"delta_diagonal_rod_trim_{t}"] for t in "abc"] == [0.0, 0.0, 0.0]
    assert v["delta_diagonal_rod"] == pytest.approx(0.215)
    assert v["delta_tower_angle_trim_a"] == pytest.approx(np.radians(-0.11))
    assert v["delta_endstop_adj_c"] == pytest.approx(-0.54e-3)
    assert any("line 6: M665 B" in note and "delta_calibration_radius" in note
               for note in p.notes)
    if isinstance(getattr(p, "extras", None), dict):
        assert p.extras["probe_radius"] == pytest.approx(0.07)
    assert any("M665 S" in note for note in p.notes)
    assert marlin_m665_letters(MARLIN_119)[0] == "1"


def test_marlin_11_line_alone_in_m503_order():
    """B after S and before X, no A or C: 1.1.x's M503 order."""
    p = MARLIN.parse("M665 L215.00 R105.20 H250.55 S160.00 B70.00 X-0.11 Y0.20 Z0.00\n", "a")
    assert p.as_dict()["delta_diagonal_rod_trim_b"] == 0.0
    assert MARLIN.parse("FIRMWARE_NAME:Marlin 1.1.9 (Github) SOURCE_CODE_URL:x\n"
                        "M665 L215 R105 H250 B70\n", "a").as_dict()[
        "delta_diagonal_rod_trim_b"] == 0.0


def test_marlin_21_rod_trims():
    v = MARLIN.parse(MARLIN_21, "m503").as_dict()
    assert v["delta_diagonal_rod_trim_b"] == pytest.approx(0.2e-3)
    assert v["delta_diagonal_rod_trim_c"] == pytest.approx(-0.1e-3)
    assert v["delta_tower_angle_trim_c"] == pytest.approx(np.radians(-0.74))
    # a hand-written 2.x line: A and C say rod trims
    v = MARLIN.parse("M665 L250 R130 H280 A0 B0.5 C0\n", "a").as_dict()
    assert v["delta_diagonal_rod_trim_b"] == pytest.approx(0.5e-3)


def test_octoprint_terminal_log():
    p = MARLIN.parse(OCTOPRINT, "terminal.txt")
    v = p.as_dict()
    assert v["delta_diagonal_rod"] == pytest.approx(0.28)       # not the sent L999
    assert v["delta_radius"] == pytest.approx(0.1419439)
    assert v["delta_endstop_adj_b"] == pytest.approx(-2.7082e-3)
    assert host_line("2024-05-01 12:00:01,123 - Send: M665 L999") == ("M665 L999", True)
    assert host_line("Recv: echo:  M665 L1") == ("M665 L1", False)


def test_rrf_config_override():
    p = REPRAPFIRMWARE.parse(RRF_OVERRIDE, "config-override.g")
    v = p.as_dict()
    assert [v[f"diagonal_{t}"] for t in "xyz"] == pytest.approx([0.3601, 0.3602, 0.3599])
    assert v["radius"] == pytest.approx(0.195) and v["homed_height"] == pytest.approx(0.4171)
    assert v["angle_correction_x"] == pytest.approx(np.radians(0.12))
    assert v["endstop_adjustment_x"] == pytest.approx(0.25e-3)
    assert v["x_tilt"] == pytest.approx(0.001) and v["y_tilt"] == pytest.approx(-0.0005)
    assert any("line 7: M665 B" in note and "printable radius" in note for note in p.notes)
    if isinstance(getattr(p, "extras", None), dict):
        assert p.extras["print_radius"] == pytest.approx(0.15)


@pytest.mark.parametrize("fmt, text, words", [
    (MARLIN, "; mine\nM665 L215 R105 H250 B0.5\n", ["line 2", "M665 B", "which Marlin"]),
    (MARLIN, "M665 L215 R105 H250 S160 X0 B70\n", ["line 1", "M665 B"]),
    (MARLIN, "M665 L215 R105 H250 I0.1 J0 K0\n", ["line 1", "M665 I", "X Y Z"]),
    (MARLIN, "Recv: echo:  M665 L215 R105x H250\n", ["line 1", "M665 R"]),
    (MARLIN, MARLIN_21.replace("M666 X0.00", "M666 X0.20"), ["line 2", "M666 X", "<= 0"]),
    (REPRAPFIRMWARE, RRF_OVERRIDE.replace("M666 X0.250", "M666 U0.1 X0.250"),
     ["line 8", "M666 U", "three"]),
    (REPRAPFIRMWARE, RRF_OVERRIDE.replace("R195.000", "R19o"), ["line 7", "M665 R"]),
])
def test_errors_name_file_line_and_letter(fmt, text, words):
    with pytest.raises(InputError) as err:
        fmt.parse(text, "pasted.txt")
    message = str(err.value)
    assert "\n" not in message and message.startswith("pasted.txt: ")
    for w in words:
        assert w in message, message


# ---- probe reports -------------------------------------------------------------------------

MARLIN_G30_LOG = OCTOPRINT.split("2024")[0] + """\
Send: G30 X0 Y0
Recv: Bed X: 0.00 Y: 0.00 Z: 0.12
Recv: X:0.00 Y:0.00 Z:15.12 E:0.00 Count A:38650 B:38650 C:38650
Recv: ok
Send: G30 X50 Y-28.87
Recv: Bed X: 50.00 Y: -28.87 Z: -0.05
Recv: ok
Send: G30 X-50 Y-28.87
Recv: echo:Bed X: -50.00 Y: -28.87 Z: 0.31
"""

RRF_BED_G = """\
; bed.g
M561 ; clear any bed transform
G30 P0 X0 Y84.9 H0 Z-99999
G30 P1 X73.53 Y42.45 H0 Z-99999
G30 P2 X73.53 Y-42.45 H0 Z-99999
G30 P3 X0 Y0 Z-99999 S-1
G32 bed probe heights: 0.012 -0.034 0.051 0.002, mean 0.008, deviation from mean 0.031
"""


def test_marlin_g30_lines_with_values():
    r = read_probe_report(MARLIN_G30_LOG, "log.txt")
    assert isinstance(r, ProbeReport) and r.firmware == "marlin"
    np.testing.assert_allclose(r.xy, [[0, 0], [50, -28.87], [-50, -28.87]])
    np.testing.assert_allclose(r.z, [0.12, -0.05, 0.31])
    assert list(r.rows) == [8, 12, 15]
    assert r.values is not None and r.values.as_dict()["delta_diagonal_rod"] == pytest.approx(0.28)


def test_marlin_g29_v3_without_values():
    text = ("G29 Auto Bed Leveling\nBed X: -60.000 Y: -60.000 Z: 0.345\n"
            "Bed X: 0.000 Y: -60.000 Z: 0.210\nBed X: 60.000 Y: -60.000 Z: 0.101\n")
    r = read_probe_report(text, "g29.txt")
    assert r.values is None and r.z.shape == (3,) and r.xy[2, 0] == 60.0


def test_rrf_bed_probe_heights_with_their_g30_commands():
    r = read_probe_report(RRF_OVERRIDE + RRF_BED_G, "bed.txt")
    assert r.firmware == "reprapfirmware"
    np.testing.assert_allclose(r.xy, [[0, 84.9], [73.53, 42.45], [73.53, -42.45], [0, 0]])
    np.testing.assert_allclose(r.z, [0.012, -0.034, 0.051, 0.002])
    assert r.values.as_dict()["radius"] == pytest.approx(0.195)
    # the reply first, bed.g pasted below it; OctoPrint Send lines give the commands too
    lines = RRF_BED_G.splitlines()
    r2 = read_probe_report("\n".join([lines[-1]] + lines[:-1]), "b")
    np.testing.assert_allclose(r2.xy, r.xy)
    sent = "\n".join("Send: " + x if x.startswith("G30") else "Recv: " + x for x in lines)
    np.testing.assert_allclose(read_probe_report(sent, "c").z, r.z)


@pytest.mark.parametrize("text, words", [
    ("Recv: G33 Auto Calibrate\nRecv: Checking... AC\n.Height:195.30  Ex:+0.00  Ey:+0.00  "
     "Ez:+0.00  Radius:94.00\n", ["line 1", "G33"]),
    ("Iteration : 01                                std dev:0.237\n", ["line 1", "G33"]),
    (".    c:+0.12  x:-0.05  y:+0.02  z:+0.11\n", ["line 1", "G33", "X/Y"]),
    ("G30 S-1\nStopped at height 0.231 mm\n", ["line 2", "Stopped at height", "G30 P"]),
    ("Bed probe heights: 0.010 0.020 0.030 0.040 0.050\n", ["line 1", "M122"]),
    (RRF_BED_G.replace("G30 P2 X73.53 Y-42.45 H0 Z-99999\n", ""),
     ["line 6", "point 2", "G30 P2"]),
    (RRF_BED_G.replace("0.051", "probing failed"), ["line 7", "point 2", "probing failed"]),
    (MARLIN_G30_LOG + RRF_BED_G, ["line 22", "both"]),
    ("Bed X: 0.00 Y: 0.00 Z: 0.1\nM665 L250 R130 H280\nBed X: 10.00 Y: 0.00 Z: 0.2\n"
     "M665 L250 R131 H280\nBed X: 20.00 Y: 0.00 Z: 0.3\n", ["line 4", "change"]),
    ("ok\nT:210.0 /210.0 B:60.0 /60.0\n", ["no probe report"]),
])
def test_probe_report_refusals_name_the_line(text, words):
    with pytest.raises(InputError) as err:
        read_probe_report(text, "pasted.txt")
    message = str(err.value)
    assert "\n" not in message and message.startswith("pasted.txt: ")
    for w in words:
        assert w in message, message
