"""Predicted pose accuracy after calibration, before measuring (SPEC 3, Cramer-Rao).

With the information ``M`` of a (planned) measurement set (:mod:`pkmcal.planning.design`),
the Cramer-Rao bound of the identifiable scaled parameters is ``M^-1``. A calibrated model
commands joints ``q = IK(x)`` and believes the platform is at ``FK_model(q)``; to first order
its pose error is ``dx = S du`` with the *pose sensitivity* ``S = -(dq/dx)^-1 dq/du`` at fixed
joints. So the predicted pose covariance at a workspace pose is ``E M^-1 E^T`` with
``E = S D V`` (``D`` column scales, ``V`` identifiable basis).

Gauge. What the data cannot identify must not count as error when it only moves a frame: the
same rule as :func:`pkmcal.analysis.accuracy.pose_errors` (SPEC 5). The pose changes that the
unidentifiable directions produce are removed by least squares, positions first (e.g. the
rotation of the base about O), then orientations (e.g. the re-orientation of the platform
about P) - the linearisation of the best-fit alignment used on calibrated models. An
unidentifiable direction that moves the platform in a way no change of base or platform frame
can (a real blind spot of the plan) makes the prediction unbounded: it is reported, not hidden.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kinematics import skew
from ..machines.base import Machine

#: relative residual above which a pose change is not a change of frames
FRAME_TOL = 1e-6


def pose_sensitivity(machine: Machine, P, R, u=None) -> np.ndarray:
    """``dx/du`` at fixed joints, (K, d, n_params): ``d = 6`` (position, small rotation in base
    axes) or 3 for translation-only machines; NaN where a pose is singular or unreachable.
    The pose moves along :attr:`~pkmcal.machines.Machine.pose_space` (the rows of the other
    coordinates are 0: a planar platform's z, rx, ry)."""
    q, Jp, Ju = machine.ik_jacobians(P, R, u)
    d = 6 if machine.rotates else 3
    space = list(machine.pose_space)
    Jp = Jp[..., space]
    ok = np.all(np.isfinite(q), -1) & np.all(np.isfinite(Jp), (-1, -2))
    S = np.full(Ju.shape[:-2] + (d, Ju.shape[-1]), np.nan)
    if ok.any():
        if len(space) == d:
            S[ok] = -np.linalg.solve(Jp[ok], Ju[ok])
        else:
            Sk = np.zeros((int(ok.sum()), d, Ju.shape[-1]))
            Sk[:, space] = -np.linalg.solve(Jp[ok], Ju[ok])
            S[ok] = Sk
    return S


def frame_motions(P, R, dof: int = 6) -> np.ndarray:
    """Pose changes (K, d, 12) of small motions of the frames: base rotation and translation,
    platform re-orientation and origin shift (platform axes)."""
    P = np.asarray(P, float)
    K = len(P)
    out = np.zeros((K, 6, 12))
    out[:, :3, 0:3] = -skew(P)                  # omega x P
    out[:, 3:, 0:3] = np.eye(3)
    out[:, :3, 3:6] = np.eye(3)
    out[:, 3:, 6:9] = R                         # R omega_C
    out[:, :3, 9:12] = R                        # R t_C
    return out[:, :dof]


def align_out(E, Z, fit=None):
    """Remove from pose changes ``E`` (K, d, n) what the frame changes ``Z`` (K, d, z) explain:
    least squares on positions first, then on orientations with what positions left free.
    ``fit`` (K,) bool: the poses the best fit is made over (default all); the fitted frame
    change is removed from every pose. Returns the aligned ``E`` (same shape)."""
    K, d, n = E.shape
    if Z.shape[-1] == 0:
        return E
    fit = np.ones(K, bool) if fit is None else np.asarray(fit, bool)
    Ep, Zp = E[:, :3].reshape(3 * K, n), Z[:, :3].reshape(3 * K, -1)
    fp = np.repeat(fit, 3)
    Zf = Zp[fp]
    w1 = np.linalg.pinv(Zf, rcond=1e-10) @ Ep[fp]
    out = np.array(E)
    out[:, :3] = (Ep - Zp @ w1).reshape(K, 3, n)
    if d == 6:
        Er, Zr = E[:, 3:].reshape(3 * K, n), Z[:, 3:].reshape(3 * K, -1)
        # all z right singular vectors; the (3K, 3K) left factor only where Zf is wide (a
        # tall Zf, 3K >> z, gives the same s and Vt without it: ~100 ms -> <1 ms at K = 400)
        _, s, Vt = np.linalg.svd(Zf, full_matrices=Zf.shape[0] < Zf.shape[1])
        rank = int(np.sum(s > 1e-10 * s[0])) if s.size and s[0] > 0 else 0
        Np = Vt[rank:].T                                  # frame changes positions leave free
        T = Er - Zr @ w1
        B = Zr @ Np
        w2 = np.linalg.pinv(B[fp], rcond=1e-10) @ T[fp] if B.shape[1] else np.zeros((0, n))
        out[:, 3:] = (T - B @ w2).reshape(K, 3, n)
    return out


@dataclass
class PoseErrorOperator:
    """Aligned first-order pose error ``dx_k = E_k g`` for identifiable coordinates ``g``
    (scaled, in the basis ``V`` of a design)."""

    P: np.ndarray
    R: np.ndarray
    E: np.ndarray                      # (K, d, p)
    Z: np.ndarray                      # (K, d, z) pose changes of the unidentifiable directions
    unbounded: int                     # unidentifiable directions that move the platform

    def align(self, dx) -> np.ndarray:
        """Pose errors ``dx`` (K, d) (e.g. of a calibrated model, position then small rotation)
        with what the unidentifiable directions explain removed, as in the prediction."""
        return align_out(np.asarray(dx, float)[..., None], self.Z)[..., 0]

    @property
    def A(self) -> np.ndarray:
        """``sum_k E_pos,k^T E_pos,k / K`` (p, p): ``trace(A C)`` is the mean squared
        position error for a covariance ``C`` of ``g``."""
        Ep = self.E[:, :3]
        return np.einsum("kdi,kdj->ij", Ep, Ep) / len(Ep)


def pose_error_operator(machine: Machine, design, P, R, n_machine: int | None = None):
    """:class:`PoseErrorOperator` of a design at workspace poses ``(P, R)``.

    The first ``n_machine`` problem parameters are the machine's (default: all of
    ``machine.parameters``); the others (link length, measurement frames) do not change
    what the model believes about poses.
    """
    n_machine = len(machine.parameters) if n_machine is None else n_machine
    S = pose_sensitivity(machine, P, R)
    K, d = S.shape[:2]
    n = len(design.free)
    full = np.zeros((K, d, n))
    full[..., :n_machine] = S
    E = (full * design.scales)[..., design.free]           # scaled free coordinates
    Z = E @ design.null                                     # what the gauge directions do
    unbounded = 0
    if Z.shape[-1]:
        Fm = frame_motions(P, R, d).reshape(K * d, -1)
        Zs = Z.reshape(K * d, -1)
        fit = Fm @ (np.linalg.pinv(Fm, rcond=1e-10) @ Zs)
        size = np.linalg.norm(E.reshape(K * d, -1), axis=0).max()
        resid = np.linalg.norm(Zs - fit, axis=0)
        unbounded = int(np.sum(resid > FRAME_TOL * max(size, 1e-300)))
    return PoseErrorOperator(np.asarray(P), np.asarray(R), align_out(E, Z) @ design.V, Z,
                             unbounded)


@dataclass
class PosePrediction:
    """Predicted 1-sigma pose errors after calibration at workspace poses."""

    P: np.ndarray
    R: np.ndarray
    position: np.ndarray               # (K,) sqrt(trace of the 3x3 position covariance), m
    orientation: np.ndarray | None     # (K,) the same for orientation, rad (None: 3-dof)
    unbounded: int

    def summary(self) -> dict:
        """RMS, max and 95th percentile over the poses (m, rad)."""
        def stats(v):
            if v is None:
                return None
            return {"rms": float(np.sqrt(np.mean(v**2))), "max": float(np.max(v)),
                    "p95": float(np.percentile(v, 95))}
        return {"poses": int(len(self.position)), "position": stats(self.position),
                "orientation": stats(self.orientation), "unbounded": self.unbounded}


def predict_pose_accuracy(machine: Machine, design, P, R, M=None,
                          n_machine: int | None = None, op=None) -> PosePrediction:
    """Cramer-Rao predicted pose errors at ``(P, R)`` for the information ``M`` (default: the
    whole design's). Infinite where the plan leaves a pose-moving direction unidentified.
    ``op``: the :func:`pose_error_operator` at these poses, when already computed."""
    M = design.information() if M is None else M
    op = pose_error_operator(machine, design, P, R, n_machine) if op is None else op
    try:
        C = np.linalg.inv(M)
    except np.linalg.LinAlgError:
        C = np.full_like(M, np.inf)
    var = np.einsum("kdi,ij,kdj->kd", op.E, C, op.E)
    pos = np.sqrt(np.clip(var[:, :3].sum(-1), 0, None))
    ori = np.sqrt(np.clip(var[:, 3:].sum(-1), 0, None)) if var.shape[1] == 6 else None
    if op.unbounded:
        pos = np.full_like(pos, np.inf)
        ori = None if ori is None else np.full_like(ori, np.inf)
    return PosePrediction(op.P, op.R, pos, ori, op.unbounded)
