"""Implementations of the ``pkmcal`` commands (imported lazily by :mod:`pkmcal.cli`).

Every command validates its inputs and options first, computes, and writes its output files
only at the very end, atomically; problems are raised as :class:`~pkmcal.errors.InputError`
(exit code 2 in :func:`pkmcal.cli.main`).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import (
    atomic_write_text,
    joint_quantity,
    load_machine,
    machine_to_text,
    parse_machine,
    read_constraint_link,
    read_full_pose,
    read_joints,
    read_poses,
    read_positions,
    read_readings,
    read_table,
    read_tracker,
    write_full_pose,
    write_joints,
    write_poses,
    write_positions,
    write_table,
    write_tracker,
)
from ..io.atomic import is_stream
from ..io.machine_file import DEFAULT_UNITS
from ..io.plausibility import check_option_scale
from ..limits import MAX_MEASUREMENTS
from ..measurements.deviations import DEFAULT_DEVIATIONS
from ..measurements.deviations import deviations as _deviations
from ..planning.scenarios import SCENARIO_OF as DEFAULT_SCENARIO
from ..report.provenance import run_date
from ..units import ANGLE, LENGTH, parse_quantity
from ._console import console, error, warning

# --------------------------------------------------------------------------------------------
# shared helpers
# --------------------------------------------------------------------------------------------


def load_machine_arg(spec: str):
    """The machine named on the command line: a file, or ``default`` (embedded Hexa Slide)."""
    if spec == "default":
        from ..machines import default_hexaslide

        machine = default_hexaslide()
        machine.file_units = dict(DEFAULT_UNITS)
        machine.source = "default"
        machine.calibration_info = None
        return machine
    return load_machine(spec)


def _machine_inputs(spec: str) -> list[Path]:
    return [] if spec == "default" else [Path(spec)]


def check_outputs(outputs: list[Path], inputs: list[Path], directories=()) -> None:
    """Check the command's outputs before any work: refuse outputs whose directory is missing
    or not writable, that are directories, that coincide, or that would overwrite an input
    file (input files are never modified). With the command's :class:`OutputSet` active
    (``pkmcal`` runs every command in one) they become its declared outputs, inputs and
    output directories; files read later are added to the inputs when read."""
    from ..io.atomic import OutputSet, active_output_set

    OutputSet(outputs, directories, inputs)       # the checks, at once
    active = active_output_set()
    if active is not None:
        for d in directories:
            active.add_directory(d)
        for inp in inputs:
            active.add_input(inp)
        for out in outputs:
            active.declare(out)


def _wrote(output: Path, beside: Path) -> str:
    """``wrote OUT and OUT.json``; a device or pipe gets no file beside it."""
    if is_stream(output):
        return f"wrote {output} (not a regular file: no {beside.suffix} file beside it)"
    return f"wrote {output} and {beside}"


def text_digest(text: str) -> str:
    """SHA-256 (hex) of a text's UTF-8 bytes: how a calibrated file pins its JSON report."""
    import hashlib

    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def commit_outputs() -> list[Path]:
    """Write the command's staged outputs now, all or none (before saying they are written);
    returns them."""
    from ..io.atomic import active_output_set

    active = active_output_set()
    return active.commit() if active is not None else []


def _units(machine) -> dict:
    return dict(getattr(machine, "file_units", None) or DEFAULT_UNITS)


def _rows_text(rows, limit: int = 10) -> str:
    rows = [int(r) for r in rows]
    return ", ".join(map(str, rows[:limit])) + (" ..." if len(rows) > limit else "")


