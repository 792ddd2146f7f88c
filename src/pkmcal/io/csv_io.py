"""Data files (CSV, SPEC 6): units in the column names, clear errors, atomic output.

Columns read here:

- joint readings ``q1_<unit> ... qn_<unit>`` (Hexa Slide: slider travel, ``_m``, ``_mm``,
  ``_um``; Delta: arm angles ``_deg``, ``_rad``, ``_urad``), optional ``passive`` (1..6:
  which actuator was passive); :func:`joint_quantity` says which a machine has;
- poses ``x_<len>, y_<len>, z_<len>`` with either ``psi_<ang>, theta_<ang>, phi_<ang>``
  (``R = RY(theta) RX(psi) RZ(phi)``, SPEC 1) or a quaternion ``qx, qy, qz, qw``; positions
  only (``x, y, z``) for a machine whose platform does not rotate (Delta);
- laser-tracker points ``mx_<len>, my_<len>, mz_<len>`` (the reflector in the tracker frame)
  beside the readings (:func:`read_tracker`);
- Stewart leg readings ``q1_<unit> ... q6_<unit>`` in the machine's reading unit (``q1_rev``;
  any length suffix when the legs read lengths) beside a measured pose (full-pose data,
  :func:`read_full_pose`).

Row numbers in messages and in the ``rows`` arrays returned are *line numbers of the file*
(header = line 1), i.e. the row numbers a spreadsheet shows. Blank lines and lines starting
with ``#`` are skipped. Every problem is an :class:`~pkmcal.errors.InputError` naming the file,
row and column. Input files are only read; outputs are written atomically at full precision.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..kinematics import euler_from_matrix, matrix_from_euler, matrix_from_quaternion
from ..measurements import ConstraintLinkData, TrackerData
from ..measurements.full_pose import FullPoseData
from ..units import COLUMN_SUFFIXES, LENGTH, QUANTITIES
from .atomic import atomic_write_text, read_input_text

Row = tuple[int, list[str]]


def _suffixes(quantity: str) -> list[str]:
    return [s for s, q in COLUMN_SUFFIXES.items() if q == quantity]


def read_table(path) -> tuple[list[str], list[Row]]:
    """Header and data rows of a CSV file.

    Returns ``(header, rows)``: ``header`` the stripped column names, ``rows`` a list of
    ``(line_number, fields)`` (line numbers of the file, header = 1). Raises
    :class:`InputError` for a missing or empty file, duplicate column names, a row with the
    wrong number of fields, or no data rows.
    """
    path = Path(path)
    text = read_input_text(path, "data file")
    reader = csv.reader(io.StringIO(text, newline=""))
    header: list[str] | None = None
    header_line = 0
    rows: list[Row] = []
    try:
        for fields in reader:
            line = reader.line_num
            if not fields or all(not f.strip() for f in fields) or fields[0].lstrip(
                    ).startswith("#"):
                continue
            fields = [f.strip() for f in fields]
            if header is None:
                header, header_line = fields, line
                continue
            if len(fields) != len(header):
                raise InputError(f"{path}: row {line}: {len(fields)} field(s), the header (row "
                                 f"{header_line}) has {len(header)} columns")
            rows.append((line, fields))
    except csv.Error as exc:
        raise InputError(f"{path}: row {reader.line_num}: CSV syntax error: {exc}") from None
    if header is None:
        raise InputError(f"{path}: empty file (expected a header line such as "
                         "q1_mm,q2_mm,q3_mm,q4_mm,q5_mm,q6_mm)")
    empty = [i + 1 for i, name in enumerate(header) if not name]
    if empty:
        raise InputError(f"{path}: row {header_line}: column {empty[0]} has no name")
    seen: set[str] = set()
    for name in header:
        if name in seen:
            raise InputError(f"{path}: row {header_line}: column {name!r} appears twice")
        seen.add(name)
    if not rows:
        raise InputError(f"{path}: no data rows after the header")
    return header, rows


def _a(word: str) -> str:
    return "an" if word[:1] in "aeiou" else "a"


def find_column(path, header: list[str], base: str, quantity: str | None,
                required: bool = True) -> tuple[int, float] | None:
    """Position and SI factor of the column ``base_<unit>`` (or ``base`` when ``quantity`` is
    None). Raises :class:`InputError` for a missing column, a missing or unknown unit suffix,
    a unit of the wrong quantity, or two columns for the same value."""
    if quantity is None:
        if base in header:
            return header.index(base), 1.0
        if required:
            raise InputError(f"{path}: missing column {base}; columns found: {', '.join(header)}")
        return None
    accepted = _suffixes(quantity)
    example = f"{base}_{accepted[0] if quantity != 'length' else 'mm'}"
    candidates = [i for i, n in enumerate(header) if n == base or n.startswith(base + "_")]
    if not candidates:
        if required:
            raise InputError(f"{path}: missing column {base}_<unit> (e.g. {example}); columns "
                             f"found: {', '.join(header)}")
        return None
    if len(candidates) > 1:
        names = ", ".join(header[i] for i in candidates)
        raise InputError(f"{path}: more than one column for {base}: {names}; keep one")
    i = candidates[0]
    name = header[i]
    if name == base:
        raise InputError(f"{path}: column {name!r} has no unit suffix: write {example} "
                         f"(accepted units: {', '.join(accepted)})")
    unit = name[len(base) + 1:]
    if unit not in COLUMN_SUFFIXES:
        raise InputError(f"{path}: column {name!r}: unknown unit suffix {unit!r} (accepted "
                         f"for {quantity}: {', '.join(accepted)})")
    if COLUMN_SUFFIXES[unit] != quantity:
        other = COLUMN_SUFFIXES[unit]
        raise InputError(f"{path}: column {name!r}: {unit!r} is {_a(other)} {other} unit, "
                         f"{base} is {_a(quantity)} {quantity} (accepted: "
                         f"{', '.join(accepted)})")
    return i, QUANTITIES[quantity][unit]


def parse_number(path, line: int, column: str, text: str) -> float:
    """A finite float from one CSV field, or :class:`InputError` naming file, row, column."""
    where = f"{path}: row {line}, column {column}"
    if not text:
        raise InputError(f"{where}: empty value")
    try:
        if "_" in text:
            raise ValueError
        value = float(text)
    except ValueError:
        raise InputError(f"{where}: not a number: {text!r}") from None
    if not math.isfinite(value):
        raise InputError(f"{where}: not a finite number: {text!r}")
    return value


def _column_values(path, header, rows: list[Row], index: int, factor: float) -> np.ndarray:
    name = header[index]
    return np.array([parse_number(path, line, name, f[index]) for line, f in rows]) * factor


def joint_quantity(machine) -> str:
    """``"length"`` or ``"angle"``: the quantity of ``machine``'s joint readings (declared by
    the machine class: prismatic actuators read lengths, revolute ones angles)."""
    return machine.joint_quantity


def read_joints(path, n_joints: int, quantity: str = "length"):
    """Joint readings ``q1_<unit> ... q<n>_<unit>`` in internal units.

    Returns ``(q (K, n_joints), rows (K,), extra)``: ``rows`` the file line numbers of the data
    rows, ``extra`` a dict ``column name -> list of raw strings`` of the other columns.
    """
    header, rows = read_table(path)
    cols = [find_column(path, header, f"q{j + 1}", quantity) for j in range(n_joints)]
    q = np.column_stack([_column_values(path, header, rows, i, f) for i, f in cols])
    used = {i for i, _ in cols}
    extra = {name: [f[k] for _, f in rows] for k, name in enumerate(header) if k not in used}
    return q, np.array([line for line, _ in rows]), extra


def read_passive(path, extra: dict, rows, n_joints: int) -> np.ndarray | None:
    """0-based passive actuator per row from the ``passive`` column (1..n in the file).

    ``extra``: raw columns as returned by :func:`read_joints`; None when there is no column.
    """
    values = extra.get("passive")
    if values is None:
        return None
    out = np.empty(len(values), int)
    for k, (line, text) in enumerate(zip(rows, values, strict=True)):
        v = parse_number(path, int(line), "passive", text)
        if v != int(v) or not 1 <= v <= n_joints:
            raise InputError(f"{path}: row {line}, column passive: must be an actuator number "
                             f"1..{n_joints}, got {text!r}")
        out[k] = int(v) - 1
    return out


def read_constraint_link(path, machine) -> ConstraintLinkData:
    """Constraint-link data (SPEC 2.1) for ``machine``: readings + optional ``passive``.

    The link length is the machine's ``constraint_link_length`` (machine file key
    ``constraint_link: {length: ...}``).
    """
    if getattr(machine, "constraint_link_length", None) is None:
        source = getattr(machine, "source", "the machine")
        raise InputError(f"{source}: constraint_link: the machine has no constraint-link "
                         "length; add `constraint_link: {length: ...}` (in the file's length "
                         "unit) to the machine file")
    q, rows, extra = read_joints(path, machine.n_joints)
    passive = read_passive(path, extra, rows, machine.n_joints)
    return ConstraintLinkData(q, float(machine.constraint_link_length), passive, rows,
                              source=str(path))


def read_tracker(path, machine) -> TrackerData:
    """Laser-tracker data (SPEC 2.2) for ``machine``: readings ``q1..q<n>`` (the machine's
    joint quantity, e.g. ``q1_deg`` for a Delta) and tracker points ``mx, my, mz`` (any
    length unit) per row. Other columns are ignored."""
    header, rows = read_table(path)
    quantity = joint_quantity(machine)
    q_cols = [find_column(path, header, f"q{j + 1}", quantity)
              for j in range(machine.n_joints)]
    m_cols = [find_column(path, header, c, "length") for c in ("mx", "my", "mz")]
    q = np.column_stack([_column_values(path, header, rows, i, f) for i, f in q_cols])
    m = np.column_stack([_column_values(path, header, rows, i, f) for i, f in m_cols])
    return TrackerData(q, m, np.array([line for line, _ in rows]), source=str(path))


def _reading_columns(path, header: list[str], machine) -> list[tuple[int, float]]:
    """Positions and factors of a Stewart's reading columns ``q1_<unit> ... q6_<unit>``."""
    unit = getattr(machine, "reading_unit", "m")
    if unit in LENGTH:
        return [find_column(path, header, f"q{j + 1}", "length")
                for j in range(machine.n_joints)]
    source = getattr(machine, "source", "the machine file")
    out = []
    for j in range(machine.n_joints):
        name = f"q{j + 1}_{unit}"
        if name in header:
            out.append((header.index(name), 1.0))
            continue
        others = [n for n in header if n == f"q{j + 1}" or n.startswith(f"q{j + 1}_")]
        found = f" (found {', '.join(others)})" if others else ""
        raise InputError(f"{path}: missing column {name}{found}: the legs of {source} read in "
                         f"{unit} (machine file key readings: {{unit: {unit}}}); columns found: "
                         f"{', '.join(header)}")
    return out


