"""Calibration from laser-tracker points (seed 001 eq. 12-15), jointly with the registration.

Unknowns: the machine's error parameters and the tracker pose ``base_from_tracker = (R, t)``
(``tracker.rx/ry/rz``: rotation increments about the base axes, applied on the left of the
closed-form start; ``tracker.x/y/z``: translation). Residual of point k, whitened with the
tracker's anisotropic noise (:class:`~pkmcal.measurements.TrackerNoise`)::

    e_k = W_k (m_k - R^T (FK(q_k; u) - h_M e_z - t))

Seed 001 registers first (with the nominal model) and then identifies the errors with the
registration fixed (``joint=False`` reproduces that); ``joint=True`` (default) estimates both
together, which removes the bias the nominal model leaves in the registration.

Identifiability (SPEC 2.2): ``da`` and ``db`` enter only as ``db - da`` (9 directions), and a
common shift of the platform joints is a translation of the tracker (3): 21 of 33.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..identifiability import NullGroup, name_null_space, name_weak_directions
from ..identifiability.rank import RTOL
from ..kinematics import matrix_from_rotvec, rotvec_from_matrix, skew
from ..machines.base import Machine
from ..measurements.tracker import TrackerData, TrackerNoise
from ..parameters import ParameterSet
from .estimator import MAX_STD, CalibrationResult, levenberg_marquardt
from .registration import register_points

TRACKER = ("tracker.rx", "tracker.ry", "tracker.rz", "tracker.x", "tracker.y", "tracker.z")


@dataclass
class TrackerState:
    u: np.ndarray            # machine parameters
    R: np.ndarray            # base_from_tracker rotation
    t: np.ndarray            # base_from_tracker translation


class TrackerProblem:
    """Block problem (no per-point unknowns) for tracker calibration.

    Global unknowns: the machine's parameters and ``tracker.rx/ry/rz/x/y/z`` (rotation
    increments about the base axes from the start registration, and the translation).

    Parameters
    ----------
    machine : Delta
        Start geometry (needs ``smr_offset``).
    data : TrackerData
        Actuator readings and tracker points.
    noise : TrackerNoise or None
        Whitens the residuals; None: unit weights (to differentiate predictions, not to fit).
    registration : tuple of ndarray
        Start ``base_from_tracker = (R (3, 3), t (3,))``.
    joint : bool, optional
        Estimate the tracker pose together with the errors; False holds it at
        ``registration`` (seed 001's two-step method).

    Raises
    ------
    InputError
        When the machine's forward kinematics cannot reproduce some readings.
    """

    local_dof = 0

    def __init__(self, machine: Machine, data: TrackerData, noise: TrackerNoise | None,
                 registration, joint: bool = True):
        self.machine, self.data = machine, data
        self.R0, self.t0 = registration
        # noise None: unit weights (used to differentiate predictions, not to fit)
        self.W = (np.broadcast_to(np.eye(3), (len(data), 3, 3)) if noise is None
                  else noise.whitening(data.m))
        self.h = np.array([0.0, 0.0, machine.smr_offset])
        # residuals are formed about the centroid of the tracker points: the points lie metres
        # from the tracker, and rounding of R^T (p - t) at that distance made the cost jitter
        # by ~2e-12 of itself, more than the last Gauss-Newton steps gain (9 of 200 noisy
        # joint fits ran to max_iter at the optimum; tests/test_tracker.py)
        self.m0 = data.m.mean(0) if len(data) else np.zeros(3)
        self.m_centred = data.m - self.m0
        tracker = ParameterSet(TRACKER, ("angle",) * 3 + ("length",) * 3,
                               np.concatenate([np.zeros(3), self.t0]), fixed=[not joint] * 6)
        self.parameters = machine.parameters.concat(tracker)
        self.scales = machine.scales_with(tracker)
        self.n_machine = len(machine.parameters)
        fk = machine.fk(data.q)
        if not fk.converged.all():
            rows = data.rows[~fk.converged].tolist()
            raise InputError(f"{data.source}: rows {rows[:10]}: no platform position "
                             "reproduces these actuator readings")

    def initial_state(self):
        """Start state: the machine's parameters and the start registration.

        Returns
        -------
        TrackerState
            The state.
        """
        return TrackerState(self.machine.u.copy(), self.R0.copy(), self.t0.copy())

    def global_values(self, state):
        """Global values of a state: machine parameters, tracker rotation increment, translation.

        Parameters
        ----------
        state : TrackerState
            An estimator state.

        Returns
        -------
        ndarray, shape (n_machine + 6,)
            Parameter values, internal units.
        """
        return np.concatenate([state.u, rotvec_from_matrix(state.R @ self.R0.T), state.t])

    def predict(self, state, q=None):
        """Predicted tracker points, and the forward kinematics behind them.

        Parameters
        ----------
        state : TrackerState
            Machine parameters and tracker pose.
        q : array_like, shape (K, n_joints), optional
            Actuator readings, rad; default: the data's.

        Returns
        -------
        m : ndarray, shape (K, 3)
            Predicted SMR points in the tracker frame, m.
        fk : FKResult
            Forward kinematics of the readings (positions and validity).
        """
        m_centred, fk = self._predict_centred(state, q)
        return m_centred + self.m0, fk

    def _predict_centred(self, state, q=None):
        """``R^T (p - h - t) - m0`` as ``R^T (p - h - (t + R m0))``: no metre-sized terms."""
        q = self.data.q if q is None else q
        fk = self.machine.fk(q, state.u)
        c = state.t + state.R @ self.m0              # the centroid's place in the base frame
        return (fk.P - self.h - c) @ state.R, fk

    def evaluate(self, state, jacobian=True):
        """Whitened point residuals ``W_k (m_k - prediction_k)`` and their Jacobian.

        Parameters
        ----------
        state : TrackerState
            Machine parameters and tracker pose.
        jacobian : bool, optional
            Also compute the Jacobian.

        Returns
        -------
        r : ndarray, shape (K, 3)
            Whitened residuals; NaN where the forward kinematics failed.
        J_g : ndarray, shape (K, 3, n_machine + 6) or None
            Derivatives with respect to the machine parameters and the tracker pose.
        J_l : None
            No local unknowns.
        """
        m_pred, fk = self._predict_centred(state)
        e = np.einsum("kij,kj->ki", self.W, self.m_centred - m_pred)
        e = np.where(fk.converged[:, None], e, np.nan)
        if not jacobian:
            return e, None, None
        _, Jp, Ju = self.machine.ik_jacobians(fk.P, None, state.u)
        dp_du = -np.linalg.solve(Jp[..., :3], Ju)                  # (K, 3, n_machine)
        RT = state.R.T
        x = fk.P - self.h - state.t
        de_du = -np.einsum("ij,kjn->kin", RT, dp_du)
        de_dw = -np.einsum("ij,kjl->kil", RT, skew(x))              # rotation on the left
        de_dt = np.broadcast_to(RT, (len(x), 3, 3))
        J = np.concatenate([de_du, de_dw, de_dt], -1)
        return e, np.einsum("kij,kjn->kin", self.W, J), None

    def retract(self, state, du, dl):
        """The state after a global step (tracker rotation applied on the left).

        Parameters
        ----------
        state : TrackerState
            Current state.
        du : ndarray, shape (n_machine + 6,)
            Step of the global parameters.
        dl : None
            Unused.

        Returns
        -------
        TrackerState
            The new state.
        """
        n = self.n_machine
        return TrackerState(state.u + du[:n], matrix_from_rotvec(du[n:n + 3]) @ state.R,
                            state.t + du[n + 3:])

    def null_groups(self, scales):
        """The known unidentifiable directions, in words (scaled coordinates).

        Per leg ``da + db`` (only ``db - da`` enters the leg equation) and, when the tracker pose
        is estimated, a translation of the tracker with every platform joint.

        Parameters
        ----------
        scales : ndarray, shape (n,)
            Column scales; the directions are returned in scaled coordinates.

        Returns
        -------
        list of NullGroup
            The groups.
        """
        p, n = self.parameters, len(self.parameters)
        groups = []
        for i in range(self.machine.n_joints):
            T = np.zeros((n, 3))
            for k, c in enumerate("xyz"):
                T[p.index(f"leg{i + 1}.da.{c}"), k] = 1.0
                T[p.index(f"leg{i + 1}.db.{c}"), k] = 1.0
            groups.append(NullGroup(
                f"leg{i + 1}.da + leg{i + 1}.db",
                "the base joint and the platform joint of the leg shifted together change "
                "nothing: only db - da enters the leg equation (seed 001 eq. 5)",
                T / scales[:, None]))
        if not p.fixed[p.index("tracker.x")]:
            T = np.zeros((n, 3))
            for i in range(self.machine.n_joints):
                T[p.indices(f"leg{i + 1}.db"), :] = self.machine.Rphi[i]
            T[p.indices(["tracker.x", "tracker.y", "tracker.z"]), :] = -np.eye(3)
            groups.append(NullGroup(
                "translation of the tracker frame",
                "moving the tracker and shifting every platform joint by the same vector "
                "changes no measurement: the data do not fix the origin of the base frame",
                T / scales[:, None]))
        return groups


def calibrate_tracker(machine: Machine, data: TrackerData, noise: TrackerNoise | None = None,
                      joint: bool = True, robust: bool = False, outlier_threshold: float = 5.0,
                      rtol: float = RTOL, **options) -> CalibrationResult:
    """Identify the error parameters (and the tracker pose) from tracker points.

    The registration starts from the closed form on the nominal model (>= 4 points, not
    collinear). ``robust=True`` rejects outlier rows iteratively: a row whose whitened
    residual norm exceeds ``outlier_threshold`` robust standard deviations (median-based) is
    flagged and left out, and the fit is repeated (at most 10 times) until the set is stable.

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
        Find and leave out outlier rows.
    outlier_threshold : float, optional
        Rejection threshold, in robust standard deviations of the residual norm.
    rtol : float, optional
        Rank tolerance of :func:`levenberg_marquardt`.
    **options
        Passed to :func:`levenberg_marquardt` (``xtol``, ``ftol``, ``max_iter``, ``max_std``;
        ``max_std`` defaults to :data:`MAX_STD`).

    Returns
    -------
    CalibrationResult
        With ``extras``: ``problem``; ``method`` (``"tracker-joint"`` or
        ``"tracker-two-step"``); ``machine``, the calibrated machine with
        ``base_from_tracker``; ``registration``; ``start_registration``; ``outlier_rows``
        (file rows left out); ``kept`` (mask of the rows used); ``unidentifiable``.

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
        raise InputError(f"{data.source}: rows {rows[:10]}: no platform position reproduces "
                         "these actuator readings")
    smr = fk.P - np.array([0.0, 0.0, machine.smr_offset])
    registration = register_points(data.m, smr, f"{data.source}: tracker registration")
    keep = np.ones(len(data), bool)
    for _ in range(10 if robust else 1):
        sub = data.subset(keep)
        problem = TrackerProblem(machine, sub, noise, registration, joint)
        n_id = int(problem.parameters.free.sum()) - (12 if joint else 9)
        if 3 * len(sub) < n_id:
            raise InputError(f"{data.source}: {len(sub)} points give {3 * len(sub)} "
                             f"equations, fewer than the {n_id} identifiable parameters")
        result = levenberg_marquardt(problem, rtol=rtol, **{"max_std": MAX_STD, **options})
        if not robust:
            break
        e_all, _, _ = TrackerProblem(machine, data, noise, registration, joint).evaluate(
            result.state, jacobian=False)
        norm2 = np.sum(e_all**2, -1)
        scale2 = np.median(norm2[keep]) / 2.366                 # chi2(3) median
        new_keep = norm2 <= outlier_threshold**2 * scale2
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    state = result.state
    calibrated = machine.with_parameters(state.u)
    calibrated.base_from_tracker = (state.R, state.t)
    result.extras.update(
        problem=problem,
        method="tracker-joint" if joint else "tracker-two-step", machine=calibrated,
        registration=(state.R, state.t), start_registration=registration,
        outlier_rows=data.rows[~keep], kept=keep,
        unidentifiable=name_null_space(result.null_space, problem.parameters,
                                       problem.null_groups(result.scales))
        + name_weak_directions(result, problem.parameters),
    )
    return result


def predict_tracker_points(machine: Machine, q, base_from_tracker):
    """Tracker-frame SMR points predicted by a model for actuator readings.

    Parameters
    ----------
    machine : Delta
        The model (needs ``smr_offset``).
    q : array_like, shape (K, n_joints)
        Actuator readings, rad.
    base_from_tracker : tuple of array_like
        ``(R (3, 3), t (3,))``: a tracker point ``m`` is ``R m + t`` in the base frame.

    Returns
    -------
    ndarray, shape (K, 3)
        Predicted points, m, tracker frame (NaN where the forward kinematics fail).
    """
    R, t = base_from_tracker
    P = machine.fk(q).P
    return (P - np.array([0.0, 0.0, machine.smr_offset]) - t) @ R


def distance_ratios(machine: Machine, q, m, pairs):
    """Seed 001 Fig. 6: FK distance / tracker distance x 100 % for point pairs (frame-free).

    Parameters
    ----------
    machine : Delta
        The model.
    q : array_like, shape (K, n_joints)
        Actuator readings, rad.
    m : ndarray, shape (K, 3)
        Measured tracker points, m.
    pairs : ndarray of int, shape (M, 2)
        Row index pairs (e.g. :func:`~pkmcal.measurements.neighbour_pairs`).

    Returns
    -------
    ndarray, shape (M,)
        Ratios in percent (100 = distances agree).
    """
    P = machine.fk(q).P
    d_model = np.linalg.norm(P[pairs[:, 0]] - P[pairs[:, 1]], axis=-1)
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
        Result of :func:`calibrate_tracker` (uses ``extras["problem"]``, ``state`` and
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
    problem = result.extras["problem"]
    pseudo = TrackerData(np.atleast_2d(q), np.zeros((len(np.atleast_2d(q)), 3)))
    unit = TrackerProblem(problem.machine, pseudo, None,
                          (problem.R0, problem.t0), joint=True)
    _, J, _ = unit.evaluate(result.state)                    # = -d(prediction)/dx
    return np.einsum("kin,nm,kjm->kij", J, result.covariance, J)
