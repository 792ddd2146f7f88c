"""Calibration of a six-leg platform from full-pose measurements (SPEC 2.4).

The measured marker pose is ``mocap_from_base * base_from_platform(q; u) * platform_from_marker``
(:mod:`pkmcal.instruments.pose`). Unknowns: the 48 leg parameters and, unless the user
fixes them, the two measurement frames, 6 each (``mocap_from_base.rx/ry/rz``: rotation
increments about the measurement axes, applied on the left of the start value;
``mocap_from_base.x/y/z``: the translation ``a``; ``platform_from_marker.rx/ry/rz/x/y/z``
likewise for ``(B, c)``, rotations about the platform axes). Two methods share the estimator
(:func:`~pkmcal.estimation.estimator.levenberg_marquardt`):

``ik`` (Zhuang, Yan & Masory 1998)
    Inverse-kinematic residuals: each measured pose is mapped through the frames to a platform
    pose, ``e_k = (q_k - IK(A^T (Pm - a) - R c, A^T Rm B^T; u)) / sigma_q``. No per-pose
    unknowns; the measured poses are taken as exact by the estimate. Their noise is carried
    into the chi-square (:meth:`FullPoseIK.noise_whitened`): the residual of a pose has the
    covariance ``diag(sigma_q^2) + J_x Sigma_x J_x^T``.
``ml`` (default)
    Maximum likelihood: the platform pose of every measurement is an unknown (6 per pose,
    eliminated by the estimator's Schur machinery); residuals are the six readings
    ``(q - IK(x_k; u)) / sigma_q``, the measured position ``(Pm - A (P_k + R_k c) - a) /
    sigma_p`` and orientation ``log(Rm (A R_k B)^T) / sigma_o``. Every measured quantity is
    noisy.

``sigma_q = noise.reading_m / |gain|`` per leg (nominal gains): the reading noise is stated as
a leg length.

Identifiability. Moving every base joint by one rigid motion and ``mocap_from_base`` by its
inverse changes nothing measured (6 directions); so does moving every platform joint by a rigid
motion and ``platform_from_marker`` by its inverse (6): with both frames unknown 48 of the 60
directions are identifiable. A frame the user fixes breaks its gauge, and all 48 leg
parameters become identifiable by themselves. Both gauges are named in words
(:meth:`FullPoseProblem.null_groups`); anything else the data cannot fix (e.g. ``l0`` against
``gain`` when a leg's readings barely vary) is named by its parameters.
"""


from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ...estimation.acceptance import chi_square_test
from ...estimation.estimator import MAX_STD, CalibrationResult, reduce_local, require_redundancy
from ...estimation.rank import RTOL, rank_rule
from ...estimation.registration import register_points
from ...estimation.variance import fit
from ...identifiability import name_null_space, name_weak_directions
from ...identifiability.analysis import right_singular
from ...kinematics import matrix_from_rotvec, rotvec_from_matrix, skew
from ...machines.base import Machine
from ...parameters import ParameterSet
from ...paths import path_text
from .data import FullPoseData, FullPoseNoise, MeasurementFrames
from .section import PoseSection

FRAME_NAMES = ("mocap_from_base", "platform_from_marker")
FRAME_FIELDS = ("rx", "ry", "rz", "x", "y", "z")
#: what each frame is, in words (identifiability reports)
FRAME_WORDS = {"mocap_from_base": "the measurement frame",
               "platform_from_marker": "the marker's place on the platform"}
METHODS = ("ml", "ik")


def frame_parameters(frames: MeasurementFrames, fixed=(False, False)) -> ParameterSet:
    """Registry of the two frames: rotation increments (0 at ``frames``) and translations."""
    (_, a), (_, c) = frames.mocap_from_base, frames.platform_from_marker
    names = [f"{f}.{k}" for f in FRAME_NAMES for k in FRAME_FIELDS]
    kinds = (("angle",) * 3 + ("length",) * 3) * 2
    values = np.concatenate([np.zeros(3), a, np.zeros(3), c])
    return ParameterSet(names, kinds, values, fixed=[fixed[0]] * 6 + [fixed[1]] * 6)


def _require_full_space(machine: Machine) -> None:
    """InputError unless the platform moves along all six pose coordinates."""
    if not machine.rotates:
        raise InputError("full-pose data need a platform that rotates; this machine's "
                         "platform only translates: calibrate it from points")
    if len(machine.pose_space) != 6:
        raise InputError("full-pose data need a platform that moves in space (six pose "
                         "coordinates); this machine's platform moves in a plane: calibrate "
                         "it from points")


