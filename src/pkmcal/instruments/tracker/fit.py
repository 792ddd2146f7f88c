"""Calibration from laser-tracker points (seed 001 eq. 12-15), jointly with the registration.

Any machine: the points instrument of :mod:`pkmcal.instruments`
(:class:`~pkmcal.instruments.PointsModel`) on the machine's forward kinematics. Unknowns: the
machine's parameters, the tracker pose ``base_from_tracker = (R, t)`` (``tracker.rx/ry/rz``:
rotation increments about the base axes, applied on the left of the closed-form start;
``tracker.x/y/z``: translation) and, unless the machine gives it (a Delta's ``smr_offset``),
the place ``c_k`` of every target on the platform (``target<k>.x/y/z``). Residual of point i,
whitened with the tracker's anisotropic noise (:class:`~pkmcal.instruments.tracker.TrackerNoise`)::

    e_i = W_i (m_i - R^T (P(q_i; u) + R_p(q_i; u) c_k - t))

Seed 001 registers first (with the nominal model) and then identifies the errors with the
registration fixed (``joint=False`` reproduces that); ``joint=True`` (default) estimates both
together, which removes the bias the nominal model leaves in the registration.

Identifiability is found from the data and named by the machine's frame motions: on the Delta
(SPEC 2.2) ``da`` and ``db`` enter only as ``db - da`` (9 directions) and a translation of the
platform frame is absorbed by the tracker frame (3): 21 of 33; on a platform that rotates a
rigid motion of the base frame is absorbed by the tracker frame and one of the platform frame
by the targets (12).

Laser-tracker measurements of a reflector (SMR) on the platform (seed 001 section 3).

The tracker measures the SMR centre, ``h_M`` below the platform point, in its own frame:
``m = R^T (p + (0, 0, -h_M) - t)`` with ``(R, t)`` = base_from_tracker (a base vector
``x_base = R m + t``). One measurement = the actuator readings and the measured point.

Noise model (documented, Leica-type): the maximum permissible error (MPE) is
``+/-(15 um + 6 um/m * range)`` transverse to the beam and ``+/-10 um`` along it; the typical
error is about half the MPE, so the standard deviations are half these values. The noise is
anisotropic: each point has its own 3x3 covariance in the tracker frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ...errors import InputError
from ...estimation.acceptance import FAILED_ALARMING, report_verdict
from ...estimation.estimator import (
    MAX_STD,
    CalibrationResult,
    levenberg_marquardt,
    require_redundancy,
)
from ...estimation.rank import RTOL
from ...estimation.sections import Section
from ...estimation.variance import OUTLIER_ALPHA, fit
from ...identifiability import name_null_space, name_weak_directions
from ...kinematics import matrix_from_rotvec
from ...machines.base import Machine
from ...machines.delta import TRACKER_GRID_SPACING  # noqa: F401  (seed 001's grid)
from ...machines.file_format import TrackerSection as TrackerFileSection
from ...machines.file_format import file_rotation, frame_section, vector
from ...paths import path_text
from ...units import format_um
from ..base import Instrument, StandardPlan, _check_groups, _fk_of, has_column, reachable
from ..data import InstrumentData
from ..experiment import MOUNTING_ERROR
from ..flow import (
    FlowContext,
    FlowResult,
    JointPart,
    convergence_json,
    identifiability_json,
    identifiability_metadata,
    load_data,
    option,
    parameter_table,
    public_parameters,
    require_converged,
    rows_text,
    solve,
    source_of,
    split_rows,
    validation_section,
    variance_json,
)
from ..models import NuisanceState, PointsModel
from ..problem import InstrumentProblem, InstrumentState
from ..setups import run_setup


@dataclass(frozen=True)
class TrackerNoise:
    """Standard deviations of a laser tracker (half the MPE by default), SI units.

    Attributes
    ----------
    distance : float, optional
        Along the beam, m.
    transverse : float, optional
        Across the beam, constant part, m.
    transverse_per_m : float, optional
        Across the beam, per metre of range (m/m).
    """

    distance: float = 5e-6            # along the beam
    transverse: float = 7.5e-6        # across the beam, constant part
    transverse_per_m: float = 3e-6    # across the beam, per metre of range

    def _beam(self, m):
        """Beam directions ``r`` (K, 3; +z at the tracker's origin, where there is none), the
        projector on them ``rr`` (K, 3, 3) and the transverse std ``st`` (K,)."""
        m = np.asarray(m, float)
        rng = np.linalg.norm(m, axis=-1)
        r = np.where(rng[..., None] > 0, m / np.where(rng > 0, rng, 1.0)[..., None],
                     np.array([0.0, 0.0, 1.0]))
        return (r, r[..., :, None] * r[..., None, :],
                self.transverse + self.transverse_per_m * rng)

    def covariance(self, m):
        """Per-point covariance in the tracker frame.

        Parameters
        ----------
        m : array_like, shape (K, 3)
            Tracker points, m, tracker frame.

        Returns
        -------
        ndarray, shape (K, 3, 3)
            Covariance of each point, m^2.
        """
        _, rr, st = self._beam(m)
        return self.distance**2 * rr + (st**2)[..., None, None] * (np.eye(3) - rr)

    def whitening(self, m):
        """Whitening matrices ``W`` with ``W^T W = Cov^-1``, rows along the beam first.

        Row 0 is along the beam (``r / s_d``), rows 1-2 across it (two unit vectors normal
        to the beam, ``/ s_t``, range-dependent): each whitened residual component belongs to
        one noise group (:meth:`groups`).

        Parameters
        ----------
        m : array_like, shape (K, 3)
            Tracker points, m, tracker frame.

        Returns
        -------
        ndarray, shape (K, 3, 3)
            Whitening matrix of each point, 1/m.
        """
        r, _, st = self._beam(m)
        # a vector normal to the beam: the axis least aligned with it, projected
        axis = np.eye(3)[np.argmin(np.abs(r), axis=-1)]
        t1 = axis - np.sum(axis * r, -1)[..., None] * r
        t1 /= np.linalg.norm(t1, axis=-1)[..., None]
        t2 = np.cross(r, t1)
        return np.stack([r / self.distance, t1 / st[..., None], t2 / st[..., None]], -2)

    def groups(self, m):
        """Noise groups of the whitened components (:meth:`whitening`'s rows).

        Parameters
        ----------
        m : array_like, shape (K, 3)
            Tracker points, m, tracker frame.

        Returns
        -------
        labels : ndarray of int, shape (K, 3)
            0 along the beam, 1 across it.
        keys, names : list of str
            The groups.
        assumed : ndarray, shape (2,)
            Along the beam, and the RMS across it over the points, m.
        kinds : list of str
            Both ``"length"``.
        """
        _, _, st = self._beam(m)
        K = len(np.asarray(m))
        across = float(np.sqrt(np.mean(st**2))) if K else self.transverse
        return (np.tile([0, 1, 1], (K, 1)), ["along", "across"],
                ["tracker along the beam", "tracker across the beam"],
                np.array([self.distance, across]), ["length", "length"])

    def sample(self, m, rng):
        """Noise vectors for tracker points, drawn from :meth:`covariance`.

        Parameters
        ----------
        m : array_like, shape (K, 3)
            Tracker points, m, tracker frame.
        rng : numpy.random.Generator
            Random generator.

        Returns
        -------
        ndarray, shape (K, 3)
            Noise to add to the points, m.
        """
        m = np.asarray(m, float)
        L = np.linalg.cholesky(self.covariance(m))
        return np.einsum("kij,kj->ki", L, rng.standard_normal(m.shape))


@dataclass
class TrackerData:
    """Actuator readings and tracker points.

    Attributes
    ----------
    q : ndarray, shape (K, n_joints)
        Joint readings, rad.
    m : ndarray, shape (K, 3)
        SMR positions in the tracker frame, m.
    rows : ndarray of int, shape (K,), optional
        File row numbers for messages; default 1..K.
    source : str, optional
        File name, for messages.
    true_P : ndarray, shape (K, 3), optional
        Simulated platform positions (base frame), m; None for real data.
    outliers : ndarray of bool, shape (K,), optional
        Rows a simulation corrupted on purpose; None for real data.
    target : ndarray of int, shape (K,), optional
        0-based target (reflector nest) of each row when there are several; None: one.
    """

    q: np.ndarray
    m: np.ndarray
    rows: np.ndarray | None = None
    source: str = "<data>"
    true_P: np.ndarray | None = None
    outliers: np.ndarray | None = None
    target: np.ndarray | None = None

    def __post_init__(self):
        self.q = np.atleast_2d(np.asarray(self.q, float))
        self.m = np.atleast_2d(np.asarray(self.m, float))
        if self.target is not None:
            self.target = np.asarray(self.target, int)
        if self.rows is None:
            self.rows = np.arange(1, len(self.q) + 1)

    def __len__(self) -> int:
        return len(self.q)

    def subset(self, mask) -> TrackerData:
        """The measurements selected by a boolean mask or index array.

        Parameters
        ----------
        mask : array_like of bool or int
            Boolean mask (K,) or indices of the rows to keep.

        Returns
        -------
        TrackerData
            The selected rows, same source.
        """
        def pick(a):
            return None if a is None else a[mask]

        return TrackerData(self.q[mask], self.m[mask], self.rows[mask], self.source,
                           pick(self.true_P), pick(self.outliers), pick(self.target))


#: where simulations put the tracker in the base frame (m): 2.5 m from the robot's axis, on
#: the floor 1.4 m below the base plane
TRACKER_POSITION = (2.0, -1.5, -1.4)
#: its tilt about its own y axis (rad)
TRACKER_TILT = np.deg2rad(1.0)


@dataclass(frozen=True)
class TrackerSetup:
    """A tracker's set-up (the machine file's ``tracker:`` section): its frame and the
    places of its targets on the platform.

    Attributes
    ----------
    base_from_tracker : tuple of ndarray
        ``(R (3, 3), t (3,))``: a tracker point ``m`` is ``R m + t`` in the base frame, m.
    targets : ndarray, shape (K, 3) or None
        Places of targets 1..K on the platform (platform frame), m; None: one target at the
        platform origin, or the machine's own (a Delta's reflector, ``smr_offset``).
    """

    base_from_tracker: tuple
    targets: np.ndarray | None = None

    def shifted(self, t) -> TrackerSetup:
        """The set-up seen from a base frame whose points moved by ``t`` (m)."""
        R, a = self.base_from_tracker
        return TrackerSetup((R, np.asarray(a, float) + np.asarray(t, float)), self.targets)

    def frame_shift(self, machine):
        """None: a tracker says nothing about the machine's frame."""
        return None

    def targets_in_base(self, machine, P):
        """``P`` itself: targets are not given relative to a tracker's set-up."""
        return P


