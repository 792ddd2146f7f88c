"""The demo's seed 003 part: clearance of the embedded cubic 6-UPU device along the circle.

The demo runs once (quick mode, through the library, inside an output set as ``pkmcal demo``
does); its clearance table is checked against the SPEC 6 columns, a direct call of the library
analysis, the ``pkmcal errors cubic`` command and the physics of the case (SPEC 2.3).
"""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from pkmcal.analysis import circle_trajectory, trajectory_errors
from pkmcal.demo import CLEARANCE_CASE, CLEARANCE_QUICK_SAMPLES, run_demo
from pkmcal.io.atomic import OutputSet
from pkmcal.machines import cubic_6upu

#: the columns of ``pkmcal errors`` on a circle (SPEC 6), in this order
SPEC_COLUMNS = ["angle_deg", *(f"f{i}_N" for i in range(1, 7)), "dx_um", "dy_um", "dz_um",
                "drx_urad", "dry_urad", "drz_urad"]
PLOTS = ("cubic_link_forces.png", "cubic_pose_errors.png")
CB = CLEARANCE_CASE["clearance"]


def read_csv(path):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


def table(path) -> np.ndarray:
    header, rows = read_csv(path)
    assert header == SPEC_COLUMNS
    return np.array(rows, float)


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """The quick demo, staged in one output set; whether its directory existed before the
    set's commit."""
    outdir = tmp_path_factory.mktemp("demo") / "out"
    with OutputSet():
        result = run_demo(outdir, quick=True)
        before_commit = outdir.exists()
    return outdir, result, before_commit


@pytest.fixture(scope="module")
def direct():
    """The same case, computed by the library directly."""
    c = CLEARANCE_CASE
    path = circle_trajectory(c["radius"], c["height"], c["omega"], CLEARANCE_QUICK_SAMPLES)
    return trajectory_errors(cubic_6upu(), path, c["mass"], c["cutting_force"], CB)


def test_the_clearance_files_appear_with_the_others(demo):
    outdir, result, before_commit = demo
    assert not before_commit            # staged: nothing appears before the set commits
    names = {p.name for p in result.files}
    for name in ("cubic_errors.csv", "cubic_errors_envelope.csv", *PLOTS):
        assert name in names
        assert (outdir / name).is_file()
    assert (outdir / "summary.json").is_file() and (outdir / "delta_tracker_data.csv").is_file()
    assert not [p for p in outdir.iterdir() if p.name.startswith(".")]     # no temporaries


