"""Self-calibration with a constraint link (seed 000, SPEC 2.1): three methods.

``ml`` (default)
    Maximum likelihood, implicit loop: unknowns = geometry + one pose per measurement on the
    sphere ``|P| = Lc`` (2 tangent + 3 rotation coordinates); residuals = all six readings
    divided by their noise. Solved by :func:`~pkmcal.estimation.estimator.levenberg_marquardt`
    with the per-pose unknowns eliminated (Schur complement). Treats every encoder as noisy.
``ik``
    The paper's inverse-kinematics method (3.4.1): the five active readings and the link fix
    the pose, the residual is the passive reading minus its inverse kinematics. Needs the
    ``passive`` column and the exact ``Lc``. By default all chains are solved jointly, with the
    active readings as (heavily weighted) equations of the implicit loop
    (:class:`ConstraintLinkIK`); ``per_chain=True`` runs the paper's algorithm literally
    (:class:`ConstraintLinkIKExplicit`: forward kinematics of the five active readings, chain
    by chain, only that chain's 9 parameters, in sweeps).
``fk``
    The paper's forward-kinematics method (3.4.2): the pose follows from all six readings, the
    residual is ``|P| - Lc`` with ``Lc`` estimated.

Starting a calibration far from the machine: continuation, pose multi-starts, rows left out.

The maximum-likelihood problems start every per-measurement pose from the forward kinematics
of its readings with the machine file's geometry. With build errors of the size of seed 000's
Table 1 (2-4 mm, up to 4 deg) on a geometry other than the default one, that start can be tens
of millimetres off for some rows, and Levenberg-Marquardt then stops in a local minimum: a
wrong geometry whose residuals are many times the noise. Two things go wrong:

- *Wrong pose branches.* The least-squares forward kinematics of a row (all readings and the
  link) has more than one local minimum near the edge of the workspace; Newton from the home
  pose may land in one that is not the pose the readings came from, even with the true
  geometry. :func:`sphere_pose_candidates` therefore starts each row from several poses (the
  home pose, and the square five-readings-plus-link solutions for every choice of the left-out
  reading) and keeps the pose that explains its readings best. With the calibrated geometry,
  the rows still left out also start from the poses of the fitted rows with the nearest
  readings (:func:`neighbour_poses`: near the edge of the workspace the pose the readings came
  from can have a narrow basin that no start from home reaches); the outlier rounds then
  bring back those it explains.
- *Ill-conditioned rows.* A row whose pose moves far for a small geometry error is a strongly
  non-linear residual, and a few of them bend the first Gauss-Newton steps into a wrong
  valley. :func:`continuation_solve` first fits the geometry to the rows whose start poses
  are the least sensitive to the geometry (:func:`start_sensitivity`), re-starts every row's
  pose with that geometry, then fits all rows; when the chi-square test of the residuals
  (:func:`~pkmcal.estimation.acceptance.residual_test`) still fails, it fits again without the
  rows with the largest residuals, re-starts those, and refits all (a few rounds), keeping the
  best solution found.

Rows whose readings no pose on the sphere explains with the start geometry are not fitted in
the first pass but retried with the improved geometry; those still unexplained at the end are
left out and named (``dropped_rows`` and a warning in the result's
:class:`ConstraintLinkSection`).

The plain fit runs first and is returned when its residuals pass the test, so a calibration
that starts close (the default machine) costs what it did.

Constraint-link measurements (seed 000 section 3, SPEC 2.1).

A bar of length ``Lc`` with ball joints joins the base point O (origin of the base frame) and the
platform point P (origin of the platform frame), so ``|P| = Lc``. Five actuators drive, the sixth
is passive and read as a sensor. One measurement = all six joint readings at a pose on the
sphere, plus which actuator was passive (optional).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np

from ...errors import ConvergenceError, InputError
from ...estimation.acceptance import (
    MAX_NOISE_FACTOR,
    ResidualTest,
    chi2_bound,
    residual_test,
)
from ...estimation.distributions import chi2_ppf
from ...estimation.estimator import (
    MAX_STD,
    CalibrationResult,
    levenberg_marquardt,
    require_redundancy,
)
from ...estimation.sections import Section
from ...estimation.variance import fit
from ...identifiability import (
    CONSTRAINT_LINK_GAUGES,
    gauge_groups,
    name_null_space,
    name_weak_directions,
)
from ...kinematics import matrix_from_euler, matrix_from_rotvec
from ...machines.base import Machine, newton_pose_solve
from ...machines.deviations import draw_accepted
from ...parameters import ParameterSet
from ...paths import path_text
from ..base import Instrument, StandardPlan, _rows, _sigma_arg, _space_words, has_column, reachable
from ..experiment import MOUNTING_ERROR
from ..flow import (
    FlowContext,
    FlowResult,
    convergence_json,
    identifiability_json,
    identifiability_metadata,
    load_data,
    parameter_table,
    public_parameters,
    require_converged,
    rows_text,
    solve,
    source_of,
    split_rows,
    um,
    validation_section,
)
from ..flow import option as _option


@dataclass
class ConstraintLinkData:
    """Joint readings taken with the constraint link mounted.

    Attributes
    ----------
    q : ndarray, shape (K, 6)
        Joint readings, internal units (m for sliders).
    link_length : float
        Assumed constraint-link length ``Lc``, m.
    passive : ndarray of int, shape (K,), optional
        0-based index of the passive actuator, or None when not recorded.
    rows : ndarray of int, shape (K,), optional
        Row numbers in the source file (1-based data rows) for messages; default 1..K.
    source : str, optional
        File name, for messages.
    true_P, true_R : ndarray, optional
        True poses of a simulation, (K, 3) m and (K, 3, 3) (for tests and plots), else None.
    """

    q: np.ndarray
    link_length: float
    passive: np.ndarray | None = None
    rows: np.ndarray | None = None
    source: str = "<data>"
    true_P: np.ndarray | None = None
    true_R: np.ndarray | None = None

    def __post_init__(self):
        self.q = np.atleast_2d(np.asarray(self.q, float))
        if self.rows is None:
            self.rows = np.arange(1, len(self.q) + 1)
        if self.passive is not None:
            self.passive = np.asarray(self.passive, int)

    def __len__(self) -> int:
        return len(self.q)

    def distinct(self) -> tuple[int, str]:
        """How many rows are distinct measurements, and the repeated rows in words.

        Returns
        -------
        count : int
            Number of distinct rows (readings and passive joint all equal count once).
        repeats : str
            E.g. ``"rows 3, 4 repeat row 2"`` (file rows), empty when every row is distinct.
        """
        key = self.q if self.passive is None else np.column_stack([self.q, self.passive])
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        inverse = np.ravel(inverse)
        copies = np.flatnonzero(first[inverse] != np.arange(len(key)))
        if not copies.size:
            return len(first), ""
        shown = ", ".join(str(int(self.rows[i])) for i in copies[:5])
        more = f" and {copies.size - 5} more" if copies.size > 5 else ""
        origin = sorted({int(self.rows[first[inverse[i]]]) for i in copies})
        origins = ", ".join(map(str, origin[:3])) + (" ..." if len(origin) > 3 else "")
        return len(first), (f"rows {shown}{more} repeat row{'s' if len(origin) > 1 else ''} "
                            f"{origins}")

    def subset(self, mask) -> ConstraintLinkData:
        """The measurements selected by a boolean mask or index array.

        Parameters
        ----------
        mask : array_like of bool or int
            Boolean mask (K,) or indices of the rows to keep.

        Returns
        -------
        ConstraintLinkData
            The selected rows, same link length and source.
        """
        pick = (lambda a: None if a is None else a[mask])
        return ConstraintLinkData(self.q[mask], self.link_length, pick(self.passive),
                                  self.rows[mask], self.source, pick(self.true_P),
                                  pick(self.true_R))


def loop_conditioning(machine: Machine, P, J):
    """Inverse condition number (K, n_joints) of the constrained loop for each passive choice.

    ``J`` (K, n, 6) is the joint Jacobian at poses with positions ``P`` (K, 3); for passive
    actuator p its row is replaced by the link's row ``[P/|P|, 0]``.
    """
    n = J.shape[-2]
    Js = np.array(J, float)
    Js[..., 3:] /= machine.characteristic_length()          # rotations as lengths
    link = np.concatenate([P / np.linalg.norm(P, axis=-1, keepdims=True),
                           np.zeros_like(P)], -1)
    loops = np.repeat(Js[:, None], n, axis=1)               # (K, p, n, 6)
    idx = np.arange(n)
    loops[:, idx, idx, :] = link[:, None, :]
    sv = np.linalg.svd(loops, compute_uv=False)
    return sv[..., -1] / sv[..., 0]


def sample_sphere_poses(machine: Machine, link_length: float, n: int, rng=None,
                        max_tilt: float = np.deg2rad(35.0),
                        max_rotation: float = np.deg2rad(25.0), min_manipulability=0.02,
                        min_loop_conditioning=2e-3):
    """``n`` reachable poses with ``|P| = link_length`` around the machine's home direction.

    P lies in a cap of half-angle ``max_tilt`` around the direction of the home position,
    uniform on the cap; Euler angles are uniform in ``+/- max_rotation``.

    Poses are redrawn where the inverse kinematics fail, where a joint value breaks the
    machine's ``joint_limits`` (machine file), where the joint Jacobian is badly
    conditioned (smallest singular value below ``min_manipulability`` times the largest,
    rotation columns scaled by the characteristic length), or where the machine cannot be
    driven with the link mounted: for some choice of passive actuator, the loop of the five
    active actuators and the link has an inverse condition number below
    ``min_loop_conditioning`` (about a tenth of its value at home on the default machine).
    Near such poses the five actuators do not hold the platform, and the pose moves far for a
    small geometry error.

    Parameters
    ----------
    machine : Machine
        The machine whose inverse kinematics decide reachability.
    link_length : float
        Constraint-link length ``Lc``, m: the sphere's radius.
    n : int
        Number of poses.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed (``numpy.random.default_rng``).
    max_tilt : float, optional
        Half-angle of the cap, rad.
    max_rotation : float, optional
        Bound of each Euler angle, rad.
    min_manipulability : float, optional
        Smallest accepted inverse condition number of the joint Jacobian.
    min_loop_conditioning : float, optional
        Smallest accepted inverse condition number of the constrained loop.

    Returns
    -------
    P : ndarray, shape (n, 3)
        Platform positions, m.
    R : ndarray, shape (n, 3, 3)
        Platform orientations.

    Raises
    ------
    InputError
        When 50 batches of draws do not give ``n`` accepted poses.
    """
    rng = np.random.default_rng(rng)
    axis = np.asarray(machine.home[0], float)
    axis = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 0 else np.array([0, 0, 1.0])
    helper = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)

    def draw(m, rng):
        cos_t = rng.uniform(np.cos(max_tilt), 1.0, m)          # uniform on the cap
        az = rng.uniform(0, 2 * np.pi, m)
        sin_t = np.sqrt(1 - cos_t**2)
        dirs = (cos_t[:, None] * axis + (sin_t * np.cos(az))[:, None] * e1
                + (sin_t * np.sin(az))[:, None] * e2)
        P = link_length * dirs
        R = matrix_from_euler(rng.uniform(-max_rotation, max_rotation, (m, 3)))
        q, J, _ = machine.ik_jacobians(P, R, want_du=False)
        ok = np.all(np.isfinite(q), -1)
        good = machine.pose_conditioning(P[ok], R[ok], dq_dpose=J[ok]) > min_manipulability
        good &= loop_conditioning(machine, P[ok], J[ok]).min(-1) > min_loop_conditioning
        ok[ok] = good
        return P, R, ok

    where = str(getattr(machine, "source", "") or "").replace("{", "{{").replace("}", "}}")
    return draw_accepted(draw, n, rng, (f"{where}: " if where else "")
                         + "only {have} of {n} sphere poses are reachable: reduce max_tilt or "
                         "max_rotation, or check constraint_link.length and home",
                         machine=machine)


def simulate_constraint_link(true_machine: Machine, n_poses: int = 150, noise_m: float = 0.0,
                             link_length: float | None = None, link_length_error: float = 0.0,
                             rng=None, max_tilt: float = np.deg2rad(35.0),
                             max_rotation: float = np.deg2rad(25.0)) -> ConstraintLinkData:
    """Simulate a constraint-link experiment on ``true_machine``.

    The true link has length ``link_length`` (default: the machine's); the data record the
    assumed length ``link_length + link_length_error``. Every reading gets Gaussian noise of
    standard deviation ``noise_m``; the passive actuator cycles 1..6.

    Parameters
    ----------
    true_machine : HexaSlide
        The true machine (a machine with ``constraint_link_length``).
    n_poses : int, optional
        Number of poses, drawn by :func:`sample_sphere_poses`.
    noise_m : float, optional
        Standard deviation of the reading noise, internal units (m for sliders).
    link_length : float, optional
        True constraint-link length, m; default: ``true_machine.constraint_link_length``.
    link_length_error : float, optional
        Recorded minus true link length, m.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.
    max_tilt : float, optional
        Half-angle of the cap of positions, rad.
    max_rotation : float, optional
        Bound of each Euler angle, rad.

    Returns
    -------
    ConstraintLinkData
        The readings with ``passive`` set and the true poses in ``true_P``, ``true_R``.

    Raises
    ------
    InputError
        When no link length is given or known, or the poses cannot be drawn.
    """
    rng = np.random.default_rng(rng)
    Lc = link_length if link_length is not None else true_machine.constraint_link_length
    if Lc is None:
        raise InputError("the machine has no constraint_link length: give link_length")
    P, R = sample_sphere_poses(true_machine, Lc, n_poses, rng, max_tilt, max_rotation)
    q = true_machine.ik(P, R) + noise_m * rng.standard_normal((n_poses, true_machine.n_joints))
    return ConstraintLinkData(q, Lc + link_length_error, np.arange(n_poses) % 6,
                              source="<simulated>", true_P=P, true_R=R)


__all__ = ["StartReport", "continuation_solve", "neighbour_poses", "sphere_pose_candidates",
           "start_sensitivity"]

#: a row's start pose must explain its readings to within this share of the machine's
#: characteristic length (RMS over the readings): plausible geometric errors stay below it
START_TOL = 0.05
#: share of the rows (the least sensitive) fitted first by the continuation
SUBSET_SHARE = 0.5
#: share of the rows kept (the smallest residuals) in a trimmed round
TRIM_KEEP = 0.5
#: trimmed rounds after the continuation when the residual test still fails
TRIM_ROUNDS = 6
#: rows left out above this share of the data make the calibration an error
MAX_LEFT_OUT = 0.25
#: when re-starting the poses with a fitted geometry, a row whose residual norm (in units of
#: the reading noise) exceeds this factor times the median row's, and this floor, is not fitted
OUTLIER_FACTOR = 8.0
OUTLIER_FLOOR = 8.0
#: a left-out row starts again from the poses of this many fitted rows with the nearest
#: readings (8 miss a row of tests/test_global_start.py's six-leg seed 12; 16 find it)
NEIGHBOURS = 16


@dataclass
class StartReport:
    """What the start strategy did (:attr:`ConstraintLinkSection.start` of a calibration
    result).

    Attributes
    ----------
    strategy : str
        ``"direct"`` (the plain fit passed the residual test), ``"continuation"`` (the
        fallback found a solution that passes), or ``"best effort"`` (nothing passed: the
        solution with the smallest residuals is returned and the residual test flags it).
    attempts : list of dict
        Every fit tried: ``stage``, ``rows`` fitted, ``noise_factor`` (residual RMS / assumed
        noise) and ``passed``.
    retried_rows : ndarray of int
        File rows whose start pose could not be found with the machine file's geometry and
        were fitted after a first fit of the other rows.
    dropped_rows : ndarray of int
        File rows left out of the result: no pose on the constraint sphere explains their
        readings even with the calibrated geometry.
    warnings : list of str
        Sentences for the user (rows left out and why).
    kept : ndarray of bool, shape (K,), optional
        The rows in the returned fit (None before the strategy has run).
    readmitted_rows : ndarray of int
        File rows the strategy left out that the outlier test brought back (:meth:`readmit`).
    left_out_poses : tuple of ndarray, optional
        ``(P (k, 3), R (k, 3, 3))``: the best pose on the constraint sphere of each row left out,
        with the returned fit's geometry (where the outlier rounds start them).
    """

    strategy: str = "direct"
    attempts: list = field(default_factory=list)
    retried_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    dropped_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    warnings: list = field(default_factory=list)
    kept: np.ndarray | None = None
    readmitted_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    left_out_poses: tuple | None = None

    def readmit(self, still_out, file_rows) -> None:
        """Only the left-out rows in ``still_out`` stay out: the outlier test found the others
        consistent with the noise once the geometry was calibrated (rows the start strategy
        left out are its first candidates, not its verdict).

        Parameters
        ----------
        still_out : array_like of bool, shape (K,)
            Rows left out of the final fit (over all the data's rows).
        file_rows : array_like of int, shape (K,)
            The data's file rows.
        """
        if self.kept is None:
            return
        out = ~self.kept & np.asarray(still_out, bool)
        back = ~self.kept & ~out
        if not back.any():
            return
        old = _left_out_text(self.dropped_rows, len(self.kept))
        self.warnings = [w for w in self.warnings if w != old]
        self.kept = ~out
        self.readmitted_rows = np.asarray(file_rows)[back]
        self.dropped_rows = np.asarray(file_rows)[out]
        if self.dropped_rows.size:
            self.warnings.insert(0, _left_out_text(self.dropped_rows, len(self.kept)))

    @property
    def fallback(self) -> bool:
        """Whether the plain fit was not enough (continuation or rows retried)."""
        return self.strategy != "direct" or self.retried_rows.size > 0

    def as_dict(self) -> dict:
        """The report as JSON-ready values.

        Returns
        -------
        dict
            ``strategy``, ``fallback``, ``attempts``, ``retried_rows``, ``dropped_rows``,
            ``readmitted_rows``, ``warnings``.
        """
        return {"strategy": self.strategy, "fallback": self.fallback,
                "attempts": list(self.attempts),
                "retried_rows": [int(v) for v in self.retried_rows],
                "dropped_rows": [int(v) for v in self.dropped_rows],
                "readmitted_rows": [int(v) for v in self.readmitted_rows],
                "warnings": list(self.warnings)}


def _rows_text(rows) -> str:
    rows = [int(v) for v in rows]
    return ", ".join(map(str, rows[:20])) + (f" and {len(rows) - 20} more" if len(rows) > 20
                                             else "")


def _reading_rms(machine, um, q, P, R, Lc):
    """RMS reading residual of each row at poses projected onto the sphere, m (inf where a
    reading cannot be reached)."""
    norm = np.linalg.norm(P, axis=-1)
    P = P * (Lc / np.where(norm > 0, norm, 1.0))[:, None]
    with np.errstate(invalid="ignore", over="ignore"):
        qc = machine.ik(P, R, um)
        rms = np.sqrt(np.mean((qc - q) ** 2, axis=-1))
    return np.where(np.isfinite(rms), rms, np.inf), P


def neighbour_poses(machine, um, q, link_length, P, R, rms, neighbours):
    """Rows started again from the poses of explained rows with the nearest readings.

    Near the edge of the workspace the least-squares forward kinematics of a row has a wide
    basin around a wrong pose (tens of millimetres off, its residual hundreds of times the
    noise) and a narrow one around the pose the readings came from: home and the square
    systems land in the wide one, even with the true geometry. A row whose readings are close
    to another's has its pose close too, so the poses of the rows with the nearest readings
    that are explained start near it: Newton on the square systems (five readings and the
    link) from there stays on that assembly mode, and least squares on all readings polishes
    the pose. Each row keeps the best pose found.

    Parameters
    ----------
    machine : Machine
        The machine (with a constraint link).
    um : array_like or None
        Its parameter vector (internal units); None for the machine's own.
    q : ndarray, shape (K, n_joints)
        Joint readings of the rows to pose again, m.
    link_length : float
        Constraint-link length ``Lc``, m.
    P, R, rms : ndarray
        The rows' poses so far and their RMS reading residuals, m (inf: no pose).
    neighbours : tuple of ndarray
        ``(q (k, n_joints), P (k, 3), R (k, 3, 3))`` of explained rows (e.g. the rows of a
        fit); each row starts from the :data:`NEIGHBOURS` nearest.

    Returns
    -------
    P, R, rms : ndarray
        The poses, improved where a neighbour's start explains the readings better.
    """
    from scipy.spatial import cKDTree


    P, R, rms = np.array(P, float), np.array(R, float), np.array(rms, float)
    q_ref, P_ref, R_ref = (np.asarray(a, float) for a in neighbours)
    K = len(q)
    if not K or not len(q_ref):
        return P, R, rms
    k = min(NEIGHBOURS, len(q_ref))
    spread = np.std(np.concatenate([q_ref, q]), axis=0)
    spread = np.where(spread > 0, spread, 1.0)
    _, nn = cKDTree(q_ref / spread).query(q / spread, k=k)
    nn = np.reshape(nn, (-1, k)).ravel()                      # (K x k,): row j, neighbour c
    n = q.shape[1]
    # from each neighbour's pose: the square systems (five readings and the link, for every
    # reading left out: Newton stays on the neighbour's assembly mode, where least squares
    # on all readings slides into the wide basin), then least squares on all readings; and
    # least squares directly
    qk = np.repeat(q, k, axis=0)
    with np.errstate(invalid="ignore", over="ignore"):
        sq = solve_sphere_poses(machine, um, np.tile(qk, (n, 1)), link_length,
                                np.repeat(np.arange(n), len(qk)),
                                start=(np.tile(P_ref[nn], (n, 1)),
                                       np.tile(R_ref[nn], (n, 1, 1))), max_iter=40)
        q_all = np.tile(qk, (n + 1, 1))
        fk = solve_sphere_poses(machine, um, q_all, link_length, None,
                                start=(np.concatenate([P_ref[nn], sq.P]),
                                       np.concatenate([R_ref[nn], sq.R])), max_iter=40)
    new, Pn = _reading_rms(machine, um, q_all, fk.P, fk.R, link_length)
    # candidates of row j: j*k .. j*k+k-1 in each of the n + 1 blocks
    new = new.reshape(n + 1, K, k).transpose(1, 0, 2).reshape(K, -1)
    pick = np.argmin(new, axis=1)
    best = new[np.arange(K), pick]
    better = best < rms
    block, col = np.divmod(pick, k)
    flat = (block * len(qk) + np.arange(K) * k + col)[better]
    P[better], R[better], rms[better] = Pn[flat], fk.R[flat], best[better]
    return P, R, rms


def sphere_pose_candidates(machine, um, q, link_length, starts=(), neighbours=None):
    """For each row, the pose on ``|P| = link_length`` that best explains its readings among
    several starts.

    Starts: the home pose; the square systems of five readings and the link from home, for
    every choice of the reading left out; and any ``starts`` given. Each is polished by least
    squares on all readings and the link (:func:`~pkmcal.instruments.constraint_link.
    solve_sphere_poses`), and the pose with the smallest RMS reading residual is kept. With
    ``neighbours`` (rows a fit explains), every row also starts from the poses of the
    neighbours with the nearest readings (:func:`neighbour_poses`).

    Parameters
    ----------
    machine : Machine
        The machine (a Hexa Slide, a six-leg platform: any with a constraint link).
    um : array_like or None
        Its parameter vector (internal units); None for the machine's own.
    q : ndarray, shape (K, n_joints)
        Joint readings, m.
    link_length : float
        Constraint-link length ``Lc``, m.
    starts : sequence of tuple, optional
        Further ``(P (K, 3), R (K, 3, 3))`` start poses (e.g. the poses of an earlier fit).
    neighbours : tuple of ndarray, optional
        ``(q, P, R)`` of rows a fit explains, whose poses also start these rows
        (:func:`neighbour_poses`). Only with a calibrated geometry: with a geometry still far
        off, more starts let rows settle on a wrong assembly mode that this geometry explains
        better and lead the continuation astray.

    Returns
    -------
    P : ndarray, shape (K, 3)
        Positions on the sphere, m.
    R : ndarray, shape (K, 3, 3)
        Orientations.
    rms : ndarray, shape (K,)
        RMS reading residual of each row at its pose, m (inf where no start gave a pose).
    """

    q = np.asarray(q, float)
    K, n = q.shape
    if K == 0:
        return np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0)
    # the square systems for every reading left out, in one batch (n K poses)
    qq = np.tile(q, (n, 1))
    sq = solve_sphere_poses(machine, um, qq, link_length, np.repeat(np.arange(n), K),
                            max_iter=40)
    P0, R0 = machine.home
    P0 = np.asarray(P0, float)
    norm = np.linalg.norm(P0)
    P0 = link_length * (P0 / norm if norm > 0 else np.array([0, 0, 1.0]))
    Ps = [np.broadcast_to(P0, (K, 3)), *(np.asarray(P, float) for P, _ in starts), sq.P]
    Rs = [np.broadcast_to(np.asarray(machine.home[1], float), (K, 3, 3)),
          *(np.asarray(R, float) for _, R in starts), sq.R]
    P_all, R_all = np.concatenate(Ps), np.concatenate(Rs)
    m = len(P_all) // K
    # each start polished by least squares on all readings and the link, in one batch
    with np.errstate(invalid="ignore", over="ignore"):
        fk = solve_sphere_poses(machine, um, np.tile(q, (m, 1)), link_length, None,
                                start=(P_all.copy(), R_all.copy()), max_iter=40)
    rms, P = _reading_rms(machine, um, np.tile(q, (m, 1)), fk.P, fk.R, link_length)
    pick = np.argmin(rms.reshape(m, K), axis=0) * K + np.arange(K)
    if neighbours is None:
        return P[pick], fk.R[pick], rms[pick]
    return neighbour_poses(machine, um, q, link_length, P[pick], fk.R[pick], rms[pick],
                           neighbours)


def start_sensitivity(problem, state) -> np.ndarray:
    """How far each row's pose moves per unit of scaled geometry error, at a state.

    The per-row least-squares pose is a function of the geometry; its derivative is
    ``-pinv(J_l) J_g`` (local and global Jacobians of the row's residuals, global columns
    scaled). Rows where this is large are where a start with the machine file's geometry is
    far and the residual most non-linear. Local coordinates that are lengths are divided by
    the machine's characteristic length (the sphere problems: 2 tangent lengths, 3 angles).

    Parameters
    ----------
    problem : BlockProblem
        A problem with local unknowns (``local_dof > 0``).
    state : object
        A state of it.

    Returns
    -------
    ndarray, shape (K,)
        Frobenius norm of the scaled sensitivity of each row's pose.
    """
    _, Jg, Jl = problem.evaluate(state)
    free = np.asarray(problem.parameters.free, bool)
    G = Jg[..., free] * np.asarray(problem.scales, float)[free]
    S = -np.linalg.pinv(Jl) @ G                                   # (K, d, n_free)
    lengths = getattr(problem, "local_lengths", 2)
    S[:, :lengths] /= problem.machine.characteristic_length()
    return np.linalg.norm(S, axis=(1, 2))


def _noise_factor(result) -> float:
    test = residual_test(result)
    return test.noise_factor if np.isfinite(test.ratio) else 0.0





def _median_noise_factor(result) -> float:
    """The residuals' typical size over the assumed noise, from their median (robust to a few
    gross errors), corrected for the unknowns fitted (``dof / N``)."""
    r = np.asarray(result.residuals, float).ravel()
    r = r[np.isfinite(r)]
    dof = int(getattr(result, "dof", 0) or 0)
    if not r.size or dof <= 0:
        return 0.0
    return float(np.sqrt(np.median(r**2) / (chi2_ppf(0.5, 1) * dof / r.size)))


def continuation_solve(problem, solve, direct=None, noise_known: bool = True) -> tuple:
    """Solve a constraint-link maximum-likelihood problem from a far start.

    Parameters
    ----------
    problem : ConstraintLinkML
        The problem on all rows (its parameters' values are the start geometry).
    solve : callable
        ``solve(problem, state) -> CalibrationResult`` (Levenberg-Marquardt with the caller's
        options).
    direct : CalibrationResult, optional
        The plain fit, when already made (it is then not repeated).
    noise_known : bool, optional
        False: the noise level will be estimated from the residuals. A fit passes when its
        median residual is within ``MAX_NOISE_FACTOR`` of the assumed noise (not on the
        chi-square test against the assumed noise, which data noisier than assumed fail);
        when the plain fit of all rows does not, the fallback runs, and the plain fit is kept
        unless the fallback's median residual is ``MAX_NOISE_FACTOR`` times smaller (a wrong
        geometry; otherwise the data are merely noisier than assumed, or a few rows wrong).

    Returns
    -------
    result : CalibrationResult
        The solution that passes the residual test, else the one with the smallest residuals.
    problem : ConstraintLinkML
        The problem of that solution (its data: the rows kept).
    report : StartReport
        What was done.

    Raises
    ------
    InputError
        When more than :data:`MAX_LEFT_OUT` of the rows (or too few to identify the geometry)
        can be explained by no pose, even with the best geometry found.
    """

    report = StartReport()
    data = problem.data
    machine = problem.machine
    scale = machine.characteristic_length()
    u0 = problem.parameters.values.copy()
    um0, Lc0 = problem.split(u0)
    K = len(data)

    def sub_problem(mask):
        sub = type(problem).__new__(type(problem))
        sub.__dict__.update(problem.__dict__)
        sub.data = data.subset(mask)
        if hasattr(problem, "_reading_sigma") and np.ndim(problem._reading_sigma) == 2:
            sub._reading_sigma = problem._reading_sigma[mask]
        return sub

    def record(stage, result, rows):
        nf = _noise_factor(result)
        # accepted unless alarming (the warning's rule): residuals a little above the assumed
        # noise are a noise that is a little off (simulated 2 um, assumed 1 um), not a wrong
        # geometry; the fallback (slower, and it leaves out rows far above the others) must not
        # run for that
        if noise_known:
            passed = not residual_test(result).alarming
        else:
            # the noise level will be estimated: a typical (median) residual within
            # MAX_NOISE_FACTOR of the assumed noise passes (a few gross errors do not move
            # it; the outlier test names them); else the fallback runs, and the plain fit is
            # kept unless it finds a geometry that explains the rows far better
            passed = bool(result.success) and _median_noise_factor(result) <= MAX_NOISE_FACTOR
        report.attempts.append({"stage": stage, "rows": int(rows),
                                "noise_factor": float(nf), "passed": passed})
        return passed

    def fit(mask, u, P, R, stage):
        sub = sub_problem(mask)
        state = SphereState(u.copy(), P[mask].copy(), R[mask].copy())
        result = solve(sub, state)
        return result, sub, record(stage, result, mask.sum())

    sigma = float(np.mean(problem.sigma))

    def restart(u, P, R):
        """Every row's pose re-started with geometry ``u``; the rows it explains: within
        START_TOL of the size, and not far beyond the others (a row whose pose the starts
        miss, or a wrong row, would bend the fit: it is retried later or left out)."""
        um, Lc = problem.split(u)
        P, R, rms = sphere_pose_candidates(machine, um, data.q, Lc, starts=[(P, R)])
        ok = rms < START_TOL * scale
        if ok.any():
            z = rms * np.sqrt(data.q.shape[1]) / sigma           # ~ whitened norm of the row
            ok &= z <= max(OUTLIER_FLOOR, OUTLIER_FACTOR * float(np.median(z[ok])))
        return P, R, ok

    def fit_all(u, P, R, stage):
        """Re-start every pose with ``u`` and fit the rows explained; once more if the
        fitted geometry explains rows the start geometry did not."""
        P, R, ok = restart(u, P, R)
        if not _enough(ok, problem):
            return None
        result, sub, passed = fit(ok, u, P, R, stage)
        consider(result, sub, ok, passed)
        P1, R1 = P.copy(), R.copy()
        P1[ok], R1[ok] = result.state.P, result.state.R
        P2, R2, ok2 = restart(result.x, P1, R1)
        if passed and (ok2 & ~ok).any() and _enough(ok2, problem):
            result, sub, passed = fit(ok2, result.x, P2, R2, stage + ", rows retried")
            consider(result, sub, ok2, passed)
            P1, R1, ok = P2.copy(), R2.copy(), ok2
            P1[ok], R1[ok] = result.state.P, result.state.R
        return result, sub, ok, P1, R1

    # 1. start poses: the plain least-squares forward kinematics from home; multi-start only
    #    where it does not explain the readings
    fk = solve_sphere_poses(machine, um0, data.q, Lc0)
    rms, P = _reading_rms(machine, um0, data.q, fk.P, fk.R, Lc0)
    R = fk.R
    ok = rms < START_TOL * scale
    if not ok.all():
        Pm, Rm, rmsm = sphere_pose_candidates(machine, um0, data.q[~ok], Lc0)
        P[~ok], R[~ok] = Pm, Rm
        ok[~ok] = rmsm < START_TOL * scale
    started = ok.copy()
    best = None                                   # (noise factor, result, problem, mask)

    def consider(result, sub, mask, passed):
        nonlocal best
        nf = _noise_factor(result)
        if result.success or best is None:
            # passing fits: the one with the most rows; else the smallest residuals
            key = (not passed, not result.success, -int(mask.sum()) if passed else 0, nf)
            if best is None or key < best[0]:
                best = (key, result, sub, mask.copy())

    plain = None            # the plain fit of every row (unknown noise: kept unless beaten)
    if direct is not None and ok.all():
        consider(direct, problem, ok, record("direct", direct, K))
        plain = (direct, problem, ok.copy())
    elif _enough(ok, problem):
        result, sub, passed = fit(ok, u0, P, R, "direct")
        consider(result, sub, ok, passed)
        if ok.all():
            plain = (result, sub, ok.copy())
        if passed and not ok.all():
            # rows without a start pose: re-started with the fitted geometry, all refitted
            P1, R1 = P.copy(), R.copy()
            P1[ok], R1[ok] = result.state.P, result.state.R
            fit_all(result.x, P1, R1, "all rows, re-started")
    if best is not None and not best[0][0]:
        return _finish(best, report, data, started, "direct")

    # 2. continuation: the least sensitive rows first, every pose re-started with their
    #    geometry, then all rows
    # (poses of step 1: with the machine file's geometry, the pose that explains the readings
    # best is often on a wrong branch; the multi-start waits for a better geometry)
    ok = started.copy()
    sens = np.full(K, np.inf)
    if ok.any():
        sens[ok] = start_sensitivity(sub_problem(ok), SphereState(u0.copy(), P[ok], R[ok]))
    k = min(int(ok.sum()), max(int(SUBSET_SHARE * K), _min_rows(problem, 1.5)))
    first = np.zeros(K, bool)
    first[np.argsort(sens)[:k]] = True
    first &= ok
    current = best
    if _enough(first, problem):
        r1, _, _ = fit(first, u0, P, R, "well-conditioned rows")
        P1, R1 = P.copy(), R.copy()
        P1[first], R1[first] = r1.state.P, r1.state.R
        done = fit_all(r1.x, P1, R1, "all rows after continuation")
        if done is not None:
            current = (None, done[0], done[1], done[2])
            P, R = done[3], done[4]

    # 3. trimmed rounds: refit without the rows with the largest residuals, re-start them
    for round_ in range(TRIM_ROUNDS):
        if best is None or not best[0][0] or current is None:
            break
        _, result, sub, mask = current
        rows = np.flatnonzero(mask)
        chi = np.sum(np.asarray(result.residuals) ** 2, axis=-1)
        keep = np.zeros(K, bool)
        keep_n = max(int(TRIM_KEEP * rows.size), _min_rows(problem, 1.5))
        keep[rows[np.argsort(chi)[:keep_n]]] = True
        if not _enough(keep, problem):
            break
        P1, R1 = P.copy(), R.copy()
        P1[rows], R1[rows] = result.state.P, result.state.R
        r1, _, _ = fit(keep, result.x, P1, R1, f"trimmed round {round_ + 1}")
        P1[keep], R1[keep] = r1.state.P, r1.state.R
        done = fit_all(r1.x, P1, R1, f"all rows after trimmed round {round_ + 1}")
        if done is None:
            break
        current = (None, done[0], done[1], done[2])
        P, R = done[3], done[4]

    if best is None:
        raise InputError(f"{path_text(data.source)}: no pose on the constraint sphere (Lc = "
                         f"{Lc0 * 1e3:.6g} mm) reproduces the readings of "
                         f"{int((~started).sum())} row(s): {_rows_text(data.rows[~started])}")
    if (not noise_known and plain is not None and plain[0].success
            and _median_noise_factor(plain[0])
            <= MAX_NOISE_FACTOR * _median_noise_factor(best[1])):
        # no geometry explains the typical row far better: the data are noisier than
        # assumed, or a few rows are wrong (the outlier test names them)
        result, sub, mask = plain
        return _finish(((False,), result, sub, mask), report, data, started, "direct")
    return _finish(best, report, data, started,
                   "continuation" if not best[0][0] else "best effort")


def _left_out_text(rows, K: int) -> str:
    """The warning for the rows left out (file rows ``rows`` of ``K``)."""
    return (f"{len(rows)} of {K} row(s) left out: with the calibrated geometry the best pose "
            "found on the constraint sphere leaves residuals more than "
            f"{OUTLIER_FACTOR:g} times the other rows' (and the noise's): rows "
            f"{_rows_text(rows)}. Usual causes: poses near another assembly mode of the loop, "
            "where the forward kinematics have several solutions, or wrong rows (readings "
            "taken without the link, another passive joint, a typing error)")


def _min_rows(problem, redundancy: float = 1.0) -> int:
    """Rows needed to identify the geometry (``redundancy`` equations per identifiable
    parameter)."""
    n_id = int(problem.parameters.free.sum()) - 6
    per_row = problem.machine.n_joints - problem.local_dof
    return int(np.ceil(redundancy * n_id / max(per_row, 1)))


def _enough(mask, problem) -> bool:
    return int(np.sum(mask)) >= _min_rows(problem)


def _finish(best, report, data, started, strategy):
    _, result, problem, mask = best
    report.strategy = strategy
    report.retried_rows = data.rows[~started & mask]
    report.dropped_rows = data.rows[~mask]
    report.kept = np.asarray(mask, bool).copy()
    K = len(data)
    if report.dropped_rows.size:
        what = _left_out_text(report.dropped_rows, K)
        if report.dropped_rows.size > MAX_LEFT_OUT * K:
            raise InputError(f"{path_text(data.source)}: {what}; that is more than "
                             f"{MAX_LEFT_OUT:.0%} of the rows: check the data and the "
                             "machine file (constraint_link.length, home, chains)")
        # readings that no pose explains even with the calibrated geometry are bad input
        um, Lc = problem.split(result.x)
        P, R, rms = sphere_pose_candidates(
            problem.machine, um, data.q[~mask], Lc,
            neighbours=(data.q[mask], result.state.P, result.state.R))
        report.left_out_poses = (P, R)
        gross = rms >= START_TOL * problem.machine.characteristic_length()
        if gross.any():
            rows = data.rows[~mask][gross]
            raise InputError(f"{path_text(data.source)}: no pose on the constraint sphere (Lc = "
                             f"{data.link_length * 1e3:.6g} mm) reproduces the readings of "
                             f"{rows.size} row(s): {_rows_text(rows)}")
        report.warnings.append(what)
    if report.retried_rows.size:
        report.warnings.append(
            f"{report.retried_rows.size} row(s) had no start pose with the machine file's "
            f"geometry and were fitted after a first fit of the others: rows "
            f"{_rows_text(report.retried_rows)}")
    return result, problem, report


LINK = "link.length"
METHODS = ("ml", "ik", "fk")


def sphere_tangents(P):
    """Orthonormal tangent basis (K, 3, 2) of the sphere through ``P`` (K, 3), and ``P/|P|``."""
    n = P / np.linalg.norm(P, axis=-1, keepdims=True)
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    t2 = np.cross(n, t1)
    return np.stack([t1, t2], -1), n


def solve_sphere_poses(machine: Machine, u, q, link_length, passive=None, start=None,
                       tol=1e-13, max_iter=100):
    """Poses on ``|P| = link_length`` that reproduce the readings ``q``.

    With ``passive`` the passive reading is ignored and the five active ones plus the
    constraint give a square system (the paper's FK of step iii); without it all six readings
    and the constraint are solved in the least-squares sense (Gauss-Newton,
    :func:`~pkmcal.machines.newton_pose_solve`).

    Parameters
    ----------
    machine : Machine
        The machine (a Hexa Slide) whose inverse kinematics are used.
    u : array_like, shape (n_params,) or None
        Its parameter vector (internal units); None for the machine's own.
    q : ndarray, shape (K, 6)
        Joint readings, m.
    link_length : float
        Constraint-link length ``Lc``, m.
    passive : ndarray of int, shape (K,), optional
        0-based index of the passive actuator of each row.
    start : tuple of array_like, optional
        ``(P (K, 3), R (K, 3, 3))`` start poses; default: the home pose moved onto the sphere.
    tol : float, optional
        Convergence tolerance on the residuals, relative to the characteristic length.
    max_iter : int, optional
        Maximum Newton iterations.

    Returns
    -------
    FKResult
        The poses, per-row convergence and residuals (m).
    """
    K = len(q)
    if start is None:
        P0, R0 = machine.home
        P0 = np.asarray(P0, float)
        norm = np.linalg.norm(P0)
        P0 = link_length * (P0 / norm if norm > 0 else np.array([0, 0, 1.0]))
        start = (np.broadcast_to(P0, (K, 3)).copy(), np.broadcast_to(R0, (K, 3, 3)).copy())
    P, R = (np.array(start[0], float), np.array(start[1], float))
    scale = machine.characteristic_length()

    def system(idx, P, R):
        qc, J, _ = machine.ik_jacobians(P, R, u, want_du=False)
        r = qc - q[idx]
        norm = np.linalg.norm(P, axis=-1)
        rc = norm - link_length
        Jc = np.concatenate([P / norm[:, None], np.zeros_like(P)], -1)
        if passive is None:
            return (np.concatenate([r, rc[:, None]], -1),
                    np.concatenate([J, Jc[:, None, :]], -2))
        rows = np.arange(len(idx))
        r[rows, passive[idx]] = rc
        J[rows, passive[idx]] = Jc
        return r, J

    return newton_pose_solve(system, P, R, tol * scale, max_iter,
                             step_tol=None if passive is not None else 1e-9 * scale)


@dataclass
class SphereState:
    """Estimator state: global values and the per-measurement poses."""

    u: np.ndarray
    P: np.ndarray
    R: np.ndarray


class _ConstraintLinkProblem:
    """What the three methods share: parameters = machine's + ``link.length``."""

    local_dof = 0
    #: whether ``link.length`` is estimated when the caller does not say
    estimates_link_length = False
    #: the residuals are no more precise than this share of the machine's characteristic
    #: length (a few ulps of the joint values through the kinematics; an inner solve's
    #: tolerance where the residuals come from one)
    rounding = 4e-15

    def _whitening(self) -> tuple[int, np.ndarray]:
        """The number of residuals and the standard deviations that whiten them."""
        return len(self.data), self.sigma

    @property
    def cost_floor(self):
        """Cost of residuals at their precision (:attr:`rounding`, whitened): noise-free data
        fitted exactly can do no better, and the estimator stops there (a fit started at
        such an optimum finds no step that lowers its cost: converged, not stuck)."""
        n, sigma = self._whitening()
        precision = self.rounding * self.machine.characteristic_length()
        return 0.5 * n * float(np.max(precision / sigma)) ** 2

    @staticmethod
    def check_data(data: ConstraintLinkData) -> None:
        """Refuse data the method cannot use (before any fit).

        Parameters
        ----------
        data : ConstraintLinkData
            The readings.

        Raises
        ------
        InputError
            Naming the data and what is missing.
        """

    def __init__(self, machine: Machine, data: ConstraintLinkData, sigma_m=1e-6,
                 estimate_link_length: bool = False):
        if data.q.shape[1] != machine.n_joints:
            raise InputError(f"{path_text(data.source)}: "
                             f"{data.q.shape[1]} joint columns, the machine has "
                             f"{machine.n_joints} actuators")
        self.machine = machine
        self.data = data
        self.sigma = np.broadcast_to(np.asarray(sigma_m, float), (machine.n_joints,))
        link = ParameterSet([LINK], ["length"], [data.link_length],
                            fixed=[not estimate_link_length])
        self.parameters = machine.parameters.concat(link)
        self.scales = machine.scales_with(link)
        self.n_machine = len(machine.parameters)

    def global_values(self, state):
        """The global parameters of a state: machine parameters followed by ``link.length``.

        Parameters
        ----------
        state : SphereState
            An estimator state.

        Returns
        -------
        ndarray, shape (n_machine + 1,)
            Parameter values, internal units.
        """
        return state.u

    def split(self, u):
        """Split a global vector into the machine's parameters and the link length.

        Parameters
        ----------
        u : ndarray, shape (n_machine + 1,)
            Global parameter vector.

        Returns
        -------
        um : ndarray, shape (n_machine,)
            Machine parameters.
        Lc : float
            Constraint-link length, m.
        """
        return u[:self.n_machine], u[self.n_machine]

    def start_poses(self, passive=None):
        """Start poses on the constraint sphere for the start geometry.

        Parameters
        ----------
        passive : ndarray of int, shape (K,), optional
            Passive actuator of each row (square systems); None: least squares on all readings.

        Returns
        -------
        P : ndarray, shape (K, 3)
            Positions, m.
        R : ndarray, shape (K, 3, 3)
            Orientations.

        Raises
        ------
        InputError
            When no pose on the sphere explains a row's readings to within 5 % of the
            characteristic length; the rows are named.
        """
        um, Lc = self.split(self.parameters.values)
        fk = solve_sphere_poses(self.machine, um, self.data.q, Lc, passive)
        # a start pose need not be exact (the estimator refines it); it must exist and
        # explain the readings to within the size of plausible geometric errors
        bad = ~(fk.converged | (fk.residual < 0.05 * self.machine.characteristic_length()))
        if bad.any():
            rows = self.data.rows[bad]
            shown = ", ".join(map(str, rows[:10])) + (" ..." if len(rows) > 10 else "")
            raise InputError(
                f"{self.data.source}: no pose on the constraint sphere (Lc = "
                f"{Lc * 1e3:.6g} mm) reproduces the readings of {bad.sum()} row(s): {shown}")
        return fk.P, fk.R


class ConstraintLinkML(_ConstraintLinkProblem):
    """Maximum likelihood with per-pose unknowns (implicit loop); 5 local unknowns per pose.

    Global unknowns: the machine's parameters and ``link.length`` (fixed unless
    ``estimate_link_length``); local unknowns: 2 tangent and 3 rotation coordinates of each
    pose on the sphere. Residuals: all readings divided by their standard deviation.

    Parameters
    ----------
    machine : Machine
        Start geometry (a Hexa Slide); its fixed flags are kept.
    data : ConstraintLinkData
        Readings taken with the link mounted.
    sigma_m : float or array_like, optional
        Encoder noise standard deviation, m: one value or one per actuator.
    estimate_link_length : bool, optional
        Estimate ``Lc`` too (else held at ``data.link_length``).

    Raises
    ------
    InputError
        When the data's joint columns do not match the machine's actuators.
    """

    local_dof = 5

    def _whitening(self) -> tuple[int, np.ndarray]:
        return self.data.q.size, self.reading_sigma()

    def initial_state(self):
        # all six readings + the constraint in the least-squares sense: robust to a far start
        """Start state: the start geometry and poses fitted to all six readings, on the sphere.

        Returns
        -------
        SphereState
            Global values and poses.

        Raises
        ------
        InputError
            When a row's readings cannot be explained by any pose on the sphere.
        """
        P, R = self.start_poses(None)
        Lc = self.split(self.parameters.values)[1]
        P *= (Lc / np.linalg.norm(P, axis=-1))[:, None]   # exactly on the sphere
        return SphereState(self.parameters.values.copy(), P, R)

    def evaluate(self, state, jacobian=True):
        """Whitened reading residuals and their Jacobians (see :meth:`BlockProblem.evaluate`).

        Parameters
        ----------
        state : SphereState
            Global values and poses.
        jacobian : bool, optional
            Also compute the Jacobians.

        Returns
        -------
        r : ndarray, shape (K, n_joints)
            ``(IK(pose) - q) / sigma``.
        J_g : ndarray, shape (K, n_joints, n_machine + 1) or None
            Derivatives with respect to the machine parameters and ``Lc``.
        J_l : ndarray, shape (K, n_joints, 5) or None
            Derivatives with respect to the pose's tangent and rotation coordinates.
        """
        um, Lc = self.split(state.u)
        q, Jx, Ju = self.machine.ik_jacobians(state.P, state.R, um, want_du=jacobian)
        sigma = self.reading_sigma()
        r = (q - self.data.q) / sigma
        if not jacobian:
            return r, None, None
        T, n = sphere_tangents(state.P)
        JP = Jx[..., :3]
        dLc = np.einsum("kji,ki->kj", JP, n)[..., None]
        Jg = np.concatenate([Ju, dLc], -1) / sigma[..., None]
        Jl = np.concatenate([JP @ T, Jx[..., 3:]], -1) / sigma[..., None]
        return r, Jg, Jl

    def reading_sigma(self):
        """Standard deviation of every reading, (K, n_joints) or broadcastable.

        Returns
        -------
        ndarray
            Standard deviations, m: here one per actuator, shape (n_joints,).
        """
        return self.sigma

    def noise_groups(self):
        """One noise group, the encoder readings (as lengths), one measurement per pose.

        Returns
        -------
        NoiseGroups
            See :class:`~pkmcal.estimation.variance.NoiseGroups`.
        """
        from ...estimation.variance import NoiseGroups

        K, n = self.data.q.shape
        groups = NoiseGroups.single((K, n), "reading", "encoder readings",
                                    float(np.mean(self.sigma)), "length",
                                    getattr(self.data, "rows", None))
        return groups

    def retract(self, state, du, dl):
        """The state after a step: poses moved on the sphere, then projected back onto it.

        Parameters
        ----------
        state : SphereState
            Current state.
        du : ndarray, shape (n_machine + 1,)
            Step of the global parameters.
        dl : ndarray, shape (K, 5)
            Step of each pose: 2 tangent (m) and 3 rotation (rad) coordinates.

        Returns
        -------
        SphereState
            The new state.
        """
        u = state.u + du
        T, _ = sphere_tangents(state.P)
        P = state.P + np.einsum("kij,kj->ki", T, dl[:, :2])
        P *= (u[self.n_machine] / np.linalg.norm(P, axis=-1))[:, None]
        R = matrix_from_rotvec(dl[:, 2:]) @ state.R
        return SphereState(u, P, R)


class ConstraintLinkIK(ConstraintLinkML):
    """The paper's inverse-kinematics method, all chains jointly.

    The five active readings are taken as exact and the passive one carries the residual.
    Solving the five-active-plus-link loop for the pose at every step (the paper's step iii)
    fails wherever that loop has no solution for the current geometry, which stalls the
    iteration from the paper's Table 1 errors. Here the poses stay unknowns, as in ``ml``, and
    the active readings are weighted ``active_weight`` (1e3) times more than the passive one:
    the estimate equals the exact method's to a relative ``1/active_weight^2`` and the problem
    is feasible at every step. :class:`ConstraintLinkIKExplicit` is the literal form.

    Parameters
    ----------
    machine : Machine
        Start geometry (a Hexa Slide).
    data : ConstraintLinkData
        Readings with the ``passive`` column.
    sigma_m : float or array_like, optional
        Encoder noise standard deviation, m: one value or one per actuator.
    estimate_link_length : bool, optional
        Estimate ``Lc`` too.

    Raises
    ------
    InputError
        When the data have no ``passive`` column or the wrong number of joint columns.
    """

    active_weight = 1e3
    #: the active readings are taken as exact: its residuals are not the noise's
    noise_groups = None

    @staticmethod
    def check_data(data: ConstraintLinkData) -> None:
        """Refuse data without the ``passive`` column (the method needs it).

        Parameters
        ----------
        data : ConstraintLinkData
            The readings.

        Raises
        ------
        InputError
            Naming the data and the column.
        """
        if data.passive is None:
            raise InputError(f"{path_text(data.source)}: the inverse-kinematics method needs "
                             "the 'passive' column (which actuator was passive at each row)")

    def __init__(self, machine, data, sigma_m=1e-6, estimate_link_length=False):
        self.check_data(data)
        super().__init__(machine, data, sigma_m, estimate_link_length)
        weights = np.full(data.q.shape, self.active_weight)
        weights[np.arange(len(data)), data.passive] = 1.0
        self._reading_sigma = self.sigma / weights

    def reading_sigma(self):
        return self._reading_sigma


class _ImplicitPoseProblem(_ConstraintLinkProblem):
    """Methods whose poses are functions of the readings (solved inside each evaluation)."""

    #: forward kinematics inside each evaluation converge to this (times the machine's
    #: characteristic length); residuals are no more precise than that
    fk_tol = 1e-13
    rounding = fk_tol

    def _keep_solved_rows(self, fk):
        """Keep the rows whose poses the start geometry can solve (seed 000's methods need
        a start close enough); the others are left out and reported as ``dropped_rows``."""
        data = self.data
        self.dropped_rows = data.rows[~fk.converged]
        self._start = (fk.P[fk.converged], fk.R[fk.converged])
        if self.dropped_rows.size:
            self.data = data.subset(fk.converged)
        if len(self.data) == 0:
            raise InputError(f"{path_text(data.source)}: no row can be solved for a pose with the "
                             "start geometry")

    #: start values of the global unknowns (None: the machine's, ``parameters.values``)
    _u0 = None

    def initial_state(self):
        """Start state: the start geometry and the poses solved for it.

        Returns
        -------
        SphereState
            Global values and the poses of the rows kept.
        """
        u = self.parameters.values if self._u0 is None else self._u0
        return SphereState(u.copy(), *self._start)

    def retract(self, state, du, dl):
        """The state after a global step (poses are recomputed in :meth:`evaluate`).

        Parameters
        ----------
        state : SphereState
            Current state.
        du : ndarray, shape (n_machine + 1,)
            Step of the global parameters.
        dl : None
            Unused (no local unknowns).

        Returns
        -------
        SphereState
            The new state, with the old poses as warm start.
        """
        return SphereState(state.u + du, state.P, state.R)

    def _poses(self, state, constrained: bool):
        um, Lc = self.split(state.u)
        if constrained:
            fk = solve_sphere_poses(self.machine, um, self.data.q, Lc, self.data.passive,
                                    start=(state.P, state.R), tol=self.fk_tol)
        else:
            fk = self.machine.fk(self.data.q, um, start=(state.P, state.R), tol=self.fk_tol)
        state.P, state.R = fk.P, fk.R          # warm start for the next evaluation
        return fk


class ConstraintLinkIKExplicit(_ImplicitPoseProblem):
    """The paper's inverse-kinematics method literally.

    The pose comes from the five active readings and the link (forward kinematics), the
    residual is the passive reading minus its inverse kinematics, and the Jacobian is the total
    derivative ``dq_p/du + dq_p/dx dx/du`` (implicit differentiation). Rows whose pose the
    start geometry cannot solve are left out and listed in ``dropped_rows``.

    Parameters
    ----------
    machine : Machine
        Start geometry (a Hexa Slide).
    data : ConstraintLinkData
        Readings with the ``passive`` column.
    sigma_m : float or array_like, optional
        Encoder noise standard deviation, m: one value or one per actuator.
    estimate_link_length : bool, optional
        Estimate ``Lc`` too.
    start : tuple of ndarray, optional
        ``(P (K, 3), R (K, 3, 3))`` start poses for the pose solves; default: fitted to all six
        readings.

    Raises
    ------
    InputError
        When the data have no ``passive`` column, the wrong number of joint columns, or no row
        can be solved.
    """

    check_data = staticmethod(ConstraintLinkIK.check_data)

    def __init__(self, machine, data, sigma_m=1e-6, estimate_link_length=False, start=None):
        self.check_data(data)
        super().__init__(machine, data, sigma_m, estimate_link_length)
        # the five active readings + the constraint may have no solution with the start
        # geometry (seed 000's method needs a start close enough): such rows are left out
        um, Lc = self.split(self.parameters.values)
        P, R = self.start_poses(None) if start is None else start
        self._keep_solved_rows(solve_sphere_poses(machine, um, data.q, Lc, data.passive,
                                                  start=(P, R)))

    def evaluate(self, state, jacobian=True):
        """Passive-reading residuals with the poses solved from the active readings and the link.

        Parameters
        ----------
        state : SphereState
            Global values; its poses are the warm start and are updated in place.
        jacobian : bool, optional
            Also compute the Jacobian.

        Returns
        -------
        r : ndarray, shape (K, 1)
            Whitened passive-reading residuals; NaN where the pose solve failed.
        J_g : ndarray, shape (K, 1, n_machine + 1) or None
            Total derivatives with respect to the global parameters.
        J_l : None
            No local unknowns.
        """
        fk = self._poses(state, constrained=True)
        um, Lc = self.split(state.u)
        K = len(self.data)
        rows = np.arange(K)
        p = self.data.passive
        q, Jx, Ju = self.machine.ik_jacobians(fk.P, fk.R, um, want_du=jacobian)
        sig = self.sigma[p]
        r = ((q[rows, p] - self.data.q[rows, p]) / sig)[:, None]
        r = np.where(fk.converged[:, None], r, np.nan)
        if not jacobian:
            return r, None, None
        # loop equations F(x, u) = [IK_active(x, u) - q_active; |P| - Lc] = 0 (square, 6x6)
        Fx = Jx.copy()
        norm = np.linalg.norm(fk.P, axis=-1)
        Fx[rows, p] = np.concatenate([fk.P / norm[:, None], np.zeros((K, 3))], -1)
        Fu = np.concatenate([Ju, np.zeros((K, 6, 1))], -1)
        Fu[rows, p] = 0.0
        Fu[rows, p, -1] = -1.0
        dx_du = -np.linalg.solve(Fx, Fu)                                   # (K, 6, n)
        Jp = np.concatenate([Ju[rows, p], np.zeros((K, 1))], -1)
        Jg = (Jp + np.einsum("ki,kin->kn", Jx[rows, p], dx_du)) / sig[:, None]
        return r, Jg[:, None, :], None


class ConstraintLinkFK(_ImplicitPoseProblem):
    """The paper's forward-kinematics method: residual = ``|FK(q)| - Lc``, ``Lc`` estimated.

    Rows whose forward kinematics the start geometry cannot solve are left out and listed in
    ``dropped_rows``.

    Parameters
    ----------
    machine : Machine
        Start geometry (a Hexa Slide).
    data : ConstraintLinkData
        Readings taken with the link mounted.
    sigma_m : float or array_like, optional
        Encoder noise standard deviation, m; the residuals are divided by its mean.
    estimate_link_length : bool, optional
        Estimate ``Lc`` too (default True: the method needs it).
    start : SphereState, optional
        Start values of the global unknowns and poses near the solution (the ml estimate's);
        default: the machine's values and the poses solved for them.

    Raises
    ------
    InputError
        When the joint columns do not match the machine, start poses cannot be found, or no row
        can be solved.
    """

    estimates_link_length = True

    def __init__(self, machine, data, sigma_m=1e-6, estimate_link_length=True, start=None):
        super().__init__(machine, data, sigma_m, estimate_link_length)
        if start is not None:           # a state near the solution (the ml estimate's)
            self._u0 = np.asarray(start.u, float).copy()
        um, _ = self.split(self.parameters.values if self._u0 is None else self._u0)
        poses = self.start_poses(None) if start is None else (start.P, start.R)
        self._keep_solved_rows(machine.fk(data.q, um, start=poses))

    def evaluate(self, state, jacobian=True):
        """Link-length residuals ``|FK(q)| - Lc`` of the forward kinematics of all six readings.

        Parameters
        ----------
        state : SphereState
            Global values; its poses are the warm start and are updated in place.
        jacobian : bool, optional
            Also compute the Jacobian.

        Returns
        -------
        r : ndarray, shape (K, 1)
            Residuals divided by the mean encoder noise; NaN where the forward kinematics failed.
        J_g : ndarray, shape (K, 1, n_machine + 1) or None
            Total derivatives with respect to the global parameters.
        J_l : None
            No local unknowns.
        """
        fk = self._poses(state, constrained=False)
        um, Lc = self.split(state.u)
        K = len(self.data)
        norm = np.linalg.norm(fk.P, axis=-1)
        sig = float(np.mean(self.sigma))
        r = ((norm - Lc) / sig)[:, None]
        r = np.where(fk.converged[:, None], r, np.nan)
        if not jacobian:
            return r, None, None
        _, Jx, Ju = self.machine.ik_jacobians(fk.P, fk.R, um)
        dx_du = -np.linalg.solve(Jx, Ju)                                   # (K, 6, n_m)
        n = fk.P / norm[:, None]
        dnorm = np.einsum("ki,kin->kn", n, dx_du[:, :3])
        Jg = np.concatenate([dnorm, -np.ones((K, 1))], -1) / sig
        return r, Jg[:, None, :], None


PROBLEMS = {"ml": ConstraintLinkML, "ik": ConstraintLinkIK, "fk": ConstraintLinkFK}


@dataclass
class ConstraintLinkSection(Section):
    """What a constraint-link calibration adds to its result
    (``result.sections["constraint_link"]``): the link length, where the method started, the
    rows left out and the start strategy's report.

    Attributes
    ----------
    link_length, assumed : float or None
        The link length identified (or held) and the machine file's, m.
    estimated : bool
        Whether the link length was estimated.
    std : float or None
        Its standard deviation, m (estimated only).
    dropped_rows : ndarray of int
        File rows left out (no pose for the start geometry; ``'ml'``: no pose found that
        explains them with the calibrated geometry).
    start : StartReport or None
        ``'ml'``: what the start strategy did.
    warnings : list of str or None
        ``'ml'``: sentences for the user (rows left out or retried, and why).
    start_from : str or None
        The paper's methods: where they started (:data:`PAPER_METHOD_START`).
    sweeps : int or None
        ``per_chain``: the sweeps made.
    """

    instrument: ClassVar[str] = "constraint_link"
    title: ClassVar[str] = "link length"

    link_length: float | None = None
    assumed: float | None = None
    estimated: bool = False
    std: float | None = None
    dropped_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    start: StartReport | None = None
    warnings: list | None = None
    start_from: str | None = None
    sweeps: int | None = None

    @classmethod
    def of(cls, result) -> ConstraintLinkSection:
        """The result's section (attached, empty, when it has none yet)."""
        section = result.section(cls)
        if section is None:
            section = cls()
            result.add_section(section)
        return section

    def as_report(self, units=None) -> dict:
        from ...units import LENGTH

        if self.link_length is None:
            return {}
        unit = (units or {}).get("length", "mm")
        fl = LENGTH[unit]
        return {"link_length": {
            "value": self.link_length / fl, "assumed": self.assumed / fl, "unit": unit,
            "estimated": bool(self.estimated),
            "std": self.std / fl if self.estimated and self.std is not None else None}}

    def summary_rows(self, units=None) -> list:
        lc = self.as_report(units).get("link_length")
        if lc is None:
            return []
        if lc["estimated"]:
            std = f" +/- {lc['std']:.3g} {lc['unit']}" if lc["std"] is not None else ""
            return [("link length Lc", f"{lc['value']:.9g} {lc['unit']} (estimated{std}; "
                     f"machine file {lc['assumed']:.9g} {lc['unit']})")]
        return [("link length Lc", f"{lc['value']:.9g} {lc['unit']} (fixed: machine file)")]


def calibrate_constraint_link(machine: Machine, data: ConstraintLinkData, method: str = "ml",
                              sigma_m=1e-6, estimate_link_length: bool | None = None,
                              per_chain: bool = False, max_sweeps: int = 200, rtol: float = 1e-7,
                              estimate_noise=True, robust: bool = False,
                              **options) -> CalibrationResult:
    """Calibrate ``machine`` from constraint-link data.

    Parameters
    ----------
    machine : Machine
        Start geometry (a Hexa Slide with ``constraint_link_length``); not modified.
    data : ConstraintLinkData
        Readings taken with the link mounted.
    method : {'ml', 'ik', 'fk'}, optional
        Maximum likelihood, the paper's inverse- or forward-kinematics method (see the module
        docstring).
    sigma_m : float or array_like, optional
        Encoder noise standard deviation(s), m (scalar or per actuator).
    estimate_link_length : bool, optional
        Estimate ``Lc`` too (default: only for ``'fk'``).
    per_chain : bool, optional
        ``'ik'`` only: the paper's chain-by-chain sweeps.
    max_sweeps : int, optional
        ``per_chain`` only: maximum number of sweeps over the chains.
    rtol : float, optional
        Rank tolerance of :func:`levenberg_marquardt`.
    estimate_noise : bool, optional
        ``'ml'``: estimate the encoder noise from the residuals (``sigma_m`` its prior;
        :func:`~pkmcal.estimation.variance.fit`); False holds ``sigma_m``.
    robust : bool, optional
        ``'ml'``: leave out the rows the outlier test names.
    **options
        Passed to :func:`levenberg_marquardt` (``xtol``, ``ftol``, ``max_iter``, ``max_std``;
        without ``per_chain``, ``max_std`` defaults to :data:`MAX_STD`).

    Returns
    -------
    CalibrationResult
        With ``method``; ``machine``, the calibrated machine (home kept from ``machine``
        when reachable, else the nearest measured pose); ``unidentifiable``, the named null
        and weak directions; its :class:`ConstraintLinkSection`: ``link_length``,
        ``dropped_rows``, file rows
        left out (the paper's methods: no pose for the start geometry; ``'ml'``: no pose found
        that explains them with the calibrated geometry); with ``per_chain`` also ``sweeps``.
        ``'ml'`` also: ``start``, the :class:`StartReport` (plain fit
        or the fallback of :func:`continuation_solve` when the plain
        fit fails the residual test); ``problem``, the problem solved (its data: the rows
        kept); ``warnings``, sentences for the user (rows left out or retried, and why).

    Raises
    ------
    InputError
        When ``method`` is unknown, ``per_chain`` is used without ``'ik'``, the data give fewer
        equations than identifiable parameters, or the problem cannot be set up (see the
        problem classes).
    """
    if method not in PROBLEMS:
        raise InputError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if per_chain and method != "ik":
        raise InputError("per_chain applies to the inverse-kinematics method (method='ik')")
    cls = PROBLEMS[method]
    if estimate_link_length is None:
        estimate_link_length = cls.estimates_link_length
    paper = method != "ml" and not per_chain        # the paper's methods start from ml's
    if paper:
        cls.check_data(data)
    problem = (ConstraintLinkML if paper else cls)(machine, data, sigma_m,
                                                   estimate_link_length=estimate_link_length)
    n_id = int(problem.parameters.free.sum()) - 6
    distinct, repeats = data.distinct()
    n_rows = distinct * (machine.n_joints - 5 if method == "ml" else 1)
    require_redundancy(data.source, f"{len(data)} rows, {distinct} distinct ({repeats})"
                       if repeats else f"{len(data)} measurements", n_rows, n_id,
                       "measure more poses spread over the sphere with varied orientation")
    start = None
    if per_chain:
        result = _per_chain_sweeps(problem, max_sweeps, rtol, **options)
    elif method == "ml":
        # far starts (large build errors, other geometries): continuation, pose multi-starts,
        # rows without a start pose retried and named (calibration.start). Not for 'ik': its
        # residuals (active readings taken as exact) fail the chi-square test by design
        lm_options = {"max_std": MAX_STD, **options}
        every_row = problem
        result, problem, start = continuation_solve(
            problem, lambda p, state: levenberg_marquardt(p, rtol=rtol, state=state,
                                                          **lm_options),
            noise_known=estimate_noise is False)
        state, left_out = result.state, None
        if start.kept is not None and not start.kept.all():
            # rows the start strategy left out are the outlier rounds' first candidates, not
            # their verdict: posed with the geometry found, brought back when it explains them
            problem, left_out = every_row, ~start.kept
            P, R = np.zeros((len(data), 3)), np.tile(np.eye(3), (len(data), 1, 1))
            P[start.kept], R[start.kept] = state.P, state.R
            P[left_out], R[left_out] = start.left_out_poses
            state = SphereState(state.u.copy(), P, R)
        # the encoder noise from the residuals, rows the noise cannot explain named (or left
        # out with robust): from the solution the start strategy found (its fit is the plain
        # refit's, when that fit ended there: it is not made again)
        result = fit(problem, estimate_noise, robust=robust, rtol=rtol, state=state,
                     left_out=left_out, fitted=result if left_out is None else None,
                     **lm_options)
        if left_out is not None:
            start.readmit(~result.outliers.kept, data.rows)
    else:
        result, problem, start = _paper_method(cls, problem, method, rtol,
                                               {"max_std": MAX_STD, **options})
    _refuse_degenerate(data, result, n_id, repeats)
    um, Lc = problem.split(result.x)
    calibrated = machine.with_parameters(um)
    calibrated.constraint_link_length = float(Lc)
    # keep the user's working pose as home (the FK start) when the calibrated machine
    # reaches it; a measured pose may lie at the edge of the workspace
    calibrated.home = machine.home
    if not np.all(np.isfinite(calibrated.ik(*machine.home))) and result.state is not None:
        i = int(np.argmin(np.linalg.norm(result.state.P - machine.home[0], axis=-1)))
        calibrated.home = (result.state.P[i], result.state.R[i])
    groups = gauge_groups(machine, um, CONSTRAINT_LINK_GAUGES, result.scales,
                          len(problem.parameters))
    section = ConstraintLinkSection.of(result)
    section.dropped_rows = getattr(problem, "dropped_rows", np.array([], int))
    if start is not None:
        section.dropped_rows = start.dropped_rows
        section.start, section.warnings = start, list(start.warnings)
        result.problem = problem
    names = list(result.parameters.names)
    k = names.index("link.length") if "link.length" in names else None
    section.link_length, section.assumed = float(Lc), float(data.link_length)
    section.estimated = k is not None and not bool(result.parameters.fixed[k])
    section.std = float(result.std[k]) if section.estimated else None
    result.method, result.machine = method, calibrated
    result.unidentifiable = (name_null_space(result.null_space, problem.parameters, groups)
                             + name_weak_directions(result, problem.parameters))
    return result


#: where the paper's methods start (the report's ``start``, the console's ``start`` row)
PAPER_METHOD_START = ("the maximum-likelihood estimate (seed 000's methods converge only from "
                      "a start close to the machine; the ml method's global start finds one "
                      "on any geometry)")


def _paper_method(cls, ml: ConstraintLinkML, method: str, rtol: float, lm_options: dict):
    """Seed 000's inverse- or forward-kinematics method (problem class ``cls``) from the
    maximum-likelihood estimate of ``ml``: the paper's methods converge only from a start
    close to the machine, which the machine file is not on other geometries (Table 1's errors
    from a far start: no convergence, a wrong geometry or too few rows solvable); the ml
    method's global start and continuation find one on any geometry. The method's own optimum
    is then returned (with noise, its estimate, not the ml one).

    Its geometry is then tested like an ml fit: every reading noisy, the poses refitted with
    the geometry held (:func:`_paper_method_test`, ``result.residual_test``). A geometry
    the readings reject (residuals :data:`MAX_NOISE_FACTOR` times the assumed noise beyond the
    chi-square bound) is refused (:class:`~pkmcal.errors.ConvergenceError`): these methods
    estimate no noise level, so no wrong geometry is returned with success.

    Returns
    -------
    result : CalibrationResult
        The method's fit (``residual_test``; its section's ``start_from``).
    problem : ConstraintLinkIK or ConstraintLinkFK
        The problem solved (its data: the rows the ml start kept).
    start : StartReport
        The ml start's report (rows left out, strategy).
    """
    machine, data = ml.machine, ml.data
    estimate = not ml.parameters.fixed[-1]
    # the start's tests as the ml method's with the noise estimated (a typical residual within
    # MAX_NOISE_FACTOR of the assumed noise): data noisier than assumed are not a far start;
    # the method's own geometry is tested at the assumed noise below
    ml_result, ml_problem, start = continuation_solve(
        ml, lambda p, state: levenberg_marquardt(p, rtol=rtol, state=state, **lm_options),
        noise_known=False)
    state = ml_result.state
    if issubclass(cls, _ImplicitPoseProblem):
        problem = cls(machine, ml_problem.data, ml.sigma, estimate_link_length=estimate,
                      start=state)
        result = levenberg_marquardt(problem, rtol=rtol, **lm_options)
    else:
        problem = cls(machine, ml_problem.data, ml.sigma, estimate_link_length=estimate)
        result = levenberg_marquardt(problem, rtol=rtol, state=state, **lm_options)
    unsolved = np.asarray(getattr(problem, "dropped_rows", np.zeros(0, int)), int)
    if unsolved.size:       # rows the method's own pose solve fails on, even from ml's poses
        start.dropped_rows = np.union1d(start.dropped_rows, unsolved).astype(int)
        start.warnings.append(f"{unsolved.size} row(s) left out: the {method} method finds no "
                              "pose for them with the maximum-likelihood estimate's geometry: "
                              f"rows {_rows_text(unsolved)}")
    if not result.success:
        return result, problem, start
    test, ml_test = _paper_method_test(problem, result), residual_test(ml_result)
    if test.alarming:
        # the paper's methods do not estimate the noise: residuals far beyond the assumed
        # noise are a wrong geometry or a wrong assumed noise, and either way no result
        why = ("the data are noisier than assumed (give --noise) or the start geometry is "
               "far from the machine" if ml_test.alarming else
               "the maximum-likelihood estimate explains them: use --method ml")
        raise ConvergenceError(
            f"{path_text(data.source)}: "
            f"the {method} method converged to a geometry the readings reject: "
            f"residuals {test.noise_factor:.3g}x the assumed noise with every reading noisy "
            f"and the poses refitted (chi2/dof = {test.ratio:.3g}, at most {test.upper:.3g} "
            f"expected; the maximum-likelihood start: {ml_test.noise_factor:.3g}x); {why}; "
            "no file written")
    result.residual_test = test
    ConstraintLinkSection.of(result).start_from = PAPER_METHOD_START
    return result, problem, start


def _paper_method_test(problem, result) -> ResidualTest:
    """The chi-square test of a paper method's geometry in the ml model's terms: every reading
    noisy (the assumed noise), each pose refitted to its six readings on the link's sphere
    with the geometry (and link length) held. Degrees of freedom as an ml fit's: the readings
    minus 5 per pose and the identified parameters (the geometry was fitted to the same
    readings)."""
    u = np.asarray(result.x, float)
    held = ConstraintLinkML(problem.machine, problem.data, problem.sigma)
    held.parameters = held.parameters.with_values(u).with_fixed(list(held.parameters.names))
    P, R = result.state.P.copy(), result.state.R.copy()
    P *= (u[-1] / np.linalg.norm(P, axis=-1))[:, None]          # onto the sphere
    poses = levenberg_marquardt(held, state=SphereState(u.copy(), P, R))
    dof = int(poses.dof) - int(result.rank)
    chi2 = 2.0 * float(poses.cost)
    if dof <= 0 or not math.isfinite(chi2):
        return ResidualTest(chi2, dof, math.nan, math.nan, True)
    ratio, upper = chi2 / dof, chi2_bound(dof)
    return ResidualTest(chi2, dof, ratio, upper, bool(ratio <= upper))


def _refuse_degenerate(data, result, n_id: int, repeats: str) -> None:
    """Refuse poses that leave more than the named frames unidentifiable (like collinear
    tracker points): the estimate would be an arbitrary member of a family of geometries."""
    null = 0 if result.null_space is None else result.null_space.shape[1]
    free = int(result.parameters.free.sum()) if result.parameters is not None else 0
    extra = null - (free - n_id)
    if extra <= 0:
        return
    why = f" ({repeats})" if repeats else ""
    raise InputError(f"{path_text(data.source)}: "
                     f"the {len(data)} poses{why} are degenerate: {extra} "
                     f"direction(s) beyond the frames' are not identifiable (only "
                     f"{free - null} of {n_id}); measure more poses spread over the sphere with "
                     "varied orientation")


def _per_chain_sweeps(problem, max_sweeps, rtol, **options):
    """Seed 000 3.4.1 literally: for each chain, fit its 9 parameters to the rows where it was
    passive, poses from the other five; repeat sweeps until no parameter moves."""
    base = problem.parameters
    machine, data = problem.machine, problem.data
    u = base.values.copy()
    state = problem.initial_state()
    P, R = state.P, state.R
    step = np.inf
    for sweep in range(1, max_sweeps + 1):
        u_before = u.copy()
        try:
            u = _one_sweep(problem, base, u, P, R, rtol, **options)
        except (ValueError, InputError) as exc:   # a chain's rows became unsolvable
            return _failed_sweeps(problem, u_before, sweep, f"sweep {sweep} failed: {exc}")
        previous, step = step, np.max(np.abs((u - u_before) / problem.scales))
        if step < options.get("xtol", 1e-12):
            break
        if sweep >= 3 and step > previous:
            return _failed_sweeps(problem, u, sweep,
                                  f"per-chain sweeps diverge (scaled change {step:.2e} after "
                                  f"{previous:.2e}): each chain's fit absorbs the other chains' "
                                  "errors through the forward kinematics of its rows; use the "
                                  "joint methods (ml, ik)")
    full = ConstraintLinkIKExplicit(machine.with_parameters(u[:-1]), data, problem.sigma)
    full.parameters = base.with_values(u)
    final = levenberg_marquardt(full, rtol=rtol, max_iter=1)  # statistics at the solution
    final.x, final.parameters = u, base.with_values(u)
    ConstraintLinkSection.of(final).sweeps = sweep
    final.success = step < options.get("xtol", 1e-12)
    final.message = f"per-chain sweeps: {sweep}"
    return final


def _failed_sweeps(problem, u, sweep, message):
    """A result object for sweeps that cannot go on: nothing identified, reason given."""
    base = problem.parameters
    n = len(base)
    return CalibrationResult(
        x=u, parameters=base.with_values(u), cost=float("nan"), residuals=np.zeros((0, 1)),
        success=False, status=3, message=message, nit=sweep, nfev=0, rank=0,
        singular_values=np.zeros(0), null_space=np.zeros((n, 0)), scales=problem.scales,
        weak_space=np.zeros((n, 0)), weak_std=np.zeros(0),
        covariance=np.zeros((n, n)), std=np.zeros(n), residual_variance=float("nan"), dof=0,
        state=None, sections={"constraint_link": ConstraintLinkSection(sweeps=sweep)})


def _one_sweep(problem, base, u, P, R, rtol, **options):
    """One pass over the chains: each chain's 9 parameters from the rows where it was passive."""
    machine, data = problem.machine, problem.data
    for i in range(machine.n_joints):
        rows = data.passive == i
        if not rows.any():
            continue
        sub = ConstraintLinkIKExplicit(machine.with_parameters(u[:-1]), data.subset(rows),
                                       problem.sigma, start=(P[rows], R[rows]))
        free = np.zeros(len(base), bool)
        free[base.indices(f"chain{i + 1}")] = True
        sub.parameters = ParameterSet(base.names, base.kinds, u, ~free)
        u = levenberg_marquardt(sub, rtol=rtol, **options).x.copy()
    return u


def link_noise_arg(text: str | float | None, machine=None) -> float:
    """The encoder noise of constraint-link data (``--noise``, default 1 um), m.

    Parameters
    ----------
    text : str or float or None
        A length with its unit (``"2um"``), a number in metres, or None for 1 um.
    machine : Machine, optional
        Checked against its size when given.

    Returns
    -------
    float
        The standard deviation, m.

    Raises
    ------
    InputError
        When it is not a positive length or implausible for the machine.
    """
    if text is None or (isinstance(text, str) and not text):
        text = "1um"
    return _sigma_arg(text, machine, "the encoder noise", None)


@dataclass(frozen=True, slots=True)
class ConstraintLinkOptions:
    """The options of the constraint link's calibration flow (:meth:`ConstraintLink.calibrate`)."""

    method: str | None = _option(
        None, "--method", "ml maximum likelihood, every reading noisy (default); ik the "
        "paper's inverse-kinematics method (needs the passive column); fk the paper's "
        "forward-kinematics method (estimates Lc).", choices=("ml", "ik", "fk"))
    noise: object = _option(
        None, "--noise", "encoder noise, standard deviation (default 1um); held as given, else "
        "estimated from the residuals.")
    estimate_lc: bool | None = _option(
        None, "--estimate-lc/--no-estimate-lc", "Estimate the constraint-link length too "
        "(default: only with --method fk).", negative_help="Hold the constraint-link length "
        "at the machine file's, with --method fk too.")
    robust: bool = _option(
        False, "--robust", "Leave out the rows the noise cannot explain (a chi-square test of "
        "each row) and fit again (ml).")


class ConstraintLink(Instrument):
    """Seed 000: joint readings with the constraint link mounted, one joint passive."""

    name = "constraint-link"
    words = "a fixed-length constraint link, one joint passive (no external sensor)"
    plan_size = 150
    columns = "q1_mm..q6_mm (optionally passive) with a constraint_link in the machine file"
    priority = 90
    readings_only = True
    data_class = "ConstraintLinkData"
    joint_refusal = "the constraint link estimates a platform pose per measurement"

    def detect(self, header):
        return has_column(header, "q1")

    def applies(self, machine):
        if not machine.rotates:
            return ("the constraint link takes one degree of freedom of a platform that "
                    "rotates; this machine's platform only translates")
        if len(machine.pose_space) != 6:
            return ("the constraint link takes one degree of freedom of a platform that moves "
                    "in space (six pose coordinates); this machine's platform moves along "
                    f"{_space_words(machine)} only")
        if getattr(machine, "constraint_link_length", None) is None:
            return ("the machine file has no constraint link: add `constraint_link: {length: "
                    "...}` (in the file's length unit)")
        return None

    def default_noise(self):
        return 1e-6

    def describe_noise(self, noise):
        return f"encoder noise {noise * 1e6:.4g} um (std)"

    montecarlo_variables = ("noise", "lc-error", "poses", "tolerance")
    montecarlo_metrics = {
        "position_mean": ("um", 1e-6, "mean position error over the workspace, aligned"),
        "position_max": ("um", 1e-6, "max position error over the workspace, aligned"),
        "orientation_mean": ("urad", 1e-6, "mean orientation error, aligned"),
        "orientation_max": ("urad", 1e-6, "max orientation error, aligned"),
    }
    montecarlo_evaluation_poses = 300
    montecarlo_poses = 150
    montecarlo_exact_data = True

    def montecarlo_minimum_poses(self, settings):
        # one equation per pose
        return len(settings.machine.parameters) - 6 + int(settings.estimate_lc)

    def check_montecarlo(self, settings, what):
        Lc = getattr(settings.machine, "constraint_link_length", None)
        if Lc is None:
            raise InputError(f"{getattr(settings.machine, 'source', 'the machine')}: "
                             "constraint_link: the machine has no constraint-link length; add "
                             "`constraint_link: {length: ...}` to the machine file")
        if not Lc - settings.lc_error > 0:
            raise InputError(f"{what['lc_error']}: the true link length "
                             f"{(Lc - settings.lc_error) * 1e3:.6g} mm is not positive")

    def montecarlo_run(self, run):
        """Maximum likelihood (Lc estimated with ``estimate_lc``) from encoder readings on the
        true link's sphere; pose accuracy over the SPEC 5 workspace, gauge-aligned."""
        s = run.settings
        nominal = s.machine
        true = run.true_machine()
        lc_true = nominal.constraint_link_length - s.lc_error
        true.constraint_link_length = lc_true
        noise = 2e-6 if s.noise is None else s.noise
        data = simulate_constraint_link(true, s.poses or self.montecarlo_poses, noise,
                                        link_length=lc_true, link_length_error=s.lc_error,
                                        rng=run.rng)
        res = calibrate_constraint_link(nominal, data, sigma_m=run.weight(noise),
                                        estimate_link_length=s.estimate_lc)
        return res, run.workspace_accuracy(true, res.machine,
                                           self.montecarlo_evaluation_poses)

    def candidates(self, machine, n, rng):

        P, R = sample_sphere_poses(machine, link_length(machine), n, rng)
        return P, R, None

    def standard_plan(self, machine, n, seed):
        P, R, _ = self.candidates(machine, n, np.random.default_rng(seed))
        return StandardPlan(f"{n} random planned poses on the constraint sphere (seed {seed})",
                            P, R)

    def planned_data(self, machine, P, R, rows, source, group=None):

        P = _on_sphere(P, machine, rows, source)
        q = reachable(machine, P, R, rows, source)
        return ConstraintLinkData(q, link_length(machine),
                                  np.arange(len(P)) % machine.n_joints, rows, source,
                                  true_P=P, true_R=R)

    report_sections = {"link_length": "a constraint-link report states the link length it used"}

    simulate_options = {"link_error": 0.0}
    simulate_options_words = "link_error: applies to the constraint-link scenario"

    def simulate(self, machine, true, n, noise, rng, truth, *, poses=None,
                 mounting_error=MOUNTING_ERROR, link_error=0.0):
        """:func:`simulate_constraint_link` on the sphere of the true link (the file's length
        minus ``link_error``); ``noise`` the encoder std (m, default 1 um; False: exact).
        See :meth:`Instrument.simulate <pkmcal.instruments.base.Instrument.simulate>`.

        Returns
        -------
        tuple
            ``(data, true, truth)``; ``truth`` with ``link_length``.
        """
        Lc = float(machine.constraint_link_length) - float(link_error)
        if not Lc > 0:
            raise InputError(f"link_error: the true link length {Lc * 1e3:.6g} mm is not "
                             "positive")
        true.constraint_link_length = Lc
        sigma = 1e-6 if noise is None else (0.0 if noise is False else float(noise))
        data = simulate_constraint_link(true, n, sigma, link_length=Lc,
                                        link_length_error=float(link_error), rng=rng)
        lc = machine.constraint_link_length
        rows = [("link", f"true length {Lc * 1e3:.6g} mm")]
        if abs(lc - Lc) > 0:
            rows.append(("Lc error", f"machine file says {lc * 1e3:.6g} mm, true link "
                         f"{Lc * 1e3:.6g} mm"))
        truth.update(link_length=Lc, poses=f"{n} poses on the true link's sphere |P| = "
                     f"{Lc * 1e3:.6g} mm", rows=rows)
        return data, true, truth

    simulate_flags = {"--lc-error": "--scenario constraint-link"}

    def simulate_arguments(self, machine, noise, lc_error="0", **flags):
        from ...plausibility import check_option_scale
        from ...units import parse_quantity

        text = "2um" if noise is None else noise
        noise_m = parse_quantity(text, "length", "--noise")
        if not noise_m >= 0:
            raise InputError(f"--noise: must be >= 0, got {text}")
        check_option_scale(noise_m, machine, "--noise", "noise", text)
        lc_error_m = check_option_scale(parse_quantity(lc_error, "length", "--lc-error"),
                                        machine, "--lc-error", "error", lc_error)
        lc = machine.constraint_link_length
        if not lc - lc_error_m > 0:
            raise InputError(f"--lc-error: the true link length {(lc - lc_error_m) * 1e3:.6g} "
                             "mm is not positive")
        return noise_m, f"encoder noise {noise_m * 1e6:.4g} um", {"link_error": lc_error_m}

    writer = "write_constraint_link"

    def calibration_summary(self, report):
        res, ident = report["residuals"], report["identifiability"]
        noise = res["estimated_noise_um"]
        rows = [("measurement", f"{report['measurement']}, {report['measurements']} poses"),
                ("method", {"ml": "ml (maximum likelihood, all readings noisy)",
                            "ik": "ik (paper 3.4.1, inverse kinematics of the passive chain)",
                            "fk": "fk (paper 3.4.2, spread of the link length)"}
                 [report["method"]]),
                *([("start", report["start"])] if "start" in report else []),
                "identifiable",
                ("RMS residual", f"{res['rms_um']:.4g} um ({res['of']}; assumed noise "
                 f"{report['noise_sigma_um']:.4g} um"
                 + (f", estimated {noise:.3g} um)" if noise is not None else ")")),
                # the link length: its section's row (ConstraintLinkSection.summary_rows)
                "held-out", "noise levels", "convergence", "sections"]
        if ident["unidentifiable"]:
            rows.append(("note", "note: the data do not fix the directions listed as not "
                         "identifiable; the changes are the smallest ones (scaled) that fit "
                         "the data, and std is for the identifiable part."))
        return rows

    def problem(self, machine, data, noise=None, **start):

        return ConstraintLinkML(machine, data, self.default_noise() if noise is None else noise)

    measurement_words = ("constraint link (maximum likelihood: every reading noisy; one pose on "
                         "the sphere per measurement)")

    def noise_arg(self, text, machine=None):
        """The encoder noise of ``--noise`` (default 1 um), m."""
        return _sigma_arg(text, machine, "the encoder noise", 1e-6)

    #: the io reader of its CSV files (:func:`pkmcal.io.read_measurements`)
    reader = "read_constraint_link"
    Options = ConstraintLinkOptions

    def check_options(self, options, source) -> None:
        """``--robust`` with ml alone (see
        :meth:`~pkmcal.instruments.base.Instrument.check_options`)."""
        _check_options(options, source)

    def calibrate(self, machine: Machine, data, context, options):
        """The geometry (and the link length with ``estimate_lc``) by ``method``, the joint
        readings' residuals before and after (see
        :meth:`~pkmcal.instruments.base.Instrument.calibrate`)."""
        return _calibration_flow(machine, data, context, options)


#: constraint-link plans: largest allowed deviation of |P| from Lc (m); poses within it are
#: put on the sphere (rounding in a hand-made plan file)
SPHERE_TOL = 1e-4


def link_length(machine: Machine) -> float:
    """The machine file's constraint-link length, m; InputError when it has none."""
    Lc = getattr(machine, "constraint_link_length", None)
    if Lc is None:
        raise InputError(f"{getattr(machine, 'source', 'the machine file')}: no "
                         "constraint_link length; constraint-link plans need it")
    return float(Lc)


def _on_sphere(P, machine, rows, source):
    """Constraint-link plan poses put exactly on ``|P| = Lc`` (refused beyond SPHERE_TOL)."""
    Lc = link_length(machine)
    norm = np.linalg.norm(P, axis=-1)
    off = ~(np.abs(norm - Lc) <= SPHERE_TOL)
    if off.any():
        raise InputError(f"{path_text(source)}: row(s) {_rows(rows[off])}: |P| differs from the "
                         f"constraint-link length {Lc * 1e3:.6g} mm by more than "
                         f"{SPHERE_TOL * 1e3:g} mm; a constraint-link plan has its poses on "
                         "that sphere")
    return P * (Lc / norm)[:, None]


#: this module's instrument (:data:`~pkmcal.instruments.registry.INSTRUMENT_MODULES`)
INSTRUMENT = ConstraintLink()


def constraint_link_reading_rms(machine, data, sigma_m: float, max_iter: int = 20) -> float:
    """RMS joint-reading residual (m) of ``machine``'s geometry on constraint-link ``data``.

    The poses on the link's sphere are fitted by maximum likelihood with the geometry and the
    link length (``data.link_length``) held: the residual a calibration would start from, or,
    for held-out data, the residual the calibrated geometry leaves on readings it never saw.

    Parameters
    ----------
    machine : HexaSlide
        The geometry to test (its current parameters are held).
    data : ConstraintLinkData
        Readings taken with the link mounted.
    sigma_m : float
        Encoder noise (m); it only scales the iterations, not the result.
    max_iter : int
        Gauss-Newton iterations for the poses.

    Returns
    -------
    float
        RMS over all readings (m); NaN when the poses cannot be fitted.
    """
    try:
        problem = ConstraintLinkML(machine.with_parameters(machine.u), data, sigma_m)
        problem.parameters = problem.parameters.with_fixed(list(problem.parameters.names))
        res = levenberg_marquardt(problem, max_iter=max_iter)
    except (InputError, ValueError, np.linalg.LinAlgError):
        return float("nan")
    r = np.asarray(res.residuals, float) * sigma_m
    return float(np.sqrt(np.mean(r**2))) if r.size and np.all(np.isfinite(r)) else float("nan")


# -- calibration flow (pkmcal calibrate) ------------------------------------------------------


def _check_options(options: ConstraintLinkOptions, source) -> None:
    """The constraint link's options that do not go together, refused naming them (an option
    it does not declare is refused by the calibration layer)."""
    if options.robust and options.method not in (None, "ml"):
        raise InputError(f"--robust: applies to the ml method (its residuals are the noise's); "
                         f"--method {options.method} takes some readings as exact")


def _calibration_flow(machine, data, context: FlowContext,
                      options: ConstraintLinkOptions) -> FlowResult:
    """``pkmcal calibrate`` from constraint-link readings (:meth:`ConstraintLink.calibrate`)."""

    source, split = context.source, context.split
    method = options.method or "ml"
    estimate_lc = options.estimate_lc
    sigma = link_noise_arg(options.noise, machine)
    kind = "constraint-link"
    data, held = split_rows(load_data(data, context.read, machine), split, source)

    result = solve(source, calibrate_constraint_link, machine, data, held=held,
                    method=method, sigma_m=sigma, estimate_link_length=estimate_lc,
                    estimate_noise=options.noise is None, robust=options.robust)
    require_converged(result, source)
    kw = {} if estimate_lc is None else {"estimate_link_length": estimate_lc}
    result.rebuild_problem = lambda: PROBLEMS[method](machine, data, sigma, **kw)

    units = context.units
    calibrated = result.machine
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    # FK start of the calibrated file: the input machine's home (a central pose of the working
    # assembly mode) rather than the first measured pose, which may sit at the workspace edge
    home_P, home_R = machine.home
    if np.all(np.isfinite(calibrated.ik(home_P, home_R))):
        calibrated.home = (home_P, home_R)
    nominal_of = dict(zip(machine.parameters.names, machine.u, strict=True))
    nominal_of["link.length"] = data.link_length
    params = parameter_table(result, nominal_of, units)
    r = np.asarray(result.residuals, float)
    if result.used is not None:             # the rows in the fit (not those left out)
        r = r[np.asarray(result.used, bool).reshape(len(r), -1).all(axis=-1)]
    r_m = r * sigma
    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.unidentifiable)
    section = ConstraintLinkSection.of(result)
    dropped = [int(v) for v in np.asarray(section.dropped_rows)]
    lc_estimated = bool(section.estimated)
    lc = float(section.link_length if section.link_length is not None else data.link_length)
    residual_what = {"ml": "all joint readings", "ik": "passive joint readings",
                     "fk": "computed link length |P| - Lc"}[method]
    report = {
        **context.head(machine, kind, method, units),
        "measurements": len(data),
        "dropped_rows": dropped,
        "noise_sigma_um": sigma * 1e6,
        **section.as_report(units),         # link_length
        "convergence": convergence_json(result),
        "residuals": {
            "of": residual_what,
            "count": int(r.size),
            "rms_um": float(np.sqrt(np.mean(r_m**2)) * 1e6) if r.size else None,
            "max_abs_um": float(np.max(np.abs(r_m)) * 1e6) if r.size else None,
            "rms_per_column_um": (np.sqrt(np.mean(r_m**2, axis=0)) * 1e6).tolist()
            if r.ndim == 2 and r.shape[1] > 1 else None,
            "before_rms_um": um(constraint_link_reading_rms(machine, data, sigma)),
            "before": "machine file's geometry, all readings, poses fitted (maximum "
                      "likelihood)",
            "residual_variance": float(result.residual_variance),
            "estimated_noise_um": float(np.sqrt(result.residual_variance) * sigma * 1e6)
            if np.isfinite(result.residual_variance) else None,
            "dof": int(result.dof),
        },
        "identifiability": identifiability_json(n_free, rank, unidentifiable, s),
        "parameters": public_parameters(params),
    }
    if section.start_from is not None:      # the paper's methods: where they started
        report["start"] = section.start_from
    if held is not None:
        report["validation"] = validation_section(
            split, held, "joint readings of the held-out rows (poses fitted, geometry and Lc "
            "held); before: the machine file's geometry", "um",
            um(constraint_link_reading_rms(machine, held, sigma)),
            um(constraint_link_reading_rms(calibrated, replace(held, link_length=lc),
                                            sigma)),
            report["residuals"]["rms_um"])
    metadata = {
        "method": method,
        "date": report["date"],
        "data": path_text(source),
        "machine": source_of(machine),
        "measurements": len(data),
        "rms_residual_um": report["residuals"]["rms_um"],
        "identifiable": rank,
        "free_parameters": n_free,
        **identifiability_metadata(unidentifiable),
        "link_length_estimated": lc_estimated,
    }
    calibration = FlowResult(kind, machine, calibrated, result, report, metadata, params, units)
    if section.warnings is not None:        # ml: the start strategy says what it left out
        calibration.warnings += [f"{path_text(source)}: "
                                 f"{text}" for text in section.warnings]
    elif dropped:
        calibration.warnings.append(
            f"{path_text(source)}: "
            f"{len(dropped)} row(s) left out (no pose from the five active readings "
            f"and the link with the start geometry): {rows_text(dropped)}")
    return calibration
