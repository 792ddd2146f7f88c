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

One verdict per question. Whether the residuals agree with the noise model is decided here
and only here: :func:`residual_verdict` gives a :class:`ResidualVerdict` (passed, failed but
small, failed, or not tested and why) and its one sentence; the console, the JSON and HTML
reports, the model-adequacy section and the warnings all state that verdict. Its number is
the *noise ratio* (:func:`noise_ratio`): the residuals' standard deviation over the assumed
noise, ``sqrt(chi2 / dof)``, the degrees of freedom corrected for every unknown the fit
absorbed. Other numbers that compare residuals with a noise level (an RMS of whitened
residuals without that correction, an estimated level over its assumed one) are named
differently wherever they are shown.

The functions return plain results; the command line turns a failed check into a warning with
the usual causes, and the report records it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["FAILED_ALARMING", "FAILED_SMALL", "GROSS_RESIDUAL", "MAX_ANGLE_CHANGE",
           "MAX_LENGTH_CHANGE", "MAX_NOISE_FACTOR", "NOT_TESTED", "PASSED", "VERDICTS",
           "WHITENED_METHODS", "ParameterChanges", "ResidualTest", "ResidualVerdict",
           "chi2_bound", "chi_square_test", "noise_ratio", "parameter_changes",
           "residual_test", "residual_verdict"]

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
#: false-alarm rate of the residual test: a correct calibration with the right noise fails it
#: with this probability
ALPHA = 1e-3

#: the verdicts of :func:`residual_verdict`: the chi-square test passed ...
PASSED = "passed"
#: ... failed, the residuals less than :data:`MAX_NOISE_FACTOR` times the assumed noise (the
#: noise a little larger than assumed) ...
FAILED_SMALL = "failed-small"
#: ... failed, the residuals at least :data:`MAX_NOISE_FACTOR` times the assumed noise (the
#: model does not explain the data at that noise: a warning) ...
FAILED_ALARMING = "failed-alarming"
#: ... or not tested (a method that takes some measurements as exact, no redundancy)
NOT_TESTED = "not-tested"
VERDICTS = (PASSED, FAILED_SMALL, FAILED_ALARMING, NOT_TESTED)
#: the words that open each verdict's sentence
VERDICT_WORDS = {PASSED: "passed", FAILED_SMALL: "failed, by a little",
                 FAILED_ALARMING: "failed", NOT_TESTED: "not tested"}

#: methods whose residuals are whitened by the whole noise model (every measurement noisy):
#: their chi-square is the test. Other methods are tested when they state a test in the
#: whitened model's terms (``result.residual_test``) or fit noise groups.
WHITENED_METHODS = ("ml", "joint")
#: why a method's residuals are not tested against the noise (``result.method`` or
#: the report's method)
UNTESTED_METHODS = {
    "ik": "the ik method takes the five active readings as exact (its residuals, the passive "
          "readings, exceed the noise by design)",
    "fk": "the fk method takes every reading as exact (its residual, the spread of the "
          "computed link length, is not the readings' noise)",
}


