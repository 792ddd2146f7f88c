"""The commands as a library (issue 38 item 3): ``pkmcal.workflows`` functions called from
Python, without the command line - their files (read back and checked against the
kinematics, the simulated truth and each other) and the :class:`~pkmcal.report.summary.Summary`
they return; the CLI prints that summary and nothing else."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from pkmcal.errors import InputError
from pkmcal.report.summary import RawText, Summary, SummaryTable
from pkmcal.workflows.check import check
from pkmcal.workflows.common import load_machine_arg
from pkmcal.workflows.demo import bench, demo
from pkmcal.workflows.errors import ERRORS_PLOTS, errors, read_trajectory_file
from pkmcal.workflows.kinematics import fk, ik
from pkmcal.workflows.report import report
from pkmcal.workflows.simulate import parse_grid, simulate

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
DELTA = EXAMPLES / "delta_default.yaml"
CUBIC = EXAMPLES / "cubic_6upu.yaml"


def _columns(path: Path) -> dict[str, np.ndarray]:
    """A CSV's numeric columns by name."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return {name: np.array([float(r[i]) for r in rows[1:]]) for i, name in enumerate(rows[0])}


def _tables(summary: Summary) -> dict[str, SummaryTable]:
    return {t.title: t for t in summary.blocks if isinstance(t, SummaryTable)}


def _pairs(table: SummaryTable) -> dict[str, str]:
    return {row[0]: row[1] for row in table.rows}


def _lines(summary: Summary) -> list[str]:
    return [b for b in summary.blocks if isinstance(b, str)]


class Recorder:
    """The progress protocol, recording: ``new(description, total) -> advance(n=1,
    description=None)``."""

    def __init__(self):
        self.tasks = []

    def __call__(self, description, total):
        task = {"description": description, "total": total, "done": 0, "names": []}
        self.tasks.append(task)

        def advance(n=1, description=None):
            task["done"] += n
            if description is not None:
                task["names"].append(description)

        return advance


# -- fk, ik ------------------------------------------------------------------------------


POSES = ("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n"
         "0,0,300,0,0,0\n10,5,310,1,2,3\n-20,15,290,-2,1,-4\n")


def test_ik_then_fk_gives_the_poses_back(tmp_path):
    (tmp_path / "poses.csv").write_text(POSES)
    s_ik = ik("default", tmp_path / "poses.csv", tmp_path / "q.csv")
    s_fk = fk("default", tmp_path / "q.csv", tmp_path / "back.csv")
    assert _lines(s_ik) == [f"3 joint vector(s) written to {tmp_path / 'q.csv'} (mm)"]
    assert _lines(s_fk) == [f"3 pose(s) written to {tmp_path / 'back.csv'} (mm, deg)"]
    assert s_ik.exit_code == s_fk.exit_code == 0 and not s_ik.warnings
    q = _columns(tmp_path / "q.csv")
    assert list(q) == [f"q{j}_mm" for j in range(1, 7)]
    given, back = _columns(tmp_path / "poses.csv"), _columns(tmp_path / "back.csv")
    assert list(back) == list(given)
    for name in given:
        scale = max(np.max(np.abs(given[name])), 1.0)
        np.testing.assert_allclose(back[name], given[name], rtol=0, atol=1e-9 * scale,
                                   err_msg=name)
    # the joint values are the machine's inverse kinematics of those poses
    machine = load_machine_arg("default")
    from pkmcal.io import read_poses

    P, R, _ = read_poses(tmp_path / "poses.csv")
    expect = machine.ik(P, R) * 1e3
    got = np.stack([q[f"q{j}_mm"] for j in range(1, 7)], axis=1)
    np.testing.assert_allclose(got, expect, rtol=1e-12)


