"""Reports that answer first (issue 36): did it work, how accurate is the machine now, what to
do next, in pictures people already read; each finding of the issue is a test here.

The reports are made as the docs make them (``pkmcal simulate`` + ``pkmcal calibrate
--report``): the Hexa Slide's self-calibration (constraint link), the Delta robot with a laser
tracker, a simulated printer's probe heights, the same printer's probe heights with a ballbar,
and a Klipper ``printer.cfg`` an owner published (``tests/data/klipper``; the FLSUN V400 of
``../shared/data/printers`` where it is there). tests/test_report_browser.py renders them in a
headless browser.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from clitools import PKMCAL, run
from pkmcal.estimation.acceptance import FAILED_ALARMING, NOT_TESTED, PASSED, report_verdict
from pkmcal.identifiability.determination import POOR_FRACTION
from pkmcal.io import load_machine, load_machine_file
from run_once import once

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
#: the published configs and their saved runs (beside the repository; tests/data/klipper is gone)
KLIPPER = ROOT.parent / "shared" / "data" / "printers" / "klipper_saved"
SHARED_V400 = ROOT.parent / "shared" / "data" / "printers" / "flsun_v400_aieie78" / "printer.cfg"


def _calibrate(d: Path, machine, data: list, *options):
    proc = run("calibrate", machine, *data, "-o", "cal.yaml", *options, "--report", "rep",
               cwd=d)
    assert proc.returncode == 0, proc.stderr
    return proc


class _Reports(dict):
    """The reports made; a test of a printer's config that is not beside the repository is
    skipped (a missing file was a KeyError)."""

    def __missing__(self, kind):
        pytest.skip(f"{kind}: its printer.cfg is not in ../shared/data/printers")


def make_reports(base: Path) -> dict:
    """``{kind: directory}`` of the docs' reports (each with cal.json, rep/report.html and the
    calibrate command's ``out.txt`` / ``err.txt``)."""
    out = _Reports()

    def case(kind, steps, machine, data, *options):
        d = base / kind
        d.mkdir()
        for step in steps:
            proc = run(*step, cwd=d)
            assert proc.returncode == 0, proc.stderr
        proc = _calibrate(d, machine, data, *options)
        (d / "out.txt").write_text(proc.stdout)
        (d / "err.txt").write_text(proc.stderr)
        out[kind] = d

    hexaslide = EXAMPLES / "hexaslide_default.yaml"
    case("hexaslide", [("simulate", hexaslide, "--scenario", "constraint-link",
                        "--deviations", "paper-table1", "--noise", "2um", "--poses", "150",
                        "-o", "data.csv")],
         hexaslide, ["data.csv"], "--holdout", "0.2")
    delta = EXAMPLES / "delta_default.yaml"
    case("delta-tracker", [("simulate", delta, "--scenario", "tracker", "--seed", "1",
                            "-o", "tracker.csv")], delta, ["tracker.csv"])
    printer = EXAMPLES / "linear_delta.yaml"
    case("printer-probe", [("simulate", printer, "--seed", "1", "--truth", "true.yaml",
                            "-o", "probe.csv")], printer, ["probe.csv"], "--parameters",
         "klipper")
    case("printer-probe-ballbar",
         [("simulate", printer, "--seed", "1", "--truth", "true.yaml", "-o", "probe.csv"),
          ("simulate", "true.yaml", "--deviations", "none", "--scenario", "distance",
           "--seed", "2", "-o", "bar.csv")],
         printer, ["probe.csv", "bar.csv"], "--parameters", "klipper")
    for kind, cfg in (("printer-cfg", KLIPPER / "v400-aieie78-run9.cfg"),
                      ("printer-cfg-v400", SHARED_V400)):
        if not cfg.is_file():
            continue
        d = base / kind
        d.mkdir()
        shutil.copy(cfg, d / "printer.cfg")
        proc = run("import", "printer.cfg", "--from", "klipper", "-o", "printer.yaml", cwd=d)
        assert proc.returncode == 0, proc.stderr
        proc = _calibrate(d, "printer.yaml", ["printer.cfg"], "--parameters", "klipper")
        (d / "out.txt").write_text(proc.stdout)
        (d / "err.txt").write_text(proc.stderr)
        out[kind] = d
    return out


