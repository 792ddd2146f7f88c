"""The tracker's estimation problem (:class:`TrackerProblem`: the machine's parameters, the
tracker pose and the targets' places), the calibration (:func:`calibrate_tracker`) and what a
calibrated model predicts (:func:`predict_tracker_points`, :func:`prediction_covariance`)."""

from __future__ import annotations

import numpy as np

from ...errors import InputError
from ...estimation.estimator import (
    MAX_STD,
    CalibrationResult,
    levenberg_marquardt,
    require_redundancy,
)
from ...estimation.rank import RTOL
from ...estimation.variance import OUTLIER_ALPHA, fit
from ...identifiability import name_null_space, name_weak_directions
from ...machines.base import Machine
from ...paths import path_text
from ..data import InstrumentData
from ..models import PointsModel
from ..problem import InstrumentProblem, InstrumentState
from .data import TrackerData, as_points
from .noise import TrackerNoise
from .section import TrackerSection

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


def registration_of(state) -> tuple[np.ndarray, np.ndarray]:
    """``base_from_tracker = (R, t)`` of a tracker problem's state."""
    v = state.nuisance.values
    return state.nuisance.rotations[0], np.array(v[3:6], float)


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
        ``machine``, the calibrated machine; ``unidentifiable``;
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
