"""A Klipper printer owner's path (issue 24): printer.cfg -> pkmcal -> printer.cfg.

The saved calibration data of published printers (``../shared/data/printers/klipper_saved``
beside the repository, sources in each file's first line; the tests that read them skip
without it) are calibrated through pkmcal's documented path (import, calibrate with
Klipper's parameter set, export onto the config) and the written config is evaluated with
``klipper_reference``, an independent port of Klipper's ``delta.py`` / ``delta_calibrate.py``
that does not import pkmcal: the exported values must reproduce the saved heights (and
DELTA_ANALYZE distances) within 1.02x of Klipper's own DELTA_CALIBRATE on the same points and
parameter set. Measured on the 27 sets: the ratio is 1.000 for heights and distances alike
(pkmcal finds the least-squares optimum of Klipper's own objective; Klipper's coordinate
descent stops at it to its threshold).
"""

from __future__ import annotations

import contextlib
import io
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

import klipper_reference as K
from pkmcal.calibration.run import calibrate
from pkmcal.errors import InputError
from pkmcal.export import controller_format, export
from pkmcal.instruments.probe import bed_plane
from pkmcal.io.klipper_config import KlipperConfig, save_config_text
from pkmcal.io.klipper_data import delta_calibrate_data, klipper_weights

#: the published printers' saved data stay outside the project (``../shared`` beside the
#: repository: ``shared/data/printers/klipper_saved``, see its README and PROVENANCE files)
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "printers" / "klipper_saved"
needs_shared = pytest.mark.skipif(not DATA.is_dir(), reason=f"{DATA} not found: the real "
                                  "printers' files stay outside the project (../shared)")
SETS = sorted(DATA.glob("*.cfg"))
KLIPPER = controller_format("klipper")


def pkmcal(*args, cwd) -> tuple[int, str, str]:
    """``pkmcal *args`` in process (exit code, stdout, stderr)."""
    from pkmcal.cli import main

    out, err = io.StringIO(), io.StringIO()
    here = Path.cwd()
    code = 0
    try:
        import os

        os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                main([str(a) for a in args])
            except SystemExit as exc:
                code = int(exc.code or 0)
    finally:
        os.chdir(here)
    return code, out.getvalue(), err.getvalue()


def the_set(path: Path) -> str:
    """Klipper's parameter set for the data: extended with distances, basic without."""
    return "klipper" if "distance0" in path.read_text() else "klipper-basic"


def library_path(path: Path, tmp: Path) -> Path:
    """import -> calibrate -> export onto a copy of the config, through the library."""
    cfg = tmp / path.name
    shutil.copy(path, cfg)
    text = cfg.read_text(encoding="utf-8")
    machine = KLIPPER.to_machine(KLIPPER.parse(text, str(cfg)))
    # Klipper's own data set: the DELTA_CALIBRATE points alone (a saved bed mesh is more data,
    # which Klipper's calibration does not see)
    c = calibrate(machine, points_of(cfg, machine), parameters=the_set(path))
    cal = c.calibrated
    ws = cal.print_workspace(rng=0, bed=bed_plane(c.setups))
    r = export(KLIPPER, cal, ws.P, ws.R, surface=ws.surface, setups=c.setups)
    cfg.write_text(KLIPPER.update(text, r.params, cal, str(cfg)), encoding="utf-8")
    return cfg


def points_of(path: Path, machine):
    """Klipper's own data set of a config: its DELTA_CALIBRATE points alone (a saved bed mesh
    is more data, which Klipper's calibration does not see), as calibrate takes them."""
    points = delta_calibrate_data(KlipperConfig.read(path), 3, machine.characteristic_length())
    return points if len(points) > 1 else points[0]


def saved_rms(calibration, path: Path) -> float:
    """RMS (mm) of the saved DELTA_CALIBRATE heights and bed meshes (those pkmcal's reader
    takes, carriage travels recovered with the config's values) under Klipper values, through
    the reference's kinematics; one free offset per data set."""
    from pkmcal.io.klipper_data import bed_mesh_data

    cfg = KlipperConfig.read(path)
    ds = K.load_data_set(str(path))
    parts = [np.array(K.height_residuals(calibration, ds.data))]
    for d in bed_mesh_data(cfg)[0]:
        stable = d.q * 1e3 / np.asarray(ds.data.stepdists)
        z = np.array([calibration.get_position_from_stable(list(s))[2] for s in stable])
        parts.append(z - d.values[:, 0] * 1e3)
    r = np.concatenate([p - p.mean() for p in parts])
    return float(np.sqrt(np.mean(r * r)))