def shared_reports(tmp_path_factory) -> dict:
    """:func:`make_reports`' reports, made once per test run (test_report_browser reads the
    same ones); a test that writes beside them copies the directory first."""
    base = once(tmp_path_factory, "docs-reports", make_reports)
    return _Reports({p.name: p for p in sorted(base.iterdir()) if p.is_dir()})


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    return shared_reports(tmp_path_factory)


def _load(d: Path):
    return json.loads((d / "cal.json").read_text()), (d / "rep" / "report.html").read_text()


def _text(page: str) -> str:
    page = re.sub(r'src="data:image/png;base64,[^"]*"', "", page)
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", page))


# -- 1. the answer first --------------------------------------------------------------------

def test_no_converged_above_a_failed_test(reports):
    """The probe + ballbar report put a green "Status: converged" above a residual test that
    fails at 21 times the noise; now the verdict is the residual test's, first."""
    report, page = _load(reports["printer-probe-ballbar"])
    verdict = report_verdict(report)
    assert verdict.status == FAILED_ALARMING
    assert "Status:" not in page and "converged</span>" not in page
    first = page.index("id=verdict")
    assert "failed" in _text(page[first:first + 400])
    assert first < page.index("Gauss-Newton") and first < page.index("id=details")
    assert page.index("id=details") < page.index("Gauss-Newton")


@pytest.mark.parametrize("kind", ["hexaslide", "delta-tracker", "printer-probe",
                                  "printer-probe-ballbar", "printer-cfg"])
def test_accuracy_before_and_after_then_the_next_step(reports, kind):
    """Every report says how accurate the machine is, before and after, and what to run next,
    above its details."""
    report, page = _load(reports[kind])
    acc = report["outcome"]["accuracy"]
    assert acc["basis"] == "predicted" and acc["unit"] == "um"
    for when in ("before", "after"):
        assert np.isfinite(acc[when]["rms"]) and acc[when]["rms"] >= 0
    details = page.index("id=details")
    assert page.index("id=accuracy") < details
    assert page.index("pkmcal compensate cal.yaml") < details
    printer = kind.startswith("printer")
    assert acc["quantity"] == ("nozzle height above the bed" if printer else "position error")
    if printer:
        assert page.index("pkmcal export cal.yaml") < details
    out = (reports[kind] / "out.txt").read_text()
    assert out.lstrip().startswith("pkmcal calibrate:")
    assert out.index("verdict") < out.index("accuracy") < out.index("next") < out.index(
        "details")


def test_held_out_rows_are_the_accuracy_where_there_are_some(reports):
    report, page = _load(reports["hexaslide"])
    held = report["outcome"]["held_out_rows"]
    assert held["rows"] == report["validation"]["held_out"]
    assert held["after_rms"] == report["validation"]["after_rms"]
    answer = page[:page.index("id=details")]
    assert "held-out rows" in answer


def test_predicted_height_error_is_the_kinematics(reports):
    """The bed map's height error with the values in force is where the machine file's values
    put the nozzle by the calibrated model (checked here at the map's grid points through the
    machines' own ik and fk)."""
    d = reports["printer-probe-ballbar"]
    report, _ = _load(d)
    pmap = report["outcome"]["map"]
    nominal = load_machine(str(EXAMPLES / "linear_delta.yaml"))
    calibrated, setups = load_machine_file(str(d / "cal.yaml"))
    g = np.asarray(pmap["grid_mm"]) * 1e-3
    values = np.asarray([np.nan if v is None else v for v in pmap["before_um"]]).reshape(
        g.size, g.size)
    iy, ix = np.nonzero(np.isfinite(values))
    pick = np.linspace(0, iy.size - 1, 7).astype(int)
    P = np.column_stack([g[ix[pick]], g[iy[pick]], np.zeros(pick.size)])
    q = nominal.ik(P, np.broadcast_to(np.eye(3), (pick.size, 3, 3)))
    fk = calibrated.fk(q)
    bed = np.asarray(setups["probe"].plane)
    height = fk.P[:, 2] - (bed[0] + bed[1] * fk.P[:, 0] + bed[2] * fk.P[:, 1])
    np.testing.assert_allclose(values[iy[pick], ix[pick]] * 1e-6, height,
                               atol=1e-6 * np.max(np.abs(height)) + 1e-12)
    # the probe points are the data's: one per probe row, their residuals after the fit
    points = pmap["points"]
    assert len(points["x_mm"]) == report["files"][0]["measurements"]
    after = np.asarray(points["after_um"], float)
    rms = np.sqrt(np.mean(after**2))
    assert rms == pytest.approx(report["files"][0]["residuals"]["rms_um"], rel=0.05)


