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

from ..instruments.probe import bed_plane
from ..instruments.setups import Setups
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
        Targets the calibrated model reaches: real inverse kinematics in home's working mode,
        within the machine's physical limits and joint limits
        (:meth:`~pkmcal.machines.Machine.reachability`).
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
    reach : Reachability, optional
        Why each target that is not ``reachable`` cannot be reached.
    """

    q: np.ndarray
    reachable: np.ndarray
    position_std: np.ndarray | None = None
    orientation_std: np.ndarray | None = None
    uncompensated_position: np.ndarray | None = None
    uncompensated_orientation: np.ndarray | None = None
    reach: object = None


def compensate(calibrated: Machine, P, R=None, covariance=None,
               nominal: Machine | None = None, null=None, frame=None,
               names=None, setups: Setups | None = None) -> Compensation:
    """Commands ``q = IK_calibrated(x)`` for targets, with their predicted residual errors.

    Targets are in the calibrated base frame, or, with ``frame``, in the measuring instrument's
    frame (see :mod:`pkmcal.compensation.frames`). In the base frame the residual error is
    predicted from the ``covariance`` of the machine's parameters, with pose changes along the
    unidentifiable directions ``null`` removed by a fit over the workspace (see the module
    docstring); in an instrument frame it is propagated from the covariance of the machine
    and frame parameters together and needs no fit (the instrument-frame pose does not change
    along the unidentifiable directions). The error the ``nominal`` model's commands would
    leave comes from the calibrated model's forward kinematics, base frame, with the same fit.

    Parameters
    ----------
    calibrated : Machine
        The calibrated machine.
    P : array_like, shape (K, 3) or (3,)
        Target positions, m (base frame - a printer's: heights above its bed,
        :meth:`~pkmcal.machines.Machine.targets_in_base` - or the instrument's with
        ``frame``).
    R : array_like, shape (K, 3, 3), optional
        Target orientations (ignored by 3-dof platforms); default identity, or with a tracker
        ``frame`` the home orientation (a tracker's targets are points).
    covariance : array_like, shape (n, n), optional
        Covariance of the parameters (SI): the machine's, in the machine's order; with
        ``frame``, of the parameters ``names``.
    nominal : Machine, optional
        The uncalibrated model, to report what compensation gains.
    null : array_like, shape (n_machine, k), optional
        Unidentifiable directions of the machine's parameters (columns, in the parameters' SI
        units), whose pose changes are removed from base-frame errors.
    frame : TrackerFrame or MocapFrames, optional
        The instrument frame the targets are in (:func:`~pkmcal.compensation.frames.
        target_frame` of the calibrated file).
    names : sequence of str, optional
        With ``frame``: the parameter names of ``covariance``; they must include the machine's
        and the frame's.
    setups : Setups, optional
        The calibrated file's set-ups: base-frame targets of a printer are heights above its
        bed (:meth:`~pkmcal.instruments.setups.Setups.targets_in_base`).

    Returns
    -------
    Compensation
        Commands, reachability and the predicted errors that were asked for.

    Raises
    ------
    ValueError
        When ``covariance`` lacks a parameter of the machine or of ``frame``.
    """
    from ..analysis.prediction import pose_sensitivity

    P = np.atleast_2d(np.asarray(P, float))
    R = None if R is None else np.asarray(R, float)
    if frame is not None:
        P, Rb = frame.to_base(P, R)
        R = R if Rb is None else Rb
        if calibrated.rotates and len(calibrated.pose_space) < 6:
            # a planar platform: a measured target is in its plane up to the instrument's
            # noise; the coordinates it does not move along are its home's
            from ..analysis.accuracy import in_pose_space

            P, R = in_pose_space(calibrated, P, R)
    else:       # a printer's targets are heights above its bed (SPEC 8)
        P = (Setups() if setups is None else setups).targets_in_base(calibrated, P)
    R = np.broadcast_to(np.eye(3), (len(P), 3, 3)) if R is None else R
    q = calibrated.ik(P, R)
    # real IK, near home, in home's working mode, within the physical and joint limits
    reach = calibrated.reachability(P, R, bed=bed_plane(setups))
    out = Compensation(q, reach.ok, reach=reach)
    d = 6 if calibrated.rotates else 3
    needs_fit = null is not None and np.size(null) and (nominal is not None or frame is None)
    S = pose_sensitivity(calibrated, P, R) if covariance is not None or needs_fit else None
    workspace = None
    if needs_fit:
        # the frames are fitted over the workspace (SPEC 5), not over the targets: a few
        # targets would absorb real errors into the fit
        from ..analysis.accuracy import machine_workspace

        Pw, Rw = machine_workspace(calibrated, n=WORKSPACE_FIT_POSES)
        Sw = pose_sensitivity(calibrated, Pw, Rw)
        N = np.asarray(null, float)
        workspace = (Pw, Rw, Sw, np.nan_to_num(np.concatenate([Sw, S])) @ N)
    if covariance is not None:
        C = np.asarray(covariance, float)
        if frame is not None:
            J, C = _instrument_jacobian(calibrated, frame, P, R, S), _ordered(
                C, list(names), [*calibrated.parameters.names, *frame.names])
        else:
            J = S if workspace is None else np.nan_to_num(_aligned(workspace[2], S,
                                                                   workspace[3]))
        var = np.einsum("kdi,ij,kdj->kd", J, C, J)
        out.position_std = np.sqrt(np.clip(var[:, :3].sum(-1), 0, None))
        if d == 6:
            out.orientation_std = np.sqrt(np.clip(var[:, 3:].sum(-1), 0, None))
    if nominal is not None:
        err = _old_command_error(calibrated, nominal, P, R)
        if workspace is not None:
            err_w = _old_command_error(calibrated, nominal, workspace[0], workspace[1])
            err = _aligned(err_w[..., None], err[..., None], workspace[3])[..., 0]
        out.uncompensated_position = np.linalg.norm(err[:, :3], axis=-1)
        out.uncompensated_orientation = np.linalg.norm(err[:, 3:], axis=-1) if d == 6 else None
    return out


def _aligned(E_workspace, E, Z):
    """Pose changes ``E`` (K, d, m) at the targets with what the unidentifiable directions
    explain removed; the fit is made over the workspace, where the same quantity is
    ``E_workspace`` and ``Z`` (workspace + targets, d, k) the pose changes of those
    directions."""
    from ..analysis.prediction import align_out

    nw = len(E_workspace)
    E_all = np.concatenate([E_workspace, E])
    finite = np.all(np.isfinite(E_all), axis=(1, 2)) & np.all(np.isfinite(Z), axis=(1, 2))
    out = align_out(np.nan_to_num(E_all), np.nan_to_num(Z), finite & (np.arange(len(E_all)) < nw))
    out[~finite] = np.nan
    return out[nw:]


def _old_command_error(calibrated, nominal, P, R):
    """Pose error (K, d) (position, small rotation) the calibrated model predicts when the
    ``nominal`` model's commands are sent for poses ``(P, R)``; NaN where it cannot tell."""
    from ..kinematics import rotvec_from_matrix

    d = 6 if calibrated.rotates else 3
    err = np.full((len(P), d), np.nan)
    qn = nominal.ik(P, R)
    good = np.all(np.isfinite(qn), -1) & np.all(np.isfinite(calibrated.ik(P, R)), -1)
    if good.any():
        fk = calibrated.fk(qn[good], start=(P[good], R[good]))
        idx = np.flatnonzero(good)[fk.converged]
        err[idx, :3] = fk.P[fk.converged] - P[idx]
        if d == 6:
            err[idx, 3:] = rotvec_from_matrix(fk.R[fk.converged] @ np.swapaxes(R[idx], -1, -2))
    return err


