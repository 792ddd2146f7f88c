"""Pose accuracy over a workspace (SPEC 5).

Sample true poses (default: the 0.1 m cube around home, orientations within +/-10 deg), compute
the joint values the *true* machine needs for them, ``q = IK_true(x)``, and the poses the
*model* believes these joints give, ``x_hat = FK_model(q)``. When the data cannot fix the frames
(constraint link: rotation of the base about O, re-orientation of the platform about P) the
model's frames are first aligned to the truth — a best-fit rotation about O for positions and a
constant platform re-orientation for orientations — and the report says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kinematics import kabsch, rotation_angle
from ..machines.base import Machine
from ..machines.reach import (  # noqa: F401  (where accuracy is evaluated)
    Workspace,
    box_workspace,
    default_workspace,
    in_pose_space,
    machine_workspace,
    workspace_poses,
)


@dataclass
class AccuracyReport:
    """Position (m) and orientation (rad) errors of a model over workspace poses.

    Attributes
    ----------
    position_mean, position_max : float
        Mean and largest position error over the poses that converged, m.
    orientation_mean, orientation_max : float
        Mean and largest orientation error, rad.
    n_poses : int
        Number of poses.
    n_failed : int
        Poses the true machine cannot reach or the model's forward kinematics did not solve.
    aligned : bool
        Whether the model's frames were aligned to the truth first.
    base_alignment_angle : float, optional
        Angle of the best-fit base rotation about O, rad (0 without alignment).
    platform_alignment_angle : float, optional
        Angle of the best-fit platform re-orientation, rad.
    """

    position_mean: float
    position_max: float
    orientation_mean: float
    orientation_max: float
    n_poses: int
    n_failed: int
    aligned: bool
    base_alignment_angle: float = 0.0
    platform_alignment_angle: float = 0.0

    def as_dict(self) -> dict:
        """The report as a dict of its fields.

        Returns
        -------
        dict
            Field name to value (SI units).
        """
        return dict(self.__dict__)


def align_poses(P_hat, R_hat, P_true, R_true):
    """Best-fit base rotation ``G`` about O and platform re-orientation ``C``.

    ``G P_hat ~ P_true`` (Kabsch) and then ``G R_hat C ~ R_true``.

    Parameters
    ----------
    P_hat : array_like, shape (K, 3)
        Model positions, m.
    R_hat : array_like, shape (K, 3, 3)
        Model orientations.
    P_true : array_like, shape (K, 3)
        True positions, m.
    R_true : array_like, shape (K, 3, 3)
        True orientations.

    Returns
    -------
    G : ndarray, shape (3, 3)
        Base rotation.
    C : ndarray, shape (3, 3)
        Platform re-orientation.
    """
    G = kabsch(P_hat, P_true)
    M = np.einsum("kji,kjl->il", G @ R_hat, R_true)        # sum (G R_hat)^T R_true
    U, _, Vt = np.linalg.svd(M)
    C = U @ np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return G, C


def pose_errors(true_machine: Machine, model_machine: Machine, P, R, align: bool = True):
    """Per-pose position and orientation errors of a model against the truth.

    The true machine's joints at the poses, ``q = IK_true(P, R)``, are run through the model's
    forward kinematics; with ``align`` (and at least 3 good poses) the model's frames are
    aligned to the truth first (:func:`align_poses`).

    Parameters
    ----------
    true_machine : Machine
        The true machine.
    model_machine : Machine
        The model (e.g. a calibrated machine).
    P : ndarray, shape (K, 3)
        True poses' positions, m.
    R : ndarray, shape (K, 3, 3)
        True poses' orientations.
    align : bool, optional
        Align the frames before comparing.

    Returns
    -------
    dp : ndarray, shape (K,)
        Position errors, m; NaN where unreachable or the forward kinematics failed.
    dr : ndarray, shape (K,)
        Orientation errors, rad; NaN likewise.
    converged : ndarray of bool, shape (K,)
        Poses with a result.
    alignment : tuple of ndarray
        ``(G, C)`` used (identities without alignment).
    """
    q = true_machine.ik(P, R)
    reachable = np.all(np.isfinite(q), -1)
    fk = model_machine.fk(np.where(reachable[:, None], q, model_machine.ik(*model_machine.home)))
    ok = fk.converged & reachable
    G, C = np.eye(3), np.eye(3)
    if align and ok.sum() >= 3:
        G, C = align_poses(fk.P[ok], fk.R[ok], P[ok], R[ok])
    P_hat = fk.P @ G.T
    R_hat = G @ fk.R @ C
    dp = np.where(ok, np.linalg.norm(P_hat - P, axis=-1), np.nan)
    dr = np.where(ok, rotation_angle(np.swapaxes(R, -1, -2) @ R_hat), np.nan)
    return dp, dr, ok, (G, C)


def pose_accuracy(true_machine: Machine, model_machine: Machine, P=None, R=None,
                  align: bool = True, n: int = 500, rng=0) -> AccuracyReport:
    """Mean and max position/orientation error of ``model_machine`` against the truth.

    Parameters
    ----------
    true_machine : Machine
        The true machine.
    model_machine : Machine
        The model.
    P : ndarray, shape (K, 3), optional
        Positions, m; default :func:`machine_workspace` of the true machine (around its home;
        no rotation for a translation-only platform).
    R : ndarray, shape (K, 3, 3), optional
        Orientations; ignored (replaced) when ``P`` is None.
    align : bool, optional
        Align the model's frames to the truth first.
    n : int, optional
        Number of default poses.
    rng : int, numpy.random.Generator or None, optional
        Seed of the default poses.

    Returns
    -------
    AccuracyReport
        Means and maxima over the poses that converged (NaN if none did).
    """
    if P is None:
        P, R = machine_workspace(true_machine, n=n, rng=rng)
    dp, dr, ok, (G, C) = pose_errors(true_machine, model_machine, P, R, align)
    return AccuracyReport(
        position_mean=float(np.nanmean(dp)) if ok.any() else float("nan"),
        position_max=float(np.nanmax(dp)) if ok.any() else float("nan"),
        orientation_mean=float(np.nanmean(dr)) if ok.any() else float("nan"),
        orientation_max=float(np.nanmax(dr)) if ok.any() else float("nan"),
        n_poses=int(len(P)), n_failed=int((~ok).sum()), aligned=align,
        base_alignment_angle=float(rotation_angle(G)),
        platform_alignment_angle=float(rotation_angle(C)),
    )
