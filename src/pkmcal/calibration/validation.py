"""Held-out validation: keep some measurements out of a calibration and test the result on them.

A calibration's own residuals flatter it (the parameters were chosen to make them small); the
residuals of measurements it never saw do not. ``pkmcal calibrate --holdout F`` uses
:func:`holdout_split` to set a random share of the rows aside, calibrates on the rest and
compares the held-out residuals of the machine file's geometry and of the calibrated one.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError


def holdout_split(n: int, holdout: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Split ``n`` measurements into a calibration set and a held-out set.

    Parameters
    ----------
    n : int
        Number of measurements.
    holdout : float
        Share of the measurements held out, ``0 < holdout < 1``, or a whole number ``>= 1`` of
        measurements.
    seed : int
        Seed of the random choice (the same seed gives the same split).

    Returns
    -------
    train, held : ndarray of int
        Sorted 0-based indices of the measurements to calibrate on and of those held out.

    Raises
    ------
    ValueError
        When ``holdout`` is not a share or a count, or leaves either set empty.
    """
    if not np.isfinite(holdout) or holdout <= 0:
        raise ValueError(f"the held-out share must be > 0, got {holdout:g}")
    if holdout < 1:
        k = int(round(holdout * n))
    elif float(holdout).is_integer():
        k = int(holdout)
    else:
        raise ValueError(f"give a share below 1 (e.g. 0.2) or a whole number of rows, got "
                         f"{holdout:g}")
    if not 1 <= k < n:
        raise ValueError(f"holding out {k} of {n} measurements leaves "
                         + ("none to test on" if k < 1 else "none to calibrate on"))
    rng = np.random.default_rng(seed)
    held = np.sort(rng.choice(n, size=k, replace=False))
    train = np.setdiff1d(np.arange(n), held)
    return train, held


def constraint_link_reading_rms(machine, data, sigma_m: float, max_iter: int = 20) -> float:
    """RMS joint-reading residual (m) of ``machine``'s geometry on constraint-link ``data``.

    The poses on the link's sphere are fitted by maximum likelihood with the geometry and the
    link length (``data.link_length``) held: the residual a calibration would start from, or,
    for held-out data, the residual the calibrated geometry leaves on readings it never saw.

    Parameters
    ----------
    machine : HexaSlide
        The geometry to test (its current parameters are held).
    data : ConstraintLinkData
        Readings taken with the link mounted.
    sigma_m : float
        Encoder noise (m); it only scales the iterations, not the result.
    max_iter : int
        Gauss-Newton iterations for the poses.

    Returns
    -------
    float
        RMS over all readings (m); NaN when the poses cannot be fitted.
    """
    from ..estimation.estimator import levenberg_marquardt
    from ..instruments.constraint_link import ConstraintLinkML

    try:
        problem = ConstraintLinkML(machine.with_parameters(machine.u), data, sigma_m)
        problem.parameters = problem.parameters.with_fixed(list(problem.parameters.names))
        res = levenberg_marquardt(problem, max_iter=max_iter)
    except (InputError, ValueError, np.linalg.LinAlgError):
        return float("nan")
    r = np.asarray(res.residuals, float) * sigma_m
    return float(np.sqrt(np.mean(r**2))) if r.size and np.all(np.isfinite(r)) else float("nan")