# -- the published printers ---------------------------------------------------------------------
@pytest.mark.parametrize("path", SETS, ids=[p.stem for p in SETS])
def test_exported_values_reproduce_klipper_on_its_own_points(path, tmp_path):
    ds = K.load_data_set(str(path))
    own = K.delta_calibrate(ds.calibration, ds.data).calibration
    written = K.load_data_set(str(library_path(path, tmp_path))).calibration
    h_k, h_p = (K.rms(K.height_residuals(c, ds.data)) for c in (own, written))
    assert h_p <= 1.02 * h_k, (h_p, h_k)
    if ds.data.distances:
        d_k, d_p = (K.rms(K.distance_residuals(c, ds.data)) for c in (own, written))
        assert d_p <= 1.02 * d_k, (d_p, d_k)
    # the written block carries the saved data on, and Klipper's precedence gives the new
    # values (the body's duplicates commented out)
    assert len(K.load_data_set(str(tmp_path / path.name)).data.probe_heights) == len(
        ds.data.probe_heights)


@needs_shared
def test_held_out_runs_at_least_as_well_as_klipper(tmp_path):
    """Several saved runs of one printer (FLSUN V400, 9 saved configs): the values pkmcal fits
    on run j predict the heights of every other run k at least as well as Klipper's own fit
    on run j (each run's constant z offset removed: its probe z_offset was re-set between
    runs)."""
    runs = sorted(DATA.glob("v400-aieie78-run*.cfg"))[:3]     # the heights-only runs
    assert len(runs) == 3
    sets = [K.load_data_set(str(p)) for p in runs]
    for j, path in enumerate(runs):
        run_dir = tmp_path / f"r{j}"
        run_dir.mkdir()
        ours = K.load_data_set(str(library_path(path, run_dir))).calibration
        theirs = K.delta_calibrate(sets[j].calibration, sets[j].data).calibration
        for k, other in enumerate(sets):
            if k == j:
                continue
            r_p = K.height_residuals(ours, other.data)
            r_k = K.height_residuals(theirs, other.data)
            assert K.rms(r_p - r_p.mean()) <= K.rms(r_k - r_k.mean()) * 1.02 + 1e-6


@needs_shared
def test_the_documented_commands(tmp_path):
    """The README's path, in process: import, calibrate (Klipper's set, DELTA_ANALYZE
    distances), export onto the config: SAVE_CONFIG's way, a dated backup, the body's
    duplicates commented out; the calibrated file shows the calibrated values."""
    src = DATA / "v400-fzechert-run1.cfg"
    cfg = tmp_path / "printer.cfg"
    shutil.copy(src, cfg)
    before = cfg.read_text()
    code, out, err = pkmcal("import", "printer.cfg", "--from", "klipper", "-o", "printer.yaml",
                            cwd=tmp_path)
    assert code == 0, err
    code, out, err = pkmcal("calibrate", "printer.yaml", "printer.cfg", "--parameters",
                            "klipper", "-o", "cal.yaml", cwd=tmp_path)
    assert code == 0, err
    assert "swapped" not in err and "Traceback" not in err
    assert "square to the towers" in out            # 19 equations: the bed as Klipper has it
    code, out, err = pkmcal("export", "cal.yaml", "--to", "klipper", "-o", "printer.cfg",
                            cwd=tmp_path)
    assert code == 0, err
    backups = sorted(tmp_path.glob("printer-*.cfg"))
    assert len(backups) == 1 and backups[0].read_text() == before
    after = cfg.read_text()
    assert "#*# [printer]" in after and "#*# delta_radius = " in after
    new = K.load_data_set(str(cfg))
    old = K.load_data_set(str(src))
    own = K.delta_calibrate(old.calibration, old.data).calibration
    assert K.rms(K.height_residuals(new.calibration, old.data)) <= 1.02 * K.rms(
        K.height_residuals(own, old.data))
    cal = (tmp_path / "cal.yaml").read_text()
    assert f"delta_radius: {new.calibration.radius:.4f}"[:20] in cal


# -- reading printer.cfg as Klipper does ----------------------------------------------------------
BLOCK = ("\n#*# <---------------------- SAVE_CONFIG ---------------------->\n"
         "#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.\n#*#\n")


