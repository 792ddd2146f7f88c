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

The readers that get the machine also check that the data's scale fits the nominal machine
(:mod:`pkmcal.plausibility`): values off by a unit factor (metres under ``_mm``, radians under
``_deg``) are refused with the unit they look like. A header with ``;`` or tabs (a spreadsheet's
export) is refused as such.

Row numbers in messages and in the ``rows`` arrays returned are *line numbers of the file*
(header = line 1), i.e. the row numbers a spreadsheet shows. Blank lines and lines starting
with ``#`` are skipped. Every problem is an :class:`~pkmcal.errors.InputError` naming the file,
row and column. Input files are only read; outputs are written atomically at full precision.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..kinematics import matrix_from_euler, matrix_from_quaternion
from ..paths import path_text
from ..plausibility import Columns, check_full_pose_scale, check_reading_levels, check_tracker_scale
from ..units import LENGTH, QUANTITIES
from .csv_table import (  # noqa: F401  (column_map ... parse_number: re-exported, the readers' API)
    _column_values,
    column_map,
    find_column,
    parse_column_map,
    parse_number,
    read_table,
    set_column_map,
)
from .csv_write import (  # noqa: F401  (re-exported: pkmcal.io.csv_io names every data file)
    write_constraint_link,
    write_full_pose,
    write_instrument,
    write_joints,
    write_poses,
    write_positions,
    write_readings,
    write_table,
    write_tracker,
)

if TYPE_CHECKING:                        # the data classes load with their instruments
    from ..instruments.constraint_link import ConstraintLinkData
    from ..instruments.pose import FullPoseData
    from ..instruments.tracker import TrackerData


def joint_quantity(machine) -> str:
    """The quantity of ``machine``'s joint readings, as declared by the machine class.

    Parameters
    ----------
    machine : Machine
        The machine.

    Returns
    -------
    str
        ``"length"`` (prismatic actuators), ``"angle"`` (revolute ones) or, for a Stewart
        platform whose legs read in a unit that is not a length, ``"reading"``.
    """
    return machine.joint_quantity


def read_joints(path, n_joints: int, quantity: str = "length", machine=None):
    """Joint readings ``q1_<unit> ... q<n>_<unit>`` in internal units.

    Parameters
    ----------
    path : str or os.PathLike
        The data file.
    n_joints : int
        Number of joint columns.
    quantity : {'length', 'angle'}, optional
        Quantity of the readings (decides the accepted unit suffixes).
    machine : Machine, optional
        When given, the readings' level is checked against the machine's at home (values
        off by a unit factor are refused with the unit they look like).

    Returns
    -------
    q : ndarray, shape (K, n_joints)
        Readings, m or rad.
    rows : ndarray of int, shape (K,)
        File line numbers of the data rows.
    extra : dict
        Column name -> list of raw strings, for the other columns.

    Raises
    ------
    InputError
        For a missing column, a missing or wrong unit suffix, or a value that is not a finite
        number (file, row and column named).
    """
    q, rows, extra, names = _read_joints(path, n_joints, quantity)
    if machine is not None:
        _check_levels(path, q, names, quantity, machine)
    return q, rows, extra


def _read_joints(path, n_joints: int, quantity: str):
    """:func:`read_joints` and the names of the joint columns."""
    header, rows = read_table(path)
    cols = [find_column(path, header, f"q{j + 1}", quantity) for j in range(n_joints)]
    q = np.column_stack([_column_values(path, header, rows, i, f) for i, f in cols])
    used = {i for i, _ in cols}
    extra = {name: [f[k] for _, f in rows] for k, name in enumerate(header) if k not in used}
    return q, np.array([line for line, _ in rows]), extra, [header[i] for i, _ in cols]


def _unit_groups(names: list[str], bases: list[str], quantity: str) -> list[tuple[list[int],
                                                                                  Columns]]:
    """The columns of one quantity grouped by unit suffix: ``(positions, Columns)`` each."""
    groups: dict[str, list[int]] = {}
    for k, (name, base) in enumerate(zip(names, bases, strict=True)):
        groups.setdefault(name[len(base) + 1:], []).append(k)
    return [(ks, Columns([names[k] for k in ks], [bases[k] for k in ks], unit, quantity))
            for unit, ks in groups.items() if unit in QUANTITIES.get(quantity, {})]


