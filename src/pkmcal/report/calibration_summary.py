"""``pkmcal calibrate``'s summary for a person, built from the calibration report (the JSON the
command writes) as a :class:`~pkmcal.report.summary.Summary`: the answer first (verdict,
accuracy before and after, next commands), then the details (the rows the instrument gives,
:meth:`~pkmcal.instruments.base.Instrument.calibration_summary`, and the rows every summary may
share), the largest parameter changes and the instrument's notes.

Nothing here names an instrument: a calibration with one instrument shows the rows its
instrument lists (the registry's entry for the report's kind), a fit of several files the rows
of its ``files``; the instruments' typed sections (``report["sections"]``,
:mod:`pkmcal.estimation.sections`) are shown by the shared row ``"sections"``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

from ..estimation.sections import section_rows
from ..paths import path_text
from ..units import format_number, format_um
from .answer import answer_rows
from .summary import Summary, SummaryTable

__all__ = ["calibrate_summary", "SHOWN_LINES", "SHARED_ROWS"]

#: lines of a long list (what each file adds) the console shows; the report has the rest
SHOWN_LINES = 4


def calibrate_summary(report: Mapping, params: list, kind: str, machine_source: str,
                      data: str, report_path: Path, report_named: Path | None = None
                      ) -> Summary:
    """The summary of a calibration (without the "wrote" line, which the workflow adds once
    the files are written).

    Parameters
    ----------
    report : mapping
        The calibration report (:attr:`~pkmcal.calibration.run.Calibration.report`).
    params : list of dict
        The parameter table (:attr:`~pkmcal.calibration.run.Calibration.params`).
    kind : str
        The calibration's kind: an instrument's registry name, or ``"joint"`` (several files).
    machine_source : str
        The machine file (or ``default``), named in the title.
    data : str
        The data file(s), named in the title.
    report_path : Path
        The JSON report beside the calibrated file.
    report_named : Path, optional
        Where the reader finds the rest of a long list (the HTML report when written).

    Returns
    -------
    Summary
        The tables and lines, in order.
    """
    summary = Summary()
    title = f"pkmcal calibrate: {path_text(machine_source)} with {path_text(data)}"
    outcome = report.get("outcome")
    if outcome:
        table = summary.pairs(title)
        for label, text in answer_rows(outcome):
            table.add_row(label, text)
    details = summary.pairs("details" if outcome else title)
    if kind == "joint":         # several files: no one instrument's summary
        _joint_rows(details, report, report_path, report_named)
        _changes(summary, [p for p in params if ":" not in p["name"]])
        return summary
    from ..instruments.base import Instrument
    from ..instruments.registry import INSTRUMENTS

    inst = INSTRUMENTS.get(kind) or Instrument()
    notes = []
    rows = list(inst.calibration_summary(report))
    if "residual test" not in rows:
        # every summary states the residual verdict: before the convergence, else last
        at = rows.index("convergence") if "convergence" in rows else len(rows)
        rows.insert(at, "residual test")
    for row in rows:
        if isinstance(row, str):
            shared_row(details, row, report)
        elif row[0] == "note":
            notes.append(row[1])
        else:
            details.add_row(*row)
    _changes(summary, params)
    for note in notes:
        summary.line(note)
    return summary


def _joint_rows(table: SummaryTable, report: Mapping, report_path: Path,
                report_named: Path | None) -> None:
    """A fit of several files: per file before/after, the joint identifiability, what each
    file adds (its first lines; the report names the rest)."""
    table.add_row("measurement", f"{len(report['files'])} files fitted together, "
                  f"{report['measurements']} rows: one geometry, each file's own instrument "
                  "unknowns (named FILE:name)")
    shared_row(table, "parameter set", report)
    for f in report["files"]:
        r = f["residuals"]
        before, after = format_um(r["before_rms_um"]), format_um(r["rms_um"])
        table.add_row(f["label"], f"{f['measurement']}, {f['measurements']} rows, noise "
                      f"{f['noise']}; RMS residual {before} -> {after} (before: the machine "
                      "file's model, this file's instrument fitted alone)")
        if "validation" in f:
            table.add_row("", f"held-out: {f['validation']['summary']}")
    _session_rows(table, report.get("sessions"))
    _identifiable_rows(table, report["identifiability"])
    lines = report["contributions"]["summary"]
    for i, line in enumerate(lines[:SHOWN_LINES]):
        table.add_row("each file adds" if i == 0 else "", line)
    if len(lines) > SHOWN_LINES:
        table.add_row("", f"and {len(lines) - SHOWN_LINES} more lines (each parameter's "
                      "standard deviation from each file alone and jointly): see "
                      f"{path_text(report_named or report_path)}")
    shared_row(table, "residual test", report)
    for section in report.get("instrument_sections", []):
        table.add_row("calibrated file", section)
    shared_row(table, "bed", report)
    shared_row(table, "sections", report)
    shared_row(table, "noise levels", report)
    shared_row(table, "convergence", report)


def _session_rows(table: SummaryTable, sessions) -> None:
    """A printer's saved configs as sessions: how many, the files that repeated another's
    points, the meshes used or left out and why, each session's own endstop offsets."""
    if not sessions:
        return
    if "sessions" in sessions:
        table.add_row("sessions", f"{sessions['sessions']} from {len(sessions['files'])} "
                      f"file(s); reference (its values are the export's): "
                      f"{path_text(Path(sessions['reference']).name)}")
    for dup, of in sessions.get("duplicates", {}).items():
        what = sessions.get("repeated", {}).get(dup) or [f"its points are {Path(of).name}'s"]
        table.add_row("", f"{path_text(Path(dup).name)}: {' and '.join(what)}: counted once")
    for i, (mesh, how) in enumerate(sessions.get("meshes", {}).items()):
        table.add_row("bed meshes" if i == 0 else "", f"{path_text(mesh)}: {how}")
    for i, (name, v) in enumerate(sessions.get("offsets", {}).items()):
        table.add_row("session offsets" if i == 0 else "", f"{path_text(name)}: " + ", ".join(
            f"q{j + 1} {o:+.4f} +- {s:.4f} {v['unit']}"
            for j, (o, s) in enumerate(zip(v["offsets"], v["std"], strict=True))))


