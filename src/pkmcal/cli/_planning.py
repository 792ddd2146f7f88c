"""``pkmcal identifiability`` and ``pkmcal select-poses``: what measurements will identify and
how accurate the calibration will be, before and after measuring (SPEC 3)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from ..calibration.run import file_units as _units
from ..calibration.run import full_pose_noise_arg, tracker_noise_arg
from ..calibration.run import json_safe as _finite_or_none
from ..calibration.run import rows_text as _rows_text
from ..errors import InputError
from ..io import read_constraint_link, read_full_pose, read_table
from ..plausibility import check_option_scale
from ..units import LENGTH, parse_quantity
from ._commands import (
    _table,
    check_outputs,
    commit_outputs,
    joint_columns,
    load_machine_arg,
    read_poses_of,
)
from ._console import console, progress_tasks

#: workspace poses of the predicted-accuracy summary (SPEC 5 cube) and of the map (per axis)
WORKSPACE_POSES = 500
MAP_STEPS = 31


def noise_model(scenario: str, noise: str | None, pose_noise: str | None, machine=None):
    """The noise model of ``--noise`` / ``--pose-noise`` for a scenario (as in calibrate),
    checked against the machine's size when given."""
    if pose_noise is not None and scenario != "pose":
        raise InputError(f"--pose-noise applies to full-pose measurements, not {scenario}")
    if scenario in ("constraint-link", "distance"):
        sigma = 1e-6 if noise is None else parse_quantity(noise, "length", "--noise")
        what = "encoder noise" if scenario == "constraint-link" else "ballbar length noise"
        if not sigma > 0:
            raise InputError(f"--noise: must be > 0 (the standard deviation of the {what}), "
                             f"got {noise}")
        if machine is not None:
            check_option_scale(sigma, machine, "--noise", "noise", noise)
        if scenario == "distance":
            from ..instruments import IsotropicNoise

            return IsotropicNoise(sigma)
        return sigma
    if scenario == "tracker":
        return tracker_noise_arg(noise, allow_none=False, machine=machine)[0]
    if scenario == "probe":
        from ..calibration.run import _probe_noise

        return _probe_noise(noise, machine)
    from ..instruments.registry import instrument

    own = getattr(instrument(scenario), "noise_arg", None)
    if callable(own):               # an instrument that reads its own --noise
        return own(noise, machine)
    return full_pose_noise_arg(noise, pose_noise, strict=True, machine=machine)


#: the measurement in words, per scenario
MEASUREMENT_WORDS = {
    "constraint-link": "constraint link (maximum likelihood: every reading noisy; one pose on "
                       "the sphere per measurement)",
    "tracker": "points of a target on the platform (laser tracker; tracker pose and unknown "
               "target places estimated jointly)",
    "pose": "full pose (maximum likelihood; both measurement frames estimated)",
    "distance": "ballbar distances (pivot and ball of each setup estimated jointly)",
    "probe": "bed-probe heights (bed height and tilt estimated jointly; on a printer the bed "
             "is z = 0 and its tilt estimated where the data tell it)",
    "pair-distances": "distances between the nozzle at two sets of readings (no unknown of "
                      "their own)",
}


def data_kind(path: Path, header: list[str], machine) -> str:
    """The scenario of a measurement file, from its columns: ``probe_z`` -> probe, ``d`` ->
    distance, ``mx, my, mz`` -> tracker (points), a pose (x, y, z + orientation) -> pose,
    readings alone -> constraint-link; refused with the registry's reason when it does not
    apply to the machine."""
    from ..io.csv_io import has_orientation
    from ..planning import scenario_for

    def has(base):
        return any(n == base or n.startswith(base + "_") for n in header)

    if has("q1b") and has("distance"):
        kind = "pair-distances"
    elif has("probe_z"):
        kind = "probe"
    elif has("d"):
        kind = "distance"
    elif has("mx") and has("my") and has("mz"):
        kind = "tracker"
    elif has("x") and has("y") and has("z") and has_orientation(header):
        kind = "pose"
    else:
        kind = "constraint-link"
    try:
        return scenario_for(machine, kind)
    except InputError as exc:
        raise InputError(f"{path}: {kind} measurements (from the columns "
                         f"{', '.join(header)}): {str(exc).split(': ', 1)[-1]}") from None


def _fk_of(machine, data, data_path: Path):
    fk = machine.fk(data.q)
    if not fk.converged.all():
        raise InputError(f"{data_path}: row(s) {_rows_text(data.rows[~fk.converged])}: no "
                         f"platform pose of {machine.source} reproduces these readings "
                         "(outside the workspace, or a wrong unit or zero)")
    return fk


