"""Implementations of the ``pkmcal`` commands (imported lazily by :mod:`pkmcal.cli`).

Every command validates its inputs and options first, computes, and writes its output files
only at the very end, atomically; problems are raised as :class:`~pkmcal.errors.InputError`
(exit code 2 in :func:`pkmcal.cli.main`).
"""

from __future__ import annotations

import math
from pathlib import Path

from ..errors import InputError
from ..io.atomic import is_stream
from ..paths import path_text
from ..units import format_number, format_um
from ..workflows.common import (  # noqa: F401  (the commands' shared steps, re-exported)
    check_outputs,
    commit_outputs,
    load_machine_arg,
)
from ..workflows.common import machine_inputs as _machine_inputs
from ..workflows.common import wrote as _wrote
from ..workflows.poses import (  # noqa: F401  (shared with compensate, planning)
    joint_columns,
    read_poses_of,
    refuse_outside_limits,
    refuse_unreachable,
)
from ._console import console, error, warning


def _table(*columns, title=None, justify=None, show_header=True):
    from rich.table import Table

    table = Table(title=title, title_justify="left", show_edge=False, pad_edge=False,
                  show_header=show_header)
    for i, col in enumerate(columns):
        table.add_column(col, justify=(justify or {}).get(i, "left"))
    return table


# --------------------------------------------------------------------------------------------
# calibrate (the calibration itself is pkmcal.calibration.calibrate)
# --------------------------------------------------------------------------------------------


def run_calibrate(machine_spec: str, data_path, output: Path, method: str | None,
                  noise, estimate_lc: bool | None, json_output: bool,
                  two_step: bool = False, robust: bool = False, pose_noise=None,
                  fix_frames: bool = False, report_dir: Path | None = None,
                  holdout: str | None = None, seed: int = 0,
                  parameters: str | None = None, extensions: str | None = None,
                  bed_tilt: str | None = None) -> int:
    from ..calibration.run import calibrate, noise_per_file_arg
    from ..errors import ConvergenceError

    paths = list(data_path) if isinstance(data_path, (list, tuple)) else [data_path]
    noise = noise_per_file_arg(noise if isinstance(noise, (list, tuple)) or noise is None
                               else [noise], paths)
    if isinstance(pose_noise, (list, tuple)):
        if len(pose_noise) > 1:
            raise InputError("--pose-noise: given more than once (one POSITION,ORIENTATION "
                             "pair holds the measured poses' noise)")
        pose_noise = pose_noise[0] if pose_noise else None
    data_path = paths[0] if len(paths) == 1 else paths
    if output.suffix.lower() == ".json":
        raise InputError(f"{path_text(output)}: "
                         "the calibrated machine is a YAML file; choose a name "
                         "ending in .yaml (the JSON report is written beside it)")
    report_path = output.with_suffix(".json")
    machine = load_machine_arg(machine_spec)
    outputs = [output] + ([] if is_stream(output) else [report_path])
    if report_dir is not None:
        if report_dir.exists() and not report_dir.is_dir():
            raise InputError(f"--report {report_dir}: a file, not a directory")
        outputs += [report_dir / "report.html", report_dir / "report.json"]
    check_outputs(outputs, paths + _machine_inputs(machine_spec),
                  [report_dir] if report_dir is not None else [])
    try:
        calibration = calibrate(machine, data_path, method=method, noise=noise,
                                pose_noise=pose_noise, estimate_lc=estimate_lc,
                                two_step=two_step, robust=robust, fix_frames=fix_frames,
                                holdout=holdout, seed=seed, parameters=parameters,
                                extensions=extensions, bed_tilt=bed_tilt)
    except ConvergenceError as exc:     # the fit ran and did not succeed: exit 1, nothing written
        error(str(exc))
        return 1
    from ..analysis.outcome import calibration_outcome

    # the answer (verdict, accuracy before and after, what changed, what next): the report's
    # first section, and the summary's first rows
    calibration.report["outcome"] = calibration_outcome(calibration, path_text(output))
    # staged first: a calibrated geometry that cannot be written is the one message (exit 2)
    json_text = calibration.write(output, report_dir)
    if json_output:
        for text in dict.fromkeys(calibration.warnings):      # each once
            warning(text)
        print(json_text, end="")
        return 0
    shown = data_path if len(paths) == 1 else ", ".join(map(str, paths))
    report_named = report_dir / "report.html" if report_dir is not None else report_path
    _print_answer(calibration.report, shown, machine)
    if calibration.kind == "joint":         # several files: no one instrument's summary
        _print_joint_calibration(calibration.report, calibration.params, shown, output,
                                 report_path, machine, report_named)
    else:
        from ..instruments.base import Instrument
        from ..instruments.registry import INSTRUMENTS

        inst = INSTRUMENTS.get(calibration.kind) or Instrument()
        _print_instrument_calibration(inst, calibration.report, calibration.params, shown,
                                      output, report_path, machine)
    # each warning once, after the summary (the summary's verdict row points to it)
    for text in dict.fromkeys(calibration.warnings):
        warning(text)
    return 0


