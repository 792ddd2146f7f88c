"""Constraint-link measurements (seed 000 section 3, SPEC 2.1) and their simulation.

A bar of length ``Lc`` with ball joints joins the base point O (origin of the base frame) and the
platform point P (origin of the platform frame), so ``|P| = Lc``. Five actuators drive, the sixth
is passive and read as a sensor. One measurement = all six joint readings at a pose on the
sphere, plus which actuator was passive (optional).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ...kinematics import matrix_from_euler
from ...machines.base import Machine
from ...machines.deviations import draw_accepted


@dataclass
class ConstraintLinkData:
    """Joint readings taken with the constraint link mounted.

    Attributes
    ----------
    q : ndarray, shape (K, 6)
        Joint readings, internal units (m for sliders).
    link_length : float
        Assumed constraint-link length ``Lc``, m.
    passive : ndarray of int, shape (K,), optional
        0-based index of the passive actuator, or None when not recorded.
    rows : ndarray of int, shape (K,), optional
        Row numbers in the source file (1-based data rows) for messages; default 1..K.
    source : str, optional
        File name, for messages.
    true_P, true_R : ndarray, optional
        True poses of a simulation, (K, 3) m and (K, 3, 3) (for tests and plots), else None.
    """

    q: np.ndarray
    link_length: float
    passive: np.ndarray | None = None
    rows: np.ndarray | None = None
    source: str = "<data>"
    true_P: np.ndarray | None = None
    true_R: np.ndarray | None = None

    def __post_init__(self):
        self.q = np.atleast_2d(np.asarray(self.q, float))
        if self.rows is None:
            self.rows = np.arange(1, len(self.q) + 1)
        if self.passive is not None:
            self.passive = np.asarray(self.passive, int)

    def __len__(self) -> int:
        return len(self.q)

    def distinct(self) -> tuple[int, str]:
        """How many rows are distinct measurements, and the repeated rows in words.

        Returns
        -------
        count : int
            Number of distinct rows (readings and passive joint all equal count once).
        repeats : str
            E.g. ``"rows 3, 4 repeat row 2"`` (file rows), empty when every row is distinct.
        """
        key = self.q if self.passive is None else np.column_stack([self.q, self.passive])
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        inverse = np.ravel(inverse)
        copies = np.flatnonzero(first[inverse] != np.arange(len(key)))
        if not copies.size:
            return len(first), ""
        shown = ", ".join(str(int(self.rows[i])) for i in copies[:5])
        more = f" and {copies.size - 5} more" if copies.size > 5 else ""
        origin = sorted({int(self.rows[first[inverse[i]]]) for i in copies})
        origins = ", ".join(map(str, origin[:3])) + (" ..." if len(origin) > 3 else "")
        return len(first), (f"rows {shown}{more} repeat row{'s' if len(origin) > 1 else ''} "
                            f"{origins}")

    def subset(self, mask) -> ConstraintLinkData:
        """The measurements selected by a boolean mask or index array.

        Parameters
        ----------
        mask : array_like of bool or int
            Boolean mask (K,) or indices of the rows to keep.

        Returns
        -------
        ConstraintLinkData
            The selected rows, same link length and source.
        """
        pick = (lambda a: None if a is None else a[mask])
        return ConstraintLinkData(self.q[mask], self.link_length, pick(self.passive),
                                  self.rows[mask], self.source, pick(self.true_P),
                                  pick(self.true_R))


def loop_conditioning(machine: Machine, P, J):
    """Inverse condition number (K, n_joints) of the constrained loop for each passive choice.

    ``J`` (K, n, 6) is the joint Jacobian at poses with positions ``P`` (K, 3); for passive
    actuator p its row is replaced by the link's row ``[P/|P|, 0]``.
    """
    n = J.shape[-2]
    Js = np.array(J, float)
    Js[..., 3:] /= machine.characteristic_length()          # rotations as lengths
    link = np.concatenate([P / np.linalg.norm(P, axis=-1, keepdims=True),
                           np.zeros_like(P)], -1)
    loops = np.repeat(Js[:, None], n, axis=1)               # (K, p, n, 6)
    idx = np.arange(n)
    loops[:, idx, idx, :] = link[:, None, :]
    sv = np.linalg.svd(loops, compute_uv=False)
    return sv[..., -1] / sv[..., 0]


def sample_sphere_poses(machine: Machine, link_length: float, n: int, rng=None,
                        max_tilt: float = np.deg2rad(35.0),
                        max_rotation: float = np.deg2rad(25.0), min_manipulability=0.02,
                        min_loop_conditioning=2e-3):
    """``n`` reachable poses with ``|P| = link_length`` around the machine's home direction.

    P lies in a cap of half-angle ``max_tilt`` around the direction of the home position,
    uniform on the cap; Euler angles are uniform in ``+/- max_rotation``.

    Poses are redrawn where the inverse kinematics fail, where a joint value breaks the
    machine's ``joint_limits`` (machine file), where the joint Jacobian is badly
    conditioned (smallest singular value below ``min_manipulability`` times the largest,
    rotation columns scaled by the characteristic length), or where the machine cannot be
    driven with the link mounted: for some choice of passive actuator, the loop of the five
    active actuators and the link has an inverse condition number below
    ``min_loop_conditioning`` (about a tenth of its value at home on the default machine).
    Near such poses the five actuators do not hold the platform, and the pose moves far for a
    small geometry error.

    Parameters
    ----------
    machine : Machine
        The machine whose inverse kinematics decide reachability.
    link_length : float
        Constraint-link length ``Lc``, m: the sphere's radius.
    n : int
        Number of poses.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed (``numpy.random.default_rng``).
    max_tilt : float, optional
        Half-angle of the cap, rad.
    max_rotation : float, optional
        Bound of each Euler angle, rad.
    min_manipulability : float, optional
        Smallest accepted inverse condition number of the joint Jacobian.
    min_loop_conditioning : float, optional
        Smallest accepted inverse condition number of the constrained loop.

    Returns
    -------
    P : ndarray, shape (n, 3)
        Platform positions, m.
    R : ndarray, shape (n, 3, 3)
        Platform orientations.

    Raises
    ------
    InputError
        When 50 batches of draws do not give ``n`` accepted poses.
    """
    rng = np.random.default_rng(rng)
    axis = np.asarray(machine.home[0], float)
    axis = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 0 else np.array([0, 0, 1.0])
    helper = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)

    def draw(m, rng):
        cos_t = rng.uniform(np.cos(max_tilt), 1.0, m)          # uniform on the cap
        az = rng.uniform(0, 2 * np.pi, m)
        sin_t = np.sqrt(1 - cos_t**2)
        dirs = (cos_t[:, None] * axis + (sin_t * np.cos(az))[:, None] * e1
                + (sin_t * np.sin(az))[:, None] * e2)
        P = link_length * dirs
        R = matrix_from_euler(rng.uniform(-max_rotation, max_rotation, (m, 3)))
        q, J, _ = machine.ik_jacobians(P, R, want_du=False)
        ok = np.all(np.isfinite(q), -1)
        good = machine.pose_conditioning(P[ok], R[ok], dq_dpose=J[ok]) > min_manipulability
        good &= loop_conditioning(machine, P[ok], J[ok]).min(-1) > min_loop_conditioning
        ok[ok] = good
        return P, R, ok

    where = str(getattr(machine, "source", "") or "").replace("{", "{{").replace("}", "}}")
    return draw_accepted(draw, n, rng, (f"{where}: " if where else "")
                         + "only {have} of {n} sphere poses are reachable: reduce max_tilt or "
                         "max_rotation, or check constraint_link.length and home",
                         machine=machine)


def simulate_constraint_link(true_machine: Machine, n_poses: int = 150, noise_m: float = 0.0,
                             link_length: float | None = None, link_length_error: float = 0.0,
                             rng=None, max_tilt: float = np.deg2rad(35.0),
                             max_rotation: float = np.deg2rad(25.0)) -> ConstraintLinkData:
    """Simulate a constraint-link experiment on ``true_machine``.

    The true link has length ``link_length`` (default: the machine's); the data record the
    assumed length ``link_length + link_length_error``. Every reading gets Gaussian noise of
    standard deviation ``noise_m``; the passive actuator cycles 1..6.

    Parameters
    ----------
    true_machine : HexaSlide
        The true machine (a machine with ``constraint_link_length``).
    n_poses : int, optional
        Number of poses, drawn by :func:`sample_sphere_poses`.
    noise_m : float, optional
        Standard deviation of the reading noise, internal units (m for sliders).
    link_length : float, optional
        True constraint-link length, m; default: ``true_machine.constraint_link_length``.
    link_length_error : float, optional
        Recorded minus true link length, m.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.
    max_tilt : float, optional
        Half-angle of the cap of positions, rad.
    max_rotation : float, optional
        Bound of each Euler angle, rad.

    Returns
    -------
    ConstraintLinkData
        The readings with ``passive`` set and the true poses in ``true_P``, ``true_R``.

    Raises
    ------
    InputError
        When no link length is given or known, or the poses cannot be drawn.
    """
    rng = np.random.default_rng(rng)
    Lc = link_length if link_length is not None else true_machine.constraint_link_length
    if Lc is None:
        raise InputError("the machine has no constraint_link length: give link_length")
    P, R = sample_sphere_poses(true_machine, Lc, n_poses, rng, max_tilt, max_rotation)
    q = true_machine.ik(P, R) + noise_m * rng.standard_normal((n_poses, true_machine.n_joints))
    return ConstraintLinkData(q, Lc + link_length_error, np.arange(n_poses) % 6,
                              source="<simulated>", true_P=P, true_R=R)