def measured_problem(machine, data_path: Path, kind: str, noise):
    """The calibration problem ``pkmcal calibrate`` would solve (default method), unsolved,
    its instrument's unknowns started from the data on the machine file's geometry (a fit
    with the machine held: the registration and target places, the pivots and balls, the
    measurement frames)."""
    from ..calibration import levenberg_marquardt
    from ..instruments.registry import instrument
    from ..io import read_distances, read_points

    inst = instrument(kind)
    if kind == "constraint-link":
        data = read_constraint_link(data_path, machine)
        return inst.problem(machine, data, noise), data
    if kind == "tracker":
        from ..instruments import PointsModel
        from ..instruments.tracker import TrackerProblem, registration_of

        data = read_points(data_path, machine)
        fk = _fk_of(machine, data, data_path)
        start = PointsModel(data.n_groups, machine.tracker_target()).start(
            fk.P, fk.R, data.values, data.group, str(data_path))
        registration = (start.rotation_starts[0], start.parameters.values[3:6].copy())
        targets = None
        if machine.tracker_target() is None:
            alone = TrackerProblem(machine, data, noise, registration).with_machine_fixed()
            first = levenberg_marquardt(alone)
            registration = registration_of(first.state)
            targets = first.state.nuisance.values[6:].copy()
        return inst.problem(machine, data, noise, registration=registration,
                            targets=targets), data
    if kind == "probe":
        from ..instruments import InstrumentProblem
        from ..instruments.bed import bed_choice
        from ..io import read_probe

        data = read_probe(data_path, machine)
        fk = _fk_of(machine, data, data_path)
        model = bed_choice(machine, data, noise).model().start(fk.P, fk.R, data.values,
                                                               data.group, str(data_path))
        return InstrumentProblem(machine, data, model, noise), data
    if kind == "pair-distances":
        from ..calibration.run import _read_pairs

        data = _read_pairs(data_path, machine)
        return inst.problem(machine, data, noise), data
    if kind == "distance":
        from ..instruments import DistancesModel, InstrumentProblem

        data = read_distances(data_path, machine)
        fk = _fk_of(machine, data, data_path)
        model = DistancesModel(data.n_groups).start(fk.P, fk.R, data.values, data.group,
                                                    str(data_path))
        alone = InstrumentProblem(machine, data, model, noise).with_machine_fixed()
        state = levenberg_marquardt(alone).state.nuisance
        start = machine.with_parameters(machine.u)
        start.ballbar_setups = [(state.values[model._ip[g]].copy(),
                                 state.values[model._ib[g]].copy())
                                for g in range(data.n_groups)]
        return inst.problem(start, data, noise), data
    from ..calibration import estimate_frames

    data = read_full_pose(data_path, machine)
    if len(data) < 4:
        raise InputError(f"{data_path}: {len(data)} pose(s); the measurement frames need at "
                         "least 4")
    frames = getattr(machine, "measurement_frames", None)
    if frames is None:
        frames = estimate_frames(machine, data)
    return inst.problem(machine, data, noise, frames=frames), data


def plan_groups(path: Path, kind: str, rows):
    """The 0-based ``setup`` (distance) or ``target`` (tracker) of each planned pose of a plan
    file, None without that column."""
    from ..io.csv_io import read_groups

    column = {"distance": "setup", "tracker": "target"}.get(kind)
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


def planning_machine(machine, kind: str, setups: int | None, radius: str | None,
                     targets: int | None):
    """The machine ``kind``'s plans use: with ``--setups`` / ``--radius`` its planned ballbar
    mountings (a copy carrying ``ballbar_setups``); refuses the options that do not apply."""
    for option, value, applies in (("--setups", setups, "distance"),
                                   ("--radius", radius, "distance"),
                                   ("--targets", targets, "tracker")):
        if value is not None and kind != applies:
            raise InputError(f"{option}: applies to {applies} measurements, not {kind}")
    if targets is not None and targets > 1 and machine.tracker_target() is not None:
        raise InputError(f"--targets {targets}: {machine.source} gives the target's place on "
                         "the platform; one target only")
    if kind != "distance" or (setups is None and radius is None):
        return machine
    from ..instruments.registry import BALLBAR_LENGTH, planned_ballbar_setups

    length = BALLBAR_LENGTH
    if radius is not None:
        length = parse_quantity(radius, "length", "--radius")
        if not length > 0:
            raise InputError(f"--radius: the ballbar length must be > 0, got {radius}")
        check_option_scale(length, machine, "--radius", "size", radius)
    out = machine.with_parameters(machine.u)
    out.ballbar_setups = planned_ballbar_setups(machine, 3 if setups is None else setups,
                                                length)
    return out


def workspace_arg(text: str | None, machine, seed: int = 0):
    """The workspace of the predicted accuracy: ``--workspace`` (a box
    ``X0,X1,Y0,Y1,Z0,Z1`` with units, or a CSV of points) or, without it, the SPEC 5 cube
    around home. Every pose must be reachable from home's working mode and within the
    machine file's joint limits."""
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
    _check_workspace(machine, ws, text, rows)
    return ws


