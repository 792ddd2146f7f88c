"""One verdict per question (issue 27 item 3): whether a calibration's residuals agree with
the noise model is decided once (:func:`pkmcal.estimation.acceptance.residual_verdict`), and
the console, the HTML report, the JSON report, the model-adequacy section and the warnings all
say what it says.

Twenty-one calibrations or more through ``pkmcal calibrate`` (in this process): every
instrument of the registry (constraint link, tracker points, full pose, ballbar distances, probe
heights written out; a case generated for every other) and two files
fitted together, passing fits (simulated with the noise the calibration is told) and failing
ones (simulated with 5-10x the noise it is told, outlier rows, the paper's methods that take
readings as exact). For each, the verdict the JSON states is the one the console's ``residual
test`` row, the HTML's verdict paragraph, the model-adequacy
section and the warnings state; every "N times the assumed noise" anywhere in the outputs is
the one noise ratio, ``sqrt(chi2 / dof)``; a failed test is never called consistent or in
agreement.

The HTML is built by ``--report`` as a user gets it, its plots replaced by a placeholder (the
verdict is text; rendering the PNGs would take most of the time).
"""

from __future__ import annotations

import html
import json
import math
import re
from pathlib import Path

import pytest

from clitools import SUBPROCESS, console_rows, run
from pkmcal.estimation.acceptance import (
    FAILED_ALARMING,
    FAILED_SMALL,
    NOT_TESTED,
    PASSED,
    VERDICTS,
    report_verdict,
)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
DELTA = EXAMPLES / "delta_default.yaml"
CUBIC = EXAMPLES / "cubic_6upu.yaml"
PRINTER = EXAMPLES / "linear_delta.yaml"
JUGGLEBOT = Path(__file__).resolve().parents[2] / "shared" / "data" / "jugglebot"

#: simulated data sets: name -> (machine, simulate options); seed 1 unless given
DATA = {
    "link": ("default", ["--scenario", "constraint-link", "--poses", "80"]),
    "link_20um": ("default", ["--scenario", "constraint-link", "--poses", "80",
                              "--noise", "20um"]),
    # two points moved by 1 mm (a beam break, a mis-seated reflector)
    "points_outliers": (DELTA, ["--scenario", "tracker", "--outliers", "2"]),
    "points": (DELTA, ["--scenario", "tracker"]),
    "points_60um": (DELTA, ["--scenario", "tracker", "--noise", "60um"]),
    "poses": (CUBIC, ["--scenario", "pose", "--poses", "40"]),
    "poses_10x": (CUBIC, ["--scenario", "pose", "--poses", "40", "--noise", "20um",
                          "--pose-noise", "200um,500urad"]),
    "ballbar": ("default", ["--scenario", "distance", "--poses", "120"]),
    "ballbar_10um": ("default", ["--scenario", "distance", "--poses", "120", "--noise",
                                 "10um"]),
    "delta_ballbar": (DELTA, ["--scenario", "distance"]),
    "heights": (PRINTER, ["--scenario", "probe"]),
    "heights_100um": (PRINTER, ["--scenario", "probe", "--noise", "100um"]),
    # Klipper's 7 heights for its 6 unknowns: too few to estimate the noise (a note, no
    # warning)
    "heights_7": (PRINTER, ["--scenario", "probe", "--poses", "7", "--noise", "100um",
                            "--seed", "2"]),
}
HELD_POSE_NOISE = ["--noise", "2um", "--pose-noise", "20um,50urad", "--extensions", "none"]
#: name -> (machine, data sets, calibrate options, the verdicts expected)
CASES = {
    "link ml, told the noise": ("default", ["link"], ["--noise", "2um"], {PASSED}),
    # the default assumed 1 um against 2 um of noise: estimated, and a little larger
    "link ml, noise estimated": ("default", ["link"], [], {FAILED_SMALL}),
    "link ml, 10x the noise told": ("default", ["link_20um"], ["--noise", "2um"],
                                    {FAILED_ALARMING}),
    "link ik": ("default", ["link"], ["--method", "ik", "--noise", "2um"], {PASSED}),
    "link fk": ("default", ["link"], ["--method", "fk", "--noise", "2um"], {PASSED}),
    "points joint": (DELTA, ["points"], [], {PASSED}),
    "points, 10x the noise told": (DELTA, ["points_60um"], ["--noise", "leica"],
                                   {FAILED_ALARMING}),
    "points, 10x the noise, estimated": (DELTA, ["points_60um"], [], {FAILED_ALARMING}),
    "points with two 1 mm outliers": (DELTA, ["points_outliers"], ["--noise", "leica"],
                                      {FAILED_ALARMING}),
    # the registration of the nominal model is held: its residuals exceed the noise
    "points two-step": (DELTA, ["points"], ["--two-step"], {FAILED_ALARMING}),
    "poses ml": (CUBIC, ["poses"], HELD_POSE_NOISE, {PASSED}),
    "poses ik": (CUBIC, ["poses"], ["--method", "ik", "--extensions", "none"], {PASSED}),
    "poses ml, 10x the noise told": (CUBIC, ["poses_10x"], HELD_POSE_NOISE,
                                     {FAILED_ALARMING}),
    "poses ik, 10x the noise told": (CUBIC, ["poses_10x"],
                                     ["--method", "ik", "--extensions", "none"],
                                     {FAILED_ALARMING}),
    "ballbar": ("default", ["ballbar"], [], {PASSED}),
    "ballbar, 10x the noise told": ("default", ["ballbar_10um"], ["--noise", "1um"],
                                    {FAILED_ALARMING}),
    "probe": (PRINTER, ["heights"], [], {PASSED}),
    "probe, 10x the noise told": (PRINTER, ["heights_100um"], ["--noise", "10um"],
                                  {FAILED_ALARMING}),
    "probe, Klipper's 7 heights": (PRINTER, ["heights_7"], ["--parameters", "klipper"],
                                   {FAILED_ALARMING}),
    "points and ballbar together": (DELTA, ["points", "delta_ballbar"], [], {PASSED}),
}
#: instruments without a calibration of their own here: the pair distances are fitted with
#: other files (a joint fit: "joint" stands for them)
WITH_OTHERS = {"pair-distances"}