def _check_levels(path, q, names: list[str], quantity: str, machine) -> None:
    """:func:`~pkmcal.plausibility.check_reading_levels` per unit of the joint columns."""
    bases = [f"q{j + 1}" for j in range(len(names))]
    for ks, cols in _unit_groups(names, bases, quantity):
        check_reading_levels(path, q, cols, machine, ks)


def _one_unit(names: list[str], bases: list[str], quantity: str) -> Columns | None:
    """The columns when they share one unit (the cross-checks convert them together)."""
    groups = _unit_groups(names, bases, quantity)
    return groups[0][1] if len(groups) == 1 and len(groups[0][0]) == len(names) else None


def read_passive(path, extra: dict, rows, n_joints: int) -> np.ndarray | None:
    """0-based passive actuator per row from the ``passive`` column (1..n in the file).

    Parameters
    ----------
    path : str or os.PathLike
        The data file (for messages).
    extra : dict
        Raw columns as returned by :func:`read_joints`.
    rows : array_like of int
        File line numbers of the rows (for messages).
    n_joints : int
        Number of actuators.

    Returns
    -------
    ndarray of int, shape (K,) or None
        Passive actuator of each row, 0-based; None when there is no ``passive`` column.

    Raises
    ------
    InputError
        When a value is not a whole number in 1..n_joints.
    """
    values = extra.get("passive")
    if values is None:
        return None
    out = np.empty(len(values), int)
    for k, (line, text) in enumerate(zip(rows, values, strict=True)):
        v = parse_number(path, int(line), "passive", text)
        if v != int(v) or not 1 <= v <= n_joints:
            raise InputError(f"{path_text(path)}: "
                             f"row {line}, column passive: must be an actuator number "
                             f"1..{n_joints}, got {text!r}")
        out[k] = int(v) - 1
    return out


def read_constraint_link(path, machine) -> ConstraintLinkData:
    """Constraint-link data (SPEC 2.1) for ``machine``: readings + optional ``passive``.

    The link length is the machine's ``constraint_link_length`` (machine file key
    ``constraint_link: {length: ...}``).

    Parameters
    ----------
    path : str or os.PathLike
        The data file.
    machine : HexaSlide
        The machine (number of joints, link length).

    Returns
    -------
    ConstraintLinkData
        Readings in m, link length, passive actuators (or None) and file rows.

    Raises
    ------
    InputError
        When the machine has no constraint-link length or the file is not valid, or the
        readings look like another unit than their columns say (far from the machine's
        readings at home, :func:`~pkmcal.plausibility.check_reading_levels`).
    """
    if getattr(machine, "constraint_link_length", None) is None:
        source = getattr(machine, "source", "the machine")
        raise InputError(f"{path_text(source)}: "
                         "constraint_link: the machine has no constraint-link "
                         "length; add `constraint_link: {length: ...}` (in the file's length "
                         "unit) to the machine file")
    q, rows, extra, _ = machine_readings(path, machine)
    passive = read_passive(path, extra, rows, machine.n_joints)
    from ..instruments.constraint_link import ConstraintLinkData

    return ConstraintLinkData(q, float(machine.constraint_link_length), passive, rows,
                              source=str(path))


def machine_readings(path, machine):
    """The joint readings of any machine, in internal units, their levels checked.

    Columns ``q1_<unit>..q<n>_<unit>`` in the machine's joint quantity (a Stewart's reading
    unit, :func:`read_readings`; lengths for sliders, angles for revolute joints).

    Parameters
    ----------
    path : str or os.PathLike
        The data file.
    machine : Machine
        The machine.

    Returns
    -------
    q : ndarray, shape (K, n_joints)
        Readings, internal units.
    rows : ndarray of int, shape (K,)
        File line numbers.
    extra : dict
        Column name -> raw strings, for every column.
    columns : Columns or None
        The reading columns when they share one unit of a physical quantity (for the
        cross-checks of :mod:`~pkmcal.plausibility`), else None.

    Raises
    ------
    InputError
        When a reading column is missing, a value is not valid, or the readings look like
        another unit than their columns say.
    """
    header, table = read_table(path)
    extra = {name: [f[k] for _, f in table] for k, name in enumerate(header)}
    beyond = [name for name in header
              if re.match(r"^q(\d+)(_|$)", name) and int(re.match(r"^q(\d+)", name).group(1))
              > machine.n_joints]
    if beyond:
        raise InputError(f"{path_text(path)}: "
                         f"column {beyond[0]}: the machine has {machine.n_joints} "
                         f"joints (q1..q{machine.n_joints}); are these readings of another "
                         "machine?")
    if getattr(machine, "reading_unit", None) is not None:
        q, rows, columns = _read_readings(path, machine)
        return q, rows, extra, columns
    quantity = joint_quantity(machine)
    q, rows, _, names = _read_joints(path, machine.n_joints, quantity)
    _check_levels(path, q, names, quantity, machine)
    return q, rows, extra, _one_unit(names, [f"q{j + 1}" for j in range(len(names))], quantity)