@dataclass
class FullPoseState:
    """Estimator state: leg parameters, the two frames and (``ml``) the platform poses."""

    u: np.ndarray
    A: np.ndarray
    a: np.ndarray
    B: np.ndarray
    c: np.ndarray
    P: np.ndarray | None = None
    R: np.ndarray | None = None

    def frames(self) -> MeasurementFrames:
        return MeasurementFrames((self.A, self.a), (self.B, self.c))


def right_jacobian_inverse(phi):
    """``Jr^-1(phi)`` (..., 3, 3): ``log(exp(phi) exp(eps)) = phi + Jr^-1(phi) eps + O(eps^2)``.

    ``Jr^-1 = I + [phi]x / 2 + (1/t^2 - (1 + cos t) / (2 t sin t)) [phi]x^2``, ``t = |phi|``.
    """
    phi = np.asarray(phi, float)
    t2 = np.sum(phi * phi, axis=-1)
    t = np.sqrt(t2)
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    coef = np.where(small, 1.0 / 12.0 + t2 / 720.0,
                    1.0 / ts**2 - (1.0 + np.cos(ts)) / (2.0 * ts * np.sin(ts)))
    K = skew(phi)
    return np.eye(3) + 0.5 * K + coef[..., None, None] * (K @ K)


class FullPoseProblem:
    """What both methods share: parameters = the machine's + the two frames.

    Parameters
    ----------
    machine : Stewart
        Start geometry (a six-leg platform).
    data : FullPoseData
        Leg readings and measured marker poses.
    noise : FullPoseNoise
        Standard deviations that whiten the residuals.
    frames : MeasurementFrames
        Start (or fixed) values of the two frames.
    fixed_frames : tuple of bool, optional
        ``(mocap_from_base, platform_from_marker)``: hold that frame at ``frames``.
    fit_machine : bool, optional
        False holds every leg parameter (fit the frames only).

    Raises
    ------
    InputError
        When the machine is not a six-leg platform, the data have the wrong number of reading
        columns, or the reading noise is not positive.
    """

    local_dof = 0

    def __init__(self, machine: Machine, data: FullPoseData, noise: FullPoseNoise,
                 frames: MeasurementFrames, fixed_frames=(False, False),
                 fit_machine: bool = True):
        _require_full_space(machine)
        if data.q.shape[1] != machine.n_joints:
            raise InputError(f"{path_text(data.source)}: "
                             f"{data.q.shape[1]} reading columns, the machine has "
                             f"{machine.n_joints} legs")
        if not noise.reading_m > 0:
            raise InputError("the reading noise must be > 0: it weighs the residuals")
        self.machine, self.data, self.noise = machine, data, noise
        self.frames0 = frames
        mp = machine.parameters if fit_machine else machine.parameters.with_fixed(
            list(machine.parameters.names))
        fp = frame_parameters(frames, tuple(bool(f) for f in fixed_frames))
        self.parameters = mp.concat(fp)
        self.scales = machine.scales_with(fp)
        self.n_machine = len(mp)
        self.fixed_frames = tuple(bool(f) for f in fixed_frames)
        self.fit_machine = fit_machine
        self.sigma_q = machine.reading_sigma(noise.reading_m)

    # -- state ----------------------------------------------------------------------------
    def _start(self) -> FullPoseState:
        (A, a), (B, c) = self.frames0.mocap_from_base, self.frames0.platform_from_marker
        return FullPoseState(self.machine.u.copy(), np.array(A, float), np.array(a, float),
                             np.array(B, float), np.array(c, float))

    def initial_state(self):
        """Start state: the machine's parameters and the start frames.

        Returns
        -------
        FullPoseState
            The state (no platform poses).
        """
        return self._start()

    def global_values(self, state):
        """Global values of a state: leg parameters, then the two frames.

        Each frame as a rotation increment from its start value and a translation.

        Parameters
        ----------
        state : FullPoseState
            An estimator state.

        Returns
        -------
        ndarray, shape (n_machine + 12,)
            Parameter values, internal units.
        """
        (A0, _), (B0, _) = self.frames0.mocap_from_base, self.frames0.platform_from_marker
        return np.concatenate([state.u, rotvec_from_matrix(state.A @ A0.T), state.a,
                               rotvec_from_matrix(state.B @ B0.T), state.c])

    def _retract_global(self, state, du) -> FullPoseState:
        n = self.n_machine
        return FullPoseState(state.u + du[:n], matrix_from_rotvec(du[n:n + 3]) @ state.A,
                             state.a + du[n + 3:n + 6],
                             matrix_from_rotvec(du[n + 6:n + 9]) @ state.B,
                             state.c + du[n + 9:n + 12], state.P, state.R)

    def retract(self, state, du, dl):
        """The state after a global step (no local unknowns).

        Parameters
        ----------
        state : FullPoseState
            Current state.
        du : ndarray, shape (n_machine + 12,)
            Step of the global parameters; frame rotations applied on the left.
        dl : None
            Unused.

        Returns
        -------
        FullPoseState
            The new state.
        """
        return self._retract_global(state, du)

    def platform_poses(self, state):
        """Measured poses mapped to platform poses in the base frame through the frames.

        Parameters
        ----------
        state : FullPoseState
            An estimator state (its frames are used).

        Returns
        -------
        P : ndarray, shape (K, 3)
            Platform positions, m.
        R : ndarray, shape (K, 3, 3)
            Platform orientations.
        """
        return state.frames().platform(self.data.P, self.data.R)

    # -- words ----------------------------------------------------------------------------
    def gauge_tangents(self, state):
        """Tangents of the frame motions the data cannot see, unscaled (one array per group).

        Parameters
        ----------
        state : FullPoseState
            The state to linearise at.

        Returns
        -------
        list of ndarray, shape (n, k)
            In the estimator's increment coordinates, one per group of
            :meth:`null_groups`.
        """
        return [g.tangents * self.scales[:, None] for g in self.null_groups(state, self.scales)]

    def null_groups(self, state, scales, null_space=None):
        """The frame motions the data cannot see, in words, with what absorbs them.

        Found in the numerical null space of the reduced Jacobian
        (:func:`~pkmcal.instruments.problem.frame_motion_groups`): on a six-dof platform a
        rigid motion of the base frame absorbed by ``mocap_from_base`` and one of the platform
        frame absorbed by ``platform_from_marker``, unless that frame is fixed.

        Parameters
        ----------
        state : FullPoseState
            The state to linearise at.
        scales : ndarray, shape (n,)
            Column scales; the directions are returned in scaled coordinates.
        null_space : ndarray, shape (n, k), optional
            The null space when known (an estimator result's); default: computed.

        Returns
        -------
        list of NullGroup
            The groups found.
        """
        from ..problem import frame_motion_groups, problem_null_space

        N = problem_null_space(self, state) if null_space is None else null_space
        return frame_motion_groups(self.machine, state.u, self.parameters, self.n_machine,
                                   np.asarray(scales, float), np.asarray(N, float), FRAME_WORDS)


