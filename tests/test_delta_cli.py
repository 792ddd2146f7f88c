"""The ``pkmcal`` command on a Delta robot with laser-tracker data (SPEC 2.2, 6), run as a
subprocess: simulate -> calibrate -> fk/ik, the calibrated file, and bad input."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, digest, run
from pkmcal.calibration import predict_tracker_points
from pkmcal.instruments.tracker import grid_points, neighbour_pairs
from pkmcal.io import (
    load_machine,
    load_machine_file,
    read_joints,
    read_positions,
    read_tracker,
    write_positions,
)
from pkmcal.machines import default_delta

DELTA = Path(__file__).resolve().parents[1] / "examples" / "delta_default.yaml"





@pytest.fixture(scope="module")
def delta_dir(tmp_path_factory):
    """simulate (default Delta, random errors, Leica noise, seed 1) -> calibrate, once."""
    d = tmp_path_factory.mktemp("delta")
    sim = run("simulate", DELTA, "--scenario", "tracker", "--seed", "1", "--truth", "true.yaml",
              "-o", "data.csv", cwd=d)
    assert sim.returncode == 0, sim.stderr
    cal = run("calibrate", DELTA, "data.csv", "-o", "cal.yaml", cwd=d)
    assert cal.returncode == 0, cal.stderr
    d.joinpath("calibrate.out").write_text(cal.stdout)
    return d


def test_simulate_writes_tracker_data_and_truth(delta_dir):
    header = (delta_dir / "data.csv").read_text().splitlines()[0]
    assert header == "q1_deg,q2_deg,q3_deg,mx_mm,my_mm,mz_mm"
    nominal = default_delta()
    data = read_tracker(delta_dir / "data.csv", nominal)
    assert len(data) == 27 and data.rows[0] == 2
    true, true_setups = load_machine_file(delta_dir / "true.yaml")
    dev = true.u - nominal.u
    kinds = np.array(nominal.parameters.kinds)
    assert 0.3e-3 < np.max(np.abs(dev[kinds == "length"])) <= 1e-3     # about 1 mm
    assert np.max(np.abs(dev[kinds == "angle"])) <= np.deg2rad(0.5)
    # the nominal model commanded the 3x3x3 grid (150/150/40 mm) at home
    np.testing.assert_allclose(nominal.fk(data.q).P,
                               grid_points([0, 0, -0.75], (0.15, 0.15, 0.04)), atol=1e-12)
    # the tracker saw the true machine's reflector (Leica noise: tens of um)
    pred = predict_tracker_points(true, data.q, true_setups["tracker"].base_from_tracker)
    err = np.linalg.norm(pred - data.m, axis=1)
    assert 1e-6 < np.max(err) < 100e-6
    R, t = true_setups["tracker"].base_from_tracker
    assert np.linalg.norm(t[:2]) == pytest.approx(2.5)                  # 2.5 m away


def test_calibrate_summary_and_report(delta_dir):
    out = (delta_dir / "calibrate.out").read_text()
    for words in ("21 of 33", "leg1.da + leg1.db", "translation of the platform frame",
                  "RMS residual", "distance ratio", "54 pairs", "wrote cal.yaml and cal.json"):
        assert words in out, out
    report = json.loads((delta_dir / "cal.json").read_text())
    assert report["measurement"] == "tracker" and report["method"] == "joint"
    ident = report["identifiability"]
    assert ident["free_parameters"] == 33 and ident["identifiable"] == 21
    assert {d["name"] for d in ident["unidentifiable"]} == {
        "leg1.da + leg1.db", "leg2.da + leg2.db", "leg3.da + leg3.db",
        "translation of the platform frame"}
    res = report["residuals"]
    assert 5 < res["rms_um"] < 40 and res["before_rms_um"] > 300
    assert 0.5 < res["noise_scale"] < 1.5
    dr = report["distance_ratio"]
    assert dr["pairs"] == 54 and dr["after"]["std"] < 0.5 * dr["before"]["std"]
    assert report["outlier_rows"] == [] and report["convergence"]["success"] is True
    assert len(report["parameters"]) == 33


def test_calibrated_file_loads_back_with_errors_tracker_and_home(delta_dir):
    cal, cal_setups = load_machine_file(delta_dir / "cal.yaml")
    true, true_setups = load_machine_file(delta_dir / "true.yaml")
    text = (delta_dir / "cal.yaml").read_text()
    assert "legs:" in text and "tracker: {rotation:" in text and "home: [0.0, 0.0, -750.0]" in text
    assert cal.kind == "delta" and cal.calibration_info["method"] == "tracker-joint"
    assert cal.calibration_info["identifiable"] == 21
    np.testing.assert_allclose(cal.home[0], [0, 0, -0.75])
    # db - da are the true ones (to ~0.1 mm) up to one common translation v of the platform:
    # db_i - da_i + Rphi_i v (the tracker pose is estimated too)
    cda, _, _, _, cdb = cal.legs()
    tda, _, _, _, tdb = true.legs()
    v = np.einsum("lji,lj->li", cal.Rphi, (cdb - cda) - (tdb - tda))   # base frame, per leg
    assert np.max(np.abs(v - v.mean(0))) < 1e-4
    report = json.loads((delta_dir / "cal.json").read_text())
    np.testing.assert_allclose(report["identifiable_combinations"]["leg2.db - leg2.da"],
                               (cdb - cda)[1] * 1e3, rtol=1e-12)
    # the identified tracker pose: rotation to < 0.01 deg; translation up to the gauge
    R, _ = cal_setups["tracker"].base_from_tracker
    Rt, _ = true_setups["tracker"].base_from_tracker
    assert np.degrees(np.arccos((np.trace(R.T @ Rt) - 1) / 2)) < 0.01
    # the calibrated file reproduces the measured points to the noise
    data = read_tracker(delta_dir / "data.csv", cal)
    pred = predict_tracker_points(cal, data.q, cal_setups["tracker"].base_from_tracker)
    assert np.sqrt(np.mean(np.sum((pred - data.m) ** 2, axis=1))) < 40e-6


def test_fk_gives_base_frame_positions_and_ik_inverts_it(delta_dir):
    proc = run("fk", "cal.yaml", "data.csv", "-o", "positions.csv", cwd=delta_dir)
    assert proc.returncode == 0, proc.stderr
    assert (delta_dir / "positions.csv").read_text().startswith("x_mm,y_mm,z_mm\n")
    P, rows = read_positions(delta_dir / "positions.csv")
    true = load_machine(delta_dir / "true.yaml")
    q, _, _ = read_joints(delta_dir / "data.csv", 3, "angle")
    # the data do not fix the origin of the base frame: equal up to one translation
    diff = P - true.fk(q).P
    assert np.max(np.abs(diff - diff.mean(0))) < 50e-6
    assert np.linalg.norm(diff.mean(0)) < 1e-2
    proc = run("ik", "cal.yaml", "positions.csv", "-o", "joints.csv", cwd=delta_dir)
    assert proc.returncode == 0, proc.stderr
    assert (delta_dir / "joints.csv").read_text().startswith("q1_deg,q2_deg,q3_deg\n")
    q2, _, _ = read_joints(delta_dir / "joints.csv", 3, "angle")
    np.testing.assert_allclose(q2, q, atol=1e-12)


def test_two_step_reports_18_of_27(delta_dir):
    proc = run("calibrate", DELTA, "data.csv", "--two-step", "-o", "cal2.yaml", "--json",
               cwd=delta_dir)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["method"] == "two-step" and report["registration"]["estimated"] is False
    assert report["identifiability"]["free_parameters"] == 27
    assert report["identifiability"]["identifiable"] == 18
    joint = json.loads((delta_dir / "cal.json").read_text())
    assert report["residuals"]["rms_um"] > joint["residuals"]["rms_um"]
    assert load_machine(delta_dir / "cal2.yaml").calibration_info["method"] == "tracker-two-step"


def test_robust_flags_the_simulated_outlier_rows(tmp_path):
    sim = run("simulate", DELTA, "--scenario", "tracker", "--seed", "2", "--outliers", "2",
              "-o", "data.csv", cwd=tmp_path)
    assert sim.returncode == 0, sim.stderr
    rows = sorted(int(v) for v in re.search(r"rows ([\d, ]+) moved", sim.stdout)
                  .group(1).split(","))
    assert len(rows) == 2
    proc = run("calibrate", DELTA, "data.csv", "--robust", "-o", "cal.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert f"row {rows[0]}:" in proc.stdout and f"row {rows[1]}:" in proc.stdout
    report = json.loads((tmp_path / "cal.json").read_text())
    assert report["outlier_rows"] == rows and report["used"] == 25
    assert report["residuals"]["rms_um"] < 40
    assert load_machine(tmp_path / "cal.yaml").calibration_info["outlier_rows"] == rows
    # without --robust the fit is spoiled and the summary says why it might be
    proc = run("calibrate", DELTA, "data.csv", "-o", "plain.yaml", cwd=tmp_path)
    assert proc.returncode == 0 and "try --robust" in proc.stdout


def test_grid_neighbour_pairs_recover_the_grid():
    from pkmcal.instruments.tracker import grid_neighbour_pairs

    for shape in ((3, 3, 3), (4, 4, 3), (2, 1, 5)):
        P = grid_points([0.1, 0.2, -0.7], (0.15, 0.1, 0.04), shape)
        order = np.random.default_rng(0).permutation(len(P))      # any row order
        got = grid_neighbour_pairs(P[order])
        expected = {tuple(sorted(p)) for p in neighbour_pairs(shape).tolist()}
        assert {tuple(sorted(order[p])) for p in got.tolist()} == expected


# -- bad input: exit 2, one line naming file/row/column/key, no output, input unchanged -------

HEADER = "q1_deg,q2_deg,q3_deg,mx_mm,my_mm,mz_mm"


def _rows(delta_dir, n, header=HEADER, edit=None):
    """The first ``n`` data rows of the simulation; ``edit = (k, column, text)`` replaces one
    field of data row k (0-based; file line k + 2)."""
    rows = [line.split(",") for line in
            (delta_dir / "data.csv").read_text().splitlines()[1:n + 1]]
    if edit is not None:
        k, col, text = edit
        rows[k][col] = text
    return "\n".join([header] + [",".join(r) for r in rows]) + "\n"


def _collinear(delta_dir):
    """Seven noise-free points of the nominal machine on a vertical line."""
    m = default_delta()
    P = np.column_stack([np.zeros(7), np.zeros(7), np.linspace(-0.81, -0.69, 7)])
    q = np.degrees(m.ik(P))
    pts = (P - [0, 0, 0.03]) * 1e3 + [2000.0, 100.0, 500.0]
    return HEADER + "\n" + "".join(",".join(map(repr, [*a, *b])) + "\n"
                                   for a, b in zip(q.tolist(), pts.tolist(), strict=True))


BAD_DATA = [
    # (id, command, data text, words in the message)
    ("missing mx column", "calibrate", lambda d: _rows(d, 27, HEADER.replace("mx_mm", "m_x")),
     ["bad.csv", "missing column mx_<unit>"]),
    ("no tracker columns", "calibrate", lambda d: "q1_deg,q2_deg,q3_deg\n1,2,3\n",
     ["bad.csv", "missing columns mx_<unit>, my_<unit>, mz_<unit>"]),
    ("unknown unit", "calibrate", lambda d: _rows(d, 27, HEADER.replace("my_mm", "my_ft")),
     ["bad.csv", "'my_ft'", "unknown unit suffix"]),
    ("length unit for an arm", "fk", lambda d: _rows(d, 5, HEADER.replace("q1_deg", "q1_mm")),
     ["bad.csv", "'q1_mm'", "q1 is an angle"]),
    ("nan", "calibrate", lambda d: _rows(d, 27, edit=(10, 5, "nan")),
     ["bad.csv", "row 12, column mz_mm", "not a finite number"]),
    ("text in a number", "calibrate", lambda d: _rows(d, 27, edit=(3, 1, "five")),
     ["bad.csv", "row 5, column q2_deg", "not a number: 'five'"]),
    ("wrong field count", "calibrate", lambda d: HEADER + "\n1,2,3\n",
     ["bad.csv", "row 2", "3 field(s)"]),
    ("fewer than 4 points", "calibrate", lambda d: _rows(d, 3),
     ["bad.csv", "3 point(s)", "at least 4 points"]),
    ("fewer equations than parameters", "calibrate", lambda d: _rows(d, 6),
     ["bad.csv", "6 points give 18 independent equation(s)", "21 identifiable"]),
    ("collinear points", "calibrate", _collinear,
     ["bad.csv", "7 tracker points lie on one line"]),
    ("empty file", "fk", lambda d: "", ["bad.csv", "empty file"]),
]


@pytest.mark.parametrize("command, make, words", [b[1:] for b in BAD_DATA],
                         ids=[b[0] for b in BAD_DATA])
def test_bad_tracker_data(delta_dir, tmp_path, command, make, words):
    bad = tmp_path / "bad.csv"
    bad.write_text(make(delta_dir))
    before = digest(bad)
    out = "out.yaml" if command == "calibrate" else "out.csv"
    assert_input_error(run(command, DELTA, "bad.csv", "-o", out, cwd=tmp_path), *words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv"]   # no output at all
    assert digest(bad) == before


LEG0 = "  - {da: [0.0, 0.0, 0.0], dtheta: 0.0, dl1: 0.0, dl2: 0.0, db: [0.0, 0.0, 0.0]}\n"
BAD_MACHINE = [
    ("two legs", lambda t: t.replace(LEG0, "", 1), ["m.yaml", "legs", "exactly 3 legs, got 2"]),
    ("unknown leg key", lambda t: t.replace("dtheta: 0.0", "dtheta: 0.0, dphi: 1", 1),
     ["m.yaml", "legs[0].dphi", "unknown key"]),
    ("non-number", lambda t: t.replace("dl1: 0.0", "dl1: O.5", 2),
     ["m.yaml", "legs[0].dl1", "not a number"]),
    ("missing units", lambda t: "\n".join(x for x in t.splitlines()
                                          if not x.startswith("units")) + "\n",
     ["m.yaml", "units", "missing key"]),
    ("missing upper arm", lambda t: t.replace("upper_arm: 300.0\n", ""),
     ["m.yaml", "upper_arm", "missing key"]),
    ("bad tracker rotation", lambda t: t + "tracker: {rotation: [[1, 0, 0], [0, 1, 0], "
     "[0, 1, 1]], translation: [0, 0, 0]}\n", ["m.yaml", "tracker.rotation", "line 16"]),
]


@pytest.mark.parametrize("edit, words", [b[1:] for b in BAD_MACHINE],
                         ids=[b[0] for b in BAD_MACHINE])
def test_bad_delta_machine_file(delta_dir, tmp_path, edit, words):
    text = edit(DELTA.read_text())
    (tmp_path / "m.yaml").write_text(text)
    (tmp_path / "data.csv").write_text((delta_dir / "data.csv").read_text())
    assert_input_error(run("calibrate", "m.yaml", "data.csv", "-o", "out.yaml", cwd=tmp_path),
                       *words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv", "m.yaml"]
    assert (tmp_path / "m.yaml").read_text() == text


def test_bad_options_and_mismatches(delta_dir, tmp_path):
    cases = [
        (("simulate", DELTA, "--deviations", "paper-table1", "-o", "o.csv"),
         ["paper-table1", "hexaslide"]),
        (("simulate", DELTA, "--grid", "3x3", "-o", "o.csv"), ["--grid", "NXxNYxNZ"]),
        (("simulate", DELTA, "--grid", "2x2x1", "--outliers", "5", "-o", "o.csv"),
         ["--outliers", "4 grid points"]),
        (("simulate", DELTA, "--grid", "9x9x3", "-o", "o.csv"), ["--grid", "workspace"]),
        (("simulate", DELTA, "--scenario", "constraint-link", "-o", "o.csv"),
         ["constraint-link", "delta", "tracker"]),
        (("simulate", DELTA, "--noise", "loud", "-o", "o.csv"), ["--noise", "'loud'"]),
        (("calibrate", "default", delta_dir / "data.csv", "-o", "o.yaml"),
         ["q1_deg", "an angle unit, q1 is a length"]),
        (("calibrate", DELTA, delta_dir / "data.csv", "--method", "ik", "-o", "o.yaml"),
         ["--method", "constraint-link"]),
        (("calibrate", DELTA, delta_dir / "data.csv", "--noise", "none", "-o", "o.yaml"),
         ["--noise none"]),
    ]
    for args, words in cases:
        assert_input_error(run(*args, cwd=tmp_path), *words)
    assert list(tmp_path.iterdir()) == []


def test_ik_refuses_rotations_and_unreachable_positions(tmp_path):
    (tmp_path / "rot.csv").write_text("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n"
                                      "0,0,-750,0,0,0\n10,0,-750,0,5,0\n")
    assert_input_error(run("ik", DELTA, "rot.csv", "-o", "j.csv", cwd=tmp_path),
                       "rot.csv", "row 3", "does not rotate")
    write_positions(tmp_path / "far.csv", [[0, 0, -0.75], [0, 0, -3.0]], "mm")
    assert_input_error(run("ik", DELTA, "far.csv", "-o", "j.csv", cwd=tmp_path),
                       "far.csv", "row(s) 3", "cannot be reached")
    assert not (tmp_path / "j.csv").exists()