def test_ik_of_a_translating_platform_and_back(tmp_path):
    """A Delta: positions only, the arms' angles in the file's angle unit."""
    machine = load_machine_arg(str(DELTA))
    home = machine.home[0] * 1e3
    offsets = np.array([[0, 0, 0], [30, -20, 10], [-40, 25, -15]])
    pts = home + offsets
    (tmp_path / "p.csv").write_text("x_mm,y_mm,z_mm\n" + "".join(
        f"{float(x)!r},{float(y)!r},{float(z)!r}\n" for x, y, z in pts))
    ik(str(DELTA), tmp_path / "p.csv", tmp_path / "q.csv")
    assert list(_columns(tmp_path / "q.csv")) == ["q1_deg", "q2_deg", "q3_deg"]
    summary = fk(str(DELTA), tmp_path / "q.csv", tmp_path / "back.csv")
    assert _lines(summary)[0].startswith("3 position(s) of the platform point, base frame")
    back = _columns(tmp_path / "back.csv")
    got = np.stack([back["x_mm"], back["y_mm"], back["z_mm"]], axis=1)
    np.testing.assert_allclose(got, pts, rtol=0, atol=1e-9 * np.max(np.abs(pts)))


def test_ik_refuses_an_unreachable_pose_and_writes_nothing(tmp_path):
    (tmp_path / "poses.csv").write_text(POSES + "5000,0,300,0,0,0\n")
    with pytest.raises(InputError, match=r"poses.csv: 1 pose\(s\) .*row\(s\) 5"):
        ik("default", tmp_path / "poses.csv", tmp_path / "q.csv")
    assert not (tmp_path / "q.csv").exists()


def test_fk_refuses_instrument_without_the_instrument_frame(tmp_path):
    (tmp_path / "poses.csv").write_text(POSES)
    with pytest.raises(InputError, match="--instrument tracker: only with --frame instrument"):
        fk("default", tmp_path / "poses.csv", tmp_path / "out.csv", instrument="tracker")


# -- simulate, check, fk --frame instrument, report --------------------------------------


@pytest.fixture(scope="module")
def delta_case(tmp_path_factory):
    """Tracker data of a true Delta (random deviations, seed 3) and its truth, simulated by
    the workflow; and the calibration of the example file on them, written."""
    from pkmcal.calibration import calibrate

    d = tmp_path_factory.mktemp("delta")
    summary = simulate(str(DELTA), d / "tracker.csv", scenario="tracker", seed=3,
                       truth=d / "true.yaml")
    cal = calibrate(load_machine_arg(str(DELTA)), d / "tracker.csv")
    cal.write(d / "cal.yaml")
    return d, summary


def test_simulate_writes_the_grid_and_says_so(delta_case):
    d, summary = delta_case
    table = _tables(summary)["pkmcal simulate"]
    rows = _pairs(table)
    assert list(rows) == ["machine", "scenario", "deviations", "tracker noise", "tracker pose"]
    assert rows["machine"] == f"{DELTA} (delta)"
    assert rows["scenario"].startswith("tracker, 3x3x3 grid") and "27 points" in rows["scenario"]
    assert rows["deviations"] == "random (seed 3)"
    assert _lines(summary) == [f"wrote {d / 'tracker.csv'} and {d / 'true.yaml'}"]
    data = _columns(d / "tracker.csv")
    assert list(data) == ["q1_deg", "q2_deg", "q3_deg", "mx_mm", "my_mm", "mz_mm"]
    assert all(len(v) == 27 for v in data.values())
    # the truth loads back and differs from the nominal machine by the deviations
    true, nominal = load_machine_arg(str(d / "true.yaml")), load_machine_arg(str(DELTA))
    assert true.u.shape == nominal.u.shape and not np.allclose(true.u, nominal.u)


def test_simulate_is_reproducible_from_its_seed(delta_case, tmp_path):
    d, _ = delta_case
    simulate(str(DELTA), tmp_path / "again.csv", scenario="tracker", seed=3)
    assert (tmp_path / "again.csv").read_bytes() == (d / "tracker.csv").read_bytes()
    simulate(str(DELTA), tmp_path / "other.csv", scenario="tracker", seed=4)
    assert (tmp_path / "other.csv").read_bytes() != (d / "tracker.csv").read_bytes()