class FullPoseIK(FullPoseProblem):
    """Inverse-kinematic residuals (Zhuang, Yan & Masory 1998); no per-pose unknowns.

    The measured poses are taken as exact and mapped through the frames to platform poses.

    Parameters
    ----------
    machine : Stewart
        Start geometry (a six-leg platform).
    data : FullPoseData
        Leg readings and measured marker poses.
    noise : FullPoseNoise
        Standard deviations of the readings and of the measured poses.
    frames : MeasurementFrames
        Start (or fixed) values of the two frames.
    fixed_frames : tuple of bool, optional
        ``(mocap_from_base, platform_from_marker)``: hold that frame at ``frames``.
    fit_machine : bool, optional
        False holds every leg parameter.

    Raises
    ------
    InputError
        As :class:`FullPoseProblem`.
    """

    local_dof = 0

    def _whitener(self, R, c, Jx):
        """Cholesky factors ``L`` (K, 6, 6) of each pose's residual covariance: the readings'
        ``diag(sigma_q^2)`` plus the measured pose's noise mapped through the inverse
        kinematics (position ``sigma_p``, orientation ``sigma_o``; a platform position carries
        the orientation noise through the marker offset ``R c``)."""
        K = len(R)
        sp, so = self.noise.position_m, self.noise.orientation_rad
        M = np.zeros((K, 6, 6))                        # d[P, Omega] / d[marker position, rot]
        M[:, :3, :3] = np.eye(3)                       # (isotropic: the frame rotation drops)
        M[:, :3, 3:] = skew(np.einsum("kij,j->ki", R, c))
        M[:, 3:, 3:] = np.eye(3)
        G = Jx @ M
        S = np.einsum("kij,j,klj->kil", G, np.r_[np.full(3, sp**2), np.full(3, so**2)], G)
        S = S + np.diag(self.sigma_q**2)
        return np.linalg.cholesky(S)

    def evaluate(self, state, jacobian=True):
        """Whitened reading residuals at the platform poses given by the measured poses.

        Parameters
        ----------
        state : FullPoseState
            Leg parameters and frames.
        jacobian : bool, optional
            Also compute the Jacobian.

        Returns
        -------
        r : ndarray, shape (K, 6)
            ``(q - IK(platform pose)) / sigma_q``.
        J_g : ndarray, shape (K, 6, n_machine + 12) or None
            Derivatives with respect to the leg parameters and the frames.
        J_l : None
            No local unknowns.
        """
        P, R = self.platform_poses(state)
        q, Jx, Ju = self.machine.ik_jacobians(P, R, state.u, want_du=jacobian)
        sig = self.sigma_q
        r = (self.data.q - q) / sig
        if not jacobian:
            return r, None, None
        A, c = state.A, state.c
        K = len(P)
        At = np.broadcast_to(A.T, (K, 3, 3))
        Rc = np.einsum("kij,j->ki", R, c)
        D = np.zeros((K, 6, 12))                       # d[P, Omega] / d frames
        D[:, :3, 0:3] = skew(P) @ A.T                  # mocap rotation w: dP = P x (A^T w)
        D[:, 3:, 0:3] = -At                            #                   dOmega = -A^T w
        D[:, :3, 3:6] = -At                            # mocap translation
        D[:, :3, 6:9] = -skew(Rc) @ R                  # marker rotation: dP = (R w) x (R c)
        D[:, 3:, 6:9] = -R                             #                  dOmega = -R w
        D[:, :3, 9:12] = -R                            # marker translation
        Jg = -np.concatenate([Ju, Jx @ D], -1) / sig[:, None]
        return r, Jg, None

    def noise_whitened(self, state) -> np.ndarray:
        """The residuals whitened by their whole covariance, for the chi-square.

        The method's estimate weighs the readings only (Zhuang's), but the measured poses are
        noisy too: the residual ``q - IK(x)`` of a pose has the covariance
        ``diag(sigma_q^2) + J_x Sigma_x J_x^T``. Whitened by it, the residuals of a correct
        model with the stated noise have unit variance (whitened by ``sigma_q`` alone they
        came out ~10x the noise on data the tool simulated itself).

        Parameters
        ----------
        state : FullPoseState
            The estimate.

        Returns
        -------
        ndarray, shape (K, 6)
            ``L^-1 (q - IK(x))`` with ``L L^T`` each pose's residual covariance.
        """
        P, R = self.platform_poses(state)
        q, Jx, _ = self.machine.ik_jacobians(P, R, state.u, want_du=False)
        L = self._whitener(R, state.c, Jx)
        return np.linalg.solve(L, (self.data.q - q)[..., None])[..., 0]


