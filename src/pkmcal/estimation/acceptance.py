"""Is a converged calibration believable? Two checks a careful user makes before using it.

An iterative fit that stops is not necessarily right: it may have stopped in a local minimum
(a wrong geometry that explains the data worse than the truth would), or the data may not be
what the user thinks (columns swapped or mis-numbered, a wrong unit, another assembly mode),
in which case the fit bends the geometry far from the machine file to absorb the mistake.

- :func:`residual_test`: the chi-square of the whitened residuals against its degrees of
  freedom. With the assumed noise right and the model right it is about 1; far above its
  upper quantile the fit does not explain the data at the assumed noise.
- :func:`parameter_changes`: how far the calibration moved the geometry, relative to the
  machine's own size; a sizeable fraction is not a calibration but a symptom.

Both return plain results; the command line turns a failed check into a warning with the
usual causes, and the report records it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["GROSS_RESIDUAL", "MAX_ANGLE_CHANGE", "MAX_LENGTH_CHANGE", "MAX_NOISE_FACTOR",
           "ParameterChanges",
           "ResidualTest", "chi2_bound",
           "parameter_changes", "residual_test"]

#: a failed residual test is worth a warning when the residuals are at least this many times
#: the assumed noise: below, the assumed noise is merely a little off (the estimated noise is
#: printed anyway); above, the model does not explain the data
MAX_NOISE_FACTOR = 3.0
#: residuals (RMS, of the lengths measured) beyond this share of the machine's characteristic
#: length are gross: a data mistake (swapped columns, a wrong unit) rather than noise or an
#: effect the model lacks (a printer: 0.3 mm)
GROSS_RESIDUAL = 1e-3
#: a calibration that changes a length by more than this share of the machine's
#: characteristic length is suspicious (real build errors are a few per mille)
MAX_LENGTH_CHANGE = 0.05
#: ... or an angle by more than this, rad (5 deg)
MAX_ANGLE_CHANGE = math.radians(5.0)


@dataclass
class ResidualTest:
    """Chi-square test of a calibration's whitened residuals.

    Attributes
    ----------
    chi2 : float
        Sum of the squared whitened residuals (``2 cost``).
    dof : int
        Degrees of freedom (residuals minus identified parameters and per-pose unknowns).
    ratio : float
        ``chi2 / dof``: the residual variance relative to the assumed noise.
    upper : float
        The ratio's upper ``1 - alpha`` quantile under the assumed noise.
    passed : bool
        Whether ``ratio <= upper`` (True when there is no redundancy to test: ``dof <= 0``).

    Notes
    -----
    :attr:`alarming` is what deserves a warning: failed and the residuals at least
    :data:`MAX_NOISE_FACTOR` times the assumed noise.
    """

    chi2: float
    dof: int
    ratio: float
    upper: float
    passed: bool

    @property
    def alarming(self) -> bool:
        """Failed, with residuals at least :data:`MAX_NOISE_FACTOR` times the assumed noise."""
        return not self.passed and self.noise_factor >= MAX_NOISE_FACTOR

    @property
    def noise_factor(self) -> float:
        """How many times the assumed noise the residuals are (``sqrt(ratio)``)."""
        return math.sqrt(self.ratio) if self.ratio >= 0 else math.nan

    def as_dict(self) -> dict:
        """The test as JSON-ready numbers (for the calibration report).

        Returns
        -------
        dict
            ``chi2``, ``dof``, ``chi2_per_dof``, ``upper_999``, ``noise_factor``, ``passed``.
        """
        finite = lambda v: float(v) if math.isfinite(v) else None
        return {"chi2": finite(self.chi2), "dof": int(self.dof),
                "chi2_per_dof": finite(self.ratio), "upper_999": finite(self.upper),
                "noise_factor": finite(self.noise_factor), "passed": bool(self.passed),
                "alarming": bool(self.alarming)}

    def message(self, gross: bool | None = None) -> str:
        """The failed test in words, with the usual causes (empty when it passed).

        Parameters
        ----------
        gross : bool, optional
            Whether the residuals are large at the machine's scale (:data:`GROSS_RESIDUAL`):
            only then are swapped columns, a wrong unit or a wrong geometry named as causes;
            None: unknown (all causes named).

        Returns
        -------
        str
            One sentence for a warning.
        """
        if self.passed:
            return ""
        causes = ("the noise is larger than assumed (give --noise), outlier rows, or an effect "
                  "the model lacks" if gross is False else
                  "the noise is larger than assumed (give --noise), outlier rows, swapped or "
                  "mis-numbered columns or a wrong unit, or the fit stopped in a wrong geometry "
                  "(a machine file far from the machine)")
        return (f"the residuals are {self.noise_factor:.3g}x the assumed noise (chi2/dof = "
                f"{self.ratio:.3g}, at most {self.upper:.3g} expected): the calibrated model "
                f"does not explain the data at that noise. Usual causes: {causes}")


def chi2_bound(dof: int, alpha: float = 1e-3) -> float:
    """Upper ``1 - alpha`` quantile of chi-square / dof: the largest residual variance
    (relative to the assumed noise) a correct calibration gives with probability ``1 - alpha``.

    Parameters
    ----------
    dof : int
        Degrees of freedom (> 0).
    alpha : float, optional
        Probability of exceeding the bound with the right model and noise.

    Returns
    -------
    float
        The bound (NaN when ``dof <= 0``).
    """
    from .distributions import chi2_ppf

    return chi2_ppf(1.0 - alpha, dof) / dof if dof > 0 else math.nan


def residual_test(result, alpha: float = 1e-3) -> ResidualTest:
    """Chi-square test of a calibration result's whitened residuals.

    Parameters
    ----------
    result : CalibrationResult
        A result of the estimator (``cost`` and ``dof`` are used).
    alpha : float, optional
        Probability of failing a correct calibration with the right noise.

    Returns
    -------
    ResidualTest
        The statistic, its bound and the verdict.
    """
    dof = int(getattr(result, "dof", 0) or 0)
    chi2 = 2.0 * float(result.cost)
    extras = getattr(result, "extras", None) or {}
    if "weighted_residuals" in extras and extras.get("noise") is not None:
        # levels estimated from the data: the test is against the *assumed* noise (what the
        # instruments are believed to do), over the rows used
        r = np.asarray(result.residuals, float)
        used = np.asarray(extras.get("used", np.ones(r.shape, bool)), bool)
        chi2 = float(np.sum(r[used & np.isfinite(r)] ** 2))
    if dof <= 0 or not math.isfinite(chi2):
        return ResidualTest(chi2, dof, math.nan, math.nan, True)
    ratio = chi2 / dof
    upper = chi2_bound(dof, alpha)
    return ResidualTest(chi2, dof, ratio, upper, bool(ratio <= upper))


@dataclass
class ParameterChanges:
    """The largest changes a calibration made, relative to the machine's scale.

    Attributes
    ----------
    length : tuple of (str, float) or None
        The parameter with the largest length change and that change, m.
    angle : tuple of (str, float) or None
        The parameter with the largest angle change and that change, rad.
    scale : float
        The machine's characteristic length, m.
    suspicious : list of str
        The parameters whose change exceeds :data:`MAX_LENGTH_CHANGE` of the scale or
        :data:`MAX_ANGLE_CHANGE`.
    """

    length: tuple[str, float] | None
    angle: tuple[str, float] | None
    scale: float
    suspicious: list[str]

    def message(self) -> str:
        """The suspicious changes in words, with the usual causes (empty when none).

        Returns
        -------
        str
            One sentence for a warning.
        """
        if not self.suspicious:
            return ""
        parts = []
        if self.length is not None and abs(self.length[1]) > MAX_LENGTH_CHANGE * self.scale:
            parts.append(f"{self.length[0]} by {self.length[1] * 1e3:+.4g} mm "
                         f"({abs(self.length[1]) / self.scale:.0%} of the machine's size)")
        if self.angle is not None and abs(self.angle[1]) > MAX_ANGLE_CHANGE:
            parts.append(f"{self.angle[0]} by {math.degrees(self.angle[1]):+.3g} deg")
        more = len(self.suspicious) - len(parts)
        return (f"the calibration moved {' and '.join(parts)}"
                + (f" ({more} more parameter(s) beyond {MAX_LENGTH_CHANGE:.0%} of the size or "
                   f"{math.degrees(MAX_ANGLE_CHANGE):g} deg)" if more > 0 else "")
                + ": that is not a build error but a symptom. Usual causes: swapped or "
                "mis-numbered columns, a wrong unit, another assembly mode, or a machine file "
                "that is not this machine")


def parameter_changes(machine, calibrated) -> ParameterChanges:
    """The largest length and angle changes from ``machine`` to ``calibrated``.

    Parameters
    ----------
    machine : Machine
        The machine file's model.
    calibrated : Machine
        The calibrated model (same parameters).

    Returns
    -------
    ParameterChanges
        The largest changes and the parameters beyond the limits.
    """
    params = machine.parameters
    du = np.asarray(calibrated.u, float) - np.asarray(machine.u, float)
    kinds = np.asarray(params.kinds, dtype=object)
    names = list(params.names)
    scale = float(machine.characteristic_length())
    out_len = out_ang = None
    suspicious = []
    for kind, limit in (("length", MAX_LENGTH_CHANGE * scale), ("angle", MAX_ANGLE_CHANGE)):
        idx = np.flatnonzero(kinds == kind)
        if not idx.size:
            continue
        k = int(idx[np.argmax(np.abs(du[idx]))])
        if kind == "length":
            out_len = (names[k], float(du[k]))
        else:
            out_ang = (names[k], float(du[k]))
        suspicious += [names[i] for i in idx if abs(du[i]) > limit]
    return ParameterChanges(out_len, out_ang, scale, suspicious)