def _ordered(C, names: list[str], wanted: list[str]) -> np.ndarray:
    """The covariance ``C`` over ``names`` restricted and reordered to ``wanted``.

    A fit of several files names each file's instrument unknowns ``FILE:name``: a wanted
    ``tracker.x`` is then the first file's ``FILE:tracker.x`` (the one whose section the
    calibrated file keeps)."""
    def find(w):
        if w in names:
            return names.index(w)
        prefixed = [i for i, n in enumerate(names) if n.endswith(":" + w)]
        return prefixed[0] if prefixed else None

    idx = [find(w) for w in wanted]
    missing = [w for w, i in zip(wanted, idx, strict=True) if i is None]
    if missing:
        raise ValueError(f"the covariance has no parameter {', '.join(missing[:5])}")
    return C[np.ix_(idx, idx)]


def _instrument_jacobian(calibrated, frame, P, R, S, h: float = 1e-6):
    """d(instrument-frame pose error)/d(machine parameters, frame parameters) at fixed
    commands, (K, d, n + f): the machine part through the pose sensitivity ``S``, the frame
    part through the frame's parameters; central differences of the rigid frame maps."""
    from ..kinematics import matrix_from_rotvec, rotvec_from_matrix

    d = 6 if calibrated.rotates else 3
    Pm0, Rm0 = frame.measure(P, R)

    def error(Pm, Rm):
        if d == 3:
            return Pm
        return np.concatenate([Pm, rotvec_from_matrix(Rm @ np.swapaxes(Rm0, -1, -2))], -1)

    columns = []
    for j in range(S.shape[-1]):
        dx = np.nan_to_num(S[..., j])
        ends = []
        for sign in (1.0, -1.0):
            Rj = R if d == 3 else matrix_from_rotvec(sign * h * dx[:, 3:]) @ R
            ends.append(error(*frame.measure(P + sign * h * dx[:, :3], Rj)))
        columns.append((ends[0] - ends[1]) / (2 * h))
    for j in range(len(frame.names)):
        e = np.zeros(len(frame.names))
        e[j] = h
        columns.append((error(*frame.measure(P, R, e)) - error(*frame.measure(P, R, -e)))
                       / (2 * h))
    J = np.stack(columns, axis=-1)
    J[~np.all(np.isfinite(S), axis=(1, 2))] = np.nan
    return J


from .frames import MocapFrames, TrackerFrame, instrument_frames, target_frame  # noqa: E402

__all__ = ["Compensation", "MocapFrames", "TrackerFrame", "compensate", "instrument_frames",
           "target_frame"]