class FullPoseML(FullPoseProblem):
    """Maximum likelihood with the platform pose of every measurement unknown (6 per pose).

    Parameters
    ----------
    machine : Stewart
        Start geometry (a six-leg platform).
    data : FullPoseData
        Leg readings and measured marker poses.
    noise : FullPoseNoise
        Standard deviations of readings, positions and orientations (all > 0).
    frames : MeasurementFrames
        Start (or fixed) values of the two frames.
    fixed_frames : tuple of bool, optional
        ``(mocap_from_base, platform_from_marker)``: hold that frame at ``frames``.
    fit_machine : bool, optional
        False holds every leg parameter.

    Raises
    ------
    InputError
        As :class:`FullPoseProblem`, or when the position or orientation noise is not positive.
    """

    local_dof = 6

    def __init__(self, machine, data, noise, frames, fixed_frames=(False, False),
                 fit_machine=True):
        super().__init__(machine, data, noise, frames, fixed_frames, fit_machine)
        if not (noise.position_m > 0 and noise.orientation_rad > 0):
            raise InputError("the maximum-likelihood method weighs the measured poses by their "
                             "noise: position and orientation noise must be > 0 (use the ik "
                             "method for exact poses)")

    def initial_state(self):
        """Start state: start frames and the platform poses of the measured poses through them.

        Returns
        -------
        FullPoseState
            The state with platform poses.
        """
        state = self._start()
        state.P, state.R = self.platform_poses(state)
        return state

    def retract(self, state, du, dl):
        """The state after a step: global step and each platform pose moved.

        Parameters
        ----------
        state : FullPoseState
            Current state.
        du : ndarray, shape (n_machine + 12,)
            Step of the global parameters.
        dl : ndarray, shape (K, 6)
            Step of each platform pose, ``[dP (m), dOmega (rad)]``.

        Returns
        -------
        FullPoseState
            The new state.
        """
        new = self._retract_global(state, du)
        new.P = state.P + dl[:, :3]
        new.R = matrix_from_rotvec(dl[:, 3:]) @ state.R
        return new

    def noise_groups(self):
        """Noise groups: the leg readings (as leg lengths), the measured positions and the
        measured orientations; one measurement per pose.

        Returns
        -------
        NoiseGroups
            See :class:`~pkmcal.estimation.variance.NoiseGroups`.
        """
        from ...estimation.variance import NoiseGroups, row_names

        K, n = self.data.q.shape
        labels = np.tile(np.r_[np.zeros(n, int), np.ones(3, int), np.full(3, 2)], (K, 1))
        return NoiseGroups(labels, ["reading", "position", "orientation"],
                           ["leg readings", "measured positions", "measured orientations"],
                           np.array([self.noise.reading_m, self.noise.position_m,
                                     self.noise.orientation_rad]),
                           ["length", "length", "angle"],
                           np.repeat(np.arange(K), n + 6).reshape(K, n + 6),
                           row_names(getattr(self.data, "rows", None), K))

    def evaluate(self, state, jacobian=True):
        """Whitened residuals of readings, measured positions and orientations.

        Parameters
        ----------
        state : FullPoseState
            Leg parameters, frames and platform poses.
        jacobian : bool, optional
            Also compute the Jacobians.

        Returns
        -------
        r : ndarray, shape (K, 12)
            Six reading residuals, three position and three orientation residuals per pose.
        J_g : ndarray, shape (K, 12, n_machine + 12) or None
            Derivatives with respect to the leg parameters and the frames.
        J_l : ndarray, shape (K, 12, 6) or None
            Derivatives with respect to each platform pose ``[dP, dOmega]``.
        """
        P, R, A, a, B, c = state.P, state.R, state.A, state.a, state.B, state.c
        q, Jx, Ju = self.machine.ik_jacobians(P, R, state.u, want_du=jacobian)
        sq, sp, so = self.sigma_q, self.noise.position_m, self.noise.orientation_rad
        Rc = np.einsum("kij,j->ki", R, c)
        y = P + Rc
        Pm_pred = y @ A.T + a
        Rm_pred = A @ R @ B
        e_rot = rotvec_from_matrix(self.data.R @ np.swapaxes(Rm_pred, -1, -2))
        r = np.concatenate([(self.data.q - q) / sq, (self.data.P - Pm_pred) / sp,
                            e_rot / so], -1)
        if not jacobian:
            return r, None, None
        K = len(P)
        nm = Ju.shape[-1]
        Jri = right_jacobian_inverse(e_rot)                              # (K, 3, 3)
        # global: machine (nm) then frames (12)
        Jg = np.zeros((K, 12, nm + 12))
        Jg[:, :6, :nm] = -Ju / sq[:, None]
        Jg[:, 6:9, nm:nm + 3] = skew(y @ A.T) / sp                       # mocap rotation
        Jg[:, 6:9, nm + 3:nm + 6] = -np.eye(3) / sp                      # mocap translation
        Jg[:, 6:9, nm + 9:nm + 12] = -(A @ R) / sp                       # marker translation
        Jg[:, 9:, nm:nm + 3] = -Jri / so                                 # mocap rotation
        Jg[:, 9:, nm + 6:nm + 9] = -(Jri @ A @ R) / so                   # marker rotation
        # local: [dP, dOmega] of the platform pose
        Jl = np.zeros((K, 12, 6))
        Jl[:, :6] = -Jx / sq[:, None]
        Jl[:, 6:9, :3] = -np.broadcast_to(A, (K, 3, 3)) / sp
        Jl[:, 6:9, 3:] = (A @ skew(Rc)) / sp
        Jl[:, 9:, 3:] = -(Jri @ A) / so
        return r, Jg, Jl