def _points_workspace(path: Path, machine, seed: int):
    """The poses of a ``--workspace`` points file (x, y, z [+ orientation]; without
    orientation columns, orientations drawn within +/-10 deg as for the default workspace)
    and the file rows: ``(Workspace, rows)``."""
    from ..analysis.accuracy import Workspace, in_pose_space
    from ..io import read_positions
    from ..io.csv_io import column_map, has_orientation
    from ..kinematics import matrix_from_euler

    if not path.exists():
        raise InputError(f"--workspace {path}: neither a box X0,X1,Y0,Y1,Z0,Z1 (six lengths "
                         "with units) nor an existing points file")
    with column_map(None):           # --columns renames the data file's columns, not these
        header, _ = read_table(path)
        words = f"{{n}} poses of {path} (--workspace)"
        if has_orientation(header) and machine.rotates:
            P, R, rows = read_poses_of(path, machine)
        else:
            P, rows = read_positions(path)
            rng = np.random.default_rng(seed)
            R = matrix_from_euler(rng.uniform(-1, 1, (len(P), 3)) * np.deg2rad(10.0))
            R = in_pose_space(machine, P, R)[1]      # the identity where it only translates
            if machine.rotates:
                words = (f"{{n}} points of {path} (--workspace), orientations within "
                         "+/-10 deg")
    return Workspace(P, np.asarray(R), words.format(n=len(P)),
                     (P.min(axis=0), P.max(axis=0))), rows


def _check_workspace(machine, ws, text: str, rows) -> None:
    """Refuse workspace poses the machine cannot take (unreachable, another working mode,
    joints outside its limits), naming the rows of a points file."""
    with np.errstate(all="ignore"):
        q = machine.ik(ws.P, ws.R)
        ok = np.all(np.isfinite(q), axis=-1) & machine.working_mode(ws.P, ws.R)
    if not ok.all():
        k = np.flatnonzero(~ok)
        where = (f"row(s) {_rows_text(np.asarray(rows)[k])}" if rows is not None else
                 f"{k.size} of its {len(ws.P)} sampled poses, e.g. at ("
                 + ", ".join(f"{v * 1e3:.6g}" for v in ws.P[k[0]]) + ") mm")
        raise InputError(f"--workspace {text}: {where}: out of the machine's reach (no real "
                         "inverse kinematics, or beyond a singularity from home); give a "
                         "workspace the machine reaches")
    if rows is None:
        rows = np.arange(1, len(q) + 1)
        what = f"--workspace {text}: {{n}} of its sampled poses"
    else:
        what = f"--workspace {text}: {{n}} pose(s)"
    from ._commands import refuse_outside_limits

    refuse_outside_limits(machine, q, rows, what)


def prediction_report(machine, design, n_machine, M=None, rng=0, op=None,
                      workspace=None) -> dict:
    """Predicted pose accuracy over the workspace (the JSON section): ``workspace`` (a
    :class:`~pkmcal.analysis.accuracy.Workspace`, e.g. of ``--workspace``) or the SPEC 5
    cube around home; ``op``: the pose-error operator at those poses when already
    computed."""
    from ..analysis.prediction import predict_pose_accuracy

    ws = workspace_arg(None, machine, rng) if workspace is None else workspace
    P, R = (op.P, op.R) if op is not None else (ws.P, ws.R)
    pred = predict_pose_accuracy(machine, design, P, R, M, n_machine, op=op)
    s = pred.summary()
    out = {"workspace": ws.description, "poses": s["poses"],
           "unbounded_directions": s["unbounded"]}
    for key, scale, unit in (("position", 1e6, "um"), ("orientation", 1e6, "urad")):
        if s[key] is not None:
            for stat in ("rms", "p95", "max"):
                out[f"{key}_{stat}_{unit}"] = s[key][stat] * scale
    return out


def _prediction_rows(table, section: dict) -> None:
    if section["unbounded_directions"]:
        table.add_row("predicted accuracy", f"unbounded: {section['unbounded_directions']} "
                      "unidentifiable direction(s) move the platform relative to every frame; "
                      "add measurements that see them")
        return
    text = (f"position {section['position_rms_um']:.3g} um RMS, "
            f"{section['position_max_um']:.3g} um max")
    if "orientation_rms_urad" in section:
        text += (f"; orientation {section['orientation_rms_urad']:.3g} urad RMS, "
                 f"{section['orientation_max_urad']:.3g} urad max")
    table.add_row("predicted accuracy", f"{text} (1 sigma, Cramer-Rao, over the "
                  f"{section['workspace']}; {section['noise']})")