# -- 2. pictures ----------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["printer-probe", "printer-probe-ballbar", "printer-cfg"])
def test_a_printer_report_shows_its_bed(reports, kind):
    report, page = _load(reports[kind])
    assert report["outcome"]["map"]["kind"] == "bed"
    assert "<h2>The bed</h2>" in page
    assert "x on the bed [mm]" in page and "nozzle height error [um]" in page
    assert page.index("<h2>The bed</h2>") < page.index("id=details")


@pytest.mark.parametrize("kind", ["hexaslide", "delta-tracker"])
def test_other_machines_show_the_error_over_the_workspace(reports, kind):
    report, page = _load(reports[kind])
    assert report["outcome"]["map"]["kind"] == "workspace"
    assert "<h2>Error over the workspace</h2>" in page and "colour=position error [" in page
    # and at each measured point, before and after
    measured = report["outcome"]["map"]["measured_points"]
    rows = report.get("used", report["measurements"])
    assert len(measured["before_um"]) == len(measured["after_um"]) == rows
    before = np.asarray([np.nan if v is None else v for v in measured["before_um"]])
    after = np.asarray([np.nan if v is None else v for v in measured["after_um"]])
    assert np.nanmedian(before) > 10 * np.nanmedian(after) > 0
    assert "measured point (row of the data, in order) [count]" in page


def test_identifiable_combinations_for_any_machine(reports):
    """48 of the Hexa Slide's 54 bars read "not identifiable alone" with no table of what is;
    now the parameters with the null space's pivots held, each with its std."""
    from pkmcal.report.html import gauge_fixed

    report, page = _load(reports["hexaslide"])
    held, rows = gauge_fixed(report)
    assert len(held) == 6 and len(rows) >= 40
    assert "<h2>Identifiable combinations</h2>" in page
    for r in rows[:5]:
        assert f"<td>{r['name']}</td>" in page
        assert np.isfinite(r["std"]) and r["std"] > 0
    # the held parameters' values are the machine file's; the others moved only along the
    # unidentifiable directions from the calibrated values (the same fit)
    params = {p["name"]: p for p in report["parameters"]}
    names = report["covariance"]["parameters"]
    N = np.asarray(report["covariance"]["null_space"], float)
    from pkmcal.report.html import _si_of

    si = np.array([_si_of(params[n]) for n in names])
    fixed = np.array([params[n]["identified"] for n in names]) * si
    by = {r["name"]: r["change"] for r in rows}
    for i, n in enumerate(names):
        if n in by:
            fixed[i] = (params[n]["nominal"] + by[n]) * si[i]
        elif n in held:
            fixed[i] = params[n]["nominal"] * si[i]
    moved = np.array([n in by or n in held for n in names])
    d = (fixed - np.array([params[n]["identified"] for n in names]) * si)[moved]
    Q, _ = np.linalg.qr(N[moved])
    assert np.linalg.norm(d - Q @ (Q.T @ d)) <= 1e-6 * np.linalg.norm(d)


def test_chart_panels_keep_a_file_name_whole():
    from pkmcal.report.html import _split_name

    assert _split_name("bar.csv:setup1.pivot.x") == ("bar.csv:setup1", "pivot.x")
    assert _split_name("chain3.a0.x") == ("chain3", "a0.x")
    assert _split_name("delta_radius") == ("delta_radius", "delta_radius")


# -- 3. honest labels -----------------------------------------------------------------------

def test_a_noise_level_from_the_same_residuals_is_not_a_passed_test(reports):
    """Klipper's saved heights and distances are weighed as Klipper weighs them, their level
    set from the residuals: the test "passed, 1 times the assumed noise" could not fail."""
    report, page = _load(reports["printer-cfg"])
    verdict = report_verdict(report)
    assert verdict.status == NOT_TESTED and "set from these residuals" in verdict.why
    assert all(g["status"] == "estimated" for g in report["noise_model"]["groups"])
    assert "held: given" not in (reports["printer-cfg"] / "out.txt").read_text()
    answer = _text(page[page.index("<section id=answer>"):page.index("</section>")])
    assert "not tested" in answer and "passed" not in answer


