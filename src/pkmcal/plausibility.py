"""Unit plausibility of measurement data: values read in the wrong unit (SPEC 6).

A column suffix says the unit, but a file exported in metres under ``_mm`` columns, or arm
angles in radians under ``_deg``, reads without complaint and fails much later (a calibration
that does not converge, degenerate poses) with advice about the poses. The readers that know
the machine compare the data's scale with what the nominal machine produces and, when the data
are off by a unit factor (1000, 180/pi, ...) and agree with the machine once converted, raise
an :class:`~pkmcal.errors.InputError` that names the columns and the unit they look like.

The checks only fire on gross disagreement (a factor 20 or more, see :data:`GROSS`) that a unit
change explains; data that are merely unusual (a small workspace, a geometry of another size,
a measurement frame metres away) pass. Frame-free quantities are compared: distances between
measured points and angles between measured orientations are the same in any measurement
frame, so they are compared with those of the nominal forward kinematics of the readings.

- :func:`check_reading_levels`: joint readings (lengths) against the inverse kinematics of the
  machine's home pose (Hexa Slide sliders, Stewart legs that read lengths).
- :func:`check_tracker_scale`: laser-tracker points against the positions the readings give
  (Delta): points in the wrong length unit, or arm angles in the wrong angle unit.
- :func:`check_full_pose_scale`: measured poses against the poses the readings give (Stewart):
  positions, Euler angles or length readings in the wrong unit.
- :func:`check_option_scale`: a command-line length (a noise, an error, a trajectory's size)
  against the machine's own size: ``--noise 1e3`` (a kilometre, a bare number is SI) on a
  half-metre machine is refused instead of simulating nonsense.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .kinematics import matrix_from_euler
from .paths import path_text
from .units import COLUMN_SUFFIXES, QUANTITIES

#: the data are "grossly" off when a scale ratio is beyond this factor (either way)
GROSS = 20.0
#: relative disagreement (:func:`disagreement`) of data that are grossly off
INCONSISTENT = 0.5
#: relative disagreement below which converted data count as explained by the machine
EXPLAINED = 0.25
#: rows used for the pairwise comparisons (evenly spaced through the file)
MAX_ROWS = 200
#: smallest median angle between orientations (rad) that is compared (below: no rotation)
MIN_ROTATION = 0.01

#: largest command-line value relative to the machine's characteristic length, per kind:
#: a noise or clearance (a standard deviation, a play), an error of a dimension (link length,
#: tolerance of the geometry), a size (a trajectory's radius or height)
OPTION_SCALE = {"noise": 0.01, "error": 0.1, "size": 10.0}
#: smallest nonzero noise relative to the machine's size (a few ulps of its coordinates)
MIN_NOISE_RATIO = 1e-12
#: largest angular noise (rad): orientation noise of a pose measurement
MAX_ANGLE_NOISE = 0.1


@dataclass
class Columns:
    """Columns of one quantity read from a data file, for messages and unit alternatives.

    Attributes
    ----------
    names : list of str
        The column names as in the file (``q1_mm`` ...).
    bases : list of str
        The names without the unit suffix (``q1`` ...).
    unit : str
        The unit suffix of the columns (the first column's when they differ).
    quantity : str
        ``"length"`` or ``"angle"``.
    """

    names: list[str]
    bases: list[str]
    unit: str
    quantity: str

    @property
    def factor(self) -> float:
        """SI value of one unit of the columns."""
        return QUANTITIES[self.quantity][self.unit]

    def alternatives(self) -> list[tuple[str, float]]:
        """Other column units of the quantity that differ by at least :data:`GROSS`.

        Returns
        -------
        list of tuple
            ``(unit, f)``: values written in ``unit`` under these columns are ``f`` times the
            SI values read.
        """
        out = []
        for unit, quantity in COLUMN_SUFFIXES.items():
            if quantity != self.quantity or unit == self.unit:
                continue
            f = QUANTITIES[quantity][unit] / self.factor
            if max(f, 1.0 / f) >= GROSS:
                out.append((unit, f))
        return out

    def span(self) -> str:
        """``q1_mm..q6_mm`` or ``x_mm, y_mm, z_mm``: the columns for a message."""
        return _span(self.names)

    def renamed(self, unit: str) -> str:
        """The columns with another unit suffix, for a message."""
        return _span([f"{b}_{unit}" for b in self.bases])


def _span(names: list[str]) -> str:
    if len(names) > 3:
        return f"{names[0]}..{names[-1]}"
    return ", ".join(names)


def _fmt(x: float) -> str:
    return f"{x:.3g}"


def _look_like(columns: Columns, unit: str) -> str:
    word = "column" if len(columns.names) == 1 else "columns"
    return (f"the values look like {unit}, not {columns.unit} (rename the {word} "
            f"{columns.renamed(unit)}, or convert the values)")


def _source(machine) -> str:
    source = getattr(machine, "source", None) or getattr(machine, "name", "")
    return f"the nominal machine ({source})" if source else "the nominal machine"


def _raise(path, columns: Columns, unit: str, why: str) -> None:
    word = "column" if len(columns.names) == 1 else "columns"
    raise InputError(f"{path_text(path)}: "
                     f"{word} {columns.span()}: {why}: {_look_like(columns, unit)}")


# -- statistics ---------------------------------------------------------------------------------

def sample_rows(k: int, n: int = MAX_ROWS) -> np.ndarray:
    """At most ``n`` row indices evenly spaced over ``k`` rows (all rows when ``k <= n``).

    Parameters
    ----------
    k : int
        Number of rows.
    n : int, optional
        Largest number of indices.

    Returns
    -------
    ndarray of int
        Sorted distinct indices.
    """
    if k <= n:
        return np.arange(k)
    return np.unique(np.linspace(0, k - 1, n).round().astype(int))


def pair_distances(X) -> np.ndarray:
    """Distances between all pairs of rows of ``X`` (k, 3), the upper triangle.

    Parameters
    ----------
    X : array_like, shape (k, 3)
        Points.

    Returns
    -------
    ndarray, shape (k (k - 1) / 2,)
        Distances, same unit as ``X``.
    """
    X = np.asarray(X, float)
    i, j = np.triu_indices(len(X), 1)
    with np.errstate(over="ignore", invalid="ignore"):     # a huge outlier: inf, not a warning
        return np.sqrt(np.sum((X[i] - X[j]) ** 2, axis=-1))


def pair_angles(R) -> np.ndarray:
    """Rotation angles between all pairs of orientations ``R`` (k, 3, 3), the upper triangle.

    The angle of ``R_i^T R_j`` is the same in any measurement and marker frame.

    Parameters
    ----------
    R : array_like, shape (k, 3, 3)
        Orientations.

    Returns
    -------
    ndarray, shape (k (k - 1) / 2,)
        Angles, rad.
    """
    F = np.asarray(R, float).reshape(len(R), 9)
    i, j = np.triu_indices(len(F), 1)
    trace = np.sum(F[i] * F[j], axis=-1)
    return np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0))


def disagreement(a, b, floor: float = 0.0) -> float:
    """Relative disagreement of two sets of paired values (distances or angles).

    ``median |a - b| / max(median a, median b)``: about 0 when they agree, 1 - 1/f when one is
    ``f`` times the other, and about 0.5 or more when they are unrelated.

    Parameters
    ----------
    a, b : array_like, shape (n,)
        Paired non-negative values.
    floor : float, optional
        When both medians are at most this, the sets cannot be compared.

    Returns
    -------
    float
        The disagreement; NaN when there is nothing to compare.
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.size == 0:
        return float("nan")
    scale = max(float(np.median(a)), float(np.median(b)))
    if not np.isfinite(scale) or scale <= floor:
        return float("nan")
    return float(np.median(np.abs(a - b)) / scale)


def _gross(e: float) -> bool:
    return bool(np.isfinite(e) and e >= INCONSISTENT) or e == np.inf


def _explains(e: float, before: float) -> bool:
    return bool(np.isfinite(e) and e <= EXPLAINED and (not np.isfinite(before)
                                                       or e <= before / 3))


def _fk(machine, q):
    """Forward kinematics of the nominal machine, silently: ``(P, R, converged)``."""
    with np.errstate(all="ignore"):
        try:
            fk = machine.fk(q)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            k = len(q)
            return np.zeros((k, 3)), np.broadcast_to(np.eye(3), (k, 3, 3)), np.zeros(k, bool)
    ok = np.asarray(fk.converged, bool) & np.all(np.isfinite(fk.P), axis=-1)
    return fk.P, fk.R, ok


def _enough(ok: np.ndarray) -> bool:
    return int(ok.sum()) >= 4 and ok.mean() >= 0.5


# -- joint readings -----------------------------------------------------------------------------

def check_reading_levels(path, q, columns: Columns, machine, joints=None) -> None:
    """Length readings against the inverse kinematics of the machine's home pose.

    A column is checked when its reading at home is at least a tenth of the machine's
    characteristic length (readings that are about zero at home say nothing about the unit). It
    is refused when the median of its absolute values is :data:`GROSS` or more times off the
    home reading, a unit change brings it within a factor 3 of it, and the forward kinematics
    of the nominal machine then solves most rows.

    Parameters
    ----------
    path : str or os.PathLike
        The data file (for messages).
    q : ndarray, shape (K, n_joints)
        All readings as read, SI.
    columns : Columns
        The reading columns checked (one unit).
    machine : Machine
        The nominal machine.
    joints : array_like of int, optional
        The joints (0-based columns of ``q``) of ``columns``; default: all, in order.

    Raises
    ------
    InputError
        When the readings look like another unit (the columns, the values and the home
        readings named).
    """
    if columns.quantity != "length" or len(q) == 0:
        return
    joints = np.arange(q.shape[1]) if joints is None else np.asarray(joints, int)
    with np.errstate(all="ignore"):
        try:
            home = np.asarray(machine.ik(*machine.home), float).reshape(-1)
            size = float(machine.characteristic_length())
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            return
    if home.shape != (q.shape[1],) or not np.isfinite(size):
        return
    level = np.median(np.abs(q), axis=0)
    flagged: dict[str, tuple[float, list[int]]] = {}
    for k, j in enumerate(joints):
        ref = abs(home[j])
        if not (np.isfinite(ref) and ref >= 0.1 * size) or not level[j] > 0:
            continue
        r = level[j] / ref
        if 1.0 / GROSS < r < GROSS:
            continue
        for unit, f in columns.alternatives():
            if 1.0 / 3.0 <= r * f <= 3.0:
                flagged.setdefault(unit, (f, []))[1].append(k)
                break
    if not flagged:
        return
    unit, (f, cols) = max(flagged.items(), key=lambda kv: len(kv[1][1]))
    converted = q[sample_rows(len(q))].copy()
    converted[:, joints[cols]] *= f
    if not _enough(_fk(machine, converted)[2]):
        return                                   # converted, the readings fit no better
    sub = Columns([columns.names[k] for k in cols], [columns.bases[k] for k in cols],
                  columns.unit, columns.quantity)
    raw = q[:, joints[cols]] / columns.factor
    at_home = np.abs(home[joints[cols]]) / columns.factor
    home_text = (_fmt(at_home.min()) if np.ptp(at_home) <= 1e-3 * at_home.max()
                 else f"{_fmt(at_home.min())}..{_fmt(at_home.max())}")
    what = getattr(machine, "joints_read_words", "joints read")
    _raise(path, sub, unit, f"values {_fmt(np.min(raw))}..{_fmt(np.max(raw))}, but the "
           f"{what} about {home_text} {columns.unit} at the home pose of {_source(machine)}")


# -- laser tracker ------------------------------------------------------------------------------

def check_tracker_scale(path, q, q_columns: Columns, m, m_columns: Columns, machine) -> None:
    """Tracker points against the positions the readings give on the nominal machine.

    Distances between tracker points do not depend on where the tracker stands; they are
    compared with the distances between the forward-kinematics positions of the same rows. When
    they disagree grossly (:data:`INCONSISTENT`) and the points in another length unit, or the
    readings in another unit, make them agree (:data:`EXPLAINED`), the data are refused.

    Parameters
    ----------
    path : str or os.PathLike
        The data file (for messages).
    q : ndarray, shape (K, n)
        Readings as read, SI.
    q_columns : Columns
        The reading columns.
    m : ndarray, shape (K, 3)
        Tracker points as read, m.
    m_columns : Columns
        The point columns.
    machine : Machine
        The nominal machine (a translation-only platform; others are not checked).

    Raises
    ------
    InputError
        When the points or the readings look like another unit.
    """
    if machine.rotates or len(q) < 4:
        return
    idx = sample_rows(len(q))
    q, m = q[idx], m[idx]
    P, _, ok = _fk(machine, q)
    i, j = np.triu_indices(len(q), 1)
    d_m_all = pair_distances(m)
    size = float(machine.characteristic_length())
    floor = 1e-9 * size

    def compare(ok, P, fm=1.0):
        if not _enough(ok):
            return np.inf
        keep = ok[i] & ok[j]
        return disagreement(fm * d_m_all[keep], _pairs_of(P, keep), floor)

    e1 = compare(ok, P)
    if not _gross(e1):
        return
    best = None
    if _enough(ok):
        for unit, f in m_columns.alternatives():
            e = compare(ok, P, f)
            if _explains(e, e1) and (best is None or e < best[0]):
                best = (e, "m", unit)
    for unit, f in q_columns.alternatives():
        P2, _, ok2 = _fk(machine, q * f)
        e = compare(ok2, P2)
        if _explains(e, e1) and (best is None or e < best[0]):
            best = (e, "q", unit, P2, ok2)
    if best is None:
        return
    d_fk = _median_pairs(P, ok)
    d_m = float(np.median(d_m_all))
    if best[1] == "m":
        _raise(path, m_columns, best[2],
               f"the tracker points are {_fmt(d_m / m_columns.factor)} {m_columns.unit} apart "
               f"(median distance between rows), but the positions the readings give on "
               f"{_source(machine)} are {_fmt(d_fk / m_columns.factor)} {m_columns.unit} apart")
    raw = q / q_columns.factor
    d_fk2 = _median_pairs(best[3], best[4])
    _raise(path, q_columns, best[2], _readings_why(
        raw, q_columns.unit, best[2], "tracker points", d_m, d_fk if _enough(ok) else None,
        d_fk2, m_columns, machine))


def _pairs_of(P, keep) -> np.ndarray:
    """Distances of the pairs ``keep`` (a mask over the upper triangle) of rows of ``P``."""
    i, j = np.triu_indices(len(P), 1)
    i, j = i[keep], j[keep]
    with np.errstate(over="ignore", invalid="ignore"):
        return np.sqrt(np.sum((P[i] - P[j]) ** 2, axis=-1))


def _median_pairs(P, ok) -> float:
    d = pair_distances(P[ok])
    return float(np.median(d)) if d.size else float("nan")


def _median_angles(R, ok) -> float:
    a = pair_angles(R[ok])
    return float(np.median(a)) if a.size else float("nan")


# -- full pose ----------------------------------------------------------------------------------

def check_full_pose_scale(path, q, q_columns: Columns | None, P, p_columns: Columns, R,
                          euler=None, e_columns: Columns | None = None, machine=None) -> None:
    """Measured poses against the poses the readings give on the nominal machine.

    Distances between measured positions and angles between measured orientations do not
    depend on the measurement or marker frame; they are compared with those of the forward
    kinematics of the same rows. A gross disagreement (:data:`INCONSISTENT`) that positions in
    another length unit, Euler angles in another angle unit or (length) readings in another
    unit remove (:data:`EXPLAINED`) is refused.

    Parameters
    ----------
    path : str or os.PathLike
        The data file (for messages).
    q : ndarray, shape (K, 6)
        Readings as read (internal units).
    q_columns : Columns or None
        The reading columns when they are lengths (the only readings with a unit to mistake).
    P : ndarray, shape (K, 3)
        Measured positions as read, m.
    p_columns : Columns
        The position columns.
    R : ndarray, shape (K, 3, 3)
        Measured orientations as read.
    euler : ndarray, shape (K, 3), optional
        The Euler angles as read (rad) when the orientation was given by Euler angles.
    e_columns : Columns, optional
        The Euler-angle columns.
    machine : Machine
        The nominal machine.

    Raises
    ------
    InputError
        When positions, angles or readings look like another unit.
    """
    if machine is None or len(q) < 4:
        return
    idx = sample_rows(len(q))
    q, P, R = q[idx], P[idx], R[idx]
    euler = None if euler is None else euler[idx]
    Pf, Rf, ok = _fk(machine, q)
    size = float(machine.characteristic_length())
    i, j = np.triu_indices(len(q), 1)
    d_m_all, a_m_all = pair_distances(P), pair_angles(R)

    def e_pos(ok, Pf, fp=1.0):
        if not _enough(ok):
            return np.inf
        keep = ok[i] & ok[j]
        return disagreement(fp * d_m_all[keep], _pairs_of(Pf, keep), 1e-9 * size)

    def e_rot(ok, Rf, a_m=a_m_all):
        if not _enough(ok):
            return np.inf
        keep = ok[i] & ok[j]
        ii, jj = i[keep], j[keep]
        F = Rf.reshape(len(Rf), 9)
        a_fk = np.arccos(np.clip((np.sum(F[ii] * F[jj], axis=-1) - 1.0) / 2.0, -1.0, 1.0))
        return disagreement(a_m[keep], a_fk, MIN_ROTATION)

    ep, er = e_pos(ok, Pf), e_rot(ok, Rf)
    d_m = float(np.median(d_m_all))
    # Readings in the wrong unit move the poses the readings give in position and orientation;
    # positions or angles in the wrong unit only one of them. Readings first when both disagree
    # (or there are no poses): positions alone could be "explained" by readings that are zero
    # at home, and the other way round.
    if q_columns is not None and ((_gross(ep) and _gross(er)) or not _enough(ok)):
        _check_readings(path, q, q_columns, ep, e_pos, d_m, Pf, ok, p_columns, machine)
    if _gross(ep) and _enough(ok):
        best = None
        for unit, f in p_columns.alternatives():
            e = e_pos(ok, Pf, f)
            if _explains(e, ep) and (best is None or e < best[0]):
                best = (e, unit)
        if best is not None:
            f = p_columns.factor
            _raise(path, p_columns, best[1],
                   f"the measured positions are {_fmt(d_m / f)} {p_columns.unit} apart "
                   f"(median distance between rows), but the poses the readings give on "
                   f"{_source(machine)} are {_fmt(_median_pairs(Pf, ok) / f)} "
                   f"{p_columns.unit} apart")
    if _gross(er) and _enough(ok) and euler is not None and e_columns is not None:
        best = None
        for unit, f in e_columns.alternatives():
            e = e_rot(ok, Rf, pair_angles(matrix_from_euler(euler * f)))
            if _explains(e, er) and (best is None or e < best[0]):
                best = (e, unit)
        if best is not None:
            _raise(path, e_columns, best[1],
                   f"the measured orientations differ by {_fmt(np.degrees(np.median(a_m_all)))}"
                   f" deg (median angle between rows), but the poses the readings give on "
                   f"{_source(machine)} differ by {_fmt(np.degrees(_median_angles(Rf, ok)))} "
                   "deg")
    if q_columns is not None and _gross(ep):
        _check_readings(path, q, q_columns, ep, e_pos, d_m, Pf, ok, p_columns, machine)


def _check_readings(path, q, q_columns: Columns, ep, e_pos, d_m, Pf, ok, p_columns: Columns,
                    machine) -> None:
    """Refuse full-pose readings that another unit makes agree with the measured positions."""
    best = None
    for unit, f in q_columns.alternatives():
        P2, _, ok2 = _fk(machine, q * f)
        e = e_pos(ok2, P2)
        if _explains(e, ep) and (best is None or e < best[0]):
            best = (e, unit, P2, ok2)
    if best is None:
        return
    _raise(path, q_columns, best[1], _readings_why(
        q / q_columns.factor, q_columns.unit, best[1], "measured positions", d_m,
        _median_pairs(Pf, ok) if _enough(ok) else None, _median_pairs(best[2], best[3]),
        p_columns, machine))


def _readings_why(raw, unit, other, measured, d_m, d_fk, d_fk2, lengths: Columns,
                  machine) -> str:
    """Why readings look like ``other``: the spread of the measured points against that of
    the platform positions the readings give, as read and converted (None: no pose)."""
    f, u = lengths.factor, lengths.unit
    as_read = (f"put the platform points {_fmt(d_fk / f)} {u} apart" if d_fk is not None
               else "give no pose for most rows")
    return (f"values {_fmt(np.min(raw))}..{_fmt(np.max(raw))}; the {measured} are "
            f"{_fmt(d_m / f)} {u} apart (median distance between rows), but read as {unit} the "
            f"readings {as_read} on {_source(machine)} (read as {other}: "
            f"{_fmt(d_fk2 / f)} {u})")


def check_option_scale(value: float, machine, option: str, kind: str,
                       text: str | None = None) -> float:
    """Refuse a command-line length that is absurd for this machine.

    Parameters
    ----------
    value : float
        The option's value, m (SI).
    machine : Machine
        The machine it applies to (its :meth:`~pkmcal.machines.base.Machine.characteristic_length`).
    option : str
        The option's name, for the message (``--noise``).
    kind : str
        A key of :data:`OPTION_SCALE` (``"noise"``, ``"error"``, ``"size"``), or ``"angle
        noise"`` for an orientation noise in rad (limit :data:`MAX_ANGLE_NOISE`).
    text : str, optional
        The option as the user typed it, for the message.

    Returns
    -------
    float
        ``value``, when plausible.

    Raises
    ------
    InputError
        Naming the option, the value and the machine's size.
    """
    shown = text if text is not None else f"{value:g}"
    if kind == "angle noise":
        if 0 < abs(value) < MIN_NOISE_RATIO:
            raise InputError(f"{option}: {shown} is below {MIN_NOISE_RATIO:g} rad: no "
                             "measurement is that exact (simulate takes 0 for exact data)")
        if abs(value) > MAX_ANGLE_NOISE:
            raise InputError(f"{option}: {shown} is not a plausible orientation noise (at most "
                             f"{MAX_ANGLE_NOISE:g} rad = {np.degrees(MAX_ANGLE_NOISE):.3g} deg; "
                             "a bare number is SI, rad)")
        return value
    size = float(machine.characteristic_length())
    ratio = OPTION_SCALE[kind]
    if kind == "noise" and 0 < abs(value) < MIN_NOISE_RATIO * size:
        raise InputError(f"{option}: {shown} is below {MIN_NOISE_RATIO:g} of the machine's size "
                         f"({_fmt(size * 1e3)} mm): no measurement is that exact and the "
                         "weights would overflow (simulate takes 0 for exact data)")
    if abs(value) > ratio * size:
        what = {"noise": "a noise", "error": "an error", "size": "a size"}[kind]
        raise InputError(f"{option}: {shown} = {_fmt(abs(value) * 1e3)} mm is not plausible as "
                         f"{what} on {_source(machine)}: more than {ratio:g} x the machine's size "
                         f"({_fmt(size * 1e3)} mm); a bare number is in metres")
    return value