def _every_other_instrument() -> None:
    """A case for every instrument of the registry the cases above do not simulate (a new
    instrument is checked without an edit here): simulated with its
    default noise on the first of the example machines it applies to and calibrated as the
    user would, which must pass the residual test."""
    from pkmcal.instruments.registry import INSTRUMENTS, instrument
    from pkmcal.io import load_machine

    simulated = {instrument(o[o.index("--scenario") + 1]).name for _, o in DATA.values()
                 if "--scenario" in o}
    for name, inst in INSTRUMENTS.items():
        if name in simulated | WITH_OTHERS:
            continue
        machine = next(m for m in (DELTA, CUBIC, PRINTER)
                       if inst.applies(load_machine(m)) is None)
        DATA[name] = (machine, ["--scenario", name])
        CASES[name] = (machine, [name], [], {PASSED})


_every_other_instrument()


def _placeholder_plots(mp) -> None:
    """The page's plots replaced by a placeholder: its own plots not made at all (building
    their figures, undrawn, was half of each page's time), the maps' figures not drawn."""
    import matplotlib.pyplot as plt

    import pkmcal.report.html as page

    mp.setattr(page, "_png", lambda fig: plt.close(fig) or '<img alt="plot">')
    for name in ("_residual_plot", "_singular_plot", "_change_plot", "_ratio_plot"):
        mp.setattr(page, name, lambda *args: '<img alt="plot">')