def test_check_explains_the_data_with_the_truth_not_with_the_nominal(delta_case, tmp_path):
    """The true machine explains its own simulated data (residuals of the order of the
    noise); the nominal one, 0.5-1 mm away, does not."""
    d, _ = delta_case
    good = check(str(d / "true.yaml"), [d / "tracker.csv"], output=tmp_path / "good.json")
    bad = check(str(DELTA), [d / "tracker.csv"])
    assert good.exit_code == bad.exit_code == 0       # a verdict is not a failure
    good_rows = _pairs(_tables(good)[f"pkmcal check: {d / 'true.yaml'} on "
                                     f"{d / 'tracker.csv'}"])
    bad_rows = _pairs(_tables(bad)[f"pkmcal check: {DELTA} on {d / 'tracker.csv'}"])
    assert list(good_rows) == ["tracker.csv", "verdict", "free"]
    assert good_rows["verdict"].startswith("the machine explains these data")
    assert bad_rows["verdict"].startswith("the machine does not explain these data")
    assert _lines(good) == [f"wrote {tmp_path / 'good.json'}"] and _lines(bad) == []
    doc = json.loads((tmp_path / "good.json").read_text())
    (f,) = doc["files"]
    assert f["explained"] and f["rows"] == 27
    assert f["noise_ratio"] <= f["noise_ratio_limit"]
    assert f"{f['noise_ratio']:.3g}x the noise" in good_rows["tracker.csv"]


def test_check_refuses_a_noise_without_its_file(delta_case):
    d, _ = delta_case
    with pytest.raises(InputError, match="--noise: give FILE=VALUE per file"):
        check(str(DELTA), [d / "tracker.csv"], noise=["20um"])


def test_fk_in_the_instrument_frame_predicts_the_measured_points(delta_case, tmp_path):
    """The calibrated file's tracker frame and geometry predict the points the tracker
    measured to within a few times the tracker's noise (tens of um on a 1.5 m machine)."""
    d, _ = delta_case
    summary = fk(str(d / "cal.yaml"), d / "tracker.csv", tmp_path / "pred.csv",
                 frame="instrument")
    assert _lines(summary)[0].startswith("27 ") and str(tmp_path / "pred.csv") in \
        _lines(summary)[0]
    measured, predicted = _columns(d / "tracker.csv"), _columns(tmp_path / "pred.csv")
    axes = ("mx_mm", "my_mm", "mz_mm")
    diff = np.stack([predicted[a] - measured[a] for a in axes], axis=1)
    rms_mm = np.sqrt(np.mean(np.sum(diff ** 2, axis=1)))
    size_mm = np.max(np.abs(np.stack([measured[a] for a in axes])))
    assert rms_mm < 0.1 and rms_mm < 1e-4 * size_mm, rms_mm


def test_report_from_the_calibrated_file_and_from_its_json(delta_case, tmp_path):
    d, _ = delta_case
    summary = report(d / "cal.yaml", tmp_path / "r.html")
    (line,) = _lines(summary)
    assert line.startswith(f"wrote {tmp_path / 'r.html'} (") and \
        line.endswith(f"kB, self-contained) and {tmp_path / 'r.json'}")
    kb = int(line.split("(")[1].split(" kB")[0])
    assert kb == len((tmp_path / "r.html").read_text()) // 1024
    assert json.loads((tmp_path / "r.json").read_text()) == \
        json.loads((d / "cal.json").read_text())
    assert (tmp_path / "r.html").read_text().lstrip().lower().startswith("<!doctype html")
    with pytest.raises(InputError, match="choose a name ending in .html"):
        report(d / "cal.json", tmp_path / "r2.json")
    with pytest.raises(InputError, match="names no calibration report beside it"):
        report(DELTA, tmp_path / "r3.html")
    assert not (tmp_path / "r3.html").exists()


