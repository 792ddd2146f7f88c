"""Pose errors of a six-leg platform from joint clearance, leg-length errors and loads
(seed 003, SPEC 2.3).

Conventions (SPEC 1, 2.3)
-------------------------
- Pose errors ``dx = [dp (3, m), dOmega (3, rad)]``: the platform origin moves by ``dp`` and the
  platform turns by the small rotation vector ``dOmega`` about the base axes
  (``R_real = exp(dOmega) R``, seed 003 eq. 6).
- Leg i joins the base joint ``b_i`` (base frame) and the platform joint ``p_i`` (platform
  frame); ``s_i = R p_i``, ``w_i = t + s_i - b_i = l_i z_i`` (seed 003 eq. 1-4): ``z_i`` is the
  unit vector **from the base joint to the platform joint**.
- ``J_p`` row i = ``[z_i^T, (s_i x z_i)^T]`` and ``J_s`` row i = ``[z_i^T R, -z_i^T]`` on the
  joint errors ``[dp_i (platform frame), db_i (base frame)]`` (eq. 8-9), so that
  ``dl = J_p dx + J_s dp`` and, for legs whose lengths are off by ``dl``,
  ``dx = J_p^-1 (dl - J_s dp)`` (eq. 10).
- **Link forces are tension positive.** A leg in tension with force ``f_i > 0`` pulls the
  platform toward the base: it applies ``-f_i z_i`` at the platform joint. The loads act at the
  platform origin (its centre of mass): weight ``m g`` (``g = (0, 0, -9.80665) m/s^2``), the
  cutting force ``F_C`` and the inertia of the accelerated platform (translation only: the
  rotational inertia is not modelled). Newton for the platform,
  ``sum_i (-f_i z_i) + m g + F_C = m a`` and the moments about the origin
  ``sum_i s_i x (-f_i z_i) = 0``, reads ``J (-f) = w`` with ``J = J_p^T`` (seed 003 eq. 14,
  columns ``[z_i; s_i x z_i]``) and the wrench ``w = [m a - m g - F_C; 0]``:
  ``f = -J^-1 w``. Hand check: a platform hanging on vertical legs under its weight has
  ``f < 0`` — the legs are in compression. (The paper calls its ``tau = J^-1 F`` "tension";
  with ``z_i`` from base to platform a positive ``tau`` pushes the platform away from the base,
  i.e. it is compression: ``tau = -f``.)
- **Clearance** (eq. 17-18, Fig. 3): the centre of each universal joint sits anywhere in a
  sphere of radius ``c`` about its nominal place; the leg force pushes it to one side. In
  tension the leg's pin bears on the side of the base hole toward the platform and on the side
  of the platform hole toward the base: the leg's ends sit at ``b_i + c_b z_i`` and
  ``t + R p_i - c_p z_i``, i.e. joint errors ``db_i = +c_b z_i``, ``dp_i = -c_p R^T z_i`` and the
  nominal joints are ``c_b + c_p`` *farther* apart than the leg is long (the leg acts
  ``+2 c`` longer). In compression all signs flip (``-2 c``). Ball-screw backlash ``e`` acts the
  same way: the nut takes up its play in the direction of the force, the leg acts ``+e`` longer
  in tension and ``-e`` shorter in compression.
- **Undetermined side.** Where ``|f_i|`` is below the force tolerance the side a joint rests on
  is unknown: the joint may sit anywhere in its sphere. The pose error is then an *envelope*:
  to first order only the component along ``z_i`` matters, so leg i contributes
  ``J_p^-1[:, i] * delta_i`` with ``delta_i`` anywhere in ``[-(c_b + c_p + e), +(c_b + c_p + e)]``
  and the bounds are the centre value ``+/- |J_p^-1| delta_max`` (the same as the min/max over
  the ``2^k`` side combinations of the ``k`` undetermined legs). The centre value (joint in the
  middle of its sphere) is reported as the error there; the sign of a round-off force is never
  used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..kinematics import rotvec_from_matrix
from ..machines.base import FKResult, newton_pose_solve

#: standard gravity, m/s^2 (the weight acts along -Z of the base frame, SPEC 1)
STANDARD_GRAVITY = 9.80665
#: names of the six components of a pose error ``[dp, dOmega]``
ERROR_COMPONENTS = ("dx", "dy", "dz", "drx", "dry", "drz")
#: relative floor of the force tolerance: a force below this fraction of the largest leg
#: force of the same pose is round-off, whatever the absolute tolerance says
FORCE_ROUNDOFF = 1e-9
#: relative tolerance on the scaled singular values of J_p (singular poses)
SINGULAR_RTOL = 1e-9


# --------------------------------------------------------------------------------------------
# statics (seed 003 eq. 11-16)
# --------------------------------------------------------------------------------------------


def platform_wrench(acceleration=None, mass: float = 4.8, cutting_force=(0.0, 0.0, -500.0),
                    gravity: float = STANDARD_GRAVITY) -> np.ndarray:
    """The wrench the legs must balance, ``w = [m a - m g - F_C; 0]``.

    The loads act at the platform origin, so their moment about it is zero; the platform's
    rotational inertia is not modelled (no angular acceleration on a fixed orientation).

    Parameters
    ----------
    acceleration : array_like, shape (..., 3), optional
        Acceleration of the platform origin, m/s^2 (None: at rest).
    mass : float, optional
        Platform mass, kg (centre of mass at the platform origin).
    cutting_force : array_like, shape (..., 3), optional
        Force on the platform at its origin, N (default 500 N down).
    gravity : float, optional
        Magnitude of the gravity acceleration along -Z, m/s^2.

    Returns
    -------
    ndarray, shape (..., 6)
        Force (N) and moment (N m, zero).
    """
    a = np.zeros(3) if acceleration is None else np.asarray(acceleration, float)
    fc = np.asarray(cutting_force, float)
    weight = np.array([0.0, 0.0, -float(mass) * float(gravity)])
    force = float(mass) * a - weight - fc
    return np.concatenate([force, np.zeros_like(force)], axis=-1)


def link_forces(Jp, wrench) -> np.ndarray:
    """Leg forces, **tension positive**, from ``J_p^T (-f) = w``.

    Seed 003 eq. 16 with the physical sign; see the module docstring.

    Parameters
    ----------
    Jp : array_like, shape (..., 6, 6)
        ``J_p`` of :meth:`pkmcal.machines.Stewart.jacobians`.
    wrench : array_like, shape (..., 6)
        The load, from :func:`platform_wrench`.

    Returns
    -------
    ndarray, shape (..., 6)
        Leg forces, N.
    """
    Jp = np.asarray(Jp, float)
    w = np.broadcast_to(np.asarray(wrench, float), Jp.shape[:-1])
    return -np.linalg.solve(np.swapaxes(Jp, -1, -2), w[..., None])[..., 0]


def force_residual(Jp, forces, wrench) -> np.ndarray:
    """Statics residual ``sum_i (-f_i) [z_i; s_i x z_i] - w`` (..., 6): zero when balanced."""
    return np.einsum("...ij,...i->...j", np.asarray(Jp, float), -np.asarray(forces, float)) \
        - np.asarray(wrench, float)


# --------------------------------------------------------------------------------------------
# first-order pose errors (seed 003 eq. 8-10, 17-18)
# --------------------------------------------------------------------------------------------


def pose_error(Jp, dl=None, Js=None, joint_errors=None) -> np.ndarray:
    """Seed 003 eq. 10: ``dx = J_p^-1 (dl - J_s dp)``.

    Parameters
    ----------
    Jp : array_like, shape (..., 6, 6)
        ``J_p`` of :meth:`pkmcal.machines.Stewart.jacobians`.
    dl : array_like, shape (..., 6), optional
        Leg-length errors, m (the leg is ``dl`` longer than commanded).
    Js : array_like, shape (..., 6, 6), optional
        Per-leg ``[z_i^T R, -z_i^T]`` (:meth:`pkmcal.machines.Stewart.jacobians`); needed
        with ``joint_errors``.
    joint_errors : array_like, shape (..., 6, 6), optional
        Per leg ``[dp_i (platform frame), db_i (base frame)]``, m.

    Returns
    -------
    ndarray, shape (..., 6)
        Pose errors ``[dp (m), dOmega (rad)]``.

    Raises
    ------
    ValueError
        When ``joint_errors`` are given without ``Js``.
    """
    Jp = np.asarray(Jp, float)
    rhs = np.zeros(Jp.shape[:-1])
    if dl is not None:
        rhs = rhs + np.asarray(dl, float)
    if joint_errors is not None:
        if Js is None:
            raise ValueError("pose_error: joint_errors need Js")
        rhs = rhs - np.einsum("...ij,...ij->...i", np.asarray(Js, float),
                              np.asarray(joint_errors, float))
    return np.linalg.solve(Jp, rhs[..., None])[..., 0]


def clearance_joint_errors(z, R, side, clearance_base, clearance_platform) -> np.ndarray:
    """Joint errors of eq. 17-18 with the physical sign (..., 6, 6): per leg
    ``[dp_i = -side_i c_p R^T z_i (platform frame), db_i = +side_i c_b z_i]``.

    ``side`` (..., 6): +1 tension, -1 compression, 0 joint centred (undetermined).
    ``clearance_base``, ``clearance_platform``: sphere radii (6,) or scalars, m.
    """
    z = np.asarray(z, float)
    side = np.asarray(side, float)[..., None]
    cb = np.broadcast_to(np.asarray(clearance_base, float), (6,))[:, None]
    cp = np.broadcast_to(np.asarray(clearance_platform, float), (6,))[:, None]
    db = side * cb * z
    dp = -side * cp * np.einsum("...ji,...kj->...ki", np.asarray(R, float), z)   # R^T z_k
    return np.concatenate([dp, db], axis=-1)


@dataclass
class ClearanceErrors:
    """Pose errors from joint clearance and backlash at a batch of poses.

    Attributes
    ----------
    dx : ndarray, shape (..., 6)
        ``[dp (m), dOmega (rad)]``; where a side is undetermined, the value with those joints
        centred (the middle of the envelope).
    dx_min, dx_max : ndarray, shape (..., 6)
        Envelope; equal to ``dx`` where every side is determined.
    side : ndarray of int, shape (..., 6)
        Per leg +1 tension, -1 compression, 0 undetermined.
    force_tol : ndarray, shape (...)
        Force tolerance used at each pose, N.
    """

    dx: np.ndarray
    dx_min: np.ndarray
    dx_max: np.ndarray
    side: np.ndarray
    force_tol: np.ndarray

    @property
    def undetermined(self) -> np.ndarray:
        """(..., 6) bool: legs whose force is within the tolerance of zero."""
        return self.side == 0


def force_sides(forces, force_tol: float = 1.0):
    """Side of every leg (..., 6): +1 tension, -1 compression, 0 where
    ``|f| <= max(force_tol, FORCE_ROUNDOFF * max_i |f_i|)``; and that tolerance (...,)."""
    f = np.asarray(forces, float)
    tol = np.maximum(float(force_tol), FORCE_ROUNDOFF * np.max(np.abs(f), axis=-1))
    side = np.where(np.abs(f) > tol[..., None], np.sign(f), 0.0).astype(int)
    return side, tol


def clearance_errors(Jp, Js, z, R, forces, clearance_base, clearance_platform=None,
                     backlash=0.0, force_tol: float = 1.0) -> ClearanceErrors:
    """Pose errors from joint clearance and ball-screw backlash under the leg forces.

    Clearance of eq. 17-18 and backlash of eq. 10, tension positive, with the envelope where
    a force is near zero (see the module docstring).

    Parameters
    ----------
    Jp : array_like, shape (..., 6, 6)
        ``J_p`` of :meth:`pkmcal.machines.Stewart.jacobians` at the poses.
    Js : array_like, shape (..., 6, 6)
        ``J_s`` of the same.
    z : array_like, shape (..., 6, 3)
        Unit leg vectors of the same.
    R : array_like, shape (..., 3, 3)
        Platform orientations.
    forces : array_like, shape (..., 6)
        Leg forces, N, tension positive (:func:`link_forces`).
    clearance_base : float or array_like, shape (6,)
        Sphere radius of the base joint centres, m.
    clearance_platform : float or array_like, shape (6,), optional
        Sphere radius of the platform joint centres, m; default ``clearance_base``.
    backlash : float or array_like, shape (6,), optional
        Ball-screw backlash, m: the leg acts ``+backlash`` longer in tension, shorter in
        compression.
    force_tol : float, optional
        A leg force with ``|f| <= force_tol`` (N, or below ``FORCE_ROUNDOFF`` of the largest leg
        force of the pose) leaves the side undetermined.

    Returns
    -------
    ClearanceErrors
        Pose errors, envelope, sides and force tolerances.

    Raises
    ------
    InputError
        When a clearance, the backlash or ``force_tol`` is negative or not finite.
    """
    cb = np.broadcast_to(np.asarray(clearance_base, float), (6,))
    cp = cb if clearance_platform is None else np.broadcast_to(
        np.asarray(clearance_platform, float), (6,))
    e = np.broadcast_to(np.asarray(backlash, float), (6,))
    for name, v in (("clearance_base", cb), ("clearance_platform", cp), ("backlash", e)):
        if not np.all(np.isfinite(v)) or np.any(v < 0):
            raise InputError(f"{name}: must be finite and >= 0, got {v.tolist()}")
    if not (np.isfinite(force_tol) and force_tol >= 0):
        raise InputError(f"force_tol: must be finite and >= 0, got {force_tol}")
    side, tol = force_sides(forces, force_tol)
    dp = clearance_joint_errors(z, R, side, cb, cp)
    dx = pose_error(Jp, dl=side * e, Js=Js, joint_errors=dp)
    Jinv = np.linalg.inv(np.asarray(Jp, float))
    half = np.einsum("...ji,...i->...j", np.abs(Jinv), (side == 0) * (cb + cp + e))
    return ClearanceErrors(dx, dx - half, dx + half, side, tol)


# --------------------------------------------------------------------------------------------
# trajectories
# --------------------------------------------------------------------------------------------


@dataclass
class Trajectory:
    """Poses of the platform along a path, with times and accelerations.

    Attributes
    ----------
    t : ndarray, shape (K,)
        Times, s.
    P : ndarray, shape (K, 3)
        Positions, m.
    R : ndarray, shape (K, 3, 3)
        Orientations.
    acceleration : ndarray, shape (K, 3)
        Acceleration of the platform origin, m/s^2.
    angle : ndarray, shape (K,), optional
        Position angle on a circle, rad (None for other trajectories).
    """

    t: np.ndarray
    P: np.ndarray
    R: np.ndarray
    acceleration: np.ndarray
    angle: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t)


def circle_trajectory(radius: float = 0.1, height: float = 0.41, omega: float = 10.0,
                      samples: int = 360, centre=(0.0, 0.0), R=None) -> Trajectory:
    """The case study of seed 003: the platform origin on a horizontal circle.

    The circle has radius ``radius`` about ``centre`` at ``z = height`` and is run
    counter-clockwise (seen from +Z) from +X at constant angular speed ``omega``, orientation
    fixed. Sample k is at angle ``2 pi k / samples`` (``360 k / samples`` deg), time
    ``angle / omega`` (0 when ``omega = 0``); the acceleration is centripetal,
    ``-omega^2 (P - centre)``.

    Parameters
    ----------
    radius : float, optional
        Radius, m (>= 0).
    height : float, optional
        Height of the circle, m.
    omega : float, optional
        Angular speed, rad/s.
    samples : int, optional
        Number of poses (>= 1).
    centre : array_like, shape (2,), optional
        Centre x, y, m.
    R : array_like, shape (3, 3), optional
        Platform orientation; default identity.

    Returns
    -------
    Trajectory
        With ``angle`` set.

    Raises
    ------
    InputError
        When ``samples`` is not a whole number >= 1, a value is not finite, or ``radius < 0``.
    """
    if not (isinstance(samples, (int, np.integer)) and samples >= 1):
        raise InputError(f"samples: must be a whole number >= 1, got {samples}")
    for name, v in (("radius", radius), ("height", height), ("omega", omega)):
        if not np.isfinite(v):
            raise InputError(f"{name}: must be finite, got {v}")
    if radius < 0:
        raise InputError(f"radius: must be >= 0, got {radius}")
    angle = 2.0 * np.pi * np.arange(samples) / samples
    c = np.asarray(centre, float)
    rel = radius * np.column_stack([np.cos(angle), np.sin(angle)])
    P = np.column_stack([c + rel, np.full(samples, float(height))])
    acc = np.column_stack([-float(omega) ** 2 * rel, np.zeros(samples)])
    t = angle / omega if omega != 0 else np.zeros(samples)
    R = np.broadcast_to(np.eye(3) if R is None else np.asarray(R, float), (samples, 3, 3))
    return Trajectory(t, P, np.array(R), acc, angle)


def acceleration_from_positions(t, P) -> np.ndarray:
    """Second derivative (K, 3) of positions ``P`` (K, 3) over times ``t`` (K,), strictly
    increasing, at least 3: the three-point formula on the (possibly uneven) grid,
    ``a_k = 2 [(P_k+1 - P_k)/h_k - (P_k - P_k-1)/h_k-1] / (h_k-1 + h_k)``; the end samples take
    their neighbour's value."""
    t = np.asarray(t, float)
    P = np.asarray(P, float)
    if t.ndim != 1 or len(t) < 3 or P.shape != (len(t), 3):
        raise InputError("a trajectory needs at least 3 poses with times to give accelerations")
    h = np.diff(t)
    if not np.all(h > 0):
        k = int(np.flatnonzero(~(h > 0))[0])
        raise InputError(f"times must increase strictly (sample {k + 2} at t = {t[k + 1]:g} s "
                         f"follows t = {t[k]:g} s)")
    v = np.diff(P, axis=0) / h[:, None]
    a = np.empty_like(P)
    a[1:-1] = 2.0 * (v[1:] - v[:-1]) / (h[:-1] + h[1:])[:, None]
    a[0], a[-1] = a[1], a[-2]
    return a


