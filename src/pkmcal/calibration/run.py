"""One calibration of a machine from its data, as ``pkmcal calibrate`` runs it: the one
generic flow.

:func:`calibrate` validates the data and the options, chooses the model (a named parameter
set of the machine, or ``--parameters auto``'s choice among the machine's candidates), runs
the calibration of the data's instrument (one data set) or one fit of several
(:func:`~pkmcal.calibration.joint.calibrate_joint`), and returns the result
(:class:`~pkmcal.calibration.result.Calibration`), after the steps every calibration passes
(:func:`register_after_step`). It prints nothing: what the command prints as warnings is in
:attr:`Calibration.warnings`.

Nothing here is named after an instrument: the data's kind follows from the columns or the
data object (:mod:`pkmcal.calibration.kinds`), an instrument's options are declared in its
module and checked by one rule (:mod:`pkmcal.calibration.options`), its flow lives in its
module (:meth:`~pkmcal.instruments.base.Instrument.calibrate`, or the generic path of
:mod:`pkmcal.calibration.flows`), and every flow ends the same way
(:func:`~pkmcal.calibration.acceptance.finish`). Adding an instrument is adding its module.

Options may be given as the user's strings (``"2um"``, ``"20%"``), parsed with the messages of
the command line, or as SI numbers and noise models.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..estimation.acceptance import WHITENED_METHODS
from ..instruments.flow import CalibrationNotConverged, JointPart, json_safe, rows_text
from ..instruments.setups import Setups
from .firmware_data import expand_firmware_data
from .joint import calibrate_joint
from .kinds import (
    KINDS,
    MeasurementKind,
    data_kinds,
    flow_kind,
    instrument_kind,
    kind_of,
    measurement_kind,
    register_kind,
    supported_kinds,
)
from .noise_args import holdout_arg, noise_of, noise_per_file_arg, noise_through_expansion
from .options import instrument_options
from .parameter_sets import apply_parameter_set, parameter_set_names, parameter_set_of
from .provenance import file_units, provenance, report_json, text_digest, versions
from .result import Calibration

__all__ = ["KINDS", "WHITENED_METHODS", "Calibration",
           "CalibrationNotConverged", "JointPart", "MeasurementKind",
           "apply_parameter_set", "calibrate", "calibrate_joint", "file_units", "flow_kind",
           "holdout_arg", "instrument_kind", "json_safe", "report_json", "measurement_kind",
           "noise_per_file_arg", "parameter_set_names", "provenance", "register_after_step",
           "register_kind", "register_model_chooser", "rows_text", "supported_kinds",
           "text_digest", "versions"]


#: ``--parameters auto``'s chooser: :func:`pkmcal.calibration.model_choice.calibrate_auto`,
#: registered by its module (it scores candidates with :func:`pkmcal.calibration.check`, which
#: reads data through this module: this module does not import it)
_MODEL_CHOOSER: list[Callable] = []
#: what every calibration passes after its fit (:func:`register_after_step`)
_AFTER_STEPS: list[Callable] = []


def register_model_chooser(choose: Callable) -> Callable:
    """Register ``--parameters auto``'s chooser (see :data:`_MODEL_CHOOSER`).

    Parameters
    ----------
    choose : callable
        ``choose(calibrate, machine, data, kinds, arguments) -> Calibration or None``: the
        chosen model's calibration, None when the machine offers no candidates for data of
        these kinds; ``arguments`` are :func:`calibrate`'s keywords.

    Returns
    -------
    callable
        ``choose``.
    """
    _MODEL_CHOOSER[:] = [choose]
    return choose


def model_chooser() -> Callable:
    """The registered chooser of ``--parameters auto`` (importing :mod:`pkmcal.calibration`
    registers it).

    Returns
    -------
    callable
        The chooser.
    """
    if not _MODEL_CHOOSER:
        raise RuntimeError("no model chooser registered: import pkmcal.calibration")
    return _MODEL_CHOOSER[0]


def register_after_step(step: Callable) -> Callable:
    """Register a step every calibration passes after its fit, in order of registration
    (the shape a surface shows beside the kinematics, registered by its module).

    Parameters
    ----------
    step : callable
        ``step(calibration, data) -> Calibration``; ``data`` the list of data fitted.

    Returns
    -------
    callable
        ``step``.
    """
    if step not in _AFTER_STEPS:
        _AFTER_STEPS.append(step)
    return step


def _after(calibration: Calibration, data: list) -> Calibration:
    for step in _AFTER_STEPS:
        calibration = step(calibration, data)
    return calibration


def calibrate(machine, data, *, noise=None, robust: bool = False,
              holdout: float | str | None = None, seed: int = 0,
              parameters: str | None = None, options: Mapping | None = None,
              setups: Mapping | None = None, **more) -> Calibration:
    """Calibrate ``machine`` from measurements; the measurement kind follows from the data.

    Parameters
    ----------
    machine : Machine
        The machine's nominal model (the start of the estimation).
    data : str or os.PathLike or data object, or a list of them
        A data file (its columns give the kind, see :data:`KINDS`), data read already (an
        instrument's data object), or a firmware's saved state holding measurements
        (:func:`~pkmcal.calibration.firmware_data.expand_firmware_data`). A list of several:
        one geometry from all of them, each file with its own instrument unknowns and noise
        (:func:`calibrate_joint`); a list of one is that one.
    noise : str or float or noise model, or mapping, optional
        The measurements' noise, held as given (text such as ``"1um"``, an SI number or the
        instrument's noise model; None: each instrument's default, the levels estimated from
        the residuals). Several files: a mapping, file (as given, its name or index) ->
        noise.
    robust : bool, optional
        Find and leave out outlier rows (the noise's chi-square test of each row), every
        instrument.
    holdout : float or str, optional
        Hold out a share (< 1, or text such as ``"20%"``) or a number of rows, chosen at
        random, for validation (the report's ``validation`` section); with several files, of
        every file.
    seed : int, optional
        Seed of the choice of held-out rows.
    parameters : str, optional
        A named parameter set of the machine (``machine.parameter_set(name)``, e.g. a
        firmware's set): its fixed flags replace the machine's before the fit; ``"auto"``
        (where the machine offers candidate models): the one predicting best.
    options : mapping, optional
        The instruments' own options, by name (each declared in its instrument's module,
        :attr:`~pkmcal.instruments.base.Instrument.Options`: e.g. ``{"method": "ik"}``); an
        option the data's instrument does not declare is refused naming the instruments that
        take it.
    setups : Setups or mapping, optional
        The experiment's set-ups by instrument name (:mod:`pkmcal.instruments.setups`: the
        machine file's, as :func:`~pkmcal.io.load_machine_file` returns them beside the
        machine); None: none. The instruments read theirs (a start, frames held); the result's
        :attr:`~Calibration.setups` are these with the fitted ones in their place. The
        machine given is not changed.
    **more
        More instrument options by name (merged into ``options``).

    Returns
    -------
    Calibration
        The calibrated machine, the estimator's result, the report, the calibrated file's
        metadata, the parameter table and the warnings.

    Raises
    ------
    InputError
        Bad data or options (the message names the file, row or option).
    CalibrationNotConverged
        When the estimator did not converge.
    """
    options = {**dict(options or {}), **more}
    setups = Setups(setups)
    instrument_options(options)         # a name no instrument declares is refused first
    split = None
    if holdout is not None:
        split = (holdout_arg(holdout) if isinstance(holdout, str) else float(holdout), seed)
    if getattr(machine, "tolerances", "none") is None and hasattr(machine, "with_tolerances"):
        # a machine that never said (made in code, imported from a firmware's file) is fitted
        # with its default build tolerances, as its machine file would give it (SPEC 9);
        # ``tolerances: none`` / ``with_tolerances(None)`` fits without
        machine = machine.with_tolerances("default")
    given = data
    data = expand_firmware_data(data, machine)
    noise = noise_through_expansion(noise, given, data)
    notes = [n for item in (data if isinstance(data, (list, tuple)) else [data])
             for n in getattr(item, "notes", None) or []]
    kinds = data_kinds(data, machine)
    if parameters == "auto" or parameters is None:
        chosen = model_chooser()(calibrate, machine, given, kinds, dict(
            noise=noise, robust=robust, holdout=holdout, seed=seed, options=options,
            setups=setups))
        if chosen is not None:
            return chosen
        parameters = None
    machine, data, chosen, note = parameter_set_of(machine, data, kinds, parameters, notes)
    if isinstance(data, (list, tuple)):
        if not data:
            raise InputError("no data file given")
        if len(data) > 1:
            calibration = _noting(notes, calibrate_joint, machine, list(data), noise=noise,
                                  split=split, options={**options, "robust": robust},
                                  setups=setups)
            calibration.inputs = _inputs_of(given, calibration.inputs)
            calibration.warnings[:0] = notes
            return _after(_with_parameter_set(calibration, chosen, note), data)
        data = data[0]
    if isinstance(noise, dict):     # named as the joint fit names it: the path or its source
        noise = noise_of(noise, [data if isinstance(data, (str, Path))
                                 else getattr(data, "source", None) or "data1"], 0)
    source, kind = kind_of(machine, data)
    every = {**options, "noise": noise, "robust": robust}
    kind.check_options(every, source)
    calibration = _noting(notes, kind.calibrate, machine, data, source, every, split,
                          setups=setups)
    inputs = [Path(source)] if isinstance(data, (str, Path)) else []
    machine_file = getattr(machine, "source", None)
    if machine_file and machine_file != "default" and Path(machine_file).is_file():
        inputs.append(Path(machine_file))
    calibration.inputs = _inputs_of(given, inputs)
    calibration.warnings[:0] = notes
    return _after(_with_parameter_set(calibration, chosen, note), [data])


def _noting(notes: list, fit, *args, **kwargs):
    """``fit(*args, **kwargs)``; a refusal also names what the data's reader passed over
    (rows a firmware's saved state skips: why fewer rows than the user sees)."""
    try:
        return fit(*args, **kwargs)
    except InputError as exc:
        if not notes:
            raise
        raise InputError(f"{exc} (note: {'; '.join(notes)})") from None


def _inputs_of(given, inputs: list) -> list:
    """The input files to protect: ``inputs`` and every path the user gave (a firmware file
    read for its measurements is an input too)."""
    items = list(given) if isinstance(given, (list, tuple)) else [given]
    out = list(inputs)
    for item in items:
        if isinstance(item, (str, Path)) and Path(item) not in out:
            out.append(Path(item))
    return out


def _with_parameter_set(calibration: Calibration, name: str | None,
                        note: str = "") -> Calibration:
    """Record the parameter set of ``--parameters`` in the report and the calibrated file."""
    if name is None:
        return calibration
    mp = calibration.machine.parameters
    calibration.report["parameter_set"] = {
        "name": name, "free": [n for n, f in zip(mp.names, mp.fixed, strict=True) if not f],
        "fixed": int(np.sum(mp.fixed)), **({"note": note} if note else {})}
    calibration.metadata["parameter_set"] = name
    return calibration