def _finite_or_none(value):
    """JSON-safe: NaN and infinities become null, numpy scalars become Python numbers."""
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(v) for v in value]
    if isinstance(value, np.ndarray):
        return _finite_or_none(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


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
            out.print(f"  {f}", markup=False)


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

#: scenarios each machine type can simulate
SCENARIOS = {"hexaslide": ("constraint-link",), "delta": ("tracker",), "stewart": ("pose",)}


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


def tracker_noise_arg(text: str | None, allow_none: bool, machine=None):
    """The tracker noise model of ``--noise``: leica (default), none, or a length (isotropic),
    checked against the machine's size when given."""
    from ..measurements import TrackerNoise

    if text is None or text.strip().lower() == "leica":
        return TrackerNoise(), "leica (5 um along the beam, 7.5 um + 3 um/m across)"
    if text.strip().lower() == "none":
        if not allow_none:
            raise InputError("--noise none: the calibration weighs the points by their noise; "
                             "give leica or a length such as 10um")
        return None, "none"
    sigma = parse_quantity(text, "length", "--noise")
    if sigma == 0 and allow_none:
        return None, "none"
    if not sigma > 0:
        raise InputError(f"--noise: must be > 0 (a standard deviation), leica or none; got "
                         f"{text}")
    if machine is not None:
        check_option_scale(sigma, machine, "--noise", "noise", text)
    return TrackerNoise(sigma, sigma, 0.0), f"isotropic {sigma * 1e6:.4g} um"


def run_simulate(machine_spec: str, output: Path, scenario: str | None, poses: int | None,
                 noise: str | None, lc_error: str, seed: int, deviations: str | None,
                 truth: Path | None, grid: str | None = None, outliers: int = 0,
                 pose_noise: str | None = None) -> None:
    machine = load_machine_arg(machine_spec)
    kind = machine.kind
    scenario = scenario or DEFAULT_SCENARIO.get(kind, "constraint-link")
    available = SCENARIOS.get(kind, ())
    if scenario not in available:
        raise InputError(f"--scenario {scenario}: not available for {kind} machines (available: "
                         f"{', '.join(available) or 'none yet'})")
    deviations = deviations or DEFAULT_DEVIATIONS.get(kind, "random")
    check_outputs([output] + ([truth] if truth else []), _machine_inputs(machine_spec))
    if pose_noise is not None and scenario != "pose":
        raise InputError("--pose-noise: applies to --scenario pose")
    if scenario == "pose":
        for option, given in (("--grid", grid is not None), ("--outliers", bool(outliers)),
                              ("--lc-error", lc_error.strip() not in ("0", "0um", "0mm", "0m"))):
            if given:
                raise InputError(f"{option}: does not apply to --scenario pose")
        _simulate_full_pose(machine, output, poses or 60, noise, pose_noise, seed, deviations,
                            truth)
        return
    if scenario == "tracker":
        if poses is not None:
            raise InputError("--poses: applies to --scenario constraint-link or pose; a "
                             "tracker scenario measures a grid (--grid NXxNYxNZ)")
        if lc_error.strip() not in ("0", "0um", "0mm", "0m"):
            raise InputError("--lc-error: applies to --scenario constraint-link")
        _simulate_tracker(machine, output, noise, seed, deviations, truth,
                          parse_grid(grid or "3x3x3"), outliers)
        return
    if grid is not None or outliers:
        raise InputError(f"--{'grid' if grid is not None else 'outliers'}: applies to "
                         "--scenario tracker")
    _simulate_constraint_link(machine, output, poses or 150,
                              "2um" if noise is None else noise, lc_error, seed,
                              deviations, truth)


def _simulate_constraint_link(machine, output: Path, poses: int, noise: str, lc_error: str,
                              seed: int, deviations: str, truth: Path | None) -> None:
    noise_m = parse_quantity(noise, "length", "--noise")
    if not noise_m >= 0:
        raise InputError(f"--noise: must be >= 0, got {noise}")
    check_option_scale(noise_m, machine, "--noise", "noise", noise)
    lc_error_m = check_option_scale(parse_quantity(lc_error, "length", "--lc-error"), machine,
                                    "--lc-error", "error", lc_error)
    lc = machine.constraint_link_length
    if lc is None:
        raise InputError(f"{machine.source}: constraint_link: the machine has no constraint-link "
                         "length; add `constraint_link: {length: ...}` to the machine file")
    lc_true = lc - lc_error_m
    if not lc_true > 0:
        raise InputError(f"--lc-error: the true link length {lc_true * 1e3:.6g} mm is not "
                         "positive")
    rng = np.random.default_rng(seed)
    true = _true_machine(machine, deviations, rng)
    true.constraint_link_length = lc_true
    from ..measurements import simulate_constraint_link

    data = simulate_constraint_link(true, poses, noise_m, link_length=lc_true, rng=rng)
    units = _units(machine)
    truth_text = None
    if truth is not None:
        truth_text = machine_to_text(true, units)
        parse_machine(truth_text, str(truth))
    # outputs, at the very end
    write_joints(output, data.q, unit=units["length"], extra={"passive": data.passive + 1})
    if truth is not None:
        atomic_write_text(truth, truth_text)
    out = console()
    table = _table("", "", title="pkmcal simulate", show_header=False)
    table.add_row("machine", f"{machine.source} ({machine.kind})")
    table.add_row("scenario", f"constraint-link, {poses} poses on |P| = "
                  f"{lc_true / LENGTH['mm']:.6g} mm (true link)")
    table.add_row("deviations", deviations)
    table.add_row("encoder noise", f"{noise_m * 1e6:.4g} um (seed {seed})")
    if lc_error_m:
        table.add_row("Lc error", f"machine file says {lc / LENGTH['mm']:.6g} mm, true link "
                      f"{lc_true / LENGTH['mm']:.6g} mm")
    out.print(table)
    commit_outputs()
    out.print(f"wrote {output}" + (f" and {truth}" if truth else ""), markup=False)


def _simulate_tracker(machine, output: Path, noise: str | None, seed: int, deviations: str,
                      truth: Path | None, shape: tuple[int, int, int], outliers: int) -> None:
    from ..measurements import (
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
                         f"outside the workspace of {machine.source} (e.g. "
                         f"{_mm(targets[bad[0]])} mm); use a smaller grid or another home")
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
    table.add_row("machine", f"{machine.source} ({machine.kind})")
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
    out.print(f"wrote {output}" + (f" and {truth}" if truth else ""), markup=False)


def full_pose_noise_arg(noise: str | None, pose_noise: str | None, strict: bool,
                        machine=None):
    """The full-pose noise model of ``--noise`` (readings, as a leg length) and
    ``--pose-noise`` (POSITION,ORIENTATION). ``strict``: every standard deviation must be > 0
    (a calibration weighs by them); else >= 0 (a simulation may be exact)."""
    from ..measurements import FullPoseNoise

    default = FullPoseNoise()
    reading = default.reading_m if noise is None else parse_quantity(noise, "length", "--noise")
    if pose_noise is None:
        position, orientation = default.position_m, default.orientation_rad
    else:
        parts = [p.strip() for p in str(pose_noise).split(",")]
        if len(parts) != 2:
            raise InputError(f"--pose-noise: expected POSITION,ORIENTATION with units (e.g. "
                             f"20um,50urad), got {pose_noise!r}")
        position = parse_quantity(parts[0], "length", "--pose-noise (position)")
        orientation = parse_quantity(parts[1], "angle", "--pose-noise (orientation)")
    for option, value, text in (("--noise", reading, noise),
                                ("--pose-noise", position, pose_noise),
                                ("--pose-noise", orientation, pose_noise)):
        if not (math.isfinite(value) and (value > 0 if strict else value >= 0)):
            need = ("must be > 0 (a standard deviation that weighs the residuals)" if strict
                    else "must be >= 0")
            raise InputError(f"{option}: {need}, got {text}")
    if machine is not None:
        check_option_scale(reading, machine, "--noise", "noise", noise)
        check_option_scale(position, machine, "--pose-noise (position)", "noise", pose_noise)
        check_option_scale(orientation, machine, "--pose-noise (orientation)", "angle noise",
                           pose_noise)
    return FullPoseNoise(reading, position, orientation)


def _noise_text(noise) -> str:
    return (f"readings {noise.reading_m * 1e6:.4g} um (as leg length), position "
            f"{noise.position_m * 1e6:.4g} um, orientation {noise.orientation_rad * 1e6:.4g} "
            "urad")


def _simulate_full_pose(machine, output: Path, n_poses: int, noise: str | None,
                        pose_noise: str | None, seed: int, deviations: str,
                        truth: Path | None) -> None:
    from ..measurements import (
        default_measurement_frames,
        sample_platform_poses,
        simulate_full_pose,
    )

    noise_model = full_pose_noise_arg(noise, pose_noise, strict=False, machine=machine)
    rng = np.random.default_rng(seed)
    true = _true_machine(machine, deviations, rng)
    frames = getattr(machine, "measurement_frames", None)
    frames_from = "the machine file's measurement_frames"
    if frames is None:
        frames, frames_from = default_measurement_frames(), "default"
    true.measurement_frames = frames
    poses = sample_platform_poses(true, n_poses, rng)
    data = simulate_full_pose(true, poses, frames, noise_model, rng)
    units = _units(machine)
    truth_text = None
    if truth is not None:
        truth_text = machine_to_text(true, units)
        parse_machine(truth_text, str(truth))
    # outputs, at the very end
    write_full_pose(output, data, machine, units["length"])
    if truth is not None:
        atomic_write_text(truth, truth_text)
    out = console()
    table = _table("", "", title="pkmcal simulate", show_header=False)
    table.add_row("machine", f"{machine.source} ({machine.kind})")
    table.add_row("scenario", f"pose, {n_poses} random poses in the 100 mm cube around home "
                  f"{_mm(machine.home[0])} mm, Euler angles within +/-10 deg")
    table.add_row("deviations", deviations + (f" (seed {seed})" if deviations == "random"
                                              else ""))
    table.add_row("noise", f"{_noise_text(noise_model)} (seed {seed})")
    table.add_row("frames", f"{frames_from}: measurement origin at "
                  f"{_mm(frames.mocap_from_base[1])} mm; marker origin at "
                  f"{_mm(frames.platform_from_marker[1])} mm in the platform frame")
    out.print(table)
    commit_outputs()
    out.print(f"wrote {output}" + (f" and {truth}" if truth else ""), markup=False)


def _mm(v) -> str:
    return "(" + ", ".join(f"{x * 1e3:.6g}" for x in np.asarray(v, float)) + ")"


# --------------------------------------------------------------------------------------------
# calibrate
# --------------------------------------------------------------------------------------------

#: measurement types each machine type can be calibrated from, with the columns they need
CALIBRATIONS = {
    "hexaslide": {"constraint-link": "q1_mm..q6_mm (optionally passive) with a constraint_link "
                                     "in the machine file"},
    "delta": {"tracker": "q1_deg..q3_deg and the tracker points mx_mm, my_mm, mz_mm"},
    "stewart": {"pose": "the leg readings q1_<unit>..q6_<unit> (the machine's reading unit) "
                        "and the measured pose x_mm, y_mm, z_mm with qx, qy, qz, qw or "
                        "psi_deg, theta_deg, phi_deg"},
}


def measurement_kind(path: Path, header: list[str], machine) -> str:
    """Measurement type from the columns of a data file (and whether ``machine`` can be
    calibrated from it)."""
    has = lambda base: any(n == base or n.startswith(base + "_") for n in header)  # noqa: E731
    supported = CALIBRATIONS.get(machine.kind, {})
    need = "; ".join(f"{k}: {v}" for k, v in supported.items()) or "none yet"
    if has("mx") or has("my") or has("mz"):
        kind = "tracker"
    elif has("x") or has("y") or has("z") or "qw" in header:
        kind = "pose"
    elif has("q1"):
        kind = "constraint-link"
    else:
        raise InputError(f"{path}: cannot tell the measurement type from the columns "
                         f"({', '.join(header)}); a {machine.kind} is calibrated from {need}")
    if kind not in supported:
        if machine.kind == "delta" and kind == "constraint-link":
            raise InputError(f"{path}: missing columns mx_<unit>, my_<unit>, mz_<unit> (e.g. "
                             f"mx_mm): a delta is calibrated from laser-tracker points ({need}); "
                             f"columns found: {', '.join(header)}")
        raise InputError(f"{path}: {kind} measurements of a {machine.kind} cannot be calibrated "
                         f"yet; this version calibrates a {machine.kind} from {need}")
    return kind


def _parameter_table(result, nominal_of: dict, units):
    """Rows of the report's parameter list, in the machine file's units; ``nominal_of`` maps
    parameter names to their start (nominal) values."""
    fl, fa = LENGTH[units["length"]], ANGLE[units["angle"]]
    rows = []
    params = result.parameters
    for i, (name, kind) in enumerate(zip(params.names, params.kinds, strict=True)):
        f = fl if kind == "length" else fa if kind == "angle" else 1.0
        unit = units["length"] if kind == "length" else units["angle"] if kind == "angle" \
            else "1"
        nominal = nominal_of.get(name, float("nan"))
        fixed = bool(params.fixed[i])
        rows.append({
            "name": name, "kind": kind, "unit": unit,
            "nominal": nominal / f, "identified": result.x[i] / f,
            "change": (result.x[i] - nominal) / f,
            "std": None if fixed else result.std[i] / f,
            "fixed": fixed,
            "scaled_change": abs(result.x[i] - nominal) / result.scales[i],
        })
    return rows


def run_calibrate(machine_spec: str, data_path: Path, output: Path, method: str | None,
                  noise: str | None, estimate_lc: bool | None, json_output: bool,
                  two_step: bool = False, robust: bool = False, pose_noise: str | None = None,
                  fix_frames: bool = False, report_dir: Path | None = None,
                  holdout: str | None = None, seed: int = 0) -> int:
    if output.suffix.lower() == ".json":
        raise InputError(f"{output}: the calibrated machine is a YAML file; choose a name "
                         "ending in .yaml (the JSON report is written beside it)")
    report_path = output.with_suffix(".json")
    machine = load_machine_arg(machine_spec)
    outputs = [output] + ([] if is_stream(output) else [report_path])
    if report_dir is not None:
        if report_dir.exists() and not report_dir.is_dir():
            raise InputError(f"--report {report_dir}: a file, not a directory")
        outputs += [report_dir / "report.html", report_dir / "report.json"]
    check_outputs(outputs, [data_path] + _machine_inputs(machine_spec),
                  [report_dir] if report_dir is not None else [])
    split = None if holdout is None else (holdout_arg(holdout), seed)
    header, _ = read_table(data_path)
    kind = measurement_kind(data_path, header, machine)
    for option, given in (("--pose-noise", pose_noise is not None),
                          ("--fix-frames", fix_frames)):
        if given and kind != "pose":
            raise InputError(f"{option}: applies to full-pose data (a Stewart with x, y, z "
                             f"and orientation columns); {data_path} has {kind} data")
    if kind == "pose":
        for option, given in (("--estimate-lc", estimate_lc is not None),
                              ("--two-step", two_step), ("--robust", robust)):
            if given:
                raise InputError(f"{option}: does not apply to full-pose data ({data_path}); "
                                 "see --method ml|ik, --fix-frames, --noise, --pose-noise")
        if method not in (None, "ml", "ik"):
            raise InputError(f"--method {method}: full-pose data are calibrated by ml "
                             "(maximum likelihood, default) or ik (inverse-kinematic residuals)")
        return _calibrate_full_pose(machine, machine_spec, data_path, output, report_path,
                                    method or "ml", noise, pose_noise, fix_frames, json_output,
                                    report_dir, split)
    if kind == "tracker":
        for option, given in (("--method", method is not None),
                              ("--estimate-lc", estimate_lc is not None)):
            if given:
                raise InputError(f"{option}: applies to constraint-link data; {data_path} has "
                                 "tracker points (see --two-step, --robust)")
        return _calibrate_tracker(machine, machine_spec, data_path, output, report_path, noise,
                                  two_step, robust, json_output, report_dir, split)
    for option, given in (("--two-step", two_step), ("--robust", robust)):
        if given:
            raise InputError(f"{option}: applies to laser-tracker data (mx, my, mz columns); "
                             f"{data_path} has {kind} data")
    return _calibrate_constraint_link(machine, machine_spec, data_path, output, report_path,
                                      method or "ml", noise or "1um", estimate_lc, json_output,
                                      report_dir, split)


def _calibrate_constraint_link(machine, machine_spec: str, data_path: Path, output: Path,
                               report_path: Path, method: str, noise: str,
                               estimate_lc: bool | None, json_output: bool,
                               report_dir: Path | None = None, split=None) -> int:
    sigma = parse_quantity(noise, "length", "--noise")
    if not sigma > 0:
        raise InputError(f"--noise: must be > 0 (the standard deviation of the encoder "
                         f"noise), got {noise}")
    check_option_scale(sigma, machine, "--noise", "noise", noise)
    kind = "constraint-link"
    data, held = _split_rows(read_constraint_link(data_path, machine), split, data_path)

    from ..calibration import calibrate_constraint_link, constraint_link_reading_rms

    result = _solve(data_path, calibrate_constraint_link, machine, data, held=held,
                    method=method, sigma_m=sigma, estimate_link_length=estimate_lc)
    if not _converged(result, data_path):
        return 1
    from ..calibration.constraint_link import PROBLEMS

    kw = {} if estimate_lc is None else {"estimate_link_length": estimate_lc}
    result.extras["rebuild_problem"] = lambda: PROBLEMS[method](machine, data, sigma, **kw)

    units = _units(machine)
    fl = LENGTH[units["length"]]
    calibrated = result.extras["machine"]
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    # FK start of the calibrated file: the input machine's home (a central pose of the working
    # assembly mode) rather than the first measured pose, which may sit at the workspace edge
    home_P, home_R = machine.home
    if np.all(np.isfinite(calibrated.ik(home_P, home_R))):
        calibrated.home = (home_P, home_R)
    date = run_date()
    nominal_of = dict(zip(machine.parameters.names, machine.u, strict=True))
    nominal_of["link.length"] = data.link_length
    params = _parameter_table(result, nominal_of, units)
    r = np.asarray(result.residuals, float)
    r_m = r * sigma
    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.extras.get("unidentifiable", []))
    dropped = [int(v) for v in np.asarray(result.extras.get("dropped_rows", []))]
    lc_index = result.parameters.names.index("link.length") \
        if "link.length" in result.parameters.names else None
    lc_estimated = lc_index is not None and not bool(result.parameters.fixed[lc_index])
    lc = float(result.extras.get("link_length", data.link_length))
    residual_what = {"ml": "all joint readings", "ik": "passive joint readings",
                     "fk": "computed link length |P| - Lc"}[method]
    report = {
        "pkmcal_report": 1,
        "command": "calibrate",
        "date": date,
        "machine_file": str(getattr(machine, "source", machine_spec)),
        "data_file": str(data_path),
        "calibrated_file": str(output),
        "measurement": kind,
        "method": method,
        "units": units,
        "measurements": len(data),
        "dropped_rows": dropped,
        "noise_sigma_um": sigma * 1e6,
        "link_length": {"value": lc / fl, "assumed": data.link_length / fl,
                        "unit": units["length"], "estimated": lc_estimated,
                        "std": params[lc_index]["std"] if lc_estimated else None},
        "convergence": {"success": bool(result.success), "status": int(result.status),
                        "message": result.message, "iterations": int(result.nit),
                        "evaluations": int(result.nfev)},
        "residuals": {
            "of": residual_what,
            "count": int(r.size),
            "rms_um": float(np.sqrt(np.mean(r_m**2)) * 1e6) if r.size else None,
            "max_abs_um": float(np.max(np.abs(r_m)) * 1e6) if r.size else None,
            "rms_per_column_um": (np.sqrt(np.mean(r_m**2, axis=0)) * 1e6).tolist()
            if r.ndim == 2 and r.shape[1] > 1 else None,
            "before_rms_um": _um(constraint_link_reading_rms(machine, data, sigma)),
            "before": "machine file's geometry, all readings, poses fitted (maximum "
                      "likelihood)",
            "residual_variance": float(result.residual_variance),
            "estimated_noise_um": float(np.sqrt(result.residual_variance) * sigma * 1e6)
            if np.isfinite(result.residual_variance) else None,
            "dof": int(result.dof),
        },
        "identifiability": _identifiability_json(n_free, rank, unidentifiable, s),
        "parameters": [{k: v for k, v in p.items() if k != "scaled_change"} for p in params],
    }
    if held is not None:
        report["validation"] = _validation(
            split, held, "joint readings of the held-out rows (poses fitted, geometry and Lc "
            "held); before: the machine file's geometry", "um",
            _um(constraint_link_reading_rms(machine, held, sigma)),
            _um(constraint_link_reading_rms(calibrated, dataclasses.replace(held, link_length=lc),
                                            sigma)),
            report["residuals"]["rms_um"])
    metadata = {
        "method": method,
        "date": date,
        "data": str(data_path),
        "machine": str(getattr(machine, "source", machine_spec)),
        "measurements": len(data),
        "rms_residual_um": report["residuals"]["rms_um"],
        "identifiable": rank,
        "free_parameters": n_free,
        "unidentifiable": [f"{d.dimension} x {d.name}" for d in unidentifiable
                           if d.std is None],
        "weakly_identifiable": [d.name for d in unidentifiable if d.std is not None],
        "link_length_estimated": lc_estimated,
        "report": report_path.name,
    }
    json_text = _write_calibration(calibrated, units, metadata, report, output, report_path,
                                   result, report_dir, nominal=machine)

    if "warnings" in result.extras:         # ml: the start strategy says what it left out
        for text in result.extras["warnings"]:
            warning(f"{data_path}: {text}")
    elif dropped:
        warning(f"{data_path}: {len(dropped)} row(s) left out (no pose from the five active "
                f"readings and the link with the start geometry): {_rows_text(dropped)}")
    if json_output:
        print(json_text, end="")
    else:
        _print_calibration(report, params, data_path, output, report_path, machine)
    return 0


