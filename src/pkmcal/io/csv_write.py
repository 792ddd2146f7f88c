"""Writing data files (SPEC 6): columns with their units in the names, full precision,
atomically; every file written here is one :mod:`pkmcal.io.csv_io` reads back."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..kinematics import euler_from_matrix
from ..units import COLUMN_SUFFIXES, QUANTITIES
from .atomic import atomic_write_text
from .csv_table import _suffixes

if TYPE_CHECKING:                        # the data classes load with their instruments
    from ..instruments.pose import FullPoseData


def _text(value) -> str:
    if isinstance(value, (bool, np.bool_)):
        return str(int(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, str):
        return value
    return repr(float(value))


def write_table(path, header: list[str], columns: list, extra: dict | None = None) -> Path:
    """Write columns (equal-length sequences) under ``header`` as CSV, atomically.

    Floats are written with ``repr`` (full precision), booleans as 0/1.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    header : list of str
        Column names.
    columns : list of sequence
        One sequence per column.
    extra : dict, optional
        Further columns after them, name -> sequence.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    ValueError
        When the columns have different lengths.
    """
    if extra:
        header = list(header) + list(extra)
        columns = list(columns) + [list(v) for v in extra.values()]
    n = {len(c) for c in columns}
    if len(n) > 1:
        raise ValueError("all columns must have the same length")
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    for k in range(n.pop() if n else 0):
        writer.writerow([_text(c[k]) for c in columns])
    return atomic_write_text(path, buf.getvalue())


def _unit_factor(unit: str, quantity: str) -> float:
    if COLUMN_SUFFIXES.get(unit) != quantity:
        raise InputError(f"unknown {quantity} unit {unit!r} for a column (accepted: "
                         f"{', '.join(_suffixes(quantity))})")
    return QUANTITIES[quantity][unit]


def write_constraint_link(path, data, machine, length_unit: str = "mm") -> Path:
    """Write constraint-link data: the joint readings ``q1_<unit> ...`` and the passive joint
    (1..n) of each pose (:func:`read_constraint_link` reads them back).

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    data : ConstraintLinkData
        The data (``q``, 0-based ``passive``).
    machine : Machine
        The machine (unused: its joints are lengths in ``length_unit``).
    length_unit : str, optional
        Column unit of the readings.

    Returns
    -------
    pathlib.Path
        The path written.
    """
    return write_joints(path, data.q, unit=length_unit, extra={"passive": data.passive + 1})


def write_joints(path, q, unit: str = "mm", extra: dict | None = None,
                 quantity: str = "length") -> Path:
    """Write joint values as ``q1_<unit> ...``, plus ``extra`` columns.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    q : array_like, shape (K, n)
        Joint values, internal units (m or rad).
    unit : str, optional
        Column unit (a CSV suffix of ``quantity``: m, mm, um or rad, deg, urad).
    extra : dict, optional
        Column name -> sequence, e.g. ``{"passive": passive + 1}``.
    quantity : {'length', 'angle'}, optional
        Quantity of the joints.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    InputError
        When ``unit`` is not a column unit of ``quantity``.
    """
    q = np.atleast_2d(np.asarray(q, float))
    f = _unit_factor(unit, quantity)
    header = [f"q{j + 1}_{unit}" for j in range(q.shape[1])]
    columns = [q[:, j] / f for j in range(q.shape[1])]
    return write_table(path, header, columns, extra)


def write_positions(path, P, length_unit: str = "mm", extra: dict | None = None) -> Path:
    """Write positions as ``x_<len>, y_<len>, z_<len>`` (a platform that does not rotate).

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    P : array_like, shape (K, 3)
        Positions, m.
    length_unit : str, optional
        Column unit (m, mm or um).
    extra : dict, optional
        Further columns, name -> sequence.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    InputError
        When ``length_unit`` is not a column length unit.
    """
    P = np.atleast_2d(np.asarray(P, float))
    fl = _unit_factor(length_unit, "length")
    header = [f"{c}_{length_unit}" for c in "xyz"]
    columns = [P[:, j] / fl for j in range(3)]
    return write_table(path, header, columns, extra)


def write_tracker(path, q, m, joint_unit: str = "deg", length_unit: str = "mm",
                  quantity: str = "angle", extra: dict | None = None) -> Path:
    """Write tracker data: readings as ``q1_<joint_unit> ...`` and points as ``mx, my, mz``.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    q : array_like, shape (K, n)
        Readings, internal units.
    m : array_like, shape (K, 3)
        Tracker points, m.
    joint_unit : str, optional
        Column unit of the readings.
    length_unit : str, optional
        Column unit of the points.
    quantity : {'angle', 'length'}, optional
        Quantity of the readings.
    extra : dict, optional
        Further columns, name -> sequence.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    InputError
        When a unit is not a column unit of its quantity.
    """
    q = np.atleast_2d(np.asarray(q, float))
    m = np.atleast_2d(np.asarray(m, float))
    fq, fl = _unit_factor(joint_unit, quantity), _unit_factor(length_unit, "length")
    header = [f"q{j + 1}_{joint_unit}" for j in range(q.shape[1])] + \
             [f"m{c}_{length_unit}" for c in "xyz"]
    columns = [q[:, j] / fq for j in range(q.shape[1])] + [m[:, j] / fl for j in range(3)]
    return write_table(path, header, columns, extra)


def write_poses(path, P, R, length_unit: str = "mm", angle_unit: str = "deg",
                extra: dict | None = None) -> Path:
    """Write poses as ``x_<len>, y_<len>, z_<len>, psi_<ang>, theta_<ang>, phi_<ang>``.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    P : array_like, shape (K, 3)
        Positions, m.
    R : array_like, shape (K, 3, 3)
        Orientations (written as Euler angles, :func:`~pkmcal.kinematics.euler_from_matrix`).
    length_unit : str, optional
        Column unit of the positions.
    angle_unit : str, optional
        Column unit of the angles.
    extra : dict, optional
        Further columns, name -> sequence.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    InputError
        When a unit is not a column unit of its quantity.
    """
    P = np.atleast_2d(np.asarray(P, float))
    fl, fa = _unit_factor(length_unit, "length"), _unit_factor(angle_unit, "angle")
    angles = np.atleast_2d(euler_from_matrix(np.asarray(R, float))) / fa
    header = [f"{c}_{length_unit}" for c in "xyz"] + \
             [f"{c}_{angle_unit}" for c in ("psi", "theta", "phi")]
    columns = [P[:, j] / fl for j in range(3)] + [angles[:, j] for j in range(3)]
    return write_table(path, header, columns, extra)


def write_readings(path, q, machine, extra: dict | None = None) -> Path:
    """Write joint readings as ``q1_<unit> ...`` in the machine file's joint unit
    (:meth:`~pkmcal.machines.Machine.joint_unit`: a Stewart's reading unit).

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    q : array_like, shape (K, n_joints)
        Readings, internal units.
    machine : Machine
        The machine (its joint unit).
    extra : dict, optional
        Further columns, name -> sequence.

    Returns
    -------
    pathlib.Path
        The path written.
    """
    q = np.atleast_2d(np.asarray(q, float))
    unit, f = machine.joint_unit()
    header = [f"q{j + 1}_{unit}" for j in range(q.shape[1])]
    columns = [q[:, j] / f for j in range(q.shape[1])]
    return write_table(path, header, columns, extra)


def write_full_pose(path, data: FullPoseData, machine, length_unit: str = "mm") -> Path:
    """Write full-pose data: readings, then the measured pose as ``x, y, z, qx, qy, qz, qw``.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    data : FullPoseData
        Readings and measured poses.
    machine : Stewart
        The machine (its ``reading_unit``).
    length_unit : str, optional
        Column unit of the positions.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    InputError
        When ``length_unit`` is not a column length unit.
    """
    from ..kinematics import quaternion_from_matrix

    fl = _unit_factor(length_unit, "length")
    Q = quaternion_from_matrix(data.R)
    extra = {f"{c}_{length_unit}": data.P[:, j] / fl for j, c in enumerate("xyz")}
    extra.update({name: Q[:, j] for j, name in enumerate(("qx", "qy", "qz", "qw"))})
    return write_readings(path, data.q, machine, extra)


def write_instrument(path, data, machine, length_unit: str = "mm") -> Path:
    """Write instrument data: the machine's readings, the measurement, the target / setup.

    Readings as ``q1_<unit> ...`` in the machine file's joint unit
    (:meth:`~pkmcal.machines.Machine.joint_unit`), then ``mx, my, mz`` (points) or ``d``
    (distances) or ``probe_z`` (probe heights) in ``length_unit``, then ``target`` / ``setup``
    (1..K) when there are several.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    data : InstrumentData
        The data (``kind`` ``"points"``, ``"distances"`` or ``"probe"``).
    machine : Machine
        The machine (its joint unit).
    length_unit : str, optional
        Column unit of the measurement.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    InputError
        When ``length_unit`` is not a length unit.
    """
    unit, fq = machine.joint_unit()
    fl = _unit_factor(length_unit, "length")
    q = np.atleast_2d(np.asarray(data.q, float))
    n = machine.n_joints
    header = [f"q{j % n + 1}{'b' if j >= n else ''}_{unit}" for j in range(q.shape[1])]
    columns = [q[:, j] / fq for j in range(q.shape[1])]
    from ..instruments.registry import instrument

    inst = instrument(data.kind)          # the data kind is the instrument's name or alias
    names = list(inst.data_columns)
    header += [f"{n}_{length_unit}" for n in names]
    columns += [data.values[:, j] / fl for j in range(len(names))]
    if data.n_groups > 1:
        header.append(inst.group_column)
        columns.append([int(g) + 1 for g in data.group])
    return write_table(path, header, columns)
