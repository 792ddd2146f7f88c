"""Closed-form registration of two point sets (seed 001 eq. 12-14; Horn / Kabsch with SVD)."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..kinematics import kabsch


def register_points(source, target, what: str = "tracker registration", rel_tol=1e-6):
    """``(R, t)`` minimising ``sum |R source_k + t - target_k|^2`` (a proper rotation).

    Needs at least 4 points (seed 001) that are not collinear: with collinear points the
    rotation about their line is undetermined. Raises :class:`InputError` otherwise.
    """
    source = np.asarray(source, float)
    target = np.asarray(target, float)
    if len(source) < 4:
        raise InputError(f"{what}: {len(source)} point(s); at least 4 are needed")
    cs, ct = source.mean(0), target.mean(0)
    sv = np.linalg.svd(source - cs, compute_uv=False)
    if sv[1] <= rel_tol * sv[0]:
        raise InputError(f"{what}: the points are collinear (or coincide): the rotation about "
                         "their line is undetermined; measure points spread in 2-3 directions")
    R = kabsch(source - cs, target - ct)
    return R, ct - R @ cs
