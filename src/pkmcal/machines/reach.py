"""Where a machine reaches: the bed plane of its nominal model and the disk on it the platform
point reaches within its limits, well conditioned (probe plans, a printer's print disk)."""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..kinematics import euler_from_matrix, matrix_from_euler
from .base import Machine
from .deviations import draw_accepted


@dataclass
class Workspace:
    """Poses where accuracy is evaluated, with what they are in words.

    Attributes
    ----------
    P : ndarray, shape (K, 3)
        Positions, m.
    R : ndarray, shape (K, 3, 3)
        Orientations.
    description : str
        E.g. "the 0.1 m cube around home, orientations within +/-10 deg".
    bounds : tuple of ndarray
        ``(lo, hi)``, (3,) each, m: the box the positions span (for maps).
    surface : ndarray of bool, shape (K,), optional
        Poses on the bed (a printer's print disk): their z error is the nozzle's height
        error above the bed.
    """

    P: np.ndarray
    R: np.ndarray
    description: str
    bounds: tuple[np.ndarray, np.ndarray]
    surface: np.ndarray | None = None


#: largest inverse condition number of the joint Jacobian accepted at a probe point
PROBE_CONDITIONING = 0.05
#: the probe radius of plans: this fraction of the largest reachable, well-conditioned radius
PROBE_MARGIN = 0.8


def bed_height(machine: Machine) -> float:
    """Height of the nominal bed (a horizontal plane) in the base frame, m.

    The machine's ``bed_height`` (an attribute or method) when it has one, else the height of
    its home position (the plane probe plans lie on).

    Parameters
    ----------
    machine : Machine
        The machine.

    Returns
    -------
    float
        The bed's z, m.
    """
    own = getattr(machine, "bed_height", None)
    if callable(own):
        own = own()
    return float(machine.home[0][2] if own is None else own)


def bed_centre(machine: Machine) -> np.ndarray:
    """Centre of probe patterns on the bed: the machine's ``bed_centre`` or home's x, y.

    Parameters
    ----------
    machine : Machine
        The machine.

    Returns
    -------
    ndarray, shape (2,)
        x, y, m.
    """
    own = getattr(machine, "bed_centre", None)
    if callable(own):
        own = own()
    return np.asarray(machine.home[0][:2] if own is None else own, float)[:2]


def _probe_ok(machine: Machine, P, R, bed=None) -> np.ndarray:
    """Probe points the machine reaches, within its physical and joint limits (over the bed
    plane ``bed``, :meth:`~pkmcal.machines.Machine.physical_limits`), well conditioned, in the
    working mode."""
    with np.errstate(all="ignore"):
        q, J, _ = machine.ik_jacobians(P, R, want_du=False)
        space = list(machine.pose_space)
        J = np.array(J, float)[..., space]
        J[..., [k for k, i in enumerate(space) if i >= 3]] /= machine.characteristic_length()
        ok = np.all(np.isfinite(q), -1) & np.all(np.isfinite(J), (-2, -1))
        sv = np.linalg.svd(np.where(ok[:, None, None], J, 1.0), compute_uv=False)
        ok &= sv[..., -1] > PROBE_CONDITIONING * sv[..., 0]
        ok &= machine.working_mode(P, R)
        ok &= machine.within_physical_limits(P, R, q, bed=bed)
        if getattr(machine, "joint_limits", None) is not None and ok.any():
            ok[ok] = machine.within_limits(q[ok])
    return ok


def _bed_points(machine: Machine, xy, bed=None):
    """Poses with the nozzle tip at ``xy`` on the bed, the platform at home orientation (the
    tip is the platform origin): the nominal bed's height, or on a machine whose frame is its
    bed the plane ``bed`` (``(height m, tilt_x, tilt_y)``, the experiment's set-up
    :class:`~pkmcal.instruments.probe.BedSetup`;
    :meth:`~pkmcal.machines.Machine.targets_in_base`: a tilted bed's points lie on it, not
    under it)."""
    xy = np.atleast_2d(np.asarray(xy, float))
    P = machine.targets_in_base(np.column_stack([xy, np.full(len(xy), bed_height(machine))]),
                                bed)
    return P, np.broadcast_to(machine.home[1], (len(P), 3, 3)).copy()