def write_map(path: Path, machine, design, n_machine, M, plan_P, title: str,
              bounds=None) -> Path:
    """Predicted position error (1 sigma) over two slices through the workspace's centre
    (x-y and x-z, home orientation; default: home +/- 50 mm, else ``bounds = (lo, hi)``) and
    the planned measurement positions."""
    from ..analysis.prediction import predict_pose_accuracy
    from ..report import plots

    if bounds is None:
        c = machine.home[0]
        half = np.full(3, 0.05)
    else:
        lo, hi = (np.asarray(b, float) for b in bounds)
        c, half = (lo + hi) / 2, np.maximum((hi - lo) / 2, 1e-6)
    t = np.linspace(-1.0, 1.0, MAP_STEPS)
    slices = []
    for (i, j) in ((0, 1), (0, 2)):
        A, B = np.meshgrid(t * half[i], t * half[j])
        P = np.tile(c, (A.size, 1))
        P[:, i] += A.ravel()
        P[:, j] += B.ravel()
        R = np.broadcast_to(machine.home[1] if machine.rotates else np.eye(3),
                            (len(P), 3, 3))
        pred = predict_pose_accuracy(machine, design, P, R, M, n_machine)
        k = 3 - i - j
        a, b = "xyz"[i], "xyz"[j]
        through = "home" if bounds is None else "the workspace's centre"
        slices.append((f"{a}-{b} slice through {through} ({'xyz'[k]} = {c[k] * 1e3:.4g} mm)",
                       (c[i] + t * half[i]) * 1e3, (c[j] + t * half[j]) * 1e3,
                       (pred.position * 1e6).reshape(A.shape),
                       f"{a} [mm]", f"{b} [mm]", "predicted position error, 1 sigma [um]"))
    plan = None if plan_P is None else np.asarray(plan_P) * 1e3
    return plots.plot_prediction_map(slices, path, title, plan, c * 1e3)


def _with_set(machine, parameters: str | None):
    """The machine with the fixed flags of its parameter set ``--parameters`` (if given)."""
    if parameters is None:
        return machine
    from ..calibration.run import apply_parameter_set

    return apply_parameter_set(machine, parameters)


def run_identifiability(machine_spec: str, data_path: Path | None, json_output: bool,
                        planned: bool = False, poses: int | None = None, seed: int = 0,
                        noise: str | None = None, pose_noise: str | None = None,
                        map_path: Path | None = None, workspace: str | None = None,
                        scenario: str | None = None, setups: int | None = None,
                        radius: str | None = None, targets: int | None = None,
                        parameters: str | None = None) -> int:
    """``pkmcal identifiability``: every scenario on every machine it applies to, from
    measurements of any kind, a plan file or the instrument's standard plan."""
    from ..identifiability import identifiability_report
    from ..instruments.registry import instrument
    from ..planning import (
        candidate_set,
        describe_noise,
        design_from_problem,
        planned_problem,
        scenario_for,
        standard_plan,
    )

    machine = _with_set(load_machine_arg(machine_spec), parameters)
    ws_file = [Path(workspace)] if workspace is not None and Path(workspace).exists() else []
    if map_path is not None or ws_file:
        check_outputs([map_path] if map_path is not None else [],
                      [p for p in (data_path,) if p is not None] + ws_file)
    ws = workspace_arg(workspace, machine, seed)
    if data_path is None and planned:
        raise InputError("--planned: give the plan file (DATA) with the planned poses")
    if data_path is not None and poses is not None:
        raise InputError("--poses: the number of random planned poses applies without DATA")
    if poses is not None and poses < 1:
        raise InputError(f"--poses: must be >= 1, got {poses}")
    group = None
    if data_path is not None and not planned:
        header, _ = read_table(data_path)
        kind = data_kind(data_path, header, machine)
        if scenario is not None and scenario_for(machine, scenario) != kind:
            raise InputError(f"--scenario {scenario}: {data_path} holds {kind} measurements "
                             "(from its columns); leave --scenario out or give a plan with "
                             "--planned")
        for option, value in (("--setups", setups), ("--radius", radius),
                              ("--targets", targets)):
            if value is not None:
                raise InputError(f"{option}: applies to planned measurements; the "
                                 f"measurements of {data_path} have their own")
        model = noise_model(kind, noise, pose_noise, machine)
        source = f"{data_path}"
    else:
        kind = scenario_for(machine, scenario)
        machine = planning_machine(machine, kind, setups, radius, targets)
        model = noise_model(kind, noise, pose_noise, machine)
        if data_path is None and poses is None and not targets:
            # the instrument's standard plan (tracker: seed 001's 3x3x3 grid), as select-poses
            # compares with
            plan = standard_plan(machine, kind, seed=seed)
            if not plan.available:
                raise InputError(f"{plan.name}: {plan.reason}")
            P, R, group = plan.P, plan.R, plan.group
            rows, source = None, plan.name
        elif data_path is None:
            n = poses if poses is not None else instrument(kind).plan_size_for(machine)
            P, R, group = candidate_set(machine, kind, n, rng=seed)
            rows, source = None, f"{n} random planned poses (seed {seed})"
        else:
            P, R, rows = read_poses_of(data_path, machine)
            group = plan_groups(data_path, kind, rows)
            source = f"planned poses of {data_path}"
        if targets:
            group = np.arange(len(P)) % targets
            source += f", {targets} target(s) in turn"
    try:
        if data_path is not None and not planned:
            problem, data = measured_problem(machine, data_path, kind, model)
        else:
            problem = planned_problem(machine, kind, P, R, model, rows,
                                      str(data_path or "<plan>"), group=group)
            data = problem.data
        rep = identifiability_report(problem)
        design = design_from_problem(problem)
        section = prediction_report(machine, design, problem.n_machine, rng=seed,
                                    workspace=ws)
    except InputError:
        raise
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise InputError(f"{data_path or 'plan'}: identifiability analysis failed: {exc}") \
            from None
    section["noise"] = describe_noise(kind, model)
    s = np.asarray(rep.singular_values, float)
    report = {
        "pkmcal_report": 1,
        "command": "identifiability",
        "machine_file": str(getattr(machine, "source", machine_spec)),
        "data_file": None if data_path is None else str(data_path),
        "planned": bool(planned or data_path is None),
        "measurement": kind,
        "measurements": len(data),
        **rep.as_dict(),
        "predicted_accuracy": section,
        "singular_values": s.tolist(),
    }
    if map_path is not None:
        plan_P = getattr(data, "true_P", None)
        write_map(map_path, machine, design, problem.n_machine, None, plan_P,
                  f"predicted accuracy after calibration ({len(data)} measurements, "
                  f"{section['noise']})", bounds=ws.bounds if workspace else None)
        report["map"] = str(map_path)
    commit_outputs()
    if json_output:
        print(json.dumps(_finite_or_none(report), indent=2))
        return 0
    out = console()
    table = _table("", "", title=f"pkmcal identifiability: {report['machine_file']} with "
                   f"{source}", show_header=False)
    table.add_row("measurement", f"{MEASUREMENT_WORDS[kind]}, {len(data)} "
                  f"{'planned ' if report['planned'] else ''}measurements")
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
    out.print(table)
    if rep.correlated:
        pairs = _table("parameter", "parameter", "correlation",
                       title=f"{len(rep.correlated)} pair(s) with |correlation| > 0.9 "
                       "(identifiable part)", justify={2: "right"})
        for a, b, c in rep.correlated[:10]:
            pairs.add_row(a, b, f"{c:+.3f}")
        if len(rep.correlated) > 10:
            pairs.add_row("...", f"{len(rep.correlated) - 10} more", "")
        out.print(pairs)
    else:
        out.print("no parameter pair correlated beyond 0.9 (identifiable part)", markup=False)
    return 0