def _groups(path, extra: dict, rows, column: str, setups) -> np.ndarray | None:
    """:func:`read_groups`, a missing column refused where the machine file's set-ups
    (``setups``) hold several groups of the instrument numbering its rows by ``column``
    (:meth:`~pkmcal.instruments.base.Instrument.check_group_column`)."""
    from ..instruments.registry import INSTRUMENTS

    group = read_groups(path, extra, rows, column)
    setups = setups or {}
    for inst in INSTRUMENTS.values():
        if inst.group_column == column:
            inst.check_group_column(setups.get(inst.name), group is not None, path)
    return group


def read_groups(path, extra: dict, rows, column: str, gaps: bool = False) -> np.ndarray | None:
    """0-based group of each row from an integer column numbered 1..K (``target``, ``setup``).

    Parameters
    ----------
    path : str or os.PathLike
        The data file (for messages).
    extra : dict
        Raw columns (:func:`machine_readings`).
    rows : array_like of int
        File line numbers (for messages).
    column : str
        The column's name.
    gaps : bool, optional
        Allow numbers below the largest without rows (rows that are predicted or commanded,
        not fitted: a file may use target 2 only).

    Returns
    -------
    ndarray of int, shape (K,) or None
        The groups, 0-based; None without the column.

    Raises
    ------
    InputError
        When a value is not a whole number >= 1, or (without ``gaps``) a number below the
        largest has no row.
    """
    values = extra.get(column)
    if values is None:
        return None
    out = np.empty(len(values), int)
    for k, (line, text) in enumerate(zip(rows, values, strict=True)):
        v = parse_number(path, int(line), column, text)
        if v != int(v) or not 1 <= v <= 10_000:
            raise InputError(f"{path_text(path)}: "
                             f"row {line}, column {column}: must be a whole number "
                             f"1, 2, ... (which {column} the row belongs to), got {text!r}")
        out[k] = int(v) - 1
    missing = [] if gaps or not len(out) else \
        sorted(set(range(int(out.max()) + 1)) - set(out.tolist()))
    if missing:
        raise InputError(f"{path_text(path)}: "
                         f"column {column}: {column} {missing[0] + 1} has no row; "
                         f"number the {column}s 1..K without gaps (largest: {out.max() + 1})")
    return out


def read_points(path, machine, setups=None):
    """Point measurements (laser tracker, CMM) of a target on ``machine``'s platform.

    Readings ``q1..q<n>`` (the machine's joint quantity), the point ``mx, my, mz`` (any length
    unit, the instrument's frame) and optionally ``target`` (1..K: several targets or nests,
    each with its own place on the platform). Other columns are ignored.

    Parameters
    ----------
    path : str or os.PathLike
        The data file.
    machine : Machine
        The machine.
    setups : Setups or mapping, optional
        The experiment's set-ups (the machine file's): a file without the target column is
        refused where the tracker's set-up holds several (None: no check).

    Returns
    -------
    InstrumentData
        ``kind="points"``: readings, points (m), targets (0-based) and file rows.

    Raises
    ------
    InputError
        When the file is not valid (file, row and column named) or the points or readings
        look like another unit than their columns say.
    """
    from ..instruments import InstrumentData

    q, rows, extra, q_units = machine_readings(path, machine)
    header, table = read_table(path)
    m_cols = [find_column(path, header, c, "length") for c in ("mx", "my", "mz")]
    m = np.column_stack([_column_values(path, header, table, i, f) for i, f in m_cols])
    m_units = _one_unit([header[i] for i, _ in m_cols], ["mx", "my", "mz"], "length")
    if q_units is not None and m_units is not None:
        check_tracker_scale(path, q, q_units, m, m_units, machine)
    return InstrumentData("points", q, m, _groups(path, extra, rows, "target", setups), rows,
                          source=str(path))