def default_tracker_pose() -> tuple[np.ndarray, np.ndarray]:
    """The true ``base_from_tracker = (R, t)`` of simulations without a tracker in the machine file.

    The tracker stands at :data:`TRACKER_POSITION` (2.5 m from the robot's axis), its x axis
    turned about Z toward the robot's axis (143.13 deg) and tilted by :data:`TRACKER_TILT`
    (1 deg) about its y axis.

    Returns
    -------
    R : ndarray, shape (3, 3)
        Orientation of the tracker frame in the base frame.
    t : ndarray, shape (3,)
        Tracker origin in the base frame, m.
    """
    t = np.array(TRACKER_POSITION, float)
    yaw = np.arctan2(-t[1], -t[0])
    R = matrix_from_rotvec([0.0, 0.0, yaw]) @ matrix_from_rotvec([0.0, TRACKER_TILT, 0.0])
    return R, t


def grid_points(center, spacing=TRACKER_GRID_SPACING, shape=(3, 3, 3)):
    """Points of a regular grid (seed 001: 3x3x3, dx = dy = 150 mm, dz = 40 mm).

    Parameters
    ----------
    center : array_like, shape (3,)
        Centre of the grid, m.
    spacing : tuple of float, optional
        Distance between neighbouring points along x, y, z, m.
    shape : tuple of int, optional
        Number of points along x, y, z.

    Returns
    -------
    ndarray, shape (N, 3)
        The points, m, x slowest and z fastest (``N = prod(shape)``).
    """
    axes = [(np.arange(n) - (n - 1) / 2) * d for n, d in zip(shape, spacing, strict=True)]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    return np.asarray(center, float) + np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])


def neighbour_pairs(shape=(3, 3, 3)):
    """Index pairs of grid points that are neighbours along one axis (for distance ratios).

    Parameters
    ----------
    shape : tuple of int, optional
        Grid shape, as in :func:`grid_points`.

    Returns
    -------
    ndarray of int, shape (M, 2)
        Indices into the rows of :func:`grid_points`, pairs along x, then y, then z.
    """
    idx = np.arange(int(np.prod(shape))).reshape(shape)
    pairs = []
    for axis in range(3):
        a = np.moveaxis(idx, axis, 0)
        pairs.append(np.stack([a[:-1].ravel(), a[1:].ravel()], -1))
    return np.concatenate(pairs)


def simulate_tracker(true_machine: Machine, nominal_machine: Machine, targets,
                     base_from_tracker, noise: TrackerNoise | None = TrackerNoise(),
                     outliers: int = 0, outlier_size: float = 1e-3, rng=None) -> TrackerData:
    """The experiment of seed 001: command points with the nominal model, measure the true machine.

    The *nominal* model commands ``targets``, the *true* machine goes elsewhere, and the
    tracker measures the SMR there (``smr_offset`` below the platform point), with noise.
    ``outliers`` random rows get an extra error of ``outlier_size`` in a random direction (beam
    breaks, a mis-seated SMR); they are flagged in ``outliers``.

    Parameters
    ----------
    true_machine : Delta
        The true machine (needs ``smr_offset``).
    nominal_machine : Delta
        The model that computes the commands.
    targets : array_like, shape (N, 3)
        Commanded platform positions, m, base frame.
    base_from_tracker : tuple of array_like
        ``(R (3, 3), t (3,))``: a tracker point ``m`` is ``R m + t`` in the base frame.
    noise : TrackerNoise or None, optional
        Tracker noise; None for exact points.
    outliers : int, optional
        Number of rows to corrupt.
    outlier_size : float, optional
        Size of the outlier error, m.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.

    Returns
    -------
    TrackerData
        Commanded joints, measured points, the true positions and the outlier flags.

    Raises
    ------
    InputError
        When a target is outside the nominal workspace or the true machine cannot reach a
        commanded point.
    """
    rng = np.random.default_rng(rng)
    q = nominal_machine.ik(np.asarray(targets, float))
    if not np.all(np.isfinite(q)):
        bad = np.flatnonzero(~np.all(np.isfinite(q), -1)) + 1
        raise InputError(f"targets {bad.tolist()} are outside the nominal workspace")
    fk = true_machine.fk(q)
    if not fk.converged.all():
        raise InputError("the true machine cannot reach some commanded points")
    R, t = base_from_tracker
    smr = fk.P - np.array([0.0, 0.0, true_machine.smr_offset])
    m = (smr - t) @ np.asarray(R)            # R^T (x - t) for each row
    if noise is not None:
        m = m + noise.sample(m, rng)
    flagged = np.zeros(len(m), bool)
    if outliers:
        flagged[rng.choice(len(m), size=outliers, replace=False)] = True
        d = rng.standard_normal((outliers, 3))
        m[flagged] += outlier_size * d / np.linalg.norm(d, axis=-1, keepdims=True)
    return TrackerData(q, m, source="<simulated>", true_P=fk.P, outliers=flagged)


TRACKER = ("tracker.rx", "tracker.ry", "tracker.rz", "tracker.x", "tracker.y", "tracker.z")


class TrackerProblem(InstrumentProblem):
    """The points instrument (:class:`~pkmcal.instruments.PointsModel`) on a machine, started
    from a registration: the block problem of tracker calibration.

    Global unknowns: the machine's parameters, ``tracker.rx/ry/rz/x/y/z`` (rotation increments
    about the base axes from the start registration, and the translation) and, unless the
    machine gives it (:meth:`~pkmcal.machines.Machine.tracker_target`, a Delta's
    ``smr_offset``), the place of each target on the platform, ``target<k>.x/y/z``.

    Parameters
    ----------
    machine : Machine
        Start geometry.
    data : TrackerData
        Actuator readings and tracker points (``target``: 0-based target of each row).
    noise : TrackerNoise or None
        Whitens the residuals; None: unit weights (to differentiate predictions, not to fit).
    registration : tuple of ndarray
        Start ``base_from_tracker = (R (3, 3), t (3,))``.
    joint : bool, optional
        Estimate the tracker pose together with the errors; False holds it at
        ``registration`` (seed 001's two-step method).
    targets : array_like, shape (n_targets, 3), optional
        Start places of the targets on the platform (m); default the machine's, else 0.

    Raises
    ------
    InputError
        When the machine's forward kinematics cannot reproduce some readings.
    """

    def __init__(self, machine: Machine, data: TrackerData, noise: TrackerNoise | None,
                 registration, joint: bool = True, targets=None):
        idata = as_points(data)
        model = PointsModel(idata.n_groups, machine.tracker_target(), fix_frame=not joint)
        R0, t0 = (np.asarray(v, float) for v in registration)
        values = np.array(model.parameters.values, float)
        values[3:6] = t0
        if targets is not None and machine.tracker_target() is None:
            values[6:] = np.asarray(targets, float).reshape(-1)
        model.parameters = model.parameters.with_values(values)
        model.rotation_starts = [R0]
        model.m0 = idata.values.mean(0) if len(idata) else np.zeros(3)
        super().__init__(machine, idata, model, noise)
        self.R0, self.t0 = R0, t0

    def predict(self, state, q=None):
        """Predicted tracker points, and the forward kinematics behind them.

        Parameters
        ----------
        state : InstrumentState
            Machine parameters and tracker pose.
        q : array_like, shape (K, n_joints), optional
            Actuator readings, rad; default: the data's (and their targets).

        Returns
        -------
        m : ndarray, shape (K, 3)
            Predicted points in the tracker frame, m (NaN where the FK failed).
        fk : FKResult
            Forward kinematics of the readings.
        """
        fk = self.poses(state, q)
        group = self.data.group if q is None else np.zeros(len(fk.P), int)
        m = self.model.predict(state.nuisance, fk.P, fk.R, group)
        return np.where(fk.converged[:, None], m, np.nan), fk