def test_two_png_plots(demo):
    outdir, result, _ = demo
    pngs = [p for p in result.files if p.name.startswith("cubic_") and p.suffix == ".png"]
    assert sorted(p.name for p in pngs) == sorted(PLOTS)
    for p in pngs:
        data = (outdir / p.name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_csv_has_the_spec_columns_one_row_per_sample(demo):
    outdir, _, _ = demo
    t = table(outdir / "cubic_errors.csv")
    assert t.shape == (CLEARANCE_QUICK_SAMPLES, 13)
    np.testing.assert_allclose(t[:, 0], 360.0 * np.arange(CLEARANCE_QUICK_SAMPLES)
                               / CLEARANCE_QUICK_SAMPLES, rtol=1e-12, atol=1e-9)
    assert np.all(np.isfinite(t))
    header, rows = read_csv(outdir / "cubic_errors_envelope.csv")
    assert header[0] == "angle_deg" and header[-1] == "undetermined_legs"
    assert len(rows) == CLEARANCE_QUICK_SAMPLES


def test_numbers_match_the_library_analysis(demo, direct):
    outdir, _, _ = demo
    t = table(outdir / "cubic_errors.csv")
    np.testing.assert_allclose(t[:, 1:7], direct.forces, rtol=1e-9, atol=1e-6)       # N
    np.testing.assert_allclose(t[:, 7:], direct.errors.dx * 1e6, rtol=1e-9, atol=1e-6)  # um
    summary = json.loads((outdir / "summary.json").read_text())["clearance"]
    assert summary["case"]["samples"] == CLEARANCE_QUICK_SAMPLES
    for i, link in enumerate(summary["link_forces_N"]):
        assert link["min_N"] == pytest.approx(direct.forces[:, i].min(), rel=1e-9)
        assert link["max_N"] == pytest.approx(direct.forces[:, i].max(), rel=1e-9)
    for j, name in enumerate(("dx", "dy", "dz")):
        got = summary["pose_error_um_urad"][name]
        assert got["min"] == pytest.approx(direct.errors.dx[:, j].min() * 1e6, rel=1e-9)
        assert got["max"] == pytest.approx(direct.errors.dx[:, j].max() * 1e6, rel=1e-9)


def test_same_table_as_pkmcal_errors_cubic(demo, cli, tmp_path):
    outdir, _, _ = demo
    proc = cli("errors", "cubic", "--trajectory", "circle", "--radius", "100mm", "--height",
               "410mm", "--omega", "10rad/s", "--samples", str(CLEARANCE_QUICK_SAMPLES),
               "--clearance", "10um", "--mass", "4.8kg", "--cutting-force", "0,0,-500N",
               "-o", "e.csv")
    assert proc.returncode == 0, proc.stderr
    ours, theirs = table(outdir / "cubic_errors.csv"), table(tmp_path / "e.csv")
    np.testing.assert_allclose(ours, theirs, rtol=1e-9, atol=1e-6)


def test_physical_signs(demo):
    """Tension positive: under the weight and the 500 N cutting force the vertical links 1-3
    are in compression all along the circle (SPEC 2.3 hand case); compressed vertical links
    let the platform sink (dz < 0); links 4-5 change side at 90 and 270 deg; the errors are of
    the order of 2 c_b."""
    outdir, result, _ = demo
    t = table(outdir / "cubic_errors.csv")
    angle, f, dp = t[:, 0], t[:, 1:7], t[:, 7:10]
    assert np.all(f[:, :3] < -20.0)                      # links 1-3: compression, well off zero
    assert np.all(dp[:, 2] < 0)                          # dz: the platform sinks
    for i in (3, 4):                                     # links 4-5 change side near 90, 270
        assert f[:, i].max() > 50 and f[:, i].min() < -50
        positive = f[:, i] > 1.0
        changes = angle[np.flatnonzero(positive != np.roll(positive, 1))]
        assert all(min(abs(a - 90), abs(a - 270)) <= 10 for a in changes), changes
    two_cb_um = 2 * CB * 1e6
    for j in range(3):
        assert 0.5 * two_cb_um < np.abs(dp[:, j]).max() < 2 * two_cb_um
    notes = "\n".join(result.notes)
    for i in (1, 2, 3):
        assert f"link {i} force (tension +)" in notes
    assert notes.count("compression all along") >= 3
    assert "2 c_b = 20 um" in notes


# -- what the demo states (issue 27 item 4) ----------------------------------------------------


def test_the_demo_states_its_seeds_and_settings(demo):
    from pkmcal.demo import (
        DELTA_SEED,
        HEXASLIDE_NOISE,
        HEXASLIDE_POSES,
        HEXASLIDE_SEED,
        hexaslide_settings,
    )

    outdir, result, _ = demo
    hexa, sweeps, delta, cubic = result.settings
    assert hexa == hexaslide_settings(HEXASLIDE_SEED) and f"seed {HEXASLIDE_SEED};" in hexa
    assert f"{HEXASLIDE_POSES} constraint-link poses" in hexa and "Table 1 deviations" in hexa
    assert f"{HEXASLIDE_NOISE * 1e6:g} um encoder noise" in hexa
    assert f"seed {HEXASLIDE_SEED}" in sweeps and "1 simulated calibration(s)" in sweeps
    assert f"Delta: seed {DELTA_SEED};" in delta and "+/-1 mm, +/-0.5 deg" in delta
    assert f"{CLEARANCE_QUICK_SAMPLES} samples" in cubic
    summary = json.loads((outdir / "summary.json").read_text())
    assert summary["settings"] == result.settings and summary["seed"] == HEXASLIDE_SEED
    # the 2 um calibration's residual verdict, in the library's words
    assert any(n.startswith("Hexa Slide, 2 um noise: residual test passed: ")
               for n in result.notes)


def test_the_demo_prints_the_figures_the_docs_quote(demo):
    """docs/researcher.md quotes the demo's Hexa Slide figures at 2 um (its seed 0): the
    rows the demo prints are those figures (tests/test_readme_figures.py checks that they are
    seed 0 of the page's table)."""
    import re
    from pathlib import Path

    page = (Path(__file__).resolve().parents[1] / "docs" / "researcher.md").read_text()
    text = " ".join(page.split())
    m = re.search(r"`pkmcal demo` runs seed (\d+) of this table .*? after calibration at "
                  r"(\d+) um it prints a mean position error of ([\d.]+) um and a mean "
                  r"orientation error of ([\d.]+) urad", text)
    assert m, "docs/researcher.md: the sentence on pkmcal demo's figures is missing"
    _, result, _ = demo
    rows = {q: after for q, _, after in result.rows}
    assert rows[f"mean position error ({m.group(2)} um noise)"] == f"{m.group(3)} um"
    assert rows[f"mean orientation error ({m.group(2)} um noise)"] == f"{m.group(4)} urad"


def test_pkmcal_demo_prints_the_settings_before_its_table(demo, tmp_path, monkeypatch):
    """The command prints every setting line first (the run itself replaced by the quick
    demo's result: the full demo's Monte Carlo takes minutes)."""
    from clitools import SUBPROCESS, run

    if SUBPROCESS:
        pytest.skip("the demo's run is replaced in this process only")
    import pkmcal.demo

    _, result, _ = demo
    monkeypatch.setattr(pkmcal.demo, "run_demo", lambda outdir, progress=None: result)
    proc = run("demo", "-o", "out", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    printed = " ".join(proc.stdout.split())
    assert printed.startswith("settings: Hexa Slide: seed 0;"), proc.stdout[:300]
    for line in result.settings:
        assert " ".join(line.split()) in printed
    assert printed.index(" ".join(result.settings[-1].split())) < printed.index("pkmcal demo:")
