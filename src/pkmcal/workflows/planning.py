"""``pkmcal identifiability`` and ``pkmcal select-poses`` as library functions: what
measurements will identify and how accurate the calibration will be, before and after
measuring (SPEC 3). They read the user's files and options, check them (an
:class:`~pkmcal.errors.InputError` naming the file, row or option), compute with
:func:`pkmcal.planning.assess_identifiability` and :func:`pkmcal.planning.select_plan`, write
their outputs all or none and return a :class:`~pkmcal.report.summary.Summary`.

Example
-------
>>> from pkmcal.workflows.planning import identifiability
>>> summary = identifiability("default", poses=30)            # doctest: +SKIP
>>> print(summary.text())                                     # doctest: +SKIP
"""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..calibration.run import file_units as _units
from ..errors import InputError
from ..instruments.flow import json_safe, rows_text
from ..instruments.probe import bed_plane
from ..instruments.registry import INSTRUMENTS, instrument
from ..io import read_table
from ..paths import path_text
from ..planning import WORKSPACE_POSES, noise_model
from ..plausibility import check_option_scale
from ..report.summary import Summary
from ..units import LENGTH, format_quantity, format_um, format_urad, parse_quantity
from .common import (
    check_outputs,
    commit_outputs,
    in_output_set,
    load_machine_setups_arg,
    no_progress,
)
from .poses import (
    joint_columns,
    read_poses_of,
    read_targets_of,
    refuse_outside_limits,
    refuse_unreachable,
    working_positions,
)

__all__ = ["identifiability", "select_poses", "workspace_arg", "planning_setup",
           "plan_groups", "joint_bounds", "parse_joint_range"]


def plan_groups(path: Path, kind: str, rows):
    """The 0-based group of each planned pose of a plan file (the instrument's
    ``group_column``: a ballbar's ``setup``, a tracker's ``target``), None without it."""
    from ..io.csv_io import read_groups

    column = instrument(kind).group_column
    if column is None:
        return None
    header, table = read_table(path)
    if column not in header:
        return None
    extra = {name: [f[k] for _, f in table] for k, name in enumerate(header)}
    lines = [line for line, _ in table]
    groups = read_groups(path, extra, lines, column)
    if rows is not None and len(rows) != len(groups):
        keep = np.isin(lines, np.asarray(rows))
        groups = groups[keep]
    return groups


def planning_setup(machine, kind: str, setups: int | None, radius: str | None,
                   targets: int | None, setup=None):
    """The set-up ``kind``'s plans use: the machine file's (``setup``), or with
    ``--setups`` / ``--radius`` a ballbar's planned mountings
    (:meth:`~pkmcal.instruments.base.Instrument.planned_setup`); refuses the options the
    instrument does not take."""
    inst = instrument(kind)
    for option, value in (("setups", setups), ("radius", radius), ("targets", targets)):
        if value is not None and option not in inst.plan_options:
            owner = next(i.name for i in INSTRUMENTS.values() if option in i.plan_options)
            raise InputError(f"--{option}: applies to {owner} measurements, not {kind}")
    length = None
    if radius is not None:
        length = parse_quantity(radius, "length", "--radius")
        if not length > 0:
            raise InputError(f"--radius: the ballbar length must be > 0, got {radius}")
        check_option_scale(length, machine, "--radius", "size", radius)
    options = {"setups": setups, "length": length, "targets": targets}
    return inst.planned_setup(machine, setup, **{k: v for k, v in options.items()
                                                 if v is not None})


