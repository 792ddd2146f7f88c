"""``pkmcal export`` and ``pkmcal import`` (issue 15): files, record, table, round trip and
the refusals (exit 2, one line, no output written, inputs unchanged)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, digest
from pkmcal.io import load_machine

ROOT = Path(__file__).resolve().parents[1]
CUBIC = ROOT / "examples" / "cubic_6upu.yaml"


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """examples/cubic_6upu.yaml simulated (pose scenario) and calibrated, through the command."""
    from clitools import run

    d = tmp_path_factory.mktemp("cal")
    shutil.copy(CUBIC, d / "cubic.yaml")
    sim = run("simulate", "cubic.yaml", "--scenario", "pose", "--poses", "60", "--truth",
              "true.yaml", "-o", "poses.csv", cwd=d)
    assert sim.returncode == 0, sim.stderr
    cal = run("calibrate", "cubic.yaml", "poses.csv", "-o", "cal.yaml", cwd=d)
    assert cal.returncode == 0, cal.stderr
    return d


@pytest.fixture
def work(calibrated, tmp_path):
    for name in ("cubic.yaml", "cal.yaml", "cal.json"):
        shutil.copy(calibrated / name, tmp_path / name)
    return tmp_path


def setp(text: str) -> dict:
    return {w[1]: float(w[2]) for w in (line.split() for line in text.splitlines())
            if len(w) == 3 and w[0] == "setp"}


def test_export_writes_the_hal_and_its_record(cli, work):
    before = {n: digest(work / n) for n in ("cal.yaml", "cubic.yaml")}
    out = cli("export", "cal.yaml", "--to", "linuxcnc-genhexkins", "--nominal", "cubic.yaml",
              "-o", "hexapod.hal")
    assert out.returncode == 0, out.stderr
    assert {n: digest(work / n) for n in before} == before
    text = (work / "hexapod.hal").read_text()
    assert "setp genhexkins.base.0.x " in text and "Lengths in mm" in text
    record = json.loads((work / "hexapod.hal.json").read_text())
    assert record["format"] == "linuxcnc-genhexkins" and record["points"] == 500
    assert record["calibrated"] == "cal.yaml" and record["nominal"] == "cubic.yaml"
    assert record["remaining_max_um"] < 1e-3           # exact to rounding
    assert record["before_rms_um"] > 100               # the nominal joints: mm off
    assert record["values"]["base.0.x"] == pytest.approx(setp(text)["genhexkins.base.0.x"]
                                                         * 1e-3, abs=1e-14)
    for words in ("linuxcnc-genhexkins", "remaining error", "RMS", "max",
                  "error of --nominal", "genhexkins.platform.5", "strut-length.0", "mm/mm"):
        assert words in out.stdout, out.stdout


def test_export_workspace_box_and_points(cli, work):
    box = cli("export", "cal.yaml", "--to", "linuxcnc-genhexkins", "--workspace",
              "-30,30,-30,30,380,440mm", "-o", "box.hal")
    assert box.returncode == 0, box.stderr
    assert "box x -30..30 mm" in json.loads((work / "box.hal.json").read_text())["workspace"]
    (work / "points.csv").write_text("x_mm,y_mm,z_mm\n0,0,400\n10,-10,420\n-20,5,390\n")
    pts = cli("export", "cal.yaml", "--to", "linuxcnc-genhexkins", "--workspace", "points.csv",
              "-o", "pts.hal")
    assert pts.returncode == 0, pts.stderr
    record = json.loads((work / "pts.hal.json").read_text())
    assert record["points"] == 3 and "points.csv" in record["workspace"]
    # the values do not depend on the workspace (genhexkins holds the model exactly)
    assert setp((work / "pts.hal").read_text()) == setp((work / "box.hal").read_text())


def test_import_then_export_round_trip(cli, work):
    assert cli("export", "cal.yaml", "--to", "linuxcnc-genhexkins", "-o", "a.hal").returncode \
        == 0
    imp = cli("import", "a.hal", "--from", "linuxcnc-genhexkins", "--like", "cubic.yaml", "-o",
              "machine.yaml")
    assert imp.returncode == 0, imp.stderr
    machine, cal = load_machine(work / "machine.yaml"), load_machine(work / "cal.yaml")
    assert machine.kind == "stewart"
    np.testing.assert_allclose(machine.u, cal.u, rtol=0, atol=1e-11)
    np.testing.assert_allclose(machine.home[0], load_machine(work / "cubic.yaml").home[0])
    again = cli("export", "machine.yaml", "--to", "linuxcnc-genhexkins", "-o", "b.hal")
    assert again.returncode == 0, again.stderr
    assert setp((work / "b.hal").read_text()) == setp((work / "a.hal").read_text())


def test_refusals(cli, work):
    shutil.copy(ROOT / "examples" / "hexaslide_default.yaml", work / "hs.yaml")
    cases = [
        (("export", "cal.yaml", "--to", "nope", "-o", "x.hal"),
         ("unknown controller format 'nope'", "linuxcnc-genhexkins")),
        (("export", "hs.yaml", "--to", "linuxcnc-genhexkins", "-o", "x.hal"),
         ("--to linuxcnc-genhexkins", "Hexa Slide")),
        (("export", "cal.yaml", "--to", "linuxcnc-genhexkins", "--nominal", "hs.yaml", "-o",
          "x.hal"), ("--nominal hs.yaml", "Hexa Slide")),
        (("export", "cal.yaml", "--to", "linuxcnc-genhexkins", "-o", "cal.yaml"),
         ("cal.yaml",)),
        (("export", "cal.yaml", "--to", "linuxcnc-genhexkins", "--workspace", "1,2,3", "-o",
          "x.hal"), ("--workspace 1,2,3",)),
        (("import", "missing.hal", "--from", "linuxcnc-genhexkins", "-o", "m.yaml"),
         ("missing.hal",)),
        (("import", "cubic.yaml", "--from", "linuxcnc-genhexkins", "-o", "m.yaml"),
         ("cubic.yaml: line 5: 'pkmcal: 1' is not HAL", "not a HAL file")),
    ]
    before = {n: digest(work / n) for n in ("cal.yaml", "cubic.yaml", "hs.yaml")}
    for args, words in cases:
        assert_input_error(cli(*args), *words)
    assert {n: digest(work / n) for n in before} == before
    assert not list(work.glob("x.hal*")) and not (work / "m.yaml").exists()
