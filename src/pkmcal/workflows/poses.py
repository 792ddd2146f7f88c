"""Poses a user's file gives, checked against the machine: read for any platform, refused
with the rows and the reason when the machine cannot take them, and joint columns written in
the machine file's units. Shared by the commands that read or write poses (select-poses,
identifiability, ik, fk, compensate).

Every position a command reads or writes as a target or a pose of the platform is in the
machine's working frame: its base frame, except on a printer, whose frame is its bed (SPEC 8:
z is the height above the bed of the experiment's set-ups). :func:`read_targets_of` reads a
file's into the base frame the library computes in, :func:`working_positions` turns them back.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..instruments.flow import rows_text
from ..io import read_poses, read_positions
from ..paths import path_text

__all__ = ["read_poses_of", "read_targets_of", "working_positions", "frame_words",
           "joint_columns", "refuse_unreachable", "refuse_outside_limits"]


def read_poses_of(path: Path, machine):
    """The poses of a file for a machine: x, y, z and an orientation (other columns
    ignored); x, y, z only (R = I) for a platform that only translates.

    Parameters
    ----------
    path : Path
        Poses (CSV): ``x, y, z`` with ``psi, theta, phi`` or ``qx, qy, qz, qw``.
    machine : Machine
        Whether its platform rotates decides the columns read.

    Returns
    -------
    P : ndarray, shape (K, 3)
        Positions, m.
    R : ndarray, shape (K, 3, 3)
        Orientations.
    rows : ndarray of int
        The file's line of each pose.
    """
    if not machine.rotates:
        P, rows = read_positions(path)
        return P, np.broadcast_to(np.eye(3), (len(P), 3, 3)), rows
    return read_poses(path)


def read_targets_of(path: Path, machine, setups):
    """The poses of a file (:func:`read_poses_of`), given in the machine's working frame,
    with their positions in its base frame (:meth:`~pkmcal.instruments.setups.Setups.
    targets_in_base`: a printer's z is the height above its bed).

    Parameters
    ----------
    path : Path
        Poses (CSV).
    machine : Machine
        The machine.
    setups : Setups
        The experiment's set-ups (a printer's bed).

    Returns
    -------
    P : ndarray, shape (K, 3)
        Positions in the base frame, m.
    R : ndarray, shape (K, 3, 3)
        Orientations.
    rows : ndarray of int
        The file's line of each pose.
    given : ndarray, shape (K, 3)
        The positions as the file gives them (for messages), m.
    """
    given, R, rows = read_poses_of(path, machine)
    return setups.targets_in_base(machine, given), R, rows, given


def working_positions(machine, setups, P):
    """Base-frame positions as a command writes them: in the machine's working frame
    (:meth:`~pkmcal.instruments.setups.Setups.targets_from_base`; ``P`` itself unless the
    set-ups move it, e.g. a printer's tilted bed)."""
    return setups.targets_from_base(machine, P)


def frame_words(machine, setups, base: str = "base frame") -> str:
    """The frame a command's positions are in, in words: ``base`` where the working frame is
    the base frame, else the machine's :attr:`~pkmcal.machines.Machine.working_frame_words`
    (a printer with a tilted bed)."""
    return base if setups.working_frame_is_base(machine) else machine.working_frame_words


def joint_columns(machine, q, units) -> dict:
    """Columns ``q1_<unit> ...`` of joint values in a file's units.

    Parameters
    ----------
    machine : Machine
        Its :meth:`joint_unit` for ``units``.
    q : ndarray, shape (K, n)
        Joint values, SI (a Stewart's: its readings).
    units : dict
        The machine file's units (``length``, ``angle``).

    Returns
    -------
    dict
        Column name -> list of K values: the machine file's length or angle unit, a
        Stewart's reading unit.
    """
    unit, f = machine.joint_unit(units)
    return {f"q{j + 1}_{unit}": (q[:, j] / f).tolist() for j in range(q.shape[1])}


def refuse_unreachable(machine, reach, what: str, rows=None, shown=None,
                       sampled: str = "") -> None:
    """Refuse poses the machine cannot take (:meth:`~pkmcal.machines.Machine.reachability`).

    Poses outside the file's ``joint_limits`` alone are left to
    :func:`refuse_outside_limits`.

    Parameters
    ----------
    machine : Machine
        The machine (its units for the pose shown).
    reach : Reachability
        ``machine.reachability(P, R)`` of the poses.
    what : str
        The message's start; ``{n}`` is the count of such poses (``"t.csv: {n} target(s)
        cannot be reached by the calibrated machine"``).
    rows : ndarray of int, optional
        The file's line of each pose, named in the message.
    shown : tuple
        ``(P, R)`` as the user gave them (R may be None): the first such pose is shown.
    sampled : str
        Without ``rows``: what the poses sample (``"500 poses of the box"``).

    Raises
    ------
    InputError
        One line: ``what``, the rows (or how many of the sampled poses), the first such pose
        and why.
    """
    bad = np.flatnonzero(~reach.ok & ~reach.limits_only)
    if not bad.size:
        return
    P, R = shown
    k = int(bad[0])
    pose = machine.pose_text(P[k], None if R is None else R[k])
    if rows is not None:
        rows = np.asarray(rows)
        where = (f", row(s) {rows_text(rows[bad])}: row {rows[k]} at {pose}: "
                 f"{reach.reasons[k]}")
    else:
        where = f" ({bad.size} of {sampled}), e.g. at {pose}: {reach.reasons[k]}"
    raise InputError(what.format(n=bad.size) + where)


def refuse_outside_limits(machine, q, rows, what: str) -> None:
    """Refuse joint values outside the machine file's ``joint_limits``.

    Parameters
    ----------
    machine : Machine
        Its joint limits.
    q : ndarray, shape (K, n)
        Joint values (rows with a non-finite value are left to the caller).
    rows : ndarray of int
        The file's line of each row.
    what : str
        The message's start; ``{n}`` is the count of such rows.

    Raises
    ------
    InputError
        Naming the rows and joints outside the limits.
    """
    outside = ~machine.within_limits(q) & np.all(np.isfinite(q), axis=-1)
    if outside.any():
        source = getattr(machine, "source", None) or "the machine file"
        raise InputError(f"{what.format(n=int(outside.sum()))} need joint values outside the "
                         f"joint limits of {path_text(source)} ({machine.joint_limits_text()}): "
                         f"{machine.limit_violation_text(q[outside], np.asarray(rows)[outside])}")
