"""``pkmcal fk`` and ``pkmcal ik`` as library functions: joint readings of a file to poses
(or to what an instrument would measure), and poses of a file to joint values; with the
steps other commands share to read poses and to refuse poses a machine cannot take.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..calibration.run import file_units
from ..errors import InputError
from ..instruments.flow import rows_text
from ..instruments.probe import bed_plane
from ..io import (
    joint_quantity,
    read_joints,
    read_readings,
    write_poses,
    write_positions,
    write_table,
)
from ..paths import path_text
from ..report.summary import Summary
from .common import (
    check_outputs,
    commit_outputs,
    group_numbers,
    load_machine_setups_arg,
    machine_inputs,
)
from .poses import (
    frame_words,
    joint_columns,
    read_targets_of,
    refuse_outside_limits,
    refuse_unreachable,
    working_positions,
)

__all__ = ["fk", "ik"]


def fk(machine_spec: str, joints: Path, output: Path, frame: str = "base",
       instrument: str | None = None) -> Summary:
    """``pkmcal fk``: forward kinematics of every row of a joint file, written as a file.

    Parameters
    ----------
    machine_spec : str
        A machine file, or ``"default"``.
    joints : Path
        Joint readings (CSV, ``q1_<unit> ...``; a Stewart's reading unit).
    output : Path
        The poses (``x, y, z`` + ``psi, theta, phi`` where the platform rotates; positions
        only where it translates) in the machine's working frame (the base frame; a
        printer's: z the height above its bed, SPEC 8) and the machine file's units; with
        ``frame="instrument"`` what the instrument would measure.
    frame : {"base", "instrument"}
        ``instrument``: the calibration's instrument's predicted measurements (``mx, my, mz``
        [+ ``target``], a marker pose, ``d`` [+ ``setup``]).
    instrument : str, optional
        With ``frame="instrument"``, which instrument when the file carries several frames.

    Returns
    -------
    Summary
        One line: how many poses were written, where, in which units.

    Raises
    ------
    InputError
        Bad input (the file, row and column named); a row whose forward kinematics does not
        converge. Nothing is written then.
    """
    if frame == "instrument":
        return _fk_instrument(machine_spec, joints, output, instrument)
    if instrument is not None:
        raise InputError(f"--instrument {instrument}: only with --frame instrument (the "
                         "instrument's predicted measurements); --frame base writes poses")
    machine, setups = load_machine_setups_arg(machine_spec)
    check_outputs([output], [joints] + machine_inputs(machine_spec))
    if getattr(machine, "reading_unit", None) is not None:   # readings in their own unit
        q, rows = read_readings(joints, machine)
    else:
        q, rows, _ = read_joints(joints, machine.n_joints, joint_quantity(machine), machine)
    result = machine.fk(q)
    result.raise_if_failed(what=f"{joints}: forward kinematics", rows=rows)
    units = file_units(machine)
    P = working_positions(machine, setups, result.P)     # a printer's: above its bed
    summary = Summary()
    if not machine.rotates:
        write_positions(output, P, units["length"])
        commit_outputs()
        where = frame_words(machine, setups, "")
        summary.line(f"{len(q)} position(s) of the platform point, "
                     + (f"written to {path_text(output)} ({units['length']}, {where})" if where
                        else f"base frame, written to {path_text(output)} "
                             f"({units['length']})"))
        return summary
    write_poses(output, P, result.R, units["length"], units["angle"])
    commit_outputs()
    where = frame_words(machine, setups, "")
    where = f", {where}" if where else ""
    summary.line(f"{len(q)} pose(s) written to {path_text(output)} ({units['length']}, "
                 f"{units['angle']}{where})")
    return summary


def _fk_instrument(machine_spec: str, joints: Path, output: Path,
                   instrument: str | None) -> Summary:
    """``pkmcal fk --frame instrument``: what the calibration's instrument measures for the
    readings (:func:`~pkmcal.instruments.predict_instrument`), in the machine file's length
    unit: ``mx, my, mz`` (+ ``target``), ``x, y, z, qx, qy, qz, qw`` or ``d`` (+ ``setup``)."""
    from ..instruments import choose_instrument, predict_instrument
    from ..instruments.registry import instrument as entry
    from ..io.csv_io import machine_readings

    machine, setups = load_machine_setups_arg(machine_spec)
    name = choose_instrument(machine, setups, instrument, option="--instrument")
    inst = entry(name)
    check_outputs([output], [joints] + machine_inputs(machine_spec))
    q, rows, extra, _ = machine_readings(joints, machine)
    column = inst.group_column
    group = group_numbers(joints, extra, rows, column) if column else None
    pred = predict_instrument(machine, setups, q, name, group, rows=rows, source=str(joints))
    pred.fk.raise_if_failed(what=f"{joints}: forward kinematics", rows=rows)
    unit = file_units(machine)["length"]
    columns = inst.prediction_columns(pred, unit)
    if group is not None:
        columns[column] = (group + 1).tolist()
    write_table(output, list(columns), [list(v) for v in columns.values()])
    commit_outputs()
    summary = Summary()
    summary.line(f"{len(q)} {inst.prediction_words} written to {path_text(output)} ({unit})")
    return summary


def ik(machine_spec: str, poses: Path, output: Path) -> Summary:
    """``pkmcal ik``: the joint values of every pose of a file, written as a file.

    Parameters
    ----------
    machine_spec : str
        A machine file, or ``"default"``.
    poses : Path
        Poses (CSV): ``x, y, z`` with ``psi, theta, phi`` or ``qx, qy, qz, qw``; positions
        only for a platform that only translates; in the machine's working frame (the base
        frame; a printer's: z the height above its bed).
    output : Path
        Joint values ``q1_<unit> ...`` in the machine file's units (a Stewart's reading
        unit).

    Returns
    -------
    Summary
        One line: how many joint vectors were written, where, in which unit.

    Raises
    ------
    InputError
        A pose the machine cannot take (no real inverse kinematics, outside the working mode
        or the joint limits), named by its rows; nothing is written then.
    """
    machine, setups = load_machine_setups_arg(machine_spec)
    check_outputs([output], [poses] + machine_inputs(machine_spec))
    P, R, rows, given = read_targets_of(poses, machine, setups)   # a printer's: above its bed
    q = machine.ik(P, R)
    bad = ~np.all(np.isfinite(q), axis=1)
    what = machine.chain_word
    if bad.any():
        chains = np.flatnonzero((~np.isfinite(q[bad])).any(axis=0)) + 1
        raise InputError(f"{poses}: {int(bad.sum())} pose(s) cannot be reached by the machine "
                         f"(no real inverse kinematics, {what}(s) "
                         f"{', '.join(map(str, chains))}), row(s) {rows_text(rows[bad])}")
    off = ~machine.working_mode(P, R)
    if off.any():
        raise InputError(f"{poses}: {int(off.sum())} pose(s) outside the machine's working "
                         f"mode (farther than {machine.MAX_REACH:g}x the machine's size from "
                         "home, or beyond a singularity, e.g. mirrored through the base), "
                         f"row(s) {rows_text(rows[off])}")
    if not machine.rotates:
        # the closed-form FK takes the working assembly mode (platform below the base): a
        # position the arms reach only on the other mode cannot be commanded back
        back = machine.fk(q).P
        off = ~(np.linalg.norm(back - P, axis=1) <= 1e-9 + 1e-9 * np.linalg.norm(P, axis=1))
        if off.any():
            raise InputError(f"{poses}: {int(off.sum())} position(s) outside the working "
                             f"assembly mode (the platform must hang below the base), row(s) "
                             f"{rows_text(rows[off])}")
    refuse_unreachable(machine, machine.reachability(P, R, bed=bed_plane(setups)),
                       f"{poses}: {{n}} pose(s) cannot "
                       "be reached by the machine", rows, (given, R))
    refuse_outside_limits(machine, q, rows, f"{poses}: {{n}} pose(s)")
    columns = joint_columns(machine, q, file_units(machine))
    write_table(output, list(columns), list(columns.values()))
    unit = next(iter(columns)).split("_", 1)[1]
    commit_outputs()
    summary = Summary()
    summary.line(f"{len(q)} {machine.joint_vector_word} vector(s) written to "
                 f"{path_text(output)} ({unit})")
    return summary