def read_readings(path, machine):
    """Stewart leg readings ``(q (K, 6), rows (K,))`` in internal units: metres for length
    readings (any length suffix), else as read in the machine's reading unit (``q1_rev``)."""
    header, rows = read_table(path)
    cols = _reading_columns(path, header, machine)
    q = np.column_stack([_column_values(path, header, rows, i, f) for i, f in cols])
    return q, np.array([line for line, _ in rows])


def read_full_pose(path, machine) -> FullPoseData:
    """Full-pose data (SPEC 2.4) for a Stewart ``machine``: readings ``q1..q6`` (its reading
    unit) and the measured pose ``x, y, z`` + ``psi, theta, phi`` or ``qx, qy, qz, qw`` per
    row (the marker frame in the measurement frame). Other columns are ignored."""
    q, rows = read_readings(path, machine)
    P, R, _ = read_poses(path)
    return FullPoseData(q, P, R, rows, source=str(path))


ORIENTATION_COLUMNS = ("psi", "theta", "phi", "qx", "qy", "qz", "qw")


def has_orientation(header: list[str]) -> bool:
    """True when a header has orientation columns (Euler angles or a quaternion)."""
    return any(n == c or n.startswith(c + "_") for n in header for c in ORIENTATION_COLUMNS)


def read_positions(path, orientation_tol: float = 1e-9):
    """Positions ``(P (K, 3) m, rows (K,))`` from ``x, y, z`` columns, for a platform that does
    not rotate. Orientation columns, when present, must describe no rotation (angle below
    ``orientation_tol`` rad); otherwise :class:`InputError` names the row."""
    header, rows = read_table(path)
    lines = np.array([line for line, _ in rows])
    if has_orientation(header):
        P, R, lines = read_poses(path)
        angle = np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1, 1))
        bad = np.flatnonzero(angle > orientation_tol)
        if bad.size:
            raise InputError(f"{path}: row {lines[bad[0]]}: the orientation columns describe a "
                             f"rotation of {np.degrees(angle[bad[0]]):.6g} deg, but this "
                             "platform does not rotate (translation only): give x, y, z only "
                             "or zero angles")
        return P, lines
    P = np.column_stack([_column_values(path, header, rows, *find_column(path, header, c,
                                                                         "length"))
                         for c in ("x", "y", "z")])
    return P, lines