def trajectory_from_poses(t, P, R) -> Trajectory:
    """A trajectory through given poses; accelerations by finite differences of the positions.

    See :func:`acceleration_from_positions`.

    Parameters
    ----------
    t : array_like, shape (K,)
        Times, s, strictly increasing (K >= 3).
    P : array_like, shape (K, 3)
        Positions, m.
    R : array_like, shape (K, 3, 3)
        Orientations.

    Returns
    -------
    Trajectory
        Without ``angle``.

    Raises
    ------
    InputError
        When fewer than 3 poses are given or the times do not increase strictly.
    """
    t = np.asarray(t, float)
    P = np.asarray(P, float)
    return Trajectory(t, P, np.asarray(R, float), acceleration_from_positions(t, P))


# --------------------------------------------------------------------------------------------
# the analysis along a trajectory
# --------------------------------------------------------------------------------------------


@dataclass
class TrajectoryErrors:
    """Leg forces and pose errors along a trajectory (SPEC 2.3, seed 003 Figs. 6-7).

    Attributes
    ----------
    trajectory : Trajectory
        The trajectory.
    forces : ndarray, shape (K, 6)
        Leg forces, N, tension positive.
    wrench : ndarray, shape (K, 6)
        The load the legs balance, ``[m a - m g - F_C; 0]``.
    errors : ClearanceErrors
        ``dx``, ``dx_min``, ``dx_max``, ``side``.
    """

    trajectory: Trajectory
    forces: np.ndarray
    wrench: np.ndarray
    errors: ClearanceErrors


