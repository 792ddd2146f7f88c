"""Every kind of report as a user sees it (issue 36 item 6): rendered by a real browser
(Debian's ``chromium``, headless, 1400 x 900), the page loads without errors, the verdict and
the accuracy before and after are on the first screen, every plot names its axes with units,
and the page prints to PDF.

One screenshot per kind is kept under ``build/report-screenshots/`` (git-ignored; the docs'
build artifacts: ``mkdocs build`` writes its site beside it in ``build/``), or under
``$PKMCAL_SCREENSHOTS`` when set. Skipped, saying why, where chromium is not installed.
"""

from __future__ import annotations

import html
import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from clitools import run
from pkmcal.io.machine_file import MACHINE_FORMATS, save_machine
from test_report_answer import _calibrate, shared_reports

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists()
                                        else None)
SCREENSHOTS = Path(os.environ.get("PKMCAL_SCREENSHOTS") or ROOT / "build" / "report-screenshots")
WIDTH, HEIGHT = 1400, 900

pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (Debian: "
                                                          "apt-get install chromium)")

#: measures the page as laid out and writes it on the body (read back from --dump-dom)
LAYOUT = """<script>
window.addEventListener('load', function () {
  function bottom(id) {
    var e = document.getElementById(id);
    return e ? Math.round(e.getBoundingClientRect().bottom) : -1;
  }
  var images = [].slice.call(document.images);
  var broken = images.filter(function (i) { return !(i.complete && i.naturalWidth > 0); });
  document.body.setAttribute('data-layout', JSON.stringify({
    verdict: bottom('verdict'), accuracy: bottom('accuracy'), images: images.length,
    broken: broken.length, screen: window.innerHeight, width: window.innerWidth}));
});
</script>"""


def chromium(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    profile = tmp_path / f"profile-{len(list(tmp_path.glob('profile-*')))}"
    return subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
         "--no-first-run", "--disable-background-networking", "--disable-component-update",
         "--disable-sync", f"--user-data-dir={profile}", f"--window-size={WIDTH},{HEIGHT}",
         "--hide-scrollbars", "--enable-logging=stderr", "--v=0", *args],
        capture_output=True, text=True, timeout=120)


#: machine types the docs' reports leave out: their registry default machine, calibrated from
#: simulated data of its default instrument (a Stewart platform's poses, a planar 3-RPR's
#: tracker)
MORE = ["stewart", "planar_3rpr"]


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    base = tmp_path_factory.mktemp("reports")
    more = {}
    for kind in MORE:
        d = base / kind
        d.mkdir()
        machine = MACHINE_FORMATS[kind].default()
        save_machine(machine, d / "nominal.yaml")
        proc = run("simulate", "nominal.yaml", "--scenario", machine.default_instrument,
                   "--seed", "1", "-o", "data.csv", cwd=d)
        assert proc.returncode == 0, proc.stderr
        _calibrate(d, "nominal.yaml", ["data.csv"])
        more[kind] = d
    # the docs' reports, made once for the run (test_report_answer reads them too; made
    # after ours, so that a worker building them there overlaps with this work)
    out = shared_reports(tmp_path_factory)
    out.update(more)
    return out


KINDS = ["hexaslide", "delta-tracker", "printer-probe", "printer-probe-ballbar", "printer-cfg",
         "printer-cfg-v400", *MORE]


@pytest.mark.parametrize("kind", KINDS)
def test_report_in_a_browser(reports, kind, tmp_path):
    if kind not in reports:
        pytest.skip("../shared/data/printers is not here (the FLSUN V400's printer.cfg)")
    page = (reports[kind] / "rep" / "report.html").read_text()
    measured = tmp_path / "measured.html"
    measured.write_text(page.replace("</body>", LAYOUT + "</body>"))
    # one screenshot per kind, kept: taken by the same browser run (the measuring script
    # draws nothing; a second browser per kind cost more than the page)
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    shot = SCREENSHOTS / f"{kind}.png"
    shot.unlink(missing_ok=True)
    proc = chromium(tmp_path, "--dump-dom", f"--screenshot={shot}", measured.as_uri())
    assert proc.returncode == 0, proc.stderr[-2000:]
    # no error in the page's console (a script error, a resource refused)
    console = [line for line in proc.stderr.splitlines() if ":CONSOLE" in line]
    assert not console, console
    dom = proc.stdout
    found = re.search(r'data-layout="([^"]*)"', dom)
    assert found, "the page did not finish loading"
    layout = json.loads(html.unescape(found.group(1)))
    assert layout["width"] == WIDTH
    screen = min(layout["screen"], HEIGHT)
    # the verdict and the accuracy before and after are on the first screen
    assert 0 < layout["verdict"] <= screen, layout
    assert 0 < layout["accuracy"] <= screen, layout
    assert layout["images"] >= 3 and layout["broken"] == 0, layout
    text = re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", " ", dom)))
    assert re.search(r"before\) \[(um|mm)\] calibrated \(after\) \[(um|mm)\]", text)
    # every plot names its axes, numbers with their unit
    axes = re.findall(r'<img[^>]* data-axes="([^"]*)"', dom)
    assert len(axes) == layout["images"]
    for coded in axes:
        for panel in html.unescape(coded).split(" | "):
            for part in panel.split("; "):
                name, _, label = part.partition("=")
                assert label.strip(), (name, panel)
                if not name.endswith("#"):          # a numeric axis or a colour bar
                    assert re.search(r"\[[^\]]+\]", label), (name, label)
    assert shot.stat().st_size > 10_000, proc.stderr[-2000:]


def test_a_report_prints(reports, tmp_path):
    pdf = tmp_path / "report.pdf"
    proc = chromium(tmp_path, f"--print-to-pdf={pdf}", "--no-pdf-header-footer",
                    (reports["printer-probe-ballbar"] / "rep" / "report.html").as_uri())
    assert proc.returncode == 0, proc.stderr[-2000:]
    data = pdf.read_bytes()
    assert data.startswith(b"%PDF") and len(data) > 50_000