def test_includes_and_precedence(tmp_path):
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "b.cfg").write_text("[stepper_a]\nrotation_distance: 40\n")
    (tmp_path / "parts" / "a.cfg").write_text("[stepper_a]\nrotation_distance: 20\n"
                                              "microsteps: 16\n")
    (tmp_path / "printer.cfg").write_text(
        "[include parts/*.cfg]\n[printer]\nkinematics: delta\nDelta_Radius: 140 # comment\n"
        "[gcode_macro X]\ngcode:\n  G28\n  delta_radius: 1\n" + BLOCK
        + "#*# [printer]\n#*# delta_radius = 151.2\n#*# print_radius = 100\n")
    cfg = KlipperConfig.read(tmp_path / "printer.cfg")
    assert cfg.number("printer", "delta_radius") == 140          # the body wins
    assert cfg.number("printer", "print_radius") == 100          # the block fills in
    assert cfg.step_distance("stepper_a") == 40 / (200 * 16)     # sorted: b.cfg last
    assert cfg.defines_in_include("stepper_a", "rotation_distance")
    with pytest.raises(InputError, match=r"p2.cfg: line 1: \[include nothing.cfg\]"):
        (tmp_path / "p2.cfg").write_text("[include nothing.cfg]\n")
        KlipperConfig.read(tmp_path / "p2.cfg")
    (tmp_path / "loop.cfg").write_text("[include loop.cfg]\n")
    with pytest.raises(InputError, match="recursive"):
        KlipperConfig.read(tmp_path / "loop.cfg")


@pytest.mark.parametrize("options, expected", [
    ("rotation_distance: 40\nmicrosteps: 16", 40 / 3200),
    ("rotation_distance: 40\nmicrosteps: 32\nfull_steps_per_rotation: 400", 40 / 12800),
    ("rotation_distance: 40\nmicrosteps: 16\ngear_ratio: 80:20, 3:1", 40 / (3200 * 12)),
    ("step_distance: 0.0125", 0.0125),
])
def test_step_distance_as_klipper_parses_it(options, expected):
    cfg = KlipperConfig.read("p.cfg", f"[stepper_a]\n{options}\n")
    assert cfg.step_distance("stepper_a") == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("options, words", [
    ("rotation_distance: -40\nmicrosteps: 16", ["line 2", "rotation_distance", "above 0"]),
    ("rotation_distance: 40\nmicrosteps: x", ["line 3", "microsteps", "a whole number"]),
    ("rotation_distance: 40\nmicrosteps: 16.0", ["line 3", "microsteps", "a whole number"]),
    ("rotation_distance: 1e-300\nmicrosteps: 16", ["line 2", "not a stepper"]),
    ("rotation_distance: 40\nmicrosteps: 16\ngear_ratio: 1e308:1e-308", ["not a stepper"]),
    ("rotation_distance: 40\nmicrosteps: 16\nfull_steps_per_rotation: 202",
     ["line 4", "multiple of 4"]),
    ("rotation_distance: 40\nmicrosteps: 16\ngear_ratio: 3-1", ["line 4", "gear_ratio"]),
    ("microsteps: 16", ["rotation_distance: missing"]),
])
def test_bad_step_settings_are_named(options, words):
    cfg = KlipperConfig.read("p.cfg", f"[stepper_a]\n{options}\n")
    with pytest.raises(InputError) as err:
        cfg.step_distance("stepper_a")
    for w in words:
        assert w in str(err.value), str(err.value)


def test_saved_data_in_si():
    text = ("[stepper_a]\nrotation_distance: 40\nmicrosteps: 16\n[stepper_b]\n"
            "rotation_distance: 40\nmicrosteps: 16\n[stepper_c]\nrotation_distance: 80\n"
            "microsteps: 16\n[delta_calibrate]\nradius: 100\n" + BLOCK
            + "#*# [delta_calibrate]\n#*# height0 = 1.5\n#*# height0_pos = 100,200,300\n"
            "#*# height1 = 1.25\n#*# height1_pos = 10,20,30\n#*# height3 = 9\n"
            "#*# height3_pos = 1,1,1\n#*# manual_height0 = 0.1\n"
            "#*# manual_height0_pos = 5,6,7\n#*# distance0 = 74.0\n"
            "#*# distance0_pos1 = 1,2,3\n#*# distance0_pos2 = 4,5,6\n")
    heights, pairs = delta_calibrate_data(KlipperConfig.read("printer.cfg", text))
    step = np.array([40, 40, 80]) / 3200 * 1e-3
    # height3 is past the first gap: Klipper stops at height2
    np.testing.assert_allclose(heights.q, np.array([[100, 200, 300], [10, 20, 30], [5, 6, 7]])
                               * step, rtol=1e-12)
    np.testing.assert_allclose(heights.values[:, 0], [1.5e-3, 1.25e-3, 0.1e-3], rtol=1e-12)
    np.testing.assert_allclose(pairs.q, np.array([[1, 2, 3, 4, 5, 6]]) * np.tile(step, 2),
                               rtol=1e-12)
    assert pairs.values[0, 0] == pytest.approx(0.074, rel=1e-12)
    assert heights.rows.tolist()[0] > 12          # the config's line numbers
    # Klipper's relative weight: z_weight = 1 / (0.5 * 2) = 1, equal levels
    (h_noise, _), (d_noise, _) = klipper_weights(2, 1)
    assert d_noise.sigma == pytest.approx(h_noise.sigma, rel=1e-12)