def as_points(data) -> InstrumentData:
    """Tracker data as the points instrument's data (``target`` kept as the group)."""
    if isinstance(data, InstrumentData):
        return data
    return InstrumentData("points", data.q, data.m, getattr(data, "target", None), data.rows,
                          data.source, data.true_P)


def registration_of(state) -> tuple[np.ndarray, np.ndarray]:
    """``base_from_tracker = (R, t)`` of a tracker problem's state."""
    v = state.nuisance.values
    return state.nuisance.rotations[0], np.array(v[3:6], float)


@dataclass
class TrackerSection(Section):
    """What a tracker calibration adds to its result (``result.sections["tracker"]``): the
    registration (``base_from_tracker``, estimated or held) and the targets' places on the
    platform, each with its start, and the rows left out.

    Attributes
    ----------
    registration, start_registration : tuple of (ndarray (3, 3), ndarray (3,))
        ``(R, t)`` of ``base_from_tracker``, m: identified and at the start (closed form with
        the nominal model).
    targets, start_targets : ndarray, shape (n, 3)
        The targets' places on the platform (platform frame), m.
    kept : ndarray of bool
        The rows used (not left out as outliers).
    outlier_rows : ndarray of int
        The file rows left out.
    estimated : bool
        Whether the registration was estimated with the legs (joint method).
    targets_given : bool
        Whether the machine file gives the target (the reflector below the platform point).
    """

    instrument: ClassVar[str] = "tracker"
    title: ClassVar[str] = "registration"

    registration: tuple
    start_registration: tuple
    targets: np.ndarray
    start_targets: np.ndarray
    kept: np.ndarray
    outlier_rows: np.ndarray
    estimated: bool = True
    targets_given: bool = False

    def as_report(self, units=None) -> dict:
        from ...units import LENGTH

        unit = (units or {}).get("length", "mm")
        fl = LENGTH[unit]
        (R, t), (R0, t0) = self.registration, self.start_registration
        R, R0 = np.asarray(R, float), np.asarray(R0, float)
        return {
            "targets": {"given_by_machine_file": bool(self.targets_given), "unit": unit,
                        "places": (np.asarray(self.targets, float) / fl).tolist(),
                        "what": "target places on the platform (platform frame)"},
            "registration": {
                "estimated": bool(self.estimated),
                "rotation": R.tolist(), "translation": (np.asarray(t) / fl).tolist(),
                "unit": unit,
                "start": {"rotation": R0.tolist(),
                          "translation": (np.asarray(t0) / fl).tolist(),
                          "method": "closed form (SVD) with the nominal model"},
                "rotation_change_deg": float(np.degrees(np.linalg.norm(_rotvec(R @ R0.T)))),
                "translation_change": float(np.linalg.norm(np.asarray(t) - t0) / fl),
            },
        }

    def summary_rows(self, units=None) -> list:
        from ...units import LENGTH

        unit = (units or {}).get("length", "mm")
        fl = LENGTH[unit]
        rep = self.as_report(units)["registration"]
        t = ", ".join(f"{v:.6g}" for v in np.asarray(self.registration[1]) / fl)
        return [("tracker frame", ("estimated" if self.estimated else "held (two-step)")
                 + f": origin at ({t}) {unit}, turned {rep['rotation_change_deg']:.4g} deg "
                 f"and moved {rep['translation_change']:.4g} {unit} from the closed-form start"),
                ("targets", f"{len(self.targets)} place(s) on the platform"
                 + (" (machine file)" if self.targets_given else " (estimated)"))]


def calibrate_tracker(machine: Machine, data: TrackerData, noise: TrackerNoise | None = None,
                      joint: bool = True, robust: bool = False,
                      outlier_alpha: float = OUTLIER_ALPHA, estimate_noise=True,
                      rtol: float = RTOL, **options) -> CalibrationResult:
    """Identify the error parameters (and the tracker pose) from tracker points.

    The registration starts from the closed form on the nominal model (>= 4 points, not
    collinear). The noise levels along and across the beam are estimated from the residuals
    (:func:`~pkmcal.estimation.variance.fit`; the given or default ``noise`` is their prior)
    and rows the noise cannot explain are named; ``robust=True`` leaves them out.

    Parameters
    ----------
    machine : Delta
        Start geometry; not modified.
    data : TrackerData
        Actuator readings and tracker points.
    noise : TrackerNoise, optional
        Tracker noise (default values when None).
    joint : bool, optional
        Estimate the tracker pose together with the errors (default); False: seed 001's
        two-step method, registration fixed.
    robust : bool, optional
        Leave out the rows the outlier test names, and fit again until none is named.
    outlier_alpha : float, optional
        False-alarm rate of the outlier test over all rows.
    estimate_noise : bool or collection of str, optional
        True: estimate the levels along and across the beam; False: hold ``noise`` (the
        covariance is scaled by the residual variance); or the keys to hold.
    rtol : float, optional
        Rank tolerance of :func:`levenberg_marquardt`.
    **options
        Passed to :func:`levenberg_marquardt` (``xtol``, ``ftol``, ``max_iter``, ``max_std``;
        ``max_std`` defaults to :data:`MAX_STD`).

    Returns
    -------
    CalibrationResult
        With ``problem``; ``method`` (``"tracker-joint"`` or ``"tracker-two-step"``);
        ``machine``, the calibrated machine with ``base_from_tracker``; ``unidentifiable``;
        ``noise`` and ``outliers`` (:func:`~pkmcal.estimation.variance.fit`); its
        :class:`TrackerSection` (registration, targets, rows kept).

    Raises
    ------
    InputError
        When the model cannot reproduce some readings, the points cannot be registered, or
        there are fewer equations than identifiable parameters.
    """
    noise = TrackerNoise() if noise is None else noise
    fk = machine.fk(data.q)
    if not fk.converged.all():
        rows = data.rows[~fk.converged].tolist()
        raise InputError(f"{path_text(data.source)}: "
                         f"rows {rows[:10]}: no platform position reproduces "
                         "these actuator readings")
    idata = as_points(data)
    start_model = PointsModel(idata.n_groups, machine.tracker_target()).start(
        fk.P, fk.R, idata.values, idata.group, data.source)
    registration = (start_model.rotation_starts[0], start_model.parameters.values[3:6].copy())
    targets = None
    if machine.tracker_target() is None:
        # the targets' places are unknown: fit them with the frame on the start geometry
        # first (the closed-form registration puts them at the platform origin)
        alone = TrackerProblem(machine, data, noise, registration, True).with_machine_fixed()
        first = levenberg_marquardt(alone, rtol=rtol, **{"max_std": MAX_STD, **options})
        registration = registration_of(first.state)
        targets = first.state.nuisance.values[6:].copy()
    problem = TrackerProblem(machine, data, noise, registration, joint, targets)
    n_id = int(problem.parameters.free.sum()) - (12 if joint else 9)
    require_redundancy(data.source, f"{len(data)} points", 3 * len(data), n_id,
                       "measure more points spread over the workspace")
    # the two-step method holds a registration of the nominal model: its residuals exceed the
    # noise by design, they cannot tell its level
    result = fit(problem, estimate_noise if joint else False, robust=robust,
                 alpha=outlier_alpha, rtol=rtol, **{"max_std": MAX_STD, **options})
    test = result.outliers
    keep = test.kept if test is not None else np.ones(len(data), bool)
    state = result.state
    calibrated = machine.with_parameters(state.u)
    calibrated.base_from_tracker = registration_of(state)
    result.problem, result.machine = problem, calibrated
    result.method = "tracker-joint" if joint else "tracker-two-step"
    result.add_section(TrackerSection(
        registration=registration_of(state), start_registration=registration,
        targets=problem.model.targets(state.nuisance).copy(),
        start_targets=(problem.model.targets(problem.model.initial()).copy()),
        kept=keep, outlier_rows=data.rows[~keep], estimated=bool(joint),
        targets_given=machine.tracker_target() is not None))
    result.unidentifiable = (
        name_null_space(result.null_space, problem.parameters,
                        problem.null_groups(state, result.scales, result.null_space))
        + name_weak_directions(result, problem.parameters))
    return result


