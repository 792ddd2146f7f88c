"""``pkmcal errors`` as a library function (seed 003): leg forces and pose errors from joint
clearance under loads (weight, cutting force, inertia) along a trajectory, written as a CSV
(and its envelope beside it, plots on request)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import read_table
from ..io.atomic import is_stream
from ..io.machine_file import DEFAULT_UNITS
from ..paths import path_text
from ..plausibility import check_option_scale
from ..report.summary import Summary
from ..units import format_number, format_quantity, parse_quantity
from .common import check_outputs, commit_outputs, load_machine_arg, machine_inputs

__all__ = ["errors", "read_trajectory_file", "ERRORS_PLOTS"]


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


def read_trajectory_file(path: Path):
    """Read a trajectory: poses over time.

    Parameters
    ----------
    path : Path
        CSV with a time column ``t_<unit>`` (``t_s``), ``x, y, z`` and optionally an
        orientation (``psi, theta, phi`` or ``qx, qy, qz, qw``; none: no rotation).

    Returns
    -------
    t : ndarray, shape (K,)
        Times, s, strictly increasing.
    P : ndarray, shape (K, 3)
        Positions, m.
    R : ndarray, shape (K, 3, 3)
        Orientations.
    lines : ndarray, shape (K,)
        The file's line of each pose.

    Raises
    ------
    InputError
        A missing or ambiguous time column, an unknown time unit, fewer than 3 poses, times
        that do not increase (the file, row and column named).
    """
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


def errors(machine_spec: str, output: Path, trajectory: str | None = None,
           trajectory_file: Path | None = None, radius: str | None = None,
           height: str | None = None, omega: str | None = None, samples: int | None = None,
           clearance: str = "10um", platform_clearance: str | None = None,
           mass: str = "4.8kg", cutting_force: str = "0,0,-500N", screw_error: str = "0um",
           force_tol: str = "1N", plot: Path | None = None) -> Summary:
    """``pkmcal errors``: leg forces and pose errors from joint clearance along a trajectory.

    Options are quantities as the command line gives them (a unit suffix; a bare number is
    SI).

    Parameters
    ----------
    machine_spec : str
        A six-leg machine file (``machine: stewart``), or ``"cubic"`` (seed 003's device).
    output : Path
        The CSV: ``angle_deg`` (``t_s`` for a file trajectory), ``f1_N..f6_N``, ``dx_um,
        dy_um, dz_um, drx_urad, dry_urad, drz_urad``; the envelope where a leg force is too
        small to tell the clearance side goes to ``OUTPUT_envelope.csv`` beside it.
    trajectory : {"circle", "file"}, optional
        Default ``file`` with ``trajectory_file``, else ``circle``.
    trajectory_file : Path, optional
        Poses over time (:func:`read_trajectory_file`).
    radius : str, optional
        circle: radius (default ``100mm``).
    height : str, optional
        circle: height of the platform origin (default ``410mm``).
    omega : str, optional
        circle: angular speed, counter-clockwise from +X (default ``10rad/s``).
    samples : int, optional
        circle: samples, sample k at 360 k / samples deg (default 360).
    clearance : str
        Radius of the sphere each joint centre can sit in.
    platform_clearance : str, optional
        The platform joints' clearance when it differs (default ``clearance``).
    mass : str
        Platform mass (centre of mass at its origin).
    cutting_force : str
        ``fx,fy,fz`` with a unit, at the platform origin, base frame.
    screw_error : str
        Ball-screw backlash.
    force_tol : str
        A leg force within this of zero leaves its joints' side undetermined.
    plot : Path, optional
        A directory for the plots (:data:`ERRORS_PLOTS`, PNG).

    Returns
    -------
    Summary
        The settings table titled ``pkmcal errors: MACHINE`` (trajectory, loads, clearance),
        the leg-force table (min, max, where each changes side), the pose-error table (min,
        max, envelope, sign changes), notes, and the ``wrote ...`` line.

    Raises
    ------
    InputError
        A bad option or file (named), a pose the machine cannot take; nothing is written.
    """
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
    inputs = machine_inputs(machine_spec) if machine_spec != "cubic" else []
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
        t, P, R, lines = read_trajectory_file(trajectory_file)
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
    return _errors_summary(machine, where, result, trajectory, mass_kg, f_cut, c_base,
                           c_platform, backlash, tol_n, output, plots)


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


def _errors_summary(machine, where, result, trajectory, mass_kg, f_cut, c_base, c_platform,
                    backlash, tol_n, output, plots) -> Summary:
    from ..analysis.errors import ERROR_COMPONENTS, STANDARD_GRAVITY, zero_crossings

    path, e, f = result.trajectory, result.errors, result.forces
    if trajectory == "circle":
        x, period, unit = np.degrees(path.angle), 360.0, "deg"
    else:
        x, period, unit = path.t, None, "s"
    summary = Summary()
    table = summary.pairs(title=f"pkmcal errors: {path_text(machine.source)}")
    table.add_row("trajectory", where)
    inertia = mass_kg * np.max(np.linalg.norm(path.acceleration, axis=1))
    table.add_row("loads", f"weight {mass_kg * STANDARD_GRAVITY:.5g} N ({mass_kg:.6g} kg), "
                  f"cutting force ({', '.join(f'{v:.6g}' for v in f_cut)}) N, inertia up to "
                  f"{inertia:.5g} N")
    table.add_row("clearance", f"{format_quantity(c_base, 'length', 6)} (base joints), "
                  f"{format_quantity(c_platform, 'length', 6)} (platform joints); backlash "
                  f"{format_quantity(backlash, 'length', 6)}; side undetermined "
                  f"below {tol_n:.6g} N")
    forces = summary.table("leg", "min [N]", "max [N]", "changes side at [" + unit + "]",
                           title="leg forces (tension positive)",
                           justify={1: "right", 2: "right"})
    for i in range(6):
        cross = zero_crossings(x, f[:, i], period)
        forces.add_row(str(i + 1), f"{f[:, i].min():.5g}", f"{f[:, i].max():.5g}",
                       ", ".join(f"{c:.4g}" for c in cross) if cross.size else "-")
    pose_table = summary.table("error", "min", "max", "envelope", "changes sign at [" + unit + "]",
                           title="pose error (um, urad)", justify={1: "right", 2: "right"})
    for j, name in enumerate(ERROR_COMPONENTS):
        v = e.dx[:, j] * 1e6
        cross = zero_crossings(x, v, period)
        pose_table.add_row(name, format_number(v.min()), format_number(v.max()),
                       f"{format_number(e.dx_min[:, j].min() * 1e6)} .. "
                       f"{format_number(e.dx_max[:, j].max() * 1e6)}",
                       ", ".join(f"{c:.4g}" for c in cross[:8])
                       + (" ..." if cross.size > 8 else "") if cross.size else "-")
    envelope = output.with_name(output.stem + "_envelope" + output.suffix)
    n_und = int(np.any(e.undetermined, axis=1).sum())
    if n_und:
        summary.line(f"note: at {n_und} of {len(path)} samples a leg force is within "
                     f"{tol_n:.6g} N of zero: the main columns take those joints centred, the "
                     f"envelope of both sides is in {envelope}.")
    if trajectory == "file" and np.any(np.abs(np.diff(path.R, axis=0)) > 1e-12):
        summary.line("note: the orientation changes along the path; the platform's rotational "
                     "inertia is not modelled (translation inertia only).")
    written = [output] + ([] if is_stream(output) else [envelope])
    summary.line("wrote " + ", ".join(map(str, written + list(plots))))
    return summary
