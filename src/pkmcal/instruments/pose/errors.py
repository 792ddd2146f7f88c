"""How well a full-pose model explains data, and its error against a known truth.

Per-row errors (:class:`FullPoseErrors`, :func:`full_pose_errors`); the gauge orbit of an
estimate aligned to a reference (:func:`align_to`) and its gauge-free error
(:func:`gauge_free_error`).
"""


from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...estimation.estimator import CalibrationResult
from ...estimation.registration import register_points
from ...kinematics import matrix_from_rotvec, rotvec_from_matrix
from ...machines.base import Machine
from .data import FullPoseData, MeasurementFrames
from .section import PoseSection


@dataclass
class FullPoseErrors:
    """How well a model with its frames explains full-pose data.

    Attributes
    ----------
    leg_length : ndarray, shape (K, n_joints)
        The reading minus the reading at the measured pose (mapped through the frames), as a
        length (:meth:`~pkmcal.machines.Machine.reading_sigma`: a Stewart's ``l0 + gain q``
        minus the leg length up to the gain's sign), m.
    position : ndarray, shape (K,)
        Distance between the measured marker position and the one predicted by forward
        kinematics of the readings, m (NaN where it did not converge).
    orientation : ndarray, shape (K,)
        Angle between the measured and the predicted marker orientation, rad (NaN where the
        forward kinematics did not converge).
    converged : ndarray of bool, shape (K,)
        Forward kinematics converged.
    """

    leg_length: np.ndarray
    position: np.ndarray
    orientation: np.ndarray
    converged: np.ndarray

    def summary(self) -> dict:
        """RMS and maximum of each error (SI units), over the converged rows for poses.

        Returns
        -------
        dict
            ``leg_length_rms``, ``leg_length_max``, ``leg_length_rms_per_leg`` (list of 6),
            ``position_rms``, ``position_max`` (m), ``orientation_rms``, ``orientation_max``
            (rad), ``poses`` and ``fk_failed`` (counts).
        """
        ok = self.converged

        def rms(v):
            return float(np.sqrt(np.mean(v**2))) if v.size else float("nan")

        return {
            "leg_length_rms": rms(self.leg_length),
            "leg_length_max": float(np.max(np.abs(self.leg_length))),
            "leg_length_rms_per_leg": np.sqrt(np.mean(self.leg_length**2, axis=0)).tolist(),
            "position_rms": rms(self.position[ok]),
            "position_max": float(np.max(self.position[ok])) if ok.any() else float("nan"),
            "orientation_rms": rms(self.orientation[ok]),
            "orientation_max": float(np.max(self.orientation[ok])) if ok.any()
            else float("nan"),
            "poses": int(len(ok)), "fk_failed": int((~ok).sum()),
        }


def full_pose_errors(machine: Machine, frames: MeasurementFrames,
                     data: FullPoseData) -> FullPoseErrors:
    """Leg-length residuals and pose errors of ``machine`` with ``frames`` on ``data``.

    Parameters
    ----------
    machine : Stewart
        The model to test.
    frames : MeasurementFrames
        Its measurement frames.
    data : FullPoseData
        Leg readings and measured marker poses.

    Returns
    -------
    FullPoseErrors
        Per-row errors.
    """
    P, R = frames.platform(data.P, data.R)
    # reading residual as a length: over the reading noise per metre (a Stewart's |gain|)
    leg = (data.q - machine.ik(P, R)) / machine.reading_sigma(1.0)
    fk = machine.fk(data.q)
    Pm, Rm = frames.measured(fk.P, fk.R)
    pos = np.linalg.norm(Pm - data.P, axis=-1)
    ang = np.linalg.norm(rotvec_from_matrix(Rm @ np.swapaxes(data.R, -1, -2)), axis=-1)
    ok = fk.converged
    return FullPoseErrors(leg, np.where(ok, pos, np.nan), np.where(ok, ang, np.nan), ok)