def predict_tracker_points(machine: Machine, q, base_from_tracker, targets=None, target=None):
    """Tracker-frame target points predicted by a model for actuator readings.

    Parameters
    ----------
    machine : Machine
        The model (its :meth:`~pkmcal.machines.Machine.tracker_target`, a Delta's
        ``smr_offset``, when it gives one).
    q : array_like, shape (K, n_joints)
        Actuator readings, rad.
    base_from_tracker : tuple of array_like
        ``(R (3, 3), t (3,))``: a tracker point ``m`` is ``R m + t`` in the base frame.
    targets : array_like, shape (n_targets, 3), optional
        Places of the targets on the platform (m) when the machine gives none (a calibration's
        :attr:`TrackerSection.targets`); default the platform origin.
    target : array_like of int, shape (K,), optional
        0-based target of each row; default 0.

    Returns
    -------
    ndarray, shape (K, 3)
        Predicted points, m, tracker frame (NaN where the forward kinematics fail).
    """
    R, t = base_from_tracker
    fk = machine.fk(q)
    c = machine.tracker_target()
    if c is None:
        c = np.zeros(3) if targets is None else np.asarray(targets, float).reshape(-1, 3)
    c = np.asarray(c, float)
    if c.ndim == 2:
        c = c[np.zeros(len(fk.P), int) if target is None else np.asarray(target, int)]
    c = np.broadcast_to(c, fk.P.shape)
    x = fk.P + np.einsum("kij,kj->ki", fk.R, c)
    return (x - t) @ R


def distance_ratios(machine: Machine, q, m, pairs, targets=None, target=None):
    """Seed 001 Fig. 6: model distance / tracker distance x 100 % for point pairs (frame-free).

    The model's distance is between the target points the readings put in the base frame
    (the platform point on a Delta; ``P + R c`` with the targets' places ``c`` otherwise).

    Parameters
    ----------
    machine : Machine
        The model.
    q : array_like, shape (K, n_joints)
        Actuator readings.
    m : ndarray, shape (K, 3)
        Measured tracker points, m.
    pairs : ndarray of int, shape (M, 2)
        Row index pairs (e.g. :func:`~pkmcal.instruments.tracker.neighbour_pairs`).
    targets : array_like, shape (n_targets, 3), optional
        Places of the targets on the platform when the machine gives none, m.
    target : array_like of int, shape (K,), optional
        0-based target of each row.

    Returns
    -------
    ndarray, shape (M,)
        Ratios in percent (100 = distances agree).
    """
    x = predict_tracker_points(machine, q, (np.eye(3), np.zeros(3)), targets, target)
    d_model = np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=-1)
    d_meas = np.linalg.norm(m[pairs[:, 0]] - m[pairs[:, 1]], axis=-1)
    return 100.0 * d_model / d_meas


def prediction_covariance(result: CalibrationResult, q):
    """Covariance of the tracker points a calibrated model predicts for readings ``q``.

    ``J C J^T`` with ``C`` the estimate's covariance (first order; the Cramér-Rao prediction
    when ``C`` is at the truth with exact noise). Gauge-free: the unidentifiable directions
    change no prediction.

    Parameters
    ----------
    result : CalibrationResult
        Result of :func:`calibrate_tracker` (uses ``problem``, ``state`` and
        ``covariance``).
    q : array_like, shape (K, n_joints) or (n_joints,)
        Actuator readings, rad.

    Returns
    -------
    ndarray, shape (K, 3, 3)
        Covariance of each predicted point, m^2, tracker frame.

    Raises
    ------
    InputError
        When the model cannot reproduce some readings.
    """
    problem = result.problem
    q = np.atleast_2d(q)
    pseudo = InstrumentData("points", q, np.zeros((len(q), 3)))
    unit = InstrumentProblem(problem.machine, pseudo, problem.model, None)
    start = unit.initial_state()
    state = InstrumentState(result.state.u, result.state.nuisance, start.P, start.R)
    _, J, _ = unit.evaluate(state)                           # = -d(prediction)/dx
    return np.einsum("kin,nm,kjm->kij", J, result.covariance, J)


def tracker_noise_arg(text: str | None, allow_none: bool, machine=None):
    """The tracker noise model of ``--noise``: leica (default), none, or a length.

    Parameters
    ----------
    text : str or None
        ``leica`` or None (the default model), ``none``, or a length for isotropic noise.
    allow_none : bool
        Whether ``none`` (exact points, a simulation) is allowed.
    machine : Machine, optional
        The length is checked against its size when given.

    Returns
    -------
    tuple
        ``(TrackerNoise or None, description)``.

    Raises
    ------
    InputError
        When the text is not a noise model allowed here.
    """
    from ...plausibility import check_option_scale
    from ...units import parse_quantity

    if text is None or text.strip().lower() == "leica":
        return TrackerNoise(), "leica (5 um along the beam, 7.5 um + 3 um/m across)"
    if text.strip().lower() == "none":
        if not allow_none:
            raise InputError("--noise none: the calibration weighs the points by their noise; "
                             "give leica or a length such as 10um")
        return None, "none"
    sigma = parse_quantity(text, "length", "--noise")
    if sigma == 0 and allow_none:
        return None, "none"
    if not sigma > 0:
        raise InputError(f"--noise: must be > 0 (a standard deviation), leica or none; got "
                         f"{text}")
    if machine is not None:
        check_option_scale(sigma, machine, "--noise", "noise", text)
    return TrackerNoise(sigma, sigma, 0.0), f"isotropic {sigma * 1e6:.4g} um"


def _tracker_noise_text(model) -> str:
    """Words of a :class:`~pkmcal.instruments.tracker.TrackerNoise` given as an object."""

    if model == TrackerNoise():
        return tracker_noise_arg(None, allow_none=False)[1]
    if model.distance == model.transverse and model.transverse_per_m == 0:
        return f"isotropic {model.distance * 1e6:.4g} um"
    return (f"{model.distance * 1e6:.4g} um along the beam, {model.transverse * 1e6:.4g} um + "
            f"{model.transverse_per_m * 1e6:.4g} um/m across")


def tracker_pose(setup: TrackerSetup | None = None):
    """``base_from_tracker`` of the machine file's tracker set-up, else the simulations'
    default.

    Parameters
    ----------
    setup : TrackerSetup, optional
        The tracker's set-up of the machine file (None: none).

    Returns
    -------
    tuple of ndarray
        ``(R (3, 3), t (3,))``.
    """
    return default_tracker_pose() if setup is None else setup.base_from_tracker


#: where plans and simulations put an unknown target on the platform (platform frame, in
#: characteristic lengths): off the platform origin, as a reflector nest on a tool would be
TARGET_OFFSET = np.array([0.1, -0.05, -0.15])


def plan_target(machine: Machine) -> np.ndarray:
    """The target's place on the platform for plans: the machine's, else an offset one."""
    c = machine.tracker_target()
    return TARGET_OFFSET * machine.characteristic_length() if c is None else c


def planned_targets(machine: Machine, n_targets: int = 1) -> np.ndarray:
    """Planned places of ``n_targets`` tracker targets (reflector nests) on the platform.

    The machine's own target when its file gives one (a Delta's ``smr_offset``; then only one
    target makes sense); else target 1 at
    :func:`plan_target` and the others turned about the platform
    z axis by ``360 deg g / n_targets``.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    n_targets : int, optional
        Number of targets (>= 1).

    Returns
    -------
    ndarray, shape (n_targets, 3)
        Places in the platform frame, m.

    Raises
    ------
    InputError
        When ``n_targets < 1``, or several targets are asked for on a machine whose file
        gives the target's place.
    """
    n_targets = int(n_targets)
    if n_targets < 1:
        raise InputError(f"the number of targets must be >= 1, got {n_targets}")
    known = machine.tracker_target()
    if known is not None:
        if n_targets > 1:
            raise InputError(f"{getattr(machine, 'source', None) or 'the machine file'} gives "
                             "the target's place on the platform (e.g. a Delta's "
                             "smr_offset): one target only")
        return np.asarray(known, float)[None, :]
    c = plan_target(machine)
    t = 2 * np.pi * np.arange(n_targets) / n_targets
    return np.column_stack([np.cos(t) * c[0] - np.sin(t) * c[1],
                            np.sin(t) * c[0] + np.cos(t) * c[1], np.full(n_targets, c[2])])