PROBLEMS = {"ml": FullPoseML, "ik": FullPoseIK}


def _fixed_pair(fix_frames) -> tuple[bool, bool]:
    """``fix_frames``: a bool (both), or frame names."""
    if isinstance(fix_frames, (bool, np.bool_)):
        return bool(fix_frames), bool(fix_frames)
    names = [fix_frames] if isinstance(fix_frames, str) else list(fix_frames)
    bad = [n for n in names if n not in FRAME_NAMES]
    if bad:
        raise InputError(f"unknown measurement frame(s) {bad}; the frames are "
                         f"{', '.join(FRAME_NAMES)}")
    return FRAME_NAMES[0] in names, FRAME_NAMES[1] in names


def estimate_frames(machine: Machine, data: FullPoseData, max_passes: int = 100,
                    rcond: float = 1e-6) -> MeasurementFrames:
    """Closed-form start of the two frames from the machine's model.

    The platform poses follow from the readings (forward kinematics); the measurement frame's
    rotation and origin from the positions (Horn, with the marker offset ``c`` of the last
    pass), the marker frame's rotation as the mean of ``R_k^T A^T Rm_k``, and ``(c, a)`` by
    linear least squares of ``A R_k c + a = Pm_k - A P_k``; passes until ``c`` settles (exact
    for exact data and the true model).

    Parameters
    ----------
    machine : Stewart
        The model (its forward kinematics give the platform poses).
    data : FullPoseData
        Leg readings and measured marker poses.
    max_passes : int, optional
        Maximum number of passes.
    rcond : float, optional
        ``rcond`` of the least-squares solve for ``(c, a)``.

    Returns
    -------
    MeasurementFrames
        Estimates of ``mocap_from_base`` and ``platform_from_marker``.

    Raises
    ------
    InputError
        Naming the rows the model cannot reach, or when fewer than 4 positions are given or
        they lie on one line.
    """
    fk = machine.fk(data.q)
    if not fk.converged.all():
        rows = data.rows[~fk.converged]
        shown = ", ".join(map(str, rows[:10].tolist())) + (" ..." if len(rows) > 10 else "")
        raise InputError(f"{path_text(data.source)}: "
                         "no platform pose of the model reproduces the readings "
                         f"of {len(rows)} row(s): {shown} (outside the workspace, or a wrong "
                         "reading unit, gain or l0)")
    P, R = fk.P, fk.R
    c = np.zeros(3)
    K = len(P)
    sv = np.linalg.svd(data.P - data.P.mean(0), compute_uv=False)
    if K < 4 or sv[1] <= 1e-6 * max(sv[0], 1e-300):
        raise InputError(f"{path_text(data.source)}: "
                         f"the {K} measured positions coincide or lie on one "
                         "line (degenerate poses): the measurement frame cannot be found; "
                         "measure poses spread over the workspace: positions along all three "
                         "axes and rotations about all three axes")
    scale = machine.characteristic_length()
    for _ in range(max_passes):
        y = P + np.einsum("kij,j->ki", R, c)
        A, a = register_points(y, data.P, f"{path_text(data.source)}: start of mocap_from_base")
        M = np.einsum("kji,lj,klm->im", R, A, data.R)      # sum_k R_k^T A^T Rm_k
        U, _, Vt = np.linalg.svd(M)
        B = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
        lhs = np.concatenate([A @ R, np.broadcast_to(np.eye(3), (K, 3, 3))], -1).reshape(
            3 * K, 6)
        rhs = (data.P - P @ A.T).reshape(-1)
        sol = np.linalg.lstsq(lhs, rhs, rcond=rcond)[0]
        c, c_before = sol[:3], c
        if np.max(np.abs(c - c_before)) < 1e-14 * scale:
            break
    a = sol[3:]
    return MeasurementFrames((A, a), (B, c))