def test_save_config_as_klipper_writes_it():
    text = ("[printer]\nkinematics: delta\ndelta_radius: 140 ; mm\n[stepper_a]\n"
            "position_endstop: 300\n  continued\n" + BLOCK
            + "#*# [delta_calibrate]\n#*# height0 = 1\n#*# height0_pos = 1,2,3\n")
    new = save_config_text(text, {("printer", "delta_radius"): "141.000000",
                                  ("stepper_a", "position_endstop"): "301.000000"},
                           "printer.cfg")
    assert "#delta_radius: 140 ; mm" in new and "#position_endstop: 300\n#  continued" in new
    cfg = KlipperConfig.read("printer.cfg", new)
    assert cfg.number("printer", "delta_radius") == 141
    assert cfg.number("stepper_a", "position_endstop") == 301
    assert cfg.number("delta_calibrate", "height0") == 1        # the block's data kept
    assert new.count("SAVE_CONFIG") == 1


# -- the printer's frame is its bed ----------------------------------------------------------------
@needs_shared
def test_klipper_points_with_klippers_set_are_fitted_as_klipper_does(tmp_path):
    """7 heights, 6 unknowns: the bed square to the towers (as Klipper), height 0."""
    path = DATA / "kossel-hpb0412.cfg"
    machine = KLIPPER.to_machine(KLIPPER.parse(path.read_text(), str(path)))
    c = calibrate(machine, points_of(path, machine), parameters="klipper-basic")
    assert c.report["bed"]["tilt_estimated"] is False
    assert "square to the towers" in c.report["bed_frame"]
    assert c.setups["probe"].plane == (0.0, 0.0, 0.0)
    assert c.report["identifiability"]["identifiable"] == 6
    forced = calibrate(machine, points_of(path, machine), parameters="klipper-basic",
                       bed_tilt="square")
    scale = 1e-9 * np.abs(c.calibrated.u).max()          # one fit, the same options
    np.testing.assert_allclose(forced.calibrated.u, c.calibrated.u, rtol=0, atol=scale)


@needs_shared
def test_a_flipped_probe_height_sign_is_named(tmp_path):
    text = (DATA / "s1pro-flight505.cfg").read_text()
    flipped = text.replace(" = -0.25", " = 0.25")
    assert flipped != text
    cfg = tmp_path / "printer.cfg"
    cfg.write_text(flipped)
    machine = KLIPPER.to_machine(KLIPPER.parse(text, "printer.cfg"))
    with pytest.raises(InputError, match="flip the sign"):
        calibrate(machine, cfg, parameters="klipper-basic")


@needs_shared
def test_klipper_set_with_heights_alone_is_klippers_basic_set():
    path = DATA / "sr-danorder.cfg"
    machine = KLIPPER.to_machine(KLIPPER.parse(path.read_text(), str(path)))
    c = calibrate(machine, points_of(path, machine), parameters="klipper")
    assert c.report["parameter_set"]["name"] == "klipper-basic"
    assert "heights alone" in c.report["parameter_set"]["note"]
    assert math.isfinite(c.report["residuals"]["rms_um"])