def _centre_unprobed(machine: Machine, centre, bed=None) -> str:
    """Why the bed's centre cannot be probed, for a message: the joint limits when the
    centre is reached, well conditioned, but needs joint values outside them (the cause to
    fix is then ``joint_limits``, not the bed or home); else out of reach or badly
    conditioned."""
    where = str(getattr(machine, "source", "") or "the machine")
    point = (f"the bed's centre ({centre[0] * 1e3:.6g}, {centre[1] * 1e3:.6g}, "
             f"{bed_height(machine) * 1e3:.6g}) mm")
    P, R = _bed_points(machine, centre[None, :], bed)
    if getattr(machine, "joint_limits", None) is not None:
        with np.errstate(all="ignore"):
            q = np.asarray(machine.ik(P, R), float).reshape(1, -1)
        free = copy.copy(machine)
        free.joint_limits = None
        if _probe_ok(free, P, R, bed).all() and not machine.within_limits(q).all():
            broken = machine.limit_violation_text(q).removeprefix("row 1: ")
            return (f"{where}: joint_limits ({machine.joint_limits_text()}) exclude "
                    f"{point}, where every probe pattern is centred: it needs {broken}; "
                    "widen joint_limits")
    return (f"{where}: {point} cannot be probed (out of reach or badly conditioned); set "
            "the bed or home")


def probe_radius(machine: Machine, bed=None) -> float:
    """Radius of probe patterns on the bed, m.

    The machine's ``probe_radius`` when it has one (a printer's configured probe radius), else
    :data:`PROBE_MARGIN` times the largest radius ``r`` (in steps of 1/40 of the
    characteristic length) such that the circles of radius up to ``r`` about
    :func:`bed_centre` on the bed are reachable, within the joint limits and well
    conditioned (inverse condition number above :data:`PROBE_CONDITIONING`).

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    bed : array_like, shape (3,), optional
        The bed plane ``(height m, tilt_x, tilt_y)`` of the experiment's set-ups (a
        printer's, :class:`~pkmcal.instruments.probe.BedSetup`); None: the nominal bed.

    Returns
    -------
    float
        The radius, m.

    Raises
    ------
    InputError
        When not even the bed's centre can be probed.
    """
    own = getattr(machine, "probe_radius", None)
    if callable(own):
        own = own()
    if own is not None:
        return float(own)
    L = machine.characteristic_length()
    centre = bed_centre(machine)
    t = np.linspace(0.0, 2 * np.pi, 72, endpoint=False)
    ring = np.column_stack([np.cos(t), np.sin(t)])
    if not _probe_ok(machine, *_bed_points(machine, centre[None, :], bed), bed).all():
        raise InputError(_centre_unprobed(machine, centre, bed))
    r = 0.0
    for k in range(1, 41):
        radius = k * L / 40
        if not _probe_ok(machine, *_bed_points(machine, centre + radius * ring, bed),
                         bed).all():
            break
        r = radius
    return PROBE_MARGIN * (r if r > 0 else L / 80)


def workspace_poses(center, half_size: float = 0.05, max_angle: float = np.deg2rad(10.0),
                    n: int = 500, rng=None):
    """``n`` poses uniform in the cube ``center +/- half_size`` with Euler angles uniform in
    ``+/- max_angle``.

    Parameters
    ----------
    center : array_like, shape (3,)
        Centre of the cube, m.
    half_size : float, optional
        Half-width of the cube, m.
    max_angle : float, optional
        Bound of each Euler angle, rad.
    n : int, optional
        Number of poses.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.

    Returns
    -------
    P : ndarray, shape (n, 3)
        Positions, m.
    R : ndarray, shape (n, 3, 3)
        Orientations (about the identity).
    """
    rng = np.random.default_rng(rng)
    P = np.asarray(center, float) + rng.uniform(-half_size, half_size, (n, 3))
    R = matrix_from_euler(rng.uniform(-max_angle, max_angle, (n, 3)))
    return P, R


