"""Full-pose measurements of a six-leg platform (SPEC 2.4): leg readings + a measured pose.

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

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ...kinematics import matrix_from_euler, matrix_from_rotvec
from ...machines.base import Machine
from ...machines.deviations import draw_accepted
from ...paths import path_text

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

    def targets_from_base(self, machine, P):
        """``P`` itself: the inverse of :meth:`targets_in_base`."""
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
