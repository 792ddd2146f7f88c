"""Implementations of the ``pkmcal`` commands (imported lazily by :mod:`pkmcal.cli`).

Every command validates its inputs and options first, computes, and writes its output files
only at the very end, atomically; problems are raised as :class:`~pkmcal.errors.InputError`
(exit code 2 in :func:`pkmcal.cli.main`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..calibration.run import file_units as _units
from ..calibration.run import json_safe as _finite_or_none
from ..calibration.run import rows_text as _rows_text
from ..errors import InputError
from ..instruments.tracker import tracker_noise_arg
from ..io import (
    atomic_write_text,
    joint_quantity,
    machine_to_text,
    parse_machine,
    read_joints,
    read_poses,
    read_positions,
    read_readings,
    read_table,
    write_poses,
    write_positions,
    write_table,
    write_tracker,
)
from ..io.atomic import is_stream
from ..io.machine_file import DEFAULT_UNITS
from ..limits import MAX_MEASUREMENTS
from ..machines.deviations import deviations as _deviations
from ..paths import path_text
from ..plausibility import check_option_scale
from ..units import (
    format_number,
    format_quantity,
    format_um,
    parse_quantity,
)
from ..workflows.common import (  # noqa: F401  (the commands' shared steps, re-exported)
    check_outputs,
    commit_outputs,
    load_machine_arg,
)
from ..workflows.common import machine_inputs as _machine_inputs
from ..workflows.common import wrote as _wrote
from ._console import console, error, warning


def _table(*columns, title=None, justify=None, show_header=True):
    from rich.table import Table

    table = Table(title=title, title_justify="left", show_edge=False, pad_edge=False,
                  show_header=show_header)
    for i, col in enumerate(columns):
        table.add_column(col, justify=(justify or {}).get(i, "left"))
    return table


# --------------------------------------------------------------------------------------------
# demo, bench
# --------------------------------------------------------------------------------------------


def _optional_module(name: str, what: str):
    import importlib

    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name == name:
            error(f"{what} is not available in this installation (module {name} is missing)")
            return None
        raise


def run_demo(outdir: Path) -> None:
    module = _optional_module("pkmcal.demo", "the demo")
    if module is None:
        raise SystemExit(1)
    check_outputs([], [], [outdir])
    from ._console import progress_tasks

    with progress_tasks() as new:
        result = module.run_demo(outdir, progress=new)
    commit_outputs()
    out = console()
    for i, line in enumerate(getattr(result, "settings", []) or []):
        out.print(f"{'settings: ' if i == 0 else '          '}{line}", markup=False)
    table = _table("quantity", "before calibration", "after calibration",
                   title="pkmcal demo: calibration (embedded Hexa Slide and Delta)")
    for row in result.rows:
        table.add_row(*map(str, row))
    out.print(table)
    for note in getattr(result, "notes", []) or []:
        out.print(f"note: {note}", markup=False)
    files = list(getattr(result, "files", []) or [])
    if files:
        out.print("files:")
        for f in files:
            out.print(f"  {path_text(f)}", markup=False)


def run_bench(json_output: bool) -> int:
    module = _optional_module("pkmcal.bench", "the benchmark suite")
    if module is None:
        return 1
    from ._console import progress_tasks

    with progress_tasks() as new_task:
        bar = {}

        def progress(done: int, total: int, description: str | None):
            if not bar:
                bar["advance"], bar["done"] = new_task("bench", total), 0
            bar["advance"](done - bar["done"], f"bench: {description}" if description else None)
            bar["done"] = done

        results = list(module.run_all(progress=progress))
    ok = all(bool(r.get("ok")) for r in results)
    if json_output:
        print(json.dumps(_finite_or_none(results), indent=2))
        return 0 if ok else 1
    table = _table("benchmark", "value", "unit", "target", "ok", title="pkmcal bench",
                   justify={1: "right"})
    for r in results:
        value = r.get("value")
        shown = f"{value:.4g}" if isinstance(value, (int, float)) else str(value)
        table.add_row(str(r.get("name")), shown, str(r.get("unit", "")),
                      str(r.get("target", "")),
                      "[green]yes[/green]" if r.get("ok") else "[red]NO[/red]")
    console().print(table)
    return 0 if ok else 1


# --------------------------------------------------------------------------------------------
# simulate
# --------------------------------------------------------------------------------------------

def _true_machine(machine, deviations: str, rng):
    """The simulated true machine: ``machine`` plus ``--deviations``, named as such."""
    true = machine.with_parameters(machine.u + _deviations(machine, deviations, rng))
    true.name = f"simulated true machine ({deviations} deviations) of {machine.name or 'MACHINE'}"
    return true


def parse_grid(text: str) -> tuple[int, int, int]:
    """``"3x3x3"`` -> ``(3, 3, 3)``; :class:`InputError` naming ``--grid`` otherwise."""
    parts = str(text).lower().replace("*", "x").split("x")
    try:
        shape = tuple(int(p) for p in parts)
    except ValueError:
        shape = ()
    if len(shape) != 3 or min(shape) < 1:
        raise InputError(f"--grid: expected NXxNYxNZ with positive whole numbers (e.g. 3x3x3), "
                         f"got {text!r}")
    count = math.prod(shape)
    if count > MAX_MEASUREMENTS:
        raise InputError(f"--grid {text}: {count} points, more than {MAX_MEASUREMENTS} "
                         "(pkmcal.limits.MAX_MEASUREMENTS)")
    if count < 4:
        raise InputError(f"--grid {text}: {count} point(s); a tracker calibration needs at "
                         "least 4 points that are not on one line (e.g. 3x3x3)")
    return shape


def _zero(text: str) -> bool:
    return str(text).strip() in ("0", "0um", "0mm", "0m")


def run_simulate(machine_spec: str, output: Path, scenario: str | None, poses: int | None,
                 noise: str | None, lc_error: str, seed: int, deviations: str | None,
                 truth: Path | None, grid: str | None = None, outliers: int = 0,
                 pose_noise: str | None = None, targets: int | None = None,
                 setups: int | None = None, radius: str | None = None,
                 circles: bool = False) -> None:
    """``pkmcal simulate``: any instrument of the registry on any machine it applies to."""
    from ..instruments.registry import INSTRUMENTS, instrument
    from ..planning import scenario_for

    machine = load_machine_arg(machine_spec)
    kind = machine.kind
    requested = scenario
    try:
        scenario = scenario_for(machine, scenario)      # the reason when it does not apply
    except InputError as exc:
        usable = [name for name, inst in INSTRUMENTS.items() if inst.applies(machine) is None]
        raise InputError(f"{exc}; this {kind} can simulate: {', '.join(usable)}") from None
    deviations = deviations or machine.DEFAULT_DEVIATIONS
    check_outputs([output] + ([truth] if truth else []), _machine_inputs(machine_spec))
    flag = f"--scenario {requested or scenario}"
    inst = instrument(scenario)
    grid_path = inst.simulates_grid(machine, targets)
    grid_where = {"--grid": "a tracker on a platform that only translates (its grid; on a "
                            "platform that rotates use --poses)",
                  "--outliers": "a tracker on a platform that only translates (its grid)"}
    given = {"--pose-noise": pose_noise is not None, "--lc-error": not _zero(lc_error),
             "--grid": grid is not None, "--outliers": bool(outliers),
             "--targets": targets is not None, "--setups": setups is not None,
             "--radius": radius is not None, "--circles": bool(circles)}
    for option, is_given in given.items():
        applies = grid_path if option in grid_where else option in inst.simulate_flags
        if is_given and not applies:
            where = grid_where.get(option) or next(
                other.simulate_flags[option] for other in INSTRUMENTS.values()
                if option in other.simulate_flags)
            raise InputError(f"{option}: does not apply to {flag} on this {kind}; it applies "
                             f"to {where}")
    if grid_path:
        if poses is not None:
            raise InputError(f"--poses: a tracker on this {kind} (a platform that only "
                             "translates) measures a grid (--grid NXxNYxNZ, seed 001)")
        _simulate_tracker(machine, output, noise, seed, deviations, truth,
                          parse_grid(grid or "3x3x3"), outliers)
        return
    _simulate_scenario(machine, scenario, output, poses, noise, pose_noise, lc_error, seed,
                       deviations, truth, targets, setups, radius, circles)


def _simulate_scenario(machine, scenario: str, output: Path, poses: int | None,
                       noise: str | None, pose_noise: str | None, lc_error: str, seed: int,
                       deviations: str, truth: Path | None, targets: int | None,
                       setups: int | None, radius: str | None, circles: bool) -> None:
    """Every scenario but the translating tracker grid, through
    :func:`pkmcal.instruments.simulate.simulate_scenario`: the instrument reads its options
    (:meth:`~pkmcal.instruments.base.Instrument.simulate_arguments`), simulates itself and
    words its truth."""
    from ..instruments.registry import instrument
    from ..instruments.simulate import simulate_scenario
    from ..io import write_measurements

    inst = instrument(scenario)
    model, noise_words, options = inst.simulate_arguments(
        machine, noise, pose_noise=pose_noise, lc_error=lc_error, targets=targets,
        setups=setups, radius=radius, circles=circles)
    rng = np.random.default_rng(seed)
    try:
        data, true, truth_info = simulate_scenario(machine, scenario, poses, model, rng,
                                                   deviations=deviations, **options)
    except InputError as exc:
        raise InputError(f"pkmcal simulate {scenario} (--deviations {deviations}, seed "
                         f"{seed}): {exc}") from None
    true.name = (f"simulated true machine ({deviations} deviations) of "
                 f"{machine.name or 'MACHINE'}")
    units = _units(machine)
    truth_text = None
    if truth is not None:
        truth_text = machine_to_text(true, units)
        parse_machine(truth_text, str(truth))
    # outputs, at the very end
    write_measurements(inst, output, data, machine, units["length"])
    if truth is not None:
        atomic_write_text(truth, truth_text)
    out = console()
    table = _table("", "", title="pkmcal simulate", show_header=False)
    table.add_row("machine", f"{path_text(machine.source)} ({machine.kind})")
    table.add_row("scenario", f"{scenario}, {truth_info['poses']}")
    table.add_row("deviations", deviations + (f" (seed {seed})" if deviations == "random"
                                              else ""))
    table.add_row("noise", f"{noise_words} (seed {seed})")
    for name, value in truth_info["rows"]:
        table.add_row(name, value)
    out.print(table)
    commit_outputs()
    out.print(f"wrote {path_text(output)}" + (f" and {path_text(truth)}" if truth else ""),
              markup=False)


def _simulate_tracker(machine, output: Path, noise: str | None, seed: int, deviations: str,
                      truth: Path | None, shape: tuple[int, int, int], outliers: int) -> None:
    from ..instruments.tracker import (
        TRACKER_GRID_SPACING,
        default_tracker_pose,
        grid_points,
        simulate_tracker,
    )

    noise_model, noise_text = tracker_noise_arg(noise, allow_none=True, machine=machine)
    n_points = int(np.prod(shape))
    if outliers > n_points:
        raise InputError(f"--outliers: {outliers} outliers among {n_points} grid points")
    rng = np.random.default_rng(seed)
    true = _true_machine(machine, deviations, rng)
    pose = getattr(machine, "base_from_tracker", None)
    pose_from = "the machine file's tracker section"
    if pose is None:
        pose, pose_from = default_tracker_pose(), "default"
    true.base_from_tracker = pose
    centre = machine.home[0]
    targets = grid_points(centre, TRACKER_GRID_SPACING, shape)
    bad = np.flatnonzero(~np.all(np.isfinite(machine.ik(targets)), axis=-1))
    if bad.size:
        raise InputError(f"--grid {'x'.join(map(str, shape))}: {bad.size} grid point(s) "
                         f"outside the workspace of {path_text(machine.source)} (e.g. "
                         f"{_mm(targets[bad[0]])} mm); use a smaller grid or another home")
    refuse_unreachable(machine, machine.reachability(targets), f"--grid "
                       f"{'x'.join(map(str, shape))}: {{n}} grid point(s) (rows of the data "
                       f"file) cannot be reached by {machine.source}",
                       np.arange(2, n_points + 2), (targets, None))
    refuse_outside_limits(machine, machine.ik(targets), np.arange(2, n_points + 2),
                          f"--grid {'x'.join(map(str, shape))}: {{n}} grid point(s) (rows of "
                          "the data file)")
    try:
        data = simulate_tracker(true, machine, targets, pose, noise_model, outliers=outliers,
                                outlier_size=1e-3, rng=rng)
    except InputError as exc:
        raise InputError(f"--deviations {deviations} (seed {seed}): {exc}; use a smaller grid "
                         "or another seed") from None
    units = _units(machine)
    truth_text = None
    if truth is not None:
        truth_text = machine_to_text(true, units)
        parse_machine(truth_text, str(truth))
    # outputs, at the very end
    write_tracker(output, data.q, data.m, joint_unit=units["angle"],
                  length_unit=units["length"])
    if truth is not None:
        atomic_write_text(truth, truth_text)
    R, t = pose
    out = console()
    table = _table("", "", title="pkmcal simulate", show_header=False)
    table.add_row("machine", f"{path_text(machine.source)} ({machine.kind})")
    dx, dy, dz = (v * 1e3 for v in TRACKER_GRID_SPACING)
    table.add_row("scenario", f"tracker, {'x'.join(map(str, shape))} grid (dx = {dx:g}, dy = "
                  f"{dy:g}, dz = {dz:g} mm) centred at home {_mm(centre)} mm: {n_points} points")
    table.add_row("deviations", deviations + (f" (seed {seed})" if deviations == "random"
                                              else ""))
    table.add_row("tracker noise", f"{noise_text} (seed {seed})")
    table.add_row("tracker pose", f"{pose_from}: at {_mm(t)} mm in the base frame, rotated "
                  f"{np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))):.4g} deg "
                  "relative to it")
    if outliers:
        rows = data.rows[data.outliers] + 1          # file lines: header = 1
        table.add_row("outliers", f"rows {_rows_text(rows, limit=50)} moved by 1 mm")
    out.print(table)
    commit_outputs()
    out.print(f"wrote {path_text(output)}" + (f" and {path_text(truth)}" if truth else ""),
              markup=False)


def _mm(v) -> str:
    return "(" + ", ".join(f"{x * 1e3:.6g}" for x in np.asarray(v, float)) + ")"


# --------------------------------------------------------------------------------------------
# calibrate (the calibration itself is pkmcal.calibration.calibrate)
# --------------------------------------------------------------------------------------------


def run_calibrate(machine_spec: str, data_path, output: Path, noise, json_output: bool,
                  robust: bool = False, report_dir: Path | None = None,
                  holdout: str | None = None, seed: int = 0, parameters: str | None = None,
                  options: dict | None = None) -> int:
    from ..calibration.run import calibrate, noise_per_file_arg
    from ..errors import ConvergenceError

    paths = list(data_path) if isinstance(data_path, (list, tuple)) else [data_path]
    noise = noise_per_file_arg(noise if isinstance(noise, (list, tuple)) or noise is None
                               else [noise], paths)
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
        calibration = calibrate(machine, data_path, noise=noise, robust=robust,
                                holdout=holdout, seed=seed, parameters=parameters,
                                options=options)
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


def run_check(machine_spec: str, data_paths, noise, output: Path | None) -> int:
    """``pkmcal check``: the machine scored on other data (:func:`pkmcal.calibration.check`)."""
    from ..calibration.check import check
    from ..calibration.run import json_safe, noise_per_file_arg, report_json

    paths = list(data_paths)
    noise = noise_per_file_arg(noise, paths) if noise else None
    if isinstance(noise, str):
        raise InputError("--noise: give FILE=VALUE per file (e.g. --noise probe.csv=20um)")
    machine = load_machine_arg(machine_spec)
    if output is not None:
        check_outputs([output], paths + _machine_inputs(machine_spec))
    result = check(machine, paths, noise=noise)
    if output is not None:
        text = report_json(json_safe(result.report))
        atomic_write_text(output, text if text.endswith("\n") else text + "\n")
        commit_outputs()
    out = console()
    table = _table("", "", title=f"pkmcal check: {path_text(machine_spec)} on "
                                 f"{', '.join(path_text(p) for p in paths)}", show_header=False)
    for f in result.report["files"]:
        table.add_row(f["label"], f"{f['measurement']}, {f['rows']} rows: RMS "
                      f"{format_um(f['rms_um'])}, max {format_um(f['max_um'])} (row "
                      f"{f['max_row']}); {f['noise_ratio']:.3g}x the noise ({f['noise']}): "
                      + ("explained" if f["explained"] else
                         f"not explained (at most {f['noise_ratio_limit']:.3g}x)"))
    table.add_row("verdict", result.report["verdict"]["text"])
    table.add_row("free", result.report["offsets_are"])
    for line in result.lines:
        if line.startswith("session "):
            table.add_row("drift", line)
    out.print(table)
    if output is not None:
        out.print(f"wrote {path_text(output)}", markup=False)
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


# --------------------------------------------------------------------------------------------
# fk, ik
# --------------------------------------------------------------------------------------------


def run_fk(machine_spec: str, joints: Path, output: Path, frame: str = "base",
           instrument: str | None = None) -> None:
    if frame == "instrument":
        _fk_instrument(machine_spec, joints, output, instrument)
        return
    if instrument is not None:
        raise InputError(f"--instrument {instrument}: only with --frame instrument (the "
                         "instrument's predicted measurements); --frame base writes poses")
    machine = load_machine_arg(machine_spec)
    check_outputs([output], [joints] + _machine_inputs(machine_spec))
    if getattr(machine, "reading_unit", None) is not None:   # readings in their own unit
        q, rows = read_readings(joints, machine)
    else:
        q, rows, _ = read_joints(joints, machine.n_joints, joint_quantity(machine), machine)
    result = machine.fk(q)
    result.raise_if_failed(what=f"{joints}: forward kinematics", rows=rows)
    units = _units(machine)
    if not machine.rotates:
        write_positions(output, result.P, units["length"])
        commit_outputs()
        console().print(f"{len(q)} position(s) of the platform point, base frame, written to "
                        f"{path_text(output)} ({units['length']})", markup=False)
        return
    write_poses(output, result.P, result.R, units["length"], units["angle"])
    commit_outputs()
    console().print(f"{len(q)} pose(s) written to {path_text(output)} ({units['length']}, "
                    f"{units['angle']})", markup=False)


def group_numbers(path: Path, extra: dict, rows, column: str):
    """0-based groups of an optional integer column (``target``, ``setup``: 1, 2, ...) of a
    file whose rows are predicted or commanded, not fitted: any of the numbers may be absent;
    None without the column (:func:`~pkmcal.io.read_groups` with gaps)."""
    from ..io import read_groups

    return read_groups(path, extra, rows, column, gaps=True)


def _fk_instrument(machine_spec: str, joints: Path, output: Path,
                   instrument: str | None) -> None:
    """``pkmcal fk --frame instrument``: what the calibration's instrument measures for the
    readings (:func:`~pkmcal.instruments.predict_instrument`), in the machine file's length
    unit: ``mx, my, mz`` (+ ``target``), ``x, y, z, qx, qy, qz, qw`` or ``d`` (+ ``setup``)."""
    from ..instruments import choose_instrument, predict_instrument
    from ..instruments.registry import instrument as entry
    from ..io.csv_io import machine_readings

    machine = load_machine_arg(machine_spec)
    name = choose_instrument(machine, instrument, option="--instrument")
    inst = entry(name)
    check_outputs([output], [joints] + _machine_inputs(machine_spec))
    q, rows, extra, _ = machine_readings(joints, machine)
    column = inst.group_column
    group = group_numbers(joints, extra, rows, column) if column else None
    pred = predict_instrument(machine, q, name, group, rows=rows, source=str(joints))
    pred.fk.raise_if_failed(what=f"{joints}: forward kinematics", rows=rows)
    unit = _units(machine)["length"]
    columns = inst.prediction_columns(pred, unit)
    if group is not None:
        columns[column] = (group + 1).tolist()
    write_table(output, list(columns), [list(v) for v in columns.values()])
    commit_outputs()
    console().print(f"{len(q)} {inst.prediction_words} written to {path_text(output)} ({unit})",
                    markup=False)


def read_poses_of(path: Path, machine):
    """Poses ``(P, R, rows)`` of a file for ``machine``: x, y, z and an orientation (other
    columns ignored); x, y, z only (R = I) for a translation-only platform."""
    if not machine.rotates:
        P, rows = read_positions(path)
        return P, np.broadcast_to(np.eye(3), (len(P), 3, 3)), rows
    return read_poses(path)


def joint_columns(machine, q, units) -> dict:
    """``q1_<unit> ...`` columns of joint values (K, n) in the file's units: the machine
    file's length or angle unit, a Stewart's reading unit."""
    unit, f = machine.joint_unit(units)
    return {f"q{j + 1}_{unit}": (q[:, j] / f).tolist() for j in range(q.shape[1])}


def refuse_unreachable(machine, reach, what: str, rows=None, shown=None,
                       sampled: str = "") -> None:
    """Refuse poses the machine cannot take (:meth:`~pkmcal.machines.Machine.reachability`):
    one line, ``what`` first (``{n}``: the count of such poses; e.g. ``"t.csv: {n}
    target(s) cannot be reached by the calibrated machine"``), then the rows (or, for
    ``sampled`` poses of a box, how many of them), the first such pose as the user gave it
    (``shown``: ``(P, R)``, R may be None) and why, in the machine file's units. Poses outside
    the file's ``joint_limits`` alone are left to :func:`refuse_outside_limits`."""
    bad = np.flatnonzero(~reach.ok & ~reach.limits_only)
    if not bad.size:
        return
    P, R = shown
    k = int(bad[0])
    pose = machine.pose_text(P[k], None if R is None else R[k])
    if rows is not None:
        rows = np.asarray(rows)
        where = (f", row(s) {_rows_text(rows[bad])}: row {rows[k]} at {pose}: "
                 f"{reach.reasons[k]}")
    else:
        where = f" ({bad.size} of {sampled}), e.g. at {pose}: {reach.reasons[k]}"
    raise InputError(what.format(n=bad.size) + where)


