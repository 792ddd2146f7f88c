"""The answer first for every machine type and every instrument (issue 36, Done when): one
generated test.

The docs' cases are checked in tests/test_report_answer.py (and rendered in a browser by
tests/test_report_browser.py); here the registries are walked instead - every machine type of
:data:`pkmcal.io.machine_file.MACHINE_FORMATS` (its module's default machine) with its default
instrument, and every instrument of :data:`pkmcal.instruments.registry.INSTRUMENTS` on the
first machine type it applies to - each calibrated from ``simulate --truth`` data with
``calibrate --report DIR``. The data are tests/test_roundtrip_matrix.py's (each instrument's
own plan; one whose plan completes another's, e.g. a dial, calibrated with that other file
beside it). The HTML is read as text (no browser): its answer section, above the details,
must hold the verdict, the accuracy before and after with its unit and the next commands; the
JSON's ``outcome`` must hold them; ``pkmcal report CAL.yaml`` of the calibrated file must give
the same first screen. Nothing here names a machine type or an instrument.
"""

from __future__ import annotations

import html
import json
import math
import re

import matplotlib.pyplot as plt
import pytest

from pkmcal.instruments.registry import INSTRUMENTS
from pkmcal.report import plots
from pkmcal.report.answer import number
from test_roundtrip_matrix import DEFAULTS, Files, _instruments, _machine


def _cases() -> list:
    """``(kind, instrument)``: every machine type with its default instrument, then every
    instrument not yet calibrated on the first machine type it applies to."""
    cases = [(kind, _machine(kind).default_instrument) for kind in DEFAULTS]
    done = {inst for _, inst in cases}
    for inst in INSTRUMENTS:
        if inst not in done:
            kind = next(k for k in DEFAULTS if inst in _instruments(k))
            cases.append((kind, inst))
            done.add(inst)
    return cases


CASES = _cases()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("every")
    cache: dict[str, Files] = {}

    def get(kind):
        if kind not in cache:
            cache[kind] = Files(root, kind)
        return cache[kind]
    return get


def _ok(proc, what):
    assert proc.returncode == 0, f"{what}: exit {proc.returncode}\n{proc.stdout[-2000:]}" \
                                 f"\n{proc.stderr[-2000:]}"
    return proc


def _first_screen(page: str) -> str:
    """The answer section at the page's top, above its details section."""
    start, details = page.find("<section id=answer>"), page.find("id=details")
    assert 0 < start < details, "no answer above the details"
    return page[start:page.index("</section>", start)]


def _text(part: str) -> str:
    part = re.sub(r'src="data:image/png;base64,[^"]*"', "", part)
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", part)).split())


def test_the_cases_cover_every_registry_member():
    """Every machine type and every instrument has a calibration here."""
    assert {k for k, _ in CASES} == set(DEFAULTS)
    assert {i for _, i in CASES} == set(INSTRUMENTS)
    assert all(inst in _instruments(kind) for kind, inst in CASES)


@pytest.mark.parametrize(("kind", "inst"), CASES, ids=[f"{k}-{i}" for k, i in CASES])
def test_the_first_screen_answers(files, kind, inst):
    f = files(kind)
    data = f.calibration_files(inst)
    out = f"{inst}-rep"
    _ok(f.cmd("calibrate", "nominal.yaml", *data, "-o", f"{inst}-cal.yaml", "--report", out),
        f"calibrate {kind} {' '.join(data)}")
    report = json.loads((f.d / out / "report.json").read_text())
    page = (f.d / out / "report.html").read_text()

    # the JSON: a verdict, the accuracy before and after in um, a next command
    outcome = report["outcome"]
    verdict = outcome["verdict"]
    assert verdict["words"] and verdict["headline"]
    acc = outcome["accuracy"]
    assert acc.get("basis") != "none", acc.get("why")
    assert acc["unit"] == "um"
    for when in ("before", "after"):
        rms = acc[when]["rms"]
        assert rms is not None and math.isfinite(rms) and rms >= 0, (when, acc)
    steps = outcome["next"]
    assert steps and all(s["command"].startswith("pkmcal ") for s in steps), steps

    # the page, above its details: the same verdict, the figures with their unit, the commands
    first = _first_screen(page)
    said = _text(first[first.index("id=verdict>") + len("id=verdict>"):])
    assert said.startswith(verdict["headline"]), said[:300]
    for word in re.findall(r"[a-z]+", verdict["words"]):
        assert word in said.split(".", 1)[0], (word, said[:300])
    table = first[first.index("<table id=accuracy"):]
    table = _text(table[:table.index("</table>")])
    assert re.search(r"before\) \[um\] calibrated \(after\) \[um\]", table), table
    rms = f"RMS {number(acc['before']['rms'])} {number(acc['after']['rms'])}"
    assert rms in table, (rms, table)
    shown = _text(first)
    for step in steps:
        assert step["command"] in shown, step["command"]

    # the report command on the calibrated file: the same first screen, its markup and its
    # plots' axes (alt, data-axes) too; the plots' figures are made as for a user, not
    # rendered to pixels a second time (the pixels of the same figures were drawn above and
    # are not compared: a report's time is its plots')
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plots, "png_bytes", lambda fig, dpi: plt.close(fig) or b"")
        _ok(f.cmd("report", f"{inst}-cal.yaml", "-o", f"{inst}-again.html"), "report")
    again = (f.d / f"{inst}-again.html").read_text()
    assert _text(_first_screen(again)) == shown
    assert _first_screen(again).count("<img") == first.count("<img")
    assert _no_pixels(_first_screen(again)) == _no_pixels(first)
    assert json.loads((f.d / f"{inst}-again.json").read_text())["outcome"] == outcome


def _no_pixels(part: str) -> str:
    return re.sub(r'src="data:image/png;base64,[^"]*"', "src", part)