def read_poses(path):
    """Poses ``(P (K, 3) m, R (K, 3, 3), rows (K,))`` from position and orientation columns.

    Orientation: ``psi/theta/phi_<angle unit>`` or ``qx, qy, qz, qw`` (normalised).
    """
    header, rows = read_table(path)
    lines = np.array([line for line, _ in rows])
    P = np.column_stack([_column_values(path, header, rows, *find_column(path, header, c,
                                                                         "length"))
                         for c in ("x", "y", "z")])
    euler = [find_column(path, header, c, "angle", required=False)
             for c in ("psi", "theta", "phi")]
    quat = [find_column(path, header, c, None, required=False) for c in ("qx", "qy", "qz", "qw")]
    has_euler, has_quat = any(e is not None for e in euler), any(c is not None for c in quat)
    if has_euler and has_quat:
        raise InputError(f"{path}: both Euler-angle (psi, theta, phi) and quaternion (qx, qy, "
                         "qz, qw) columns: keep one orientation")
    if has_quat:
        missing = [n for n, c in zip(("qx", "qy", "qz", "qw"), quat, strict=True) if c is None]
        if missing:
            raise InputError(f"{path}: missing column(s) {', '.join(missing)} of the quaternion "
                             "qx, qy, qz, qw")
        Q = np.column_stack([_column_values(path, header, rows, *c) for c in quat])
        norm = np.linalg.norm(Q, axis=1)
        bad = np.flatnonzero(norm < 1e-9)
        if bad.size:
            raise InputError(f"{path}: row {lines[bad[0]]}, columns qx, qy, qz, qw: the "
                             "quaternion is zero")
        R = matrix_from_quaternion(Q)
    elif has_euler:
        for name, c in zip(("psi", "theta", "phi"), euler, strict=True):
            if c is None:
                find_column(path, header, name, "angle")  # raises: missing column
        R = matrix_from_euler(np.column_stack([_column_values(path, header, rows, *c)
                                               for c in euler]))
    else:
        raise InputError(f"{path}: missing orientation columns: psi_deg, theta_deg, phi_deg "
                         f"(or _rad) or qx, qy, qz, qw; columns found: {', '.join(header)}")
    return P, R, lines