def refuse_outside_limits(machine, q, rows, what: str) -> None:
    """Refuse joint values ``q`` (K, n) outside the machine file's ``joint_limits``, naming
    the rows and joints; ``what`` starts the message (``{n}``: the count of such rows)."""
    outside = ~machine.within_limits(q) & np.all(np.isfinite(q), axis=-1)
    if outside.any():
        source = getattr(machine, "source", None) or "the machine file"
        raise InputError(f"{what.format(n=int(outside.sum()))} need joint values outside the "
                         f"joint limits of {path_text(source)} ({machine.joint_limits_text()}): "
                         f"{machine.limit_violation_text(q[outside], np.asarray(rows)[outside])}")


def run_ik(machine_spec: str, poses: Path, output: Path) -> None:
    machine = load_machine_arg(machine_spec)
    check_outputs([output], [poses] + _machine_inputs(machine_spec))
    P, R, rows = read_poses_of(poses, machine)
    q = machine.ik(P, R)
    bad = ~np.all(np.isfinite(q), axis=1)
    what = machine.chain_word
    if bad.any():
        chains = np.flatnonzero((~np.isfinite(q[bad])).any(axis=0)) + 1
        raise InputError(f"{poses}: {int(bad.sum())} pose(s) cannot be reached by the machine "
                         f"(no real inverse kinematics, {what}(s) "
                         f"{', '.join(map(str, chains))}), row(s) {_rows_text(rows[bad])}")
    off = ~machine.working_mode(P, R)
    if off.any():
        raise InputError(f"{poses}: {int(off.sum())} pose(s) outside the machine's working "
                         f"mode (farther than {machine.MAX_REACH:g}x the machine's size from "
                         "home, or beyond a singularity, e.g. mirrored through the base), "
                         f"row(s) {_rows_text(rows[off])}")
    if not machine.rotates:
        # the closed-form FK takes the working assembly mode (platform below the base): a
        # position the arms reach only on the other mode cannot be commanded back
        back = machine.fk(q).P
        off = ~(np.linalg.norm(back - P, axis=1) <= 1e-9 + 1e-9 * np.linalg.norm(P, axis=1))
        if off.any():
            raise InputError(f"{poses}: {int(off.sum())} position(s) outside the working "
                             f"assembly mode (the platform must hang below the base), row(s) "
                             f"{_rows_text(rows[off])}")
    refuse_unreachable(machine, machine.reachability(P, R), f"{poses}: {{n}} pose(s) cannot "
                       "be reached by the machine", rows, (P, R))
    refuse_outside_limits(machine, q, rows, f"{poses}: {{n}} pose(s)")
    columns = joint_columns(machine, q, _units(machine))
    write_table(output, list(columns), list(columns.values()))
    unit = next(iter(columns)).split("_", 1)[1]
    commit_outputs()
    console().print(f"{len(q)} {machine.joint_vector_word} vector(s) written to "
                    f"{path_text(output)} "
                    f"({unit})", markup=False)