def _refuse_beyond(path, column: str, rows, values, limit: float, what: str,
                   limit_words: str) -> None:
    """InputError naming the first row whose value exceeds ``limit`` (m): not plausible as
    ``what`` on this machine (a wrong unit suffix, most often)."""
    bad = np.flatnonzero(values > limit)
    if bad.size:
        raise InputError(f"{path_text(path)}: row {rows[bad[0]]}, column {column}: "
                         f"{values[bad[0]] * 1e3:.6g} mm is not plausible as {what}: more "
                         f"than {limit_words} ({limit * 1e3:.6g} mm); check the unit suffix")


def read_distances(path, machine, setups=None):
    """Ballbar measurements: the distance ``d`` between a pivot on the base and a ball on the
    platform, with the machine's readings.

    Readings ``q1..q<n>``, the distance ``d`` (any length unit, e.g. ``d_mm``) and optionally
    ``setup`` (1..K: each mounting has its own pivot and ball). Other columns are ignored.

    Parameters
    ----------
    path : str or os.PathLike
        The data file.
    machine : Machine
        The machine.
    setups : Setups or mapping, optional
        The experiment's set-ups (the machine file's): a file without the setup column is
        refused where the ballbar's set-up holds several (None: no check).

    Returns
    -------
    InstrumentData
        ``kind="distances"``: readings, distances (m), setups (0-based) and file rows.

    Raises
    ------
    InputError
        When the file is not valid (file, row and column named) or a distance is not > 0.
    """
    from ..instruments import InstrumentData

    q, rows, extra, _ = machine_readings(path, machine)
    header, table = read_table(path)
    i, f = find_column(path, header, "d", "length")
    d = _column_values(path, header, table, i, f)
    bad = np.flatnonzero(~(d > 0))
    if bad.size:
        raise InputError(f"{path_text(path)}: row {rows[bad[0]]}, column {header[i]}: a measured "
                         f"distance must be > 0, got {table[bad[0]][1][i]!r}")
    _refuse_beyond(path, header[i], rows, d, 10 * machine.characteristic_length(),
                   "a ballbar length", "10 x the machine's size")
    return InstrumentData("distances", q, d[:, None],
                          _groups(path, extra, rows, "setup", setups), rows, source=str(path))


def read_probe(path, machine):
    """Bed-probe heights: the machine's readings where the probe triggered and the nozzle's
    height above the bed there.

    Readings ``q1..q<n>`` (the machine's joint quantity, e.g. ``q1_mm`` for a printer's
    carriages) and ``probe_z`` (any length unit, e.g. ``probe_z_mm``: the nozzle's height
    above the bed surface at the trigger, 0 for a probe that triggers on nozzle contact). Other
    columns are ignored.

    Parameters
    ----------
    path : str or os.PathLike
        The data file.
    machine : Machine
        The machine.

    Returns
    -------
    InstrumentData
        ``kind="probe"``: readings, heights (m) and file rows.

    Raises
    ------
    InputError
        When the file is not valid (file, row and column named), a height is not finite, or
        there are fewer than 3 rows (the bed plane's height and tilt).
    """
    from ..instruments import InstrumentData

    q, rows, _, _ = machine_readings(path, machine)
    header, table = read_table(path)
    i, f = find_column(path, header, "probe_z", "length")
    h = _column_values(path, header, table, i, f)
    _refuse_beyond(path, header[i], rows, np.abs(h), machine.characteristic_length(),
                   "a probe height above the bed", "the machine's size")
    if len(h) < 3:
        raise InputError(f"{path_text(path)}: "
                         f"{len(h)} probe height(s); the bed plane (height and tilt) "
                         "needs at least 3 points not on one line")
    return InstrumentData("probe", q, h[:, None], None, rows, source=str(path))