@needs_shared
def test_the_readme_path_runs_as_written(tmp_path):
    """docs/printer.md "From printer.cfg to printer.cfg" (the README's until issue 26): its
    commands, as written, on a published config with DELTA_ANALYZE distances (the page itself
    runs them on the config it shows: tests/test_docs.py)."""
    import re
    import shlex

    page = (Path(__file__).resolve().parents[1] / "docs" / "printer.md").read_text()
    section = page[page.index("## From printer.cfg to printer.cfg"):]
    block = re.search(r"```sh\n(pkmcal import .*?)```", section, re.S).group(1)
    shutil.copy(DATA / "v400-phnxdrgn536.cfg", tmp_path / "printer.cfg")
    commands = [line.split("#")[0].strip() for line in block.splitlines()]
    commands = [c for c in commands if c]
    assert len(commands) == 3
    for command in commands:
        code, out, err = pkmcal(*shlex.split(command)[1:], cwd=tmp_path)
        assert code == 0, (command, err)
    assert list(tmp_path.glob("printer-*.cfg"))
    ds = K.load_data_set(str(DATA / "v400-phnxdrgn536.cfg"))
    own = K.delta_calibrate(ds.calibration, ds.data).calibration
    new = K.load_data_set(str(tmp_path / "printer.cfg")).calibration
    assert math.isfinite(saved_rms(new, DATA / "v400-phnxdrgn536.cfg"))
    # everything the printer saved (its points and its bed mesh) fitted in Klipper's own set:
    # pkmcal's values hold it at least as well as Klipper's DELTA_CALIBRATE on the points
    # alone (the default model's figures: benchmarks/next_session.py)
    src = DATA / "v400-phnxdrgn536.cfg"
    shutil.copy(src, tmp_path / "klipper.cfg")
    for command in (["calibrate", "printer.yaml", "klipper.cfg", "--parameters", "klipper",
                     "-o", "k.yaml"], ["export", "k.yaml", "--to", "klipper", "-o",
                                       "klipper.cfg"]):
        code, out, err = pkmcal(*command, cwd=tmp_path)
        assert code == 0, (command, err)
    ours = K.load_data_set(str(tmp_path / "klipper.cfg")).calibration
    assert saved_rms(ours, src) <= saved_rms(own, src)


def test_compensate_puts_a_printer_on_its_bed(tmp_path):
    """compensate works in the printer's frame: a target at z = 0 is on the probed bed, also
    where the calibration estimated the bed's tilt against the towers."""
    from pkmcal.compensation import compensate
    from pkmcal.instruments.probe import BedSetup
    from pkmcal.instruments.setups import Setups
    from pkmcal.machines import linear_delta

    m = linear_delta(0.14, 0.25, np.deg2rad([210.0, 330.0, 90.0]), (0.3, 0.3, 0.3))
    bed = Setups({"probe": BedSetup(0.0, 2e-3, -1e-3)})      # the calibrated file's bed
    targets = np.array([[0.0, 0.0, 0.0], [0.05, -0.03, 0.0], [-0.04, 0.06, 0.01]])
    comp = compensate(m, targets, setups=bed)
    nozzle = m.fk(comp.q).P
    above = nozzle[:, 2] - (2e-3 * nozzle[:, 0] - 1e-3 * nozzle[:, 1])
    np.testing.assert_allclose(above, targets[:, 2], rtol=0,
                               atol=1e-9 * m.characteristic_length())


def test_reprapfirmware_config_override_is_updated_as_m500_writes_it(tmp_path):
    """export onto an existing config-override.g: its M665/M666 lines replaced where they
    stood (letters pkmcal does not write, M665 B, kept), every other line kept, the previous
    file kept dated; a file without G-code is refused."""
    from pkmcal.machines import linear_delta

    rrf = controller_format("reprapfirmware")
    m = linear_delta(0.132, 0.25, np.deg2rad([210.3, 329.8, 90.0]), (0.285, 0.2853, 0.2848))
    params = rrf.initial(m)
    old = ("; config-override.g\nM307 H1 A340 C140 D5.5 B0\n"
           "M665 L250:250:250 R132 H285 B90 X0 Y0 Z0\nM666 X0 Y0 Z0 A0 B0\nG31 P500 Z-0.1\n")
    new = rrf.update(old, params, m, "config-override.g")
    lines = new.splitlines()
    assert lines[1].startswith("M307") and lines[-1].startswith("G31")
    assert sum(line.startswith("M665") for line in lines) == 1
    assert next(line for line in lines if line.startswith("M665")).endswith(" B90")
    parsed = rrf.parse(new, "config-override.g")
    np.testing.assert_allclose(parsed.values[:13], params.values[:13], rtol=0, atol=1e-8)
    with pytest.raises(InputError, match="no G-code"):
        rrf.update("hello\n", params, m, "notes.txt")
    # through the command: the backup beside it
    from pkmcal.io.machine_file import save_machine

    save_machine(m, tmp_path / "m.yaml")
    (tmp_path / "config-override.g").write_text(old)
    code, _, err = pkmcal("export", "m.yaml", "--to", "reprapfirmware", "-o",
                          "config-override.g", cwd=tmp_path)
    assert code == 0, err
    assert [p.read_text() for p in tmp_path.glob("config-override-*.g")] == [old]