def noise_ratio(chi2: float, dof: int) -> float:
    """The noise ratio: how many times the assumed noise the residuals are.

    ``sqrt(chi2 / dof)``, the chi-square of the residuals whitened by the assumed noise over
    its degrees of freedom (residuals minus every unknown the fit absorbed): 1 for a correct
    model with the right noise. This is the one number pkmcal calls the residuals' size
    relative to the noise, in every output.

    Parameters
    ----------
    chi2 : float
        Sum of the squared whitened residuals.
    dof : int
        Degrees of freedom.

    Returns
    -------
    float
        The ratio (NaN when ``dof <= 0`` or ``chi2`` is not finite).
    """
    if not dof or dof <= 0 or not math.isfinite(chi2) or chi2 < 0:
        return math.nan
    return math.sqrt(chi2 / dof)


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
    :data:`MAX_NOISE_FACTOR` times the assumed noise. :func:`residual_verdict` turns a test
    into the verdict every output states.
    """

    chi2: float
    dof: int
    ratio: float
    upper: float
    passed: bool

    @property
    def alarming(self) -> bool:
        """Failed, with residuals at least :data:`MAX_NOISE_FACTOR` times the assumed noise."""
        return not self.passed and self.noise_ratio >= MAX_NOISE_FACTOR

    @property
    def noise_ratio(self) -> float:
        """How many times the assumed noise the residuals are: :func:`noise_ratio`
        (``sqrt(chi2 / dof)``)."""
        return noise_ratio(self.chi2, self.dof)

    @property
    def noise_factor(self) -> float:
        """The same number as :attr:`noise_ratio` (its earlier name)."""
        return self.noise_ratio

    def as_dict(self) -> dict:
        """The test as JSON-ready numbers (for the calibration report).

        Returns
        -------
        dict
            ``chi2``, ``dof``, ``chi2_per_dof``, ``upper_999``, ``noise_ratio``, ``passed``,
            ``alarming``.
        """
        finite = lambda v: float(v) if math.isfinite(v) else None
        return {"chi2": finite(self.chi2), "dof": int(self.dof),
                "chi2_per_dof": finite(self.ratio), "upper_999": finite(self.upper),
                "noise_ratio": finite(self.noise_ratio), "passed": bool(self.passed),
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
        return f"{residual_verdict_of(self).sentence()}. Usual causes: {self.causes(gross)}"

    @staticmethod
    def causes(gross: bool | None = None) -> str:
        """The usual causes of a failed test, in words.

        Parameters
        ----------
        gross : bool or None, optional
            As :meth:`message`: False for a test failed by a little (no wrong geometry among
            the causes); True or None lists them all.

        Returns
        -------
        str
            The causes.
        """
        return ("the noise is larger than assumed (give --noise), outlier rows, or an effect "
                "the model lacks" if gross is False else
                "the noise is larger than assumed (give --noise), outlier rows, swapped or "
                "mis-numbered columns or a wrong unit, or the fit stopped in a wrong geometry "
                "(a machine file far from the machine)")


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


def chi_square_test(chi2: float, dof: int, alpha: float = ALPHA) -> ResidualTest:
    """The chi-square test of residuals whitened by the assumed noise, from their sum of
    squares.

    A method that takes some measurements as exact states its test through this in the
    whitened model's terms (``result.residual_test``), e.g. its residuals whitened
    by their whole covariance.

    Parameters
    ----------
    chi2 : float
        Sum of the squared whitened residuals.
    dof : int
        Degrees of freedom (residuals minus every unknown fitted).
    alpha : float, optional
        Probability of failing a correct calibration with the right noise.

    Returns
    -------
    ResidualTest
        The statistic, its bound and whether it passed (True, NaN ratio: nothing to test,
        ``dof <= 0``).
    """
    dof = int(dof or 0)
    chi2 = float(chi2)
    if dof <= 0 or not math.isfinite(chi2):
        return ResidualTest(chi2, dof, math.nan, math.nan, True)
    ratio = chi2 / dof
    upper = chi2_bound(dof, alpha)
    return ResidualTest(chi2, dof, ratio, upper, bool(ratio <= upper))


def residual_test(result, alpha: float = ALPHA) -> ResidualTest:
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
    if getattr(result, "weighted_residuals", None) is not None \
            and getattr(result, "noise", None) is not None:
        # levels estimated from the data: the test is against the *assumed* noise (what the
        # instruments are believed to do), over the rows used
        r = np.asarray(result.residuals, float)
        used = getattr(result, "used", None)
        used = np.asarray(np.ones(r.shape, bool) if used is None else used, bool)
        chi2 = float(np.sum(r[used & np.isfinite(r)] ** 2))
    return chi_square_test(chi2, dof, alpha)


def _number(value) -> float:
    """A JSON number (None: NaN)."""
    return math.nan if value is None else float(value)


@dataclass(frozen=True)
class ResidualVerdict:
    """Whether a calibration's residuals agree with the noise model: the one verdict every
    output states (:func:`residual_verdict`).

    Attributes
    ----------
    status : str
        :data:`PASSED` (the chi-square test passed), :data:`FAILED_SMALL` (failed, the
        residuals less than :data:`MAX_NOISE_FACTOR` times the assumed noise: the noise a
        little larger than assumed), :data:`FAILED_ALARMING` (failed, at least that: the model
        does not explain the data at the assumed noise) or :data:`NOT_TESTED`.
    test : ResidualTest or None
        The chi-square test (None when not tested).
    why : str
        Why the residuals were not tested, a clause that follows "as" (empty otherwise).
    """

    status: str
    test: ResidualTest | None = None
    why: str = ""

    @property
    def tested(self) -> bool:
        """Whether the residuals were tested against the noise."""
        return self.status != NOT_TESTED

    @property
    def noise_ratio(self) -> float | None:
        """The noise ratio (:func:`noise_ratio`); None when not tested."""
        return self.test.noise_ratio if self.tested and self.test is not None else None

    def sentence(self) -> str:
        """The verdict in one sentence, opened by its words (``passed:``, ``failed, by a
        little:``, ``failed:``, ``not tested:``).

        Returns
        -------
        str
            The sentence (no final period).
        """
        head = VERDICT_WORDS[self.status]
        if not self.tested:
            return f"{head}: the residuals are not compared with the noise, as {self.why}"
        t = self.test
        numbers = (f"the residuals are {t.noise_ratio:.3g} times the assumed noise (chi2/dof "
                   f"= {t.ratio:.3g} over {t.dof} degrees of freedom, at most {t.upper:.3g} "
                   "expected)")
        if self.status == PASSED:
            return f"{head}: {numbers}: they agree with it"
        if self.status == FAILED_SMALL:
            return (f"{head}: {numbers}: the noise is a little larger than assumed (or the "
                    "model lacks a small effect)")
        return (f"{head}: {numbers}: the calibrated model does not explain the data at that "
                "noise")

    def as_dict(self) -> dict:
        """The verdict as the report's ``acceptance.residuals`` section.

        Returns
        -------
        dict
            ``verdict`` (the status), ``sentence``, ``tested``; tested: the test's numbers
            (:meth:`ResidualTest.as_dict`, ``noise_ratio`` among them); not tested: ``why``.
        """
        out = {"verdict": self.status, "sentence": self.sentence(), "tested": self.tested}
        if self.tested:
            out.update(self.test.as_dict())
        else:
            out["why"] = self.why
        return out

    @classmethod
    def from_dict(cls, section) -> ResidualVerdict:
        """The verdict a report states (its ``acceptance.residuals``), also of reports written
        before the verdict was (the test's numbers, or ``tested: false`` and ``why``).

        Parameters
        ----------
        section : mapping or None
            The report's ``acceptance.residuals`` (None: the report has none).

        Returns
        -------
        ResidualVerdict
            The verdict (not tested, saying so, when the report states no test).
        """
        if not section:
            return cls(NOT_TESTED, None, "the report states no residual test")
        if section.get("tested") is False or section.get("verdict") == NOT_TESTED:
            return cls(NOT_TESTED, None, str(section.get("why") or "not stated"))
        dof = int(section.get("dof") or 0)
        chi2 = _number(section.get("chi2"))
        test = ResidualTest(chi2, dof, _number(section.get("chi2_per_dof")),
                            _number(section.get("upper_999")), bool(section.get("passed")))
        return residual_verdict_of(test)


def report_verdict(report) -> ResidualVerdict:
    """The residual verdict a calibration report states (its ``acceptance.residuals``).

    Parameters
    ----------
    report : mapping
        A calibration report (JSON-ready).

    Returns
    -------
    ResidualVerdict
        :meth:`ResidualVerdict.from_dict` of the section (not tested when there is none).
    """
    return ResidualVerdict.from_dict((report.get("acceptance") or {}).get("residuals"))


def residual_verdict_of(test: ResidualTest) -> ResidualVerdict:
    """The verdict of a chi-square test.

    Parameters
    ----------
    test : ResidualTest
        The test.

    Returns
    -------
    ResidualVerdict
        Passed, failed by a little, failed; not tested when there is no redundancy
        (``dof <= 0``) or no finite statistic.
    """
    if test.dof <= 0 or not math.isfinite(test.ratio):
        return ResidualVerdict(NOT_TESTED, None, f"there are {max(test.dof, 0)} degrees of "
                               "freedom (no more residuals than unknowns: the fit can match "
                               "any data)")
    if test.passed:
        return ResidualVerdict(PASSED, test)
    return ResidualVerdict(FAILED_ALARMING if test.alarming else FAILED_SMALL, test)


def residual_verdict(result, method: str | None = None, alpha: float = ALPHA
                     ) -> ResidualVerdict:
    """Whether a calibration's residuals agree with the noise model: the one function that
    decides it.

    Not tested when ``result.untested`` says why (the noise level was set from the
    same residuals: a test that cannot fail). Tested: the test a method states in the
    whitened model's terms
    (``result.residual_test``, e.g. residuals whitened by their whole covariance),
    else the chi-square of the residuals when they are whitened by the whole noise model
    (:data:`WHITENED_METHODS`, or noise groups fitted: ``result.noise``). Not tested:
    a method that takes some measurements as exact and states no test
    (:data:`UNTESTED_METHODS`), or no redundancy.

    Parameters
    ----------
    result : CalibrationResult
        The calibration.
    method : str, optional
        Its method (default ``result.method``).
    alpha : float, optional
        Probability of failing a correct calibration with the right noise.

    Returns
    -------
    ResidualVerdict
        The verdict, its test and its sentence.
    """
    if getattr(result, "untested", None):
        # the noise level was set from these very residuals: a test that cannot fail
        return ResidualVerdict(NOT_TESTED, None, str(result.untested))
    test = getattr(result, "residual_test", None)
    if test is None:
        method = method or getattr(result, "method", None) or ""
        if method in WHITENED_METHODS or getattr(result, "noise", None) is not None:
            test = residual_test(result, alpha)
        else:
            why = UNTESTED_METHODS.get(method, f"the {method or 'fit'} method's residuals are "
                                               "not whitened by the whole noise model")
            return ResidualVerdict(NOT_TESTED, None, why)
    return residual_verdict_of(test)


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