def _um(value_m: float) -> float | None:
    """Metres -> micrometres for a report; None when not finite."""
    return _finite_or_none(float(value_m) * 1e6)


def holdout_arg(text: str) -> float:
    """``--holdout``: a share (0.2 or 20%) or a whole number of rows (30); the range is checked
    against the data by :func:`~pkmcal.calibration.holdout_split`."""
    t = text.strip()
    try:
        value = float(t[:-1]) / 100 if t.endswith("%") else float(t)
    except ValueError:
        value = float("nan")
    if not np.isfinite(value) or (t.endswith("%") and not 0 < value < 1):
        raise InputError(f"--holdout {text}: give the share of rows to hold out (e.g. 0.2 or "
                         "20%) or their number (e.g. 30)")
    return value


def _split_rows(data, split, data_path):
    """``(calibration data, held-out data or None)`` for ``--holdout``/``--seed``."""
    if split is None:
        return data, None
    from ..calibration import holdout_split

    try:
        train, held = holdout_split(len(data), *split)
    except ValueError as exc:
        raise InputError(f"--holdout: {data_path}: {exc}") from None
    return data.subset(train), data.subset(held)


def _validation(split, held, of: str, unit: str, before, after, calibration, **extra) -> dict:
    """The report's held-out validation section: RMS residuals of the held-out rows with the
    machine file's and the calibrated model, next to the calibration rows' own RMS."""
    ratio = after / calibration if after is not None and calibration else None
    summary = (f"{len(held)} held-out rows: RMS {_fmt(before)} -> {_fmt(after)} {unit} "
               f"(calibration rows {_fmt(calibration)} {unit}"
               + (f"; held-out / calibration = {ratio:.3g}" if ratio is not None else "") + ")")
    return {"summary": summary, "held_out": len(held), "rows": [int(r) for r in held.rows],
            "holdout": split[0], "seed": split[1], "of": of, "unit": unit,
            "before_rms": before, "after_rms": after, "calibration_rms": calibration,
            "held_out_over_calibration": ratio, **extra}