def read_tracker(path, machine, setups=None) -> TrackerData:
    """Laser-tracker data (SPEC 2.2) for ``machine``: :func:`read_points` as tracker data.

    Readings ``q1..q<n>`` (the machine's joint quantity, e.g. ``q1_deg`` for a Delta),
    tracker points ``mx, my, mz`` (any length unit) per row and optionally ``target`` (1..K).
    Other columns are ignored.

    Parameters
    ----------
    path : str or os.PathLike
        The data file.
    machine : Machine
        The machine (number and quantity of joints).
    setups : Setups or mapping, optional
        The experiment's set-ups (the machine file's): a file without the target column is
        refused where the tracker's set-up holds several (None: no check).

    Returns
    -------
    TrackerData
        Readings (internal units) and points (m), with the file rows and targets (0-based,
        None for one).

    Raises
    ------
    InputError
        When the file is not valid (file, row and column named), or the points or the
        readings look like another unit than their columns say
        (:func:`~pkmcal.plausibility.check_tracker_scale`).
    """
    points = read_points(path, machine, setups)
    from ..instruments.tracker import TrackerData

    return TrackerData(points.q, points.values, points.rows, source=str(path),
                       target=points.group if points.n_groups > 1 else None)


def _reading_suffixes(header: list[str], n: int) -> list[str | None]:
    """Unit suffix of each reading column ``q<j>_<unit>`` (None: no such single column)."""
    out = []
    for j in range(n):
        names = [h for h in header if h.startswith(f"q{j + 1}_")]
        out.append(names[0][len(f"q{j + 1}_"):] if len(names) == 1 else None)
    return out


def _span_of(base_unit: str, n: int) -> str:
    return f"q1_{base_unit}..q{n}_{base_unit}"


def adopt_reading_unit(machine, unit: str, path) -> None:
    """Make ``unit`` the reading unit of a Stewart ``machine`` whose file declares none.

    The file's ``gain`` is its length unit per reading unit (SPEC 6), so the internal gains
    are rescaled from the length unit the machine assumed until now to ``unit`` (metres per
    ``unit`` for a unit that is not a length). The machine then behaves as if its file said
    ``readings: {unit: <unit>}``, and a machine file saved from it says so.

    Parameters
    ----------
    machine : Stewart
        The machine, changed in place.
    unit : str
        The reading unit of the data (the column suffix).
    path : str or os.PathLike
        The data file that decided it (kept as ``machine.reading_unit_from``).

    Raises
    ------
    InputError
        When the machine has ``joint_limits`` (leg lengths, as its file declares no reading
        unit) and ``unit`` is not a length.
    """
    if getattr(machine, "joint_limits", None) is not None and (unit in LENGTH) != (
            machine.reading_unit in LENGTH):
        source = getattr(machine, "source", None) or "the machine file"
        raise InputError(f"{path_text(path)}: "
                         f"columns {_span_of(unit, machine.n_joints)} read in {unit}, but "
                         f"the joint_limits of {source} are leg lengths in "
                         f"{machine.reading_unit} (it declares no readings unit); add readings: "
                         f"{{unit: {unit}}} and give joint_limits in {unit}")
    old = LENGTH.get(machine.reading_unit, 1.0)
    new = LENGTH.get(unit, 1.0)
    if new != old:
        u = np.array(machine.u, float)
        idx = [machine.parameters.index(f"leg{j + 1}.gain") for j in range(machine.n_joints)]
        u[idx] *= old / new
        machine.parameters = machine.parameters.with_values(u)
    machine.reading_unit = unit
    machine.reading_unit_declared = True
    machine.reading_unit_from = str(path)


def _declared_text(machine) -> str:
    """Where a Stewart's reading unit comes from, for a message."""
    unit = machine.reading_unit
    source = getattr(machine, "source", None) or "the machine file"
    adopted = getattr(machine, "reading_unit_from", None)
    if adopted is not None:
        return (f"the legs of {source} read in {unit} (the unit of {adopted}, which set it: "
                f"{path_text(source)} declares no readings unit)")
    what = " (leg lengths)" if unit in LENGTH else ""
    return f"{path_text(source)} declares readings: {{unit: {unit}}}{what}"