def _calibrate(machine, files, options, d: Path, name: str) -> dict:
    """One ``pkmcal calibrate ... --report``: its outputs as the user sees them."""
    proc = run("calibrate", machine, *files, *options, "-o", f"{name}.yaml", "--report",
               f"{name}_report", cwd=d)
    assert proc.returncode == 0, proc.stderr
    return {"stdout": proc.stdout, "stderr": proc.stderr,
            "report": json.loads((d / f"{name}.json").read_text()),
            "html": (d / f"{name}_report" / "report.html").read_text()}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The outputs of every case of :data:`CASES`, on data simulated once."""
    d = tmp_path_factory.mktemp("verdicts")
    for name, (machine, options) in DATA.items():
        seed = [] if "--seed" in options else ["--seed", "1"]
        proc = run("simulate", machine, *options, *seed, "-o", f"{name}.csv", cwd=d)
        assert proc.returncode == 0, proc.stderr
    out = {}
    with pytest.MonkeyPatch.context() as mp:
        if not SUBPROCESS:
            _placeholder_plots(mp)
        for i, (name, (machine, data, options, _)) in enumerate(CASES.items()):
            out[name] = _calibrate(machine, [f"{k}.csv" for k in data], options, d, f"run{i}")
    return out


def _html_text(page: str) -> str:
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", page)).split())


def _verdict_paragraph(page: str) -> str:
    found = re.findall(r"<p class=verdict>(.*?)</p>", page, flags=re.S)
    assert len(found) == 1, found
    return " ".join(html.unescape(re.sub(r"<[^>]+>", "", found[0])).split())


def _console_text(stdout: str) -> str:
    """Everything the command printed, table rows joined across their wrapped lines."""
    rows = console_rows(stdout)
    rest = [line for line in stdout.splitlines() if "│" not in line and "┃" not in line]
    return " ".join(" ".join([*rows.values(), *rest]).split())


def assert_one_verdict(outputs: dict, expected: set[str]) -> None:
    """The console, the HTML, the JSON and the warnings state the JSON's verdict."""
    report = outputs["report"]
    verdict = report_verdict(report)
    section = report["acceptance"]["residuals"]
    assert verdict.status in expected, verdict.sentence()
    assert section["verdict"] == verdict.status and section["sentence"] == verdict.sentence()
    sentence, note = verdict.sentence(), section.get("note")
    stated = sentence + (f"; {note}" if note else "")

    # the JSON's other sections: the same number, the same verdict
    ratio = verdict.noise_ratio
    assert (ratio is None) == (verdict.status == NOT_TESTED)
    if ratio is not None:
        assert ratio == pytest.approx(math.sqrt(section["chi2"] / section["dof"]), rel=1e-12)
        assert section["noise_ratio"] == ratio
    res = report["residuals"]
    if "noise_scale" in res:
        assert res["noise_scale"] == ratio
    if "residual_variance" in res:
        assert res["residual_variance"] == (None if ratio is None else section["chi2_per_dof"])
    for part in [report.get("model_adequacy")] + [f.get("model_adequacy") for f in
                                                  report.get("files", [])]:
        if part:
            assert part["noise_ratio"] == ratio and part["residual_verdict"] == verdict.status
            assert part["verdict"].startswith(f"residual test {sentence}")
            assert part["far_above_noise"] == (verdict.status == FAILED_ALARMING)

    # the console's row, the HTML's paragraph
    assert console_rows(outputs["stdout"])["residual test"] == stated, outputs["stdout"]
    paragraph = _verdict_paragraph(outputs["html"])
    assert paragraph.startswith(f"Residual test {stated}."), paragraph

    # the warnings: the failed test (unless the data cannot tell the noise), agreeing with the
    # verdict and its ratio, without repeating the sentence the summary's row states (said
    # once: issue 36)
    warned = [w for w in outputs["stderr"].splitlines() if "residual test" in w]
    if verdict.status == FAILED_ALARMING and not note:
        assert len(warned) == 1, warned
        assert f"residual test failed, {ratio:.3g}x the assumed noise" in warned[0], warned
        assert sentence not in " ".join(outputs["stderr"].split()), warned
    else:
        assert not warned, warned

    # every statement of the residuals' size against the noise, anywhere, is the one ratio;
    # a failed test is never "consistent" or in agreement
    texts = {"console": _console_text(outputs["stdout"]),
             "warnings": " ".join(outputs["stderr"].split()),
             "html": _html_text(outputs["html"]),
             "json": " ".join(json.dumps(report).split())}
    for where, text in texts.items():
        sizes = re.findall(r"(\S+)x? times the assumed noise|(\S+)x the assumed noise", text)
        for size in (a or b for a, b in sizes):
            assert ratio is not None and size == f"{ratio:.3g}", (where, size, ratio)
        assert "residuals / assumed noise =" not in text, where
        assert "consistent with the assumed noise" not in text, where
        if verdict.status != PASSED:
            assert "agree with" not in text, (where, text)
        if verdict.status == NOT_TESTED and where != "warnings":
            assert "not compared with the noise" in text, where


@pytest.mark.parametrize("case", list(CASES))
def test_console_html_json_and_warnings_state_one_verdict(runs, case):
    assert_one_verdict(runs[case], CASES[case][3])


def test_the_runs_cover_every_instrument_and_every_verdict(runs):
    from pkmcal.instruments.registry import INSTRUMENTS

    assert len(runs) == len(CASES) >= 21
    measured = {r["report"]["measurement"] for r in runs.values()}
    # the pair distances are fitted with other files only (a joint fit): "joint" stands for it
    assert set(INSTRUMENTS) - WITH_OTHERS | {"joint"} <= measured, measured
    # not tested: no calibration leaves it now (the paper's methods state their test in the
    # whitened model's terms; no redundancy is refused up front); test_acceptance has it
    assert {report_verdict(r["report"]).status for r in runs.values()} \
        == set(VERDICTS) - {NOT_TESTED}


@pytest.mark.skipif(not (JUGGLEBOT / "calibration_108_poses.csv").is_file(),
                    reason=f"the Jugglebot measurements are not at {JUGGLEBOT}")
def test_the_real_jugglebot_data_get_one_verdict(tmp_path, monkeypatch):
    """Issue 27: on the Jugglebot data a note said the residuals were "22.5 times the assumed
    noise" while the fit check said their size was "not compared with the noise"."""
    columns = ",".join([f"q{i}_rev=leg_length_{i}" for i in range(1, 7)]
                       + [f"{c}_mm=position_{c}" for c in "xyz"]
                       + [f"q{c}=orientation_{c}" for c in "xyzw"])
    if not SUBPROCESS:
        _placeholder_plots(monkeypatch)
    outputs = _calibrate(EXAMPLES / "jugglebot.yaml",
                         [JUGGLEBOT / "calibration_108_poses.csv"],
                         ["--columns", columns, "--method", "ik", "--extensions", "none"],
                         tmp_path, "jugglebot")
    # the default noise (2 um readings, 20 um and 50 urad poses) is far below motion capture's
    assert_one_verdict(outputs, {FAILED_ALARMING})
