"""Simulated instrument measurements on any machine: workspace poses, circles, the experiment.

The experiment: the *nominal* model commands poses, the *true* machine goes elsewhere (its
forward kinematics of the commanded readings), and the instrument, with its true unknowns,
measures there with noise.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..kinematics import matrix_from_euler
from ..machines.base import Machine
from ..measurements.deviations import draw_accepted
from .data import InstrumentData
from .models import NuisanceModel, NuisanceState

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
    Jacobian's inverse condition number (rotations scaled) is above ``min_conditioning``.

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
    rotates = machine.pose_dof == 6

    def draw(m, rng):
        P = P0 + rng.uniform(-half, half, (m, 3))
        R = (matrix_from_euler(rng.uniform(-max_angle, max_angle, (m, 3))) @ R0 if rotates
             else np.broadcast_to(np.eye(3), (m, 3, 3)).copy())
        with np.errstate(all="ignore"):
            q, J, _ = machine.ik_jacobians(P, R, want_du=False)
            J = np.array(J, float)
            if not rotates:
                J = J[..., :3]
            else:
                J[..., 3:] /= machine.characteristic_length()
            ok = np.all(np.isfinite(q), -1) & np.all(np.isfinite(J), (-2, -1))
            sv = np.linalg.svd(np.where(ok[:, None, None], J, 1.0), compute_uv=False)
            ok &= sv[..., -1] > min_conditioning * sv[..., 0]
            ok &= machine.working_mode(P, R)
        return P, R, ok

    where = str(getattr(machine, "source", "") or "").replace("{", "{{").replace("}", "}}")
    return draw_accepted(draw, n, rng, (f"{where}: " if where else "")
                         + "only {have} of {n} random poses around home are reachable and "
                         "well conditioned: check the geometry and home", machine=machine)


def circle_poses(machine: Machine, centre, radius: float, n: int, normal=(0.0, 0.0, 1.0)):
    """``n`` poses on a circle (a ballbar test, ISO 230-4), the platform at home orientation.

    Parameters
    ----------
    machine : Machine
        The machine (its home orientation is kept).
    centre : array_like, shape (3,)
        Centre of the circle (the ballbar's pivot), m.
    radius : float
        Radius, m.
    n : int
        Number of poses, equally spaced.
    normal : array_like, shape (3,), optional
        Normal of the circle's plane.

    Returns
    -------
    P : ndarray, shape (n, 3)
        Positions, m.
    R : ndarray, shape (n, 3, 3)
        Orientations.
    """
    nvec = np.asarray(normal, float)
    nvec = nvec / np.linalg.norm(nvec)
    a = np.cross(nvec, [1.0, 0.0, 0.0] if abs(nvec[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(nvec, a)
    t = 2 * np.pi * np.arange(n) / n
    P = np.asarray(centre, float) + radius * (np.cos(t)[:, None] * a + np.sin(t)[:, None] * b)
    return P, np.broadcast_to(machine.home[1], (n, 3, 3)).copy()


def simulate_instrument(true_machine: Machine, nominal_machine: Machine, model: NuisanceModel,
                        truth: NuisanceState, P, R, group=None, noise=None,
                        rng=None) -> InstrumentData:
    """Measurements of the true machine by an instrument at poses the nominal model commands.

    Parameters
    ----------
    true_machine : Machine
        The machine that moves.
    nominal_machine : Machine
        The model that computes the commanded readings (inverse kinematics of ``P, R``).
    model : NuisanceModel
        The instrument's model.
    truth : NuisanceState
        Its true unknowns (frame, targets, pivots).
    P : array_like, shape (K, 3)
        Commanded positions, m.
    R : array_like, shape (K, 3, 3)
        Commanded orientations.
    group : array_like of int, shape (K,), optional
        0-based target / setup of each row.
    noise : object, optional
        Has ``sample(values, rng)``; None: exact measurements.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.

    Returns
    -------
    InstrumentData
        Readings, measurements and the true poses.

    Raises
    ------
    InputError
        When the nominal model cannot reach a commanded pose or the true machine cannot reach
        the commanded readings.
    """
    rng = np.random.default_rng(rng)
    q = nominal_machine.ik(np.asarray(P, float), np.asarray(R, float))
    if not np.all(np.isfinite(q)):
        bad = np.flatnonzero(~np.all(np.isfinite(q), -1)) + 1
        raise InputError(f"poses {bad[:10].tolist()} are outside the nominal workspace")
    fk = true_machine.fk(q, start=(np.asarray(P, float), np.asarray(R, float)))
    if not fk.converged.all():
        raise InputError("the true machine cannot reach some commanded readings")
    group = np.zeros(len(q), int) if group is None else np.asarray(group, int)
    y = model.predict(truth, fk.P, fk.R, group)
    if noise is not None:
        y = y + noise.sample(y, rng)
    return InstrumentData(model.kind, q, y, group, source="<simulated>", true_P=fk.P,
                          true_R=fk.R)