def _reading_columns(path, header: list[str], machine) -> list[tuple[int, float]]:
    """Positions and factors of a Stewart's reading columns ``q1_<unit> ... q6_<unit>``.

    Without a declared reading unit (no ``readings:`` in the machine file) the columns' suffix
    decides it (SPEC 7): a length suffix reads lengths, any other word (``rev``) becomes the
    machine's reading unit (:func:`adopt_reading_unit`). With a declared unit, columns that
    all carry another unit are refused with what to rename or change.
    """
    n = machine.n_joints
    unit = getattr(machine, "reading_unit", "m")
    suffixes = _reading_suffixes(header, n)
    common = suffixes[0] if all(x == suffixes[0] for x in suffixes) else None
    if not getattr(machine, "reading_unit_declared", True):
        present = [x for x in suffixes if x is not None]
        words = {x for x in present if x not in LENGTH}
        if len(words) > 1 or (words and len(present) > len([x for x in present
                                                               if x in words])):
            shown = ", ".join(f"q{j + 1}_{x}" for j, x in enumerate(suffixes) if x is not None)
            raise InputError(f"{path_text(path)}: "
                             f"columns {shown}: the leg readings must share one unit "
                             f"(the machine file declares none, so the column suffix is the "
                             f"reading unit); rename the columns")
        if common is not None and common not in LENGTH:
            if not re.match(r"^[A-Za-z][A-Za-z0-9]*$", common):
                raise InputError(f"{path_text(path)}: "
                                 f"columns {_span_of(common, n)}: {common!r} is not a "
                                 "reading unit (one word of letters and digits, e.g. q1_rev)")
            adopt_reading_unit(machine, common, path)
            unit = common
    if common is not None and (common in LENGTH) != (unit in LENGTH) or (
            common is not None and common not in LENGTH and common != unit):
        lengths = " (or another length unit: mm, m, um)" if unit in LENGTH else ""
        raise InputError(f"{path_text(path)}: columns {_span_of(common, n)} are in {common} but "
                         f"{_declared_text(machine)}; rename the columns to "
                         f"{_span_of(unit, n)}{lengths} or change readings.unit")
    if unit in LENGTH:
        return [find_column(path, header, f"q{j + 1}", "length") for j in range(n)]
    source = getattr(machine, "source", "the machine file")
    out = []
    for j in range(n):
        name = f"q{j + 1}_{unit}"
        if name in header:
            out.append((header.index(name), 1.0))
            continue
        others = [h for h in header if h == f"q{j + 1}" or h.startswith(f"q{j + 1}_")]
        found = f" (found {', '.join(others)})" if others else ""
        raise InputError(f"{path_text(path)}: "
                         f"missing column {name}{found}: the legs of {source} read in "
                         f"{unit} (machine file key readings: {{unit: {unit}}}); columns found: "
                         f"{', '.join(header)}")
    return out


def read_readings(path, machine):
    """Stewart leg readings in internal units.

    Metres for length readings (any length suffix), else as read in the machine's reading
    unit (``q1_rev``).

    Parameters
    ----------
    path : str or os.PathLike
        The data file.
    machine : Stewart
        The machine (its ``reading_unit``).

    Returns
    -------
    q : ndarray, shape (K, 6)
        Readings.
    rows : ndarray of int, shape (K,)
        File line numbers.

    Raises
    ------
    InputError
        When a reading column is missing or a value is not valid.
    """
    q, rows, _ = _read_readings(path, machine)
    return q, rows


def _read_readings(path, machine):
    """:func:`read_readings` and the reading columns when they are lengths (else None); the
    reading levels checked."""
    header, rows = read_table(path)
    cols = _reading_columns(path, header, machine)
    q = np.column_stack([_column_values(path, header, rows, i, f) for i, f in cols])
    columns = None
    if getattr(machine, "reading_unit", "m") in LENGTH:
        names = [header[i] for i, _ in cols]
        _check_levels(path, q, names, "length", machine)
        columns = _one_unit(names, [f"q{j + 1}" for j in range(len(names))], "length")
    return q, np.array([line for line, _ in rows]), columns