def positional(value: float, digits: int = 3, sign: bool = False) -> str:
    """``digits`` significant digits, never an exponent (a change of 2.78e-05 deg reads
    -0.0000278 beside values in degrees)."""
    value = float(value)
    if value != 0 and math.isfinite(value) and abs(value) < 1e-4:
        decimals = digits - 1 - math.floor(math.log10(abs(value)))
        return format(value, f"{'+' if sign else ''}.{decimals}f")
    return format_number(value, digits, sign=sign)


def _changes(summary: Summary, params: list, limit: int = 10) -> None:
    """The largest parameter changes (scaled): lengths and angles, their changes and standard
    deviations in the machine file's unit (three significant digits)."""
    top = sorted((p for p in params if not p["fixed"]), key=lambda p: -p["scaled_change"])[:limit]
    changes = summary.table("parameter", "nominal", "identified", "change", "std", "",
                            title="largest parameter changes",
                            justify={1: "right", 2: "right", 3: "right", 4: "right"})
    for p in top:
        if p["kind"] in ("length", "angle"):
            # the value's own unit (the machine file's) for the change and its std: one unit
            # per quantity, as the nominal and identified columns
            unit, f = p["unit"], 1.0
        elif p["kind"] == "slope":                  # a plane's slope, mm/m: absolute change
            unit, f = "um/m", 1e3
        else:                                       # a gain: relative change
            unit = "ppm" if p["nominal"] else p["unit"]    # from 0 (a curvature): its unit
            f = 1e6 / abs(p["nominal"]) if p["nominal"] else 1.0
        std = positional(p["std"] * f, 3) if p["std"] is not None else "fixed"
        changes.add_row(p["name"], f"{p['nominal']:.6f} {p['unit']}",
                        f"{p['identified']:.6f} {p['unit']}",
                        positional(p["change"] * f, 3, sign=True), std, unit)


