"""The one rank rule of pkmcal (issue 12): how many parameter directions the data identify.

Every command that counts identifiable directions - ``calibrate`` (the estimator, the
degenerate-pose refusals), ``identifiability``, ``select-poses`` and the report - decides on
the singular values ``s_1 >= s_2 >= ...`` of the same matrix: the identification Jacobian of
the free parameters with the residuals *whitened* by the assumed noise (so the noise model
enters), the columns scaled (lengths by the machine's characteristic length, angles by 1 rad)
and the per-pose unknowns eliminated. Two thresholds, one function (:func:`rank_rule`):

numerically identifiable (``identifiable``)
    ``s_i > rtol * s_1`` with ``rtol =`` :data:`RTOL`. The others form the numerical null
    space: no measurement changes along them (gauges such as a rigid motion of a frame, or
    degenerate poses). This count does not depend on the noise level and is the one every
    command reports as "identifiable".
weakly identifiable (``weak``, a subset of the above)
    Identifiable directions whose standard deviation under the assumed noise, ``1 / s_i`` in
    scaled units, is at least ``max_std =`` :data:`MAX_STD` (0.1 = a tenth of the
    characteristic length, or 5.7 deg). The data determine them in principle, but to no
    useful accuracy: the calibrations leave them at their start values (a fit would move them
    by noise, typically more than any plausible geometric error, and stepping along them
    stalls Levenberg-Marquardt in curved valleys) and report them with their standard
    deviation. ``adjusted = identifiable - weak`` directions are fitted.

Since the weak test divides by the assumed noise, ``identifiability`` agrees with
``calibrate`` on the weak count when it is given the same noise (``--noise``,
``--pose-noise``). It linearises at the start geometry, ``calibrate`` at its estimate: a
direction whose standard deviation lies within a few per cent of the threshold can be counted
differently by the two, the identifiable count cannot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: relative tolerance on the singular values of the scaled, whitened Jacobian (numerical rank)
RTOL = 1e-7

#: largest standard deviation (scaled units) of a direction that is adjusted; see the module
MAX_STD = 0.1


@dataclass(frozen=True)
class Rank:
    """The decision of :func:`rank_rule` on one set of singular values.

    Attributes
    ----------
    identifiable : int
        Numerical rank: directions with ``s_i > rtol * s_1``.
    weak : int
        Of those, the directions with a standard deviation ``1 / s_i >= max_std`` (the last
        ``weak`` of the identifiable singular values); 0 without ``max_std``.
    parameters : int
        Number of free parameters (columns), when known; else the number of singular values.
    max_std : float or None
        The threshold used (scaled units), None for the numerical rank alone.
    rtol : float
        The relative tolerance used.
    """

    identifiable: int
    weak: int
    parameters: int
    max_std: float | None = MAX_STD
    rtol: float = RTOL

    @property
    def adjusted(self) -> int:
        """Directions a calibration fits: ``identifiable - weak``."""
        return self.identifiable - self.weak

    @property
    def unidentifiable(self) -> int:
        """Dimension of the numerical null space: ``parameters - identifiable``."""
        return self.parameters - self.identifiable

    def as_dict(self) -> dict:
        """The counts as a JSON-ready dict.

        Returns
        -------
        dict
            ``identifiable``, ``weakly_identifiable``, ``adjusted``, ``max_std`` and
            ``rtol``.
        """
        return {"identifiable": self.identifiable, "weakly_identifiable": self.weak,
                "adjusted": self.adjusted, "max_std": self.max_std, "rtol": self.rtol}

    def words(self) -> str:
        """The counts in words, e.g. ``"48 of 60 free parameter directions identifiable, of
        which 4 weakly (standard deviation >= 0.1 of the characteristic length (or 5.7 deg)
        under the assumed noise: left at their start values)"``.

        Returns
        -------
        str
            One line.
        """
        text = (f"{self.identifiable} of {self.parameters} free parameter directions "
                "identifiable")
        if self.weak:
            text += (f", of which {self.weak} weakly ({weak_words(self.max_std)}: left at "
                     "their start values)")
        return text


def weak_words(max_std: float | None = MAX_STD) -> str:
    """What "weakly identifiable" means at ``max_std``, in words.

    Parameters
    ----------
    max_std : float or None, optional
        The threshold, scaled units.

    Returns
    -------
    str
        ``"standard deviation >= 0.1 of the characteristic length (or 5.7 deg) under the
        assumed noise"``.
    """
    if max_std is None:
        return "no threshold"
    return (f"standard deviation >= {max_std:g} of the characteristic length (or "
            f"{np.degrees(max_std):.2g} deg) under the assumed noise")


def _check(rtol: float, max_std: float | None) -> None:
    if not (np.isfinite(rtol) and 0 <= rtol < 1):
        raise ValueError(f"rtol must be in [0, 1), got {rtol}")
    if max_std is not None and not (np.isfinite(max_std) and max_std > 0):
        raise ValueError(f"max_std must be positive or None, got {max_std}")


def numerical_rank(singular_values, rtol: float = RTOL) -> int:
    """Number of singular values above ``rtol`` times the largest.

    Parameters
    ----------
    singular_values : array_like
        Singular values of the scaled, whitened Jacobian, largest first.
    rtol : float, optional
        Relative tolerance, in [0, 1).

    Returns
    -------
    int
        The numerical rank; 0 for no or only zero singular values.

    Raises
    ------
    ValueError
        When ``rtol`` is outside [0, 1).
    """
    _check(rtol, None)
    s = np.asarray(singular_values, float).ravel()
    if s.size == 0 or not s[0] > 0:
        return 0
    return int(np.sum(s > rtol * s[0]))


def rank_rule(singular_values, rtol: float = RTOL, max_std: float | None = MAX_STD,
              parameters: int | None = None) -> Rank:
    """Identifiable and weakly identifiable directions (see the module docstring).

    Parameters
    ----------
    singular_values : array_like
        Singular values of the whitened, column-scaled (reduced) Jacobian of the free
        parameters, largest first.
    rtol : float, optional
        Relative tolerance of the numerical rank.
    max_std : float or None, optional
        Standard deviation (scaled units) from which an identifiable direction is weak; None:
        none is.
    parameters : int, optional
        Number of free parameters (default: the number of singular values).

    Returns
    -------
    Rank
        The counts.

    Raises
    ------
    ValueError
        When ``rtol`` is outside [0, 1) or ``max_std`` is not positive.
    """
    _check(rtol, max_std)
    s = np.asarray(singular_values, float).ravel()
    rank = numerical_rank(s, rtol)
    weak = 0 if max_std is None else int(np.sum(s[:rank] <= 1.0 / max_std))
    n = s.size if parameters is None else int(parameters)
    return Rank(rank, weak, n, max_std, rtol)