def align_to(machine: Machine, u, frames: MeasurementFrames, u_ref):
    """The member of the gauge orbit of ``(u, frames)`` closest to ``u_ref``.

    The base joints are moved by the rigid motion that best fits them to ``u_ref``'s (Horn),
    the platform joints likewise, and the frames by the inverse motions, so the aligned pair
    predicts exactly the same data. Used to compare an estimate with a known truth (SPEC 5)
    when the frames were unknown.

    Parameters
    ----------
    machine : Stewart
        Any machine of the family (used for its parameter layout and transforms).
    u : array_like, shape (48,)
        Leg parameters to align.
    frames : MeasurementFrames
        The frames that go with ``u``.
    u_ref : array_like, shape (48,)
        Reference leg parameters (e.g. the truth).

    Returns
    -------
    u_aligned : ndarray, shape (48,)
        Aligned leg parameters.
    frames_aligned : MeasurementFrames
        The frames moved by the inverse motions.
    """
    if callable(getattr(machine, "legs", None)):
        # a six-leg platform: the joints themselves, registered in closed form (Horn)
        b, p, _, _ = machine.legs(u)
        b_ref, p_ref, _, _ = machine.legs(u_ref)
        G, g = register_points(b, b_ref, "base joints")
        H, h = register_points(p, p_ref, "platform joints")  # p' = H p + h = C^T (p - c0)
        C, c0 = H.T, -H.T @ h
    else:
        G, g, C, c0 = _frame_motions_towards(machine, u, u_ref)
    u1 = machine.transform_platform(machine.transform_base(u, G, g), C, c0)
    (A, a), (B, c) = frames.mocap_from_base, frames.platform_from_marker
    return u1, MeasurementFrames((A @ G.T, a - A @ G.T @ g), (C.T @ B, C.T @ (c - c0)))


def _frame_motions_towards(machine: Machine, u, u_ref):
    """The base and platform rigid motions that bring ``u`` nearest ``u_ref`` (scaled least
    squares over :meth:`~pkmcal.machines.Machine.transform_base` and ``transform_platform``
    with translations), for machines without a closed form."""
    from scipy.optimize import least_squares

    scales = machine.parameter_scales()
    L = machine.characteristic_length()

    def motions(x):
        return (matrix_from_rotvec(x[:3]), x[3:6] * L, matrix_from_rotvec(x[6:9]), x[9:] * L)

    def residual(x):
        G, g, C, c0 = motions(x)
        return (machine.transform_platform(machine.transform_base(u, G, g), C, c0)
                - u_ref) / scales

    return motions(least_squares(residual, np.zeros(12), xtol=1e-15, ftol=1e-15,
                                 gtol=1e-15).x)


def gauge_free_error(machine: Machine, result: CalibrationResult, u_true,
                     frames_true: MeasurementFrames) -> np.ndarray:
    """Error of a full-pose estimate against a known truth, in scaled increment coordinates.

    Leg parameters after :func:`align_to` (when the machine was fitted and at least one frame
    was estimated), then the frames as rotation increments and translations, each divided by
    the estimator's column scale.

    Parameters
    ----------
    machine : Stewart
        Machine of the family (for :func:`align_to`).
    result : CalibrationResult
        Result of :func:`calibrate_full_pose` (uses ``problem`` and its
        :class:`PoseSection`).
    u_true : array_like, shape (48,)
        True leg parameters.
    frames_true : MeasurementFrames
        True frames.

    Returns
    -------
    ndarray, shape (60,)
        Scaled errors: 48 leg parameters, then 12 frame coordinates.
    """
    problem = result.problem
    frames = result.section(PoseSection).frames
    u = result.x[:problem.n_machine]
    if problem.fit_machine and not all(problem.fixed_frames):
        u, frames = align_to(machine, u, frames, u_true)
    (A, a), (B, c) = frames.mocap_from_base, frames.platform_from_marker
    (At, at), (Bt, ct) = frames_true.mocap_from_base, frames_true.platform_from_marker
    e = np.concatenate([u - u_true, rotvec_from_matrix(A @ At.T), a - at,
                        rotvec_from_matrix(B @ Bt.T), c - ct])
    return e / result.scales