def test_simulate_refuses_an_option_of_another_scenario_and_writes_nothing(tmp_path):
    with pytest.raises(InputError, match="--setups: does not apply to --scenario tracker"):
        simulate(str(DELTA), tmp_path / "x.csv", scenario="tracker", setups=2,
                 truth=tmp_path / "t.yaml")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("text,shape", [("3x3x3", (3, 3, 3)), ("2*3*4", (2, 3, 4)),
                                        ("4X1x1", (4, 1, 1))])
def test_parse_grid(text, shape):
    assert parse_grid(text) == shape


@pytest.mark.parametrize("text", ["3x3", "0x3x3", "axbxc", "1x1x3"])
def test_parse_grid_refuses(text):
    with pytest.raises(InputError, match="--grid"):
        parse_grid(text)


def test_simulate_pose_data_of_a_stewart_and_fk_of_its_readings(tmp_path):
    """The pose scenario on the cubic 6-UPU: readings and measured marker poses; with no
    deviations and exact data the nominal model's FK of the readings is the commanded pose
    seen through the measurement frames, so its distance to the home pose stays bounded."""
    summary = simulate(str(CUBIC), tmp_path / "poses.csv", scenario="pose", poses=8,
                       deviations="none", noise="0um", pose_noise="0um,0urad")
    rows = _pairs(_tables(summary)["pkmcal simulate"])
    assert rows["deviations"] == "none" and rows["scenario"].startswith("pose")
    data = _columns(tmp_path / "poses.csv")
    readings = [c for c in data if c[0] == "q" and c[1].isdigit()]
    assert len(readings) == 6 and all(len(data[c]) == 8 for c in data)
    fk(str(CUBIC), tmp_path / "poses.csv", tmp_path / "fk.csv")
    back = _columns(tmp_path / "fk.csv")
    assert len(back["x_mm"]) == 8
    # readings back to joints: ik of fk's poses gives the same readings
    ik(str(CUBIC), tmp_path / "fk.csv", tmp_path / "q.csv")
    again = _columns(tmp_path / "q.csv")
    for c in readings:
        np.testing.assert_allclose(again[c], data[c], rtol=1e-9, err_msg=c)


# -- errors --------------------------------------------------------------------------------


def test_errors_scale_with_the_clearance(tmp_path):
    """Pose errors from joint clearance are linear in it where every leg's side is
    determined; the leg forces do not depend on it."""
    one = errors("cubic", tmp_path / "e10.csv", samples=36, clearance="10um")
    two = errors("cubic", tmp_path / "e20.csv", samples=36, clearance="20um")
    a, b = _columns(tmp_path / "e10.csv"), _columns(tmp_path / "e20.csv")
    assert list(a)[:13] == ["angle_deg", *(f"f{i}_N" for i in range(1, 7)), "dx_um", "dy_um",
                            "dz_um", "drx_urad", "dry_urad", "drz_urad"]
    np.testing.assert_allclose(a["angle_deg"], np.arange(36) * 10.0, atol=1e-12)
    for i in range(1, 7):
        np.testing.assert_array_equal(a[f"f{i}_N"], b[f"f{i}_N"])
    dx = np.stack([a[c] for c in ("dx_um", "dy_um", "dz_um")], axis=1)
    dx2 = np.stack([b[c] for c in ("dx_um", "dy_um", "dz_um")], axis=1)
    np.testing.assert_allclose(dx2, 2 * dx, rtol=1e-9, atol=1e-9 * np.max(np.abs(dx)))
    assert np.max(np.abs(dx)) > 1.0             # um: the clearance moves the platform
    tables = _tables(one)
    assert [r[0] for r in tables["leg forces (tension positive)"].rows] == \
        [str(i) for i in range(1, 7)]
    assert [r[0] for r in tables["pose error (um, urad)"].rows] == \
        ["dx", "dy", "dz", "drx", "dry", "drz"]
    rows = _pairs(tables["pkmcal errors: cubic"])
    assert rows["trajectory"].startswith("circle r = 100 mm at z = 410 mm") \
        and rows["trajectory"].endswith("36 samples")
    assert rows["clearance"].startswith("10 um (base joints)")
    assert _pairs(_tables(two)["pkmcal errors: cubic"])["clearance"].startswith("20 um")
    # the table's min and max are the file's
    dx_row = tables["pose error (um, urad)"].rows[0]
    assert float(dx_row[1]) == pytest.approx(a["dx_um"].min(), rel=1e-3)
    assert float(dx_row[2]) == pytest.approx(a["dx_um"].max(), rel=1e-3)
    assert _lines(one)[-1] == f"wrote {tmp_path / 'e10.csv'}, {tmp_path / 'e10_envelope.csv'}"