def tracker_targets(machine: Machine, setup=None) -> tuple[np.ndarray, bool]:
    """Places of the tracker's targets on the platform, and whether they are one for all.

    Parameters
    ----------
    machine : Machine
        The machine: its :meth:`~pkmcal.machines.Machine.tracker_target` (a Delta's
        reflector, the same for every target number), else the set-up's ``targets``, else
        the platform origin.
    setup : TrackerSetup, optional
        The tracker's set-up (None: none).

    Returns
    -------
    targets : ndarray, shape (K, 3)
        Platform-frame places, m.
    shared : bool
        True when every target number is the same place (the machine file fixes it).
    """
    known = machine.tracker_target()
    if known is not None:
        return np.asarray(known, float).reshape(1, 3), True
    targets = None if setup is None else setup.targets
    if targets is None:
        return np.zeros((1, 3)), False
    return np.asarray(targets, float).reshape(-1, 3), False


def _point_errors(measured, exact) -> dict:
    """Mean and max distance between predicted and exact tracker points (NaN where a
    prediction failed; NaN metrics when all did)."""
    e = np.linalg.norm(measured - exact, axis=-1)
    ok = np.isfinite(e)
    return {"position_mean": float(np.mean(e[ok])) if ok.any() else math.nan,
            "position_max": float(np.max(e[ok])) if ok.any() else math.nan}


@dataclass(frozen=True, slots=True)
class TrackerOptions:
    """The options of the tracker's calibration flow (:meth:`Tracker.calibrate`)."""

    noise: object = option(
        None, "--noise", "leica (default) or a length for isotropic noise (e.g. 10um); held "
        "as given (a TrackerNoise too), else the levels are estimated from the residuals.")
    two_step: bool = option(
        False, "--two-step", "The paper's method, registration first (closed form with the "
        "nominal model) and then the errors with the registration fixed. Default: errors and "
        "registration together.")
    robust: bool = option(
        False, "--robust", "Leave out the rows the noise cannot explain (a chi-square test of "
        "each row) and fit again.")