# --------------------------------------------------------------------------------------------
# errors (seed 003: joint clearance under loads along a trajectory)
# --------------------------------------------------------------------------------------------

#: the plots of ``pkmcal errors --plot DIR`` (DIR/<name>.png)
ERRORS_PLOTS = ("link_forces", "pose_errors", "error_map")


def _errors_machine(spec: str):
    """MACHINE of ``pkmcal errors``: a stewart machine file, or ``cubic`` (seed 003 device)."""
    if spec == "cubic":
        from ..machines import cubic_6upu

        machine = cubic_6upu()
        machine.file_units = dict(DEFAULT_UNITS)
        machine.source = "cubic"
        return machine
    machine = load_machine_arg(spec)
    if machine.n_joints != 6 or machine.leg_joints(np.zeros(6)) is None:
        raise InputError(f"{path_text(spec)}: "
                         "pkmcal errors needs a six-leg machine (machine: stewart; "
                         f"or 'cubic' for the embedded seed 003 device), not "
                         f"{getattr(machine, 'kind', 'this machine')}")
    return machine


def _nonnegative(text: str, quantity: str, option: str) -> float:
    value = parse_quantity(text, quantity, option)
    if not (math.isfinite(value) and value >= 0):
        raise InputError(f"{option}: must be >= 0, got {text}")
    return value