def _fmt(value) -> str:
    return "n/a" if value is None else f"{value:.4g}"


def _solve(data_path, calibrate, *args, held=None, **kwargs):
    """Run a calibration; numerical failures caused by the data become an InputError naming
    the data file (exit 2). With ``held`` (the rows --holdout set aside) a failure names the
    option too: the rows left may be too few."""
    try:
        return calibrate(*args, **kwargs)
    except (InputError, ValueError, np.linalg.LinAlgError) as exc:
        message = str(exc) if isinstance(exc, InputError) else \
            f"{data_path}: calibration failed: {exc}"
        if held is not None:
            message = (f"--holdout: holding out {len(held)} row(s) leaves {len(args[1])} "
                       f"to calibrate on: {message}")
        raise InputError(message) from None


def _converged(result, source, advice: str = "") -> bool:
    """True when the calibration converged; else says why (and what to try) on stderr,
    naming the data file ``source``."""
    if result.success and np.all(np.isfinite(result.x)):
        return True
    error(f"{source}: calibration did not converge: {result.message} (after {result.nit} "
          "iterations)" + (f"; {advice}" if advice else "") + "; check the columns (order, "
          "units) and the machine file; no file written")
    return False


def _identifiability_json(n_free, rank, unidentifiable, s) -> dict:
    """The identifiability section of a calibration report: the directions the data cannot
    fix, and apart from them the weakly identifiable ones (counted in ``identifiable``, left
    at their start values; each with its standard deviation)."""
    return {
        "free_parameters": n_free,
        "identifiable": rank,
        "unidentifiable": [d.as_dict() for d in unidentifiable if d.std is None],
        "weakly_identifiable": [d.as_dict() for d in unidentifiable if d.std is not None],
        "condition_number": float(s[0] / s[rank - 1]) if rank else None,
        "singular_values": s.tolist(),
    }


def versions(*extra: str) -> dict:
    """Versions of Python, pkmcal, numpy, scipy and the ``extra`` packages (None: absent)."""
    import platform
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version()}
    for name in ("pkmcal", "numpy", "scipy", *extra):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out


def provenance() -> dict:
    """The command line, the versions and the platform that produce a report."""
    import platform
    import shlex
    import sys

    return {"command": "pkmcal " + shlex.join(sys.argv[1:]), **versions(),
            "platform": platform.platform()}


#: methods whose residuals are whitened by the whole noise model (every measurement noisy):
#: only their chi-square can be tested against the noise. The paper's methods (constraint
#: link ik/fk, full-pose ik, the tracker's two-step) treat some measurements as exact, so
#: their residuals exceed the noise by design.
WHITENED_METHODS = ("ml", "joint")


def _acceptance(result, nominal, calibrated, source, method) -> dict:
    """The believability checks of a converged calibration (chi-square of the residuals
    against the assumed noise, for :data:`WHITENED_METHODS`; size of the changes against the
    machine's scale): warnings in words with the usual causes, and the report's
    ``acceptance`` section."""
    from ..calibration.acceptance import parameter_changes, residual_test

    out = {}
    if method in WHITENED_METHODS:
        test = residual_test(result)
        out["residuals"] = test.as_dict()
        if test.alarming:
            warning(f"{source}: {test.message()}")
    else:
        out["residuals"] = {"tested": False, "why": f"the {method} method treats some "
                            "measurements as exact: its residuals exceed the noise by design"}
    if nominal is not None:
        changes = parameter_changes(nominal, calibrated)
        out["parameter_changes"] = {"suspicious": changes.suspicious}
        if changes.suspicious:
            warning(f"{source}: {changes.message()}")
    return out


def _write_calibration(calibrated, units, metadata, report, output, report_path,
                       result=None, report_dir: Path | None = None, nominal=None) -> str:
    """Write the calibrated machine file and its JSON report, at the very end and atomically;
    the machine file is checked to load back first. Returns the JSON text.

    With ``result`` the report carries the covariance of the machine's parameters (SI: m,
    rad; the identifiable part, frames the data cannot fix held at the start values), which
    ``pkmcal compensate`` propagates to the targets."""
    if result is not None:
        names = list(calibrated.parameters.names)
        n = len(names)
        report["covariance"] = {
            "of": "machine parameters, SI units (m, rad, ratio), minimum-norm (identifiable "
                  "part)",
            "parameters": names,
            "matrix": np.asarray(result.covariance, float)[:n, :n].tolist(),
            # unidentifiable directions (columns, same units): pose changes along them are
            # changes of frames the data cannot see, removed before predicting errors
            "null_space": (np.asarray(result.null_space, float)
                           * np.asarray(result.scales, float)[:, None])[:n].tolist(),
        }
        all_names = list(result.parameters.names)
        if len(all_names) > n and all_names[:n] == names:
            # with the measurement frames (tracker pose, motion-capture frames) and Lc: what
            # compensate needs for targets given in the instrument's frame
            report["covariance"]["with_frames"] = {
                "parameters": all_names,
                "matrix": np.asarray(result.covariance, float).tolist(),
                "null_space": (np.asarray(result.null_space, float)
                               * np.asarray(result.scales, float)[:, None]).tolist(),
            }
        # residual / assumed noise std of every residual, for the report's histogram
        report["normalised_residuals"] = np.asarray(result.residuals, float).ravel().tolist()
        standardised = _standardised(result)
        if standardised is not None:
            report["standardised_residuals"] = standardised
        report["acceptance"] = _acceptance(result, nominal, calibrated,
                                           report.get("data_file", "the data"),
                                           report.get("method"))
    report["provenance"] = provenance()
    json_text = json.dumps(_finite_or_none(report), indent=2, allow_nan=False) + "\n"
    # the machine file names its report and pins it by digest: a report of another run
    # (or a half-replaced pair) is refused by compensate and report
    beside = not is_stream(output)      # no JSON report beside /dev/null or a pipe
    metadata = {**metadata, "report_sha256": text_digest(json_text)} if beside else \
        {k: v for k, v in metadata.items() if k != "report"}
    yaml_text = machine_to_text(calibrated, units, calibration=metadata)
    parse_machine(yaml_text, str(output))   # the calibrated file must load back
    html_text = None
    if report_dir is not None:
        from ..report.html import build_html

        html_text = build_html(json.loads(json_text))
    # one set: the report, then the machine file that names it, then --report DIR
    if beside:
        atomic_write_text(report_path, json_text)
    atomic_write_text(output, yaml_text)
    if html_text is not None:
        atomic_write_text(report_dir / "report.json", json_text)
        atomic_write_text(report_dir / "report.html", html_text)
    commit_outputs()
    return json_text


def _standardised(result):
    """Leverage-corrected standardised residuals for the report (None when the problem
    cannot be evaluated again)."""
    problem = result.extras.get("problem")
    if problem is None and callable(result.extras.get("rebuild_problem")):
        problem = result.extras["rebuild_problem"]()
    if problem is None or result.state is None:
        return None
    from ..report.residuals import standardised_residuals

    try:
        return standardised_residuals(problem, result)
    except (ValueError, np.linalg.LinAlgError):
        return None


def _print_calibration(report, params, data_path, output, report_path, machine) -> None:
    out = console()
    res, ident, conv = report["residuals"], report["identifiability"], report["convergence"]
    lc = report["link_length"]
    table = _table("", "", title=f"pkmcal calibrate: {machine.source} with {data_path}",
                   show_header=False)
    table.add_row("measurement", f"{report['measurement']}, {report['measurements']} poses")
    table.add_row("method", {"ml": "ml (maximum likelihood, all readings noisy)",
                             "ik": "ik (paper 3.4.1, inverse kinematics of the passive chain)",
                             "fk": "fk (paper 3.4.2, spread of the link length)"}
                  [report["method"]])
    table.add_row("identifiable", f"{ident['identifiable']} of {ident['free_parameters']} free "
                  "parameter directions" + (f", of which {len(ident['weakly_identifiable'])} "
                                            "weakly" if ident["weakly_identifiable"] else ""))
    for d in ident["unidentifiable"]:
        table.add_row("not identifiable", f"{d['dimension']} x {d['name']}: {d['description']}")
    for d in ident["weakly_identifiable"]:
        table.add_row("weakly identifiable", f"{d['name']}: {d['description']}")
    rms = res["rms_um"]
    noise = res["estimated_noise_um"]
    table.add_row("RMS residual", f"{rms:.4g} um ({res['of']}; assumed noise "
                  f"{report['noise_sigma_um']:.4g} um"
                  + (f", estimated {noise:.3g} um)" if noise is not None else ")"))
    if "validation" in report:
        table.add_row("held-out", report["validation"]["summary"])
    table.add_row("convergence", f"{conv['message']} ({conv['iterations']} iterations)")
    if lc["estimated"]:
        std = f" +/- {lc['std']:.3g} {lc['unit']}" if lc["std"] is not None else ""
        table.add_row("link length Lc", f"{lc['value']:.9g} {lc['unit']} (estimated{std}; "
                      f"machine file {lc['assumed']:.9g} {lc['unit']})")
    else:
        table.add_row("link length Lc", f"{lc['value']:.9g} {lc['unit']} (fixed: machine file)")
    out.print(table)

    _print_changes(params)
    if ident["unidentifiable"]:
        out.print("note: the data do not fix the directions listed as not identifiable; the "
                  "changes are the smallest ones (scaled) that fit the data, and std is for "
                  "the identifiable part.", markup=False)
    commit_outputs()
    out.print(_wrote(output, report_path), markup=False)