def _print_answer(report, data_path, machine) -> None:
    """The answer first: verdict, accuracy before and after, what changed, the next
    commands (:func:`pkmcal.report.answer.answer_rows`)."""
    from ..report.answer import answer_rows

    outcome = report.get("outcome")
    if not outcome:
        return
    table = _table("", "", title=f"pkmcal calibrate: {path_text(machine.source)} with "
                                 f"{path_text(data_path)}", show_header=False)
    for label, text in answer_rows(outcome):
        table.add_row(label, text)
    console().print(table)


def _noise_rows(table, report) -> None:
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


#: lines of a long list (what each file adds) the console shows; the report has the rest
SHOWN_LINES = 4


def _print_joint_calibration(report, params, data_path, output, report_path, machine,
                             report_named=None):
    """Summary of a fit of several files: per file before/after, the joint identifiability,
    what each file adds (its first lines; the report names the rest)."""
    out = console()
    ident, conv = report["identifiability"], report["convergence"]
    table = _table("", "", title="details" if report.get("outcome") else
                   f"pkmcal calibrate: {path_text(machine.source)} with "
                   f"{path_text(data_path)}", show_header=False)
    table.add_row("measurement", f"{len(report['files'])} files fitted together, "
                  f"{report['measurements']} rows: one geometry, each file's own instrument "
                  "unknowns (named FILE:name)")
    if "parameter_set" in report:
        ps = report["parameter_set"]
        table.add_row("parameter set", f"{ps['name']} ({len(ps['free'])} free machine "
                      "parameters)" + (f"; {ps['note']}" if ps.get("note") else ""))
    for f in report["files"]:
        r = f["residuals"]
        before, after = format_um(r["before_rms_um"]), format_um(r["rms_um"])
        table.add_row(f["label"], f"{f['measurement']}, {f['measurements']} rows, noise "
                      f"{f['noise']}; RMS residual {before} -> {after} (before: the machine "
                      "file's model, this file's instrument fitted alone)")
        if "validation" in f:
            table.add_row("", f"held-out: {f['validation']['summary']}")
    _session_rows(table, report.get("sessions"))
    _identifiable_rows(table, ident)
    lines = report["contributions"]["summary"]
    for i, line in enumerate(lines[:SHOWN_LINES]):
        table.add_row("each file adds" if i == 0 else "", line)
    if len(lines) > SHOWN_LINES:
        table.add_row("", f"and {len(lines) - SHOWN_LINES} more lines (each parameter's "
                      "standard deviation from each file alone and jointly): see "
                      f"{path_text(report_named or report_path)}")
    _verdict_row(table, report)
    for section in report.get("instrument_sections", []):
        table.add_row("calibrated file", section)
    if report.get("bed_frame"):
        table.add_row("bed", report["bed_frame"])
    _noise_rows(table, report)
    table.add_row("convergence", f"{conv['message']} ({conv['iterations']} iterations)")
    out.print(table)
    _print_changes([p for p in params if ":" not in p["name"]])
    commit_outputs()
    out.print(_wrote(output, report_path), markup=False)


def _session_rows(table, sessions) -> None:
    """A printer's saved configs as sessions: how many, the files that repeated another's
    points, the meshes used or left out and why, each session's own endstop offsets."""
    if not sessions:
        return
    from rich.markup import escape  # Klipper's names: [bed_mesh default]

    if "sessions" in sessions:
        table.add_row("sessions", f"{sessions['sessions']} from {len(sessions['files'])} "
                      f"file(s); reference (its values are the export's): "
                      f"{path_text(Path(sessions['reference']).name)}")
    for dup, of in sessions.get("duplicates", {}).items():
        what = sessions.get("repeated", {}).get(dup) or [f"its points are {Path(of).name}'s"]
        table.add_row("", f"{path_text(Path(dup).name)}: {' and '.join(what)}: counted once")
    for i, (mesh, how) in enumerate(sessions.get("meshes", {}).items()):
        table.add_row("bed meshes" if i == 0 else "", escape(f"{path_text(mesh)}: {how}"))
    for i, (name, v) in enumerate(sessions.get("offsets", {}).items()):
        table.add_row("session offsets" if i == 0 else "", f"{path_text(name)}: " + ", ".join(
            f"q{j + 1} {o:+.4f} +- {s:.4f} {v['unit']}"
            for j, (o, s) in enumerate(zip(v["offsets"], v["std"], strict=True))))


