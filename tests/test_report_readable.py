"""Reports a person can read (issue 12, item 6): no raw dictionaries or '(N values)', a unit
for every number, standardised (leverage-corrected) residuals with their chi-square, and
parameters that are not identifiable one by one never flagged significant; the residual verdict
is the one the JSON report states."""

from __future__ import annotations

import copy
import html
import json
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from clitools import run
from pkmcal.estimation.acceptance import FAILED_SMALL, PASSED, report_verdict
from pkmcal.report.html import build_html, gauge_parameters
from pkmcal.units import format_number

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
#: (machine, scenario, calibrate options): simulated with the noise calibrate assumes
CASES = {
    "hexaslide": ("default", "constraint-link", ["--noise", "2um"]),
    "delta": (EXAMPLES / "delta_default.yaml", "tracker", []),
    "stewart": (EXAMPLES / "cubic_6upu.yaml", "pose", []),
}


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    """``{kind: (report dict, html text)}`` of a real calibration of each machine (the
    pages' figures made, their alt text and axes real, not drawn to pixels: nothing here
    reads an image's bytes)."""
    import matplotlib.pyplot as plt

    from pkmcal.report import plots

    out = {}
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plots, "png_bytes", lambda fig, dpi: plt.close(fig) or b"")
        for kind, (machine, scenario, options) in CASES.items():
            out[kind] = _real_calibration(tmp_path_factory, kind, machine, scenario, options)
    return out


def _real_calibration(tmp_path_factory, kind, machine, scenario, options):
    """simulate + ``calibrate --report``: ``(report dict, html text)``."""
    d = tmp_path_factory.mktemp(kind)
    proc = run("simulate", machine, "--scenario", scenario, "--seed", "3", "-o", "d.csv",
               cwd=d)
    assert proc.returncode == 0, proc.stderr
    proc = run("calibrate", machine, "d.csv", "-o", "cal.yaml", *options, "--report", "rep",
               cwd=d)
    assert proc.returncode == 0, proc.stderr
    return (json.loads((d / "cal.json").read_text()),
            (d / "rep" / "report.html").read_text())


class _Tables(HTMLParser):
    """Every table as rows of ``(tag, class, text)`` cells."""

    def __init__(self):
        super().__init__()
        self.tables, self._cell = [], None

    def handle_starttag(self, tag, attrs):
        if tag == "table":
            self.tables.append([])
        elif tag == "tr" and self.tables:
            self.tables[-1].append([])
        elif tag in ("td", "th") and self.tables:
            self._cell = [tag, dict(attrs).get("class") or "", ""]

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self.tables[-1][-1].append(tuple(self._cell))
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell[2] += data


def _tables(page: str):
    parser = _Tables()
    parser.feed(page)
    return parser.tables


def _verdict_paragraph(page: str) -> str:
    """The text of the page's residual verdict (its one ``<p class=verdict>``)."""
    found = re.findall(r"<p class=verdict>(.*?)</p>", page, flags=re.S)
    assert len(found) == 1, found
    return html.unescape(re.sub(r"<[^>]+>", "", found[0]))


def _numeric(text: str) -> bool:
    return bool(re.search(r"\d", text)) and not re.search(r"[A-Za-z_/]{4,}", text)


@pytest.mark.parametrize("kind", list(CASES))
def test_no_raw_dictionaries_or_value_counts(reports, kind):
    _, page = reports[kind]
    body = html.unescape(re.sub(r'src="data:image/png;base64,[^"]*"', "", page))
    assert not re.search(r"\(\d+ values\)", body)
    assert "{'" not in body and "[{" not in body and "[[" not in body


@pytest.mark.parametrize("kind", list(CASES))
def test_every_number_has_a_unit(reports, kind):
    _, page = reports[kind]
    tables = _tables(page)
    assert tables
    for table in tables:
        head = [text.strip() for tag, _, text in table[0] if tag == "th"]
        rows = table[1:]
        if head[:3] == ["quantity", "value", "unit"]:
            # label | value | unit: a number's row names its unit
            for row in rows:
                label, value, unit = (c[2].strip() for c in row)
                if "num" in row[1][1]:
                    assert unit, f"{kind}: {label} = {value} has no unit"
            continue
        if "unit" in head:          # a unit column (parameters, combinations, before/after)
            continue
        for j, name in enumerate(head):   # else the header of every numeric column has one
            if any(j < len(r) and _numeric(r[j][2]) for r in rows):
                assert "[" in name, f"{kind}: column {name!r} has numbers and no unit"


