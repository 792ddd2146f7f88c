"""The ``pkmcal`` command (SPEC 6): outputs, exit codes, messages (run in this process as the
console script runs it, :mod:`clitools`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, digest, run
from pkmcal.io import load_machine, read_joints, read_poses, write_poses
from pkmcal.kinematics import kabsch, matrix_from_euler
from pkmcal.machines import default_hexaslide

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "hexaslide_default.yaml"
COMMANDS = ["demo", "simulate", "calibrate", "fk", "ik", "bench"]




@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """simulate (default, paper-table1, noise 0, 150 poses) -> calibrate, once per module."""
    d = tmp_path_factory.mktemp("cli")
    sim = run("simulate", "default", "--poses", "150", "--noise", "0um", "--deviations",
              "paper-table1", "--seed", "3", "--truth", "true.yaml", "-o", "data.csv", cwd=d)
    assert sim.returncode == 0, sim.stderr
    cal = run("calibrate", "default", "data.csv", "-o", "cal.yaml", cwd=d)
    assert cal.returncode == 0, cal.stderr
    d.joinpath("calibrate.out").write_text(cal.stdout)
    return d


def test_help_of_every_command(cli):
    proc = cli("--help")
    assert proc.returncode == 0
    for c in COMMANDS:
        assert c in proc.stdout
    for c in COMMANDS:
        proc = cli(c, "--help")
        assert proc.returncode == 0, proc.stderr
        assert "Example" in proc.stdout and f"pkmcal {c}" in proc.stdout


def test_a_run_builds_its_command_alone_and_says_the_same():
    """pkmcal builds only the named command for a run (typer builds every command's options
    from its signature): its help and its usage errors read exactly as the whole app's."""
    from typer.main import get_command_name
    from typer.testing import CliRunner

    from pkmcal.cli import _command_app, app

    runner = CliRunner()
    names = [info.name or get_command_name(info.callback.__name__)
             for info in app.registered_commands]
    assert set(COMMANDS) <= set(names)
    for name in names:
        one = _command_app(["-q", name, "--help"])
        assert [i.callback for i in one.registered_commands] == \
            [i.callback for i in app.registered_commands
             if (i.name or get_command_name(i.callback.__name__)) == name]
        for args in ([name, "--help"], [name, "--no-such-option"]):
            whole = runner.invoke(app, args, prog_name="pkmcal")
            alone = runner.invoke(_command_app(args), args, prog_name="pkmcal")
            assert (alone.exit_code, alone.output) == (whole.exit_code, whole.output), args
    # no command, an unknown one, or only options: the whole app (its help, its message)
    for args in ([], ["--help"], ["calibrat"], ["-q"]):
        assert _command_app(args) is app


def test_simulate_writes_readings_and_truth(run_dir):
    q, rows, extra = read_joints(run_dir / "data.csv", 6)
    assert q.shape == (150, 6) and rows[0] == 2
    assert sorted(set(extra["passive"])) == ["1", "2", "3", "4", "5", "6"]
    true = load_machine(run_dir / "true.yaml")
    nominal = default_hexaslide()
    assert np.max(np.abs(true.u - nominal.u)) > 1e-3          # paper Table 1 deviations
    P = true.fk(q).P                                          # readings of the true machine
    np.testing.assert_allclose(np.linalg.norm(P, axis=1), 0.3, atol=1e-12)


def test_calibrate_outputs_and_report(run_dir):
    out = (run_dir / "calibrate.out").read_text()
    assert "48 of 54" in out and "rotation of the base frame about O" in out
    report = json.loads((run_dir / "cal.json").read_text())
    assert report["method"] == "ml" and report["measurements"] == 150
    ident = report["identifiability"]
    assert ident["free_parameters"] == 54 and ident["identifiable"] == 48
    names = {d["name"] for d in ident["unidentifiable"]}
    assert names == {"rotation of the base frame about O",
                     "re-orientation of the platform frame about P"}
    assert report["residuals"]["rms_um"] < 1e-6
    assert report["convergence"]["success"] is True
    assert len(report["parameters"]) == 55
    p = report["parameters"][0]
    assert set(p) >= {"name", "nominal", "identified", "std", "unit"}
    cal = load_machine(run_dir / "cal.yaml")
    assert cal.calibration_info["method"] == "ml"
    assert cal.calibration_info["identifiable"] == 48
    assert cal.file_units == {"length": "mm", "angle": "deg"}


def test_calibrated_machine_reproduces_the_data_gauge_free(run_dir):
    """FK of the calibrated file on the measured readings lands on |P| = Lc."""
    cal = load_machine(run_dir / "cal.yaml")
    q, _, _ = read_joints(run_dir / "data.csv", 6)
    fk = cal.fk(q)
    assert fk.converged.all()
    np.testing.assert_allclose(np.linalg.norm(fk.P, axis=1), 0.3, atol=1e-9)