def test_errors_along_a_file_trajectory_and_its_plots(tmp_path):
    t = np.linspace(0, 1, 21)
    path = tmp_path / "path.csv"
    path.write_text("t_s,x_mm,y_mm,z_mm\n" + "".join(
        f"{ti:.17g},{40 * np.cos(2 * np.pi * ti):.17g},{40 * np.sin(2 * np.pi * ti):.17g},410\n"
        for ti in t))
    t_read, P, R, lines = read_trajectory_file(path)
    np.testing.assert_allclose(t_read, t)
    np.testing.assert_allclose(P[:, 2], 0.41)
    assert list(lines) == list(range(2, 23)) and np.allclose(R, np.eye(3))
    summary = errors("cubic", tmp_path / "e.csv", trajectory_file=path, plot=tmp_path / "plots")
    assert _pairs(_tables(summary)["pkmcal errors: cubic"])["trajectory"] == \
        f"{path}: 21 poses over 1 s"
    assert "t_s" in _columns(tmp_path / "e.csv")
    assert sorted(p.name for p in (tmp_path / "plots").iterdir()) == \
        sorted(f"{n}.png" for n in ERRORS_PLOTS)
    assert all(str(tmp_path / "plots" / f"{n}.png") in _lines(summary)[-1]
               for n in ERRORS_PLOTS)


def test_errors_refuses_before_writing(tmp_path):
    with pytest.raises(InputError, match="--radius: applies to --trajectory circle"):
        errors("cubic", tmp_path / "e.csv", trajectory="file",
               trajectory_file=tmp_path / "none.csv", radius="10mm")
    with pytest.raises(InputError, match="--clearance: must be >= 0"):
        errors("cubic", tmp_path / "e.csv", clearance="-1um")
    (tmp_path / "back.csv").write_text("t_s,x_mm,y_mm,z_mm\n0,0,0,410\n1,0,0,410\n0.5,0,0,410\n")
    with pytest.raises(InputError, match="row 4, column t_s: times must increase"):
        errors("cubic", tmp_path / "e.csv", trajectory_file=tmp_path / "back.csv")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["back.csv"]


# -- demo, bench (their long runs replaced: the wiring is what is tested here) --------------


def test_demo_says_its_settings_table_notes_and_files(tmp_path, monkeypatch):
    import pkmcal.demo
    from pkmcal.io.atomic import atomic_write_text, output_directory

    def quick_stand_in(outdir, progress=None):
        advance = progress("Fig. 5", 3)
        for _ in range(3):
            advance()
        outdir = output_directory(outdir)
        atomic_write_text(outdir / "summary.json", "{}\n")
        return pkmcal.demo.DemoResult(
            rows=[("mean position error", "4.976 mm", "1.2 um")], files=[outdir / "summary.json"],
            notes=["a note"], settings=["Hexa Slide: seed 0", "Delta: seed 1"])

    monkeypatch.setattr(pkmcal.demo, "run_demo", quick_stand_in)
    progress = Recorder()
    summary = demo(tmp_path / "out", progress=progress)
    assert progress.tasks == [{"description": "Fig. 5", "total": 3, "done": 3, "names": []}]
    assert (tmp_path / "out" / "summary.json").read_text() == "{}\n"
    lines = _lines(summary)
    assert lines[:2] == ["settings: Hexa Slide: seed 0", "          Delta: seed 1"]
    assert lines[2:] == ["note: a note", "files:", f"  {tmp_path / 'out' / 'summary.json'}"]
    table = _tables(summary)["pkmcal demo: calibration (embedded Hexa Slide and Delta)"]
    assert table.columns == ("quantity", "before calibration", "after calibration")
    assert table.rows == [("mean position error", "4.976 mm", "1.2 um")]
    # the settings come before the table, the notes after it
    assert summary.blocks.index(table) == 2


