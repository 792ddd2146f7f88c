"""``pkmcal errors`` (SPEC 6) run as a subprocess: the columns of the public contract, the
numbers against the library, units on the command line, trajectories from files, plots, and
bad input (exit 2, one line, no output file)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, digest, run
from pkmcal.analysis import errors as err
from pkmcal.kinematics import quaternion_from_matrix
from pkmcal.machines import cubic_6upu

SPEC_COLUMNS = ["angle_deg", "f1_N", "f2_N", "f3_N", "f4_N", "f5_N", "f6_N", "dx_um", "dy_um",
                "dz_um", "drx_urad", "dry_urad", "drz_urad"]
ENVELOPE_COLUMNS = [f"{c}_{b}_{u}" for c, u in (("dx", "um"), ("dy", "um"), ("dz", "um"),
                                                 ("drx", "urad"), ("dry", "urad"),
                                                 ("drz", "urad"))
                    for b in ("min", "max")] + ["undetermined_legs"]
CUBIC_FILE = Path(__file__).resolve().parents[1] / "examples" / "cubic_6upu.yaml"
PAPER = ("--trajectory", "circle", "--radius", "100mm", "--height", "410mm", "--omega",
         "10rad/s", "--samples", "360", "--clearance", "10um", "--mass", "4.8kg",
         "--cutting-force", "0,0,-500N")


def read_csv(path):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


def numbers(rows, header, names):
    return np.array([[float(r[header.index(n)]) for n in names] for r in rows])


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("errors")
    proc = run("errors", "cubic", *PAPER, "--plot", "plots", "-o", "errors.csv", cwd=d)
    assert proc.returncode == 0, proc.stderr
    return d, proc


def test_columns_are_the_public_contract(paper_run):
    d, _ = paper_run
    header, rows = read_csv(d / "errors.csv")
    assert header == SPEC_COLUMNS                      # exactly the SPEC 6 columns
    env_header, env_rows = read_csv(d / "errors_envelope.csv")
    assert env_header == ["angle_deg", *ENVELOPE_COLUMNS]
    assert len(rows) == len(env_rows) == 360
    np.testing.assert_allclose(numbers(rows, header, ["angle_deg"])[:, 0], np.arange(360.0),
                               atol=1e-12)


def test_numbers_match_the_library(paper_run):
    d, _ = paper_run
    header, rows = read_csv(d / "errors.csv")
    res = err.trajectory_errors(cubic_6upu(), err.circle_trajectory(0.1, 0.41, 10.0, 360),
                                mass=4.8, cutting_force=(0, 0, -500), clearance=10e-6)
    np.testing.assert_allclose(numbers(rows, header, SPEC_COLUMNS[1:7]), res.forces, atol=1e-9)
    np.testing.assert_allclose(numbers(rows, header, SPEC_COLUMNS[7:]), res.errors.dx * 1e6,
                               atol=1e-9)
    env_header, env_rows = read_csv(d / "errors_envelope.csv")
    lo = numbers(env_rows, env_header, ENVELOPE_COLUMNS[0:12:2])
    hi = numbers(env_rows, env_header, ENVELOPE_COLUMNS[1:12:2])
    np.testing.assert_allclose(lo, res.errors.dx_min * 1e6, atol=1e-9)
    np.testing.assert_allclose(hi, res.errors.dx_max * 1e6, atol=1e-9)
    legs = [r[env_header.index("undetermined_legs")] for r in env_rows]
    assert legs[0] == "6" and legs[90] == "4 5" and legs[45] == ""
    # tension positive: legs 1-3 carry the cutting force and the weight in compression
    assert np.all(numbers(rows, header, ["f1_N", "f2_N", "f3_N"]) < 0)


def test_summary_names_switch_angles(paper_run):
    _, proc = paper_run
    out = proc.stdout
    assert "changes side at" in out and "envelope" in out
    line = next(ln for ln in out.splitlines() if ln.strip().startswith("dx "))
    crossings = [float(v) for v in line.split("│")[-1].split(",")]
    assert abs(crossings[0] - 90) < 3 and abs(crossings[1] - 270) < 3


def test_plots_written(paper_run):
    d, proc = paper_run
    for name in ("link_forces.png", "pose_errors.png", "error_map.png"):
        f = d / "plots" / name
        assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and f.stat().st_size > 10_000
        assert name in proc.stdout
    assert not list((d / "plots").glob("*.tmp*"))


def test_machine_file_gives_the_embedded_device(paper_run, tmp_path):
    """examples/cubic_6upu.yaml (machine: stewart) is the embedded 'cubic' device."""
    if not CUBIC_FILE.exists():
        pytest.skip("examples/cubic_6upu.yaml not shipped")
    d, _ = paper_run
    before = digest(CUBIC_FILE)
    proc = run("errors", CUBIC_FILE, *PAPER, "-o", "file.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert digest(CUBIC_FILE) == before
    h, rows = read_csv(tmp_path / "file.csv")
    h0, rows0 = read_csv(d / "errors.csv")
    assert h == h0
    np.testing.assert_allclose(numbers(rows, h, h[:-1]), numbers(rows0, h0, h0[:-1]),
                               atol=1e-9)


def test_bare_numbers_are_si_and_units_convert(tmp_path):
    a = run("errors", "cubic", "--samples", "12", "--radius", "0.1", "--height", "0.41",
            "--omega", "10", "--clearance", "1e-5", "--mass", "4.8", "--cutting-force",
            "0,0,-500", "-o", "a.csv", cwd=tmp_path)
    b = run("errors", "cubic", "--samples", "12", "--radius", "10cm", "--height", "410mm",
            "--omega", "95.49296585513721rpm", "--clearance", "0.01mm", "--mass", "4800g",
            "--cutting-force", "0,0,-0.5kN", "-o", "b.csv", cwd=tmp_path)
    assert a.returncode == 0 and b.returncode == 0, a.stderr + b.stderr
    ha, ra = read_csv(tmp_path / "a.csv")
    hb, rb = read_csv(tmp_path / "b.csv")
    np.testing.assert_allclose(numbers(ra, ha, SPEC_COLUMNS), numbers(rb, hb, SPEC_COLUMNS),
                               rtol=1e-9, atol=1e-9)
    # the defaults are the paper's case
    c = run("errors", "cubic", "--samples", "12", "-o", "c.csv", cwd=tmp_path)
    assert c.returncode == 0, c.stderr
    hc, rc = read_csv(tmp_path / "c.csv")
    np.testing.assert_allclose(numbers(rc, hc, SPEC_COLUMNS), numbers(ra, ha, SPEC_COLUMNS),
                               rtol=1e-9, atol=1e-9)


def test_screw_backlash_and_clearance_are_inputs(tmp_path):
    base = run("errors", "cubic", "--samples", "8", "-o", "a.csv", cwd=tmp_path)
    screw = run("errors", "cubic", "--samples", "8", "--clearance", "0um", "--screw-error",
                "20um", "-o", "b.csv", cwd=tmp_path)
    big = run("errors", "cubic", "--samples", "8", "--clearance", "30um", "-o", "c.csv",
              cwd=tmp_path)
    assert base.returncode == screw.returncode == big.returncode == 0
    h, ra = read_csv(tmp_path / "a.csv")
    rb, rc = read_csv(tmp_path / "b.csv")[1], read_csv(tmp_path / "c.csv")[1]
    dx = numbers(ra, h, SPEC_COLUMNS[7:])
    np.testing.assert_allclose(numbers(rb, h, SPEC_COLUMNS[7:]), dx, atol=1e-9)
    np.testing.assert_allclose(numbers(rc, h, SPEC_COLUMNS[7:]), 3 * dx, atol=1e-9)


def _text(values):
    return [repr(float(v)) for v in np.atleast_1d(values)]


def _write_circle_file(path, n=721, orientation="euler"):
    t = np.linspace(0.0, 2 * np.pi / 10, n)
    P = np.column_stack([0.1 * np.cos(10 * t), 0.1 * np.sin(10 * t), np.full(n, 0.41)])
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        if orientation == "euler":
            w.writerow(["t_s", "x_mm", "y_mm", "z_mm", "psi_deg", "theta_deg", "phi_deg"])
            for k in range(n):
                w.writerow([*_text(t[k]), *_text(P[k] * 1e3), 0, 0, 0])
        elif orientation == "quaternion":
            q = quaternion_from_matrix(np.eye(3))
            w.writerow(["t_ms", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"])
            for k in range(n):
                w.writerow([*_text(t[k] * 1e3), *_text(P[k]), *_text(q)])
        else:
            w.writerow(["t_s", "x_mm", "y_mm", "z_mm"])
            for k in range(n):
                w.writerow([*_text(t[k]), *_text(P[k] * 1e3)])
    return t, P


@pytest.mark.parametrize("orientation", ["euler", "quaternion", "none"])
def test_trajectory_from_a_file(tmp_path, orientation):
    """The circle given as poses over time: finite-difference accelerations give the forces
    of the analytic circle (inner samples; 0.5 deg steps)."""
    t, P = _write_circle_file(tmp_path / "path.csv", orientation=orientation)
    before = digest(tmp_path / "path.csv")
    proc = run("errors", "cubic", "--trajectory-file", "path.csv", "-o", "out.csv",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert digest(tmp_path / "path.csv") == before
    header, rows = read_csv(tmp_path / "out.csv")
    assert header[0] == "t_s" and header[1:13] == SPEC_COLUMNS[1:]
    assert len(rows) == len(t)
    f = numbers(rows, header, SPEC_COLUMNS[1:7])
    path = err.circle_trajectory(0.1, 0.41, 10.0, 720)
    ref = err.trajectory_errors(cubic_6upu(), path)
    np.testing.assert_allclose(f[1:-1], ref.forces[1:], atol=0.01)
    np.testing.assert_allclose(numbers(rows, header, ["t_s"])[:, 0], t, rtol=1e-12)


def test_plot_for_a_file_trajectory(tmp_path):
    _write_circle_file(tmp_path / "path.csv", n=50)
    proc = run("errors", "cubic", "--trajectory-file", "path.csv", "--plot", "p", "-o",
               "out.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert sorted(f.name for f in (tmp_path / "p").iterdir()) == [
        "error_map.png", "link_forces.png", "pose_errors.png"]


@pytest.mark.parametrize("args, words", [
    (("--radius", "100furlongs"), ("--radius", "furlongs")),
    (("--radius", "ten"), ("--radius",)),
    (("--clearance", "-1um"), ("--clearance", ">= 0")),
    (("--mass", "4.8m"), ("--mass", "unit")),
    (("--cutting-force", "0,-500N"), ("--cutting-force", "3")),
    (("--omega", "10deg"), ("--omega",)),
    (("--samples", "0"), ("--samples",)),
    (("--height", "0mm"), ("singularity",)),
    (("--trajectory", "file"), ("--trajectory-file",)),
    (("--force-tol", "-1N"), ("--force-tol",)),
])
def test_bad_options_exit_2_without_output(tmp_path, args, words):
    proc = run("errors", "cubic", *args, "-o", "out.csv", cwd=tmp_path)
    assert_input_error(proc, *words)
    assert not (tmp_path / "out.csv").exists()


def test_bad_machines_and_files_exit_2(tmp_path):
    proc = run("errors", "default", "-o", "out.csv", cwd=tmp_path)         # a Hexa Slide
    assert_input_error(proc, "stewart")
    proc = run("errors", "missing.yaml", "-o", "out.csv", cwd=tmp_path)
    assert proc.returncode == 2
    (tmp_path / "notime.csv").write_text("x_mm,y_mm,z_mm\n0,0,410\n1,0,410\n2,0,410\n")
    proc = run("errors", "cubic", "--trajectory-file", "notime.csv", "-o", "out.csv",
               cwd=tmp_path)
    assert_input_error(proc, "notime.csv", "t_s")
    (tmp_path / "back.csv").write_text("t_s,x_mm,y_mm,z_mm\n0,0,0,410\n0.1,1,0,410\n"
                                       "0.1,2,0,410\n")
    proc = run("errors", "cubic", "--trajectory-file", "back.csv", "-o", "out.csv",
               cwd=tmp_path)
    assert_input_error(proc, "back.csv", "row 4", "increase")
    (tmp_path / "nan.csv").write_text("t_s,x_mm,y_mm,z_mm\n0,0,0,410\n0.1,abc,0,410\n"
                                      "0.2,2,0,410\n")
    proc = run("errors", "cubic", "--trajectory-file", "nan.csv", "-o", "out.csv",
               cwd=tmp_path)
    assert_input_error(proc, "nan.csv", "row 3", "x_mm")
    (tmp_path / "two.csv").write_text("t_s,x_mm,y_mm,z_mm\n0,0,0,410\n0.1,1,0,410\n")
    proc = run("errors", "cubic", "--trajectory-file", "two.csv", "-o", "out.csv",
               cwd=tmp_path)
    assert_input_error(proc, "two.csv", "at least 3")
    (tmp_path / "flat.csv").write_text("t_s,x_mm,y_mm,z_mm\n0,0,0,0\n0.1,0,0,0\n0.2,0,0,0\n")
    proc = run("errors", "cubic", "--trajectory-file", "flat.csv", "-o", "out.csv",
               cwd=tmp_path)
    assert_input_error(proc, "flat.csv", "singularity", "row(s) 2, 3, 4")
    _write_circle_file(tmp_path / "ok.csv", n=10)
    proc = run("errors", "cubic", "--trajectory-file", "ok.csv", "--radius", "50mm", "-o",
               "out.csv", cwd=tmp_path)
    assert_input_error(proc, "--radius", "circle")
    proc = run("errors", "cubic", "--trajectory", "circle", "--trajectory-file", "ok.csv",
               "-o", "out.csv", cwd=tmp_path)
    assert_input_error(proc, "--trajectory-file")
    proc = run("errors", "cubic", "--trajectory-file", "ok.csv", "-o", "ok.csv",
               cwd=tmp_path)
    assert_input_error(proc, "overwrite")
    (tmp_path / "plotfile").write_text("x")
    proc = run("errors", "cubic", "--plot", "plotfile", "-o", "out.csv", cwd=tmp_path)
    assert proc.returncode == 2
    assert not (tmp_path / "out.csv").exists()


def test_help_names_the_command():
    proc = run("errors", "--help", cwd=".")
    assert proc.returncode == 0
    for word in ("--radius", "--clearance", "--cutting-force", "--screw-error", "--plot",
                 "tension"):
        assert word in proc.stdout