def _read_trajectory_file(path: Path):
    """Times (s), positions (m) and orientations of a trajectory CSV, with the file's lines."""
    from ..io.csv_io import has_orientation, parse_number, read_poses, read_positions
    from ..units import TIME

    header, rows = read_table(path)
    t_cols = [i for i, n in enumerate(header) if n == "t" or n.startswith("t_")]
    if not t_cols:
        raise InputError(f"{path_text(path)}: "
                         "missing column t_s (time of each pose); columns found: "
                         f"{', '.join(header)}")
    if len(t_cols) > 1:
        raise InputError(f"{path_text(path)}: more than one time column: "
                         f"{', '.join(header[i] for i in t_cols)}; keep one")
    name = header[t_cols[0]]
    unit = name[2:]
    if unit not in TIME:
        raise InputError(f"{path_text(path)}: column {name!r}: "
                         + ("no unit suffix" if not unit else f"unknown time unit {unit!r}")
                         + f" (write t_s; accepted: {', '.join('t_' + u for u in TIME)})")
    t = np.array([parse_number(path, line, name, f[t_cols[0]]) for line, f in rows]) * TIME[unit]
    if has_orientation(header):
        P, R, lines = read_poses(path)
    else:
        P, lines = read_positions(path)
        R = np.broadcast_to(np.eye(3), (len(P), 3, 3)).copy()
    if len(t) < 3:
        raise InputError(f"{path_text(path)}: "
                         f"{len(t)} pose(s); a trajectory needs at least 3 to give "
                         "accelerations")
    h = np.diff(t)
    if not np.all(h > 0):
        k = int(np.flatnonzero(~(h > 0))[0])
        raise InputError(f"{path_text(path)}: "
                         f"row {lines[k + 1]}, column {name}: times must increase "
                         f"strictly ({t[k + 1] / TIME[unit]:g} after {t[k] / TIME[unit]:g})")
    return t, P, R, lines


