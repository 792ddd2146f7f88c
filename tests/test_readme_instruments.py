"""The documentation's "Every instrument on every machine" (docs/researcher.md) runs as written:
its command block, the Python example of docs/integrator.md, and the table's identifiable
counts are what the commands print; the printer session (docs/printer.md) and the export table
(docs/integrator.md) likewise. (These were the README's sections until issue 26.)"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from clitools import run

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
RESEARCHER = (DOCS / "researcher.md").read_text()
INTEGRATOR = (DOCS / "integrator.md").read_text()
PRINTER_PAGE = (DOCS / "printer.md").read_text()
SECTION = RESEARCHER[RESEARCHER.index("## Every instrument on every machine"):
                     RESEARCHER.index("## Noise levels from the data")]


def _examples(tmp_path):
    """The example machine files, as the pages' first blocks write them (test_docs.py checks
    that those blocks write exactly these files)."""
    for path in (ROOT / "examples").glob("*.yaml"):
        (tmp_path / path.name).write_text(path.read_text())


def _block(lang: str) -> str:
    return re.search(rf"```{lang}\n(pkmcal .*?)```", SECTION, re.S).group(1)


def test_the_commands_run(tmp_path):
    _examples(tmp_path)
    for line in _block("sh").splitlines():
        command = line.split("#")[0].strip()
        if not command:
            continue
        args = shlex.split(command)
        assert args[0] == "pkmcal"
        proc = run(*args[1:], cwd=tmp_path)
        assert proc.returncode == 0, (command, proc.stderr)
    assert (tmp_path / "cal.yaml").is_file() and (tmp_path / "predicted.csv").is_file()


def test_the_python_example_runs(tmp_path, monkeypatch):
    _examples(tmp_path)
    command = re.search(r"```sh\n(pkmcal -q simulate cubic_6upu.yaml --scenario distance "
                        r"-o cubic_bar.csv)\n```\n\n```python\n", INTEGRATOR).group(1)
    proc = run(*shlex.split(command)[1:], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    monkeypatch.chdir(tmp_path)
    python = re.search(r"```python\n(from pkmcal.calibration import calibrate.*?)```",
                       INTEGRATOR, re.S).group(1)
    exec(compile(python, "README", "exec"), {})
    assert (tmp_path / "cal.yaml").is_file() and (tmp_path / "cal.json").is_file()


@pytest.mark.parametrize("machine, scenario", [("hexaslide_default", "points"),
                                               ("hexaslide_default", "pose"),
                                               ("hexaslide_default", "distance"),
                                               ("delta_default", "points"),
                                               ("delta_default", "distance"),
                                               ("cubic_6upu", "points"),
                                               ("cubic_6upu", "pose"),
                                               ("cubic_6upu", "distance")])
def test_the_table_counts(machine, scenario, tmp_path):
    """Each cell's count is the one ``identifiability`` prints for the example machine."""
    proc = run("identifiability", ROOT / "examples" / f"{machine}.yaml", "--scenario",
               scenario, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    count = re.search(r"(\d+) of (\d+)", proc.stdout).group(0)
    row = {"hexaslide_default": "Hexa Slide", "delta_default": "Delta",
           "cubic_6upu": "Stewart"}[machine]
    cells = re.search(rf"\| \*\*{row}\*\* \|(.*)\|\n", SECTION).group(1).split(" | ")
    cell = cells[{"points": 0, "pose": 1, "distance": 2}[scenario]]
    assert f"**{count}**" in cell, (count, cell)


PRINTER = PRINTER_PAGE[PRINTER_PAGE.index("## A Delta 3D printer"):
                       PRINTER_PAGE.index("## From printer.cfg to printer.cfg")]


def test_the_printer_session_runs_and_its_table_is_what_it_reports(tmp_path):
    """The printer section's commands run as written, and its table of standard deviations
    (probe alone, ballbar alone, both) is what the joint calibration reports."""
    _examples(tmp_path)
    block = re.search(r"```sh\n(# probe heights.*?)```", PRINTER, re.S).group(1)
    block = block.replace("\\\n", "")
    for line in block.splitlines():
        command = line.split("#")[0].strip()
        if not command:
            continue
        if command.startswith("printf"):
            (tmp_path / "targets.csv").write_text("x_mm,y_mm,z_mm\n0,0,10\n40,-30,0.2\n")
            continue
        proc = run(*shlex.split(command)[1:], cwd=tmp_path)
        assert proc.returncode == 0, (command, proc.stderr)
    import json

    report = json.loads((tmp_path / "both.json").read_text())
    std = {p["name"]: p for p in report["contributions"]["parameters"]}
    # the HTML report shows the files fitted together and what each adds
    assert run("report", "both.yaml", "-o", "both_report.html", cwd=tmp_path).returncode == 0
    html = (tmp_path / "both_report.html").read_text()
    assert "Files fitted together" in html and "What each file adds" in html
    assert "tower1.arm_trim: std" in html

    def mean(prefix, key, file=None):
        values = [p["joint"] if file is None else p["alone"][file]
                  for name, p in std.items() if name.endswith(prefix)]
        return float(np.mean(values))

    factor = {"mm": 1.0, "um": 1e-3, "deg": 1.0, "urad": np.degrees(1e-6)}
    rows = {"arm length trims": "arm_trim", "delta radius": "delta_radius",
            "tower angles": ".angle"}
    for words, suffix in rows.items():
        cells = re.search(rf"\| {words} \| (.*) \|\n", PRINTER).group(1).split(" | ")
        for text, file in zip(cells, ("probe.csv", "bar.csv", None), strict=True):
            value, unit = text.split()
            expected = float(value) * factor[unit]
            assert mean(suffix, "alone", file) == pytest.approx(expected, rel=0.1), (words,
                                                                                     file)


EXPORT = INTEGRATOR[INTEGRATOR.index("## Handing the calibration to the controller"):
                    INTEGRATOR.index("## Before measuring")]


@pytest.fixture(scope="module")
def calibrated_examples(tmp_path_factory):
    """The export table's machines: the examples simulated and calibrated, seed 1."""
    d = tmp_path_factory.mktemp("export")
    out = {}
    for name, machine, scenario in (("delta", "delta_default", None),
                                    ("printer", "linear_delta", "points")):
        extra = ["--scenario", scenario] if scenario else []
        assert run("simulate", EXAMPLES_DIR / f"{machine}.yaml", "--seed", "1", *extra, "-o",
                   f"{name}.csv", cwd=d).returncode == 0
        proc = run("calibrate", EXAMPLES_DIR / f"{machine}.yaml", f"{name}.csv", "-o",
                   f"{name}_cal.yaml", cwd=d)
        assert proc.returncode == 0, proc.stderr
        out[name] = (d, f"{name}_cal.yaml", EXAMPLES_DIR / f"{machine}.yaml")
    return out


EXAMPLES_DIR = ROOT / "examples"


@pytest.mark.parametrize("fmt, machine", [("klipper", "printer"), ("marlin", "printer"),
                                          ("reprapfirmware", "printer"),
                                          ("linuxcnc-lineardelta", "printer"),
                                          ("klipper-rotary-delta", "delta")])
def test_the_export_table_is_what_export_prints(calibrated_examples, fmt, machine):
    """Each format's remaining error in the export table (RMS / max, um) is what ``pkmcal
    export`` reports for the example calibrated as the table says."""
    import json

    d, cal, nominal = calibrated_examples[machine]
    proc = run("export", cal, "--to", fmt, "--nominal", nominal, "-o", f"{fmt}.out", cwd=d)
    assert proc.returncode == 0, proc.stderr
    record = json.loads((d / f"{fmt}.out.json").read_text())
    row = re.search(rf"\| `{fmt}` \|[^\n]*\| (\d+\.?\d*) / (\d+\.?\d*) um", EXPORT)
    assert row is not None, fmt
    rms, peak = float(row.group(1)), float(row.group(2))
    assert record["remaining_rms_um"] == pytest.approx(rms, abs=0.5 + 0.01 * rms)
    assert record["remaining_max_um"] == pytest.approx(peak, abs=0.5 + 0.01 * peak)