def workspace_arg(text: str | None, machine, seed: int = 0, setups=None):
    """The workspace of the predicted accuracy: ``--workspace`` (a box
    ``X0,X1,Y0,Y1,Z0,Z1`` with units, or a CSV of points) or, without it, the SPEC 5 cube
    around home. Every pose must be reachable from home's working mode and within the
    machine file's joint limits (and above a printer's bed, the plane of its set-ups
    ``setups``: :meth:`~pkmcal.machines.Machine.reachability`). The box and the points are in
    the machine's working frame with those set-ups (a printer's: z the height above
    its bed, :meth:`~pkmcal.instruments.setups.Setups.targets_in_base`); the workspace
    returned is in the base frame."""
    from ..analysis.accuracy import box_workspace, default_workspace

    if text is None:
        return default_workspace(machine, WORKSPACE_POSES, seed)
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) == 6 and not Path(text).exists():
        unit = re.match(r"^.*?([A-Za-z]*)$", parts[-1]).group(1)
        if unit and not any(re.search(r"[A-Za-z]$", p) for p in parts[:-1]):
            parts = [p + unit for p in parts[:-1]] + parts[-1:]     # 0,100,...,350mm
        v = [parse_quantity(p, "length", "--workspace") for p in parts]
        lo, hi = np.array(v[0::2]), np.array(v[1::2])
        bad = [c for c, a, b in zip("XYZ", lo, hi, strict=True) if not a < b]
        if bad:
            raise InputError(f"--workspace {text}: {bad[0]}0 must be below {bad[0]}1 (a box "
                             "X0,X1,Y0,Y1,Z0,Z1, e.g. -50mm,50mm,-50mm,50mm,250mm,350mm)")
        for value, part in zip(v, parts, strict=True):
            check_option_scale(value, machine, "--workspace", "size", part)
        unit_name = _units(machine)["length"]
        f = LENGTH[unit_name]
        words = "box " + ", ".join(f"{c} {a / f:.6g}..{b / f:.6g} {unit_name}"
                                   for c, a, b in zip("xyz", lo, hi, strict=True))
        ws = box_workspace(machine, lo, hi, WORKSPACE_POSES, seed,
                           description=words + " (--workspace)")
        rows = None
    else:
        ws, rows = _points_workspace(Path(text), machine, seed)
    given = ws.P
    if setups is not None and not setups.working_frame_is_base(machine):
        ws = replace(ws, P=setups.targets_in_base(machine, ws.P))     # above a printer's bed
    _check_workspace(machine, ws, text, rows, bed_plane(setups), given)
    return ws


def _points_workspace(path: Path, machine, seed: int):
    """The poses of a ``--workspace`` points file (x, y, z [+ orientation]; without
    orientation columns, orientations drawn within +/-10 deg as for the default workspace)
    and the file rows: ``(Workspace, rows)``."""
    from ..analysis.accuracy import Workspace
    from ..io import read_positions
    from ..io.csv_io import column_map, has_orientation
    from ..kinematics import matrix_from_euler

    if not path.exists():
        raise InputError(f"--workspace {path_text(path)}: neither a box X0,X1,Y0,Y1,Z0,Z1 (six "
                         "lengths "
                         "with units) nor an existing points file")
    with column_map(None):           # --columns renames the data file's columns, not these
        header, _ = read_table(path)
        words = f"{{n}} poses of {path_text(path)} (--workspace)"
        if has_orientation(header) and machine.rotates:
            P, R, rows = read_poses_of(path, machine)
        else:
            P, rows = read_positions(path)
            rng = np.random.default_rng(seed)
            R = matrix_from_euler(rng.uniform(-1, 1, (len(P), 3)) * np.deg2rad(10.0))
            if not machine.rotates:
                R = np.broadcast_to(np.eye(3), R.shape)
            else:
                words = (f"{{n}} points of {path_text(path)} (--workspace), orientations within "
                         "+/-10 deg")
    return Workspace(P, np.asarray(R), words.format(n=len(P)),
                     (P.min(axis=0), P.max(axis=0))), rows