@needs_shared
def test_import_keeps_the_print_and_probing_radius(tmp_path):
    """Klipper's [printer] print_radius and [delta_calibrate] radius, Marlin 1.1's M665 B (the
    G33 calibration radius) and RepRapFirmware's M665 B (the printable radius) end in the
    machine file, where the probe plan and the export's print disk take them from."""
    shutil.copy(DATA / "kossel-hpb0412.cfg", tmp_path / "printer.cfg")
    (tmp_path / "m503.txt").write_text(
        "Recv: echo:  M665 L215.00 R105.20 H250.55 S160.00 B70.00 X-0.11 Y0.20 Z0.00\n"
        "Recv: echo:  M666 X-0.31 Y0.00 Z-0.54\n")
    (tmp_path / "config-override.g").write_text("M665 L215 R105.2 H250 B85\nM666 X0 Y0 Z0\n")
    for src, fmt in (("printer.cfg", "klipper"), ("m503.txt", "marlin"),
                     ("config-override.g", "reprapfirmware")):
        code, out, err = pkmcal("import", src, "--from", fmt, "-o", f"{fmt}.yaml",
                                cwd=tmp_path)
        assert code == 0, err
    cfg = KlipperConfig.read(tmp_path / "printer.cfg")
    klipper = (tmp_path / "klipper.yaml").read_text()
    assert f"probe_radius: {cfg.number('delta_calibrate', 'radius'):g}" in klipper.replace(
        ".0\n", "\n")
    assert "probe_radius: 70.0" in (tmp_path / "marlin.yaml").read_text()
    assert "print_radius: 85.0" in (tmp_path / "reprapfirmware.yaml").read_text()


# -- what an independent catalogue of malformed configs found (issue 24's review) -----------------
def _export_onto(tmp_path, text: str):
    """Calibrate a published config and export onto ``text`` written as printer.cfg."""
    src = DATA / "kossel-hpb0412.cfg"
    shutil.copy(src, tmp_path / "data.cfg")
    assert pkmcal("import", "data.cfg", "--from", "klipper", "-o", "m.yaml",
                  cwd=tmp_path)[0] == 0
    code, _, err = pkmcal("calibrate", "m.yaml", "data.cfg", "--parameters", "klipper-basic",
                          "-o", "cal.yaml", cwd=tmp_path)
    assert code == 0, err
    (tmp_path / "printer.cfg").write_bytes(text.encode("utf-8"))
    return pkmcal("export", "cal.yaml", "--to", "klipper", "-o", "printer.cfg", cwd=tmp_path)


@needs_shared
def test_export_keeps_what_klipper_runs(tmp_path):
    """Multi-line block values (a bed mesh) survive; an option the body defines stays the
    body's (Klipper never read the block's stale value); the backup is the previous file
    byte for byte (a BOM kept)."""
    text = ("\ufeff[printer]\nkinematics: delta\ndelta_radius: 140\n[stepper_a]\n"
            "arm_length: 270\nposition_endstop: 300\n[probe]\nz_offset: 1.5\n" + BLOCK
            + "#*# [probe]\n#*# z_offset = 16.046\n#*#\n#*# [bed_mesh default]\n"
              "#*# version = 1\n#*# points =\n#*# \t-0.1, 0.2\n#*# \t0.3, -0.4\n")
    code, _, err = _export_onto(tmp_path, text)
    assert code == 0, err
    new = KlipperConfig.read(tmp_path / "printer.cfg")
    assert new.number("probe", "z_offset") == 1.5
    mesh = new.entry("bed_mesh default", "points")
    assert mesh.more == ["\t-0.1, 0.2", "\t0.3, -0.4"]
    backup = next(tmp_path.glob("printer-*.cfg"))
    assert backup.read_bytes() == text.encode("utf-8")


@pytest.mark.parametrize("text, words", [
    ("[printer]\nkinematics: delta\ndelta_radius: 140\n#*# [stepper_a]\n#*# angle = 1\n"
     + BLOCK + "#*# [printer]\n#*# delta_radius = 150\n", ["ignores its SAVE_CONFIG block"]),
    ("[printer]\nkinematics: delta\ndelta_radius: 140\n" + BLOCK
     + "#*# [printer]\n#*# delta_radius = 150\nafter = 1\n", ["does not start with '#*# '"]),
])
def test_a_block_klipper_ignores_is_ignored_and_not_saved_into(tmp_path, text, words):
    cfg = KlipperConfig.read("printer.cfg", text)
    assert cfg.number("printer", "delta_radius") == 140 and not cfg.autosave
    for w in words:
        assert w in cfg.ignored_block
    with pytest.raises(InputError, match="corrupted"):
        save_config_text(text, {("printer", "delta_radius"): "141"}, "printer.cfg")