def _identifiable_rows(table: SummaryTable, ident: Mapping, grouped: bool = False) -> None:
    """How many parameter directions the data identify, and which they do not (``grouped``:
    one line per description)."""
    table.add_row("identifiable", f"{ident['identifiable']} of {ident['free_parameters']} free "
                  "parameter directions" + (f", of which {len(ident['weakly_identifiable'])} "
                                            "weakly" if ident["weakly_identifiable"] else ""))
    if grouped:
        groups: dict[str, list[str]] = {}
        for d in ident["unidentifiable"]:
            groups.setdefault(d["description"], []).append(f"{d['dimension']} x {d['name']}")
        for description, names in groups.items():
            table.add_row("not identifiable", f"{', '.join(names)}: {description}")
    else:
        for d in ident["unidentifiable"]:
            table.add_row("not identifiable", f"{d['dimension']} x {d['name']}: "
                          f"{d['description']}")
    for d in ident["weakly_identifiable"]:
        table.add_row("weakly identifiable", f"{d['name']}: {d['description']}")


def _noise_rows(table: SummaryTable, report: Mapping) -> None:
    """The noise levels the fit used (estimated from the residuals, or assumed / given) and
    the rows the outlier test names."""
    from ..estimation.variance import NoiseEstimate

    levels = report.get("noise_model")
    if levels is not None:
        title = ("noise (estimated)" if levels["estimated"] else "noise (held)")
        for i, line in enumerate(NoiseEstimate.lines_of(levels)):
            table.add_row(title if i == 0 else "", line)
    outliers = report.get("outliers")
    if outliers and outliers["flagged"]:
        # how many; the warnings name them (said once)
        left = sum(bool(f["left_out"]) for f in outliers["flagged"])
        table.add_row("outlier rows", f"{len(outliers['flagged'])}"
                      + (f", {left} left out" if left else "") + " (the warnings name them)")


def _verdict_row(table: SummaryTable, report: Mapping) -> None:
    """The residual verdict the report states (``acceptance.residuals``, the one verdict of
    :func:`~pkmcal.estimation.acceptance.residual_verdict`), in its sentence."""
    from ..estimation.acceptance import report_verdict

    section = (report.get("acceptance") or {}).get("residuals")
    text = report_verdict(report).sentence()
    if section and section.get("note"):
        text += f"; {section['note']}"
    table.add_row("residual test", text)


def _parameter_set_row(table: SummaryTable, report: Mapping) -> None:
    if "parameter_set" in report:
        ps = report["parameter_set"]
        table.add_row("parameter set", f"{ps['name']} ({len(ps['free'])} free machine "
                      "parameters)" + (f"; {ps['note']}" if ps.get("note") else ""))


def _held_out_row(table: SummaryTable, report: Mapping) -> None:
    if "validation" in report:
        table.add_row("held-out", report["validation"]["summary"])


def _bed_row(table: SummaryTable, report: Mapping) -> None:
    if report.get("bed_frame"):
        table.add_row("bed", report["bed_frame"])


def _convergence_row(table: SummaryTable, report: Mapping) -> None:
    conv = report["convergence"]
    table.add_row("convergence", f"{conv['message']} ({conv['iterations']} iterations)")


def _section_rows(table: SummaryTable, report: Mapping) -> None:
    for label, text in section_rows(report):
        table.add_row(label, text)


#: the rows every calibration summary may have, by name (see
#: :meth:`~pkmcal.instruments.base.Instrument.calibration_summary`): name -> fill(table, report)
SHARED_ROWS = {
    "residual test": _verdict_row,
    "identifiable": lambda table, report: _identifiable_rows(table, report["identifiability"]),
    "identifiable, grouped": lambda table, report: _identifiable_rows(
        table, report["identifiability"], grouped=True),
    "parameter set": _parameter_set_row,
    "held-out": _held_out_row,
    "bed": _bed_row,
    "noise levels": _noise_rows,
    "convergence": _convergence_row,
    "sections": _section_rows,
}


def shared_row(table: SummaryTable, name: str, report: Mapping) -> None:
    """Add the shared row ``name`` (a key of :data:`SHARED_ROWS`) from the report."""
    try:
        fill = SHARED_ROWS[name]
    except KeyError:
        raise ValueError(f"unknown summary row {name!r}") from None
    fill(table, report)