def _check_workspace(machine, ws, text: str, rows, bed=None, given=None) -> None:
    """Refuse workspace poses the machine cannot take (:meth:`~pkmcal.machines.Machine.
    reachability`: unreachable, another working mode, past the machine's physical limits such
    as a printer's endstops and bed, joints outside its limits), naming the rows of a points
    file or, for a box, the first such pose (at ``given``, its positions as the user gave
    them, default ``ws.P``), and why."""
    reach = machine.reachability(ws.P, ws.R, bed=bed)
    q = reach.q
    k = np.flatnonzero(~reach.ok & ~reach.limits_only)
    if k.size:
        R = ws.R[k[0]] if machine.rotates else None
        shown = ws.P if given is None else given
        pose = f"{machine.pose_text(shown[k[0]], R)}: {reach.reasons[int(k[0])]}"
        where = (f"row(s) {rows_text(np.asarray(rows)[k])}: out of the machine's reach: row "
                 f"{np.asarray(rows)[k[0]]} at {pose}" if rows is not None else
                 f"{k.size} of its {len(ws.P)} sampled poses: out of the machine's reach, "
                 f"e.g. at {pose}")
        raise InputError(f"--workspace {text}: {where}; give a workspace the machine reaches")
    if rows is None:
        rows = np.arange(1, len(q) + 1)
        what = f"--workspace {text}: {{n}} of its sampled poses"
    else:
        what = f"--workspace {text}: {{n}} pose(s)"
    refuse_outside_limits(machine, q, rows, what)


def _prediction_rows(table, section: dict) -> None:
    """The "predicted accuracy" row of a planning table from a prediction section
    (:func:`pkmcal.planning.prediction_summary`): RMS and max position (and orientation)
    error, or why it is unbounded."""
    if section["unbounded_directions"]:
        table.add_row("predicted accuracy", f"unbounded: {section['unbounded_directions']} "
                      "unidentifiable direction(s) move the platform relative to every frame; "
                      "add measurements that see them")
        return
    text = (f"position {format_um(section['position_rms_um'], 3)} RMS, "
            f"{format_um(section['position_max_um'], 3)} max")
    if "orientation_rms_urad" in section:
        text += (f"; orientation {format_urad(section['orientation_rms_urad'], 3)} RMS, "
                 f"{format_urad(section['orientation_max_urad'], 3)} max")
    table.add_row("predicted accuracy", f"{text} (1 sigma, Cramer-Rao, over the "
                  f"{section['workspace']}; {section['noise']})")


def _with_set(machine, parameters: str | None):
    """The machine with the fixed flags of its parameter set ``--parameters`` (if given)."""
    if parameters is None:
        return machine
    from ..calibration.parameter_sets import apply_parameter_set

    return apply_parameter_set(machine, parameters)


