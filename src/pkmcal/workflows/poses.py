"""Poses a user's file gives, checked against the machine: read for any platform, refused
with the rows and the reason when the machine cannot take them, and joint columns written in
the machine file's units. Shared by the commands that read or write poses (select-poses,
identifiability, ik, compensate)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..instruments.flow import rows_text
from ..io import read_poses, read_positions
from ..paths import path_text

__all__ = ["read_poses_of", "joint_columns", "refuse_unreachable", "refuse_outside_limits"]


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
        where = (f", row(s) {rows_text(rows[bad])}: row {rows[k]} at {pose}: "
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