def read_full_pose(path, machine) -> FullPoseData:
    """Full-pose data (SPEC 2.4) for a Stewart ``machine``.

    Readings ``q1..q6`` (its reading unit) and the measured pose ``x, y, z`` + ``psi, theta,
    phi`` or ``qx, qy, qz, qw`` per row (the marker frame in the measurement frame). Other
    columns are ignored.

    Parameters
    ----------
    path : str or os.PathLike
        The data file.
    machine : Stewart
        The machine (its ``reading_unit``).

    Returns
    -------
    FullPoseData
        Readings, measured poses (m) and file rows.

    Raises
    ------
    InputError
        When the file is not valid, a quaternion is not normalised, or positions, Euler
        angles or length readings look like another unit than their columns say
        (:func:`~pkmcal.plausibility.check_full_pose_scale`).
    """
    q, rows, q_units = _read_readings(path, machine)
    P, R, _, p_units, euler, e_units = _read_poses(path)
    if p_units is not None:
        check_full_pose_scale(path, q, q_units, P, p_units, R, euler, e_units, machine)
    from ..instruments.pose import FullPoseData

    return FullPoseData(q, P, R, rows, source=str(path))


ORIENTATION_COLUMNS = ("psi", "theta", "phi", "qx", "qy", "qz", "qw")


def has_orientation(header: list[str]) -> bool:
    """True when a header has orientation columns (Euler angles or a quaternion)."""
    return any(n == c or n.startswith(c + "_") for n in header for c in ORIENTATION_COLUMNS)


def read_positions(path, orientation_tol: float = 1e-9):
    """Positions from ``x, y, z`` columns, for a platform that does not rotate.

    Orientation columns, when present, must describe no rotation.

    Parameters
    ----------
    path : str or os.PathLike
        The data file.
    orientation_tol : float, optional
        Largest accepted rotation angle of the orientation columns, rad.

    Returns
    -------
    P : ndarray, shape (K, 3)
        Positions, m.
    rows : ndarray of int, shape (K,)
        File line numbers.

    Raises
    ------
    InputError
        When a column is missing or invalid, or a row's orientation is a rotation (row named).
    """
    header, rows = read_table(path)
    lines = np.array([line for line, _ in rows])
    if has_orientation(header):
        P, R, lines = read_poses(path)
        angle = np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1, 1))
        bad = np.flatnonzero(angle > orientation_tol)
        if bad.size:
            raise InputError(f"{path_text(path)}: "
                             f"row {lines[bad[0]]}: the orientation columns describe a "
                             f"rotation of {np.degrees(angle[bad[0]]):.6g} deg, but this "
                             "platform does not rotate (translation only): give x, y, z only "
                             "or zero angles")
        return P, lines
    P = np.column_stack([_column_values(path, header, rows, *find_column(path, header, c,
                                                                         "length"))
                         for c in ("x", "y", "z")])
    return P, lines


def read_poses(path):
    """Poses from position and orientation columns.

    Orientation: ``psi/theta/phi_<angle unit>`` or ``qx, qy, qz, qw`` (normalised).

    Parameters
    ----------
    path : str or os.PathLike
        The data file.

    Returns
    -------
    P : ndarray, shape (K, 3)
        Positions, m.
    R : ndarray, shape (K, 3, 3)
        Orientations.
    rows : ndarray of int, shape (K,)
        File line numbers.

    Raises
    ------
    InputError
        When columns are missing, both orientation forms are given, a quaternion is zero or
        not normalised (``| |q| - 1 | > 1e-3``), or a value is not valid.
    """
    P, R, lines, _, _, _ = _read_poses(path)
    return P, R, lines


#: largest accepted | |q| - 1 | of a quaternion (exports are normalised to about 1e-6)
QUATERNION_NORM_TOL = 1e-3