@in_output_set
def identifiability(machine_spec: str, data_path: Path | None = None, *,
                    json_output: bool = False, planned: bool = False, poses: int | None = None,
                    seed: int = 0, noise: str | None = None, pose_noise: str | None = None,
                    map_path: Path | None = None, workspace: str | None = None,
                    scenario: str | None = None, setups: int | None = None,
                    radius: str | None = None, targets: int | None = None,
                    parameters: str | None = None) -> Summary:
    """``pkmcal identifiability``: what measurements identify and the accuracy they predict,
    for every scenario on every machine it applies to, from measurements of any kind
    (``data_path``), a plan file (``data_path`` with ``planned``) or the instrument's standard
    or random plan (no ``data_path``).

    Parameters
    ----------
    machine_spec : str
        A machine file, or ``"default"``.
    data_path : Path, optional
        Measurements (the kind follows from the columns) or, with ``planned``, planned poses.
    json_output : bool
        The summary is the JSON report (raw text) instead of the tables.
    planned : bool
        ``data_path`` holds planned poses, not measurements.
    poses : int, optional
        Without ``data_path``: the number of random planned poses.
    seed : int
        Seed of random planned poses and of the workspace sample.
    noise, pose_noise : str, optional
        The noise model of the prediction, as ``calibrate --noise`` / ``--pose-noise``.
    map_path : Path, optional
        A PNG map of the predicted position error, written with the rest or not at all.
    workspace : str, optional
        ``--workspace``: a box ``X0,X1,Y0,Y1,Z0,Z1`` with units or a points file
        (:func:`workspace_arg`).
    scenario : str, optional
        The instrument of a plan (default the machine type's own).
    setups, radius, targets : optional
        Plan options of the instruments that take them (:func:`planning_setup`).
    parameters : str, optional
        The machine's named parameter set to analyse.

    Returns
    -------
    Summary
        The identifiability table (identifiable, weak and unidentifiable directions,
        condition number, observability, minimal set, predicted accuracy) and the correlated
        pairs; or the JSON report. Exit code 0.

    Raises
    ------
    InputError
        A bad file or option, named; nothing is written.
    """
    from ..calibration.run import measurement_kind
    from ..planning import assess_identifiability, scenario_for

    machine, file_setups = load_machine_setups_arg(machine_spec)
    machine = _with_set(machine, parameters)
    ws_file = [Path(workspace)] if workspace is not None and Path(workspace).exists() else []
    if map_path is not None or ws_file:
        check_outputs([map_path] if map_path is not None else [],
                      [p for p in (data_path,) if p is not None] + ws_file)
    ws = workspace_arg(workspace, machine, seed, setups=file_setups)
    if data_path is None and planned:
        raise InputError("--planned: give the plan file (DATA) with the planned poses")
    if data_path is not None and poses is not None:
        raise InputError("--poses: the number of random planned poses applies without DATA")
    if poses is not None and poses < 1:
        raise InputError(f"--poses: must be >= 1, got {poses}")
    measured = data_path is not None and not planned
    if measured:
        kind = measurement_kind(data_path, read_table(data_path)[0], machine)
        if scenario is not None and scenario_for(machine, scenario) != kind:
            raise InputError(f"--scenario {scenario}: {path_text(data_path)} holds {kind} "
                             "measurements "
                             "(from its columns); leave --scenario out or give a plan with "
                             "--planned")
        for option, value in (("--setups", setups), ("--radius", radius),
                              ("--targets", targets)):
            if value is not None:
                raise InputError(f"{option}: applies to planned measurements; the "
                                 f"measurements of {path_text(data_path)} have their own")
        setup = file_setups.get(kind)
    else:
        kind = scenario_for(machine, scenario)
        setup = planning_setup(machine, kind, setups, radius, targets,
                               file_setups.get(kind))
    model = noise_model(kind, noise, pose_noise, machine)
    plan = rows = groups = None
    if data_path is not None and not measured:
        *plan, rows, _ = read_targets_of(data_path, machine, file_setups)
        groups = plan_groups(data_path, kind, rows)
    result = assess_identifiability(machine, kind, data=data_path if measured else None,
                                    poses=plan, rows=rows, groups=groups,
                                    source=None if plan is None else str(data_path),
                                    n=poses, noise=model, seed=seed, workspace=ws,
                                    targets=None if measured else targets, setup=setup)
    rep, section = result.report, result.prediction
    report = {
        "pkmcal_report": 1,
        "command": "identifiability",
        "machine_file": path_text(getattr(machine, "source", machine_spec)),
        "data_file": None if data_path is None else path_text(data_path),
        **result.as_dict(),
    }
    if map_path is not None:
        result.write_map(map_path, bounds=ws.bounds if workspace else None)
        report["map"] = str(map_path)
    commit_outputs()
    summary = Summary()
    if json_output:
        summary.raw(json.dumps(json_safe(report), indent=2) + "\n")
        return summary
    table = summary.pairs(title=f"pkmcal identifiability: {report['machine_file']} with "
                          f"{result.source}")
    table.add_row("measurement", f"{instrument(kind).measurement_words}, "
                  f"{result.measurements} {'planned ' if result.planned else ''}measurements")
    table.add_row("identifiable", rep.rank.words())
    for d in rep.weak:
        table.add_row("weakly identifiable", f"{d.name}: {d.description}")
    for d in rep.unidentifiable:
        table.add_row("not identifiable", f"{d.dimension} x {d.name}: {d.description}")
    table.add_row("condition number", f"{rep.condition_number:.4g} (scaled Jacobian, "
                  "identifiable part)")
    o = rep.observability
    table.add_row("observability", ", ".join(f"{k} = {o[k]:.4g}" for k in sorted(o)))
    if rep.hold_fixed:
        table.add_row("minimal set", f"hold {len(rep.hold_fixed)} parameters at their nominal "
                      f"values and identify the other {rep.identifiable}: "
                      + ", ".join(rep.hold_fixed))
    _prediction_rows(table, section)
    if map_path is not None:
        table.add_row("map", str(map_path))
    if rep.correlated:
        pairs = summary.table("parameter", "parameter", "correlation",
                              title=f"{len(rep.correlated)} pair(s) with |correlation| > 0.9 "
                              "(identifiable part)", justify={2: "right"})
        for a, b, c in rep.correlated[:10]:
            pairs.add_row(a, b, f"{c:+.3f}")
        if len(rep.correlated) > 10:
            pairs.add_row("...", f"{len(rep.correlated) - 10} more", "")
    else:
        summary.line("no parameter pair correlated beyond 0.9 (identifiable part)")
    return summary