@pytest.mark.parametrize("text, words", [
    ("[printer]\nprint_radius 110\n", ["line 2", "neither a [section] nor an option"]),
    ("delta_radius: 140\n[printer]\n", ["line 1", "before any [section]"]),
    ("[printer\ndelta_radius: 140\n", ["line 1"]),
])
def test_lines_klipper_refuses_are_refused(text, words):
    with pytest.raises(InputError) as err:
        KlipperConfig.read("printer.cfg", text)
    for w in words:
        assert w in str(err.value), str(err.value)


@needs_shared
def test_an_included_file_is_an_input(tmp_path):
    (tmp_path / "extra.cfg").write_text("[printer]\nprint_radius: 100\n")
    text = (DATA / "kossel-hpb0412.cfg").read_text()
    (tmp_path / "printer.cfg").write_text("[include extra.cfg]\n" + text)
    before = (tmp_path / "extra.cfg").read_text()
    code, _, err = pkmcal("import", "printer.cfg", "--from", "klipper", "-o", "extra.cfg",
                          cwd=tmp_path)
    assert code == 2 and "input file" in err
    assert (tmp_path / "extra.cfg").read_text() == before
    (tmp_path / "bin.cfg").write_bytes(b"[printer]\x00\xff\n")
    (tmp_path / "p2.cfg").write_text("[include bin.cfg]\n" + text)
    code, _, err = pkmcal("import", "p2.cfg", "--from", "klipper", "-o", "x.yaml", cwd=tmp_path)
    assert code == 2 and "bin.cfg" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("change, words", [
    (("#*# height2 = ", "#*# height2 = 1e30 ; "), ["height2", "cannot be meant"]),
    (("#*# height0_pos = ", "#*# height0_pos = -5,1,1\n#*# old = "), ["height0_pos", ">= 0"]),
    (("#*# height3_pos = ", "#*# xheight3_pos = "), ["height3", "has no height3_pos"]),
    (("kinematics: delta", "kinematics: cartesian"), ["kinematics", "delta"]),
])
@needs_shared
def test_saved_data_that_cannot_be_meant_are_named(tmp_path, change, words):
    text = (DATA / "kossel-hpb0412.cfg").read_text()
    assert change[0] in text
    (tmp_path / "printer.cfg").write_text(text.replace(change[0], change[1], 1))
    machine = KLIPPER.to_machine(KLIPPER.parse(text, "printer.cfg"))
    with pytest.raises(InputError) as err:
        calibrate(machine, tmp_path / "printer.cfg", parameters="klipper-basic")
    for w in words:
        assert w in str(err.value), str(err.value)


@needs_shared
def test_heights_after_a_gap_are_named(tmp_path):
    text = (DATA / "sr-danorder.cfg").read_text()
    (tmp_path / "printer.cfg").write_text(text.replace("#*# height5 = ", "#*# xheight5 = "))
    machine = KLIPPER.to_machine(KLIPPER.parse(text, "printer.cfg"))
    with pytest.raises(InputError, match="5 rows"):     # 5 heights for 6 unknowns
        calibrate(machine, points_of(tmp_path / "printer.cfg", machine),
                  parameters="klipper-basic")
    (tmp_path / "p.cfg").write_text(text.replace("#*# height5 = ", "#*# xheight5 = "))
    with pytest.raises(InputError) as err:           # the refusal names what was not read
        calibrate(machine, points_of(tmp_path / "p.cfg", machine), parameters="klipper-basic")
    assert "height5 is missing" in str(err.value) and "height6" in str(err.value)


def test_backups_never_overwrite_each_other(tmp_path):
    from pkmcal.io.klipper_config import backup_name

    first = backup_name(tmp_path / "printer.cfg")
    first.write_text("x")
    second = backup_name(tmp_path / "printer.cfg")
    assert second != first and second.name.startswith(first.stem)


@pytest.mark.parametrize("path", [p for p in SETS if "distance0" in p.read_text()][:4],
                         ids=lambda p: p.stem)