def _print_changes(params, limit: int = 10) -> None:
    """The largest parameter changes (scaled), in um / urad."""
    out = console()
    top = sorted((p for p in params if not p["fixed"]), key=lambda p: -p["scaled_change"])[:limit]
    changes = _table("parameter", "nominal", "identified", "change", "std", "",
                     title="largest parameter changes", justify={1: "right", 2: "right",
                                                                 3: "right", 4: "right"})
    for p in top:
        micro = "um" if p["kind"] == "length" else "urad"
        f = (1e3 if p["unit"] == "mm" else 1e6) if p["kind"] == "length" else \
            (math.pi / 180 * 1e6 if p["unit"] == "deg" else 1e6)
        if p["kind"] not in ("length", "angle"):     # a gain: relative change
            micro = "ppm"
            f = 1e6 / abs(p["nominal"]) if p["nominal"] else 1e6
        std = f"{p['std'] * f:.3g}" if p["std"] is not None else "fixed"
        changes.add_row(p["name"], f"{p['nominal']:.6f} {p['unit']}",
                        f"{p['identified']:.6f} {p['unit']}", f"{p['change'] * f:+.4g}", std,
                        micro)
    out.print(changes)


def grid_neighbour_pairs(P, abs_tol: float = 1e-4, rel_tol: float = 0.01) -> np.ndarray:
    """Index pairs (n, 2) of neighbouring points of an axis-aligned grid in positions ``P``.

    ``j`` is the neighbour of ``i`` along an axis when ``P_j - P_i`` points along the positive
    axis (off-axis part within ``abs_tol + rel_tol * distance``) and no closer point lies that
    way; missing grid points are allowed. Seed 001 Fig. 6 compares such pairs.
    """
    P = np.asarray(P, float)
    K = len(P)
    pairs = []
    for start in range(0, K, 512):                       # K x K temporaries in blocks
        D = P[None, :, :] - P[start:start + 512, None, :]   # (B, K, 3) P_j - P_i
        for axis in range(3):
            along = D[..., axis]
            off = np.linalg.norm(np.delete(D, axis, axis=-1), axis=-1)
            dist = np.where((along > abs_tol) & (off <= abs_tol + rel_tol * along), along,
                            np.inf)
            j = np.argmin(dist, axis=1)
            i = np.flatnonzero(np.isfinite(dist[np.arange(len(D)), j]))
            pairs.append(np.stack([i + start, j[i]], -1))
    return np.concatenate(pairs) if pairs else np.zeros((0, 2), int)


def distance_ratio_pairs(machine, q) -> tuple[np.ndarray, str]:
    """Pairs for the distance ratio: neighbours of the grid the readings were commanded to
    (``machine``'s forward kinematics of them, i.e. the commanded points when ``machine`` is
    the controller's model); nearest neighbours when the points form no grid."""
    P = machine.fk(q).P
    ok = np.all(np.isfinite(P), axis=-1)
    pairs = grid_neighbour_pairs(np.where(ok[:, None], P, 1e9))
    pairs = pairs[ok[pairs].all(axis=1)] if len(pairs) else pairs
    if len(pairs):
        return pairs, "neighbours on the commanded grid"
    D = np.linalg.norm(P[:, None] - P[None], axis=-1)
    np.fill_diagonal(D, np.inf)
    j = np.argmin(np.where(np.isfinite(D), D, np.inf), axis=1)
    pairs = np.unique(np.sort(np.stack([np.arange(len(P)), j], -1), axis=1), axis=0)
    return pairs[ok[pairs].all(axis=1)], "nearest neighbours (the points form no grid)"


def _ratio_stats(r) -> dict:
    r = np.asarray(r, float)
    r = r[np.isfinite(r)]
    if not r.size:
        return {"mean": None, "std": None, "min": None, "max": None}
    return {"mean": float(r.mean()), "std": float(r.std()), "min": float(r.min()),
            "max": float(r.max())}


def _check_spread(data, noise_model) -> None:
    """Refuse (nearly) collinear tracker points: the registration's rotation about their line
    would be fixed only by the noise. Also fewer than 4 points (seed 001 eq. 12-14)."""
    K = len(data)
    if K < 4:
        raise InputError(f"{data.source}: {K} point(s): the tracker registration needs at "
                         "least 4 points that are not on one line (seed 001 uses a 3x3x3 grid)")
    m = data.m - data.m.mean(0)
    sv = np.linalg.svd(m, compute_uv=False)
    off_line = sv[1] / math.sqrt(K)                       # RMS distance from the best line
    sigma = float(np.sqrt(np.max(np.trace(noise_model.covariance(data.m), axis1=1, axis2=2))))
    if off_line <= max(20 * sigma, 1e-6 * sv[0]):
        raise InputError(f"{data.source}: the {K} tracker points lie on one line or nearly (RMS "
                         f"distance from the best line {off_line * 1e6:.3g} um, tracker noise "
                         f"{sigma * 1e6:.3g} um): the "
                         "rotation of the tracker about that line cannot be found; measure "
                         "points spread in 2-3 directions (e.g. a 3x3x3 grid)")