def machine_workspace(machine: Machine, n: int = 500, rng=0):
    """:func:`workspace_poses` around ``machine``'s home (SPEC 5 defaults).

    Parameters
    ----------
    machine : Machine
        The machine; its home position is the centre.
    n : int, optional
        Number of poses.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed (default 0: the same poses every call).

    Returns
    -------
    P : ndarray, shape (n, 3)
        Positions, m.
    R : ndarray, shape (n, 3, 3)
        Orientations; the identity for a translation-only platform, turned about z alone
        for a planar one (:func:`in_pose_space`).
    """
    P, R = workspace_poses(machine.home[0], n=n, rng=rng)
    return in_pose_space(machine, P, R)


def in_pose_space(machine: Machine, P, R):
    """Poses held to the coordinates the platform moves along (:attr:`Machine.pose_space`).

    A coordinate the platform does not move along keeps its home value: the identity
    orientation of a translation-only platform; a planar platform's home height and its
    Euler angles about x and y at 0 (angle i turns about axis i). A platform that moves along
    every coordinate gets the poses unchanged.

    Parameters
    ----------
    machine : Machine
        The machine.
    P : ndarray, shape (K, 3)
        Positions, m.
    R : ndarray, shape (K, 3, 3)
        Orientations.

    Returns
    -------
    P : ndarray, shape (K, 3)
        Positions, m.
    R : ndarray, shape (K, 3, 3)
        Orientations.
    """
    if not machine.rotates:
        return P, np.broadcast_to(np.eye(3), np.shape(R))
    space = machine.pose_space
    if len(space) == 6:
        return P, R
    moves = np.isin(np.arange(6), space)
    P = np.where(moves[:3], P, np.asarray(machine.home[0], float))
    R = matrix_from_euler(np.where(moves[3:], euler_from_matrix(R), 0.0))
    return P, R


def _orientation_words(machine: Machine, max_angle: float) -> str:
    """``", orientations within +/-10 deg"`` (``rotations about z`` for a planar platform),
    empty for a platform that only translates."""
    if not machine.rotates:
        return ""
    axes = [a for i, a in zip((3, 4, 5), "xyz", strict=True) if i in machine.pose_space]
    what = "orientations" if len(axes) == 3 else "rotations about " + ", ".join(axes)
    return f", {what} within +/-{np.degrees(max_angle):.3g} deg"


