"""Model extensions chosen by held-out data, never by the fit.

A machine offers candidate extensions of its model (:meth:`~pkmcal.machines.Machine.
model_extensions`: e.g. a six-leg platform's per-leg reading curvature). More parameters always
fit the calibration data better, so the fit cannot tell whether the machine has them. Here each
candidate is judged by *k-fold cross-validation* on the calibration data: the rows are split
into ``folds`` groups at random (seeded: the same data give the same choice); each group is
predicted by the model calibrated on the others, so every row is predicted once by a model that
did not see it. A candidate is adopted when its held-out loss beats the current model's by more
than the cross-validation's standard error (the paired differences of the rows' losses:
``mean(d) > se(d) = std(d) / sqrt(n)``) and by at least :data:`MIN_RELATIVE_GAIN` of the loss
(exact data: differences of rounding are no evidence). Candidates are tried greedily: the best
adopted one becomes the model the others must beat.

The core (:func:`cross_validate`) knows nothing of machines or instruments: it is given the
candidates and a function that calibrates on some rows and returns the losses of others.
:func:`choose_full_pose_extensions` is that function for full-pose data: the loss of a held-out
pose is the method's own whitened residual sum of squares with the leg parameters *and both
measurement frames* of the training fit (the frames are those of the same session: both models
carry their own, fitted on the same rows), the platform pose of ``ml`` fitted on the row alone
(its six unknowns are the row's own); the noise levels that weigh it are the same for every
model (those of the plain calibration). The held-out RMS of the leg lengths (inverse kinematics
of the measured pose) and of the positions and orientations (forward kinematics of the
readings) are reported beside it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError

__all__ = ["ExtensionChoice", "ExtensionTrial", "MIN_RELATIVE_GAIN", "choose_full_pose_extensions",
           "cross_validate", "fold_labels"]

#: default number of cross-validation folds
FOLDS = 5
#: an extension must lower the held-out loss by at least this share of the current model's
MIN_RELATIVE_GAIN = 0.01
#: ... and by more than this many standard errors of the paired differences (one: the usual
#: rule; a term the data do not have passes it about 6 % of the time, measured on a toy
#: polynomial with 60 rows, 0 of 10 simulated Jugglebot data sets for the leg curvature)
SE_FACTOR = 1.0
#: fewer rows per fold than this: no cross-validation (too few rows to predict)
MIN_ROWS_PER_FOLD = 3


def fold_labels(n_rows: int, folds: int = FOLDS, seed: int = 0) -> np.ndarray:
    """The fold of every row: a seeded random permutation cut into ``folds`` near-equal parts.

    Parameters
    ----------
    n_rows : int
        Number of rows.
    folds : int, optional
        Number of folds.
    seed : int, optional
        Seed of the permutation.

    Returns
    -------
    ndarray of int, shape (n_rows,)
        Fold (0 .. folds-1) of each row.
    """
    order = np.random.default_rng(seed).permutation(n_rows)
    labels = np.empty(n_rows, int)
    labels[order] = np.arange(n_rows) % folds
    return labels


@dataclass
class ExtensionTrial:
    """One candidate judged against the model it would extend.

    Attributes
    ----------
    name, description : str
        The candidate (:class:`~pkmcal.machines.base.ModelExtension`).
    parameters : tuple of str
        The parameters it adds.
    loss : float
        Mean held-out loss per row with it (NaN when it could not be fitted).
    baseline : float
        Mean held-out loss per row of the model it extends.
    gain : float
        ``mean(d)``: baseline minus candidate loss, per row (positive: it predicts better).
    se : float
        Standard error of ``gain`` (paired over the rows).
    adopted : bool
        Whether it was adopted.
    why : str
        The decision in words.
    figures : dict
        Held-out RMS figures with it (per quantity; the problem's own, e.g. leg, position,
        orientation).
    """

    name: str
    description: str
    parameters: tuple
    loss: float
    baseline: float
    gain: float
    se: float
    adopted: bool
    why: str
    figures: dict = field(default_factory=dict)

    def as_dict(self, units: dict | None = None) -> dict:
        """JSON-ready; ``units`` as for :meth:`ExtensionChoice.as_dict`."""
        return {"name": self.name, "description": self.description,
                "parameters": list(self.parameters), "cv_loss": self.loss,
                "cv_loss_baseline": self.baseline, "cv_gain": self.gain, "cv_se": self.se,
                "adopted": self.adopted, "why": self.why,
                "held_out_rms": _figures(self.figures, units)}


def _figures(figures: dict, units: dict | None) -> dict:
    """Held-out RMS figures in display units: ``units`` maps a figure's name to ``(SI value
    of one unit, unit name)``; figures not named stay SI."""
    units = units or {}
    out = {}
    for key, value in figures.items():
        factor, unit = units.get(key, (1.0, "SI"))
        out[key] = {"value": float(value) / factor, "unit": unit}
    return out


@dataclass
class ExtensionChoice:
    """What cross-validation tried and adopted.

    Attributes
    ----------
    machine : Machine
        The model to calibrate: the machine with the adopted extensions (the machine itself
        when none was adopted).
    adopted : list of str
        Names of the adopted extensions, in order.
    trials : list of ExtensionTrial
        Every candidate tried (greedy rounds in order).
    plain_loss : float
        Mean held-out loss per row of the plain model.
    plain_figures : dict
        Its held-out RMS figures.
    folds : int
        Number of folds.
    rows : int
        Rows cross-validated.
    seed : int
        Seed of the folds.
    loss : str
        What the loss is, in words.
    skipped : str
        Why nothing was tried ("" when cross-validation ran).
    """

    machine: object
    adopted: list
    trials: list
    plain_loss: float = float("nan")
    plain_figures: dict = field(default_factory=dict)
    folds: int = FOLDS
    rows: int = 0
    seed: int = 0
    loss: str = ""
    skipped: str = ""

    def as_dict(self, units: dict | None = None) -> dict:
        """JSON-ready (the report's ``model_extensions`` section).

        Parameters
        ----------
        units : dict, optional
            Figure name -> ``(SI value of one display unit, unit name)`` for the held-out
            RMS figures (default SI).

        Returns
        -------
        dict
            ``tried``, ``adopted``, ``criterion``, ``loss``, ``folds``, ``rows``, ``seed``,
            ``plain`` (its CV loss and held-out RMS), ``trials`` and, when nothing was
            tried, ``skipped``.
        """
        return {"tried": [t.name for t in self.trials], "adopted": list(self.adopted),
                "criterion": (f"{self.folds}-fold cross-validation on the calibration rows "
                              f"(seed {self.seed}): an extension is adopted when its mean "
                              "held-out loss is lower than the model it extends by more than "
                              "the standard error of the paired differences and by at least "
                              f"{MIN_RELATIVE_GAIN:.0%}"),
                "loss": self.loss, "folds": self.folds, "rows": self.rows, "seed": self.seed,
                "plain": {"cv_loss": self.plain_loss,
                          "held_out_rms": _figures(self.plain_figures, units)},
                "trials": [t.as_dict(units) for t in self.trials],
                **({"skipped": self.skipped} if self.skipped else {})}

    def lines(self) -> list[str]:
        """The choice in words, one line per candidate."""
        if self.skipped:
            return [f"none tried: {self.skipped}"]
        return [f"{t.name}: held-out loss {t.loss:.4g} vs {t.baseline:.4g} per row "
                f"(gain {t.gain:.3g} +- {t.se:.2g}): {t.why}" for t in self.trials]


def _decide(base: np.ndarray, cand: np.ndarray) -> tuple[float, float, bool, str]:
    d = base - cand
    n = len(d)
    gain = float(np.mean(d))
    se = float(np.std(d, ddof=1) / np.sqrt(n)) if n > 1 else float("inf")
    floor = MIN_RELATIVE_GAIN * float(np.mean(base))
    if not np.all(np.isfinite(d)):
        return gain, se, False, "not adopted: the extended model could not predict every row"
    if gain > SE_FACTOR * se and gain > floor:
        return gain, se, True, (f"adopted: held-out loss lower by {gain:.3g} per row, "
                                f"{gain / se:.1f} standard errors")
    if gain <= 0:
        return gain, se, False, "not adopted: it predicts held-out rows no better"
    if gain <= SE_FACTOR * se:
        return gain, se, False, ("not adopted: better by less than the cross-validation's "
                                 "standard error")
    return gain, se, False, f"not adopted: better by less than {MIN_RELATIVE_GAIN:.0%}"


def cross_validate(machine, n_rows: int, fit_and_predict: Callable, candidates=None,
                   folds: int = FOLDS, seed: int = 0, loss: str = "") -> ExtensionChoice:
    """Choose model extensions by k-fold cross-validation (see the module docstring).

    Parameters
    ----------
    machine : Machine
        The plain model.
    n_rows : int
        Number of calibration rows.
    fit_and_predict : callable
        ``fit_and_predict(machine, train, test) -> (losses, errors)``: calibrate ``machine``
        on the rows ``train`` (int array) and return the held-out loss of each row of
        ``test`` (array, shape (len(test),)) and a dict of per-row error arrays (e.g. leg,
        position, orientation; summarised as RMS). May raise :class:`InputError` (the model
        cannot be fitted on those rows).
    candidates : list of ModelExtension, optional
        Default: ``machine.model_extensions()``.
    folds : int, optional
        Number of folds.
    seed : int, optional
        Seed of the folds.
    loss : str, optional
        What the loss is, in words (for the report).

    Returns
    -------
    ExtensionChoice
        The model to calibrate and what was tried.
    """
    candidates = list(machine.model_extensions() if candidates is None else candidates)
    choice = ExtensionChoice(machine, [], [], folds=folds, rows=n_rows, seed=seed, loss=loss)
    if not candidates:
        choice.skipped = "the machine offers no model extensions"
        return choice
    if n_rows < folds * MIN_ROWS_PER_FOLD:
        choice.skipped = (f"{n_rows} rows: too few for {folds}-fold cross-validation "
                          f"(at least {folds * MIN_ROWS_PER_FOLD})")
        return choice
    labels = fold_labels(n_rows, folds, seed)

    def evaluate(model):
        losses = np.full(n_rows, np.nan)
        errors: dict = {}
        for k in range(folds):
            train, test = np.flatnonzero(labels != k), np.flatnonzero(labels == k)
            value, err = fit_and_predict(model, train, test)
            losses[test] = value
            for key, v in err.items():
                errors.setdefault(key, np.full((n_rows,) + np.shape(v)[1:], np.nan))[test] = v
        return losses, {k: float(np.sqrt(np.nanmean(np.asarray(v) ** 2)))
                        for k, v in errors.items()}

    try:
        current, figures = evaluate(machine)
    except (InputError, ValueError, np.linalg.LinAlgError) as exc:
        choice.skipped = f"the plain model cannot be cross-validated on these rows: {exc}"
        return choice
    choice.plain_loss, choice.plain_figures = float(np.mean(current)), figures
    remaining = list(candidates)
    model = machine
    while remaining:
        round_trials = []
        for ext in remaining:
            try:
                extended = ext.apply(model)
                losses, figs = evaluate(extended)
            except (InputError, ValueError, np.linalg.LinAlgError) as exc:
                round_trials.append((ext, None, None, ExtensionTrial(
                    ext.name, ext.description, tuple(ext.parameters), float("nan"),
                    float(np.mean(current)), float("nan"), float("nan"), False,
                    f"not adopted: it cannot be fitted on the folds ({exc})")))
                continue
            gain, se, ok, why = _decide(current, losses)
            round_trials.append((ext, extended, losses, ExtensionTrial(
                ext.name, ext.description, tuple(ext.parameters), float(np.mean(losses)),
                float(np.mean(current)), gain, se, ok, why, figs)))
        adopted = [t for t in round_trials if t[3].adopted]
        if adopted:
            best = max(adopted, key=lambda t: t[3].gain)
            for t in adopted:
                if t is not best:
                    t[3].adopted = False
                    t[3].why = f"not adopted this round: {best[0].name} predicts better"
        choice.trials += [t[3] for t in round_trials]
        if not adopted:
            break
        ext, model, current, _ = best
        choice.adopted.append(ext.name)
        remaining = [e for e in remaining if e is not ext]
        # candidates already tried against the smaller model are tried again on this one
    choice.machine = model
    return choice


# -- full poses --------------------------------------------------------------------------------


def choose_full_pose_extensions(machine, data, method: str = "ml", noise=None, frames=None,
                                fix_frames=False, folds: int = FOLDS, seed: int = 0,
                                candidates=None, **options) -> ExtensionChoice:
    """Cross-validate a six-dof platform's model extensions on full-pose data.

    Parameters
    ----------
    machine : Machine
        The plain model (a platform with full-pose data).
    data : FullPoseData
        The calibration rows.
    method : {'ml', 'ik'}, optional
        The method the calibration uses (the folds are fitted and scored by it).
    noise : FullPoseNoise, optional
        Noise levels: they weigh every model's held-out residuals alike and are held in the
        folds' fits (the levels of the plain calibration, estimated or given).
    frames : MeasurementFrames, optional
        Start (or fixed) frames, as for the calibration.
    fix_frames : bool or str or sequence of str, optional
        As for :func:`~pkmcal.instruments.pose.calibrate_full_pose`.
    folds, seed : int, optional
        Cross-validation folds and their seed.
    candidates : list of ModelExtension, optional
        Default: the machine's.
    **options
        Passed to the folds' fits (``rtol``, ``max_std``, ...).

    Returns
    -------
    ExtensionChoice
        The model to calibrate and what was tried.
    """
    from ..instruments.pose import (
        FullPoseNoise,
        PoseSection,
        calibrate_full_pose,
        full_pose_errors,
    )

    noise = FullPoseNoise() if noise is None else noise

    def fit_and_predict(model, train, test):
        fit = calibrate_full_pose(model, data.subset(train), method=method, noise=noise,
                                  frames=frames, fix_frames=fix_frames, estimate_noise=False,
                                  **options)
        if not (fit.success and np.all(np.isfinite(fit.x))):
            raise InputError(f"the fit on {len(train)} rows did not converge ({fit.message})")
        fitted, f = fit.machine, fit.section(PoseSection).frames
        held = data.subset(test)
        return (held_out_loss(fitted, f, held, method, noise),
                _errors(full_pose_errors(fitted, f, held)))

    words = ("the method's whitened residual sum of squares of a held-out pose (ml: its "
             "platform pose fitted on the row alone; ik: readings against the measured pose, "
             "whitened by the readings' and the pose's noise), leg parameters and frames from "
             "the other folds, noise levels those of the plain calibration")
    return cross_validate(machine, len(data), fit_and_predict, candidates, folds, seed, words)


def _errors(errors) -> dict:
    ok = errors.converged
    return {"leg_length": np.asarray(errors.leg_length, float),
            "position": np.where(ok, errors.position, np.nan),
            "orientation": np.where(ok, errors.orientation, np.nan)}


def held_out_loss(machine, frames, data, method: str, noise) -> np.ndarray:
    """Per-row held-out loss of a calibrated full-pose model (see the module docstring).

    Parameters
    ----------
    machine : Machine
        The calibrated model.
    frames : MeasurementFrames
        Its frames.
    data : FullPoseData
        Rows it did not see.
    method : {'ml', 'ik'}
        The criterion.
    noise : FullPoseNoise
        The noise levels that whiten the residuals.

    Returns
    -------
    ndarray, shape (len(data),)
        Sum of squared whitened residuals per row.
    """
    from ..instruments.pose import calibrate_full_pose

    fit = calibrate_full_pose(machine, data, method=method, noise=noise, frames=frames,
                              fix_frames=True, fit_machine=False, estimate_noise=False,
                              require_identifiable=False)
    problem = fit.problem
    r = (problem.noise_whitened(fit.state) if hasattr(problem, "noise_whitened")
         else np.asarray(fit.residuals, float))
    return np.sum(np.asarray(r, float) ** 2, axis=-1)