def test_end_to_end_ik_true_fk_calibrated(run_dir, cli):
    """ik of the true machine -> fk of the calibrated one = the true poses, up to the gauge."""
    rng = np.random.default_rng(5)
    P = rng.uniform(-0.05, 0.05, (40, 3)) + [0.0, 0.0, 0.3]
    R = matrix_from_euler(rng.uniform(-0.1, 0.1, (40, 3)))
    write_poses(run_dir / "poses.csv", P, R, "mm", "deg")
    proc = cli("ik", "true.yaml", "poses.csv", "-o", "joints.csv", cwd=run_dir)
    assert proc.returncode == 0, proc.stderr
    proc = cli("fk", "cal.yaml", "joints.csv", "-o", "poses_cal.csv", cwd=run_dir)
    assert proc.returncode == 0, proc.stderr
    P2, R2, _ = read_poses(run_dir / "poses_cal.csv")
    # the data fix neither the base orientation about O nor the platform's about P:
    # align positions by a rotation about O, orientations by G (left) and a constant C (right)
    G = kabsch(P, P2)
    assert np.linalg.norm(G - np.eye(3)) < 0.1   # a small rotation
    np.testing.assert_allclose(P2, P @ G.T, atol=1e-9)
    C = np.einsum("kji,kjl->kil", np.einsum("ij,kjl->kil", G, R), R2)   # (G R)^T R2
    np.testing.assert_allclose(C, np.broadcast_to(C[0], C.shape), atol=1e-9)


def test_ik_fk_round_trip_and_units(tmp_path, cli):
    rng = np.random.default_rng(1)
    P = rng.uniform(-0.04, 0.04, (10, 3)) + [0.0, 0.0, 0.3]
    R = matrix_from_euler(rng.uniform(-0.1, 0.1, (10, 3)))
    write_poses(tmp_path / "poses.csv", P, R, "m", "rad")
    assert cli("ik", "default", "poses.csv", "-o", "joints.csv").returncode == 0
    assert (tmp_path / "joints.csv").read_text().startswith("q1_mm,")
    assert cli("fk", "default", "joints.csv", "-o", "back.csv").returncode == 0
    assert (tmp_path / "back.csv").read_text().startswith("x_mm,y_mm,z_mm,psi_deg,theta_deg,")
    P2, R2, _ = read_poses(tmp_path / "back.csv")
    np.testing.assert_allclose(P2, P, atol=1e-12)
    np.testing.assert_allclose(R2, R, atol=1e-12)


def test_calibrate_json_on_stdout(run_dir, cli):
    proc = cli("calibrate", "default", "data.csv", "-o", "cal_lc.yaml", "--estimate-lc",
               "--json", cwd=run_dir)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["method"] == "ml" and report["link_length"]["estimated"] is True
    assert report["link_length"]["value"] == pytest.approx(300.0, abs=1e-6)
    assert json.loads((run_dir / "cal_lc.json").read_text()) == report
    assert load_machine(run_dir / "cal_lc.yaml").calibration_info["link_length_estimated"]


# -- bad input: exit 2, one line naming file/row/column/key, no output, input unchanged ----

HEADER = "q1_mm,q2_mm,q3_mm,q4_mm,q5_mm,q6_mm,passive"


def _data(run_dir, n, header=HEADER, edit=None):
    """The first ``n`` rows of the simulated data; ``edit = (k, column, text)`` replaces one
    field of data row k (0-based; file line k + 2)."""
    rows = [line.split(",") for line in
            (run_dir / "data.csv").read_text().splitlines()[1:n + 1]]
    if edit is not None:
        k, col, text = edit
        rows[k][col] = text
    return "\n".join([header] + [",".join(r) for r in rows]) + "\n"


BAD_DATA = [
    # (id, command, data text, words in the message)
    ("missing column", "calibrate", lambda d: _data(d, 60, HEADER.replace("q4_mm", "q_4mm")),
     ["bad.csv", "missing column q4"]),
    ("unknown unit", "calibrate", lambda d: _data(d, 60, HEADER.replace("q2_mm", "q2_ft")),
     ["bad.csv", "q2_ft", "unknown unit"]),
    ("nan", "calibrate", lambda d: _data(d, 60, edit=(10, 0, "nan")),
     ["bad.csv", "row 12, column q1_mm", "not a finite number"]),
    ("text in a number", "fk", lambda d: _data(d, 5, edit=(3, 4, "five")),
     ["bad.csv", "row 5, column q5_mm", "not a number: 'five'"]),
    ("empty file", "calibrate", lambda d: "", ["bad.csv", "empty file"]),
    ("wrong field count", "fk", lambda d: HEADER + "\n1,2,3\n", ["bad.csv", "row 2", "field"]),
    ("passive outside 1..6", "calibrate", lambda d: _data(d, 60, edit=(2, 6, "9")),
     ["bad.csv", "row 4, column passive", "1..6"]),
    ("unreachable readings", "calibrate", lambda d: _data(d, 150, edit=(6, 0, "5000")),
     ["bad.csv", "no pose", "row(s): 8"]),
    ("fk does not converge", "fk",
     lambda d: _data(d, 2) + "5000,5000,5000,5000,5000,5000,1\n",
     ["bad.csv", "forward kinematics did not converge", "row(s) 4"]),
    ("fewer poses than parameters", "calibrate", lambda d: _data(d, 10),
     ["bad.csv", "10 measurements", "48 identifiable"]),
]