def test_bench_exit_code_table_and_json(monkeypatch):
    import pkmcal.bench

    results = [{"name": "fk", "value": 1.23456, "unit": "s", "target": "< 2", "ok": True},
               {"name": "crb", "value": float("nan"), "unit": "", "target": "1", "ok": False}]

    def run_all(quick=False, progress=None):
        for k, r in enumerate(results):
            progress(k, len(results), r["name"])
        progress(len(results), len(results), None)
        return results

    monkeypatch.setattr(pkmcal.bench, "run_all", run_all)
    progress = Recorder()
    summary = bench(progress=progress)
    assert summary.exit_code == 1                   # a benchmark missed its target
    (task,) = progress.tasks
    assert task["description"] == "bench" and task["total"] == 2 and task["done"] == 2
    assert task["names"] == ["bench: fk", "bench: crb"]
    table = _tables(summary)["pkmcal bench"]
    assert [r[:2] for r in table.rows] == [("fk", "1.235"), ("crb", "nan")]
    assert [r[4] for r in table.rows] == [("yes", "green"), ("NO", "red")]
    as_json = bench(json_output=True)
    (raw,) = as_json.blocks
    assert isinstance(raw, RawText) and raw.text.endswith("\n")
    doc = json.loads(raw.text)
    assert doc[0] == results[0] and doc[1]["value"] is None      # NaN is not JSON
    results[1]["ok"] = True
    assert bench().exit_code == 0


# -- the CLI prints the summary ------------------------------------------------------------


def test_the_cli_prints_the_workflows_summary(tmp_path):
    from clitools import run

    (tmp_path / "poses.csv").write_text(POSES)
    proc = run("ik", "default", "poses.csv", "-o", "q.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == "3 joint vector(s) written to q.csv (mm)\n"
    expected = ik("default", tmp_path / "poses.csv", tmp_path / "q2.csv").text()
    assert expected == f"3 joint vector(s) written to {tmp_path / 'q2.csv'} (mm)\n"
    assert (tmp_path / "q.csv").read_bytes() == (tmp_path / "q2.csv").read_bytes()


def test_quiet_still_prints_raw_text(monkeypatch, capsys):
    """``pkmcal --quiet``: "--json output is still printed" (the option's help)."""
    from pkmcal.cli import _console

    monkeypatch.setattr(_console, "_QUIET", True)
    _console.console.cache_clear()
    try:
        summary = Summary(exit_code=1)
        summary.line("a line")
        summary.raw('{"a": 1}\n')
        summary.warn("careful")
        assert _console.print_summary(summary) == 1
        out, err = capsys.readouterr()
        assert out == '{"a": 1}\n' and "warning: careful" in err
    finally:
        _console.console.cache_clear()


def test_table_headings_and_titles_are_plain_text(tmp_path):
    """A heading's unit in brackets is shown, not read as rich markup: ``pkmcal errors``
    printed "changes side at" without its "[deg]"."""
    from clitools import run

    proc = run("errors", "cubic", "--samples", "12", "-o", "e.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "changes side at [deg]" in proc.stdout and "changes sign at [deg]" in proc.stdout