def zero_crossings(x, values, period: float | None = None, roundoff: float = FORCE_ROUNDOFF,
                   max_skipped: int = 1) -> np.ndarray:
    """Where a sampled quantity changes sign: ``x`` (K,) increasing, ``values`` (K,).

    Samples within ``roundoff`` of the largest ``|value|`` count as zero. Two samples of
    opposite signs with at most ``max_skipped`` zero samples between them make a crossing,
    placed by linear interpolation; a longer run of zeros (a quantity that vanishes over a
    stretch) is not a crossing. With ``period`` (a closed path such as a circle, ``x`` in
    ``[0, period)``) the last sample is also compared with the first; crossings are returned in
    ``[0, period)``.
    """
    x = np.asarray(x, float)
    v = np.asarray(values, float)
    K = v.size
    idx = np.flatnonzero(np.abs(v) > roundoff * (np.max(np.abs(v)) if K else 0.0))
    xs, vs = x[idx], v[idx]
    if period is not None and idx.size > 1:
        idx = np.append(idx, idx[0] + K)
        xs = np.append(xs, xs[0] + period)
        vs = np.append(vs, vs[0])
    k = np.flatnonzero((np.sign(vs[:-1]) * np.sign(vs[1:]) < 0)
                       & (np.diff(idx) <= max_skipped + 1))
    out = xs[k] + (xs[k + 1] - xs[k]) * vs[k] / (vs[k] - vs[k + 1])
    return np.sort(np.mod(out, period)) if period is not None else out