def parse_joint_range(text: str, machine) -> tuple[float, float]:
    """``MIN,MAX`` of ``--joint-range`` in the joints' quantity (length or angle), SI."""
    from ..io import joint_quantity

    gains = machine.reading_gains()          # readings in their own unit: give lengths
    quantity = "length" if gains is not None else joint_quantity(machine)
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) != 2:
        raise InputError(f"--joint-range: expected MIN,MAX with units (e.g. 100mm,600mm or "
                         f"-60deg,90deg), got {text!r}")
    lo, hi = (parse_quantity(p, quantity, "--joint-range") for p in parts)
    if not lo < hi:
        raise InputError(f"--joint-range: MIN must be below MAX, got {text}")
    if gains is not None:
        if not np.allclose(np.abs(gains), 1.0):
            raise InputError("--joint-range: this Stewart's readings are not lengths (gain "
                             "!= 1); give candidates within its range with --from")
    return lo, hi


def joint_bounds(machine, joint_range: str | None):
    """The joint bounds select-poses keeps its candidates within: the machine file's
    ``joint_limits`` and ``--joint-range``, their intersection when both are given.

    Returns ``((lo, hi), words)`` with ``lo``, ``hi`` (n_joints,) in internal units and the
    bounds in words for messages, or ``(None, "")`` when there are none. Refuses bounds whose
    intersection is empty for some joint.
    """
    limits = getattr(machine, "joint_limits", None)
    source = getattr(machine, "source", None) or "the machine file"
    if limits is None and joint_range is None:
        return None, ""
    n = machine.n_joints
    lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
    words = []
    if limits is not None:
        lo, hi = np.maximum(lo, limits[0]), np.minimum(hi, limits[1])
        words.append(f"the joint limits of {path_text(source)} ({machine.joint_limits_text()})")
    if joint_range is not None:
        a, b = parse_joint_range(joint_range, machine)
        lo, hi = np.maximum(lo, a), np.minimum(hi, b)
        words.append(f"--joint-range {joint_range}")
    if limits is not None and joint_range is not None:
        empty = np.flatnonzero(~(lo < hi))
        if empty.size:
            raise InputError(f"--joint-range {joint_range}: no value of "
                             f"{', '.join(f'q{j + 1}' for j in empty)} is both within it and "
                             f"within the joint limits of {path_text(source)} "
                             f"({machine.joint_limits_text()})")
    return (lo, hi), " and ".join(words)