class Tracker(Instrument):
    """Points of a target on the platform in the instrument's frame (seed 001's tracker)."""

    name = "tracker"
    aliases = ("points",)
    words = "a target on the platform measured in the instrument frame (laser tracker, CMM)"
    plan_size = 27
    #: the quantities of its machine-file section (unit conversion, magnitude checks)
    file_quantities = {("tracker", "translation", "*"): "length",
                       ("tracker", "targets", "*", "*"): "length"}
    columns = "q1_deg..q3_deg and the tracker points mx_mm, my_mm, mz_mm"
    priority = 10
    missing = ("mx_<unit>, my_<unit>, mz_<unit> (e.g. mx_mm)", "laser-tracker points")
    data_class = "TrackerData"

    def detect(self, header):
        return has_column(header, "mx") or has_column(header, "my") or has_column(header, "mz")

    def plan_size_for(self, machine):
        # the source paper's 3x3x3 grid (seed 001, the Delta); random poses otherwise
        return self.plan_size if machine.tracker_grid_spacing() is not None else 60

    def default_noise(self):

        return TrackerNoise()

    def describe_noise(self, noise):
        if hasattr(noise, "sigma"):
            return f"points: {noise.sigma * 1e6:.3g} um per coordinate (std)"
        return (f"laser tracker: {noise.distance * 1e6:.3g} um along the beam, "
                f"{noise.transverse * 1e6:.3g} um + {noise.transverse_per_m * 1e6:.3g} um/m "
                "across (std)")

    montecarlo_variables = ("noise", "poses", "tolerance")
    montecarlo_metrics = {
        "position_mean": ("um", 1e-6, "mean held-out tracker-point error"),
        "position_max": ("um", 1e-6, "max held-out tracker-point error"),
    }
    montecarlo_evaluation_poses = 200
    montecarlo_exact_data = True
    montecarlo_noise_words = ("leica",)

    def montecarlo_default_poses(self, machine):
        # seed 001's grid on a platform that only translates, the plan size otherwise
        return "3x3x3 grid" if not machine.rotates else self.plan_size_for(machine)

    def montecarlo_minimum_poses(self, settings):
        # 3 equations per point, 12 gauges
        return max(4, math.ceil((len(settings.machine.parameters) + 6 - 12) / 3))

    @staticmethod
    def _montecarlo_noises(run):
        """Simulated and fitted tracker noise of a run (None: Leica-type)."""
        noise = run.settings.noise
        if noise is None:
            return TrackerNoise(), TrackerNoise()
        sim_noise = TrackerNoise(noise, noise, 0.0) if noise > 0 else None
        return sim_noise, TrackerNoise(run.weight(noise), run.weight(noise), 0.0)

    def montecarlo_run(self, run):
        """Errors jointly with the tracker pose; held out: the tracker points at readings in
        the grid's box that were not measured, the calibrated model with its registration
        against the true machine's exact points. A machine whose file does not give the
        target's place (a platform that rotates): :meth:`_montecarlo_points_run`."""
        s = run.settings
        nominal = s.machine
        if nominal.tracker_target() is None:
            return self._montecarlo_points_run(run)
        true = run.true_machine()
        pose = tracker_pose(run_setup(run, self.name))
        sim_noise, fit_noise = self._montecarlo_noises(run)
        if s.poses is None and nominal.tracker_grid_spacing() is not None:
            targets = grid_points(nominal.home[0], nominal.tracker_grid_spacing())
        else:
            targets = self.candidates(nominal, s.poses or self.montecarlo_poses, run.rng)[0]
        data = simulate_tracker(true, nominal, targets, pose, sim_noise, rng=run.rng)
        res = calibrate_tracker(nominal, data, fit_noise)
        held = self.candidates(nominal, self.montecarlo_evaluation_poses, run.rng)[0]
        q = nominal.ik(held)
        m = predict_tracker_points(res.machine, q, res.section(TrackerSection).registration)
        return res, _point_errors(m, predict_tracker_points(true, q, pose))

    def _montecarlo_points_run(self, run):
        """Random workspace poses with rotations, the target's place estimated; held out: the
        points at other poses through the identified registration and target."""
        nominal = run.settings.machine
        sim_noise, fit_noise = self._montecarlo_noises(run)
        data, true, truth = run.simulate(run.settings.poses,
                                         False if sim_noise is None else sim_noise)
        res = calibrate_tracker(nominal, data, fit_noise)
        P, R, _ = self.candidates(nominal, self.montecarlo_evaluation_poses, run.rng)
        q = nominal.ik(P, R)
        sec = res.section(TrackerSection)
        m = predict_tracker_points(res.machine, q, sec.registration, targets=sec.targets)
        return res, _point_errors(m, predict_tracker_points(true, q, truth["base_from_tracker"],
                                                            targets=truth["targets"]))

    def candidates(self, machine, n, rng, setup=None):
        if machine.tracker_grid_spacing() is None:
            return super().candidates(machine, n, rng)
        from ...machines.deviations import draw_accepted

        half = np.asarray(machine.tracker_grid_spacing(), float)   # the 3x3x3 grid: +/- spacing
        centre = machine.home[0]

        def draw(m, rng):
            P = centre + rng.uniform(-1.0, 1.0, (m, 3)) * half
            R = np.broadcast_to(np.eye(3), (m, 3, 3))
            q, J, _ = machine.ik_jacobians(P, R, want_du=False)
            ok = np.all(np.isfinite(q), -1)
            sv = np.linalg.svd(np.asarray(J)[ok][..., :3], compute_uv=False)
            ok[ok] = sv[..., -1] / sv[..., 0] > 0.05
            return P, R, ok

        where = str(getattr(machine, "source", "") or "").replace("{", "{{").replace("}", "}}")
        P, R = draw_accepted(draw, n, rng, (f"{where}: " if where else "")
                             + "only {have} of {n} candidate points around home are reachable "
                             "and well conditioned: check the geometry and home")
        return P, R, None

    def standard_plan(self, machine, n, seed, setup=None):
        if machine.tracker_grid_spacing() is None:
            return super().standard_plan(machine, n, seed, setup)

        k = int(round(n ** (1.0 / 3.0)))
        if k < 2 or k**3 != n:
            return StandardPlan("seed 001's grid around home",
                                reason=f"seed 001's grid has 3 x 3 x 3 = 27 points (k x k x k "
                                       f"grids in its box: 8, 27, 64, ...), not {n}")
        span = 2.0 * np.asarray(machine.tracker_grid_spacing(), float)   # 3x3x3 extent
        P = grid_points(machine.home[0], span / (k - 1), (k, k, k))
        return StandardPlan(f"the {k}x{k}x{k} grid of seed 001 around home", P,
                            np.broadcast_to(np.eye(3), (n, 3, 3)))

    def planned_data(self, machine, P, R, rows, source, group=None, setup=None):

        q = reachable(machine, P, R, rows, source)
        Rt, t = tracker_pose(setup)
        x = P + np.einsum("kij,j->ki", R, plan_target(machine))
        return TrackerData(q, (x - t) @ Rt, rows=rows, source=source, true_P=P,
                           target=None if group is None else np.asarray(group, int))

    section = "tracker"
    section_words = ("a calibration from points (mx, my, mz: laser tracker, CMM) writes the "
                     "tracker section")
    Setup = TrackerSetup
    section_order = 10
    section_schema = TrackerFileSection
    section_lists = {"targets": "a list of target places [[x, y, z], ...] on the platform "
                                "(one per target)"}

    def read_setup(self, section, length_factor, machine):
        targets = getattr(section, "targets", None)
        return TrackerSetup(
            (file_rotation(section.rotation),
             np.asarray(section.translation, float) * length_factor),
            None if targets is None else np.asarray(targets, float) * length_factor)

    def setup_section(self, setup, length_factor, machine):
        out = frame_section(setup.base_from_tracker, length_factor)
        if setup.targets is not None:
            targets = np.asarray(setup.targets, float).reshape(-1, 3)
            known = machine.tracker_target()
            if known is None:
                out["targets"] = [vector(c, length_factor) for c in targets]
            elif not np.allclose(targets, known, rtol=0, atol=1e-12):
                raise InputError(f"cannot save tracker targets for a {machine.kind}: its "
                                 "target on the platform is fixed by the machine file "
                                 "(smr_offset)")
        return out

    def carried_by(self, machine, setup):
        return setup is not None

    def groups_carried(self, setup):
        return 0 if setup is None or setup.targets is None else len(setup.targets)

    def predict(self, machine, setup, P, R, ok, group, rows=None, source=None):
        targets, shared = tracker_targets(machine, setup)
        if shared:
            group = np.zeros(len(P), int)     # every target number is the file's reflector
        _check_groups(group, len(targets), "target", "tracker.targets" if setup.targets
                      is not None else "tracker (one target: the platform origin, no targets "
                      "key)", rows, source)
        A, a = (np.asarray(v, float) for v in setup.base_from_tracker)
        model = PointsModel(len(targets), targets[0] if shared else None)
        values = np.concatenate([np.zeros(3), a] + ([] if shared else [targets.ravel()]))
        return model.predict(NuisanceState(values, [A]), P, R, group), None, group

    simulate_options = {"targets": 1}
    simulate_options_words = "targets: apply to the tracker (points) scenario"

    def simulate(self, machine, true, n, noise, rng, truth, *, setup=None, poses=None,
                 mounting_error=MOUNTING_ERROR, targets=1):
        """``n`` random workspace poses (:meth:`candidates`: rotations on platforms that
        rotate), or ``poses``; ``targets`` targets, rows cycling through them; the tracker at
        the machine file's (``setup``, else the simulations' default); true target
        places = planned (:func:`planned_targets`) + a uniform error of ``mounting_error`` per
        coordinate (the file's target when it gives one). ``noise`` a tracker noise model
        (default ``TrackerNoise()``; False: exact data). See
        :meth:`Instrument.simulate <pkmcal.instruments.base.Instrument.simulate>`.

        Returns
        -------
        tuple
            ``(data, true, truth)``; ``truth`` with ``base_from_tracker``, ``targets``,
            ``planned_targets`` and ``setup`` (the true :class:`TrackerSetup`).
        """
        from ..experiment import given_poses, mm_text, noise_model, simulate_instrument

        k = int(targets)
        planned = planned_targets(machine, k)
        known = machine.tracker_target() is not None
        c = planned if known else planned + rng.uniform(-mounting_error, mounting_error,
                                                        planned.shape)
        Rt, t = tracker_pose(setup)
        model = PointsModel(k, machine.tracker_target())
        state = model.initial()
        state.rotations = [np.asarray(Rt, float)]
        state.values[3:6] = t
        if not known:
            state.values[model._it.ravel()] = c.ravel()
        if poses is None:
            P, R, _ = self.candidates(machine, n, rng)
            words = (f"{n} random workspace poses around home"
                     + (" with rotations within +/-10 deg" if machine.rotates else ""))
        else:
            P, R = given_poses(poses)
            words = f"{len(P)} given poses"
        group = np.arange(len(P)) % k
        data = simulate_instrument(true, machine, model, state, P, R, group,
                                   noise_model(noise, TrackerNoise()), rng)
        true_setup = TrackerSetup((np.asarray(Rt, float), np.asarray(t, float)),
                                  None if known else c)
        R_true, t_true = true_setup.base_from_tracker
        angle = np.degrees(np.arccos(np.clip((np.trace(R_true) - 1) / 2, -1, 1)))
        rows = [("tracker pose", f"at {mm_text(t_true)} mm in the base frame, rotated "
                 f"{angle:.4g} deg relative to it")]
        rows += [(f"target {g + 1}", f"{mm_text(cg)} mm on the platform (true)")
                 for g, cg in enumerate(c)]
        truth.update(base_from_tracker=true_setup.base_from_tracker, targets=c,
                     planned_targets=planned, poses=words, rows=rows, setup=true_setup)
        return data, true, truth

    simulate_flags = {"--targets": "--scenario points (tracker)"}

    def simulates_grid(self, machine, targets=None):
        # seed 001's grid on a platform that only translates (its file gives the spacing)
        return machine.tracker_grid_spacing() is not None and not targets

    def simulate_arguments(self, machine, noise, targets=None, **flags):
        model, words = tracker_noise_arg(noise, allow_none=True, machine=machine)
        model = False if model is None else model
        targets = 1 if targets is None else targets
        if targets < 1:
            raise InputError(f"--targets: must be >= 1, got {targets}")
        return model, words, {"targets": targets}

    data_columns = ("mx", "my", "mz")

    def calibration_summary(self, report):
        res, ident = report["residuals"], report["identifiability"]
        reg, dr = report["registration"], report["distance_ratio"]
        unit = report["units"]["length"]
        if "smr_offset" in report:
            where = f"reflector {report['smr_offset']:.6g} {unit} below the platform point"
        else:
            places = report["targets"]["places"]
            where = (f"{len(places)} target(s) at estimated places on the platform: "
                     + ", ".join("(" + ", ".join(f"{v:.6g}" for v in c) + ")" for c in places)
                     + f" {unit}")
        rows = [("measurement", f"laser tracker, {report['measurements']} points ({where})"),
                ("method", "joint: the leg errors and the tracker pose together"
                 if report["method"] == "joint" else
                 "two-step (seed 001): tracker registered first with the nominal model, then "
                 "the leg errors with the registration fixed"),
                "identifiable, grouped",
                ("RMS residual", f"{format_um(res['rms_um'])} over {res['count']} points "
                 f"(3-D, measured - predicted tracker point); before calibration "
                 f"{format_um(res['before_rms_um'])} ({res['before']})"),
                ("noise", f"{report['noise']}")]
        if report["robust"]:
            if res["outliers"]:
                worst = ", ".join(f"row {o['row']}: {o['residual_um']:.4g} um"
                                  for o in res["outliers"][:10])
                rows.append(("outliers", f"{len(res['outliers'])} row(s) left out (--robust): "
                             f"{worst}"))
            else:
                rows.append(("outliers", "none found (--robust)"))
        if dr["pairs"] and dr["before"]["std"] is not None:
            b, a = dr["before"], dr["after"]
            change = 100 * (1 - a["std"] / b["std"]) if b["std"] > 0 else 0.0
            change_text = (f"{change:.3g} % smaller" if change >= 0
                           else f"{-change:.3g} % larger")
            rows.append(("distance ratio", f"spread (std) {b['std']:.4g} % before, "
                         f"{a['std']:.4g} % after ({change_text}); range {b['min']:.3f}.."
                         f"{b['max']:.3f} % -> {a['min']:.3f}..{a['max']:.3f} %; "
                         f"{dr['pairs']} pairs ({dr['pairs_from']})"))
        t = reg["translation"]
        rows += [("tracker pose", f"base_from_tracker: tracker origin at ({t[0]:.6g}, "
                  f"{t[1]:.6g}, {t[2]:.6g}) {unit}; "
                  + ("estimated: " if reg["estimated"] else "fixed: ")
                  + f"{reg['rotation_change_deg']:.3g} deg and "
                  f"{reg['translation_change']:.3g} {unit} from the closed-form registration"),
                 "held-out", "noise levels", "residual test", "convergence"]
        if report_verdict(report).status == FAILED_ALARMING:
            causes = ["outliers (try --robust)" if not report["robust"] else None,
                      "a registration biased by the nominal model (drop --two-step)"
                      if report["method"] == "two-step" else None,
                      "a wrong smr_offset or noise model", "errors the model does not have"]
            rows.append(("note", "note: the residual test failed; usual causes: "
                         f"{', '.join(c for c in causes if c)}."))
        if ident["unidentifiable"] and "identifiable_combinations" in report:
            what = report["identifiable_combinations"]["description"].split(" (file length")[0]
            rows.append(("note", f"note: {what}; the changes are the smallest ones (scaled) "
                         "that fit the data, and std is for the identifiable part."))
        elif ident["unidentifiable"]:
            rows.append(("note", "note: the data fix the machine only relative to the tracker "
                         "frame and the targets; the changes are the smallest ones (scaled) "
                         "that fit the data, and std is for the identifiable part."))
        return rows
    prediction_words = "predicted tracker point(s) (target in the tracker frame)"

    def problem(self, machine, data, noise=None, setup=None, registration=None, targets=None,
                **start):

        groups = getattr(data, "target", getattr(data, "group", None))
        n_targets = 1 if groups is None or not len(groups) else int(np.max(groups)) + 1
        target = None if machine.tracker_target() is not None else \
            np.tile(plan_target(machine), (n_targets, 1)) if targets is None else targets
        return TrackerProblem(machine, data, self.default_noise() if noise is None else noise,
                              tracker_pose(setup) if registration is None else registration,
                              targets=target)

    measurement_words = ("points of a target on the platform (laser tracker; tracker pose and "
                         "unknown target places estimated jointly)")
    group_column = "target"
    plan_options = ("targets",)

    def noise_arg(self, text, machine=None):
        """The tracker noise of ``--noise``: leica (default), or a length per coordinate."""

        if text is not None and not isinstance(text, str):
            return text
        return tracker_noise_arg(text, allow_none=False, machine=machine)[0]

    #: the io reader of its CSV files (:func:`pkmcal.io.read_measurements`)
    reader = "read_points"
    #: its flow reads :class:`TrackerData` (the registration's start needs the points alone)
    calibration_reader = "read_tracker"
    Options = TrackerOptions

    def check_options(self, options, source) -> None:
        """``--robust`` with ``--two-step`` refused (see
        :meth:`~pkmcal.instruments.base.Instrument.check_options`)."""
        _check_options(options, source)

    def calibrate(self, machine: Machine, data, context, options):
        """Registration and errors together (or ``two_step``), the distance ratio (seed 001
        Fig. 6) before and after (see :meth:`~pkmcal.instruments.base.Instrument.calibrate`)."""
        return _calibration_flow(machine, data, context, options)

    def joint_part(self, machine: Machine, data, source, noise, read, options=None):
        """The tracker file's part of a fit of several files: its points, one target per
        ``target`` group, the tracker's pose unknown (see
        :meth:`~pkmcal.instruments.base.Instrument.joint_part`)."""
        if noise is None or isinstance(noise, str):
            noise_model, text = tracker_noise_arg(noise, allow_none=False, machine=machine)
        else:
            noise_model, text = noise, _tracker_noise_text(noise)
        raw = as_tracker_data(load_data(data, read, machine))
        check_spread(raw, noise_model)
        points = as_points(raw)
        points.source = str(source)
        return JointPart(points, PointsModel(points.n_groups, machine.tracker_target()),
                         noise_model, text, "tracker")

    def measured_problem(self, machine, data, noise=None, source="", setup=None):
        """The tracker's pose and the target places started from the data: registered on the
        machine file's forward kinematics, then (unknown targets) fitted with the machine
        held."""
        from ...estimation.estimator import levenberg_marquardt
        from ..models import PointsModel

        noise = self.default_noise() if noise is None else noise
        fk = _fk_of(machine, data, source)
        start = PointsModel(data.n_groups, machine.tracker_target()).start(
            fk.P, fk.R, data.values, data.group, str(source))
        registration = (start.rotation_starts[0], start.parameters.values[3:6].copy())
        targets = None
        if machine.tracker_target() is None:
            alone = TrackerProblem(machine, data, noise, registration).with_machine_fixed()
            first = levenberg_marquardt(alone)
            registration = registration_of(first.state)
            targets = first.state.nuisance.values[6:].copy()
        return self.problem(machine, data, noise, registration=registration, targets=targets)

    def planned_setup(self, machine, setup=None, targets=None, **options):
        """The file's set-up (several targets in turn need the target's place unknown)."""
        if targets is not None and targets > 1 and machine.tracker_target() is not None:
            raise InputError(f"--targets {targets}: {machine.source} gives the target's place "
                             "on the platform; one target only")
        return setup


