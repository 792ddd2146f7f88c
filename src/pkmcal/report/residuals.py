"""Standardised residuals of a calibration: whitened residuals corrected for leverage.

A least-squares fit pulls the model towards every measurement: the whitened residual
``r_i`` of a correct fit has variance ``1 - h_ii``, not 1, where ``h_ii`` is the diagonal of
the hat matrix ``H = J J^+`` of the linearised problem (local unknowns such as the platform
pose of each measurement included). ``sum(1 - h_ii) = dof``. A histogram of ``r_i`` against
N(0, 1) therefore looks too narrow for a right fit (the Hexa Slide's ML fit has 5 pose unknowns
per 6 readings: ``1 - h_ii`` is about 0.11 on average); ``r_i / sqrt(1 - h_ii)`` is N(0, 1).
"""

from __future__ import annotations

import numpy as np

__all__ = ["leverages", "standardised_residuals"]

#: residuals with ``1 - h_ii`` below this are fitted exactly (no information left)
MIN_FREEDOM = 1e-8


def leverages(problem, result) -> np.ndarray:
    """Diagonal of the hat matrix of the linearised problem at the solution.

    Parameters
    ----------
    problem : BlockProblem
        The calibration problem that produced ``result`` (its ``evaluate`` gives the
        Jacobians at ``result.state``).
    result : CalibrationResult
        The estimate; its ``adjusted`` directions of the free parameters (identified and
        not weak; scaled by ``result.scales``) span the global part of the fit.

    Returns
    -------
    ndarray, shape (K, m)
        ``h_ii`` per whitened residual, in [0, 1]; their sum is the number of unknowns fitted
        (local unknowns + identified directions).
    """
    from ..estimation.variance import _leverages, hat_factors

    return _leverages(*hat_factors(problem, result))


def standardised_residuals(problem, result) -> list:
    """Whitened residuals divided by ``sqrt(1 - h_ii)`` (N(0, 1) for a correct fit).

    Parameters
    ----------
    problem : BlockProblem
        The calibration problem that produced ``result``.
    result : CalibrationResult
        The estimate (whitened residuals in ``result.residuals``).

    Returns
    -------
    list of float or None
        One per residual, flattened like ``result.residuals``; None where the residual is
        fitted exactly (``1 - h_ii`` below :data:`MIN_FREEDOM`) or not finite.
    """
    r = np.asarray(result.residuals, float)
    h = leverages(problem, result).reshape(r.shape)
    free = 1.0 - h
    out = np.where(free > MIN_FREEDOM, r / np.sqrt(np.maximum(free, MIN_FREEDOM)), np.nan)
    return [float(v) if np.isfinite(v) else None for v in out.ravel()]