def test_basic_set_on_a_config_with_distances_is_klippers_basic_fit(path, tmp_path):
    """--parameters klipper-basic is Klipper's heights-only DELTA_CALIBRATE: the saved
    DELTA_ANALYZE distances are left out (named), and the values reproduce the heights as the
    basic coordinate descent does."""
    cfg = tmp_path / "printer.cfg"
    shutil.copy(path, cfg)
    machine = KLIPPER.to_machine(KLIPPER.parse(cfg.read_text(), str(cfg)))
    c = calibrate(machine, points_of(cfg, machine), parameters="klipper-basic")
    assert any("distances: left out" in w for w in c.warnings)
    ws = c.calibrated.print_workspace(rng=0, bed=bed_plane(c.setups))
    r = export(KLIPPER, c.calibrated, ws.P, ws.R, surface=ws.surface, setups=c.setups)
    cfg.write_text(KLIPPER.update(cfg.read_text(), r.params, c.calibrated, str(cfg)))
    ds = K.load_data_set(str(path))
    basic = K.delta_calibrate(ds.calibration, ds.data, extended=False).calibration
    new = K.load_data_set(str(cfg)).calibration
    assert K.rms(K.height_residuals(new, ds.data)) <= 1.02 * K.rms(
        K.height_residuals(basic, ds.data))


def test_rotary_delta_config_is_updated_as_save_config_does():
    """klipper-rotary-delta reads printer.cfg as Klipper does and saves onto it as
    SAVE_CONFIG does (the sections' values commented out, the block rewritten)."""
    rotary = controller_format("klipper-rotary-delta")
    text = ("[printer]\nkinematics: rotary_delta\nshoulder_radius: 31\nshoulder_height: 400\n"
            "[stepper_a]\nposition_endstop: 250\nupper_arm_length: 170\n"
            "lower_arm_length: 320\n" + BLOCK + "#*# [printer]\n#*# shoulder_radius = 30\n")
    params = rotary.parse(text, "printer.cfg")
    assert params.as_dict()["shoulder_radius"] == pytest.approx(0.031)    # the body wins
    values = params.values.copy()
    values[0] += 1e-3
    new = rotary.update(text, params.with_values(values), rotary.to_machine(params),
                        "printer.cfg")
    again = rotary.parse(new, "printer.cfg")
    # the file keeps the digits SAVE_CONFIG writes: 3 parts in 1e8 of the values' scale
    np.testing.assert_allclose(again.values[:15], values[:15], rtol=0,
                               atol=3e-8 * np.abs(values[:15]).max())
    assert "#shoulder_radius: 31" in new
    with pytest.raises(InputError, match="not a Klipper rotary_delta"):
        rotary.update("[printer]\nkinematics: delta\n", params, rotary.to_machine(params),
                      "printer.cfg")


@needs_shared
def test_without_parameters_the_saved_data_are_fitted_in_klippers_set():
    """A newcomer who gives no --parameters gets Klipper's own set for Klipper's saved
    points (7 heights and 12 DELTA_ANALYZE distances cannot judge a larger model:
    --parameters auto keeps the firmware's), named in the report."""
    path = DATA / "q5-razorcopter.cfg"
    machine = KLIPPER.to_machine(KLIPPER.parse(path.read_text(), str(path)))
    default = calibrate(machine, path)
    own = calibrate(machine, path, parameters="klipper")
    assert default.report["parameter_set"]["name"] == "klipper"
    assert "its own set" in default.report["parameter_set"]["note"]
    assert default.report["model_choice"]["chosen"] == 0
    np.testing.assert_allclose(default.calibrated.u, own.calibrated.u, rtol=0,
                               atol=1e-9 * np.abs(own.calibrated.u).max())


@needs_shared
def test_auto_judges_the_models_where_a_mesh_gives_enough_equations():
    """With a bed mesh beside the points (sr-danorder: 7 points and a 9x9 mesh) every
    candidate is fitted and judged by its leave-one-out error; the chosen one has the
    smallest (a larger one by at least 2 %), and the report names it and why."""
    from pkmcal.calibration.model_choice import MIN_GAIN

    path = DATA / "sr-danorder.cfg"
    machine = KLIPPER.to_machine(KLIPPER.parse(path.read_text(), str(path)))
    c = calibrate(machine, path)
    choice = c.report["model_choice"]
    scores = [s["loo_rms_over_noise"] for s in choice["candidates"]]
    assert all(s is not None for s in scores)
    best = scores[choice["chosen"]]
    assert all(best ** 2 <= s ** 2 for s in scores[:choice["chosen"]])
    assert all(best ** 2 < (s ** 2) / (1 - MIN_GAIN) for s in scores)
    assert "leave-one-out" in choice["words"] and choice["words"] in c.warnings
    assert c.report["parameter_set"]["name"] == choice["candidates"][choice["chosen"]][
        "parameters"]
