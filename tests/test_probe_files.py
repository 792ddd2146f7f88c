"""A probe calibration's bed plane is kept in the calibrated file (``bed``), loads back, and
``fk --frame instrument`` predicts the probe heights from it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clitools import run
from pkmcal.instruments.probe import BedSetup
from pkmcal.instruments.setups import Setups
from pkmcal.io import load_machine, load_machine_file, machine_to_text, parse_machine_file

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.mark.parametrize("units", [{"length": "mm", "angle": "deg"},
                                   {"length": "in", "angle": "rad"}])
def test_bed_round_trip(units):
    machine = load_machine(EXAMPLES / "linear_delta.yaml")
    bed = BedSetup(4.2e-4, -1.3e-3, 2.5e-4)
    back, setups = parse_machine_file(
        machine_to_text(machine, units, setups=Setups({"probe": bed})), "m.yaml")
    # a printer's frame is its bed (issue 37): the height is carried by the endstops, the
    # tilt kept; the printer is the same, its frame 0.42 mm higher
    np.testing.assert_allclose(setups["probe"].plane[1:], bed.plane[1:], rtol=1e-14)
    assert setups["probe"].plane[0] == 0.0
    P, R = machine.home
    q = machine.ik(P[None], R[None])
    np.testing.assert_allclose(back.ik(P[None] - [0, 0, 4.2e-4], R[None]), q,
                               rtol=1e-12, atol=1e-12 * np.abs(q).max())


def test_calibrate_writes_the_bed_and_fk_predicts_the_heights(tmp_path):
    # every tower quantity, maximum likelihood (the build tolerances off: with them nothing
    # is poorly determined, the tolerances hold it)
    machine = tmp_path / "ld.yaml"
    machine.write_text((EXAMPLES / "linear_delta.yaml").read_text() + "tolerances: none\n")
    assert run("simulate", machine, "--seed", "4", "-o", "probe.csv",
               cwd=tmp_path).returncode == 0
    proc = run("calibrate", machine, "probe.csv", "--parameters", "full", "-o", "cal.yaml",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert load_machine_file(tmp_path / "cal.yaml")[1].get("probe") is not None
    proc = run("fk", "cal.yaml", "probe.csv", "--frame", "instrument", "-o", "z.csv",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = (tmp_path / "z.csv").read_text().splitlines()
    assert lines[0] == "probe_z_mm"
    z = np.array([float(v) for v in lines[1:]])
    # the data say probe_z = 0 at every trigger: the prediction is the residual, ~ the noise
    import json

    report = json.loads((tmp_path / "cal.json").read_text())
    rms = np.sqrt(np.mean(z**2)) * 1e3
    assert rms == pytest.approx(report["residuals"]["rms_um"], rel=1e-6)
    # the HTML report shows the bed and the poorly determined parameters
    assert run("report", "cal.yaml", "-o", "cal_report.html", cwd=tmp_path).returncode == 0
    html = (tmp_path / "cal_report.html").read_text()
    assert "<h2>bed</h2>" in html and "Poorly determined" in html


@pytest.mark.parametrize("column, value, words", [
    ("probe_z_mm", "1e9", "not plausible as a probe height"),
    ("d_mm", "1e7", "not plausible as a ballbar length"),
])
def test_absurd_instrument_values_are_refused(tmp_path, column, value, words):
    """A height or a length far beyond the machine's size (a unit slip) is refused naming the
    row and column, and nothing is written."""
    (tmp_path / "data.csv").write_text(f"q1_mm,q2_mm,q3_mm,{column}\n"
                                       + "".join(f"{10 + k},{12 + k},{11 + k},{value}\n"
                                                 for k in range(8)))
    proc = run("calibrate", EXAMPLES / "linear_delta.yaml", "data.csv", "-o", "o.yaml",
               cwd=tmp_path)
    assert proc.returncode == 2 and words in proc.stderr and "row 2" in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv"]