def _calibrate_tracker(machine, machine_spec: str, data_path: Path, output: Path,
                       report_path: Path, noise: str | None, two_step: bool, robust: bool,
                       json_output: bool, report_dir: Path | None = None, split=None) -> int:
    from ..calibration import calibrate_tracker, distance_ratios, predict_tracker_points

    noise_model, noise_text = tracker_noise_arg(noise, allow_none=False, machine=machine)
    data, held = _split_rows(read_tracker(data_path, machine), split, data_path)
    _check_spread(data, noise_model)
    fk = machine.fk(data.q)
    if not fk.converged.all():
        raise InputError(f"{data_path}: row(s) {_rows_text(data.rows[~fk.converged])}: no "
                         f"platform position of {machine.source} reproduces these arm angles "
                         "(outside the workspace, or a wrong angle unit or zero)")
    result = _solve(data_path, calibrate_tracker, machine, data, noise_model, held=held,
                    joint=not two_step, robust=robust)
    if not _converged(result, data_path,
                      "spread the points in all three directions, e.g. a 3x3x3 grid"):
        return 1

    units = _units(machine)
    fl = LENGTH[units["length"]]
    method = "two-step" if two_step else "joint"
    calibrated = result.extras["machine"]
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    # FK start of the calibrated file: the input machine's home, else the measured position
    # closest to the middle of the data that the calibrated model reaches
    P_cal = calibrated.fk(data.q).P
    order = np.argsort(np.linalg.norm(P_cal - np.nanmean(P_cal, axis=0), axis=1))
    for P_home in [machine.home[0], *P_cal[order]]:
        if np.all(np.isfinite(calibrated.ik(P_home))):
            calibrated.home = (np.asarray(P_home, float), np.eye(3))
            break
    R, t = result.extras["registration"]
    R0, t0 = result.extras["start_registration"]
    kept = np.asarray(result.extras["kept"], bool)
    outlier_rows = [int(v) for v in result.extras["outlier_rows"]]
    date = run_date()

    nominal_of = dict(zip(machine.parameters.names, machine.u, strict=True))
    nominal_of.update(zip(("tracker.rx", "tracker.ry", "tracker.rz"), (0.0, 0.0, 0.0),
                          strict=True))
    nominal_of.update(zip(("tracker.x", "tracker.y", "tracker.z"), t0, strict=True))
    params = _parameter_table(result, nominal_of, units)

    # residuals in the tracker frame (m); before = nominal model + closed-form registration
    r = data.m - predict_tracker_points(calibrated, data.q, (R, t))
    r0 = data.m - predict_tracker_points(machine, data.q, (R0, t0))
    norm, norm0 = np.linalg.norm(r, axis=1), np.linalg.norm(r0, axis=1)
    rms = lambda v: float(np.sqrt(np.mean(v**2)) * 1e6) if v.size else None
    # distance ratio (seed 001 Fig. 6) over pairs of kept rows
    pairs, pairs_from = distance_ratio_pairs(machine, data.q)
    pairs = pairs[kept[pairs].all(axis=1)] if len(pairs) else pairs
    d_meas = np.linalg.norm(data.m[pairs[:, 0]] - data.m[pairs[:, 1]], axis=-1) \
        if len(pairs) else np.zeros(0)
    pairs = pairs[d_meas > 1e-9] if len(pairs) else pairs
    ratio_before = distance_ratios(machine, data.q, data.m, pairs) if len(pairs) else []
    ratio_after = distance_ratios(calibrated, data.q, data.m, pairs) if len(pairs) else []
    before, after = _ratio_stats(ratio_before), _ratio_stats(ratio_after)

    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.extras.get("unidentifiable", []))
    da, _, _, _, db = calibrated.legs()
    rot_change = float(np.degrees(np.linalg.norm(_rotvec(R @ R0.T))))
    report = {
        "pkmcal_report": 1,
        "command": "calibrate",
        "date": date,
        "machine_file": str(getattr(machine, "source", machine_spec)),
        "data_file": str(data_path),
        "calibrated_file": str(output),
        "measurement": "tracker",
        "method": method,
        "robust": robust,
        "units": units,
        "measurements": len(data),
        "used": int(kept.sum()),
        "outlier_rows": outlier_rows,
        "noise": noise_text,
        "smr_offset": machine.smr_offset / fl,
        "registration": {
            "estimated": not two_step,
            "rotation": R.tolist(), "translation": (np.asarray(t) / fl).tolist(),
            "unit": units["length"],
            "start": {"rotation": R0.tolist(), "translation": (np.asarray(t0) / fl).tolist(),
                      "method": "closed form (SVD) with the nominal model"},
            "rotation_change_deg": rot_change,
            "translation_change": float(np.linalg.norm(t - t0) / fl),
        },
        "convergence": {"success": bool(result.success), "status": int(result.status),
                        "message": result.message, "iterations": int(result.nit),
                        "evaluations": int(result.nfev)},
        "residuals": {
            "of": "tracker points, measured - predicted (3-D distance, tracker frame)",
            "count": int(kept.sum()),
            "rms_um": rms(norm[kept]),
            "max_um": float(norm[kept].max() * 1e6) if kept.any() else None,
            "rms_per_axis_um": (np.sqrt(np.mean(r[kept] ** 2, axis=0)) * 1e6).tolist(),
            "before_rms_um": rms(norm0[kept]),
            "before": "machine file's model, closed-form registration",
            "residual_variance": float(result.residual_variance),
            "noise_scale": float(np.sqrt(result.residual_variance))
            if np.isfinite(result.residual_variance) else None,
            "dof": int(result.dof),
            "outliers": [{"row": int(row), "residual_um": float(v * 1e6)} for row, v in
                         zip(data.rows[~kept], norm[~kept], strict=True)],
        },
        "distance_ratio": {
            "unit": "%", "pairs": int(len(pairs)), "pairs_from": pairs_from,
            "before": before, "after": after,
        },
        "identifiability": _identifiability_json(n_free, rank, unidentifiable, s),
        "identifiable_combinations": {
            "description": "db - da per leg (leg frame, file length unit): only this "
                           "difference enters the model" + (
                               "; with the tracker pose estimated it is fixed only up to one "
                               "common translation v of the platform (db_i - da_i + Rphi_i v "
                               "fits equally well)" if not two_step else ""),
            **{f"leg{i + 1}.db - leg{i + 1}.da": ((db[i] - da[i]) / fl).tolist()
               for i in range(3)}},
        "parameters": [{k: v for k, v in p.items() if k != "scaled_change"} for p in params],
    }
    if held is not None:
        d_after = np.linalg.norm(held.m - predict_tracker_points(calibrated, held.q, (R, t)),
                                 axis=1)
        d_before = np.linalg.norm(held.m - predict_tracker_points(machine, held.q, (R0, t0)),
                                  axis=1)
        ok = np.isfinite(d_after) & np.isfinite(d_before)
        report["validation"] = _validation(
            split, held, "tracker points of the held-out rows, measured - predicted (3-D "
            "distance) with the identified tracker pose; before: the machine file's model and "
            "the closed-form registration of the calibration rows", "um",
            rms(d_before[ok]), rms(d_after[ok]), report["residuals"]["rms_um"],
            max_after=float(d_after[ok].max() * 1e6) if ok.any() else None,
            not_reached=[int(r) for r in held.rows[~ok]])
    metadata = {
        "method": f"tracker-{method}",
        "date": date,
        "data": str(data_path),
        "machine": str(getattr(machine, "source", machine_spec)),
        "measurements": len(data),
        "outlier_rows": outlier_rows,
        "rms_residual_um": report["residuals"]["rms_um"],
        "identifiable": rank,
        "free_parameters": n_free,
        "unidentifiable": [f"{d.dimension} x {d.name}" for d in unidentifiable
                           if d.std is None],
        "weakly_identifiable": [d.name for d in unidentifiable if d.std is not None],
        "distance_ratio_std_percent": {"before": before["std"], "after": after["std"]},
        "report": report_path.name,
    }
    json_text = _write_calibration(calibrated, units, metadata, report, output, report_path,
                                   result, report_dir, nominal=machine)

    if json_output:
        print(json_text, end="")
    else:
        _print_tracker_calibration(report, params, data_path, output, report_path, machine)
    return 0


def _rotvec(R):
    from ..kinematics import rotvec_from_matrix

    return rotvec_from_matrix(R)


def _print_tracker_calibration(report, params, data_path, output, report_path, machine):
    out = console()
    res, ident, conv = report["residuals"], report["identifiability"], report["convergence"]
    reg, dr = report["registration"], report["distance_ratio"]
    unit = report["units"]["length"]
    table = _table("", "", title=f"pkmcal calibrate: {machine.source} with {data_path}",
                   show_header=False)
    table.add_row("measurement", f"laser tracker, {report['measurements']} points (reflector "
                  f"{report['smr_offset']:.6g} {unit} below the platform point)")
    table.add_row("method", "joint: the leg errors and the tracker pose together"
                  if report["method"] == "joint" else
                  "two-step (seed 001): tracker registered first with the nominal model, then "
                  "the leg errors with the registration fixed")
    table.add_row("identifiable", f"{ident['identifiable']} of {ident['free_parameters']} free "
                  "parameter directions" + (f", of which {len(ident['weakly_identifiable'])} "
                                            "weakly" if ident["weakly_identifiable"] else ""))
    groups: dict[str, list[str]] = {}                 # one line per description
    for d in ident["unidentifiable"]:
        groups.setdefault(d["description"], []).append(f"{d['dimension']} x {d['name']}")
    for description, names in groups.items():
        table.add_row("not identifiable", f"{', '.join(names)}: {description}")
    for d in ident["weakly_identifiable"]:
        table.add_row("weakly identifiable", f"{d['name']}: {d['description']}")
    scale = res["noise_scale"]
    table.add_row("RMS residual", f"{res['rms_um']:.4g} um over {res['count']} points (3-D, "
                  f"measured - predicted tracker point); before calibration "
                  f"{res['before_rms_um']:.4g} um ({res['before']})")
    table.add_row("noise", f"{report['noise']}" + (f"; residuals / assumed noise = {scale:.3g}"
                                                   if scale is not None else ""))
    if report["robust"]:
        if res["outliers"]:
            worst = ", ".join(f"row {o['row']}: {o['residual_um']:.4g} um"
                              for o in res["outliers"][:10])
            table.add_row("outliers", f"{len(res['outliers'])} row(s) left out (--robust): "
                          f"{worst}")
        else:
            table.add_row("outliers", "none found (--robust)")
    if dr["pairs"] and dr["before"]["std"] is not None:
        b, a = dr["before"], dr["after"]
        change = 100 * (1 - a["std"] / b["std"]) if b["std"] > 0 else 0.0
        change_text = f"{change:.3g} % smaller" if change >= 0 else f"{-change:.3g} % larger"
        table.add_row("distance ratio", f"spread (std) {b['std']:.4g} % before, {a['std']:.4g} % "
                      f"after ({change_text}); range {b['min']:.3f}..{b['max']:.3f} % -> "
                      f"{a['min']:.3f}..{a['max']:.3f} %; {dr['pairs']} pairs "
                      f"({dr['pairs_from']})")
    t = reg["translation"]
    table.add_row("tracker pose", f"base_from_tracker: tracker origin at ({t[0]:.6g}, "
                  f"{t[1]:.6g}, {t[2]:.6g}) {unit}; "
                  + ("estimated: " if reg["estimated"] else "fixed: ")
                  + f"{reg['rotation_change_deg']:.3g} deg and {reg['translation_change']:.3g} "
                  f"{unit} from the closed-form registration")
    if "validation" in report:
        table.add_row("held-out", report["validation"]["summary"])
    table.add_row("convergence", f"{conv['message']} ({conv['iterations']} iterations)")
    out.print(table)
    _print_changes(params)
    if scale is not None and scale > 3:
        causes = ["outliers (try --robust)" if not report["robust"] else None,
                  "a registration biased by the nominal model (drop --two-step)"
                  if report["method"] == "two-step" else None,
                  "a wrong smr_offset or noise model", "errors the model does not have"]
        out.print(f"note: the residuals are {scale:.3g} times the assumed noise: "
                  f"{', '.join(c for c in causes if c)}.", markup=False)
    if ident["unidentifiable"]:
        origin = (" and, with the tracker pose unknown, not the origin of the base frame"
                  if report["registration"]["estimated"] else "")
        out.print(f"note: the data fix only db - da of each leg{origin}; the "
                  "changes are the smallest ones (scaled) that fit the data, and std is for the "
                  "identifiable part.", markup=False)
    commit_outputs()
    out.print(_wrote(output, report_path), markup=False)


def _frame_report(frame, fl: float, unit: str) -> dict:
    R, t = frame
    from ..kinematics import rotation_angle

    return {"rotation": np.asarray(R, float).tolist(),
            "translation": (np.asarray(t, float) / fl).tolist(), "unit": unit,
            "rotation_angle_deg": float(np.degrees(rotation_angle(np.asarray(R, float))))}