def _text(value) -> str:
    if isinstance(value, (bool, np.bool_)):
        return str(int(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, str):
        return value
    return repr(float(value))


def write_table(path, header: list[str], columns: list) -> Path:
    """Write columns (equal-length sequences) under ``header`` as CSV, atomically."""
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


def write_joints(path, q, unit: str = "mm", extra: dict | None = None,
                 quantity: str = "length") -> Path:
    """Write joint values ``q`` (K, n) in internal units as ``q1_<unit> ...`` (+ ``extra``
    columns, name -> sequence, e.g. ``{"passive": passive + 1}``)."""
    q = np.atleast_2d(np.asarray(q, float))
    f = _unit_factor(unit, quantity)
    header = [f"q{j + 1}_{unit}" for j in range(q.shape[1])]
    columns = [q[:, j] / f for j in range(q.shape[1])]
    for name, values in (extra or {}).items():
        header.append(name)
        columns.append(list(values))
    return write_table(path, header, columns)


def write_positions(path, P, length_unit: str = "mm", extra: dict | None = None) -> Path:
    """Write positions as ``x_<len>, y_<len>, z_<len>`` (a platform that does not rotate)."""
    P = np.atleast_2d(np.asarray(P, float))
    fl = _unit_factor(length_unit, "length")
    header = [f"{c}_{length_unit}" for c in "xyz"]
    columns = [P[:, j] / fl for j in range(3)]
    for name, values in (extra or {}).items():
        header.append(name)
        columns.append(list(values))
    return write_table(path, header, columns)


def write_tracker(path, q, m, joint_unit: str = "deg", length_unit: str = "mm",
                  quantity: str = "angle", extra: dict | None = None) -> Path:
    """Write tracker data: readings ``q`` (K, n) as ``q1_<joint_unit> ...`` and tracker points
    ``m`` (K, 3) as ``mx_<len>, my_<len>, mz_<len>`` (internal units in, file units out)."""
    q = np.atleast_2d(np.asarray(q, float))
    m = np.atleast_2d(np.asarray(m, float))
    fq, fl = _unit_factor(joint_unit, quantity), _unit_factor(length_unit, "length")
    header = [f"q{j + 1}_{joint_unit}" for j in range(q.shape[1])] + \
             [f"m{c}_{length_unit}" for c in "xyz"]
    columns = [q[:, j] / fq for j in range(q.shape[1])] + [m[:, j] / fl for j in range(3)]
    for name, values in (extra or {}).items():
        header.append(name)
        columns.append(list(values))
    return write_table(path, header, columns)


def write_poses(path, P, R, length_unit: str = "mm", angle_unit: str = "deg",
                extra: dict | None = None) -> Path:
    """Write poses as ``x_<len>, y_<len>, z_<len>, psi_<ang>, theta_<ang>, phi_<ang>``."""
    P = np.atleast_2d(np.asarray(P, float))
    fl, fa = _unit_factor(length_unit, "length"), _unit_factor(angle_unit, "angle")
    angles = np.atleast_2d(euler_from_matrix(np.asarray(R, float))) / fa
    header = [f"{c}_{length_unit}" for c in "xyz"] + \
             [f"{c}_{angle_unit}" for c in ("psi", "theta", "phi")]
    columns = [P[:, j] / fl for j in range(3)] + [angles[:, j] for j in range(3)]
    for name, values in (extra or {}).items():
        header.append(name)
        columns.append(list(values))
    return write_table(path, header, columns)


def write_readings(path, q, machine, extra: dict | None = None) -> Path:
    """Write Stewart readings ``q`` (K, 6, internal units) as ``q1_<unit> ...`` in the
    machine's reading unit."""
    q = np.atleast_2d(np.asarray(q, float))
    unit = getattr(machine, "reading_unit", "m")
    f = LENGTH[unit] if unit in LENGTH else 1.0
    header = [f"q{j + 1}_{unit}" for j in range(q.shape[1])]
    columns = [q[:, j] / f for j in range(q.shape[1])]
    for name, values in (extra or {}).items():
        header.append(name)
        columns.append(list(values))
    return write_table(path, header, columns)


def write_full_pose(path, data: FullPoseData, machine, length_unit: str = "mm") -> Path:
    """Write full-pose data: readings in ``machine``'s reading unit, then the measured pose as
    ``x_<len>, y_<len>, z_<len>, qx, qy, qz, qw``."""
    from ..kinematics import quaternion_from_matrix

    fl = _unit_factor(length_unit, "length")
    Q = quaternion_from_matrix(data.R)
    extra = {f"{c}_{length_unit}": data.P[:, j] / fl for j, c in enumerate("xyz")}
    extra.update({name: Q[:, j] for j, name in enumerate(("qx", "qy", "qz", "qw"))})
    return write_readings(path, data.q, machine, extra)