def run_errors(machine_spec: str, output: Path, trajectory: str | None,
               trajectory_file: Path | None, radius: str | None, height: str | None,
               omega: str | None, samples: int | None, clearance: str,
               platform_clearance: str | None, mass: str, cutting_force: str,
               screw_error: str, force_tol: str, plot: Path | None) -> None:
    from ..analysis import errors as err
    from ..units import parse_vector

    # -- options, all checked before any computation ---------------------------------------
    if trajectory is None:
        trajectory = "file" if trajectory_file is not None else "circle"
    if trajectory == "file" and trajectory_file is None:
        raise InputError("--trajectory file: give the poses with --trajectory-file POSES.csv")
    if trajectory == "circle" and trajectory_file is not None:
        raise InputError("--trajectory-file: applies to --trajectory file, not circle")
    if trajectory == "file":
        given = [o for o, v in (("--radius", radius), ("--height", height), ("--omega", omega),
                                ("--samples", samples)) if v is not None]
        if given:
            raise InputError(f"{given[0]}: applies to --trajectory circle; the file gives "
                             "the poses and times")
    c_base = _nonnegative(clearance, "length", "--clearance")
    c_platform = c_base if platform_clearance is None else _nonnegative(
        platform_clearance, "length", "--platform-clearance")
    mass_kg = _nonnegative(mass, "mass", "--mass")
    f_cut = np.array(parse_vector(cutting_force, "force", 3, "--cutting-force"))
    if not np.all(np.isfinite(f_cut)):
        raise InputError(f"--cutting-force: must be finite, got {cutting_force}")
    backlash = _nonnegative(screw_error, "length", "--screw-error")
    tol_n = _nonnegative(force_tol, "force", "--force-tol")
    if plot is not None and plot.exists() and not plot.is_dir():
        raise InputError(f"--plot {path_text(plot)}: exists and is not a directory")
    machine = _errors_machine(machine_spec)
    for option, value, text in (("--clearance", c_base, clearance),
                                ("--platform-clearance", c_platform, platform_clearance),
                                ("--screw-error", backlash, screw_error)):
        check_option_scale(value, machine, option, "noise", text)
    inputs = _machine_inputs(machine_spec) if machine_spec != "cubic" else []
    envelope_path = output.with_name(output.stem + "_envelope" + output.suffix)
    plot_files = [] if plot is None else [plot / f"{n}.png" for n in ERRORS_PLOTS]
    envelope_path = None if is_stream(output) else envelope_path    # no file beside a pipe
    check_outputs([output, *([envelope_path] if envelope_path else []), *plot_files],
                  inputs + ([trajectory_file] if trajectory_file else []),
                  [plot] if plot is not None else [])

    if trajectory == "circle":
        r_m = _nonnegative(radius or "100mm", "length", "--radius")
        z_m = parse_quantity(height or "410mm", "length", "--height")
        w = parse_quantity(omega or "10rad/s", "angular_speed", "--omega")
        if not (math.isfinite(z_m) and math.isfinite(w)):
            raise InputError("--height, --omega: must be finite")
        check_option_scale(r_m, machine, "--radius", "size", radius)
        check_option_scale(z_m, machine, "--height", "size", height)
        n = 360 if samples is None else samples
        if n < 1:
            raise InputError(f"--samples: must be >= 1, got {n}")
        path = err.circle_trajectory(r_m, z_m, w, n)
        where = (f"circle r = {r_m * 1e3:.6g} mm at z = {z_m * 1e3:.6g} mm, "
                 f"{w:.6g} rad/s counter-clockwise from +X, {n} samples")
    else:
        t, P, R, lines = _read_trajectory_file(trajectory_file)
        path = err.trajectory_from_poses(t, P, R)
        where = f"{path_text(trajectory_file)}: {len(t)} poses over {t[-1] - t[0]:.6g} s"
    try:
        if trajectory == "file":
            err.check_poses(machine, path.P, path.R, lines, "row")
        else:
            err.check_poses(machine, path.P, path.R, np.arange(len(path)), "sample")
    except InputError as exc:
        raise InputError(f"{path_text(trajectory_file)}: {exc}" if trajectory == "file" else
                         f"the circle has {exc}; change --radius or --height") from None

    result = err.trajectory_errors(machine, path, mass_kg, f_cut, c_base, c_platform, backlash,
                                   tol_n)
    # -- outputs, at the very end -----------------------------------------------------------
    plots = []
    if plot is not None:
        plots = _errors_plots(plot, machine, path, result, trajectory, mass_kg, f_cut, c_base,
                              c_platform, backlash, tol_n)
    # the SPEC 6 columns exactly; the envelope (where a link force is too small to tell the
    # clearance side) goes to a second file beside it
    err.write_errors_csv(output, result, envelope_path)
    commit_outputs()
    _print_errors(machine, where, result, trajectory, mass_kg, f_cut, c_base, c_platform,
                  backlash, tol_n, output, plots)