@in_output_set
def select_poses(machine_spec: str, output: Path, n: int, *, candidates: int = 2000,
                 candidates_path: Path | None = None, criterion: str = "d",
                 random_sets: int = 100, noise: str | None = None,
                 pose_noise: str | None = None, seed: int = 0, map_path: Path | None = None,
                 json_output: bool = False, joint_range: str | None = None,
                 workspace: str | None = None, scenario: str | None = None,
                 setups: int | None = None, radius: str | None = None,
                 targets: int | None = None, parameters: str | None = None,
                 progress=no_progress) -> Summary:
    """``pkmcal select-poses``: choose ``n`` poses by a criterion, never worse than the
    instrument's standard plan (:func:`pkmcal.planning.select_plan`); write them (the machine
    file's units and working frame - a printer's: z the height above its bed - with the
    joint values that reach them, the candidate row and the instrument's group column) and
    report them next to the standard plan and random sets of the same size.

    Parameters
    ----------
    machine_spec : str
        A machine file, or ``"default"``.
    output : Path
        The plan (CSV) to write; ``identifiability(machine, output, planned=True)`` analyses
        it again.
    n : int
        The number of poses to choose.
    candidates : int
        The number of random feasible candidates (without ``candidates_path``).
    candidates_path : Path, optional
        Choose among the poses of this file instead (every one must be reachable).
    criterion : str
        ``"d"``, ``"a"`` or ``"pose"`` (:data:`pkmcal.planning.CRITERION_WORDS`).
    random_sets : int
        Random sets of ``n`` candidates to compare against.
    noise, pose_noise, seed, map_path, json_output, workspace, scenario, setups, radius, \
targets, parameters
        As for :func:`identifiability`.
    joint_range : str, optional
        ``MIN,MAX`` joint bounds with units (:func:`joint_bounds`).
    progress : callable
        ``progress(description, total) -> advance(n=1, description=None)``
        (:func:`~pkmcal.workflows.common.no_progress` by default).

    Returns
    -------
    Summary
        The selection table (or the JSON report). Exit code 0.

    Raises
    ------
    InputError
        A bad file or option, named; nothing is written.
    """
    from ..io import write_poses, write_positions
    from ..planning import scenario_for, select_plan

    if n < 1:
        raise InputError(f"-n/--poses: give the number of poses to choose (>= 1), got {n}")
    machine, file_setups = load_machine_setups_arg(machine_spec)
    machine = _with_set(machine, parameters)
    inputs = [p for p in (candidates_path,) if p is not None]
    if workspace is not None and Path(workspace).exists():
        inputs.append(Path(workspace))
    check_outputs([output] + ([map_path] if map_path else []), inputs)
    ws = workspace_arg(workspace, machine, seed, setups=file_setups)
    if random_sets < 0:
        raise InputError(f"--random-sets: must be >= 0, got {random_sets}")
    kind = scenario_for(machine, scenario)
    setup = planning_setup(machine, kind, setups, radius, targets,
                           file_setups.get(kind))
    model = noise_model(kind, noise, pose_noise, machine)
    step = progress("select-poses: candidate poses", 5)
    given = rows = groups = None
    if candidates_path is not None:
        # positions in the working frame (a printer's: above its bed), computed in the base's
        P, R, rows, shown = read_targets_of(candidates_path, machine, file_setups)
        given = [P, R]
        refuse_unreachable(machine, machine.reachability(
            *given, bed=bed_plane(file_setups)), f"{candidates_path}: "
                           "{n} candidate pose(s) cannot be reached by the machine", rows,
                           (shown, R))
        groups = plan_groups(candidates_path, kind, rows)
    elif candidates < n:
        raise InputError(f"-n/--poses {n}: more than the {candidates} candidate poses "
                         "(--candidates); choose fewer or more candidates")
    lo_hi, limits_words = joint_bounds(machine, joint_range)
    sel = select_plan(machine, kind, n, noise=model, candidates=candidates,
                      criterion=criterion, random_sets=random_sets, seed=seed,
                      workspace=ws, joint_bounds=lo_hi, bounds_words=limits_words,
                      targets=targets, progress=step, poses=given, rows=rows,
                      groups=groups, source=candidates_path and str(candidates_path),
                      setup=setup)
    report = {"pkmcal_report": 1, "command": "select-poses",
              "machine_file": path_text(getattr(machine, "source", machine_spec)),
              **sel.as_dict(), "output": str(output)}
    units = _units(machine)
    extra = {"candidate": sel.candidate.tolist()}
    extra.update(joint_columns(machine, sel.q, units))
    column = instrument(kind).group_column
    if column is not None and sel.group is not None:
        extra[column] = (sel.group + 1).tolist()
    P = working_positions(machine, file_setups, sel.P)     # a printer's: above its bed
    if machine.rotates:
        write_poses(output, P, sel.R, units["length"], units["angle"], extra=extra)
    else:
        write_positions(output, P, units["length"], extra=extra)
    if map_path is not None:
        sel.write_map(map_path, bounds=ws.bounds if workspace else None)
        report["map"] = str(map_path)
    commit_outputs()
    summary = Summary()
    if json_output:
        summary.raw(json.dumps(json_safe(report), indent=2) + "\n")
    else:
        _selection_table(summary, sel, report["machine_file"], output, map_path,
                         None if file_setups.working_frame_is_base(machine)
                         else machine.working_frame_words)
    return summary


