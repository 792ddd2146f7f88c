"""The tracker's measurements (:class:`TrackerData`: actuator readings and tracker points),
seed 001's grid of commanded points and the simulation of its experiment."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ...machines.base import Machine
from ...machines.delta import TRACKER_GRID_SPACING
from ..data import InstrumentData
from .noise import TrackerNoise


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


def simulate_tracker(true_machine: Machine, nominal_machine: Machine, targets,
                     base_from_tracker, noise: TrackerNoise | None = TrackerNoise(),  # noqa: B008
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


def as_points(data) -> InstrumentData:
    """Tracker data as the points instrument's data (``target`` kept as the group)."""
    if isinstance(data, InstrumentData):
        return data
    return InstrumentData("points", data.q, data.m, getattr(data, "target", None), data.rows,
                          data.source, data.true_P)


def as_tracker_data(data):
    """Points given as the instrument layer's data (``kind == "points"``), as tracker data;
    other data unchanged.

    Parameters
    ----------
    data : object
        Tracker data, or the instrument layer's points.

    Returns
    -------
    object
        :class:`TrackerData` for points, else ``data``.
    """
    if getattr(data, "kind", None) != "points":
        return data
    return TrackerData(data.q, data.values, data.rows, data.source, data.true_P,
                       target=data.group if data.n_groups > 1 else None)