@pytest.mark.parametrize("kind", list(CASES))
def test_standardised_residuals_of_a_correct_fit(reports, kind):
    report, page = reports[kind]
    r = np.asarray(report["normalised_residuals"], float)
    st = np.asarray([np.nan if v is None else v for v in report["standardised_residuals"]])
    dof = report["residuals"]["dof"]
    # leverage correction: sum(r_i^2 / st_i^2) = sum(1 - h_ii) = dof
    ok = np.isfinite(st) & (np.abs(r) > 1e-12)
    assert np.sum((r[ok] / st[ok]) ** 2) == pytest.approx(dof, rel=1e-6)
    # N(0, 1) for the right noise, while the raw whitened residuals are too narrow
    assert 0.8 < np.mean(st[np.isfinite(st)] ** 2) < 1.25
    verdict = report_verdict(report)
    assert verdict.status == PASSED, verdict.sentence()
    assert _verdict_paragraph(page).startswith(f"Residual test {verdict.sentence()}")
    # three significant digits in tables (issue 36)
    assert format_number(verdict.test.ratio, 3) in page and "leverage-corrected" in page


def _no_pixels(monkeypatch):
    """The page's plots made but not rendered (a test of its words; the pixels of these
    figures are what test_report_browser and the reports above render)."""
    import matplotlib.pyplot as plt

    import pkmcal.report.html as page

    monkeypatch.setattr(page, "_png", lambda fig: plt.close(fig) or '<img alt="plot">')


def test_a_wrong_noise_is_named(reports, tmp_path, monkeypatch):
    """The Hexa Slide data have 2 um of noise; calibrated assuming 1 um, chi2/dof ~ 4."""
    proc = run("simulate", "default", "--scenario", "constraint-link", "--seed", "3",
               "-o", "d.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = run("calibrate", "default", "d.csv", "-o", "cal.yaml", "--noise", "1um",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    report = json.loads((tmp_path / "cal.json").read_text())
    verdict = report_verdict(report)
    assert verdict.status == FAILED_SMALL and 3 < verdict.test.ratio < 5.5
    _no_pixels(monkeypatch)
    page = build_html(report)
    assert _verdict_paragraph(page).startswith(f"Residual test {verdict.sentence()}")
    assert "a little larger than assumed" in page


def test_older_reports_get_the_global_dof_correction(reports, monkeypatch):
    report = copy.deepcopy(reports["stewart"][0])
    del report["standardised_residuals"]
    _no_pixels(monkeypatch)
    page = build_html(report)
    assert "global correction" in page and "sqrt(dof / N)" in page


def _rows_of(page, first_cell):
    for table in _tables(page):
        for row in table:
            if row and row[0][2].strip() == first_cell:
                yield row


def test_delta_null_space_parameters_are_not_significant(reports):
    report, page = reports["delta"]
    gauge = gauge_parameters(report)
    names = {p["name"] for p in report["parameters"]}
    da_db = {n for n in names if re.fullmatch(r"leg\d\.d[ab]\.[xyz]", n)}
    assert len(da_db) == 18 and da_db <= gauge
    assert {"tracker.x", "tracker.y", "tracker.z"} <= gauge      # the tracker translation
    assert not gauge & {"leg1.dtheta", "leg1.dl1", "tracker.rx"}  # identifiable alone
    for name in da_db | {"tracker.x"}:
        # the parameters table's row (the identifiable combinations list them too, with
        # the null space's pivots held: issue 36)
        (row,) = [r for r in _rows_of(page, name) if len(r) == 8]
        assert all("bad" not in cls for _, cls, _ in row), name
        assert [text for _, _, text in row][5:7] == ["-", "-"]      # std, change/std
    # a large identifiable change is still flagged
    flagged = [p["name"] for p in report["parameters"] if p["name"] not in gauge
               and p["std"] and abs(p["change"] / p["std"]) > 3]
    assert flagged
    for name in flagged:
        (row,) = [r for r in _rows_of(page, name) if len(r) == 8]
        assert "bad" in row[6][1]
    # the combinations are shown with their change and standard deviation
    assert "<h2>Identifiable combinations" in page
    for leg in (1, 2, 3):
        for axis in "xyz":
            (row,) = _rows_of(page, f"leg{leg}.db.{axis} - leg{leg}.da.{axis}")
            value, std = row[2][2], row[3][2]
            expected = report["identifiable_combinations"][f"leg{leg}.db - leg{leg}.da"]
            # three significant digits (issue 36)
            assert float(value) == pytest.approx(expected["xyz".index(axis)], rel=5e-3,
                                                 abs=5e-4 * max(map(abs, expected)))
            assert float(std) > 0


def test_stewart_frames_and_joints_not_identifiable_alone(reports):
    report, page = reports["stewart"]
    gauge = gauge_parameters(report)
    names = [p["name"] for p in report["parameters"]]
    assert len(names) >= 60
    alone = {n for n in names if n.endswith((".l0", ".gain"))}
    assert alone and not alone & gauge
    assert set(names) - alone <= gauge
    # the parameter plot: one panel per leg and frame, readable (not one 60-bar strip)
    assert "not identifiable alone" in page
