"""An instrument's own calibration flow (``pkmcal calibrate`` from one data file): what the
calibration layer gives it and what it hands back, and the steps every flow shares.

An instrument with a flow of its own (:meth:`~pkmcal.instruments.base.Instrument.calibrate`)
reads and splits its data, fits, and builds its report sections and the calibrated file's
metadata; it returns a :class:`FlowResult`. The calibration layer
(:mod:`pkmcal.calibration.run`) chose the instrument from the data, checked the options and
finishes every flow the same way (covariance, residual verdict, acceptance, provenance). What
the flow needs from the layers above the instruments (the machine file's units, the run's date,
the reader of its files, the model choice) comes in a :class:`FlowContext`, so instruments
import nothing above them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from ..errors import ConvergenceError, InputError
from ..paths import path_text
from .setups import Setups

__all__ = ["CalibrationNotConverged", "FlowContext", "FlowResult", "JointPart",
           "convergence_json",
           "fit_with_baseline", "holdout_split", "identifiability_json",
           "identifiability_metadata", "json_safe", "load_data", "option",
           "option_specs", "parameter_table", "public_parameters", "report_head",
           "require_converged", "rows_text", "scalar_rms", "solve", "source_of", "split_rows",
           "um", "validation_section"]


@dataclass(frozen=True)
class FlowContext:
    """What the calibration layer gives an instrument's flow.

    Attributes
    ----------
    source : str or pathlib.Path
        The data file (or the data's name), named in messages and the report.
    split : tuple or None
        ``(holdout, seed)``: rows held out for validation; None: none.
    units : dict
        The machine file's units (``length``, ``angle``).
    date : callable
        ``date() -> str``: the run's date (ISO 8601), as every report states it.
    read : callable
        ``read(path, machine) -> data``: the :mod:`pkmcal.io` reader the instrument names
        (:attr:`~pkmcal.instruments.base.Instrument.calibration_reader`).
    model_choice : object, optional
        The calibration layer's choice of model extensions by cross-validation
        (:mod:`pkmcal.calibration.extensions`), for flows whose machines offer extensions.
    setups : Setups, optional
        The experiment's set-ups as given (the machine file's: a tracker's frame, the
        motion-capture frames, ...), by instrument name (:mod:`pkmcal.instruments.setups`);
        a flow reads its own with ``setups.get(name)``.
    """

    source: object
    split: tuple | None
    units: dict
    date: Callable
    read: Callable
    model_choice: object = None
    setups: Setups = field(default_factory=Setups)

    def head(self, machine, kind: str, method: str, units=None) -> dict:
        """The first keys of the report (:func:`report_head`)."""
        return report_head(self.date(), machine, self.source, kind, method, units)


@dataclass
class FlowResult:
    """What an instrument's flow hands back to the calibration layer, which finishes it into a
    :class:`~pkmcal.calibration.result.Calibration`.

    Attributes
    ----------
    kind : str
        The measurement kind (the instrument's name).
    machine : Machine
        The nominal model the fit started from (the machine given, or the model with an
        adopted extension).
    calibrated : Machine
        The calibrated machine.
    result : CalibrationResult
        The estimator's result.
    report : dict
        The report so far (its head, the instrument's sections).
    metadata : dict
        The calibrated file's ``calibration:`` section.
    params : list of dict
        The parameter table (:func:`parameter_table`).
    units : dict
        The machine file's units.
    warnings : list of str
        The flow's own warnings, after those every calibration states.
    setups : dict
        The set-ups the fit determined, by instrument name (e.g. ``{"tracker":
        TrackerSetup(...)}``); the calibration layer merges them into the given ones
        (:attr:`~pkmcal.calibration.result.Calibration.setups`).
    """

    kind: str
    machine: object
    calibrated: object
    result: object
    report: dict
    metadata: dict
    params: list
    units: dict
    warnings: list = field(default_factory=list)
    setups: dict = field(default_factory=dict)


@dataclass
class JointPart:
    """One file of a joint fit, ready for :func:`~pkmcal.instruments.joint.fit_joint` (what an
    instrument's :meth:`~pkmcal.instruments.base.Instrument.joint_part` brings to a fit of
    several files).

    Attributes
    ----------
    data : InstrumentData
        Readings and measurements.
    model : NuisanceModel
        The instrument's model (start values computed by the fit).
    noise : object
        Noise model (``whitening``).
    noise_text : str
        The noise in words.
    kind : str
        The measurement kind (the instrument's name).
    """

    data: object
    model: object
    noise: object
    noise_text: str
    kind: str
    #: ``with_others(equations, unknowns) -> (model, words)``: the part's model once the
    #: other files are known (a printer's bed tilt, decided on every file's equations)
    with_others: Callable | None = None
    frame: str = ""
    #: weighed as the data's source weighs them (relative levels held, common level fitted)
    tied: bool = False


def report_head(date: str, machine, source, kind: str, method: str, units=None) -> dict:
    """The first keys of every report (``units`` last, when given)."""
    head = {"pkmcal_report": 1, "command": "calibrate", "date": date,
            "machine_file": source_of(machine), "data_file": path_text(source),
            "calibrated_file": None, "measurement": kind, "method": method}
    return head if units is None else {**head, "units": units}


class CalibrationNotConverged(ConvergenceError):
    """The estimator did not converge; nothing to write.

    Parameters
    ----------
    message : str
        Why, naming the data, and what to try.
    result : CalibrationResult, optional
        The estimator's last state (also the attribute ``result``).
    """

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result


def json_safe(value):
    """A value made JSON-safe: NaN and infinities become None, numpy values Python ones.

    Parameters
    ----------
    value : object
        A number, array, list, tuple or dict (nested), or anything else (returned as is).

    Returns
    -------
    object
        The same structure with lists for arrays and tuples, Python numbers for numpy
        scalars and None for non-finite floats.
    """
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "biu" or (value.dtype.kind == "f" and np.isfinite(value).all()):
            return value.tolist()           # Python numbers already, every one finite
        return json_safe(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


def rows_text(rows, limit: int = 10) -> str:
    """Row numbers for a message: the first ``limit``, then ``...``.

    Parameters
    ----------
    rows : iterable of int
        Row numbers.
    limit : int, optional
        How many to show.

    Returns
    -------
    str
        E.g. ``"3, 7, 12"``.
    """
    rows = [int(r) for r in rows]
    return ", ".join(map(str, rows[:limit])) + (" ..." if len(rows) > limit else "")


def source_of(machine) -> str:
    """The machine's file (``default`` for the embedded one), else its name."""
    return path_text(getattr(machine, "source", None) or getattr(machine, "name", None)
                     or "the machine")


def load_data(data, reader, machine):
    """Data read from ``data`` (a path) with ``reader``, or ``data`` itself."""
    return reader(Path(data), machine) if isinstance(data, (str, Path)) else data


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


def split_rows(data, split, source):
    """``(calibration data, held-out data or None)`` for ``holdout``/``seed``."""
    if split is None:
        return data, None
    try:
        train, held = holdout_split(len(data), *split)
    except ValueError as exc:
        raise InputError(f"--holdout: {path_text(source)}: {exc}") from None
    return data.subset(train), data.subset(held)


def solve(source, estimator, *args, held=None, **kwargs):
    """Run a calibration; numerical failures caused by the data become an InputError naming
    the data. With ``held`` (the rows held out) a failure names the option too: the rows left
    may be too few."""
    try:
        return estimator(*args, **kwargs)
    except (InputError, ValueError, np.linalg.LinAlgError) as exc:
        message = str(exc) if isinstance(exc, InputError) else \
            f"{path_text(source)}: calibration failed: {exc}"
        if held is not None:
            message = (f"--holdout: holding out {len(held)} row(s) leaves {len(args[1])} "
                       f"to calibrate on: {message}")
        raise InputError(message) from None


def require_converged(result, source, advice: str = "") -> None:
    """Raise :class:`CalibrationNotConverged` (saying why and what to try, naming the data)
    unless the calibration converged."""
    if result.success and np.all(np.isfinite(result.x)):
        return
    raise CalibrationNotConverged(
        f"{path_text(source)}: calibration did not converge: {result.message} (after {result.nit} "
        "iterations)" + (f"; {advice}" if advice else "") + "; check the columns (order, "
        "units) and the machine file; no file written", result)


def parameter_table(result, nominal_of: dict, units):
    """Rows of the report's parameter list, in the machine file's units; ``nominal_of`` maps
    parameter names to their start (nominal) values."""
    from ..units import ANGLE, LENGTH

    fl, fa = LENGTH[units["length"]], ANGLE[units["angle"]]
    rows = []
    params = result.parameters
    for i, (name, kind) in enumerate(zip(params.names, params.kinds, strict=True)):
        f = fl if kind == "length" else fa if kind == "angle" else 1e-3 if kind == "slope" \
            else 1.0
        unit = units["length"] if kind == "length" else units["angle"] if kind == "angle" \
            else "mm/m" if kind == "slope" else "1"
        nominal = nominal_of.get(name, float("nan"))
        fixed = bool(params.fixed[i])
        rows.append({
            "name": name, "kind": kind, "unit": unit,
            "nominal": nominal / f, "identified": result.x[i] / f,
            "change": (result.x[i] - nominal) / f,
            "std": None if fixed else result.std[i] / f,
            "fixed": fixed,
            "scaled_change": abs(result.x[i] - nominal) / result.scales[i],
        })
    return rows


def public_parameters(params) -> list[dict]:
    """The parameter table as the report lists it (without ``scaled_change``)."""
    return [{k: v for k, v in p.items() if k != "scaled_change"} for p in params]


def um(value_m: float) -> float | None:
    """Metres -> micrometres for a report; None when not finite."""
    return json_safe(float(value_m) * 1e6)


def _fmt(value) -> str:
    return "n/a" if value is None else f"{value:.4g}"


def validation_section(split, held, of: str, unit: str, before, after, calibration,
                       **extra) -> dict:
    """The report's held-out validation section: RMS residuals of the held-out rows with the
    machine file's and the calibrated model, next to the calibration rows' own RMS."""
    ratio = after / calibration if after is not None and calibration else None
    summary = (f"{len(held)} held-out rows: RMS {_fmt(before)} -> {_fmt(after)} {unit} "
               f"(calibration rows {_fmt(calibration)} {unit}"
               + (f"; held-out / calibration = {ratio:.3g}" if ratio is not None else "") + ")")
    return {"summary": summary, "held_out": len(held), "rows": [int(r) for r in held.rows],
            "holdout": split[0], "seed": split[1], "of": of, "unit": unit,
            "before_rms": before, "after_rms": after, "calibration_rms": calibration,
            "held_out_over_calibration": ratio, **extra}


def identifiability_json(n_free, rank, unidentifiable, s) -> dict:
    """The identifiability section of a calibration report: the directions the data cannot
    fix, and apart from them the weakly identifiable ones (counted in ``identifiable``, left
    at their start values; each with its standard deviation)."""
    return {
        "free_parameters": n_free,
        "identifiable": rank,
        "unidentifiable": [d.as_dict() for d in unidentifiable if d.std is None],
        "weakly_identifiable": [d.as_dict() for d in unidentifiable if d.std is not None],
        "condition_number": float(s[0] / s[rank - 1]) if rank else None,
        "singular_values": s.tolist(),
    }


def convergence_json(result) -> dict:
    """The report's convergence section of an estimator's result."""
    return {"success": bool(result.success), "status": int(result.status),
            "message": result.message, "iterations": int(result.nit),
            "evaluations": int(result.nfev)}


def identifiability_metadata(unidentifiable) -> dict:
    """The calibrated file's words for the directions the data cannot fix or fix weakly."""
    return {"unidentifiable": [f"{d.dimension} x {d.name}" for d in unidentifiable
                               if d.std is None],
            "weakly_identifiable": [d.name for d in unidentifiable if d.std is not None]}


def scalar_rms(problem, state, data) -> tuple[float | None, np.ndarray]:
    """RMS (um) and residuals (m) of a one-value instrument (ballbar lengths, probe heights)
    under a problem's state (NaN where the forward kinematics fail)."""
    predicted = problem.predict(state, data.q, data.group)[:, 0]
    r = data.values[:, 0] - predicted
    ok = np.isfinite(r)
    return (um(math.sqrt(float(np.mean(r[ok] ** 2)))) if ok.any() else None), r


def variance_json(result) -> dict:
    """The residual variance, its square root (the noise scale, None when not finite) and the
    degrees of freedom of an estimator's result, for a report's residuals section."""
    return {"residual_variance": float(result.residual_variance),
            "noise_scale": float(np.sqrt(result.residual_variance))
            if np.isfinite(result.residual_variance) else None,
            "dof": int(result.dof)}


def scalar_residuals_json(result, r_after, rms_after, rms_before, of: str, before: str,
                          r_before=None) -> dict:
    """The report's residuals section of a one-value instrument (:func:`scalar_rms`'s RMS and
    residuals after and before the fit; with ``r_before`` its largest too)."""
    ok = np.isfinite(r_after)
    out = {"of": of, "count": int(ok.sum()), "rms_um": rms_after,
           "max_abs_um": um(float(np.max(np.abs(r_after[ok])))) if ok.any() else None,
           "before_rms_um": rms_before}
    if r_before is not None:
        out["before_max_abs_um"] = um(float(np.nanmax(np.abs(r_before)))) \
            if np.isfinite(r_before).any() else None
    return {**out, "before": before, **variance_json(result)}


def scalar_metadata(method: str, report: dict, source, machine, result, rms_after,
                    measurements: int, unidentifiable) -> dict:
    """The calibrated file's metadata of a one-value instrument's calibration."""
    return {"method": method, "date": report["date"], "data": path_text(source),
            "machine": source_of(machine), "measurements": measurements,
            "rms_residual_um": rms_after, "identifiable": int(result.rank),
            "free_parameters": int(np.sum(result.parameters.free)),
            **identifiability_metadata(unidentifiable)}


def fit_with_baseline(machine, data, context: FlowContext, fit, noise, advice: str, *,
                      estimate_noise: bool, robust: bool):
    """What the instrument-layer flows share: read and split the data, fit the instrument
    with the machine and alone on the machine file's model (the "before" baseline), check
    convergence, name the calibrated machine and build the parameter table (start values of
    the instrument's unknowns as their nominal).

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    data : path or data object
        The data (read with ``context.read``).
    context : FlowContext
        Source, split, units and reader.
    fit : callable
        ``fit(machine, data, noise, held=..., estimate_noise=..., robust=...,
        fit_machine=...) -> CalibrationResult``.
    noise : object
        The instrument's noise model.
    advice : str
        What to measure when the fit does not converge.
    estimate_noise : bool
        Estimate the noise level from the residuals (the user gave none).
    robust : bool
        Leave out the rows the noise cannot explain.

    Returns
    -------
    tuple
        ``(data, held, result, before, calibrated, params, units)``.
    """
    source, split = context.source, context.split
    data, held = split_rows(load_data(data, context.read, machine), split, source)
    # the noise level from the residuals unless the user gave it; rows it cannot explain
    # named (left out with --robust)
    result = solve(source, fit, machine, data, noise, held=held,
                   estimate_noise=estimate_noise, robust=robust)
    before = solve(source, fit, machine, data, noise, held=held, fit_machine=False)
    require_converged(result, source, advice)
    units = context.units
    calibrated = result.machine
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    calibrated.home = machine.home
    nominal_of = dict(zip(machine.parameters.names, machine.u, strict=True))
    start = result.start_model.parameters
    nominal_of.update(zip(start.names, start.values, strict=True))
    params = parameter_table(result, nominal_of, units)
    return data, held, result, before, calibrated, params, units


def option(default, flag: str, help: str, *, metavar: str | None = None,
           choices: tuple | None = None, joint: bool = False, negative_help: str = ""):
    """A field of an instrument's ``Options`` (its calibration flow's options): the default,
    the command-line flag, its help text and how the command line shows and checks it
    (``dataclasses.field`` metadata; ``pkmcal calibrate``'s options are built from them).

    Parameters
    ----------
    default : object
        The value when not given (immutable).
    flag : str
        The option of ``pkmcal calibrate`` (``--two-step``; ``--x/--no-x`` for a switch that
        is None until given either way).
    help : str
        What it does, in one or two sentences.
    metavar : str, optional
        The value's name in the help (a text option).
    choices : tuple of str, optional
        The values it takes (anything else is refused naming the flag).
    joint : bool, optional
        It applies to this instrument's part of a fit of several data files too.
    negative_help : str, optional
        The help of the ``--no-x`` flag of a ``--x/--no-x`` switch.

    Returns
    -------
    dataclasses.Field
        The field.
    """
    return field(default=default, metadata={"flag": flag, "help": help, "metavar": metavar,
                                            "choices": tuple(choices) if choices else None,
                                            "joint": bool(joint),
                                            "negative_help": negative_help})


def option_specs(options_class) -> list[dict]:
    """The options an ``Options`` class declares: name, flag, type, default, help, metavar,
    choices and whether they apply to a fit of several files.

    Parameters
    ----------
    options_class : type
        A dataclass of :func:`option` fields.

    Returns
    -------
    list of dict
        One per field, in order.
    """
    return [{"name": f.name, "flag": f.metadata.get("flag"), "type": f.type,
             "default": f.default, "help": f.metadata.get("help"),
             "metavar": f.metadata.get("metavar"), "choices": f.metadata.get("choices"),
             "joint": bool(f.metadata.get("joint"))}
            for f in fields(options_class)]