def _errors_plots(outdir: Path, machine, path, result, trajectory, mass_kg, f_cut, c_base,
                  c_platform, backlash, tol_n) -> list[Path]:
    from ..analysis.errors import clearance_map
    from ..io.atomic import output_directory
    from ..report import plots

    output_directory(outdir)
    e = result.errors
    if trajectory == "circle":
        x, xlabel = np.degrees(path.angle), "angle [deg]"
    else:
        x, xlabel = path.t, "time [s]"
    files = [
        plots.plot_link_forces(x, result.forces, outdir / "link_forces.png", xlabel,
                               undetermined=e.undetermined),
        plots.plot_pose_errors(x, e.dx, e.dx_min, e.dx_max, outdir / "pose_errors.png", xlabel,
                               title="pose error from joint clearance "
                                     + format_quantity(c_base, "length", 3)
                                     + (f" (platform {format_quantity(c_platform, 'length', 3)})"
                                        if c_platform != c_base else "")
                                     + (f", backlash {format_quantity(backlash, 'length', 3)}"
                                        if backlash else "")),
    ]
    lo, hi = path.P[:, :2].min(axis=0), path.P[:, :2].max(axis=0)
    mid, half = (lo + hi) / 2, np.max(hi - lo) * 0.75
    half = half if half > 0 else 0.05
    gx = np.linspace(mid[0] - half, mid[0] + half, 41)
    gy = np.linspace(mid[1] - half, mid[1] + half, 41)
    z = float(np.mean(path.P[:, 2]))
    cmap = clearance_map(machine, gx, gy, z, path.R[0], mass_kg, f_cut, c_base, c_platform,
                         backlash, tol_n)
    norm = lambda v: np.linalg.norm(v, axis=-1)   # noqa: E731
    panels = [
        ("|dp| at rest under weight and cutting force", norm(cmap.dx[..., :3]) * 1e6, "um"),
        ("|dOmega| at rest under weight and cutting force", norm(cmap.dx[..., 3:]) * 1e6,
         "urad"),
        ("bound of |dp|, any force direction", norm(cmap.bound[..., :3]) * 1e6, "um"),
        ("bound of |dOmega|, any force direction", norm(cmap.bound[..., 3:]) * 1e6, "urad"),
    ]
    files.append(plots.plot_error_map(gx * 1e3, gy * 1e3, panels, outdir / "error_map.png",
                                      title=f"clearance errors at z = {z * 1e3:.6g} mm "
                                            "(platform orientation of the first pose)",
                                      overlay=path.P[:, :2] * 1e3))
    return files


