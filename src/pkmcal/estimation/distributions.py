"""The few probability distribution functions pkmcal's tests of fit need, from
:mod:`scipy.special`.

:mod:`scipy.stats` takes about a second to import (it pulls in scipy.spatial, scipy.optimize,
scipy.sparse and every distribution); a calibration needs four functions of three
distributions. Each function here is the formula :mod:`scipy.stats` itself evaluates for the
distribution (``chi2._ppf = 2 gammaincinv(k/2, q)``, ``chi2._sf = chdtrc``, ``f._sf = fdtrc``,
``t._ppf = stdtrit``), so the numbers are the same; ``tests/test_distributions.py`` compares
them with :mod:`scipy.stats`.
"""

from __future__ import annotations

import numpy as np
from scipy import special


def chi2_ppf(q, dof):
    """Quantile of the chi-square distribution: the ``x`` with ``P(X <= x) = q``.

    Parameters
    ----------
    q : float or array_like
        Probability in [0, 1].
    dof : float or array_like
        Degrees of freedom (> 0).

    Returns
    -------
    float or ndarray
        The quantile (a float for scalar arguments).
    """
    out = 2.0 * special.gammaincinv(np.asarray(dof, float) / 2.0, np.asarray(q, float))
    return float(out) if np.ndim(out) == 0 else out


def chi2_sf(x, dof):
    """Survival function of the chi-square distribution, ``P(X > x)`` (1 for ``x <= 0``)."""
    x = np.asarray(x, float)
    out = np.where(x > 0, special.chdtrc(np.asarray(dof, float), np.maximum(x, 0.0)), 1.0)
    return float(out) if np.ndim(out) == 0 else out


def f_sf(x, dfn, dfd):
    """Survival function of Fisher's F distribution, ``P(F > x)`` (1 for ``x <= 0``)."""
    x = np.asarray(x, float)
    out = np.where(x > 0, special.fdtrc(dfn, dfd, np.maximum(x, 0.0)), 1.0)
    return float(out) if np.ndim(out) == 0 else out


def t_ppf(q, dof):
    """Quantile of Student's t distribution with ``dof`` degrees of freedom."""
    out = special.stdtrit(np.asarray(dof, float), np.asarray(q, float))
    return float(out) if np.ndim(out) == 0 else out