def _selection_table(summary: Summary, sel, machine_file: str, output: Path,
                     map_path: Path | None, frame: str | None = None) -> None:
    """The select-poses table (``frame``: the positions' frame in words, where it is not the
    base frame)."""
    from ..planning import CRITERION_WORDS, criterion_ratio

    n, k, rms, rank = sel.n, sel.standard_poses, sel.position_rms, sel.design.rank
    std, std_rms, criterion = sel.standard, sel.standard_position_rms, sel.criterion
    table = summary.pairs(title=f"pkmcal select-poses: {machine_file}")
    table.add_row("measurement", instrument(sel.scenario).measurement_words)
    how = ("the standard plan (the search ended worse)" if sel.returned_standard
           else f"greedy + {sel.exchanges} exchanges" if sel.search_start is None
           else f"standard plan + {sel.exchanges} exchanges")
    extra_words = (f"; the standard plan's {k} poses were further candidates and a start"
                   if sel.standard_start else "")
    table.add_row("selected", f"{n} of {sel.candidates} candidate poses by criterion "
                  f"{criterion} ({how}{extra_words}); {sel.rank.words()}")
    _prediction_rows(table, sel.prediction)
    if k and not np.isfinite(std_rms):
        table.add_row("standard plan", f"{std.name}: leaves parameter directions that move the "
                      "platform unidentified (no bounded prediction); not a start")
    elif k:
        text = (f"{std.name}: predicted position error {format_quantity(std_rms, 'length', 3)} "
                f"RMS, {std_rms / rms:.2f}x the selected set's "
                f"{format_quantity(rms, 'length', 3)}")
        if sel.note:
            text += f"; {sel.note}"
        table.add_row("standard plan", text)
    else:
        table.add_row("standard plan", f"none of {n} poses: {std.reason}")
    median, crit_median = sel.random_median, sel.random_criterion_median
    if sel.random_sets:
        table.add_row("random sets", "median predicted position error "
                      f"{format_quantity(median, 'length', 3)} RMS over {sel.random_sets} "
                      f"random sets of {n} candidates: {median / rms:.2f}x the selected set's "
                      f"{format_quantity(rms, 'length', 3)}")
    words, ratio_words = CRITERION_WORDS[criterion]
    crit = f"{criterion} ({words}): selected {sel.value:.5g}"
    ratios = []
    if k and not np.isfinite(sel.standard_value):
        crit += ", standard plan singular"
    elif k:
        crit += f", standard plan {sel.standard_value:.5g}"
        ratios.append(f"{criterion_ratio(criterion, sel.standard_value, sel.value, rank):.2f}x "
                      "the standard plan")
    if sel.random_sets:
        crit += f", median random set {crit_median:.5g}"
        ratios.append(f"{criterion_ratio(criterion, crit_median, sel.value, rank):.2f}x "
                      "the median random set")
    if ratios:
        crit += (f"; the selected set is {' and '.join(ratios)} "
                 f"({ratio_words.format(p=rank)})")
    table.add_row("criterion", crit)
    table.add_row("written", path_text(output) + (f" ({frame})" if frame else "")
                  + (f", {path_text(map_path)}" if map_path else ""))