def parse_joint_range(text: str, machine) -> tuple[float, float]:
    """``MIN,MAX`` of ``--joint-range`` in the joints' quantity (length or angle), SI."""
    from ..io import joint_quantity

    quantity = "length" if machine.kind == "stewart" else joint_quantity(machine)
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) != 2:
        raise InputError(f"--joint-range: expected MIN,MAX with units (e.g. 100mm,600mm or "
                         f"-60deg,90deg), got {text!r}")
    lo, hi = (parse_quantity(p, quantity, "--joint-range") for p in parts)
    if not lo < hi:
        raise InputError(f"--joint-range: MIN must be below MAX, got {text}")
    if machine.kind == "stewart":
        gain = np.abs(machine.legs()[3])
        if not np.allclose(gain, 1.0):
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
        words.append(f"the joint limits of {source} ({machine.joint_limits_text()})")
    if joint_range is not None:
        a, b = parse_joint_range(joint_range, machine)
        lo, hi = np.maximum(lo, a), np.minimum(hi, b)
        words.append(f"--joint-range {joint_range}")
    if limits is not None and joint_range is not None:
        empty = np.flatnonzero(~(lo < hi))
        if empty.size:
            raise InputError(f"--joint-range {joint_range}: no value of "
                             f"{', '.join(f'q{j + 1}' for j in empty)} is both within it and "
                             f"within the joint limits of {source} "
                             f"({machine.joint_limits_text()})")
    return (lo, hi), " and ".join(words)


#: relative tolerance of "no worse than the standard plan" (the search keeps a 1e-9 ridge)
NO_WORSE_RTOL = 1e-6

_CRITERION_WORDS = {
    "d": ("-log det of the information", "D-efficiency: (det ratio)^(1/{p})"),
    "a": ("mean variance of the scaled parameters", "ratio of the mean parameter variances"),
    "pose": ("mean squared position error over the workspace",
             "ratio of the mean squared position errors"),
}


def criterion_ratio(criterion: str, other: float, selected: float, rank: int) -> float:
    """How many times better the selected set is than another by the criterion (> 1: better).

    Parameters
    ----------
    criterion : {'d', 'a', 'pose'}
        The criterion.
    other, selected : float
        Criterion values (:func:`~pkmcal.planning.criterion_value`) of the other and the
        selected set.
    rank : int
        Number ``p`` of identifiable directions (the dimension of the information).

    Returns
    -------
    float
        ``(det M_sel / det M_other)^(1/p)`` for ``d`` (the D-efficiency), ``other /
        selected`` for ``a`` and ``pose``; inf when only the other is singular.
    """
    if not (np.isfinite(selected) and np.isfinite(other)):
        return float("inf") if np.isfinite(selected) else float("nan")
    if criterion == "d":
        return float(np.exp((other - selected) / max(rank, 1)))
    return float(other / selected) if selected > 0 else float("nan")


