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

from ..kinematics import kabsch, matrix_from_euler, rotation_angle
from ..machines.base import Machine


def workspace_poses(center, half_size: float = 0.05, max_angle: float = np.deg2rad(10.0),
                    n: int = 500, rng=None):
    """``n`` poses uniform in the cube ``center +/- half_size`` (m) with Euler angles uniform in
    ``+/- max_angle`` (rad). Returns ``P`` (n, 3), ``R`` (n, 3, 3)."""
    rng = np.random.default_rng(rng)
    P = np.asarray(center, float) + rng.uniform(-half_size, half_size, (n, 3))
    R = matrix_from_euler(rng.uniform(-max_angle, max_angle, (n, 3)))
    return P, R


def machine_workspace(machine: Machine, n: int = 500, rng=0):
    """:func:`workspace_poses` around ``machine``'s home; the identity orientation for a
    translation-only platform (``pose_dof == 3``)."""
    P, R = workspace_poses(machine.home[0], n=n, rng=rng)
    if machine.pose_dof == 3:
        R = np.broadcast_to(np.eye(3), R.shape)
    return P, R


@dataclass
class AccuracyReport:
    """Position (m) and orientation (rad) errors of a model over workspace poses."""

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
        return dict(self.__dict__)


def align_poses(P_hat, R_hat, P_true, R_true):
    """Best-fit base rotation ``G`` about O and platform re-orientation ``C`` with
    ``G P_hat ~ P_true`` and ``G R_hat C ~ R_true``."""
    G = kabsch(P_hat, P_true)
    M = np.einsum("kji,kjl->il", G @ R_hat, R_true)        # sum (G R_hat)^T R_true
    U, _, Vt = np.linalg.svd(M)
    C = U @ np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return G, C


def pose_errors(true_machine: Machine, model_machine: Machine, P, R, align: bool = True):
    """Per-pose position (m) and orientation (rad) errors; NaN where FK fails.

    Returns ``(dp, dr, converged, (G, C))``.
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

    Poses default to :func:`workspace_poses` around the true machine's home.
    """
    if P is None:
        P, R = workspace_poses(true_machine.home[0], n=n, rng=rng)
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