def test_weak_parameters_are_warned_in_a_joint_printer_fit(reports):
    """The printer.cfg's heights + distances (a joint fit) left arm trims of +-1.9 mm without
    a warning where the probe calibration warns at 0.025 deg: one rule."""
    report, _ = _load(reports["printer-cfg"])
    poor = report["poorly_determined"]["parameters"]
    # the rule of every calibration: 1/2500 of the machine's size (0.1 mm on a 250 mm printer)
    section = report["poorly_determined"]
    assert poor and section["threshold_mm"] == pytest.approx(
        POOR_FRACTION * section["characteristic_length_mm"], rel=1e-12)
    err = (reports["printer-cfg"] / "err.txt").read_text()
    assert "poorly determined" in err and poor[0]["name"] in err


def test_a_result_equal_to_what_the_printer_runs_says_so(reports):
    """Klipper's 7 saved points alone: pkmcal's result is the printer's own values (issue 35:
    1.00x DELTA_CALIBRATE), and the report says so first."""
    report, page = _load(reports["printer-cfg"])
    assert report["outcome"]["same_as_running"]["same"]
    assert "equal what the machine runs" in _text(page[:page.index("id=details")])
    assert "equal what the machine runs" in (reports["printer-cfg"] / "out.txt").read_text()


@pytest.mark.skipif(not SHARED_V400.is_file(), reason="../shared/data/printers is not here")
def test_a_printer_cfg_with_its_meshes_is_not_called_equal(reports):
    """The V400's printer.cfg with its bed meshes as data (issue 35): the result differs from
    what the printer runs, and no page says it is equal; firmware values per stepper with the
    config's own digits."""
    report, page = _load(reports["printer-cfg-v400"])
    assert not report["outcome"]["same_as_running"]["same"]
    assert "equal what the machine runs" not in page
    assert "equal what the machine runs" not in (reports["printer-cfg-v400"] / "out.txt"
                                                 ).read_text()
    assert "stepper_a arm_length" in page and "343.702445" in page and "161.893820" in page


def test_firmware_values_per_stepper_with_the_configs_digits(reports):
    d = reports["printer-probe-ballbar"]
    _, page = _load(d)
    values = load_machine(str(d / "cal.yaml")).firmware_values()
    for i, stepper in enumerate(("stepper_a", "stepper_b", "stepper_c")):
        assert f"{stepper} position_endstop" in page
        assert f"{values['position_endstop'][i] * 1e3:.6f}" in page
        assert f"{values['arm_length'][i] * 1e3:.6f}" in page
    assert f"{values['radius'][0] * 1e3:.6f}" in page and "delta_radius" in page


def test_the_histogram_is_over_the_assumed_noise(reports):
    """Residuals scaled by a noise level estimated from them look normal beside "failed": the
    Hexa Slide's data have 2 um of noise, calibrate assumes 1 um and estimates the level."""
    from pkmcal.report.html import _assumed_scale

    report, page = _load(reports["hexaslide"])
    verdict = report_verdict(report)
    assert verdict.status != PASSED and report["noise_model"]["estimated"]
    scale, words = _assumed_scale(report)
    assert scale == pytest.approx(verdict.noise_ratio, rel=0.02)
    assert words == "over the assumed noise"
    st = np.asarray([v for v in report["standardised_residuals"] if v is not None]) * scale
    assert np.mean(st**2) == pytest.approx(verdict.noise_ratio**2, rel=0.1)   # not N(0, 1)
    assert "over the estimated noise levels" not in page


# -- 4. numbers a person reads --------------------------------------------------------------

_SIG = re.compile(r"[-+]?\d[\d.]*(?:e[-+]?\d+)?")


def _significant(text: str) -> int:
    digits = text.lstrip("+-").split("e")[0].replace(".", "").lstrip("0")
    return len(digits.rstrip("0")) if "." not in text else len(digits)


