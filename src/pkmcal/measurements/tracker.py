"""Laser-tracker measurements of a reflector (SMR) on the platform (seed 001 section 3).

The tracker measures the SMR centre, ``h_M`` below the platform point, in its own frame:
``m = R^T (p + (0, 0, -h_M) - t)`` with ``(R, t)`` = base_from_tracker (a base vector
``x_base = R m + t``). One measurement = the actuator readings and the measured point.

Noise model (documented, Leica-type): the maximum permissible error (MPE) is
``+/-(15 um + 6 um/m * range)`` transverse to the beam and ``+/-10 um`` along it; the typical
error is about half the MPE, so the standard deviations are half these values. The noise is
anisotropic: each point has its own 3x3 covariance in the tracker frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..kinematics import matrix_from_rotvec
from ..machines.base import Machine


@dataclass(frozen=True)
class TrackerNoise:
    """Standard deviations of a laser tracker (half the MPE by default), SI units.

    Attributes
    ----------
    distance : float, optional
        Along the beam, m.
    transverse : float, optional
        Across the beam, constant part, m.
    transverse_per_m : float, optional
        Across the beam, per metre of range (m/m).
    """

    distance: float = 5e-6            # along the beam
    transverse: float = 7.5e-6        # across the beam, constant part
    transverse_per_m: float = 3e-6    # across the beam, per metre of range

    def _beam(self, m):
        """Beam directions ``r`` (K, 3; +z at the tracker's origin, where there is none), the
        projector on them ``rr`` (K, 3, 3) and the transverse std ``st`` (K,)."""
        m = np.asarray(m, float)
        rng = np.linalg.norm(m, axis=-1)
        r = np.where(rng[..., None] > 0, m / np.where(rng > 0, rng, 1.0)[..., None],
                     np.array([0.0, 0.0, 1.0]))
        return (r, r[..., :, None] * r[..., None, :],
                self.transverse + self.transverse_per_m * rng)

    def covariance(self, m):
        """Per-point covariance in the tracker frame.

        Parameters
        ----------
        m : array_like, shape (K, 3)
            Tracker points, m, tracker frame.

        Returns
        -------
        ndarray, shape (K, 3, 3)
            Covariance of each point, m^2.
        """
        _, rr, st = self._beam(m)
        return self.distance**2 * rr + (st**2)[..., None, None] * (np.eye(3) - rr)

    def whitening(self, m):
        """Whitening matrices ``W`` with ``W^T W = Cov^-1``, rows along the beam first.

        Row 0 is along the beam (``r / s_d``), rows 1-2 across it (two unit vectors normal
        to the beam, ``/ s_t``, range-dependent): each whitened residual component belongs to
        one noise group (:meth:`groups`).

        Parameters
        ----------
        m : array_like, shape (K, 3)
            Tracker points, m, tracker frame.

        Returns
        -------
        ndarray, shape (K, 3, 3)
            Whitening matrix of each point, 1/m.
        """
        r, _, st = self._beam(m)
        # a vector normal to the beam: the axis least aligned with it, projected
        axis = np.eye(3)[np.argmin(np.abs(r), axis=-1)]
        t1 = axis - np.sum(axis * r, -1)[..., None] * r
        t1 /= np.linalg.norm(t1, axis=-1)[..., None]
        t2 = np.cross(r, t1)
        return np.stack([r / self.distance, t1 / st[..., None], t2 / st[..., None]], -2)

    def groups(self, m):
        """Noise groups of the whitened components (:meth:`whitening`'s rows).

        Parameters
        ----------
        m : array_like, shape (K, 3)
            Tracker points, m, tracker frame.

        Returns
        -------
        labels : ndarray of int, shape (K, 3)
            0 along the beam, 1 across it.
        keys, names : list of str
            The groups.
        assumed : ndarray, shape (2,)
            Along the beam, and the RMS across it over the points, m.
        kinds : list of str
            Both ``"length"``.
        """
        _, _, st = self._beam(m)
        K = len(np.asarray(m))
        across = float(np.sqrt(np.mean(st**2))) if K else self.transverse
        return (np.tile([0, 1, 1], (K, 1)), ["along", "across"],
                ["tracker along the beam", "tracker across the beam"],
                np.array([self.distance, across]), ["length", "length"])

    def sample(self, m, rng):
        """Noise vectors for tracker points, drawn from :meth:`covariance`.

        Parameters
        ----------
        m : array_like, shape (K, 3)
            Tracker points, m, tracker frame.
        rng : numpy.random.Generator
            Random generator.

        Returns
        -------
        ndarray, shape (K, 3)
            Noise to add to the points, m.
        """
        m = np.asarray(m, float)
        L = np.linalg.cholesky(self.covariance(m))
        return np.einsum("kij,kj->ki", L, rng.standard_normal(m.shape))


@dataclass
class TrackerData:
    """Actuator readings and tracker points.

    Attributes
    ----------
    q : ndarray, shape (K, n_joints)
        Joint readings, rad.
    m : ndarray, shape (K, 3)
        SMR positions in the tracker frame, m.
    rows : ndarray of int, shape (K,), optional
        File row numbers for messages; default 1..K.
    source : str, optional
        File name, for messages.
    true_P : ndarray, shape (K, 3), optional
        Simulated platform positions (base frame), m; None for real data.
    outliers : ndarray of bool, shape (K,), optional
        Rows a simulation corrupted on purpose; None for real data.
    target : ndarray of int, shape (K,), optional
        0-based target (reflector nest) of each row when there are several; None: one.
    """

    q: np.ndarray
    m: np.ndarray
    rows: np.ndarray | None = None
    source: str = "<data>"
    true_P: np.ndarray | None = None
    outliers: np.ndarray | None = None
    target: np.ndarray | None = None

    def __post_init__(self):
        self.q = np.atleast_2d(np.asarray(self.q, float))
        self.m = np.atleast_2d(np.asarray(self.m, float))
        if self.target is not None:
            self.target = np.asarray(self.target, int)
        if self.rows is None:
            self.rows = np.arange(1, len(self.q) + 1)

    def __len__(self) -> int:
        return len(self.q)

    def subset(self, mask) -> TrackerData:
        """The measurements selected by a boolean mask or index array.

        Parameters
        ----------
        mask : array_like of bool or int
            Boolean mask (K,) or indices of the rows to keep.

        Returns
        -------
        TrackerData
            The selected rows, same source.
        """
        def pick(a):
            return None if a is None else a[mask]

        return TrackerData(self.q[mask], self.m[mask], self.rows[mask], self.source,
                           pick(self.true_P), pick(self.outliers), pick(self.target))


#: seed 001's measurement grid: dx = dy = 150 mm, dz = 40 mm
TRACKER_GRID_SPACING = (0.15, 0.15, 0.04)
#: where simulations put the tracker in the base frame (m): 2.5 m from the robot's axis, on
#: the floor 1.4 m below the base plane
TRACKER_POSITION = (2.0, -1.5, -1.4)
#: its tilt about its own y axis (rad)
TRACKER_TILT = np.deg2rad(1.0)


def default_tracker_pose() -> tuple[np.ndarray, np.ndarray]:
    """The true ``base_from_tracker = (R, t)`` of simulations without a tracker in the machine file.

    The tracker stands at :data:`TRACKER_POSITION` (2.5 m from the robot's axis), its x axis
    turned about Z toward the robot's axis (143.13 deg) and tilted by :data:`TRACKER_TILT`
    (1 deg) about its y axis.

    Returns
    -------
    R : ndarray, shape (3, 3)
        Orientation of the tracker frame in the base frame.
    t : ndarray, shape (3,)
        Tracker origin in the base frame, m.
    """
    t = np.array(TRACKER_POSITION, float)
    yaw = np.arctan2(-t[1], -t[0])
    R = matrix_from_rotvec([0.0, 0.0, yaw]) @ matrix_from_rotvec([0.0, TRACKER_TILT, 0.0])
    return R, t


def grid_points(center, spacing=TRACKER_GRID_SPACING, shape=(3, 3, 3)):
    """Points of a regular grid (seed 001: 3x3x3, dx = dy = 150 mm, dz = 40 mm).

    Parameters
    ----------
    center : array_like, shape (3,)
        Centre of the grid, m.
    spacing : tuple of float, optional
        Distance between neighbouring points along x, y, z, m.
    shape : tuple of int, optional
        Number of points along x, y, z.

    Returns
    -------
    ndarray, shape (N, 3)
        The points, m, x slowest and z fastest (``N = prod(shape)``).
    """
    axes = [(np.arange(n) - (n - 1) / 2) * d for n, d in zip(shape, spacing, strict=True)]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    return np.asarray(center, float) + np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])


def neighbour_pairs(shape=(3, 3, 3)):
    """Index pairs of grid points that are neighbours along one axis (for distance ratios).

    Parameters
    ----------
    shape : tuple of int, optional
        Grid shape, as in :func:`grid_points`.

    Returns
    -------
    ndarray of int, shape (M, 2)
        Indices into the rows of :func:`grid_points`, pairs along x, then y, then z.
    """
    idx = np.arange(int(np.prod(shape))).reshape(shape)
    pairs = []
    for axis in range(3):
        a = np.moveaxis(idx, axis, 0)
        pairs.append(np.stack([a[:-1].ravel(), a[1:].ravel()], -1))
    return np.concatenate(pairs)


def simulate_tracker(true_machine: Machine, nominal_machine: Machine, targets,
                     base_from_tracker, noise: TrackerNoise | None = TrackerNoise(),
                     outliers: int = 0, outlier_size: float = 1e-3, rng=None) -> TrackerData:
    """The experiment of seed 001: command points with the nominal model, measure the true machine.

    The *nominal* model commands ``targets``, the *true* machine goes elsewhere, and the
    tracker measures the SMR there (``smr_offset`` below the platform point), with noise.
    ``outliers`` random rows get an extra error of ``outlier_size`` in a random direction (beam
    breaks, a mis-seated SMR); they are flagged in ``outliers``.

    Parameters
    ----------
    true_machine : Delta
        The true machine (needs ``smr_offset``).
    nominal_machine : Delta
        The model that computes the commands.
    targets : array_like, shape (N, 3)
        Commanded platform positions, m, base frame.
    base_from_tracker : tuple of array_like
        ``(R (3, 3), t (3,))``: a tracker point ``m`` is ``R m + t`` in the base frame.
    noise : TrackerNoise or None, optional
        Tracker noise; None for exact points.
    outliers : int, optional
        Number of rows to corrupt.
    outlier_size : float, optional
        Size of the outlier error, m.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.

    Returns
    -------
    TrackerData
        Commanded joints, measured points, the true positions and the outlier flags.

    Raises
    ------
    InputError
        When a target is outside the nominal workspace or the true machine cannot reach a
        commanded point.
    """
    rng = np.random.default_rng(rng)
    q = nominal_machine.ik(np.asarray(targets, float))
    if not np.all(np.isfinite(q)):
        bad = np.flatnonzero(~np.all(np.isfinite(q), -1)) + 1
        raise InputError(f"targets {bad.tolist()} are outside the nominal workspace")
    fk = true_machine.fk(q)
    if not fk.converged.all():
        raise InputError("the true machine cannot reach some commanded points")
    R, t = base_from_tracker
    smr = fk.P - np.array([0.0, 0.0, true_machine.smr_offset])
    m = (smr - t) @ np.asarray(R)            # R^T (x - t) for each row
    if noise is not None:
        m = m + noise.sample(m, rng)
    flagged = np.zeros(len(m), bool)
    if outliers:
        flagged[rng.choice(len(m), size=outliers, replace=False)] = True
        d = rng.standard_normal((outliers, 3))
        m[flagged] += outlier_size * d / np.linalg.norm(d, axis=-1, keepdims=True)
    return TrackerData(q, m, source="<simulated>", true_P=fk.P, outliers=flagged)