def check_poses(machine, P, R, labels=None, label: str = "pose") -> None:
    """Raise :class:`InputError` naming the poses (``labels``, default 1-based numbers) where a
    leg has no length or ``J_p`` is singular (scaled singular values, relative tolerance
    ``SINGULAR_RTOL``), outside home's working mode, or that the machine cannot take
    (:meth:`~pkmcal.machines.Machine.reachability`: its physical and joint limits)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        Jp, _, _ = machine.jacobians(P, R)
    _, _, L = machine.leg_vectors(P, R)
    scale = np.ones(6)
    scale[3:] = 1.0 / machine.characteristic_length()
    finite = np.all(np.isfinite(Jp), axis=(-1, -2))
    s = np.linalg.svd(np.where(finite[..., None, None], Jp, 0.0) * scale, compute_uv=False)
    bad = ~finite | ~(s[..., -1] > SINGULAR_RTOL * s[..., 0])
    bad |= ~np.all(L > 1e-9 * machine.characteristic_length(), axis=-1)
    if np.any(bad):
        idx = np.flatnonzero(np.atleast_1d(bad))
        names = (idx + 1) if labels is None else np.asarray(labels)[idx]
        shown = ", ".join(map(str, names[:10])) + (" ..." if idx.size > 10 else "")
        raise InputError(f"{idx.size} pose(s) at a singularity of the machine (the legs cannot "
                         f"hold the platform there): {label}(s) {shown}")
    off = ~np.atleast_1d(machine.working_mode(P, R))
    if np.any(off):
        idx = np.flatnonzero(off)
        names = (idx + 1) if labels is None else np.asarray(labels)[idx]
        shown = ", ".join(map(str, names[:10])) + (" ..." if idx.size > 10 else "")
        raise InputError(f"{idx.size} pose(s) outside the machine's working mode (farther than "
                         f"{machine.MAX_REACH:g}x its size from home, or beyond a singularity, "
                         f"e.g. the platform mirrored through the base): {label}(s) {shown}")
    reach = machine.reachability(P, R)        # physical and joint limits (machine file)
    if not reach.ok.all():
        idx = reach.unreachable
        names = (idx + 1) if labels is None else np.asarray(labels)[idx]
        shown = ", ".join(map(str, names[:10])) + (" ..." if idx.size > 10 else "")
        k = int(idx[0])
        pose = machine.pose_text(np.reshape(P, (-1, 3))[k], np.reshape(R, (-1, 3, 3))[k])
        raise InputError(f"{idx.size} pose(s) the machine cannot take: {label}(s) {shown}; "
                         f"{label} {names[0]} at {pose}: {reach.reasons[k]}")


def trajectory_errors(machine, trajectory: Trajectory, mass: float = 4.8,
                      cutting_force=(0.0, 0.0, -500.0), clearance: float = 10e-6,
                      clearance_platform: float | None = None, backlash: float = 0.0,
                      force_tol: float = 1.0, gravity: float = STANDARD_GRAVITY,
                      u=None) -> TrajectoryErrors:
    """Leg forces and clearance/backlash pose errors along ``trajectory`` (seed 003 case study).

    Parameters
    ----------
    machine : Stewart
        Any six-leg geometry.
    trajectory : Trajectory
        E.g. :func:`circle_trajectory`.
    mass : float, optional
        Platform mass, kg (>= 0).
    cutting_force : array_like, shape (3,) or (K, 3), optional
        Force on the platform, N.
    clearance : float or array_like, shape (6,), optional
        Sphere radius of the base joint centres, m.
    clearance_platform : float or array_like, shape (6,), optional
        Sphere radius of the platform joint centres, m; default ``clearance``.
    backlash : float or array_like, shape (6,), optional
        Ball-screw backlash, m.
    force_tol : float, optional
        N, see :func:`clearance_errors`.
    gravity : float, optional
        Gravity acceleration along -Z, m/s^2.
    u : array_like, shape (48,), optional
        Parameter vector; default: the machine's.

    Returns
    -------
    TrajectoryErrors
        Forces, wrenches and pose errors per pose.

    Raises
    ------
    InputError
        When ``mass`` or ``cutting_force`` is invalid, or a pose is singular (named).
    """
    if not (np.isfinite(mass) and mass >= 0):
        raise InputError(f"mass: must be finite and >= 0, got {mass}")
    fc = np.asarray(cutting_force, float)
    if not np.all(np.isfinite(fc)):
        raise InputError(f"cutting_force: must be finite, got {fc.tolist()}")
    P, R = trajectory.P, trajectory.R
    check_poses(machine, P, R)
    Jp, Js, z = machine.jacobians(P, R, u)
    wrench = platform_wrench(trajectory.acceleration, mass, fc, gravity)
    forces = link_forces(Jp, wrench)
    errors = clearance_errors(Jp, Js, z, R, forces, clearance, clearance_platform, backlash,
                              force_tol)
    return TrajectoryErrors(trajectory, forces, wrench, errors)


#: columns of the error table (SPEC 6, ``pkmcal errors``) after the first (``angle_deg`` on a
#: circle, else ``t_s``): leg forces, tension positive, then the pose error
ERRORS_FORCE_COLUMNS = tuple(f"f{i}_N" for i in range(1, 7))
ERRORS_POSE_COLUMNS = ("dx_um", "dy_um", "dz_um", "drx_urad", "dry_urad", "drz_urad")


def write_errors_csv(path, result: TrajectoryErrors, envelope_path=None) -> list:
    """Write the error table of SPEC 6 (``pkmcal errors -o``) and, optionally, its envelope.

    ``path`` gets exactly the SPEC 6 columns: ``angle_deg`` (a circle, :func:`circle_trajectory`)
    or ``t_s``, then ``f1_N..f6_N`` (tension positive) and ``dx_um, dy_um, dz_um, drx_urad,
    dry_urad, drz_urad``. ``envelope_path`` gets, per pose, the ``_min``/``_max`` bounds of
    each error component and ``undetermined_legs`` (1-based, space separated) where a leg
    force is too small to tell the clearance side. Files are written atomically (staged in the
    running output set, if any), the envelope first.

    Parameters
    ----------
    path : str or os.PathLike
        The error table.
    result : TrajectoryErrors
        Of :func:`trajectory_errors`.
    envelope_path : str or os.PathLike, optional
        The envelope table; None writes none.

    Returns
    -------
    list of pathlib.Path
        The files written, the error table first.
    """
    from ..io.csv_io import write_table

    path_ = result.trajectory
    e = result.errors
    first = (("angle_deg", np.degrees(path_.angle)) if path_.angle is not None
             else ("t_s", path_.t))
    scale = 1e6                                              # m -> um, rad -> urad
    header = [first[0], *ERRORS_FORCE_COLUMNS, *ERRORS_POSE_COLUMNS]
    columns = [first[1], *(result.forces.T + 0.0), *(e.dx * scale).T + 0.0]
    written = []
    if envelope_path is not None:
        env_header, env_columns = [first[0]], [first[1]]
        for j, name in enumerate(ERRORS_POSE_COLUMNS):
            base, unit = name.rsplit("_", 1)
            env_header += [f"{base}_min_{unit}", f"{base}_max_{unit}"]
            env_columns += [e.dx_min[:, j] * scale + 0.0, e.dx_max[:, j] * scale + 0.0]
        env_header.append("undetermined_legs")
        env_columns.append([" ".join(str(i + 1) for i in np.flatnonzero(row))
                            for row in e.undetermined])
        written.append(write_table(envelope_path, env_header, env_columns))
    return [write_table(path, header, columns), *written]


@dataclass
class ClearanceMap:
    """Clearance pose errors over a horizontal slice of the workspace.

    Attributes
    ----------
    x : ndarray, shape (nx,)
        Grid, m.
    y : ndarray, shape (ny,)
        Grid, m.
    z : float
        Height, m.
    dx : ndarray, shape (ny, nx, 6)
        Error under the given loads (joints centred where undetermined).
    bound : ndarray, shape (ny, nx, 6)
        Worst case over every side of every joint (any load), ``|J_p^-1| (c_b + c_p + e)``.
    valid : ndarray of bool, shape (ny, nx)
        False at singular poses (values NaN there).
    """

    x: np.ndarray
    y: np.ndarray
    z: float
    dx: np.ndarray
    bound: np.ndarray
    valid: np.ndarray


def clearance_map(machine, x, y, z: float, R=None, mass: float = 4.8,
                  cutting_force=(0.0, 0.0, -500.0), clearance: float = 10e-6,
                  clearance_platform: float | None = None, backlash: float = 0.0,
                  force_tol: float = 1.0, gravity: float = STANDARD_GRAVITY) -> ClearanceMap:
    """Clearance errors over a grid at one height, and their load-independent worst case.

    The platform is at rest under its weight and the cutting force; the worst case
    ``|J_p^-1| (c_b + c_p + e)`` has every joint on its worst side.

    Parameters
    ----------
    machine : Stewart
        Any six-leg geometry.
    x : array_like, shape (nx,)
        Grid positions along X, m.
    y : array_like, shape (ny,)
        Grid positions along Y, m.
    z : float
        Height, m.
    R : array_like, shape (3, 3), optional
        Platform orientation; default identity.
    mass : float, optional
        Platform mass, kg.
    cutting_force : array_like, shape (3,), optional
        Force on the platform, N.
    clearance : float or array_like, shape (6,), optional
        Sphere radius of the base joint centres, m.
    clearance_platform : float or array_like, shape (6,), optional
        Sphere radius of the platform joint centres, m; default ``clearance``.
    backlash : float or array_like, shape (6,), optional
        Ball-screw backlash, m.
    force_tol : float, optional
        N, see :func:`clearance_errors`.
    gravity : float, optional
        Gravity acceleration along -Z, m/s^2.

    Returns
    -------
    ClearanceMap
        The maps over the ``ny`` by ``nx`` grid.

    Raises
    ------
    InputError
        When a clearance, the backlash or ``force_tol`` is negative or not finite.
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    X, Y = np.meshgrid(x, y)
    P = np.stack([X, Y, np.full_like(X, float(z))], axis=-1)
    R = np.broadcast_to(np.eye(3) if R is None else np.asarray(R, float), X.shape + (3, 3))
    Jp, Js, zz = machine.jacobians(P, R)
    scale = np.ones(6)
    scale[3:] = 1.0 / machine.characteristic_length()
    s = np.linalg.svd(Jp * scale, compute_uv=False)
    valid = s[..., -1] > SINGULAR_RTOL * s[..., 0]
    Jp = np.where(valid[..., None, None], Jp, np.eye(6))
    forces = link_forces(Jp, platform_wrench(None, mass, cutting_force, gravity))
    err = clearance_errors(Jp, Js, zz, R, forces, clearance, clearance_platform, backlash,
                           force_tol)
    cb = np.broadcast_to(np.asarray(clearance, float), (6,))
    cp = cb if clearance_platform is None else np.broadcast_to(
        np.asarray(clearance_platform, float), (6,))
    e = np.broadcast_to(np.asarray(backlash, float), (6,))
    bound = np.einsum("...ji,i->...j", np.abs(np.linalg.inv(Jp)), cb + cp + e)
    nan = ~valid[..., None]
    return ClearanceMap(x, y, float(z), np.where(nan, np.nan, err.dx),
                        np.where(nan, np.nan, bound), valid)


