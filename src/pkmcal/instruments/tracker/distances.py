"""Seed 001 Fig. 6's distance ratio: the model's distance over the tracker's between pairs of
neighbouring points (frame-free), and how the pairs are found."""

from __future__ import annotations

import numpy as np

from ...machines.base import Machine
from .fit import predict_tracker_points


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


def distance_ratios(machine: Machine, q, m, pairs, targets=None, target=None):
    """Seed 001 Fig. 6: model distance / tracker distance x 100 % for point pairs (frame-free).

    The model's distance is between the target points the readings put in the base frame
    (the platform point on a Delta; ``P + R c`` with the targets' places ``c`` otherwise).

    Parameters
    ----------
    machine : Machine
        The model.
    q : array_like, shape (K, n_joints)
        Actuator readings.
    m : ndarray, shape (K, 3)
        Measured tracker points, m.
    pairs : ndarray of int, shape (M, 2)
        Row index pairs (e.g. :func:`~pkmcal.instruments.tracker.neighbour_pairs`).
    targets : array_like, shape (n_targets, 3), optional
        Places of the targets on the platform when the machine gives none, m.
    target : array_like of int, shape (K,), optional
        0-based target of each row.

    Returns
    -------
    ndarray, shape (M,)
        Ratios in percent (100 = distances agree).
    """
    x = predict_tracker_points(machine, q, (np.eye(3), np.zeros(3)), targets, target)
    d_model = np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=-1)
    d_meas = np.linalg.norm(m[pairs[:, 0]] - m[pairs[:, 1]], axis=-1)
    return 100.0 * d_model / d_meas


def grid_neighbour_pairs(P, abs_tol: float = 1e-4, rel_tol: float = 0.01) -> np.ndarray:
    """Index pairs of neighbouring points of an axis-aligned grid.

    ``j`` is the neighbour of ``i`` along an axis when ``P_j - P_i`` points along the positive
    axis (off-axis part within ``abs_tol + rel_tol * distance``) and no closer point lies that
    way; missing grid points are allowed. Seed 001 Fig. 6 compares such pairs.

    Parameters
    ----------
    P : array_like, shape (K, 3)
        Positions, m.
    abs_tol : float, optional
        Absolute off-axis tolerance, m.
    rel_tol : float, optional
        Off-axis tolerance relative to the distance.

    Returns
    -------
    ndarray of int, shape (n, 2)
        The pairs ``(i, j)``.
    """
    P = np.asarray(P, float)
    K = len(P)
    pairs = []
    for start in range(0, K, 512):                       # K x K temporaries in blocks
        D = P[None, :, :] - P[start:start + 512, None, :]   # (B, K, 3) P_j - P_i
        for axis in range(3):
            along = D[..., axis]
            off = np.linalg.norm(np.delete(D, axis, axis=-1), axis=-1)
            dist = np.where((along > abs_tol) & (off <= abs_tol + rel_tol * along), along,
                            np.inf)
            j = np.argmin(dist, axis=1)
            i = np.flatnonzero(np.isfinite(dist[np.arange(len(D)), j]))
            pairs.append(np.stack([i + start, j[i]], -1))
    return np.concatenate(pairs) if pairs else np.zeros((0, 2), int)


def distance_ratio_pairs(machine, q) -> tuple[np.ndarray, str]:
    """Pairs of measurements for the distance ratio (seed 001 Fig. 6).

    Neighbours of the grid the readings were commanded to (``machine``'s forward kinematics
    of them, i.e. the commanded points when ``machine`` is the controller's model); nearest
    neighbours when the points form no grid.

    Parameters
    ----------
    machine : Machine
        The controller's model.
    q : array_like, shape (K, n)
        Joint readings.

    Returns
    -------
    tuple
        ``(pairs (n, 2) of row indices, how they were found)``.
    """
    P = machine.fk(q).P
    ok = np.all(np.isfinite(P), axis=-1)
    pairs = grid_neighbour_pairs(np.where(ok[:, None], P, 1e9))
    pairs = pairs[ok[pairs].all(axis=1)] if len(pairs) else pairs
    if len(pairs) >= max(1, len(P) // 4):      # a grid: most points have a neighbour
        return pairs, "neighbours on the commanded grid"
    D = np.linalg.norm(P[:, None] - P[None], axis=-1)
    np.fill_diagonal(D, np.inf)
    j = np.argmin(np.where(np.isfinite(D), D, np.inf), axis=1)
    pairs = np.unique(np.sort(np.stack([np.arange(len(P)), j], -1), axis=1), axis=0)
    return pairs[ok[pairs].all(axis=1)], "nearest neighbours (the points form no grid)"


def _ratio_stats(r) -> dict:
    r = np.asarray(r, float)
    r = r[np.isfinite(r)]
    if not r.size:
        return {"mean": None, "std": None, "min": None, "max": None}
    return {"mean": float(r.mean()), "std": float(r.std()), "min": float(r.min()),
            "max": float(r.max())}
