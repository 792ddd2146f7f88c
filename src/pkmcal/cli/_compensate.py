"""``pkmcal compensate``: joint commands from a calibrated machine file (SPEC 4)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..calibration.run import file_units as _units
from ..calibration.run import json_safe as _finite_or_none
from ..errors import InputError
from ..paths import path_text, recorded_path
from ..units import format_um, format_urad
from ..workflows.report import calibration_report_path
from ._commands import (
    _machine_inputs,
    _table,
    check_outputs,
    group_numbers,
    joint_columns,
    load_machine_arg,
    read_poses_of,
    refuse_outside_limits,
    refuse_unreachable,
)
from ._console import console, warning


def read_covariance(path: Path, machine, with_frames: bool = False):
    """The machine-parameter covariance of a calibration report (JSON), checked against the
    machine's parameter names, and the unidentifiable directions (n, k) when given; with
    ``with_frames`` also ``(names, matrix)`` of the machine and frame parameters together."""
    from ..report.schema import load_report

    cov = load_report(path).get("covariance")
    if cov is None:
        raise InputError(f"{path_text(path)}: no covariance section (written by pkmcal calibrate); "
                         "calibrate again with this version or leave out --report")
    names = list(machine.parameters.names)
    if list(cov["parameters"]) != names:
        raise InputError(f"{path_text(path)}: the covariance is of other parameters than those of "
                         f"{getattr(machine, 'source', 'the machine')} (another machine?)")
    C = np.asarray(cov["matrix"], float)          # shapes and finiteness: load_report
    N = None
    if cov.get("null_space") is not None:
        N = np.asarray(cov["null_space"], float)  # n rows of one length: load_report
    if not with_frames:
        return C, N
    full = cov.get("with_frames")
    if full is None:
        raise InputError(f"{path_text(path)}: no covariance of the measurement frames (covariance."
                         "with_frames); calibrate again with this version")
    all_names = [str(v) for v in full["parameters"]]
    C_all = np.asarray(full["matrix"], float)
    return C, N, (all_names, C_all)


def choose_frame(machine, machine_spec: str, instrument: str | None):
    """The instrument frame of ``--frame instrument``: the one ``--instrument`` names, or the
    only one the calibrated file carries (a tracker's or motion capture's)."""
    from ..compensation import instrument_frames
    from ..instruments import instrument_name
    from ..instruments.registry import instrument as entry

    where = getattr(machine, "source", machine_spec)
    frames = instrument_frames(machine)
    if not frames:
        ballbar = (" (its ballbar section gives distances, not a frame to place targets in)"
                   if getattr(machine, "ballbar_setups", None) else "")
        raise InputError(f"--frame instrument: {where} has no instrument frame{ballbar}: a "
                         "calibration from points writes the tracker section (targets in the "
                         "tracker's frame), one from poses writes measurement_frames (marker "
                         "poses in the motion-capture frame); a constraint-link calibration "
                         "measures in no external frame: give the targets in the base frame")
    if instrument is not None:
        name = instrument_name(instrument)
        if name not in frames:
            raise InputError(f"--instrument {instrument}: {where} has no "
                             f"{entry(name).section} frame to give targets in; it has: "
                             f"{', '.join(frames)}")
        return frames[name]
    if len(frames) > 1:
        raise InputError(f"--frame instrument: {where} carries several instrument frames: "
                         f"name one with --instrument ({'|'.join(frames)})")
    return next(iter(frames.values()))


def read_instrument_targets(path: Path, machine, frame):
    """Targets in the instrument's frame: ``(P, R, rows, group)``. A tracker's targets are
    x, y, z, with an optional orientation (a platform that rotates; tracker frame; without it
    the home orientation: R None) and an optional ``target`` column (1..K); marker poses are
    full poses."""
    from ..instruments.registry import instrument
    from ..io.csv_io import has_orientation, read_positions, read_table

    column = instrument(frame.instrument).group_column     # numbered targets (a tracker's)
    if column is None:
        P, R, rows = read_poses_of(path, machine)
        return P, R, rows, None
    header, table = read_table(path)
    if machine.rotates and has_orientation(header):
        P, R, rows = read_poses_of(path, machine)
    elif machine.rotates:
        (P, rows), R = read_positions(path), None
    else:
        P, _, rows = read_poses_of(path, machine)
        R = None
    extra = {name: [f[k] for _, f in table] for k, name in enumerate(header)}
    group = group_numbers(path, extra, rows, column)
    n = len(frame.targets)
    if group is not None and machine.tracker_target() is None and group.max() >= n:
        k = int(np.argmax(group >= n))
        raise InputError(f"{path_text(path)}: "
                         f"row {rows[k]}, column target: target {group[k] + 1}, but "
                         f"the machine file's tracker section has {n} target(s) (numbered "
                         f"1..{n})")
    return P, R, rows, group


def run_compensate(machine_spec: str, targets: Path, output: Path, report: Path | None,
                   nominal_spec: str | None, json_output: bool, frame_name: str = "base",
                   instrument: str | None = None) -> int:
    from ..compensation import compensate, target_frame

    machine = load_machine_arg(machine_spec)
    frame = None
    if frame_name == "instrument":
        frame = choose_frame(machine, machine_spec, instrument)
    elif instrument is not None:
        raise InputError(f"--instrument {instrument}: only with --frame instrument (targets in "
                         "that instrument's frame)")
    inputs = [targets] + _machine_inputs(machine_spec) + ([report] if report else [])
    check_outputs([output], inputs)
    nominal = None
    if nominal_spec is not None:
        nominal = load_machine_arg(nominal_spec)
        for ext in nominal.model_extensions():      # adopted by the calibration: the nominal
            if set(ext.parameters) <= set(machine.parameters.names):  # at its neutral values
                nominal = ext.apply(nominal)
        if nominal.kind != machine.kind or \
                list(nominal.parameters.names) != list(machine.parameters.names):
            raise InputError(f"--nominal {nominal_spec}: a {nominal.kind} with other parameters "
                             f"than the calibrated {machine.kind}")
    report_path = calibration_report_path(machine, machine_spec, report)
    C, N, names = None, None, None
    if report_path is not None and frame is not None:
        _, N, (names, C) = read_covariance(report_path, machine, with_frames=True)
    elif report_path is not None:
        C, N = read_covariance(report_path, machine)
    group = None
    if frame is None:
        P, R, rows = read_poses_of(targets, machine)
    else:
        P, R, rows, group = read_instrument_targets(targets, machine, frame)
        frame = frame.with_group(group)
    if len(P) == 0:
        raise InputError(f"{path_text(targets)}: no target rows")
    try:
        comp = compensate(machine, P, R, C, nominal, N, frame=frame, names=names)
    except ValueError as exc:
        raise InputError(f"{path_text(report_path)}: {exc}") from None
    refuse_unreachable(machine, comp.reach, f"{path_text(targets)}: {{n}} target(s) cannot be "
                       "reached by the calibrated machine", rows, (P, R))
    refuse_outside_limits(machine, comp.q, rows, f"{path_text(targets)}: {{n}} target(s)")
    units = _units(machine)
    columns = joint_columns(machine, comp.q, units)
    if comp.position_std is not None:
        columns["predicted_position_um"] = (comp.position_std * 1e6).tolist()
        if comp.orientation_std is not None:
            columns["predicted_orientation_urad"] = (comp.orientation_std * 1e6).tolist()
    if comp.uncompensated_position is not None:
        columns["uncompensated_position_um"] = (comp.uncompensated_position * 1e6).tolist()
        if comp.uncompensated_orientation is not None:
            columns["uncompensated_orientation_urad"] = (
                comp.uncompensated_orientation * 1e6).tolist()
    from ..io import write_poses, write_positions

    if group is not None:
        columns = {"target": (group + 1).tolist(), **columns}
    if not machine.rotates or R is None:
        write_positions(output, P, units["length"], extra=columns)
    else:
        write_poses(output, P, R, units["length"], units["angle"], extra=columns)

    def stats(v, scale):
        if v is None:
            return None
        v = np.asarray(v, float) * scale
        f = v[np.isfinite(v)]
        return {"rms": float(np.sqrt(np.mean(f**2))) if f.size else None,
                "max": float(f.max()) if f.size else None}

    summary = {
        "pkmcal_report": 1,
        "command": "compensate",
        "machine_file": path_text(getattr(machine, "source", machine_spec)),
        "targets_file": path_text(targets),
        "commands_file": path_text(output),
        "targets": int(len(P)),
        "targets_frame": "base" if frame is None else frame.description,
        "covariance_from": None if report_path is None else path_text(report_path),
        "nominal_file": nominal_spec,
        "predicted_position_um": stats(comp.position_std, 1e6),
        "predicted_orientation_urad": stats(comp.orientation_std, 1e6),
        "uncompensated_position_um": stats(comp.uncompensated_position, 1e6),
        "uncompensated_orientation_urad": stats(comp.uncompensated_orientation, 1e6),
    }
    if report_path is None:
        named = (getattr(machine, "calibration_info", None) or {}).get("report")
        where = (f"{path_text(recorded_path(Path(machine_spec).parent, str(named)))} (named by "
                 f"{path_text(machine_spec)}) is missing"
                 if named else "no calibration report (JSON with a covariance) beside the "
                               "machine file")
        warning(f"{where}: the predicted residual error is not given; pass --report FILE.json")
    if json_output:
        print(json.dumps(_finite_or_none(summary), indent=2, allow_nan=False))
        return 0
    table = _table("", "", title=f"pkmcal compensate: {summary['machine_file']}",
                   show_header=False)
    table.add_row("targets", f"{len(P)} from {path_text(targets)} ("
                  + (machine.working_frame_words if frame is None
                     else frame.description) + ")")
    table.add_row("commands", f"{path_text(output)} "
                  f"({', '.join(list(columns)[:machine.n_joints])})")
    pp, po = summary["predicted_position_um"], summary["predicted_orientation_urad"]
    if pp:
        text = f"position {format_um(pp['rms'], 3)} RMS, {format_um(pp['max'], 3)} max"
        if po:
            text += (f"; orientation {format_urad(po['rms'], 3)} RMS, "
                     f"{format_urad(po['max'], 3)} max")
        table.add_row("predicted residual", f"{text} (1 sigma, from the calibration's "
                      f"covariance in {path_text(report_path)}; " + (
                          "frames the data cannot fix aligned)" if frame is None else
                          "in the instrument's frame, its pose uncertainty included)"))
    up, uo = summary["uncompensated_position_um"], summary["uncompensated_orientation_urad"]
    if up:
        text = f"position {format_um(up['rms'])} RMS, {format_um(up['max'])} max"
        if uo:
            text += f"; orientation {format_urad(uo['rms'])} RMS, {format_urad(uo['max'])} max"
        table.add_row("without compensation", f"{text} (commands of {nominal_spec}, as the "
                      "calibrated model sees them; frames the data cannot fix aligned)")
    console().print(table)
    unseen = (getattr(machine, "calibration_info", None) or {}).get("unidentifiable") or []
    if frame is None and unseen and target_frame(machine) is not None:
        console().print(
            f"note: the calibration data did not fix {'; '.join(map(str, unseen))[:300]}: "
            "base-frame targets land off by that unknown motion (often millimetres). Give the "
            "targets in the instrument's frame (--frame instrument) or set the work offset on "
            "the machine (touch off a reference).", markup=False)
    elif frame is None and unseen:
        console().print(
            f"note: the calibration data did not fix {'; '.join(map(str, unseen))[:300]}: "
            "the base frame keeps the machine file's orientation there; register the work "
            "frame on the machine (probe or touch off a reference) and give the targets in "
            "it.", markup=False)
    return 0