#: this module's instrument (:data:`~pkmcal.instruments.registry.INSTRUMENT_MODULES`)
INSTRUMENT = Tracker()


def as_tracker_data(data):
    """Points given as the instrument layer's data (``kind == "points"``), as tracker data;
    other data unchanged.

    Parameters
    ----------
    data : object
        Tracker data, or the instrument layer's points.

    Returns
    -------
    object
        :class:`TrackerData` for points, else ``data``.
    """
    if getattr(data, "kind", None) != "points":
        return data
    return TrackerData(data.q, data.values, data.rows, data.source, data.true_P,
                       target=data.group if data.n_groups > 1 else None)


# -- calibration flow (pkmcal calibrate) ------------------------------------------------------


def grid_neighbour_pairs(P, abs_tol: float = 1e-4, rel_tol: float = 0.01) -> np.ndarray:
    """Index pairs of neighbouring points of an axis-aligned grid.

    ``j`` is the neighbour of ``i`` along an axis when ``P_j - P_i`` points along the positive
    axis (off-axis part within ``abs_tol + rel_tol * distance``) and no closer point lies that
    way; missing grid points are allowed. Seed 001 Fig. 6 compares such pairs.

    Parameters
    ----------
    P : array_like, shape (K, 3)
        Positions, m.
    abs_tol : float, optional
        Absolute off-axis tolerance, m.
    rel_tol : float, optional
        Off-axis tolerance relative to the distance.

    Returns
    -------
    ndarray of int, shape (n, 2)
        The pairs ``(i, j)``.
    """
    P = np.asarray(P, float)
    K = len(P)
    pairs = []
    for start in range(0, K, 512):                       # K x K temporaries in blocks
        D = P[None, :, :] - P[start:start + 512, None, :]   # (B, K, 3) P_j - P_i
        for axis in range(3):
            along = D[..., axis]
            off = np.linalg.norm(np.delete(D, axis, axis=-1), axis=-1)
            dist = np.where((along > abs_tol) & (off <= abs_tol + rel_tol * along), along,
                            np.inf)
            j = np.argmin(dist, axis=1)
            i = np.flatnonzero(np.isfinite(dist[np.arange(len(D)), j]))
            pairs.append(np.stack([i + start, j[i]], -1))
    return np.concatenate(pairs) if pairs else np.zeros((0, 2), int)


