"""``pkmcal report`` as a library function: the self-contained HTML report of a calibration
and its JSON twin; and the calibration report a calibrated machine file names."""

from __future__ import annotations

import json
from pathlib import Path

from ..calibration.run import text_digest
from ..errors import InputError
from ..io import atomic_write_text
from ..io.atomic import is_stream, read_input_text
from ..paths import path_text, recorded_path
from ..report.summary import Summary
from .common import check_outputs, commit_outputs, load_machine_arg

__all__ = ["report", "calibration_report_path"]


def calibration_report_path(machine, machine_spec: str, report: Path | None) -> Path | None:
    """The calibration report of a calibrated machine file.

    Parameters
    ----------
    machine : Machine
        The machine read from ``machine_spec`` (its ``calibration_info``).
    machine_spec : str
        The machine file's path (the report is beside it).
    report : Path, optional
        The report given (``--report``); checked against the file all the same.

    Returns
    -------
    Path or None
        ``report``, else the one the calibrated file names; None when it names none or the
        file is missing (the YAML travelled without its report).

    Raises
    ------
    InputError
        The name recorded is not a bare file name, names a directory, or the report is
        another run's (its SHA-256 differs from ``calibration.report_sha256``).
    """
    info = getattr(machine, "calibration_info", None) or {}
    pinned = info.get("report_sha256")
    if report is not None:
        path = report
    else:
        name = info.get("report")
        if name is None:
            return None
        if not isinstance(name, str) or not name.strip() or Path(name).name != name:
            raise InputError(f"{path_text(machine_spec)}: "
                             "calibration.report: expected the file name of "
                             f"the JSON report beside it, got {name!r}")
        path = recorded_path(Path(machine_spec).parent, name)      # recorded by path_text
        if not path.exists():
            return None             # the YAML travelled without its report: warned later
        if not path.is_file():
            raise InputError(f"{path_text(path)}: "
                             f"the calibration report {path_text(machine_spec)} names is not a "
                             "file; give the report with --report")
    if pinned is not None and text_digest(read_input_text(path, "calibration report")) \
            != str(pinned):
        raise InputError(f"{path_text(path)}: "
                         f"is not the report of {path_text(machine_spec)} (its SHA-256 differs "
                         f"from calibration.report_sha256 there: written by another run); "
                         "calibrate again, or give the right report with --report")
    return path


def report(result: Path, output: Path) -> Summary:
    """``pkmcal report``: the HTML report of a calibration and its JSON twin.

    Parameters
    ----------
    result : Path
        A calibration report (the JSON ``pkmcal calibrate`` writes beside the calibrated
        file), or the calibrated machine file (its report found beside it).
    output : Path
        The HTML file (self-contained: plots embedded); the JSON twin is written beside it
        (same name, ``.json``; none beside a device or pipe).

    Returns
    -------
    Summary
        One line: ``wrote OUTPUT (N kB, self-contained) and TWIN``.

    Raises
    ------
    InputError
        ``output`` ends in ``.json``; a machine file that names no report; a report that
        does not validate. Nothing is written then.
    """
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
            raise InputError(f"{path_text(result)}: names no calibration report beside it (is "
                             "it a calibrated file?); give the JSON report")
        source = found
    check_outputs([output] + ([twin] if twin else []), [result, source])
    doc = load_report(source)
    page = build_html(doc)
    if twin is not None:
        atomic_write_text(twin, json.dumps(doc, indent=2) + "\n")
    atomic_write_text(output, page)
    commit_outputs()
    summary = Summary()
    summary.line(f"wrote {path_text(output)} ({len(page) // 1024} kB, self-contained)"
                 + (f" and {path_text(twin)}" if twin else ""))
    return summary