@pytest.mark.parametrize("kind", ["hexaslide", "delta-tracker", "printer-probe-ballbar"])
def test_words_not_codes_and_three_digits(reports, kind):
    _, page = _load(reports[kind])
    text = _text(page)
    assert "status 1" not in text and " code " not in text
    assert "redundancy 17.3814" not in text
    # the answer's accuracy table and the combinations: three significant digits
    acc = page[page.index("id=accuracy"):]
    acc = acc[:acc.index("</table>")]
    for cell in re.findall(r"<td class=num>([^<]*)</td>", acc):
        assert _significant(cell.strip()) <= 3, cell
    # model adequacy in the page's unit for residuals (um), never "rows" for a noise level
    adequacy = page[page.index("<h2>Model adequacy</h2>"):]
    assert "used 0.0" not in adequacy and "<th>unit</th>" in adequacy


def test_combination_change_over_std_is_shown(reports):
    """The combinations' change / std read "-" where both numbers were there."""
    _, page = _load(reports["delta-tracker"])
    section = page[page.index("<h2>Identifiable combinations</h2>"):]
    row = re.search(r"<tr><td>leg1\.db\.x - leg1\.da\.x</td>(.*?)</tr>", section).group(1)
    cells = re.findall(r"<td[^>]*>([^<]*)</td>", row)
    assert cells[3].strip() not in ("-", "")


# -- 5. the console ------------------------------------------------------------------------

def test_console_honours_columns_and_says_warnings_once_after_the_summary(reports, tmp_path):
    """Warnings were lines of 568 characters, printed before the header and again in the
    summary; piped, calibrate ignored COLUMNS (120 wide) where simulate honoured it."""
    d = tmp_path / "d"                  # the shared reports are read, never written into
    shutil.copytree(reports["printer-probe-ballbar"], d)
    env = {**os.environ, "COLUMNS": "80"}
    command = [str(PKMCAL), "calibrate", str(EXAMPLES / "linear_delta.yaml"), "probe.csv",
               "bar.csv", "--parameters", "klipper", "-o", "again.yaml"]
    proc = subprocess.run(command, cwd=d, env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    for line in proc.stdout.splitlines() + proc.stderr.splitlines():
        assert len(line) <= 80, line
    # the verdict's failure is warned once, on stderr, and the summary comes first
    assert proc.stderr.count("warning:") == len(re.findall(r"^warning:", proc.stderr, re.M))
    assert proc.stderr.count("residual test failed") == 1
    merged = subprocess.run(command, cwd=d, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, timeout=300)
    assert merged.stdout.lstrip().startswith("pkmcal calibrate:"), merged.stdout[:300]


def test_long_lists_are_summarised_with_the_report_named(reports):
    out = (reports["printer-cfg"] / "out.txt").read_text()
    block = out[out.index("each file adds"):]
    block = block[:block.index("residual test")]
    rows = [line for line in block.splitlines() if "std" in line and "alone" in line]
    assert len(rows) <= 2, block
    assert "more lines" in block and "rep/report.html" in block.replace("│", "").replace(
        "\n", "")


def test_uncertainty_in_the_values_unit(reports):
    out = (reports["printer-cfg"] / "out.txt").read_text()
    table = out[out.index("largest parameter changes"):]
    assert "urad" not in table and "mrad" not in table
    for line in table.splitlines():
        cells = [c.strip() for c in line.split("│")]
        if len(cells) == 6:
            assert cells[1].endswith(cells[5]), line


def test_a_broken_outcome_is_refused_with_its_key(reports, tmp_path):
    """``pkmcal report`` reads the outcome section it shows first: a wrong one is one message
    naming the key (exit 2), never a traceback or a half-written page."""
    report, _ = _load(reports["printer-probe"])
    report["outcome"]["map"]["before_um"] = report["outcome"]["map"]["before_um"][:5]
    (tmp_path / "bad.json").write_text(json.dumps(report))
    proc = run("report", "bad.json", "-o", "page.html", cwd=tmp_path)
    assert proc.returncode == 2 and "outcome.map" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "page.html").exists()
    del report["outcome"]["verdict"]["headline"]
    report["outcome"]["map"] = None
    (tmp_path / "bad.json").write_text(json.dumps(report))
    proc = run("report", "bad.json", "-o", "page.html", cwd=tmp_path)
    assert proc.returncode == 2 and "outcome.verdict.headline" in proc.stderr, proc.stderr