def _errors_report(errors, fl: float) -> dict:
    s = errors.summary()
    return {"leg_length_rms": s["leg_length_rms"] / fl, "leg_length_max": s["leg_length_max"] / fl,
            "leg_length_rms_per_leg": [v / fl for v in s["leg_length_rms_per_leg"]],
            "position_rms": s["position_rms"] / fl, "position_max": s["position_max"] / fl,
            "orientation_rms_deg": float(np.degrees(s["orientation_rms"])),
            "orientation_max_deg": float(np.degrees(s["orientation_max"])),
            "fk_failed": s["fk_failed"]}


def _calibrate_full_pose(machine, machine_spec: str, data_path: Path, output: Path,
                         report_path: Path, method: str, noise: str | None,
                         pose_noise: str | None, fix_frames: bool, json_output: bool,
                         report_dir: Path | None = None, split=None) -> int:
    from ..calibration import calibrate_full_pose, full_pose_errors
    from ..measurements import MeasurementFrames

    noise_model = full_pose_noise_arg(noise, pose_noise, strict=True, machine=machine)
    data, held = _split_rows(read_full_pose(data_path, machine), split, data_path)
    file_frames = getattr(machine, "measurement_frames", None)
    if fix_frames:
        frames = file_frames if file_frames is not None else MeasurementFrames.identity()
        frames_from = ("the machine file's measurement_frames" if file_frames is not None
                       else "identity (the machine file has no measurement_frames)")
    else:
        frames = file_frames
        frames_from = ("start: the machine file's measurement_frames" if file_frames is not None
                       else "start: closed form from the design model")
    result = _solve(data_path, calibrate_full_pose, machine, data, held=held, method=method,
                    noise=noise_model, frames=frames, fix_frames=fix_frames)
    # the machine file's legs with the frames fitted alone: "before calibration"
    before = _solve(data_path, calibrate_full_pose, machine, data, held=held, method=method,
                    noise=noise_model, frames=frames if fix_frames
                    else result.extras["start_frames"], fix_frames=fix_frames,
                    fit_machine=False)
    if not _converged(result, data_path):
        return 1

    units = _units(machine)
    fl = LENGTH[units["length"]]
    calibrated = result.extras["machine"]
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    calibrated.home = machine.home
    frames_id = result.extras["frames"]
    err_after = full_pose_errors(calibrated, frames_id, data)
    err_before = full_pose_errors(machine, before.extras["frames"], data)
    date = run_date()

    from ..io.machine_file import reading_factor

    reading_unit = machine.reading_unit
    gain_factor = fl / reading_factor(reading_unit)         # internal gain -> file gain
    nominal_of = dict(zip(machine.parameters.names, machine.u, strict=True))
    start = result.extras["start_frames"]
    for name, (R, t) in (("mocap_from_base", start.mocap_from_base),
                         ("platform_from_marker", start.platform_from_marker)):
        nominal_of.update({f"{name}.r{c}": 0.0 for c in "xyz"})
        nominal_of.update({f"{name}.{c}": v for c, v in zip("xyz", t, strict=True)})
    params = _parameter_table(result, nominal_of, units)
    for p in params:
        if p["name"].endswith(".gain"):
            for key in ("nominal", "identified", "change", "std"):
                if p[key] is not None:
                    p[key] = p[key] / gain_factor
            p["unit"] = f"{units['length']}/{reading_unit}"
    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.extras.get("unidentifiable", []))
    variance = float(result.residual_variance)
    if hasattr(result.extras.get("problem"), "noise_whitened") and result.dof > 0:
        # the ik estimate takes the poses as exact, but their noise is in the residuals: the
        # residual variance relative to the whole noise (readings + poses through the IK)
        r = result.extras["problem"].noise_whitened(result.state)
        variance = float(np.sum(r**2) / result.dof)
    after, before_rep = _errors_report(err_after, fl), _errors_report(err_before, fl)
    report = {
        "pkmcal_report": 1,
        "command": "calibrate",
        "date": date,
        "machine_file": str(getattr(machine, "source", machine_spec)),
        "data_file": str(data_path),
        "calibrated_file": str(output),
        "measurement": "pose",
        "method": method,
        "units": units,
        "reading_unit": reading_unit,
        "measurements": len(data),
        "noise": {"reading_um": noise_model.reading_m * 1e6,
                  "position_um": noise_model.position_m * 1e6,
                  "orientation_urad": noise_model.orientation_rad * 1e6},
        "frames": {
            "fixed": bool(fix_frames), "from": frames_from,
            "mocap_from_base": _frame_report(frames_id.mocap_from_base, fl, units["length"]),
            "platform_from_marker": _frame_report(frames_id.platform_from_marker, fl,
                                                  units["length"]),
        },
        "convergence": {"success": bool(result.success), "status": int(result.status),
                        "message": result.message, "iterations": int(result.nit),
                        "evaluations": int(result.nfev)},
        "residuals": {
            "unit": units["length"],
            "leg_length": "l0 + gain q minus the leg length at the measured pose (through the "
                          "frames)",
            "pose": "measured marker pose minus the one forward kinematics of the readings "
                    "predict (through the frames)",
            "before": "the machine file's legs, frames fitted alone",
            "before_calibration": before_rep,
            "after_calibration": after,
            "residual_variance": variance,
            "noise_scale": math.sqrt(variance) if math.isfinite(variance) else None,
            "dof": int(result.dof),
        },
        "identifiability": _identifiability_json(n_free, rank, unidentifiable, s),
        "parameters": [{k: v for k, v in p.items() if k != "scaled_change"} for p in params],
    }
    if held is not None:
        h_after = _errors_report(full_pose_errors(calibrated, frames_id, held), fl)
        h_before = _errors_report(full_pose_errors(machine, before.extras["frames"], held), fl)
        report["validation"] = _validation(
            split, held, "pose error of the held-out rows: forward kinematics of the readings "
            "(through the identified frames) vs the measured pose; before: the machine file's "
            "legs, frames fitted alone on the calibration rows", units["length"],
            *_finite_or_none([h_before["position_rms"], h_after["position_rms"],
                              after["position_rms"]]), before_calibration=h_before,
            after_calibration=h_after)
    metadata = {
        "method": f"full-pose-{method}",
        "date": date,
        "data": str(data_path),
        "machine": str(getattr(machine, "source", machine_spec)),
        "measurements": len(data),
        "leg_length_rms": {"before": before_rep["leg_length_rms"],
                           "after": after["leg_length_rms"], "unit": units["length"]},
        "frames_fixed": bool(fix_frames),
        "identifiable": rank,
        "free_parameters": n_free,
        "unidentifiable": [f"{d.dimension} x {d.name}" for d in unidentifiable
                           if d.std is None],
        "weakly_identifiable": [d.name for d in unidentifiable if d.std is not None],
        "report": report_path.name,
    }
    json_text = _write_calibration(calibrated, units, metadata, report, output, report_path,
                                   result, report_dir, nominal=machine)
    if json_output:
        print(json_text, end="")
    else:
        _print_full_pose_calibration(report, params, data_path, output, report_path, machine)
    return 0


def _print_full_pose_calibration(report, params, data_path, output, report_path,
                                 machine) -> None:
    out = console()
    res, ident, conv = report["residuals"], report["identifiability"], report["convergence"]
    unit = report["units"]["length"]
    b, a = res["before_calibration"], res["after_calibration"]
    table = _table("", "", title=f"pkmcal calibrate: {machine.source} with {data_path}",
                   show_header=False)
    table.add_row("measurement", f"full pose, {report['measurements']} poses (readings in "
                  f"{report['reading_unit']}, marker pose in the measurement frame)")
    table.add_row("method", {"ml": "ml (maximum likelihood: readings and measured poses "
                                   "noisy, one pose unknown per measurement)",
                             "ik": "ik (inverse-kinematic residuals, Zhuang, Yan & Masory "
                                   "1998: measured poses exact)"}[report["method"]])
    table.add_row("identifiable", f"{ident['identifiable']} of {ident['free_parameters']} free "
                  "parameter directions" + (f", of which {len(ident['weakly_identifiable'])} "
                                            "weakly" if ident["weakly_identifiable"] else ""))
    for d in ident["unidentifiable"]:
        table.add_row("not identifiable", f"{d['dimension']} x {d['name']}: {d['description']}")
    for d in ident["weakly_identifiable"]:
        table.add_row("weakly identifiable", f"{d['name']}: {d['description']}")
    table.add_row("leg-length RMS", f"{b['leg_length_rms']:.4g} {unit} before, "
                  f"{a['leg_length_rms']:.4g} {unit} after ({res['before']})")
    table.add_row("pose error RMS", f"position {b['position_rms']:.4g} -> "
                  f"{a['position_rms']:.4g} {unit}, orientation "
                  f"{b['orientation_rms_deg']:.4g} -> {a['orientation_rms_deg']:.4g} deg "
                  "(forward kinematics of the readings vs measured)")
    n = report["noise"]
    scale = res["noise_scale"]
    table.add_row("noise", f"readings {n['reading_um']:.4g} um, position "
                  f"{n['position_um']:.4g} um, orientation {n['orientation_urad']:.4g} urad"
                  + (f"; residuals / assumed noise = {scale:.3g}" if scale is not None
                     else ""))
    fr = report["frames"]
    m, k = fr["mocap_from_base"], fr["platform_from_marker"]
    table.add_row("frames", ("fixed: " if fr["fixed"] else f"estimated ({fr['from']}): ")
                  + "mocap_from_base turned "
                  f"{m['rotation_angle_deg']:.4g} deg, base origin at "
                  f"({', '.join(f'{v:.6g}' for v in m['translation'])}) {unit} measured; "
                  f"platform_from_marker turned {k['rotation_angle_deg']:.4g} deg, marker at "
                  f"({', '.join(f'{v:.6g}' for v in k['translation'])}) {unit}")
    if "validation" in report:
        table.add_row("held-out", report["validation"]["summary"])
    table.add_row("convergence", f"{conv['message']} ({conv['iterations']} iterations)")
    out.print(table)
    _print_changes(params)
    if scale is not None and scale > 3:
        out.print(f"note: the residuals are {scale:.3g} times the assumed noise: give the real "
                  "noise (--noise, --pose-noise), or the model lacks errors the machine has.",
                  markup=False)
    if ident["unidentifiable"]:
        out.print("note: the data fix the legs only relative to the measurement frames; the "
                  "changes are the smallest ones (scaled) that fit the data, and std is for "
                  "the identifiable part.", markup=False)
    commit_outputs()
    out.print(_wrote(output, report_path), markup=False)