def box_workspace(machine: Machine, lo, hi, n: int = 500, rng=0,
                  max_angle: float = np.deg2rad(10.0), description: str | None = None):
    """``n`` poses uniform in the box ``lo..hi`` with Euler angles uniform in ``+/-
    max_angle`` (the identity for a translation-only platform).

    The draws are those of :func:`workspace_poses` for a cube: a box equal to the SPEC 5
    cube around home gives the poses of :func:`machine_workspace` with the same ``rng``.

    Parameters
    ----------
    machine : Machine
        The machine (its ``pose_space``).
    lo, hi : array_like, shape (3,)
        Corners of the box, m (``lo < hi``).
    n : int, optional
        Number of poses.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.
    max_angle : float, optional
        Bound of each Euler angle, rad.
    description : str, optional
        The box in words; default: its corners in mm.

    Returns
    -------
    Workspace
        The poses, their description and the box.
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    rng = np.random.default_rng(rng)
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    P = centre + rng.uniform(-1.0, 1.0, (n, 3)) * half
    R = matrix_from_euler(rng.uniform(-max_angle, max_angle, (n, 3)))
    P, R = in_pose_space(machine, P, R)
    if description is None:
        description = "box " + ", ".join(f"{c} {a * 1e3:.6g}..{b * 1e3:.6g} mm"
                                         for c, a, b in zip("xyz", lo, hi, strict=True))
    description += _orientation_words(machine, max_angle)
    return Workspace(P, R, description, (lo, hi))


def default_workspace(machine: Machine, n: int = 500, rng=0) -> Workspace:
    """The SPEC 5 workspace of ``machine`` (:func:`machine_workspace`) as a :class:`Workspace`.

    Parameters
    ----------
    machine : Machine
        The machine; its home position is the centre.
    n : int, optional
        Number of poses.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.

    Returns
    -------
    Workspace
        The 0.1 m cube around home, orientations within +/-10 deg.
    """
    P, R = machine_workspace(machine, n, rng)
    c = np.asarray(machine.home[0], float)
    box = "cube" if {0, 1, 2} <= set(machine.pose_space) else "square in the plane"
    words = f"0.1 m {box} around home" + _orientation_words(machine, np.deg2rad(10.0))
    return Workspace(P, R, words, (c - 0.05, c + 0.05))


#: half-width of the sampled workspace box, in characteristic lengths of the machine
HALF_RANGE = 0.25
#: bound of each sampled Euler angle (rad) for platforms that rotate
MAX_ANGLE = np.deg2rad(10.0)


def sample_workspace_poses(machine: Machine, n: int, rng=None, half_range: float | None = None,
                           max_angle: float = MAX_ANGLE, min_conditioning: float = 0.05):
    """``n`` random poses around home that the machine can command, well conditioned.

    Positions uniform in a cube of half-width ``half_range`` (default :data:`HALF_RANGE`
    characteristic lengths) around home; for platforms that rotate, Euler angles uniform in
    ``+/- max_angle`` on the home orientation. Kept: reachable poses of the working mode
    (:meth:`~pkmcal.machines.Machine.working_mode`) within the joint limits whose joint
    Jacobian's inverse condition number (rotations scaled) is above ``min_conditioning``,
    within the machine's physical limits (:meth:`~pkmcal.machines.Machine.physical_limits`).

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    n : int
        Number of poses (>= 1).
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.
    half_range : float, optional
        Half-width of the position cube, m.
    max_angle : float, optional
        Bound of each Euler angle, rad (unused for translation-only platforms).
    min_conditioning : float, optional
        Smallest accepted inverse condition number.

    Returns
    -------
    P : ndarray, shape (n, 3)
        Positions, m.
    R : ndarray, shape (n, 3, 3)
        Orientations.

    Raises
    ------
    InputError
        When ``n < 1`` or not enough feasible poses are found.
    """
    if n < 1:
        raise InputError(f"the number of poses must be >= 1, got {n}")
    rng = np.random.default_rng(rng)
    P0, R0 = machine.home
    half = HALF_RANGE * machine.characteristic_length() if half_range is None else half_range
    rotates = machine.rotates
    # the pose coordinates the platform moves along (a planar platform: x, y and the angle
    # about z; Euler angle i turns about axis i, so the angles keep the rotation's axes)
    space = list(machine.pose_space)
    moves = np.zeros(6, bool)
    moves[space] = True

    def draw(m, rng):
        P = P0 + np.where(moves[:3], rng.uniform(-half, half, (m, 3)), 0.0)
        R = (matrix_from_euler(np.where(moves[3:], rng.uniform(-max_angle, max_angle, (m, 3)),
                                        0.0)) @ R0 if rotates
             else np.broadcast_to(np.eye(3), (m, 3, 3)).copy())
        with np.errstate(all="ignore"):
            q, J, _ = machine.ik_jacobians(P, R, want_du=False)
            J = np.array(J, float)
            J[..., 3:] /= machine.characteristic_length()
            J = J[..., space]
            ok = np.all(np.isfinite(q), -1) & np.all(np.isfinite(J), (-2, -1))
            sv = np.linalg.svd(np.where(ok[:, None, None], J, 1.0), compute_uv=False)
            ok &= sv[..., -1] > min_conditioning * sv[..., 0]
            ok &= machine.working_mode(P, R)
            ok &= machine.within_physical_limits(P, R, q)
        return P, R, ok

    where = str(getattr(machine, "source", "") or "").replace("{", "{{").replace("}", "}}")
    return draw_accepted(draw, n, rng, (f"{where}: " if where else "")
                         + "only {have} of {n} random poses around home are reachable and "
                         "well conditioned: check the geometry and home", machine=machine)