def calibrate_full_pose(machine: Machine, data: FullPoseData, method: str = "ml",
                        noise: FullPoseNoise | None = None,
                        frames: MeasurementFrames | None = None, fix_frames=False,
                        fit_machine: bool = True, rtol: float = RTOL,
                        require_identifiable: bool = True, estimate_noise=True,
                        robust: bool = False, **options) -> CalibrationResult:
    """Identify the leg parameters (and the measurement frames) from full-pose data.

    Parameters
    ----------
    machine : Stewart
        Start geometry (a six-leg platform); not modified.
    data : FullPoseData
        Leg readings and measured marker poses.
    method : {'ml', 'ik'}, optional
        ``'ml'`` (every measured quantity noisy, poses unknown) or ``'ik'`` (inverse-kinematic
        residuals, measured poses exact); see the module docstring.
    noise : FullPoseNoise, optional
        Noise levels (default values when None).
    frames : MeasurementFrames, optional
        Start (or fixed) values of the frames; None: closed form (:func:`estimate_frames`).
    fix_frames : bool, str or sequence of str, optional
        True (both), False (none), or frame names (``"mocap_from_base"``,
        ``"platform_from_marker"``) held at ``frames``.
    fit_machine : bool, optional
        False keeps the leg parameters and fits the frames only (the baseline "before
        calibration" of a model whose frames are unknown).
    rtol : float, optional
        Rank tolerance of :func:`levenberg_marquardt`.
    require_identifiable : bool, optional
        Raise :class:`InputError` when the poses leave directions other than the frame gauges
        undetermined (degenerate poses: all alike, or no rotation), naming them; False returns
        the fit with those directions reported instead. By the one rank rule
        (:mod:`pkmcal.estimation.rank`): unidentifiable directions are refused; weakly
        identifiable ones (standard deviation of at least ``max_std`` under the assumed
        noise) only when the measured poses do not vary beyond their noise; otherwise they are
        left at their start values and reported (``weak_space``, ``weak_std``, named in
        ``unidentifiable``).
    estimate_noise : bool or collection of str, optional
        ``'ml'``: estimate the noise of the readings, positions and orientations from the
        residuals (``noise`` their prior; :func:`~pkmcal.estimation.variance.fit`); False
        holds ``noise``; or the group keys to hold (``"reading"``, ``"position"``,
        ``"orientation"``).
    robust : bool, optional
        Leave out the poses the outlier test names.
    **options
        Passed to :func:`levenberg_marquardt` (``xtol``, ``ftol``, ``max_iter``, ``max_std``;
        ``max_std`` defaults to :data:`MAX_STD`).

    Returns
    -------
    CalibrationResult
        With ``method``; ``machine``, the calibrated machine (home kept); its
        :class:`PoseSection` (``frames``, the fitted measurement frames, ``start_frames``,
        ``fixed_frames``); ``unidentifiable``, the named null and weak directions;
        ``problem``; ``'ik'``:
        ``residual_test``, the chi-square of its residuals whitened by their whole covariance
        (:meth:`FullPoseIK.noise_whitened`).

    Raises
    ------
    InputError
        For an unknown method or frame name, a machine that is not a six-leg platform, fixed
        frames without ``frames``, fewer than 4 poses or fewer equations than identifiable
        parameters, degenerate poses (with ``require_identifiable``), or data the start
        model cannot explain.
    """
    if method not in PROBLEMS:
        raise InputError(f"unknown method {method!r} for full-pose data; choose one of "
                         f"{', '.join(METHODS)}")
    _require_full_space(machine)
    noise = FullPoseNoise() if noise is None else noise
    fixed = _fixed_pair(fix_frames)
    if any(fixed) and frames is None:
        raise InputError("fixed measurement frames need values: pass frames=")
    if len(data) < 4:
        raise InputError(f"{path_text(data.source)}: "
                         f"{len(data)} pose(s); full-pose calibration needs "
                         "many poses spread over the workspace (at least 4 for the frames, "
                         "more than 8 for the legs)")
    start = estimate_frames(machine, data) if frames is None else frames
    problem = PROBLEMS[method](machine, data, noise, start, fixed, fit_machine)
    n_gauge = 6 * sum(not f for f in fixed) if fit_machine else 0
    n_id = int(problem.parameters.free.sum()) - n_gauge
    require_redundancy(data.source, f"{len(data)} poses", 6 * len(data), n_id,
                       "measure more poses spread over the workspace")
    if require_identifiable:
        _check_identifiable(problem, n_id, rtol, options.get("max_std", MAX_STD))
    # ml: the reading, position and orientation noise from the residuals (ik: its residuals
    # take the poses as exact and are not the noise's; one scale as before)
    result = fit(problem, estimate_noise, robust=robust, rtol=rtol,
                 **{"max_std": MAX_STD, **options})
    state = result.state
    calibrated = machine.with_parameters(state.u)
    calibrated.home = machine.home
    groups = problem.null_groups(state, result.scales)
    if hasattr(problem, "noise_whitened") and result.dof > 0:
        # the ik estimate takes the poses as exact, but their noise is in its residuals: its
        # residual test is in the whole noise model's terms (readings + poses through the IK)
        r = problem.noise_whitened(state)
        result.residual_test = chi_square_test(float(np.sum(r[np.isfinite(r)] ** 2)),
                                                         result.dof)
    result.problem, result.method, result.machine = problem, method, calibrated
    result.add_section(PoseSection(frames=state.frames(), start_frames=start,
                                   fixed_frames=tuple(fixed)))
    result.unidentifiable = (name_null_space(result.null_space, problem.parameters, groups)
                             + name_weak_directions(result, problem.parameters))
    return result