def _read_poses(path):
    """:func:`read_poses` and, for the unit checks, the position columns (None when their
    units differ), the Euler angles as read (rad; None for quaternions) and their columns."""
    header, rows = read_table(path)
    lines = np.array([line for line, _ in rows])
    p_cols = [find_column(path, header, c, "length") for c in ("x", "y", "z")]
    P = np.column_stack([_column_values(path, header, rows, *c) for c in p_cols])
    p_units = _one_unit([header[i] for i, _ in p_cols], ["x", "y", "z"], "length")
    angles, e_units = None, None
    euler = [find_column(path, header, c, "angle", required=False)
             for c in ("psi", "theta", "phi")]
    quat = [find_column(path, header, c, None, required=False) for c in ("qx", "qy", "qz", "qw")]
    has_euler, has_quat = any(e is not None for e in euler), any(c is not None for c in quat)
    if has_euler and has_quat:
        raise InputError(f"{path_text(path)}: "
                         "both Euler-angle (psi, theta, phi) and quaternion (qx, qy, "
                         "qz, qw) columns: keep one orientation")
    if has_quat:
        missing = [n for n, c in zip(("qx", "qy", "qz", "qw"), quat, strict=True) if c is None]
        if missing:
            raise InputError(f"{path_text(path)}: "
                             f"missing column(s) {', '.join(missing)} of the quaternion "
                             "qx, qy, qz, qw")
        Q = np.column_stack([_column_values(path, header, rows, *c) for c in quat])
        with np.errstate(over="ignore"):            # 1e300: an infinite norm, refused below
            norm = np.linalg.norm(Q, axis=1)
        bad = np.flatnonzero(norm < 1e-9)
        if bad.size:
            raise InputError(f"{path_text(path)}: row {lines[bad[0]]}, columns qx, qy, qz, qw: the "
                             "quaternion is zero")
        bad = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_NORM_TOL)
        if bad.size:
            k = bad[0]
            more = f" (and {bad.size - 1} more row(s))" if bad.size > 1 else ""
            raise InputError(f"{path_text(path)}: "
                             f"row {lines[k]}, columns qx, qy, qz, qw: the quaternion "
                             f"has norm {norm[k]:.6g}, not 1{more}: a rotation is a unit "
                             f"quaternion (accepted within {QUATERNION_NORM_TOL:g}); check "
                             "the columns and their order (qx, qy, qz, then the scalar qw)")
        R = matrix_from_quaternion(Q)
    elif has_euler:
        for name, c in zip(("psi", "theta", "phi"), euler, strict=True):
            if c is None:
                find_column(path, header, name, "angle")  # raises: missing column
        angles = np.column_stack([_column_values(path, header, rows, *c) for c in euler])
        R = matrix_from_euler(angles)
        e_units = _one_unit([header[i] for i, _ in euler], ["psi", "theta", "phi"], "angle")
    else:
        raise InputError(f"{path_text(path)}: "
                         "missing orientation columns: psi_deg, theta_deg, phi_deg "
                         f"(or _rad) or qx, qy, qz, qw; columns found: {', '.join(header)}")
    return P, R, lines, p_units, angles, e_units


def read_declared(instrument, path, machine):
    """An instrument's measurements from a CSV file, by the columns it declares.

    Columns ``q1<s>_<unit>..q<n><s>_<unit>`` for each suffix ``s`` of the instrument's
    ``reading_sets`` (``("", "b")``: two sets of readings per row) and one column per entry
    ``(name, quantity)`` of its ``value_columns``, converted to SI; values the instrument
    requires to be positive (``positive_values``) are checked; its ``from_columns(readings,
    values, rows, source)`` makes the data.

    Parameters
    ----------
    instrument : Instrument
        The registry entry.
    path : str or os.PathLike
        The data file.
    machine : Machine
        The machine (its joints' quantity).

    Returns
    -------
    object
        The instrument's data.

    Raises
    ------
    InputError
        For a missing column or a value not above 0, naming the file, row and column.
    """
    header, table = read_table(path)
    quantity = joint_quantity(machine)
    readings = []
    for suffix in instrument.reading_sets:
        q = []
        for j in range(machine.n_joints):
            i, f = find_column(path, header, f"q{j + 1}{suffix}", quantity)
            q.append(_column_values(path, header, table, i, f))
        readings.append(np.column_stack(q))
    rows = np.array([line for line, _ in table], int)
    values = []
    for name, kind in instrument.value_columns:
        i, f = find_column(path, header, name, kind)
        v = _column_values(path, header, table, i, f)
        bad = np.flatnonzero(~(v > 0)) if instrument.positive_values else []
        if len(bad):
            raise InputError(f"{path_text(path)}: "
                             f"row {rows[bad[0]]}, column {header[i]}: a {name} must "
                             "be > 0")
        values.append(v)
    return instrument.from_columns(readings, np.column_stack(values), rows, str(path))
