"""``pkmcal simulate`` as a library function: measurements of a simulated true machine (the
machine named plus deviations) by any instrument of the registry on any machine it applies
to, written as a data file (and the true machine as a machine file)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..calibration.run import file_units
from ..errors import InputError
from ..instruments.flow import rows_text
from ..instruments.probe import bed_plane
from ..instruments.tracker import tracker_noise_arg
from ..io import atomic_write_text, machine_to_text, parse_machine, write_tracker
from ..limits import MAX_MEASUREMENTS
from ..machines.deviations import deviations as draw_deviations
from ..paths import path_text
from ..report.summary import Summary
from .common import (
    check_outputs,
    commit_outputs,
    load_machine_setups_arg,
    machine_inputs,
)
from .poses import refuse_outside_limits, refuse_unreachable

__all__ = ["simulate", "parse_grid"]


def parse_grid(text: str) -> tuple[int, int, int]:
    """A tracker grid ``"3x3x3"`` -> ``(3, 3, 3)``.

    Parameters
    ----------
    text : str
        ``NXxNYxNZ``, positive whole numbers (``*`` also separates).

    Returns
    -------
    tuple of int
        The points along x, y and z.

    Raises
    ------
    InputError
        Naming ``--grid``: not three positive numbers, more than
        :data:`~pkmcal.limits.MAX_MEASUREMENTS` points, or fewer than 4.
    """
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


def _mm(v) -> str:
    """A position (m) as ``(x, y, z)`` in mm."""
    return "(" + ", ".join(f"{x * 1e3:.6g}" for x in np.asarray(v, float)) + ")"


def simulate(machine_spec: str, output: Path, scenario: str | None = None,
             poses: int | None = None, noise: str | None = None, lc_error: str = "0um",
             seed: int = 0, deviations: str | None = None, truth: Path | None = None,
             grid: str | None = None, outliers: int = 0, pose_noise: str | None = None,
             targets: int | None = None, setups: int | None = None,
             radius: str | None = None, circles: bool = False) -> Summary:
    """``pkmcal simulate``: simulated measurements of a true machine, written as a data file.

    Parameters
    ----------
    machine_spec : str
        A machine file, or ``"default"``.
    output : Path
        The data file (CSV, the instrument's columns in the machine file's units).
    scenario : str, optional
        The instrument (a name or alias of the registry); default the machine type's own.
    poses : int, optional
        The number of measurements (default the instrument's).
    noise : str, optional
        The measurement noise as the command line gives it (``2um``, ``leica``, ``none``).
    lc_error : str
        constraint-link: the true link is the file's length minus this (``"0um"``).
    seed : int
        Seed of the poses, the noise and random deviations.
    deviations : str, optional
        ``paper-table1``, ``none`` or ``random`` (default the machine type's).
    truth : Path, optional
        Also write the true machine here (YAML).
    grid : str, optional
        A tracker on a platform that only translates: ``NXxNYxNZ`` (default ``3x3x3``).
    outliers : int
        A tracker on a platform that only translates: points moved by 1 mm.
    pose_noise : str, optional
        pose: the measured poses' noise, ``POSITION,ORIENTATION``.
    targets : int, optional
        Points on a platform that rotates: the number of targets.
    setups : int, optional
        distance: the number of ballbar mountings.
    radius : str, optional
        distance: the ballbar length.
    circles : bool
        distance: ISO 230-4 circles instead of random poses on the spheres.

    Returns
    -------
    Summary
        The settings table titled ``pkmcal simulate`` (machine, scenario, deviations, noise,
        the instrument's truth rows) and the ``wrote ...`` line.

    Raises
    ------
    InputError
        An option that does not apply to the scenario on this machine (naming where it
        applies), a bad value, a simulated pose the machine cannot take. Nothing is written.
    """
    from ..instruments.registry import INSTRUMENTS, instrument
    from ..planning import scenario_for

    machine, file_setups = load_machine_setups_arg(machine_spec)
    kind = machine.kind
    requested = scenario
    try:
        scenario = scenario_for(machine, scenario)      # the reason when it does not apply
    except InputError as exc:
        usable = [name for name, inst in INSTRUMENTS.items() if inst.applies(machine) is None]
        raise InputError(f"{exc}; this {kind} can simulate: {', '.join(usable)}") from None
    deviations = deviations or machine.DEFAULT_DEVIATIONS
    check_outputs([output] + ([truth] if truth else []), machine_inputs(machine_spec))
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
        return _simulate_tracker(machine, output, noise, seed, deviations, truth,
                                 parse_grid(grid or "3x3x3"), outliers,
                                 file_setups)
    return _simulate_scenario(machine, scenario, output, poses, noise, pose_noise, lc_error,
                              seed, deviations, truth, targets, setups, radius, circles,
                              file_setups)


def _truth_text(machine, true, truth: Path | None, setups) -> str | None:
    """The true machine's file text with the true set-ups (read back before anything is
    written), or None."""
    if truth is None:
        return None
    text = machine_to_text(true, file_units(machine), setups=setups)
    parse_machine(text, str(truth))
    return text


def _settings(machine):
    """A summary and its settings table with the machine row (the caller adds the others)."""
    summary = Summary()
    table = summary.pairs(title="pkmcal simulate")
    table.add_row("machine", f"{path_text(machine.source)} ({machine.kind})")
    return summary, table


def _deviation_words(deviations: str, seed: int) -> str:
    return deviations + (f" (seed {seed})" if deviations == "random" else "")


def _wrote(output: Path, truth: Path | None) -> str:
    return f"wrote {path_text(output)}" + (f" and {path_text(truth)}" if truth else "")


def _simulate_scenario(machine, scenario: str, output: Path, poses: int | None,
                       noise: str | None, pose_noise: str | None, lc_error: str, seed: int,
                       deviations: str, truth: Path | None, targets: int | None,
                       setups: int | None, radius: str | None, circles: bool,
                       file_setups=None) -> Summary:
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
                                                   deviations=deviations,
                                                   machine_setups=file_setups, **options)
    except InputError as exc:
        raise InputError(f"pkmcal simulate {scenario} (--deviations {deviations}, seed "
                         f"{seed}): {exc}") from None
    true.name = (f"simulated true machine ({deviations} deviations) of "
                 f"{machine.name or 'MACHINE'}")
    truth_text = _truth_text(machine, true, truth, truth_info["true_setups"])
    # outputs, at the very end
    write_measurements(inst, output, data, machine, file_units(machine)["length"])
    if truth is not None:
        atomic_write_text(truth, truth_text)
    commit_outputs()
    summary, table = _settings(machine)
    table.add_row("scenario", f"{scenario}, {truth_info['poses']}")
    table.add_row("deviations", _deviation_words(deviations, seed))
    table.add_row("noise", f"{noise_words} (seed {seed})")
    for name, value in truth_info["rows"]:
        table.add_row(name, value)
    summary.line(_wrote(output, truth))
    return summary


def _simulate_tracker(machine, output: Path, noise: str | None, seed: int, deviations: str,
                      truth: Path | None, shape: tuple[int, int, int],
                      outliers: int, file_setups=None) -> Summary:
    """A laser tracker on a platform that only translates: the nominal model commands the
    points of a grid around home, the true machine goes elsewhere (seed 001)."""
    from ..instruments.setups import Setups
    from ..instruments.tracker import (
        TRACKER_GRID_SPACING,
        TrackerSetup,
        default_tracker_pose,
        grid_points,
        simulate_tracker,
    )

    noise_model, noise_text = tracker_noise_arg(noise, allow_none=True, machine=machine)
    n_points = int(np.prod(shape))
    if outliers > n_points:
        raise InputError(f"--outliers: {outliers} outliers among {n_points} grid points")
    rng = np.random.default_rng(seed)
    true = machine.with_parameters(machine.u + draw_deviations(machine, deviations, rng))
    true.name = f"simulated true machine ({deviations} deviations) of {machine.name or 'MACHINE'}"
    tracker = (file_setups or {}).get("tracker")
    pose = None if tracker is None else tracker.base_from_tracker
    pose_from = "the machine file's tracker section"
    if pose is None:
        pose, pose_from = default_tracker_pose(), "default"
    true_setups = Setups(file_setups).with_setup("tracker", TrackerSetup(pose))
    centre = machine.home[0]
    grid_text = "x".join(map(str, shape))
    targets = grid_points(centre, TRACKER_GRID_SPACING, shape)
    bad = np.flatnonzero(~np.all(np.isfinite(machine.ik(targets)), axis=-1))
    if bad.size:
        raise InputError(f"--grid {grid_text}: {bad.size} grid point(s) "
                         f"outside the workspace of {path_text(machine.source)} (e.g. "
                         f"{_mm(targets[bad[0]])} mm); use a smaller grid or another home")
    refuse_unreachable(machine, machine.reachability(targets, bed=bed_plane(true_setups)),
                       f"--grid {grid_text}: {{n}} "
                       f"grid point(s) (rows of the data file) cannot be reached by "
                       f"{machine.source}", np.arange(2, n_points + 2), (targets, None))
    refuse_outside_limits(machine, machine.ik(targets), np.arange(2, n_points + 2),
                          f"--grid {grid_text}: {{n}} grid point(s) (rows of the data file)")
    try:
        data = simulate_tracker(true, machine, targets, pose, noise_model, outliers=outliers,
                                outlier_size=1e-3, rng=rng)
    except InputError as exc:
        raise InputError(f"--deviations {deviations} (seed {seed}): {exc}; use a smaller grid "
                         "or another seed") from None
    units = file_units(machine)
    truth_text = _truth_text(machine, true, truth, true_setups)
    # outputs, at the very end
    write_tracker(output, data.q, data.m, joint_unit=units["angle"],
                  length_unit=units["length"])
    if truth is not None:
        atomic_write_text(truth, truth_text)
    commit_outputs()
    R, t = pose
    summary, table = _settings(machine)
    dx, dy, dz = (v * 1e3 for v in TRACKER_GRID_SPACING)
    table.add_row("scenario", f"tracker, {grid_text} grid (dx = {dx:g}, dy = "
                  f"{dy:g}, dz = {dz:g} mm) centred at home {_mm(centre)} mm: {n_points} points")
    table.add_row("deviations", _deviation_words(deviations, seed))
    table.add_row("tracker noise", f"{noise_text} (seed {seed})")
    table.add_row("tracker pose", f"{pose_from}: at {_mm(t)} mm in the base frame, rotated "
                  f"{np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))):.4g} deg "
                  "relative to it")
    if outliers:
        rows = data.rows[data.outliers] + 1          # file lines: header = 1
        table.add_row("outliers", f"rows {rows_text(rows, limit=50)} moved by 1 mm")
    summary.line(_wrote(output, truth))
    return summary