#: measured poses whose positions or orientations spread by no more than this many times their
#: noise (largest axis) do not vary: directions determined only weakly by them are refused
DEGENERATE_SPREAD = 3.0


def pose_spread(data: FullPoseData) -> tuple[float, float]:
    """Spread of the measured poses: the largest standard deviation over the axes of the
    positions (m) and of the orientations (rad, rotation vectors about the mean orientation).

    Parameters
    ----------
    data : FullPoseData
        The measured poses.

    Returns
    -------
    tuple of float
        ``(position, orientation)``.
    """
    P, R = np.asarray(data.P, float), np.asarray(data.R, float)
    U, _, Vt = np.linalg.svd(np.sum(R, axis=0))       # chordal mean orientation
    mean = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    phi = rotvec_from_matrix(np.einsum("ji,kjl->kil", mean, R))

    def largest(x):
        return float(np.sqrt(np.linalg.eigvalsh(np.cov(x.T, bias=True))[-1])) if len(x) > 1 \
            else 0.0
    return largest(P), largest(phi)


def _check_identifiable(problem: FullPoseProblem, n_id: int, rtol: float,
                        max_std: float | None) -> None:
    """Refuse poses that leave more than the frame gauges undetermined, in words.

    By the one rank rule (:mod:`pkmcal.estimation.rank`, as ``pkmcal identifiability``):
    directions beyond the gauges that are unidentifiable (numerical null space) are refused.
    Weakly identifiable ones (standard deviation of at least ``max_std`` under the assumed
    noise) are left at their start values and reported, not refused - unless the measured
    positions or orientations do not vary beyond :data:`DEGENERATE_SPREAD` times their noise
    (all poses alike, no rotation): then what "determines" those directions is the noise of
    the poses the model is linearised at, and they are unidentifiable in fact.
    """
    state = problem.initial_state()
    r, Jg, Jl = problem.evaluate(state)
    if not np.all(np.isfinite(r)):
        raise InputError(f"{path_text(problem.data.source)}: "
                         "the residuals are not finite at the start "
                         "(check the readings and poses)")
    free = problem.parameters.free
    Jr, _, _ = reduce_local(r, Jg[..., free] * problem.scales[free], Jl)
    s, Vt = right_singular(Jr)
    decision = rank_rule(s, rtol, max_std, parameters=int(free.sum()))
    rank, why = decision.identifiable, ""
    if rank >= n_id and decision.weak:
        position, orientation = pose_spread(problem.data)
        noise = problem.noise
        if orientation <= DEGENERATE_SPREAD * noise.orientation_rad:
            why = (f"the measured orientations vary by {orientation * 1e6:.3g} urad at most, "
                   f"within {DEGENERATE_SPREAD:g}x their noise; ")
        elif position <= DEGENERATE_SPREAD * noise.position_m:
            why = (f"the measured positions vary by {position * 1e6:.3g} um at most, within "
                   f"{DEGENERATE_SPREAD:g}x their noise; ")
        if why:
            rank = decision.adjusted
    if rank >= n_id:
        return
    N = np.zeros((len(problem.parameters), Vt.shape[0] - rank))
    N[free] = Vt[rank:].T
    named = name_null_space(N, problem.parameters,
                            problem.null_groups(state, problem.scales))
    gauge = {"rigid motion of the base frame", "rigid motion of the platform frame"}
    words = [d.name for d in named if d.name not in gauge] or ["(several combinations)"]
    shown = "; ".join(words[:3]) + (f"; and {len(words) - 3} more" if len(words) > 3 else "")
    raise InputError(
        f"{path_text(problem.data.source)}: "
        f"the {len(problem.data)} poses determine only {rank} of the "
        f"{n_id} identifiable parameter directions ({why}degenerate poses); undetermined: "
        f"{shown}. Measure poses spread over the workspace: positions along all three axes "
        "and rotations about all three axes")
