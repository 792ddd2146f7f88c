"""HTML reports (issue 6, item 1): ``pkmcal calibrate --report DIR`` and ``pkmcal report``."""

from __future__ import annotations

import json
import re
from pathlib import Path

import matplotlib.pyplot as plt
import pytest

from clitools import assert_input_error, digest
from pkmcal.report import plots

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
CASES = {
    "hexaslide": (EXAMPLES / "hexaslide_default.yaml", ["Residuals", "link length"]),
    "delta": (EXAMPLES / "delta_default.yaml", ["Distance ratios", "Before / after"]),
    "stewart": (EXAMPLES / "cubic_6upu.yaml", ["Before / after", "frames"]),
}


def _self_contained(page: str) -> None:
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    # nothing fetched: every src is an embedded image, no link to anywhere
    assert all(s.startswith("data:image/png;base64,") for s in re.findall(r'src="([^"]*)"', page))
    assert "http://" not in page and "https://" not in page and "<link" not in page


@pytest.mark.parametrize("kind", list(CASES))
def test_calibrate_report_dir_and_report_command(kind, cli, tmp_path):
    machine, sections = CASES[kind]
    assert cli("simulate", machine, "--seed", "4", "-o", "data.csv").returncode == 0
    (tmp_path / "out").mkdir()
    proc = cli("calibrate", machine, "data.csv", "-o", "cal.yaml", "--report", "out")
    assert proc.returncode == 0, proc.stderr
    page = (tmp_path / "out" / "report.html").read_text()
    _self_contained(page)
    # the internals (files, convergence) are under Details, below the answer (issue 36)
    for words in ["Details", "Identifiability", "Parameters", "Provenance", *sections]:
        assert f"<h2>{words}" in page, words
    twin = json.loads((tmp_path / "out" / "report.json").read_text())
    assert twin == json.loads((tmp_path / "cal.json").read_text())
    assert twin["provenance"]["command"].startswith("pkmcal calibrate")
    assert {"numpy", "scipy", "python", "pkmcal"} <= set(twin["provenance"])
    # every parameter is in the table, with its identified value
    for p in twin["parameters"][:5]:
        assert f"<td>{p['name']}</td>" in page
    # the plots: singular values, normalised residuals, parameter changes (+ ratios, Delta)
    assert page.count("data:image/png;base64,") >= 3
    # the same report from the calibrated file, later (one kind's plots rendered again; the
    # others' figures made as for a user but not drawn to pixels a second time: the same
    # figures' pixels were drawn above)
    before = digest(tmp_path / "cal.yaml")
    with pytest.MonkeyPatch.context() as mp:
        if kind != "delta":
            mp.setattr(plots, "png_bytes", lambda fig, dpi: plt.close(fig) or b"")
        proc = cli("report", "cal.yaml", "-o", "again.html")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "again.json").exists()
    assert digest(tmp_path / "cal.yaml") == before
    again = (tmp_path / "again.html").read_text()
    _self_contained(again)
    assert again.count("<h2>") == page.count("<h2>")
    assert again.count("<img") == page.count("<img")


def test_report_bad_input(cli, tmp_path):
    machine = CASES["hexaslide"][0]
    assert cli("simulate", machine, "--poses", "80", "-o", "data.csv").returncode == 0
    # --report DIR is created when missing; a file of that name is refused, nothing written
    (tmp_path / "afile").write_text("x")
    proc = cli("calibrate", machine, "data.csv", "-o", "cal.yaml", "--report", "afile")
    assert proc.returncode == 2 and "afile" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "cal.yaml").exists() and not (tmp_path / "cal.json").exists()
    assert cli("calibrate", machine, "data.csv", "-o", "cal.yaml", "--report",
               "new/dir").returncode == 0
    assert (tmp_path / "new" / "dir" / "report.html").is_file()
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"command": "identifiability"}))
    assert_input_error(cli("report", other, "-o", "r.html"), "other.json", "calibration report")
    broken = tmp_path / "broken.json"
    broken.write_text("{")
    assert_input_error(cli("report", broken, "-o", "r.html"), "broken.json")
    assert_input_error(cli("report", machine, "-o", "r.html"), "calibration report")
    assert_input_error(cli("report", other, "-o", "r.json"), ".html")
    assert not (tmp_path / "r.html").exists()


@pytest.mark.parametrize("dpi", [100, 120])
def test_a_laid_out_figure_is_drawn_once_with_the_bytes_of_savefig(dpi):
    """The report's and the commands' plots (:func:`pkmcal.report.plots.png_bytes`): a figure
    with a layout engine is laid out once and drawn once (savefig draws it twice: a draw that
    renders nothing, for the layout, then the drawing), and the PNG is savefig's, byte for
    byte, at the report's dpi (100, the figure's own) and the commands' (120)."""
    import io

    import numpy as np

    from pkmcal.report.plots import plt, png_bytes

    def figure():
        fig, axes = plt.subplots(2, 2, figsize=(6, 4), layout="constrained")
        for k, ax in enumerate(axes.flat):
            ax.barh(np.arange(5), np.arange(5) - k, color="C3")
            ax.set_yticks(np.arange(5), [f"chain{k}.a0.{i}" for i in range(5)], fontsize=9)
            ax.set_title(f"panel {k}")
            ax.set_xlabel("change / std [1]")
        fig.suptitle("identified - nominal in standard deviations")
        return fig

    fig = figure()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    fig = figure()
    draws = []
    real = fig.draw
    fig.draw = lambda renderer: draws.append(renderer) or real(renderer)
    assert png_bytes(fig, dpi) == buf.getvalue()
    assert len(draws) == 1