def distance_ratio_pairs(machine, q) -> tuple[np.ndarray, str]:
    """Pairs of measurements for the distance ratio (seed 001 Fig. 6).

    Neighbours of the grid the readings were commanded to (``machine``'s forward kinematics
    of them, i.e. the commanded points when ``machine`` is the controller's model); nearest
    neighbours when the points form no grid.

    Parameters
    ----------
    machine : Machine
        The controller's model.
    q : array_like, shape (K, n)
        Joint readings.

    Returns
    -------
    tuple
        ``(pairs (n, 2) of row indices, how they were found)``.
    """
    P = machine.fk(q).P
    ok = np.all(np.isfinite(P), axis=-1)
    pairs = grid_neighbour_pairs(np.where(ok[:, None], P, 1e9))
    pairs = pairs[ok[pairs].all(axis=1)] if len(pairs) else pairs
    if len(pairs) >= max(1, len(P) // 4):      # a grid: most points have a neighbour
        return pairs, "neighbours on the commanded grid"
    D = np.linalg.norm(P[:, None] - P[None], axis=-1)
    np.fill_diagonal(D, np.inf)
    j = np.argmin(np.where(np.isfinite(D), D, np.inf), axis=1)
    pairs = np.unique(np.sort(np.stack([np.arange(len(P)), j], -1), axis=1), axis=0)
    return pairs[ok[pairs].all(axis=1)], "nearest neighbours (the points form no grid)"


def _ratio_stats(r) -> dict:
    r = np.asarray(r, float)
    r = r[np.isfinite(r)]
    if not r.size:
        return {"mean": None, "std": None, "min": None, "max": None}
    return {"mean": float(r.mean()), "std": float(r.std()), "min": float(r.min()),
            "max": float(r.max())}


def check_spread(data, noise_model) -> None:
    """Refuse (nearly) collinear tracker points: the registration's rotation about their line
    would be fixed only by the noise. Also fewer than 4 points (seed 001 eq. 12-14)."""
    K = len(data)
    if K < 4:
        raise InputError(f"{path_text(data.source)}: "
                         f"{K} point(s): the tracker registration needs at "
                         "least 4 points that are not on one line (seed 001 uses a 3x3x3 grid)")
    m = data.m - data.m.mean(0)
    sv = np.linalg.svd(m, compute_uv=False)
    off_line = sv[1] / math.sqrt(K)                       # RMS distance from the best line
    sigma = float(np.sqrt(np.max(np.trace(noise_model.covariance(data.m), axis1=1, axis2=2))))
    if off_line <= max(20 * sigma, 1e-6 * sv[0]):
        raise InputError(f"{path_text(data.source)}: "
                         f"the {K} tracker points lie on one line or nearly (RMS "
                         f"distance from the best line {off_line * 1e6:.3g} um, tracker noise "
                         f"{sigma * 1e6:.3g} um): the "
                         "rotation of the tracker about that line cannot be found; measure "
                         "points spread in 2-3 directions (e.g. a 3x3x3 grid)")


def _rotvec(R):
    from ...kinematics import rotvec_from_matrix

    return rotvec_from_matrix(R)


def _check_options(options: TrackerOptions, source) -> None:
    """The tracker's options that do not go together, refused naming them (an option it does
    not declare is refused by the calibration layer)."""
    if options.two_step and options.robust:
        raise InputError("--robust: applies to the joint method (its residuals are the "
                         "noise's); --two-step holds a registration of the nominal model, whose "
                         "residuals exceed the noise by design")


def _calibration_flow(machine, data, context: FlowContext,
                      options: TrackerOptions) -> FlowResult:
    """``pkmcal calibrate`` from tracker points (:meth:`Tracker.calibrate`)."""
    from ...units import LENGTH

    source, split = context.source, context.split
    two_step, robust = options.two_step, options.robust
    if options.noise is None or isinstance(options.noise, str):
        noise_model, noise_text = tracker_noise_arg(options.noise, allow_none=False,
                                                    machine=machine)
    else:
        noise_model, noise_text = options.noise, _tracker_noise_text(options.noise)
    data, held = split_rows(as_tracker_data(load_data(data, context.read, machine)), split,
                            source)
    check_spread(data, noise_model)
    fk = machine.fk(data.q)
    if not fk.converged.all():
        raise InputError(f"{path_text(source)}: row(s) {rows_text(data.rows[~fk.converged])}: no "
                         f"platform pose of {source_of(machine)} reproduces these readings "
                         "(outside the workspace, or a wrong unit or zero)")
    result = solve(source, calibrate_tracker, machine, data, noise_model, held=held,
                    joint=not two_step, robust=robust, estimate_noise=options.noise is None)
    require_converged(result, source,
                       "spread the points in all three directions, e.g. a 3x3x3 grid")

    units = context.units
    fl = LENGTH[units["length"]]
    method = "two-step" if two_step else "joint"
    calibrated = result.machine
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    # FK start of the calibrated file: the input machine's home, else the measured position
    # closest to the middle of the data that the calibrated model reaches
    fk_cal = calibrated.fk(data.q)
    order = np.argsort(np.linalg.norm(fk_cal.P - np.nanmean(fk_cal.P, axis=0), axis=1))
    for P_home, R_home in [machine.home, *zip(fk_cal.P[order], fk_cal.R[order], strict=True)]:
        if np.all(np.isfinite(calibrated.ik(P_home, R_home))):
            calibrated.home = (np.asarray(P_home, float), np.asarray(R_home, float))
            break
    section = result.section(TrackerSection)
    R, t = section.registration
    R0, t0 = section.start_registration
    given = machine.tracker_target() is not None
    targets, targets0 = section.targets, section.start_targets
    calibrated.tracker_targets = None if given else np.array(targets, float)
    kept = np.asarray(section.kept, bool)
    outlier_rows = [int(v) for v in section.outlier_rows]

    nominal_of = dict(zip(machine.parameters.names, machine.u, strict=True))
    nominal_of.update(zip(("tracker.rx", "tracker.ry", "tracker.rz"), (0.0, 0.0, 0.0),
                          strict=True))
    nominal_of.update(zip(("tracker.x", "tracker.y", "tracker.z"), t0, strict=True))
    params = parameter_table(result, nominal_of, units)

    # residuals in the tracker frame (m); before = nominal model + closed-form registration
    r = data.m - predict_tracker_points(calibrated, data.q, (R, t), targets, data.target)
    r0 = data.m - predict_tracker_points(machine, data.q, (R0, t0), targets0, data.target)
    norm, norm0 = np.linalg.norm(r, axis=1), np.linalg.norm(r0, axis=1)
    rms = lambda v: float(np.sqrt(np.mean(v**2)) * 1e6) if v.size else None  # noqa: E731
    # distance ratio (seed 001 Fig. 6) over pairs of kept rows
    pairs, pairs_from = distance_ratio_pairs(machine, data.q)
    pairs = pairs[kept[pairs].all(axis=1)] if len(pairs) else pairs
    d_meas = np.linalg.norm(data.m[pairs[:, 0]] - data.m[pairs[:, 1]], axis=-1) \
        if len(pairs) else np.zeros(0)
    pairs = pairs[d_meas > 1e-9] if len(pairs) else pairs
    ratio_before = distance_ratios(machine, data.q, data.m, pairs, targets0, data.target) \
        if len(pairs) else []
    ratio_after = distance_ratios(calibrated, data.q, data.m, pairs, targets, data.target) \
        if len(pairs) else []
    before, after = _ratio_stats(ratio_before), _ratio_stats(ratio_after)

    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.unidentifiable)
    combinations = calibrated.identifiable_combinations()
    if combinations is not None:
        combinations = {k: (v if k == "description" else (np.asarray(v) / fl).tolist())
                        for k, v in combinations.items()}
        combinations["description"] += " (file length unit)"
    report = {
        **context.head(machine, "tracker", method),
        "robust": robust,
        "units": units,
        "measurements": len(data),
        "used": int(kept.sum()),
        "outlier_rows": outlier_rows,
        "noise": noise_text,
        **({"smr_offset": float(-machine.tracker_target()[2]) / fl} if given else {}),
        **section.as_report(units),         # targets, registration
        "convergence": convergence_json(result),
        "residuals": {
            "of": "tracker points, measured - predicted (3-D distance, tracker frame)",
            "count": int(kept.sum()),
            "rms_um": rms(norm[kept]),
            "max_um": float(norm[kept].max() * 1e6) if kept.any() else None,
            "rms_per_axis_um": (np.sqrt(np.mean(r[kept] ** 2, axis=0)) * 1e6).tolist(),
            "before_rms_um": rms(norm0[kept]),
            "before": "machine file's model, closed-form registration" if given else
                      "machine file's model, tracker frame and targets fitted alone",
            **variance_json(result),
            "outliers": [{"row": int(row), "residual_um": float(v * 1e6)} for row, v in
                         zip(data.rows[~kept], norm[~kept], strict=True)],
        },
        "distance_ratio": {
            "unit": "%", "pairs": int(len(pairs)), "pairs_from": pairs_from,
            "before": before, "after": after,
        },
        "identifiability": identifiability_json(n_free, rank, unidentifiable, s),
        **({"identifiable_combinations": combinations} if combinations else {}),
        "parameters": public_parameters(params),
    }
    if held is not None:
        d_after = np.linalg.norm(held.m - predict_tracker_points(
            calibrated, held.q, (R, t), targets, held.target), axis=1)
        d_before = np.linalg.norm(held.m - predict_tracker_points(
            machine, held.q, (R0, t0), targets0, held.target), axis=1)
        ok = np.isfinite(d_after) & np.isfinite(d_before)
        report["validation"] = validation_section(
            split, held, "tracker points of the held-out rows, measured - predicted (3-D "
            "distance) with the identified tracker pose; before: the machine file's model and "
            "the closed-form registration of the calibration rows", "um",
            rms(d_before[ok]), rms(d_after[ok]), report["residuals"]["rms_um"],
            max_after=float(d_after[ok].max() * 1e6) if ok.any() else None,
            not_reached=[int(r) for r in held.rows[~ok]])
    metadata = {
        "method": f"tracker-{method}",
        "date": report["date"],
        "data": path_text(source),
        "machine": source_of(machine),
        "measurements": len(data),
        "outlier_rows": outlier_rows,
        "rms_residual_um": report["residuals"]["rms_um"],
        "identifiable": rank,
        "free_parameters": n_free,
        **identifiability_metadata(unidentifiable),
        "distance_ratio_std_percent": {"before": before["std"], "after": after["std"]},
    }
    return FlowResult("tracker", machine, calibrated, result, report, metadata, params, units)