# --------------------------------------------------------------------------------------------
# exact closure (reference for the first-order model, Monte Carlo)
# --------------------------------------------------------------------------------------------


def closure_pose(P0, R0, base, platform, lengths, tol: float = 1e-13,
                 max_iter: int = 30) -> FKResult:
    """Exact poses of platforms whose joints and leg lengths are given per sample: solves
    ``|t + R p_i - b_i| = l_i`` by Newton from ``(P0, R0)``, all samples at once.

    Parameters
    ----------
    P0, R0 : start pose (3,), (3, 3) or per sample (N, 3), (N, 3, 3).
    base, platform : (N, 6, 3) joints (base frame; platform frame), m.
    lengths : (N, 6) leg lengths, m.
    tol : m, on the largest leg-length residual.
    """
    base = np.asarray(base, float)
    platform = np.asarray(platform, float)
    lengths = np.asarray(lengths, float)
    N = base.shape[0]
    P = np.array(np.broadcast_to(np.asarray(P0, float), (N, 3)))
    R = np.array(np.broadcast_to(np.asarray(R0, float), (N, 3, 3)))

    def system(idx, P, R):
        s = np.einsum("kij,kmj->kmi", R, platform[idx])
        w = P[:, None, :] + s - base[idx]
        L = np.linalg.norm(w, axis=-1)
        zz = w / L[..., None]
        return L - lengths[idx], np.concatenate([zz, np.cross(s, zz)], axis=-1)

    return newton_pose_solve(system, P, R, tol, max_iter)


def pose_difference(P, R, P0, R0) -> np.ndarray:
    """``[P - P0, dOmega]`` (..., 6) with ``R = exp(dOmega) R0`` (rotation vector, base axes)."""
    dR = np.asarray(R, float) @ np.swapaxes(np.asarray(R0, float), -1, -2)
    return np.concatenate([np.asarray(P, float) - np.asarray(P0, float),
                           rotvec_from_matrix(dR)], axis=-1)


__all__ = [
    "ERROR_COMPONENTS", "STANDARD_GRAVITY", "ClearanceErrors", "ClearanceMap", "Trajectory",
    "TrajectoryErrors", "acceleration_from_positions", "check_poses", "circle_trajectory",
    "clearance_errors", "clearance_joint_errors", "clearance_map", "closure_pose",
    "force_residual", "force_sides", "link_forces", "platform_wrench", "pose_difference",
    "pose_error", "trajectory_errors", "trajectory_from_poses", "zero_crossings",
]
