"""``pkmcal report``: the HTML report of a calibration and its JSON twin (issue 6)."""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import InputError
from ..paths import path_text
from ._commands import check_outputs, commit_outputs, load_machine_arg
from ._compensate import calibration_report_path
from ._console import console


def run_report(result: Path, output: Path) -> None:
    """``pkmcal report``: the HTML report and its JSON twin from a calibration report."""
    from ..io import atomic_write_text
    from ..io.atomic import is_stream
    from ..report.html import build_html
    from ..report.schema import load_report

    if output.suffix.lower() == ".json":
        raise InputError(f"{path_text(output)}: "
                         "the report is an HTML file (its JSON twin is written "
                         "beside it); choose a name ending in .html")
    twin = None if is_stream(output) else output.with_suffix(".json")
    source = result
    if result.suffix.lower() in (".yaml", ".yml"):
        machine = load_machine_arg(str(result))
        found = calibration_report_path(machine, str(result), None)
        if found is None:
            raise InputError(f"{path_text(result)}: names no calibration report beside it (is it a "
                             "calibrated file?); give the JSON report")
        source = found
    check_outputs([output] + ([twin] if twin else []), [result, source])
    doc = load_report(source)
    page = build_html(doc)
    if twin is not None:
        atomic_write_text(twin, json.dumps(doc, indent=2) + "\n")
    atomic_write_text(output, page)
    commit_outputs()
    console().print(f"wrote {path_text(output)} ({len(page) // 1024} kB, self-contained)"
                    + (f" and {path_text(twin)}" if twin else ""),
                    markup=False)
