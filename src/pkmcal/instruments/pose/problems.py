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

Full-pose measurements of a six-leg platform (SPEC 2.4): leg readings + a measured pose.

A motion-capture system (or a 6-D tracker) measures the pose of a *marker frame* fixed to the
platform, in its own *measurement frame*. Neither frame is the machine's: the measured pose is ::

    mocap_from_marker = mocap_from_base * base_from_platform(q; u) * platform_from_marker

with ``mocap_from_base = (A, a)`` (a base-frame point ``x`` is ``A x + a`` in the measurement
frame) and ``platform_from_marker = (B, c)`` (a marker-frame point ``y`` is ``B y + c`` in the
platform frame). One measurement = the six leg readings and the measured pose ``(Pm, Rm)``.

Noise model (:class:`FullPoseNoise`): every reading has a standard deviation given as a leg
length (``reading_m``; the reading's own standard deviation is ``reading_m / |gain|``), the
measured position an isotropic ``position_m``, the measured orientation an isotropic
``orientation_rad`` (a small rotation about the measurement axes, applied on the left).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from ...errors import InputError
from ...estimation.acceptance import FAILED_ALARMING, chi_square_test, report_verdict
from ...estimation.estimator import MAX_STD, CalibrationResult, reduce_local, require_redundancy
from ...estimation.rank import RTOL, rank_rule
from ...estimation.registration import register_points
from ...estimation.sections import Section
from ...estimation.variance import fit
from ...identifiability import name_null_space, name_weak_directions
from ...identifiability.analysis import right_singular
from ...kinematics import matrix_from_euler, matrix_from_rotvec, rotvec_from_matrix, skew
from ...machines.base import Machine
from ...machines.deviations import draw_accepted
from ...machines.file_format import file_rotation, frame_section
from ...parameters import ParameterSet
from ...paths import path_text
from ..base import Instrument, _space_words, has_column, reachable
from ..experiment import MOUNTING_ERROR
from ..flow import (
    FlowContext,
    FlowResult,
    convergence_json,
    identifiability_json,
    identifiability_metadata,
    json_safe,
    load_data,
    parameter_table,
    public_parameters,
    require_converged,
    solve,
    source_of,
    split_rows,
    validation_section,
)
from ..flow import option as _option
from ..setups import machine_setup, run_setup

Frame = tuple[np.ndarray, np.ndarray]


@dataclass(frozen=True)
class FullPoseNoise:
    """Standard deviations of full-pose data, SI units.

    Attributes
    ----------
    reading_m : float, optional
        Of a leg reading, expressed as a leg length, m.
    position_m : float, optional
        Of each coordinate of the measured position, m.
    orientation_rad : float, optional
        Of each component of the measured orientation (small rotation), rad.

    Raises
    ------
    InputError
        When a value is negative or not finite.
    """

    reading_m: float = 2e-6
    position_m: float = 20e-6
    orientation_rad: float = 50e-6

    def __post_init__(self):
        for name in ("reading_m", "position_m", "orientation_rad"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise InputError(f"noise {name}: must be a finite number >= 0, got {value}")


@dataclass(frozen=True)
class MeasurementFrames:
    """The two frames that separate the measured poses from the machine's.

    Attributes
    ----------
    mocap_from_base : tuple of ndarray
        ``(A (3, 3), a (3,))``: a base point ``x`` is measured at ``A x + a``.
    platform_from_marker : tuple of ndarray
        ``(B (3, 3), c (3,))``: a marker point ``y`` is ``B y + c`` in the platform frame.
    """

    mocap_from_base: Frame
    platform_from_marker: Frame

    @classmethod
    def identity(cls) -> MeasurementFrames:
        """Both frames the identity: the measured pose is the platform pose.

        Returns
        -------
        MeasurementFrames
            Identity rotations, zero offsets.
        """
        return cls((np.eye(3), np.zeros(3)), (np.eye(3), np.zeros(3)))

    def measured(self, P, R):
        """Measured marker poses ``(Pm, Rm)`` of platform poses ``(P, R)`` (base frame).

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Platform positions, m, base frame.
        R : array_like, shape (..., 3, 3)
            Platform orientations.

        Returns
        -------
        Pm : ndarray, shape (..., 3)
            Marker positions in the measurement frame, m.
        Rm : ndarray, shape (..., 3, 3)
            Marker orientations in the measurement frame.
        """
        (A, a), (B, c) = self.mocap_from_base, self.platform_from_marker
        P, R = np.asarray(P, float), np.asarray(R, float)
        Pm = (P + np.einsum("...ij,j->...i", R, c)) @ A.T + a
        return Pm, A @ R @ B

    def platform(self, Pm, Rm):
        """Platform poses in the base frame of measured marker poses (inverse of :meth:`measured`).

        ``R = A^T Rm B^T``, ``P = A^T (Pm - a) - R c``.

        Parameters
        ----------
        Pm : array_like, shape (..., 3)
            Marker positions in the measurement frame, m.
        Rm : array_like, shape (..., 3, 3)
            Marker orientations in the measurement frame.

        Returns
        -------
        P : ndarray, shape (..., 3)
            Platform positions, m, base frame.
        R : ndarray, shape (..., 3, 3)
            Platform orientations.
        """
        (A, a), (B, c) = self.mocap_from_base, self.platform_from_marker
        Pm, Rm = np.asarray(Pm, float), np.asarray(Rm, float)
        R = A.T @ Rm @ B.T
        P = (Pm - a) @ A - np.einsum("...ij,j->...i", R, c)
        return P, R

    def shifted(self, t) -> MeasurementFrames:
        """The frames seen from a base frame whose points moved by ``t`` (m): a base point
        ``x + t`` is measured where ``x`` was."""
        A, a = self.mocap_from_base
        return MeasurementFrames((A, np.asarray(a, float) - A @ np.asarray(t, float)),
                                 self.platform_from_marker)

    def frame_shift(self, machine):
        """None: motion capture says nothing about the machine's frame."""
        return None

    def targets_in_base(self, machine, P):
        """``P`` itself: base-frame targets are not given relative to the frames (those in
        the motion-capture frame: :class:`~pkmcal.compensation.frames.MocapFrames`)."""
        return P


@dataclass
class FullPoseData:
    """Leg readings and measured marker poses.

    Attributes
    ----------
    q : ndarray, shape (K, 6)
        Readings, internal units (m for length readings, else the reading unit).
    P : ndarray, shape (K, 3)
        Measured marker positions, measurement frame, m.
    R : ndarray, shape (K, 3, 3)
        Measured marker orientations.
    rows : ndarray of int, shape (K,), optional
        Row numbers in the source file, for messages; default 1..K.
    source : str, optional
        File name, for messages.
    true_P, true_R : ndarray, optional
        Platform poses of a simulation (base frame), (K, 3) m and (K, 3, 3), else None.

    Raises
    ------
    InputError
        When ``q``, ``P``, ``R`` and ``rows`` do not have the same number of rows.
    """

    q: np.ndarray
    P: np.ndarray
    R: np.ndarray
    rows: np.ndarray | None = None
    source: str = "<data>"
    true_P: np.ndarray | None = None
    true_R: np.ndarray | None = None

    def __post_init__(self):
        self.q = np.atleast_2d(np.asarray(self.q, float))
        self.P = np.atleast_2d(np.asarray(self.P, float))
        self.R = np.asarray(self.R, float).reshape(-1, 3, 3)
        if self.rows is None:
            self.rows = np.arange(1, len(self.q) + 1)
        self.rows = np.asarray(self.rows)
        if not (len(self.q) == len(self.P) == len(self.R) == len(self.rows)):
            raise InputError(f"{path_text(self.source)}: readings, positions and orientations have "
                             f"different lengths ({len(self.q)}, {len(self.P)}, {len(self.R)})")

    def __len__(self) -> int:
        return len(self.q)

    def subset(self, mask) -> FullPoseData:
        """The measurements selected by a boolean mask or index array.

        Parameters
        ----------
        mask : array_like of bool or int
            Boolean mask (K,) or indices of the rows to keep.

        Returns
        -------
        FullPoseData
            The selected rows, same source.
        """
        pick = (lambda a: None if a is None else a[mask])
        return FullPoseData(self.q[mask], self.P[mask], self.R[mask], self.rows[mask],
                            self.source, pick(self.true_P), pick(self.true_R))


def default_measurement_frames() -> MeasurementFrames:
    """The true frames of simulations without ``measurement_frames`` in the machine file.

    ``mocap_from_base``: the base origin is at (1.2, -0.4, -0.3) m in the measurement frame,
    whose axes are turned 30 deg about Z and tilted 2 deg about X relative to the base axes;
    ``platform_from_marker``: the marker origin at (10, -5, 25) mm in the platform frame,
    turned 90 deg about X (a Y-up marker body) and 3 deg about Z.

    Returns
    -------
    MeasurementFrames
        The default frames.
    """
    A = matrix_from_rotvec([0.0, 0.0, np.deg2rad(30.0)]) @ matrix_from_rotvec(
        [np.deg2rad(2.0), 0.0, 0.0])
    B = matrix_from_rotvec([np.deg2rad(90.0), 0.0, 0.0]) @ matrix_from_rotvec(
        [0.0, 0.0, np.deg2rad(3.0)])
    return MeasurementFrames((A, np.array([1.2, -0.4, -0.3])),
                             (B, np.array([0.01, -0.005, 0.025])))


#: default pose set of simulations (SPEC 5 workspace): a 0.1 m cube around home, Euler angles
#: within +/-10 deg
POSE_HALF_RANGE = 0.05
POSE_MAX_ANGLE = np.deg2rad(10.0)


def sample_platform_poses(machine: Machine, n: int, rng=None, half_range=POSE_HALF_RANGE,
                          max_angle=POSE_MAX_ANGLE, min_conditioning: float = 0.05):
    """``n`` random platform poses around the machine's home.

    Positions are uniform in a cube of half-width ``half_range`` around the home position,
    Euler angles uniform in ``+/- max_angle`` applied to the home orientation. Poses whose leg
    Jacobian is badly conditioned (smallest singular value below ``min_conditioning`` times the
    largest, rotation columns scaled by the characteristic length), whose legs would be
    shorter than a tenth of their home length or whose readings break the machine's
    ``joint_limits`` (machine file) are drawn again.

    Parameters
    ----------
    machine : Stewart
        The six-leg platform (uses ``leg_vectors`` and ``lengths``).
    n : int
        Number of poses (>= 1).
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.
    half_range : float, optional
        Half-width of the position cube, m.
    max_angle : float, optional
        Bound of each Euler angle, rad.
    min_conditioning : float, optional
        Smallest accepted inverse condition number of the leg Jacobian.

    Returns
    -------
    P : ndarray, shape (n, 3)
        Platform positions, m.
    R : ndarray, shape (n, 3, 3)
        Platform orientations.

    Raises
    ------
    InputError
        When ``n < 1`` or not enough well-conditioned poses are found.
    """
    if n < 1:
        raise InputError(f"the number of poses must be >= 1, got {n}")
    rng = np.random.default_rng(rng)
    P0, R0 = machine.home
    _, _, L0 = machine.leg_vectors(P0, R0)

    def draw(m, rng):
        P = P0 + rng.uniform(-half_range, half_range, (m, 3))
        R = matrix_from_euler(rng.uniform(-max_angle, max_angle, (m, 3))) @ R0
        q, J, _ = machine.ik_jacobians(P, R, want_du=False)
        ok = (machine.pose_conditioning(P, R, dq_dpose=J) > min_conditioning) \
            & np.all(machine.lengths(q) > 0.1 * L0, axis=-1)
        return P, R, ok

    where = str(getattr(machine, "source", "") or "").replace("{", "{{").replace("}", "}}")
    return draw_accepted(draw, n, rng, (f"{where}: " if where else "")
                         + "only {have} of {n} random poses around home are well conditioned: "
                         "reduce the pose range or check the geometry (legs) and home",
                         machine=machine)


def simulate_full_pose(true_machine: Machine, poses, frames: MeasurementFrames | None = None,
                       noise: FullPoseNoise | None = FullPoseNoise(), rng=None) -> FullPoseData:
    """Full-pose data of ``true_machine`` at given or random platform poses.

    Exact readings and measured marker poses through ``frames``, plus Gaussian noise: the
    readings ``reading_m`` as a length (:meth:`~pkmcal.machines.Machine.reading_sigma`: over
    ``|gain|`` for a Stewart), the positions ``position_m`` per coordinate and the
    orientations a small rotation of ``orientation_rad`` per component, applied on the left.

    Parameters
    ----------
    true_machine : Machine
        The true machine (a platform that rotates).
    poses : tuple of array_like or int
        Platform poses ``(P (K, 3), R (K, 3, 3))`` in the base frame, or a number of random
        poses (:func:`sample_platform_poses`).
    frames : MeasurementFrames, optional
        True measurement frames; default :func:`default_measurement_frames`.
    noise : FullPoseNoise or None, optional
        Noise levels; None for exact data.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.

    Returns
    -------
    FullPoseData
        The readings and measured poses, with the true platform poses in ``true_P``,
        ``true_R``.
    """
    rng = np.random.default_rng(rng)
    if isinstance(poses, (int, np.integer)):
        poses = sample_platform_poses(true_machine, int(poses), rng)
    P, R = (np.asarray(poses[0], float), np.asarray(poses[1], float))
    frames = default_measurement_frames() if frames is None else frames
    q = true_machine.ik(P, R)
    Pm, Rm = frames.measured(P, R)
    if noise is not None:
        q = q + true_machine.reading_sigma(noise.reading_m) * rng.standard_normal(q.shape)
        Pm = Pm + noise.position_m * rng.standard_normal(Pm.shape)
        Rm = matrix_from_rotvec(noise.orientation_rad * rng.standard_normal(Pm.shape)) @ Rm
    return FullPoseData(q, Pm, Rm, source="<simulated>", true_P=P, true_R=R)


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


@dataclass
class PoseSection(Section):
    """What a full-pose calibration adds to its result (``result.sections["pose"]``): the
    measurement frames (identified and at the start) and which were held.

    Attributes
    ----------
    frames, start_frames : MeasurementFrames
        ``mocap_from_base`` and ``platform_from_marker``, identified and at the start.
    fixed_frames : tuple of bool
        Whether each frame was held at its given value.
    origin : str
        Where the frames (or their start) came from, in words (the report's ``from``).
    """

    instrument: ClassVar[str] = "pose"
    title: ClassVar[str] = "frames"

    frames: object
    start_frames: object
    fixed_frames: tuple = (False, False)
    origin: str = ""

    def as_report(self, units=None) -> dict:
        from ...units import LENGTH

        unit = (units or {}).get("length", "mm")
        fl = LENGTH[unit]
        return {"frames": {
            "fixed": bool(any(self.fixed_frames)), "from": self.origin,
            "mocap_from_base": _frame_report(self.frames.mocap_from_base, fl, unit),
            "platform_from_marker": _frame_report(self.frames.platform_from_marker, fl, unit),
        }}

    def summary_rows(self, units=None) -> list:
        fr = self.as_report(units)["frames"]
        unit = (units or {}).get("length", "mm")
        rows = []
        for name in ("mocap_from_base", "platform_from_marker"):
            f = fr[name]
            rows.append((name, ("fixed: " if fr["fixed"] else "estimated: ")
                         + f"turned {f['rotation_angle_deg']:.4g} deg, origin at ("
                         + ", ".join(f"{v:.6g}" for v in f["translation"]) + f") {unit}"))
        return rows


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
        With ``method``; ``machine``, the calibrated machine (with ``measurement_frames``,
        home kept); its :class:`PoseSection` (``frames``, ``start_frames``,
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
    calibrated.measurement_frames = state.frames()
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


def full_pose_noise_arg(noise: str | None, pose_noise: str | None, strict: bool,
                        machine=None):
    """The full-pose noise model of ``--noise`` and ``--pose-noise``.

    Parameters
    ----------
    noise : str or None
        Noise of the readings, as a leg length (default: the model's).
    pose_noise : str or None
        ``POSITION,ORIENTATION`` with units (e.g. ``20um,50urad``; default: the model's).
    strict : bool
        Every standard deviation must be > 0 (a calibration weighs by them); else >= 0 (a
        simulation may be exact).
    machine : Machine, optional
        The values are checked against its size when given.

    Returns
    -------
    FullPoseNoise
        The noise model, SI units.

    Raises
    ------
    InputError
        When a value is malformed, out of range or implausible for the machine.
    """
    from ...plausibility import check_option_scale
    from ...units import parse_quantity

    default = FullPoseNoise()
    reading = default.reading_m if noise is None else parse_quantity(noise, "length", "--noise")
    if pose_noise is None:
        position, orientation = default.position_m, default.orientation_rad
    else:
        parts = [p.strip() for p in str(pose_noise).split(",")]
        if len(parts) != 2:
            raise InputError(f"--pose-noise: expected POSITION,ORIENTATION with units (e.g. "
                             f"20um,50urad), got {pose_noise!r}")
        position = parse_quantity(parts[0], "length", "--pose-noise (position)")
        orientation = parse_quantity(parts[1], "angle", "--pose-noise (orientation)")
    for option, value, text in (("--noise", reading, noise),
                                ("--pose-noise", position, pose_noise),
                                ("--pose-noise", orientation, pose_noise)):
        if not (math.isfinite(value) and (value > 0 if strict else value >= 0)):
            need = ("must be > 0 (a standard deviation that weighs the residuals)" if strict
                    else "must be >= 0")
            raise InputError(f"{option}: {need}, got {text}")
    if machine is not None:
        check_option_scale(reading, machine, "--noise", "noise", noise)
        check_option_scale(position, machine, "--pose-noise (position)", "noise", pose_noise)
        check_option_scale(orientation, machine, "--pose-noise (orientation)", "angle noise",
                           pose_noise)
    return FullPoseNoise(reading, position, orientation)


@dataclass(frozen=True, slots=True)
class PoseOptions:
    """The options of the full-pose calibration flow (:meth:`Pose.calibrate`)."""

    method: str | None = _option(
        None, "--method", "ml maximum likelihood, readings and measured poses noisy "
        "(default); ik inverse-kinematic residuals (Zhuang, Yan & Masory 1998), measured poses "
        "exact.", choices=("ml", "ik"))
    noise: object = _option(
        None, "--noise", "noise of the leg readings, as a leg length (default 2um); held as "
        "given (a FullPoseNoise too), else estimated from the residuals.")
    pose_noise: str | None = _option(
        None, "--pose-noise", "Noise of the measured poses, POSITION,ORIENTATION with units, "
        "held as given (default: estimated from the residuals, starting from 20um,50urad).",
        metavar="POS,ORI")
    fix_frames: bool = _option(
        False, "--fix-frames", "Hold the measurement frames (mocap_from_base, "
        "platform_from_marker) at the machine file's measurement_frames (identity without "
        "that section) instead of estimating them.")
    extensions: str | None = _option(
        None, "--extensions", "auto (default) tries the machine's model extensions (a six-leg "
        "platform's per-leg reading curvature) and adopts one only when it predicts rows held "
        "out of the fit better (5-fold cross-validation, in the report); none fits the plain "
        "model.", metavar="auto|none",
        choices=("auto", "none"))
    robust: bool = _option(
        False, "--robust", "Leave out the rows the noise cannot explain (a chi-square test of "
        "each row) and fit again (ml).")


class Pose(Instrument):
    """Full poses of a marker on the platform (motion capture), SPEC 2.4."""

    name = "pose"
    aliases = ("poses",)
    words = "the marker pose (motion capture, 6-D tracker)"
    plan_size = 60
    #: the quantities of its machine-file section (unit conversion, magnitude checks)
    file_quantities = {("measurement_frames", "*", "translation", "*"): "length"}
    columns = ("the leg readings q1_<unit>..q6_<unit> (the machine's reading unit) and the "
               "measured pose x_mm, y_mm, z_mm with qx, qy, qz, qw or psi_deg, theta_deg, "
               "phi_deg")
    priority = 20
    data_class = "FullPoseData"
    joint_refusal = "full poses estimate a platform pose per measurement"

    def detect(self, header):
        return (has_column(header, "x") or has_column(header, "y") or has_column(header, "z")
                or "qw" in header)

    def applies(self, machine):
        if not machine.rotates:
            return ("full poses need a platform that rotates; this machine's platform only "
                    "translates: measure points (tracker) instead")
        if len(machine.pose_space) != 6:
            return ("full poses need a platform that moves in space (six pose coordinates); "
                    f"this machine's platform moves along {_space_words(machine)} only: "
                    "measure points (tracker) instead")
        return None

    def default_noise(self):

        return FullPoseNoise()

    def describe_noise(self, noise):
        return (f"leg readings {noise.reading_m * 1e6:.3g} um, poses "
                f"{noise.position_m * 1e6:.3g} um / {noise.orientation_rad * 1e6:.3g} urad "
                "(std)")

    montecarlo_variables = ("noise", "poses", "tolerance")
    montecarlo_metrics = {
        "position_mean": ("um", 1e-6, "mean held-out marker position error"),
        "position_max": ("um", 1e-6, "max held-out marker position error"),
        "orientation_mean": ("urad", 1e-6, "mean held-out marker orientation error"),
        "orientation_max": ("urad", 1e-6, "max held-out marker orientation error"),
        "parameter_rms": ("", 1.0, "RMS gauge-free parameter error, scaled coordinates"),
    }
    #: the gauge-free parameter error needs a six-leg platform's leg layout
    montecarlo_optional_metrics = frozenset({"parameter_rms"})
    montecarlo_evaluation_poses = 100
    montecarlo_poses = 60

    def montecarlo_run(self, run):
        """Maximum likelihood with both measurement frames estimated, the noise of leg
        readings varied (the pose noise at its default); held out: exact poses through the
        identified frames, and the gauge-free parameter error (:func:`gauge_free_error`)."""
        from ...machines.reach import sample_workspace_poses

        s = run.settings
        nominal = s.machine
        true = run.true_machine()
        frames = measurement_frames(run_setup(run, self.name))
        default = FullPoseNoise()
        noise = default.reading_m if s.noise is None else s.noise
        data = simulate_full_pose(true, sample_workspace_poses(true, s.poses or
                                                               self.montecarlo_poses, run.rng),
                                  frames, replace(default, reading_m=noise), run.rng)
        res = calibrate_full_pose(nominal, data, "ml",
                                  noise=replace(default, reading_m=run.weight(noise)))
        held = simulate_full_pose(true, sample_workspace_poses(
            true, self.montecarlo_evaluation_poses, run.rng), frames, None, run.rng)
        err = full_pose_errors(res.machine, res.section(PoseSection).frames, held)
        ok = err.converged
        e = gauge_free_error(nominal, res, true.u, frames)

        def stat(f, v):
            return float(f(v[ok])) if ok.any() else math.nan

        return res, {"position_mean": stat(np.mean, err.position),
                     "position_max": stat(np.max, err.position),
                     "orientation_mean": stat(np.mean, err.orientation),
                     "orientation_max": stat(np.max, err.orientation),
                     "parameter_rms": float(np.sqrt(np.mean(e**2)))}

    def planned_data(self, machine, P, R, rows, source, group=None, setup=None):

        q = reachable(machine, P, R, rows, source)
        Pm, Rm = measurement_frames(setup).measured(P, R)
        return FullPoseData(q, Pm, Rm, rows, source, true_P=P, true_R=R)

    section = "measurement_frames"
    section_words = ("a calibration from poses (x, y, z, qx..qw: motion capture) writes "
                     "measurement_frames")
    Setup = MeasurementFrames
    section_order = 40

    def read_setup(self, section, length_factor, machine):
        return MeasurementFrames(
            *((file_rotation(f.rotation), np.asarray(f.translation, float) * length_factor)
              for f in (section.mocap_from_base, section.platform_from_marker)))

    def setup_section(self, setup, length_factor, machine):
        if len(machine.pose_space) != 6:
            return None
        return {"mocap_from_base": frame_section(setup.mocap_from_base, length_factor),
                "platform_from_marker": frame_section(setup.platform_from_marker,
                                                      length_factor)}

    def carried_by(self, machine, setup):
        return setup is not None and len(machine.pose_space) == 6

    def predict(self, machine, setup, P, R, ok, group, rows=None, source=None):
        values, Rm = setup.measured(P, R)
        return values, np.where(ok[:, None, None], Rm, np.nan), np.zeros(len(P), int)

    def simulate(self, machine, true, n, noise, rng, truth, *, setup=None, poses=None,
                 mounting_error=MOUNTING_ERROR):
        """:func:`simulate_full_pose` at ``n`` random poses (or ``poses``), through the machine
        file's measurement frames (``setup``, else the default); ``noise`` a
        ``FullPoseNoise`` (False: exact). See
        :meth:`Instrument.simulate <pkmcal.instruments.base.Instrument.simulate>`.

        Returns
        -------
        tuple
            ``(data, true, truth)``; ``truth`` with ``frames`` (also its ``setup``).
        """
        from ...machines.reach import sample_workspace_poses
        from ..experiment import given_poses, mm_text, noise_model

        frames = measurement_frames(setup)
        model = noise_model(noise, FullPoseNoise())
        if poses is None:
            poses = sample_workspace_poses(true, n, rng)
            words = (f"{n} random poses in the 0.1 m cube around home, Euler angles within "
                     "+/-10 deg")
        else:
            poses = given_poses(poses)
            words = f"{len(poses[0])} given poses"
        data = simulate_full_pose(true, poses, frames, model, rng)
        rows = [("frames", f"measurement origin at {mm_text(frames.mocap_from_base[1])} mm; "
                 f"marker origin at {mm_text(frames.platform_from_marker[1])} mm in the "
                 "platform frame")]
        truth.update(frames=frames, poses=words, rows=rows, setup=frames)
        return data, true, truth

    simulate_flags = {"--pose-noise": "--scenario pose"}

    def simulate_arguments(self, machine, noise, pose_noise=None, **flags):
        model = full_pose_noise_arg(noise, pose_noise, strict=False, machine=machine)
        return model, (f"readings {model.reading_m * 1e6:.4g} um (as leg length), position "
                       f"{model.position_m * 1e6:.4g} um, orientation "
                       f"{model.orientation_rad * 1e6:.4g} urad"), {}

    writer = "write_full_pose"

    def calibration_summary(self, report):
        res, ident = report["residuals"], report["identifiability"]
        unit = report["units"]["length"]
        b, a = res["before_calibration"], res["after_calibration"]
        n = report["noise"]
        fr = report["frames"]
        m, k = fr["mocap_from_base"], fr["platform_from_marker"]
        rows = [("measurement", f"full pose, {report['measurements']} poses (readings in "
                 f"{report['reading_unit']}, marker pose in the measurement frame)"),
                ("method", {"ml": "ml (maximum likelihood: readings and measured poses "
                                  "noisy, one pose unknown per measurement)",
                            "ik": "ik (inverse-kinematic residuals, Zhuang, Yan & Masory "
                                  "1998: measured poses exact)"}[report["method"]]),
                "identifiable",
                ("leg-length RMS", f"{b['leg_length_rms']:.4g} {unit} before, "
                 f"{a['leg_length_rms']:.4g} {unit} after ({res['before']})"),
                ("pose error RMS", f"position {b['position_rms']:.4g} -> "
                 f"{a['position_rms']:.4g} {unit}, orientation "
                 f"{b['orientation_rms_deg']:.4g} -> {a['orientation_rms_deg']:.4g} deg "
                 "(forward kinematics of the readings vs measured)"),
                ("noise", f"readings {n['reading_um']:.4g} um, position "
                 f"{n['position_um']:.4g} um, orientation {n['orientation_urad']:.4g} urad "
                 "(assumed)"),
                ("frames", ("fixed: " if fr["fixed"] else f"estimated ({fr['from']}): ")
                 + "mocap_from_base turned "
                 f"{m['rotation_angle_deg']:.4g} deg, base origin at "
                 f"({', '.join(f'{v:.6g}' for v in m['translation'])}) {unit} measured; "
                 f"platform_from_marker turned {k['rotation_angle_deg']:.4g} deg, marker at "
                 f"({', '.join(f'{v:.6g}' for v in k['translation'])}) {unit}"),
                "held-out", "noise levels"]
        ext = report.get("model_extensions") or {}
        for t in ext.get("trials", []):
            rows.append(("model extension", f"{t['name']}: {t['why']} ({ext['folds']}-fold "
                         f"cross-validation: held-out loss {t['cv_loss']:.4g} vs "
                         f"{t['cv_loss_baseline']:.4g} per pose)"))
        if "model_adequacy" in report:
            adequacy = report["model_adequacy"]
            rows.append(("model adequacy", adequacy.get("findings", adequacy["verdict"])))
        rows += ["residual test", "convergence"]
        if report_verdict(report).status == FAILED_ALARMING:
            rows.append(("note", "note: the residual test failed: give the real noise "
                         "(--noise, --pose-noise), or the model lacks errors the machine "
                         "has."))
        if ident["unidentifiable"]:
            rows.append(("note", "note: the data fix the legs only relative to the "
                         "measurement frames; the changes are the smallest ones (scaled) that "
                         "fit the data, and std is for the identifiable part."))
        return rows
    prediction_words = "predicted marker pose(s) (motion-capture frame)"

    def prediction_columns(self, prediction, unit):
        """``x, y, z`` (``unit``) and ``qx, qy, qz, qw`` of the predicted marker poses."""
        from ...kinematics import quaternion_from_matrix
        from ...units import LENGTH

        f = LENGTH[unit]
        Q = quaternion_from_matrix(prediction.R)
        columns = {f"{c}_{unit}": prediction.values[:, j] / f for j, c in enumerate("xyz")}
        columns.update({c: Q[:, j] for j, c in enumerate(("qx", "qy", "qz", "qw"))})
        return columns

    def problem(self, machine, data, noise=None, setup=None, frames=None, **start):

        return FullPoseML(machine, data, self.default_noise() if noise is None else noise,
                          measurement_frames(setup) if frames is None else frames)

    measurement_words = "full pose (maximum likelihood; both measurement frames estimated)"

    def noise_option(self, noise, pose_noise=None, machine=None):

        if noise is not None and not isinstance(noise, str):
            return noise
        return full_pose_noise_arg(noise, pose_noise, strict=True, machine=machine)

    def noise_arg(self, text, machine=None):
        """The full-pose noise of ``--noise`` (the leg readings; poses at their default)."""
        return self.noise_option(text, None, machine)

    #: the io reader of its CSV files (:func:`pkmcal.io.read_measurements`)
    reader = "read_full_pose"
    Options = PoseOptions

    def check_options(self, options, source) -> None:
        """``--robust`` with ml alone (see
        :meth:`~pkmcal.instruments.base.Instrument.check_options`)."""
        _check_options(options, source)

    def calibrate(self, machine: Machine, data, context, options):
        """Legs and both measurement frames (or the frames held), the machine's model
        extensions adopted by cross-validation, errors before and after (see
        :meth:`~pkmcal.instruments.base.Instrument.calibrate`)."""
        return _calibration_flow(machine, data, context, options)

    def measured_problem(self, machine, data, noise=None, source="", setup=None):
        """The measurement frames of the machine file, else estimated from the data (at least
        4 poses)."""

        if len(data) < 4:
            raise InputError(f"{path_text(source)}: "
                             f"{len(data)} pose(s); the measurement frames need at "
                             "least 4")
        frames = machine_setup(machine, self.name) if setup is None else setup
        if frames is None:
            frames = estimate_frames(machine, data)
        return self.problem(machine, data, noise, frames=frames)


def measurement_frames(setup: MeasurementFrames | None = None) -> MeasurementFrames:
    """The measurement frames of the machine file (its set-up), else the simulations'
    default.

    Parameters
    ----------
    setup : MeasurementFrames, optional
        The machine file's (None: none).

    Returns
    -------
    MeasurementFrames
        The frames.
    """
    return default_measurement_frames() if setup is None else setup


#: this module's instrument (:data:`~pkmcal.instruments.registry.INSTRUMENT_MODULES`)
INSTRUMENT = Pose()


def pose_noise_option(noise, pose_noise, machine):
    """The noise model of a full-pose calibration and the levels held (those the user gave;
    the others are estimated from the residuals).

    Parameters
    ----------
    noise : str, float, FullPoseNoise or None
        ``--noise`` (the leg readings' std), or a whole noise model.
    pose_noise : str or None
        ``--pose-noise`` (``POSITION,ORIENTATION``).
    machine : Machine
        The machine (levels checked against its size).

    Returns
    -------
    noise_model : FullPoseNoise
        The model.
    hold : list of str
        Its levels given by the user (``reading``, ``position``, ``orientation``).

    Raises
    ------
    InputError
        For ``pose_noise`` beside a whole model, or a bad level.
    """
    if isinstance(noise, FullPoseNoise):
        if pose_noise is not None:
            raise InputError("--pose-noise: the noise model given as noise holds the pose "
                             "noise already")
        return noise, ["reading", "position", "orientation"]
    model = full_pose_noise_arg(noise, pose_noise, strict=True, machine=machine)
    hold = ((["reading"] if noise is not None else [])
            + (["position", "orientation"] if pose_noise is not None else []))
    return model, hold


# -- calibration flow (pkmcal calibrate) ------------------------------------------------------


def _frame_report(frame, fl: float, unit: str) -> dict:
    """A measurement frame in the report (rotation, translation in the file's unit, angle)."""
    from ...kinematics import rotation_angle

    R, t = frame
    return {"rotation": np.asarray(R, float).tolist(),
            "translation": (np.asarray(t, float) / fl).tolist(), "unit": unit,
            "rotation_angle_deg": float(np.degrees(rotation_angle(np.asarray(R, float))))}


def _errors_report(errors, fl: float) -> dict:
    """Full-pose errors in the report (the file's length unit, degrees)."""
    s = errors.summary()
    return {"leg_length_rms": s["leg_length_rms"] / fl, "leg_length_max": s["leg_length_max"] / fl,
            "leg_length_rms_per_leg": [v / fl for v in s["leg_length_rms_per_leg"]],
            "position_rms": s["position_rms"] / fl, "position_max": s["position_max"] / fl,
            "orientation_rms_deg": float(np.degrees(s["orientation_rms"])),
            "orientation_max_deg": float(np.degrees(s["orientation_max"])),
            "fk_failed": s["fk_failed"]}


def _check_options(options: PoseOptions, source) -> None:
    """The full-pose options that do not go together, refused naming them (an option it does
    not declare, or a value out of its choices, is refused by the calibration layer)."""
    if options.robust and options.method == "ik":
        raise InputError("--robust: applies to the ml method (its residuals are the noise's); "
                         "--method ik takes the measured poses as exact")


def _calibration_flow(machine, data, context: FlowContext,
                      options: PoseOptions) -> FlowResult:
    """``pkmcal calibrate`` from full poses (:meth:`Pose.calibrate`)."""
    from ...machines.stewart import reading_factor
    from ...units import LENGTH

    source, split = context.source, context.split
    method, fix_frames = options.method or "ml", options.fix_frames
    noise_model, hold = pose_noise_option(options.noise, options.pose_noise, machine)
    data, held = split_rows(load_data(data, context.read, machine), split, source)
    file_frames = machine_setup(machine, "pose")     # transitional: the machine file's
    if fix_frames:
        frames = file_frames if file_frames is not None else MeasurementFrames.identity()
        frames_from = ("the machine file's measurement_frames" if file_frames is not None
                       else "identity (the machine file has no measurement_frames)")
    else:
        frames = file_frames
        frames_from = ("start: the machine file's measurement_frames" if file_frames is not None
                       else "start: closed form from the design model")
    result = solve(source, calibrate_full_pose, machine, data, held=held, method=method,
                    noise=noise_model, frames=frames, fix_frames=fix_frames,
                    estimate_noise=hold, robust=options.robust)
    # the machine's model extensions (a leg's reading curvature ...), adopted only when they
    # predict rows held out of the fit better (k-fold cross-validation on these data)
    model, choice = machine, None
    if options.extensions != "none" and machine.model_extensions():
        require_converged(result, source)
        levels = result.noise
        cv_noise = noise_model if levels is None else FullPoseNoise(
            **{f"{k}_{'rad' if k == 'orientation' else 'm'}": v
               for k, v in zip(levels.keys, levels.sigma, strict=True)})
        choose = context.model_choice.choose_full_pose_extensions
        choice = choose(machine, data, method, cv_noise, frames=frames, fix_frames=fix_frames)
        if choice.adopted:
            model = choice.machine
            result = solve(source, calibrate_full_pose, model, data, held=held,
                            method=method, noise=noise_model, frames=frames,
                            fix_frames=fix_frames, estimate_noise=hold, robust=options.robust)
        result.extensions = choice
    # the machine file's legs with the frames fitted alone: "before calibration"
    before = solve(source, calibrate_full_pose, machine, data, held=held, method=method,
                    noise=noise_model, frames=frames if fix_frames
                    else result.section(PoseSection).start_frames, fix_frames=fix_frames,
                    fit_machine=False)
    require_converged(result, source)

    units = context.units
    fl = LENGTH[units["length"]]
    calibrated = result.machine
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    calibrated.home = machine.home
    section = result.section(PoseSection)
    section.origin = frames_from
    frames_id, frames_before = section.frames, before.section(PoseSection).frames
    err_after = full_pose_errors(calibrated, frames_id, data)
    err_before = full_pose_errors(machine, frames_before, data)

    reading_unit = getattr(machine, "reading_unit", None) or machine.joint_unit()[0]
    gain_factor = fl / reading_factor(reading_unit)         # internal gain -> file gain
    nominal_of = dict(zip(model.parameters.names, model.u, strict=True))
    start = section.start_frames
    for name, (R, t) in (("mocap_from_base", start.mocap_from_base),
                         ("platform_from_marker", start.platform_from_marker)):
        nominal_of.update({f"{name}.r{c}": 0.0 for c in "xyz"})
        nominal_of.update({f"{name}.{c}": v for c, v in zip("xyz", t, strict=True)})
    params = parameter_table(result, nominal_of, units)
    for p in params:
        if p["name"].endswith(".gain"):
            for key in ("nominal", "identified", "change", "std"):
                if p[key] is not None:
                    p[key] = p[key] / gain_factor
            p["unit"] = f"{units['length']}/{reading_unit}"
        elif p["name"].endswith(".curvature"):           # internal -> file length / reading^2
            for key in ("nominal", "identified", "change", "std"):
                if p[key] is not None:
                    p[key] = p[key] * reading_factor(reading_unit) ** 2 / fl
            p["unit"] = f"{units['length']}/{reading_unit}^2"
    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.unidentifiable)
    # the ik estimate takes the poses as exact, but their noise is in the residuals: its
    # residual test is against the whole noise (readings + poses through the IK); the residuals
    # section states the verdict's numbers (the calibration layer's finish)
    variance = float(result.residual_variance)
    after, before_rep = _errors_report(err_after, fl), _errors_report(err_before, fl)
    extensions = (choice.as_dict({"leg_length": (fl, units["length"]), "position": (
        fl, units["length"]), "orientation": (math.pi / 180, "deg")}) if choice is not None
        else {"tried": [], "adopted": [], "skipped": "--extensions none" if
              options.extensions == "none" else "the machine offers none"})
    report = {
        **context.head(machine, "pose", method, units),
        "reading_unit": reading_unit,
        "measurements": len(data),
        "noise": {"reading_um": noise_model.reading_m * 1e6,
                  "position_um": noise_model.position_m * 1e6,
                  "orientation_urad": noise_model.orientation_rad * 1e6},
        **section.as_report(units),         # frames
        "convergence": convergence_json(result),
        "residuals": {
            "unit": units["length"],
            "leg_length": "l0 + gain q minus the leg length at the measured pose (through the "
                          "frames)",
            "pose": "measured marker pose minus the one forward kinematics of the readings "
                    "predict (through the frames)",
            "before": "the machine file's legs, frames fitted alone",
            "before_calibration": before_rep,
            "after_calibration": after,
            "residual_variance": variance,
            "noise_scale": math.sqrt(variance) if math.isfinite(variance) else None,
            "dof": int(result.dof),
        },
        "identifiability": identifiability_json(n_free, rank, unidentifiable, s),
        "parameters": public_parameters(params),
        "model_extensions": extensions,
    }
    if held is not None:
        h_after = _errors_report(full_pose_errors(calibrated, frames_id, held), fl)
        h_before = _errors_report(full_pose_errors(machine, frames_before, held), fl)
        report["validation"] = validation_section(
            split, held, "pose error of the held-out rows: forward kinematics of the readings "
            "(through the identified frames) vs the measured pose; before: the machine file's "
            "legs, frames fitted alone on the calibration rows", units["length"],
            *json_safe([h_before["position_rms"], h_after["position_rms"],
                        after["position_rms"]]), before_calibration=h_before,
            after_calibration=h_after)
    metadata = {
        "method": f"full-pose-{method}",
        "date": report["date"],
        "data": path_text(source),
        "machine": source_of(machine),
        "measurements": len(data),
        "leg_length_rms": {"before": before_rep["leg_length_rms"],
                           "after": after["leg_length_rms"], "unit": units["length"]},
        "frames_fixed": bool(fix_frames),
        "model_extensions": list(choice.adopted) if choice is not None else [],
        "identifiable": rank,
        "free_parameters": n_free,
        **identifiability_metadata(unidentifiable),
    }
    # the nominal of the fitted model (with an adopted extension at its neutral values)
    return FlowResult("pose", model, calibrated, result, report, metadata, params, units)