# --------------------------------------------------------------------------------------------
# fk, ik
# --------------------------------------------------------------------------------------------


def run_fk(machine_spec: str, joints: Path, output: Path) -> None:
    machine = load_machine_arg(machine_spec)
    check_outputs([output], [joints] + _machine_inputs(machine_spec))
    if machine.kind == "stewart":
        q, rows = read_readings(joints, machine)
    else:
        q, rows, _ = read_joints(joints, machine.n_joints, joint_quantity(machine), machine)
    result = machine.fk(q)
    result.raise_if_failed(what=f"{joints}: forward kinematics", rows=rows)
    units = _units(machine)
    if machine.pose_dof == 3:
        write_positions(output, result.P, units["length"])
        commit_outputs()
        console().print(f"{len(q)} position(s) of the platform point, base frame, written to "
                        f"{output} ({units['length']})", markup=False)
        return
    write_poses(output, result.P, result.R, units["length"], units["angle"])
    commit_outputs()
    console().print(f"{len(q)} pose(s) written to {output} ({units['length']}, "
                    f"{units['angle']})", markup=False)


def read_poses_of(path: Path, machine):
    """Poses ``(P, R, rows)`` of a file for ``machine``: x, y, z and an orientation (other
    columns ignored); x, y, z only (R = I) for a translation-only platform."""
    if machine.pose_dof == 3:
        P, rows = read_positions(path)
        return P, np.broadcast_to(np.eye(3), (len(P), 3, 3)), rows
    return read_poses(path)


def joint_columns(machine, q, units) -> dict:
    """``q1_<unit> ...`` columns of joint values (K, n) in the file's units: the machine
    file's length or angle unit, a Stewart's reading unit."""
    if machine.kind == "stewart":
        unit = getattr(machine, "reading_unit", "m")
        f = LENGTH.get(unit, 1.0)
    elif joint_quantity(machine) == "angle":
        unit = units["angle"]
        f = ANGLE[unit]
    else:
        unit = units["length"]
        f = LENGTH[unit]
    return {f"q{j + 1}_{unit}": (q[:, j] / f).tolist() for j in range(q.shape[1])}


def refuse_outside_limits(machine, q, rows, what: str) -> None:
    """Refuse joint values ``q`` (K, n) outside the machine file's ``joint_limits``, naming
    the rows and joints; ``what`` starts the message (``{n}``: the count of such rows)."""
    outside = ~machine.within_limits(q) & np.all(np.isfinite(q), axis=-1)
    if outside.any():
        source = getattr(machine, "source", None) or "the machine file"
        raise InputError(f"{what.format(n=int(outside.sum()))} need joint values outside the "
                         f"joint limits of {source} ({machine.joint_limits_text()}): "
                         f"{machine.limit_violation_text(q[outside], np.asarray(rows)[outside])}")


def run_ik(machine_spec: str, poses: Path, output: Path) -> None:
    machine = load_machine_arg(machine_spec)
    check_outputs([output], [poses] + _machine_inputs(machine_spec))
    P, R, rows = read_poses_of(poses, machine)
    q = machine.ik(P, R)
    bad = ~np.all(np.isfinite(q), axis=1)
    what = "leg" if machine.kind in ("delta", "stewart") else "chain"
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
    if machine.pose_dof == 3:
        # the closed-form FK takes the working assembly mode (platform below the base): a
        # position the arms reach only on the other mode cannot be commanded back
        back = machine.fk(q).P
        off = ~(np.linalg.norm(back - P, axis=1) <= 1e-9 + 1e-9 * np.linalg.norm(P, axis=1))
        if off.any():
            raise InputError(f"{poses}: {int(off.sum())} position(s) outside the working "
                             f"assembly mode (the platform must hang below the base), row(s) "
                             f"{_rows_text(rows[off])}")
    refuse_outside_limits(machine, q, rows, f"{poses}: {{n}} pose(s)")
    columns = joint_columns(machine, q, _units(machine))
    write_table(output, list(columns), list(columns.values()))
    unit = next(iter(columns)).split("_", 1)[1]
    commit_outputs()
    console().print(f"{len(q)} {'leg reading' if machine.kind == 'stewart' else 'joint'} "
                    f"vector(s) written to {output} ({unit})", markup=False)


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
    if getattr(machine, "kind", "") != "stewart":
        raise InputError(f"{spec}: pkmcal errors needs a six-leg machine (machine: stewart; "
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
        raise InputError(f"{path}: missing column t_s (time of each pose); columns found: "
                         f"{', '.join(header)}")
    if len(t_cols) > 1:
        raise InputError(f"{path}: more than one time column: "
                         f"{', '.join(header[i] for i in t_cols)}; keep one")
    name = header[t_cols[0]]
    unit = name[2:]
    if unit not in TIME:
        raise InputError(f"{path}: column {name!r}: "
                         + ("no unit suffix" if not unit else f"unknown time unit {unit!r}")
                         + f" (write t_s; accepted: {', '.join('t_' + u for u in TIME)})")
    t = np.array([parse_number(path, line, name, f[t_cols[0]]) for line, f in rows]) * TIME[unit]
    if has_orientation(header):
        P, R, lines = read_poses(path)
    else:
        P, lines = read_positions(path)
        R = np.broadcast_to(np.eye(3), (len(P), 3, 3)).copy()
    if len(t) < 3:
        raise InputError(f"{path}: {len(t)} pose(s); a trajectory needs at least 3 to give "
                         "accelerations")
    h = np.diff(t)
    if not np.all(h > 0):
        k = int(np.flatnonzero(~(h > 0))[0])
        raise InputError(f"{path}: row {lines[k + 1]}, column {name}: times must increase "
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
        raise InputError(f"--plot {plot}: exists and is not a directory")
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
        where = f"{trajectory_file}: {len(t)} poses over {t[-1] - t[0]:.6g} s"
    try:
        if trajectory == "file":
            err.check_poses(machine, path.P, path.R, lines, "row")
        else:
            err.check_poses(machine, path.P, path.R, np.arange(len(path)), "sample")
    except InputError as exc:
        raise InputError(f"{trajectory_file}: {exc}" if trajectory == "file" else
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
                               title=f"pose error from joint clearance {c_base * 1e6:.3g} um"
                                     + (f" (platform {c_platform * 1e6:.3g} um)"
                                        if c_platform != c_base else "")
                                     + (f", backlash {backlash * 1e6:.3g} um" if backlash
                                        else "")),
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
    table = _table("", "", title=f"pkmcal errors: {machine.source}", show_header=False)
    table.add_row("trajectory", where)
    inertia = mass_kg * np.max(np.linalg.norm(path.acceleration, axis=1))
    table.add_row("loads", f"weight {mass_kg * STANDARD_GRAVITY:.5g} N ({mass_kg:.6g} kg), "
                  f"cutting force ({', '.join(f'{v:.6g}' for v in f_cut)}) N, inertia up to "
                  f"{inertia:.5g} N")
    table.add_row("clearance", f"{c_base * 1e6:.6g} um (base joints), {c_platform * 1e6:.6g} um "
                  f"(platform joints); backlash {backlash * 1e6:.6g} um; side undetermined "
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
        errors.add_row(name, f"{v.min():.4g}", f"{v.max():.4g}",
                       f"{e.dx_min[:, j].min() * 1e6:.4g} .. {e.dx_max[:, j].max() * 1e6:.4g}",
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


# --------------------------------------------------------------------------------------------
# identifiability
# --------------------------------------------------------------------------------------------

_MEASUREMENT_WORDS = {
    "constraint-link": "constraint link (maximum likelihood: every reading noisy; one pose "
                       "on the sphere per measurement)",
    "tracker": "laser tracker (tracker pose estimated jointly)",
    "pose": "full pose (maximum likelihood; both measurement frames estimated)",
}
