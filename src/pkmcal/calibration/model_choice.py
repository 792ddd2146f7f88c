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

Why leave-one-SESSION-out where the data come in sessions (a printer's saved configs, at least
:data:`MIN_SESSIONS`). Rows of one session share what a session changes (where its endstops
triggered, the probe's offset, the bed's state): leaving out a row keeps its session's own
unknowns fitted on its other rows, so PRESS judges how well a model reproduces a session it has
already seen, and a large model that bends to each session's quirks scores well there and
predicts the next session worse (Aieie78's V400, three points-only sessions: the per-tower
model won PRESS and predicted the two later sessions at 0.83x Klipper's values; Klipper's set,
chosen as below, at 0.15x). The question the user asks is the next session's: each session is
left out in turn, the candidate fitted on the others (the newest remaining session the
reference) and the left-out session's data scored as ``pkmcal check`` scores a session
(:func:`~pkmcal.calibration.check.check`: the machine held, one free offset per data set),
each file's residuals relative to its noise level (the smallest any candidate's fit of all
data estimated for it, so that a file the data show to be coarse, such as DELTA_ANALYZE
distances measured on a print, does not decide alone). A session without which a candidate
is another model (Klipper's set without the distances that fix its arms is its basic set) is
not left out, for any candidate: every candidate is judged on the same sessions.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import ConvergenceError, InputError
from .firmware_data import expand_firmware_data
from .run import register_model_chooser

#: equations beyond the fitted directions a candidate after the first must leave
MIN_REDUNDANCY = 10
#: relative decrease of PRESS a larger model must bring to be kept
MIN_GAIN = 0.02
#: sessions (a reference and others) from which a model is judged by leaving each out
MIN_SESSIONS = 3


@dataclass
class CandidateScore:
    """One candidate's fit and score.

    Attributes
    ----------
    parameters, bed_tilt, words : str
        The candidate (:class:`~pkmcal.machines.base.ModelCandidate`).
    press : float or None
        Mean squared leave-one-out residual, whitened by the assumed noise, or with
        ``by_sessions`` the mean squared error of each session predicted by the others' fit
        relative to each file's noise level (None: not judged; the report gives its root,
        the leave-one-out RMS relative to the noise).
    redundancy : int or None
        Equations beyond the fitted directions.
    note : str
        Why it was not judged, or empty.
    by_sessions : bool
        Judged by leave-one-session-out (:func:`loso_score`).
    """

    parameters: str
    bed_tilt: str | None
    words: str
    press: float | None = None
    redundancy: int | None = None
    note: str = ""
    by_sessions: bool = False

    def as_dict(self) -> dict:
        return {"parameters": self.parameters, "bed_tilt": self.bed_tilt, "model": self.words,
                "loo_rms_over_noise": None if self.press is None else float(np.sqrt(self.press)),
                "redundancy": self.redundancy, **({"note": self.note} if self.note else {})}


def loo_press(result) -> float:
    """Mean squared leave-one-out residual of a fit (whitened by the problem's assumed noise).

    Parameters
    ----------
    result : CalibrationResult
        A fit with ``problem`` (the problem it solved, unweighted).

    Returns
    -------
    float
        ``mean((r_i / (1 - h_ii))^2)`` over the finite residual components; inf when a row
        has leverage 1 (left out, nothing predicts it).
    """
    from ..estimation.variance import _leverages, hat_factors

    problem = result.problem
    r = np.asarray(problem.evaluate(result.state, jacobian=False)[0], float)
    L, G = hat_factors(problem, result)
    h = _leverages(L, G)
    ok = np.isfinite(r)
    if np.any(h[ok] >= 1.0 - 1e-9):
        return float("inf")
    return float(np.mean((r[ok] / (1.0 - h[ok])) ** 2))


def session_data(machine, given) -> tuple:
    """The data as objects and each one's session, when they come in at least
    :data:`MIN_SESSIONS` sessions (else None).

    Parameters
    ----------
    machine : Machine
        The machine.
    given : object
        The data as the user gave them (a printer's configs are expanded into sessions).

    Returns
    -------
    tuple or None
        ``(items, sessions)``: the data objects and per object its session's name (None: the
        reference session).
    """

    try:
        data = expand_firmware_data(given, machine)
    except InputError:
        return None
    items = list(data) if isinstance(data, (list, tuple)) else [data]
    if any(isinstance(d, (str, bytes)) or hasattr(d, "__fspath__") for d in items):
        return None                 # CSV files: no sessions
    sessions = [getattr(d, "session", None) for d in items]
    if len(set(sessions)) < MIN_SESSIONS:
        return None
    return items, sessions


def _without_session(items, sessions, name) -> tuple:
    """The data of every session but ``name`` (copies; the newest remaining session is the
    reference when the reference is left out) and the left-out session's data."""
    import copy

    kept = [copy.copy(d) for d, s in zip(items, sessions, strict=True) if s != name]
    out = [d for d, s in zip(items, sessions, strict=True) if s == name]
    if name is None:
        remaining = [s for s in dict.fromkeys(sessions) if s is not None]
        for d in kept:
            if getattr(d, "session", None) == remaining[-1]:
                d.session = None
    return kept, out


def noise_levels(items, calibrations) -> list:
    """Per data object the smallest noise level (m) any of ``calibrations`` estimated or
    assumed for it (None where none has it): the scale its prediction errors are judged on."""
    from ..instruments.joint import file_labels

    labels = file_labels([getattr(d, "source", None) or f"data{i + 1}"
                          for i, d in enumerate(items)])
    out = []
    for label in labels:
        found = []
        for c in calibrations:
            groups = ((c.report.get("noise_model") or {}).get("groups") or []) \
                if c is not None else []
            found += [float(g["sigma"]) * 1e-6 for g in groups
                      if str(g.get("key", "")).startswith(label + ":")
                      and g.get("sigma") is not None and g.get("unit", "um") == "um"]
        out.append(min(found) if found else None)
    return out


def loso_folds(fit_on, candidate, items, sessions, levels, model=None) -> dict:
    """Each session left out in turn: the squared prediction errors of its data relative to
    each file's noise level (see the module docstring).

    Parameters
    ----------
    fit_on : callable
        ``fit_on(parameters, bed_tilt, data) -> Calibration``.
    candidate : ModelCandidate
        The candidate.
    items, sessions : list
        The data objects and their sessions (:func:`session_data`).
    levels : list
        Per data object its noise level, m (:func:`noise_levels`; None: not scored).
    model : str, optional
        The parameter set the candidate is on all the data: a fold whose remaining data fit
        another (Klipper's set without the distances that fix its arms is its basic set)
        judges another model and is marked so.

    Returns
    -------
    dict
        ``{session: (sum of (r / sigma)^2, rows, same model)}`` per left-out session with
        data to score.
    """
    from .check import check

    out = {}
    for name in dict.fromkeys(sessions):
        kept, left = _without_session(items, sessions, name)
        scored = [(d, lv) for d, lv in zip(items, levels, strict=True)
                  if any(d is o for o in left) and lv]
        if not scored or not kept:
            continue
        calibration = fit_on(candidate.parameters, candidate.bed_tilt, kept)
        same = model is None or \
            (calibration.report.get("parameter_set") or {}).get("name") == model
        result = check(calibration.calibrated, [d for d, _ in scored])
        total, rows = 0.0, 0
        for f, (_, level) in zip(result.report["files"], scored, strict=True):
            total += f["rows"] * (f["rms_um"] * 1e-6 / level) ** 2
            rows += f["rows"]
        out[name] = (total, rows, same)
    return out


def choose_model(fit, machine, candidates, sessions=None) -> tuple:
    """Fit every candidate and keep the one that predicts best (see the module docstring).

    Parameters
    ----------
    fit : callable
        ``fit(parameters, bed_tilt) -> Calibration``.
    machine : Machine
        The machine (for the words).
    candidates : list of ModelCandidate
        The firmware's own first.

    sessions : tuple, optional
        ``(fit_on, items, sessions)``: judge by leave-one-session-out
        (:func:`loso_score`; ``fit_on(parameters, bed_tilt, data)``) instead of PRESS.

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
    if sessions is not None:
        judged = _choose_by_sessions(fit, candidates, sessions)
        if judged is not None:
            return judged
    for i, c in enumerate(candidates):
        score, calibration = _fitted(fit, c, i)
        scores.append(score)
        if calibration is None:
            fits.append(None)
            continue
        result = calibration.result
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
    chosen = _best(scores, fits)
    return fits[chosen], scores, chosen


def _fitted(fit, candidate, i: int):
    """Candidate ``i`` fitted: its :class:`CandidateScore` (the redundancy set) and its
    calibration, or None with the score's note saying why (the first candidate's
    InputError raised)."""
    score = CandidateScore(candidate.parameters, candidate.bed_tilt, candidate.words)
    try:
        calibration = fit(candidate.parameters, candidate.bed_tilt)
    except InputError as exc:
        if i == 0:
            raise
        score.note = f"not fitted: {exc}"
        return score, None
    score.redundancy = int(calibration.result.dof)
    return score, calibration


def _best(scores, fits) -> int:
    """Index of the chosen candidate: the first unless a fitted one's score is lower than
    the best so far by :data:`MIN_GAIN` (or the best so far has none)."""
    chosen = 0
    for i, score in enumerate(scores):
        if i == 0 or score.press is None or fits[i] is None:
            continue
        best = scores[chosen].press
        if best is None or not np.isfinite(best) or score.press < (1.0 - MIN_GAIN) * best:
            chosen = i
    return chosen


def _choose_by_sessions(fit, candidates, sessions):
    """:func:`choose_model` by leave-one-session-out; None when the first candidate cannot be
    judged so (then PRESS decides). Every candidate is judged on the same left-out sessions:
    those whose remaining data leave each candidate the model it is on all the data."""
    fit_on, items, names = sessions
    scores, fits = [], []
    for i, c in enumerate(candidates):
        score, calibration = _fitted(fit, c, i)
        scores.append(score)
        fits.append(calibration)
    levels = noise_levels(items, fits)
    folds = []
    for i, (c, score) in enumerate(zip(candidates, scores, strict=True)):
        folds.append(None)
        if fits[i] is None:
            continue
        model = (fits[i].report.get("parameter_set") or {}).get("name")
        try:
            folds[i] = loso_folds(fit_on, c, items, names, levels, model)
        except (InputError, ValueError, ConvergenceError, np.linalg.LinAlgError) as exc:
            # a session the others' fit cannot predict (or no fit without it): not judged
            if i == 0:
                return None
            score.note = f"not judged: {exc}"
            fits[i] = None
    judged = [f for f in folds if f is not None]
    common = [n for n in judged[0] if all(n in f and f[n][2] for f in judged)]
    if not common:
        return None
    for f, score in zip(folds, scores, strict=True):
        if f is not None:
            score.press = sum(f[n][0] for n in common) / sum(f[n][1] for n in common)
            score.by_sessions = True
    chosen = _best(scores, fits)
    left = [n for n in judged[0] if n not in common]
    if left:
        scores[chosen].note = ("sessions left out in turn: " + ", ".join(
            str(n or "the reference") for n in common) + "; not " + ", ".join(
            str(n or "the reference") for n in left) + " (without it a candidate is "
            "another model)")
    return fits[chosen], scores, chosen


def choice_words(scores, chosen: int) -> str:
    """The choice in one line for the report and the console."""
    c = scores[chosen]
    judged = [s for s in scores if s.press is not None and np.isfinite(s.press)]
    table = "; ".join(f"{s.parameters}/{s.bed_tilt or 'default'} "
                      f"{np.sqrt(s.press):.3g}" for s in judged)
    if len(judged) > 1 and c.by_sessions:
        why = ("the smallest error predicting each session from the others' fit (leave one "
               f"session out, relative to each file's noise level: {table})")
    else:
        why = None
    why = why or ("the smallest leave-one-out prediction error of the measurements (PRESS, "
           f"relative to the noise: {table})" if len(judged) > 1 else
           "the only candidate the data can judge (the others need "
           f"{MIN_REDUNDANCY} equations beyond what they fit)")
    return f"model chosen (--parameters auto): {c.words}; {why}"


def calibrate_auto(calibrate, machine, given, kinds, arguments: dict):
    """``--parameters auto``: every candidate model the machine offers for data of these kinds
    (:meth:`~pkmcal.machines.Machine.model_candidates`) fitted with ``calibrate``, the one
    that predicts best kept (:func:`choose_model`); its report's ``model_choice`` and
    ``parameter_set`` say which and why.

    Parameters
    ----------
    calibrate : callable
        :func:`pkmcal.calibration.calibrate` (``parameters`` and ``bed_tilt`` given per
        candidate).
    machine : Machine
        The machine.
    given : object
        The data as the user gave them.
    kinds : list of MeasurementKind
        The data's kinds: a candidate's bed tilt applies only to heights above the bed, a
        candidate of lengths only to data that fix one.
    arguments : dict
        The other keywords of the call (``options``: the instruments' options; a
        ``bed_tilt`` given overrides the candidates').

    Returns
    -------
    Calibration or None
        The chosen candidate's calibration; None when the machine offers no candidates.
    """
    lengths = any(k.fixes_lengths for k in kinds)
    candidates = machine.model_candidates(lengths) if hasattr(machine, "model_candidates") \
        else []
    if not any(k.measures_bed_height for k in kinds):
        # a bed's tilt is a candidate's only where the data are heights above the bed
        candidates = list({c.parameters: replace(c, bed_tilt=None)
                           for c in candidates}.values())
    if not candidates:
        return None
    arguments = dict(arguments)
    options = dict(arguments.pop("options", None) or {})
    bed_tilt = options.pop("bed_tilt", None)

    def fit(name, bed):
        return calibrate(machine, given, parameters=name, options={
            **options, "bed_tilt": bed_tilt if bed_tilt is not None else bed}, **arguments)

    def fit_on(name, bed, data):
        return calibrate(machine, data, parameters=name, options={
            **options, "bed_tilt": bed_tilt if bed_tilt is not None else bed}, **arguments)

    found = session_data(machine, given)
    sessions = None if found is None else (fit_on, *found)
    calibration, scores, chosen = choose_model(fit, machine, candidates, sessions)
    words = choice_words(scores, chosen)
    criterion = ("each session predicted by the fit of the others (leave one session out; "
                 "the machine held, one free offset per data set), relative to each file's "
                 "noise level" if scores[chosen].by_sessions else
                 "leave-one-out prediction error of the measurements (PRESS), whitened by "
                 "the assumed noise")
    calibration.report["model_choice"] = {
        "chosen": chosen, "criterion": f"{criterion}; a larger model kept only when it "
        f"lowers it by {MIN_GAIN:.0%}", "words": words,
        "candidates": [sc.as_dict() for sc in scores]}
    calibration.warnings.append(words)
    chosen_set = calibration.report.get("parameter_set")
    if chosen_set is not None:
        # the choice's words are its warning (said once): the set names where they are
        chosen_set["note"] = ("fitted in its own set, the firmware's; " if chosen == 0
                              else "") + "chosen by --parameters auto (the report's model_choice)"
    return calibration


register_model_chooser(calibrate_auto)
