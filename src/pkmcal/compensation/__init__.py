"""Compensation (SPEC 4): joint commands from a calibrated model, and what is left.

The calibrated model's inverse kinematics gives the commands that put the real machine on the
targets. What is left is the calibration's own uncertainty: with the covariance ``C`` of the
identified parameters, the pose error at a target is, to first order, ``S C S^T`` with the
pose sensitivity ``S = -(dq/dx)^-1 dq/du`` at fixed joints
(:func:`pkmcal.analysis.prediction.pose_sensitivity`). Directions the data cannot fix (e.g. the
base orientation about O with a constraint link) keep the machine file's values: the targets
are in the calibrated model's frames, and the pose changes along those directions (``null``)
are removed from the predicted error by a best fit over the SPEC 5 workspace around home
(not over the targets, which may be few) - a machine tool's work offsets are set on the
calibrated machine anyway.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..machines.base import Machine

#: workspace poses (SPEC 5 cube around home) the unseen frames are fitted over
WORKSPACE_FIT_POSES = 300


@dataclass
class Compensation:
    """Joint commands for targets and their predicted residual errors.

    Attributes
    ----------
    q : ndarray, shape (K, n_joints)
        Commands, internal units (NaN where a target is unreachable).
    reachable : ndarray of bool, shape (K,)
        Targets the calibrated model reaches.
    position_std : ndarray, shape (K,), optional
        Predicted 1-sigma residual position error, m, from the calibration's covariance; None
        without one.
    orientation_std : ndarray, shape (K,), optional
        The same for the orientation, rad; None without a covariance or for 3-dof platforms.
    uncompensated_position : ndarray, shape (K,), optional
        How far the calibrated model says the platform would be from the target when commanded
        with the ``nominal`` model, m; NaN where that cannot be computed; None without
        ``nominal``.
    uncompensated_orientation : ndarray, shape (K,), optional
        The same for the orientation, rad; None without ``nominal`` or for 3-dof platforms.
    """

    q: np.ndarray
    reachable: np.ndarray
    position_std: np.ndarray | None = None
    orientation_std: np.ndarray | None = None
    uncompensated_position: np.ndarray | None = None
    uncompensated_orientation: np.ndarray | None = None


def compensate(calibrated: Machine, P, R=None, covariance=None,
               nominal: Machine | None = None, null=None) -> Compensation:
    """Commands ``q = IK_calibrated(x)`` for targets, with their predicted residual errors.

    The residual error is predicted from the ``covariance`` of the calibrated machine's
    parameters, with pose changes along the unidentifiable directions ``null`` removed by a
    fit over the workspace (see the module docstring); the error the ``nominal`` model's
    commands would leave comes from the calibrated model's forward kinematics.

    Parameters
    ----------
    calibrated : Machine
        The calibrated machine.
    P : array_like, shape (K, 3) or (3,)
        Target positions, m.
    R : array_like, shape (K, 3, 3), optional
        Target orientations (ignored by 3-dof platforms); default identity.
    covariance : array_like, shape (n, n), optional
        Covariance of the calibrated machine's parameters (SI).
    nominal : Machine, optional
        The uncalibrated model, to report what compensation gains.
    null : array_like, shape (n, k), optional
        Unidentifiable directions of the parameters (columns, in the parameters' SI units),
        whose pose changes are removed from the predicted error.

    Returns
    -------
    Compensation
        Commands, reachability and the predicted errors that were asked for.
    """
    from ..analysis.prediction import align_out, pose_sensitivity
    from ..kinematics import rotation_angle

    P = np.atleast_2d(np.asarray(P, float))
    R = np.broadcast_to(np.eye(3), (len(P), 3, 3)) if R is None else np.asarray(R, float)
    q = calibrated.ik(P, R)
    ok = np.all(np.isfinite(q), -1)
    out = Compensation(q, ok)
    if covariance is not None:
        C = np.asarray(covariance, float)
        S = pose_sensitivity(calibrated, P, R)
        if null is not None and np.size(null):
            # the frames are fitted over the workspace (SPEC 5), not over the targets: a
            # few targets would absorb real errors into the fit
            from ..analysis.accuracy import machine_workspace

            Pw, Rw = machine_workspace(calibrated, n=WORKSPACE_FIT_POSES)
            S_all = np.concatenate([pose_sensitivity(calibrated, Pw, Rw), S])
            fit = np.arange(len(S_all)) < len(Pw)
            fit &= np.all(np.isfinite(S_all), axis=(1, 2))
            N = np.asarray(null, float)
            S = align_out(np.nan_to_num(S_all), np.nan_to_num(S_all) @ N, fit)[len(Pw):]
        var = np.einsum("kdi,ij,kdj->kd", S, C, S)
        out.position_std = np.sqrt(np.clip(var[:, :3].sum(-1), 0, None))
        if calibrated.pose_dof == 6:
            out.orientation_std = np.sqrt(np.clip(var[:, 3:].sum(-1), 0, None))
    if nominal is not None:
        qn = nominal.ik(P, R)
        good = ok & np.all(np.isfinite(qn), -1)
        dp = np.full(len(P), np.nan)
        dr = np.full(len(P), np.nan)
        if good.any():
            fk = calibrated.fk(qn[good], start=(P[good], R[good]))
            conv = fk.converged
            idx = np.flatnonzero(good)[conv]
            dp[idx] = np.linalg.norm(fk.P[conv] - P[idx], axis=-1)
            if calibrated.pose_dof == 6:
                dr[idx] = rotation_angle(np.swapaxes(R[idx], -1, -2) @ fk.R[conv])
        out.uncompensated_position = dp
        out.uncompensated_orientation = dr if calibrated.pose_dof == 6 else None
    return out


__all__ = ["Compensation", "compensate"]