def _standard_plan_of(machine, kind, n, seed, lo_hi, words="the joint limits"):
    """The standard plan of ``n`` poses for select-poses, unavailable (with the reason) when
    the machine cannot reach it or it needs joints outside ``--joint-range``."""
    from ..planning import StandardPlan, standard_plan

    try:
        plan = standard_plan(machine, kind, n, seed)
    except InputError as exc:
        return StandardPlan(f"standard plan of {n} poses", reason=str(exc))
    if not plan.available:
        return plan
    q = machine.ik(plan.P, plan.R)
    reach = np.all(np.isfinite(q), -1)
    if not reach.all():
        return StandardPlan(plan.name, reason=f"{int((~reach).sum())} of its poses are out of "
                            "this machine's reach")
    if lo_hi is not None and not np.all((q >= lo_hi[0]) & (q <= lo_hi[1])):
        return StandardPlan(plan.name, reason=f"it needs joint values outside {words}")
    return plan


def run_select_poses(machine_spec: str, output: Path, n: int, candidates: int,
                     candidates_path: Path | None, criterion: str, random_sets: int,
                     noise: str | None, pose_noise: str | None, seed: int,
                     map_path: Path | None, json_output: bool,
                     joint_range: str | None = None, workspace: str | None = None,
                     scenario: str | None = None, setups: int | None = None,
                     radius: str | None = None, targets: int | None = None,
                     parameters: str | None = None) -> int:
    """``pkmcal select-poses``: choose ``n`` poses by a criterion, starting from the greedy
    choice and from the instrument's standard plan, never returning a plan worse than the
    standard one (by the criterion or the predicted RMS position error) when it is among the
    candidates; report it next to the standard plan and random sets of the same size."""
    from dataclasses import replace

    from ..analysis.prediction import pose_error_operator
    from ..identifiability import numerical_rank
    from ..io import write_poses, write_positions
    from ..planning import (
        candidate_set,
        criterion_value,
        describe_noise,
        design_from_problem,
        planned_problem,
        random_values,
        scenario_for,
        select_poses,
    )

    machine = _with_set(load_machine_arg(machine_spec), parameters)
    inputs = [p for p in (candidates_path,) if p is not None]
    if workspace is not None and Path(workspace).exists():
        inputs.append(Path(workspace))
    check_outputs([output] + ([map_path] if map_path else []), inputs)
    ws = workspace_arg(workspace, machine, seed)
    if n < 1:
        raise InputError(f"-n/--poses: must be >= 1, got {n}")
    if random_sets < 0:
        raise InputError(f"--random-sets: must be >= 0, got {random_sets}")
    kind = scenario_for(machine, scenario)
    machine = planning_machine(machine, kind, setups, radius, targets)
    model = noise_model(kind, noise, pose_noise, machine)
    with progress_tasks() as new_task:
        step = new_task("select-poses: candidate poses", 5)
        if candidates_path is not None:
            P, R, rows = read_poses_of(candidates_path, machine)
            G = plan_groups(candidates_path, kind, rows)
            source = str(candidates_path)
        else:
            if candidates < n:
                raise InputError(f"-n/--poses {n}: more than the {candidates} candidate poses "
                                 "(--candidates); choose fewer or more candidates")
            P, R, G = candidate_set(machine, kind, candidates, rng=seed)
            rows, source = None, "<candidates>"
        if targets:
            G = np.arange(len(P)) % targets
        dropped = 0
        lo_hi, limits_words = joint_bounds(machine, joint_range)
        if lo_hi is not None:
            q = machine.ik(P, R)
            inside = np.all((q >= lo_hi[0]) & (q <= lo_hi[1]), axis=-1)   # NaN: outside
            dropped = int((~inside).sum())
            P, R = P[inside], R[inside]
            G = None if G is None else np.asarray(G)[inside]
            rows = None if rows is None else np.asarray(rows)[inside]
            if candidates_path is None:
                rows = np.flatnonzero(inside) + 1
        if len(P) < n:
            raise InputError(f"{source}: {len(P)} candidate pose(s)"
                             + (f" within {limits_words} ({dropped} outside)" if dropped
                                else "")
                             + f"; cannot choose {n}")
        K = len(P)
        # the instrument's standard plan of n poses: evaluated by the same criterion, and
        # (without --from) further candidates and a start of the exchanges
        std = _standard_plan_of(machine, kind, n, seed, lo_hi, limits_words)
        k = len(std)
        P_all = np.concatenate([P, std.P]) if k else P
        R_all = np.concatenate([R, std.R]) if k else R
        std_G = std.group if not (k and targets) else np.arange(k) % targets
        G_all = G
        if k and (G is not None or std_G is not None):
            G_all = np.concatenate([np.zeros(K, int) if G is None else np.asarray(G, int),
                                    np.zeros(k, int) if std_G is None else np.asarray(std_G,
                                                                                      int)])
        rows_all = rows
        if k and rows is not None:
            first = len(rows) if candidates_path is not None else candidates
            rows_all = np.concatenate([np.asarray(rows), first + 1 + np.arange(k)])
        step(1, "select-poses: information of each candidate")
        problem = planned_problem(machine, kind, P_all, R_all, model, rows_all, source,
                                  group=G_all)
        design = design_from_problem(problem)
        selectable = K + (k if candidates_path is None else 0)
        pool = replace(design, F=design.F[:selectable])
        if k and selectable == K:
            sv = np.linalg.svd(pool.F.reshape(-1, design.rank), compute_uv=False)
            if numerical_rank(sv) < design.rank:
                # the standard plan sees directions the --from poses cannot: not comparable
                std = replace(std, P=None, R=None, reason="it identifies directions the "
                              f"poses of {candidates_path} cannot")
                k = 0
                problem = planned_problem(machine, kind, P, R, model, rows, source, group=G)
                G_all = G
                design = pool = design_from_problem(problem)
        step(1, "select-poses: pose-error operator over the workspace")
        op = pose_error_operator(machine, design, ws.P, ws.R, problem.n_machine)
        if op.unbounded:
            raise InputError(f"{source}: even all {len(P_all)} candidates leave {op.unbounded} "
                             "direction(s) that move the platform unidentified; widen the "
                             "candidate set")
        per = design.F.shape[1]
        if n * per < design.rank:
            need = -(-design.rank // per)
            raise InputError(f"-n/--poses: {n} {kind} measurement(s) give at most {n * per} "
                             f"independent equations ({per} each) for the {design.rank} "
                             f"identifiable parameter directions; choose at least {need}")
        A = op.A
        std_idx = np.arange(K, K + k)
        std_value = std_ms = float("inf")
        if k:
            M_std = design.information(std_idx)
            std_value = criterion_value(M_std, criterion, A)
            std_ms = criterion_value(M_std, "pose", A)
        as_start = bool(k and selectable > K and np.isfinite(std_ms))
        step(1, f"select-poses: choosing {n} of {selectable} (greedy and the standard plan, "
             "then exchanges)")
        sel = select_poses(pool, n, criterion, A=A, starts=[std_idx] if as_start else (),
                           bound=std_ms * (1 + 1e-9) if as_start else None)
        idx = np.asarray(sel.index)
        value = criterion_value(design.information(idx), criterion, A)
        ms = criterion_value(design.information(idx), "pose", A)
        note = None
        worse = bool(k and np.isfinite(std_ms) and (
            value > std_value + NO_WORSE_RTOL * max(abs(std_value), 1.0)
            or ms > std_ms * (1 + NO_WORSE_RTOL)))
        returned_standard = False
        if worse and as_start:
            note = (f"the search ended worse than the standard plan (criterion {value:.6g} "
                    f"against {std_value:.6g}, {np.sqrt(ms) * 1e6:.3g} um against "
                    f"{np.sqrt(std_ms) * 1e6:.3g} um); the standard plan is returned")
            idx, value, ms, returned_standard = std_idx, std_value, std_ms, True
        elif worse:
            note = (f"worse than the standard plan, which is not among the poses of "
                    f"{candidates_path}")
        elif as_start and sel.start is not None:
            note = "the best plan came from the exchanges started at the standard plan"
        M = design.information(idx)
        rms = float(np.sqrt(ms))
        step(1, f"select-poses: {random_sets} random sets for comparison")
        random_pool = replace(design, F=design.F[:K])       # the candidates proper
        baseline = np.sqrt(random_values(random_pool, n, random_sets, "pose", A,
                                         rng=seed + 1)) if random_sets else np.zeros(0)
        random_crit = random_values(random_pool, n, random_sets, criterion, A,
                                    rng=seed + 1) if random_sets else np.zeros(0)
        step(1)
    finite = baseline[np.isfinite(baseline)]
    median = float(np.median(baseline)) if baseline.size else float("nan")
    crit_median = float(np.median(random_crit)) if random_crit.size else float("nan")
    from ..identifiability import observability_indices, rank_rule

    sv = np.linalg.svd(design.F[idx].reshape(-1, design.rank), compute_uv=False)
    # the selected plan's counts by the rule calibrate applies to its data (same noise)
    plan_rank = rank_rule(sv, parameters=design.rank + design.null.shape[1])
    section = prediction_report(machine, design, problem.n_machine, M, op=op, workspace=ws)
    section["noise"] = describe_noise(kind, model)
    std_rms = float(np.sqrt(std_ms))
    origin = ("the standard plan" if returned_standard
              else "exchanges from the standard plan" if sel.start is not None
              else "greedy, then exchanges")
    report = {
        "pkmcal_report": 1,
        "command": "select-poses",
        "machine_file": str(getattr(machine, "source", machine_spec)),
        "measurement": kind,
        "candidates": int(K),
        "outside_joint_range": dropped,
        "joint_limits": None if lo_hi is None else limits_words,
        "candidates_file": None if candidates_path is None else str(candidates_path),
        "selected": int(n),
        "criterion": criterion,
        "exchanges": 0 if returned_standard else sel.exchanges,
        "identifiable": plan_rank.identifiable,
        "weakly_identifiable": plan_rank.weak,
        "max_std": plan_rank.max_std,
        "observability": observability_indices(sv),
        "predicted_accuracy": section,
        "selected_plan": {"origin": origin, "criterion_value": value,
                          "position_rms_um": rms * 1e6},
        "standard_plan": {
            "name": std.name, "available": bool(k), "reason": std.reason or None,
            "poses": int(k),
            "candidates": [K + 1 if rows_all is None else int(rows_all[K]),
                           K + k if rows_all is None else int(rows_all[-1])]
            if k and selectable > K else None,
            "start": as_start,
            "criterion_value": std_value if k else None,
            "position_rms_um": std_rms * 1e6 if k else None,
            "ratio_to_selected": std_rms / rms if k and rms > 0 else None,
            "criterion_ratio_to_selected": criterion_ratio(criterion, std_value, value,
                                                           design.rank) if k else None,
            "returned": returned_standard, "note": note},
        "random_sets": {"sets": int(random_sets), "singular": int(baseline.size - finite.size),
                        "position_rms_median_um": median * 1e6,
                        "position_rms_best_um": float(finite.min()) * 1e6 if finite.size
                        else None,
                        "ratio_median_to_selected": median / rms if rms > 0 else None,
                        "criterion_median": crit_median,
                        "criterion_ratio_median_to_selected":
                            criterion_ratio(criterion, crit_median, value, design.rank)
                            if random_sets else None},
        "seed": seed,
        "output": str(output),
    }
    units = _units(machine)
    extra = {"candidate": (idx + 1 if rows_all is None else np.asarray(rows_all)[idx]).tolist()}
    extra.update(joint_columns(machine, machine.ik(P_all[idx], R_all[idx]), units))
    column = {"distance": "setup", "tracker": "target"}.get(kind)
    if column is not None and G_all is not None:
        extra[column] = (np.asarray(G_all)[idx] + 1).tolist()
    if not machine.rotates:
        write_positions(output, P_all[idx], units["length"], extra=extra)
    else:
        write_poses(output, P_all[idx], R_all[idx], units["length"], units["angle"],
                    extra=extra)
    if map_path is not None:
        write_map(map_path, machine, design, problem.n_machine, M, P_all[idx],
                  f"predicted accuracy with the {n} selected poses ({section['noise']})",
                  bounds=ws.bounds if workspace else None)
        report["map"] = str(map_path)
    commit_outputs()
    if json_output:
        print(json.dumps(_finite_or_none(report), indent=2))
        return 0
    out = console()
    table = _table("", "", title=f"pkmcal select-poses: {report['machine_file']}",
                   show_header=False)
    table.add_row("measurement", MEASUREMENT_WORDS[kind])
    how = ("the standard plan (the search ended worse)" if returned_standard
           else f"greedy + {sel.exchanges} exchanges" if sel.start is None
           else f"standard plan + {sel.exchanges} exchanges")
    extra_words = (f"; the standard plan's {k} poses were further candidates and a start"
                   if as_start else "")
    table.add_row("selected", f"{n} of {K} candidate poses by criterion {criterion} ({how}"
                  f"{extra_words}); {plan_rank.words()}")
    _prediction_rows(table, section)
    if k and not np.isfinite(std_ms):
        table.add_row("standard plan", f"{std.name}: leaves parameter directions that move the "
                      "platform unidentified (no bounded prediction); not a start")
    elif k:
        text = (f"{std.name}: predicted position error {std_rms * 1e6:.3g} um RMS, "
                f"{std_rms / rms:.2f}x the selected set's {rms * 1e6:.3g} um")
        if note:
            text += f"; {note}"
        table.add_row("standard plan", text)
    else:
        table.add_row("standard plan", f"none of {n} poses: {std.reason}")
    if random_sets:
        table.add_row("random sets", f"median predicted position error {median * 1e6:.3g} um "
                      f"RMS over {random_sets} random sets of {n} candidates: "
                      f"{median / rms:.2f}x the selected set's {rms * 1e6:.3g} um")
    words, ratio_words = _CRITERION_WORDS[criterion]
    crit = f"{criterion} ({words}): selected {value:.5g}"
    ratios = []
    if k and not np.isfinite(std_value):
        crit += ", standard plan singular"
    elif k:
        crit += f", standard plan {std_value:.5g}"
        ratios.append(f"{criterion_ratio(criterion, std_value, value, design.rank):.2f}x the "
                      "standard plan")
    if random_sets:
        crit += f", median random set {crit_median:.5g}"
        ratios.append(f"{criterion_ratio(criterion, crit_median, value, design.rank):.2f}x "
                      "the median random set")
    if ratios:
        crit += (f"; the selected set is {' and '.join(ratios)} "
                 f"({ratio_words.format(p=design.rank)})")
    table.add_row("criterion", crit)
    table.add_row("written", str(output) + (f", {map_path}" if map_path else ""))
    out.print(table)
    return 0
