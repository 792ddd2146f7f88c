"""``--parameters auto``: the model that predicts best (issue 35).

A machine offers candidate models (:meth:`~pkmcal.machines.Machine.model_candidates`: a
printer's firmware set first, then larger ones, with the machine's build tolerances as a prior
where it has them). Each is fitted; the one with the smallest **leave-one-out prediction
error** of the measurements (PRESS) is kept.

Why leave-one-out over rows (PRESS). What the user wants from a model is the error at a point
it was not fitted to (the next probe touch, the next session's bed). PRESS is exactly that
error for each row left out of a linearised fit, ``e_i / (1 - h_ii)`` with ``h_ii`` the row's
leverage under the fitted model (its posterior's, with a prior), computed from the one fit
without refitting (Allen 1974). It is asymptotically equivalent to Akaike's criterion
(Stone 1977) but needs no count of parameters, which a prior makes fractional: a direction the
prior holds costs little leverage, one the data must fix costs a lot. The residuals are those
whitened by the *assumed* noise (the same for every candidate), so a model that explains the
data worse cannot hide behind a larger estimated noise.

A candidate beyond the first is judged only where the data leave at least
:data:`MIN_REDUNDANCY` equations beyond what it fits (else its leave-one-out error is mostly
its own leverage: Klipper's 7 points stay with Klipper's set, 1.00x Klipper). A larger model is
kept only when it lowers PRESS by at least :data:`MIN_GAIN` (a simpler model that predicts as
well is preferred).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

#: equations beyond the fitted directions a candidate after the first must leave
MIN_REDUNDANCY = 10
#: relative decrease of PRESS a larger model must bring to be kept
MIN_GAIN = 0.02


@dataclass
class CandidateScore:
    """One candidate's fit and score.

    Attributes
    ----------
    parameters, bed_tilt, words : str
        The candidate (:class:`~pkmcal.machines.base.ModelCandidate`).
    press : float or None
        Mean squared leave-one-out residual, whitened by the assumed noise (None: not judged;
        the report gives its root, the leave-one-out RMS relative to the noise).
    redundancy : int or None
        Equations beyond the fitted directions.
    note : str
        Why it was not judged, or empty.
    """

    parameters: str
    bed_tilt: str | None
    words: str
    press: float | None = None
    redundancy: int | None = None
    note: str = ""

    def as_dict(self) -> dict:
        return {"parameters": self.parameters, "bed_tilt": self.bed_tilt, "model": self.words,
                "loo_rms_over_noise": None if self.press is None else float(np.sqrt(self.press)),
                "redundancy": self.redundancy, **({"note": self.note} if self.note else {})}


def loo_press(result) -> float:
    """Mean squared leave-one-out residual of a fit (whitened by the problem's assumed noise).

    Parameters
    ----------
    result : CalibrationResult
        A fit with ``extras["problem"]`` (the problem it solved, unweighted).

    Returns
    -------
    float
        ``mean((r_i / (1 - h_ii))^2)`` over the finite residual components; inf when a row
        has leverage 1 (left out, nothing predicts it).
    """
    from ..estimation.variance import _leverages, hat_factors

    problem = result.extras["problem"]
    r = np.asarray(problem.evaluate(result.state, jacobian=False)[0], float)
    L, G = hat_factors(problem, result)
    h = _leverages(L, G)
    ok = np.isfinite(r)
    if np.any(h[ok] >= 1.0 - 1e-9):
        return float("inf")
    return float(np.mean((r[ok] / (1.0 - h[ok])) ** 2))


def choose_model(fit, machine, candidates) -> tuple:
    """Fit every candidate and keep the one that predicts best (see the module docstring).

    Parameters
    ----------
    fit : callable
        ``fit(parameters, bed_tilt) -> Calibration``.
    machine : Machine
        The machine (for the words).
    candidates : list of ModelCandidate
        The firmware's own first.

    Returns
    -------
    calibration : Calibration
        The chosen candidate's calibration.
    scores : list of CandidateScore
        Every candidate, judged or not.
    chosen : int
        Index of the chosen candidate.

    Raises
    ------
    InputError
        When the first candidate cannot be fitted (its message).
    """
    scores, fits = [], []
    for i, c in enumerate(candidates):
        score = CandidateScore(c.parameters, c.bed_tilt, c.words)
        scores.append(score)
        try:
            calibration = fit(c.parameters, c.bed_tilt)
        except InputError as exc:
            if i == 0:
                raise
            score.note = f"not fitted: {exc}"
            fits.append(None)
            continue
        result = calibration.result
        score.redundancy = int(result.dof)
        if i > 0 and result.dof < MIN_REDUNDANCY:
            score.note = (f"not judged: {result.dof} equation(s) beyond what it fits, fewer "
                          f"than {MIN_REDUNDANCY}")
            fits.append(None)
            continue
        try:
            score.press = loo_press(result)
        except (KeyError, AttributeError, ValueError, np.linalg.LinAlgError) as exc:
            score.note = f"not judged: {exc}"
            fits.append(None if i else calibration)
            continue
        fits.append(calibration)
    chosen = 0
    for i, score in enumerate(scores):
        if i == 0 or score.press is None or fits[i] is None:
            continue
        best = scores[chosen].press
        if best is None or not np.isfinite(best) or score.press < (1.0 - MIN_GAIN) * best:
            chosen = i
    return fits[chosen], scores, chosen


def choice_words(scores, chosen: int) -> str:
    """The choice in one line for the report and the console."""
    c = scores[chosen]
    judged = [s for s in scores if s.press is not None and np.isfinite(s.press)]
    table = "; ".join(f"{s.parameters}/{s.bed_tilt or 'default'} "
                      f"{np.sqrt(s.press):.3g}" for s in judged)
    why = ("the smallest leave-one-out prediction error of the measurements (PRESS, "
           f"relative to the noise: {table})" if len(judged) > 1 else
           "the only candidate the data can judge (the others need "
           f"{MIN_REDUNDANCY} equations beyond what they fit)")
    return f"model chosen (--parameters auto): {c.words}; {why}"


def calibrate_auto(calibrate, machine, given, candidates, bed_tilt, options: dict):
    """``--parameters auto``: every candidate fitted with ``calibrate``, the one that predicts
    best kept (:func:`choose_model`); its report's ``model_choice`` and ``parameter_set``
    say which and why.

    Parameters
    ----------
    calibrate : callable
        :func:`pkmcal.calibration.calibrate` (``parameters`` and ``bed_tilt`` given per
        candidate).
    machine : Machine
        The machine.
    given : object
        The data as the user gave them.
    candidates : list of ModelCandidate
        The machine's candidates.
    bed_tilt : str or None
        ``--bed-tilt`` when the user gave it (it overrides the candidates').
    options : dict
        The other keywords of the call.

    Returns
    -------
    Calibration
        The chosen candidate's calibration.
    """
    def fit(name, bed):
        return calibrate(machine, given, parameters=name,
                         bed_tilt=bed_tilt if bed_tilt is not None else bed, **options)

    calibration, scores, chosen = choose_model(fit, machine, candidates)
    words = choice_words(scores, chosen)
    calibration.report["model_choice"] = {
        "chosen": chosen, "criterion": "leave-one-out prediction error of the measurements "
        f"(PRESS), whitened by the assumed noise; a larger model kept only when it lowers it "
        f"by {MIN_GAIN:.0%}", "words": words,
        "candidates": [sc.as_dict() for sc in scores]}
    calibration.warnings.append(words)
    chosen_set = calibration.report.get("parameter_set")
    if chosen_set is not None:
        # the choice's words are its warning (said once): the set names where they are
        chosen_set["note"] = ("fitted in its own set, the firmware's; " if chosen == 0
                              else "") + "chosen by --parameters auto (the report's model_choice)"
    return calibration