@pytest.mark.parametrize("command, make, words", [b[1:] for b in BAD_DATA],
                         ids=[b[0] for b in BAD_DATA])
def test_bad_data_file(run_dir, tmp_path, cli, command, make, words):
    bad = tmp_path / "bad.csv"
    bad.write_text(make(run_dir))
    before = digest(bad)
    out = "out.yaml" if command == "calibrate" else "out.csv"
    proc = cli(command, "default", "bad.csv", "-o", out)
    assert_input_error(proc, *words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv"]   # no output at all
    assert digest(bad) == before


BAD_MACHINE = [
    ("wrong number of chains",
     lambda t: "\n".join(x for x in t.splitlines() if "alpha: -160.0" not in x) + "\n",
     ["m.yaml", "chains", "exactly 6 chains, got 5"]),
    ("unknown key", lambda t: t.replace("beta: 70.0", "beta: 70.0, gamma: 1", 1),
     ["m.yaml", "chains[0].gamma", "unknown key"]),
    ("missing units", lambda t: "\n".join(x for x in t.splitlines()
                                          if not x.startswith("units")) + "\n",
     ["m.yaml", "units", "missing key"]),
    ("non-number", lambda t: t.replace("alpha: -40.0", "alpha: -4O.0"),
     ["m.yaml", "chains[3].alpha", "not a number"]),
    ("no constraint link", lambda t: "\n".join(x for x in t.splitlines()
                                               if not x.startswith("constraint_link")) + "\n",
     ["m.yaml", "constraint_link: {length: ...}"]),
]


@pytest.mark.parametrize("edit, words", [b[1:] for b in BAD_MACHINE],
                         ids=[b[0] for b in BAD_MACHINE])
def test_bad_machine_file(run_dir, tmp_path, cli, edit, words):
    text = edit(EXAMPLE.read_text())
    (tmp_path / "m.yaml").write_text(text)
    (tmp_path / "data.csv").write_text((run_dir / "data.csv").read_text())
    proc = cli("calibrate", "m.yaml", "data.csv", "-o", "out.yaml")
    assert_input_error(proc, *words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv", "m.yaml"]
    assert (tmp_path / "m.yaml").read_text() == text


def test_missing_files_and_bad_options(run_dir, tmp_path, cli):
    assert_input_error(cli("fk", "nope.yaml", run_dir / "data.csv", "-o", "o.csv"),
                       "nope.yaml", "not found")
    assert_input_error(cli("calibrate", "default", "nope.csv", "-o", "o.yaml"),
                       "nope.csv", "not found")
    assert_input_error(cli("calibrate", "default", run_dir / "data.csv", "-o", "o.yaml",
                           "--noise", "1parsec"), "--noise")
    assert_input_error(cli("fk", "default", run_dir / "data.csv", "-o", "no/dir/o.csv"),
                       "does not exist")
    assert list(tmp_path.iterdir()) == []
    # never overwrite an input
    before = digest(run_dir / "data.csv")
    assert_input_error(cli("fk", "default", "data.csv", "-o", "data.csv", cwd=run_dir),
                       "overwrite the input")
    assert digest(run_dir / "data.csv") == before
    # -o is required
    proc = cli("calibrate", "default", run_dir / "data.csv")
    assert proc.returncode == 2 and "Missing option" in proc.stderr


def test_unreachable_pose_for_ik(tmp_path, cli):
    P = np.array([[0, 0, 0.3], [0, 0, 3.0], [0.01, 0, 0.3]])
    write_poses(tmp_path / "p.csv", P, np.broadcast_to(np.eye(3), (3, 3, 3)), "mm", "deg")
    assert_input_error(cli("ik", "default", "p.csv", "-o", "j.csv"), "p.csv", "row(s) 3",
                       "cannot be reached")
    assert not (tmp_path / "j.csv").exists()


def test_calibration_that_does_not_converge_writes_nothing(run_dir, tmp_path, monkeypatch,
                                                           capsys):
    """Exit code 1, the reason on stderr, no calibrated file and no report."""
    import pkmcal.instruments.constraint_link as link
    from pkmcal.cli import main

    real = link.calibrate_constraint_link

    def not_converged(*args, **kwargs):
        result = real(*args, **kwargs)
        result.success, result.status, result.message = False, 0, "maximum number of iterations"
        return result

    monkeypatch.setattr(link, "calibrate_constraint_link", not_converged)
    with pytest.raises(SystemExit) as info:
        main(["calibrate", "default", str(run_dir / "data.csv"), "-o", str(tmp_path / "c.yaml")])
    assert info.value.code == 1
    assert "did not converge: maximum number of iterations" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
