"""Closed-form registration of two point sets (seed 001 eq. 12-14; Horn / Kabsch with SVD)."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..kinematics import kabsch


def register_points(source, target, what: str = "tracker registration", rel_tol=1e-6):
    """``(R, t)`` minimising ``sum |R source_k + t - target_k|^2`` (a proper rotation).

    Needs at least 4 points (seed 001) that are not collinear: with collinear points the
    rotation about their line is undetermined. Both sets are checked (second singular value of
    the centred points at most ``rel_tol`` times the first): measured points are never exactly
    collinear, but points commanded on a line are collinear in the model, and the rotation
    about that line is undetermined just the same.

    Parameters
    ----------
    source : array_like, shape (K, 3)
        Points to transform.
    target : array_like, shape (K, 3)
        Corresponding points to match.
    what : str, optional
        What is being registered, the start of error messages.
    rel_tol : float, optional
        Collinearity threshold on the ratio of singular values.

    Returns
    -------
    R : ndarray, shape (3, 3)
        Rotation.
    t : ndarray, shape (3,)
        Translation, in the units of the points.

    Raises
    ------
    InputError
        When the shapes differ or are not (K, 3), fewer than 4 points are given, or either set
        is collinear.
    """
    source = np.asarray(source, float)
    target = np.asarray(target, float)
    if source.shape != target.shape or source.ndim != 2 or source.shape[-1] != 3:
        raise InputError(f"{what}: point sets of shapes {source.shape} and {target.shape}; "
                         "expected two (K, 3) arrays of corresponding points")
    if len(source) < 4:
        raise InputError(f"{what}: {len(source)} point(s); at least 4 are needed")
    cs, ct = source.mean(0), target.mean(0)
    for points, centre in ((source, cs), (target, ct)):
        sv = np.linalg.svd(points - centre, compute_uv=False)
        if sv[1] <= rel_tol * sv[0]:
            raise InputError(f"{what}: the points are collinear (or coincide): the rotation "
                             "about their line is undetermined; measure points spread in 2-3 "
                             "directions")
    R = kabsch(source - cs, target - ct)
    return R, ct - R @ cs