def _positional(value: float, digits: int = 3, sign: bool = False) -> str:
    """``digits`` significant digits, never an exponent (a change of 2.78e-05 deg reads
    -0.0000278 beside values in degrees)."""
    value = float(value)
    if value != 0 and math.isfinite(value) and abs(value) < 1e-4:
        decimals = digits - 1 - math.floor(math.log10(abs(value)))
        return format(value, f"{'+' if sign else ''}.{decimals}f")
    return format_number(value, digits, sign=sign)


def _print_changes(params, limit: int = 10) -> None:
    """The largest parameter changes (scaled): lengths and angles, their changes and standard
    deviations in the machine file's unit (three significant digits)."""
    out = console()
    top = sorted((p for p in params if not p["fixed"]), key=lambda p: -p["scaled_change"])[:limit]
    changes = _table("parameter", "nominal", "identified", "change", "std", "",
                     title="largest parameter changes", justify={1: "right", 2: "right",
                                                                 3: "right", 4: "right"})
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
        std = _positional(p["std"] * f, 3) if p["std"] is not None else "fixed"
        changes.add_row(p["name"], f"{p['nominal']:.6f} {p['unit']}",
                        f"{p['identified']:.6f} {p['unit']}",
                        _positional(p["change"] * f, 3, sign=True), std, unit)
    out.print(changes)


def _identifiable_rows(table, ident, grouped: bool = False) -> None:
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


def _verdict_row(table, report) -> None:
    """The residual verdict the report states (``acceptance.residuals``, the one verdict of
    :func:`~pkmcal.estimation.acceptance.residual_verdict`), in its sentence."""
    from ..estimation.acceptance import report_verdict

    section = (report.get("acceptance") or {}).get("residuals")
    text = report_verdict(report).sentence()
    if section and section.get("note"):
        text += f"; {section['note']}"
    table.add_row("residual test", text)


def _shared_rows(table, name: str, report) -> None:
    """A row every calibration summary may have, from the report (see
    :meth:`~pkmcal.instruments.base.Instrument.calibration_summary`)."""
    if name == "residual test":
        _verdict_row(table, report)
    elif name in ("identifiable", "identifiable, grouped"):
        _identifiable_rows(table, report["identifiability"], name != "identifiable")
    elif name == "parameter set":
        if "parameter_set" in report:
            ps = report["parameter_set"]
            table.add_row("parameter set", f"{ps['name']} ({len(ps['free'])} free machine "
                          "parameters)" + (f"; {ps['note']}" if ps.get("note") else ""))
    elif name == "held-out":
        if "validation" in report:
            table.add_row("held-out", report["validation"]["summary"])
    elif name == "bed":
        if report.get("bed_frame"):
            table.add_row("bed", report["bed_frame"])
    elif name == "noise levels":
        _noise_rows(table, report)
    elif name == "convergence":
        conv = report["convergence"]
        table.add_row("convergence", f"{conv['message']} ({conv['iterations']} iterations)")
    else:
        raise ValueError(f"unknown summary row {name!r}")


def _print_instrument_calibration(inst, report, params, data_path, output, report_path,
                                  machine) -> None:
    """The summary of a calibration with one instrument: the rows it gives
    (:meth:`~pkmcal.instruments.base.Instrument.calibration_summary`), the parameter changes,
    its notes."""
    out = console()
    table = _table("", "", title="details" if report.get("outcome") else
                   f"pkmcal calibrate: {path_text(machine.source)} with "
                   f"{path_text(data_path)}", show_header=False)
    notes = []
    rows = list(inst.calibration_summary(report))
    if "residual test" not in rows:
        # every summary states the residual verdict: before the convergence, else last
        at = rows.index("convergence") if "convergence" in rows else len(rows)
        rows.insert(at, "residual test")
    for row in rows:
        if isinstance(row, str):
            _shared_rows(table, row, report)
        elif row[0] == "note":
            notes.append(row[1])
        else:
            table.add_row(*row)
    out.print(table)
    _print_changes(params)
    for note in notes:
        out.print(note, markup=False)
    commit_outputs()
    out.print(_wrote(output, report_path), markup=False)