def _print_errors(machine, where, result, trajectory, mass_kg, f_cut, c_base, c_platform,
                  backlash, tol_n, output, plots) -> None:
    from ..analysis.errors import ERROR_COMPONENTS, STANDARD_GRAVITY, zero_crossings

    path, e, f = result.trajectory, result.errors, result.forces
    if trajectory == "circle":
        x, period, unit = np.degrees(path.angle), 360.0, "deg"
    else:
        x, period, unit = path.t, None, "s"
    out = console()
    table = _table("", "", title=f"pkmcal errors: {path_text(machine.source)}", show_header=False)
    table.add_row("trajectory", where)
    inertia = mass_kg * np.max(np.linalg.norm(path.acceleration, axis=1))
    table.add_row("loads", f"weight {mass_kg * STANDARD_GRAVITY:.5g} N ({mass_kg:.6g} kg), "
                  f"cutting force ({', '.join(f'{v:.6g}' for v in f_cut)}) N, inertia up to "
                  f"{inertia:.5g} N")
    table.add_row("clearance", f"{format_quantity(c_base, 'length', 6)} (base joints), "
                  f"{format_quantity(c_platform, 'length', 6)} (platform joints); backlash "
                  f"{format_quantity(backlash, 'length', 6)}; side undetermined "
                  f"below {tol_n:.6g} N")
    out.print(table)
    forces = _table("leg", "min [N]", "max [N]", "changes side at [" + unit + "]",
                    title="leg forces (tension positive)", justify={1: "right", 2: "right"})
    for i in range(6):
        cross = zero_crossings(x, f[:, i], period)
        forces.add_row(str(i + 1), f"{f[:, i].min():.5g}", f"{f[:, i].max():.5g}",
                       ", ".join(f"{c:.4g}" for c in cross) if cross.size else "-")
    out.print(forces)
    errors = _table("error", "min", "max", "envelope", "changes sign at [" + unit + "]",
                    title="pose error (um, urad)", justify={1: "right", 2: "right"})
    for j, name in enumerate(ERROR_COMPONENTS):
        v = e.dx[:, j] * 1e6
        cross = zero_crossings(x, v, period)
        errors.add_row(name, format_number(v.min()), format_number(v.max()),
                       f"{format_number(e.dx_min[:, j].min() * 1e6)} .. "
                       f"{format_number(e.dx_max[:, j].max() * 1e6)}",
                       ", ".join(f"{c:.4g}" for c in cross[:8])
                       + (" ..." if cross.size > 8 else "") if cross.size else "-")
    out.print(errors)
    n_und = int(np.any(e.undetermined, axis=1).sum())
    if n_und:
        out.print(f"note: at {n_und} of {len(path)} samples a leg force is within "
                  f"{tol_n:.6g} N of zero: the main columns take those joints centred, the "
                  "envelope of both sides is in "
                  f"{output.with_name(output.stem + '_envelope' + output.suffix)}.",
                  markup=False)
    if trajectory == "file" and np.any(np.abs(np.diff(path.R, axis=0)) > 1e-12):
        out.print("note: the orientation changes along the path; the platform's rotational "
                  "inertia is not modelled (translation inertia only).", markup=False)
    written = [output] + ([] if is_stream(output) else
                          [output.with_name(output.stem + "_envelope" + output.suffix)])
    commit_outputs()
    out.print("wrote " + ", ".join(map(str, written + list(plots))), markup=False)
