"""Gauge freedoms: frame changes that no measurement of a given type can see.

With constraint-link data the base frame can be rotated about O and the platform frame
re-oriented about P without changing any joint reading (SPEC 2.1): 6 of the 54 Hexa Slide
parameter directions are unidentifiable. Each :class:`Gauge` is a 3-parameter group of such
frame changes, defined through the machine's :meth:`~pkmcal.machines.Machine.transform_base` /
:meth:`~pkmcal.machines.Machine.transform_platform`, so every machine gets them for free.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..kinematics import matrix_from_rotvec


@dataclass(frozen=True)
class Gauge:
    """A 3-dimensional group of frame rotations that leaves the data unchanged.

    Attributes
    ----------
    name : str
        Short name.
    description : str
        What it means, in words.
    apply : callable
        ``apply(machine, u_machine, G (3, 3)) -> u_machine'``: the parameters with the frame
        rotated by ``G``.
    """

    name: str
    description: str
    apply: Callable  # (machine, u_machine, G (3,3)) -> u_machine'


BASE_ROTATION_ABOUT_O = Gauge(
    "rotation of the base frame about O",
    "turning every base-side element (rail starts A0 and rail directions) together about the "
    "base point O of the constraint link changes no joint reading: the data fix the base frame's "
    "origin but not its orientation",
    lambda m, u, G: m.transform_base(u, G),
)
PLATFORM_ROTATION_ABOUT_P = Gauge(
    "re-orientation of the platform frame about P",
    "turning every platform joint B together about the platform point P changes no joint "
    "reading: the data fix the platform frame's origin but not its orientation",
    lambda m, u, G: m.transform_platform(u, G),
)
CONSTRAINT_LINK_GAUGES = (BASE_ROTATION_ABOUT_O, PLATFORM_ROTATION_ABOUT_P)


def apply_gauges(machine, u_machine, gauges: Sequence[Gauge], g) -> np.ndarray:
    """Apply the rotations ``g`` (3 per gauge, rotation vectors) to machine parameters.

    Parameters
    ----------
    machine : Machine
        The machine whose frame transforms are used.
    u_machine : array_like, shape (n_machine,)
        Machine parameters, internal units.
    gauges : sequence of Gauge
        The gauges, in the order of ``g``.
    g : array_like, shape (3 * len(gauges),)
        Rotation vectors, rad.

    Returns
    -------
    ndarray, shape (n_machine,)
        The transformed parameters.
    """
    return _apply_rotations(machine, u_machine, gauges, g, None)


def _apply_rotations(machine, u_machine, gauges, g, memo):
    """:func:`apply_gauges`; ``memo`` (a dict, or None) keeps each gauge's rotation matrix by
    the exact bytes of its rotation vector: the finite differences of :func:`align_gauge` and
    :func:`transport_covariance` rotate most gauges by the same vector again and again."""
    u = np.array(u_machine, float)
    for i, gauge in enumerate(gauges):
        v = np.asarray(g[3 * i:3 * i + 3], float)
        if memo is None:
            G = matrix_from_rotvec(v)
        else:
            key = (i, v.tobytes())
            G = memo.get(key)
            if G is None:
                G = memo[key] = matrix_from_rotvec(v)
                G.flags.writeable = False       # shared: a transform must not change it
        u = gauge.apply(machine, u, G)
    return u


def gauge_generators(machine, u_machine, gauges: Sequence[Gauge], eps: float = 1e-6):
    """Tangent directions of the gauges at ``u_machine``.

    Central differences of the exact frame transforms (their only use is to *name* null
    directions, so finite-difference precision is ample).

    Parameters
    ----------
    machine : Machine
        The machine whose frame transforms are used.
    u_machine : array_like, shape (n_machine,)
        Machine parameters, internal units.
    gauges : sequence of Gauge
        The gauges.
    eps : float, optional
        Finite-difference step, rad.

    Returns
    -------
    ndarray, shape (n_machine, 3 * len(gauges))
        Unscaled tangents.
    """
    cols = []
    for j in range(3 * len(gauges)):
        e = np.zeros(3 * len(gauges))
        e[j] = eps
        diff = (apply_gauges(machine, u_machine, gauges, e)
                - apply_gauges(machine, u_machine, gauges, -e))
        cols.append(diff / (2 * eps))
    return np.column_stack(cols) if cols else np.zeros((len(u_machine), 0))


def gauge_groups(machine, u_machine, gauges: Sequence[Gauge], scales, n_total=None):
    """The gauges as :class:`~pkmcal.identifiability.analysis.NullGroup` in scaled coordinates.

    Parameters
    ----------
    machine : Machine
        The machine whose frame transforms are used.
    u_machine : array_like, shape (n_machine,)
        Machine parameters, internal units.
    gauges : sequence of Gauge
        The gauges.
    scales : array_like, shape (n_total,)
        Column scales of the full parameter vector.
    n_total : int, optional
        Length of the full parameter vector, whose first entries are the machine's (the rest
        are padded with zeros); default ``n_machine``.

    Returns
    -------
    list of NullGroup
        One group (3 tangents) per gauge.
    """
    from .analysis import NullGroup

    gen = gauge_generators(machine, u_machine, gauges)
    n_total = len(u_machine) if n_total is None else n_total
    gen = np.vstack([gen, np.zeros((n_total - gen.shape[0], gen.shape[1]))])
    gen = gen / np.asarray(scales, float)[:, None]
    return [NullGroup(g.name, g.description, gen[:, 3 * i:3 * i + 3])
            for i, g in enumerate(gauges)]


def align_gauge(machine, u_est, u_ref, gauges: Sequence[Gauge], scales, max_iter: int = 20):
    """The member of ``u_est``'s gauge orbit closest to ``u_ref`` (scaled least squares).

    Used to compare an estimate with a known truth gauge-free (SPEC 5). Gauss-Newton with a
    finite-difference Jacobian.

    Parameters
    ----------
    machine : Machine
        The machine whose frame transforms are used.
    u_est : array_like, shape (n_machine,)
        Estimated parameters.
    u_ref : array_like, shape (n_machine,)
        Reference parameters (e.g. the truth).
    gauges : sequence of Gauge
        The gauges to move along.
    scales : array_like, shape (n_machine,)
        Column scales weighting the least squares.
    max_iter : int, optional
        Maximum Gauss-Newton iterations.

    Returns
    -------
    u_aligned : ndarray, shape (n_machine,)
        The aligned parameters.
    g : ndarray, shape (3 * len(gauges),)
        The gauge rotation vectors, rad.
    """
    g = np.zeros(3 * len(gauges))
    scales = np.asarray(scales, float)
    for _ in range(max_iter):
        memo = {}       # the rotations at g, shared by the differences along other gauges
        u = _apply_rotations(machine, u_est, gauges, g, memo)
        r = (u - u_ref) / scales
        # Jacobian by central differences of the transforms at g
        J = np.column_stack([
            (_apply_rotations(machine, u_est, gauges, g + e, memo)
             - _apply_rotations(machine, u_est, gauges, g - e, memo)) / (2e-7)
            for e in np.eye(len(g)) * 1e-7]) / scales[:, None]
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        g = g + step
        if np.max(np.abs(step)) < 1e-15:
            break
    return apply_gauges(machine, u_est, gauges, g), g


def transport_covariance(machine, u_machine, gauges: Sequence[Gauge], g, covariance,
                         eps: float = 1e-7):
    """Covariance of ``apply_gauges(u, g)`` given that of ``u``: ``T C T^T``.

    A covariance is expressed in the frames of its estimate; once the estimate is aligned to
    another member of its gauge orbit (:func:`align_gauge`), its covariance must follow, or a
    rotation of ~1 deg mixes weakly and strongly determined directions.
    ``T`` is the Jacobian of the frame transform by central differences.

    Parameters
    ----------
    machine : Machine
        The machine whose frame transforms are used.
    u_machine : array_like, shape (n_machine,)
        The estimate.
    gauges : sequence of Gauge
        The gauges.
    g : array_like, shape (3 * len(gauges),)
        The gauge rotation vectors (from :func:`align_gauge`), rad.
    covariance : array_like, shape (n_machine, n_machine)
        Covariance of ``u_machine``.
    eps : float, optional
        Relative finite-difference step.

    Returns
    -------
    ndarray, shape (n_machine, n_machine)
        The transported covariance.
    """
    u = np.asarray(u_machine, float)
    n = len(u)
    T = np.empty((n, n))
    memo = {}           # g is the same in every difference
    for j in range(n):
        du = np.zeros(n)
        du[j] = eps * max(1.0, abs(u[j]))
        T[:, j] = (_apply_rotations(machine, u + du, gauges, g, memo)
                   - _apply_rotations(machine, u - du, gauges, g, memo)) / (2 * du[j])
    return T @ np.asarray(covariance, float) @ T.T
