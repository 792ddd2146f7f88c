"""How an instrument's data are calibrated from one file: its own flow
(:meth:`~pkmcal.instruments.base.Instrument.calibrate`, given only the options its ``Options``
declare) or the generic path of the shared layer (:func:`calibrate_instrument`: the
instrument's model, fitted by :func:`~pkmcal.instruments.fit_instrument`); and their parts of a
fit of several files."""

from __future__ import annotations

import numpy as np

from ..instruments.flow import (
    FlowContext,
    JointPart,
    scalar_metadata,
    scalar_residuals_json,
)
from ..instruments.flow import convergence_json as _convergence_json
from ..instruments.flow import identifiability_json as _identifiability_json
from ..instruments.flow import load_data as _load
from ..instruments.flow import public_parameters as _public
from ..instruments.flow import scalar_rms as _scalar_rms
from ..instruments.setups import Setups
from .acceptance import calibration_report_head as _report_head
from .acceptance import finish as _finish
from .acceptance import fit_with_nominal_baseline as _fit_with_baseline
from .options import check_instrument_options, options_for
from .provenance import file_units
from .result import Calibration


def _io_reader(inst, setups=None):
    """``read(path, machine)``: the :mod:`pkmcal.io` function the instrument names; one that
    numbers its rows by a group column (``target``, ``setup``) reads with the experiment's
    ``setups`` (a file without the column refused where the set-up holds several groups)."""
    from .. import io

    read = getattr(io, inst.calibration_reader or inst.reader)
    if inst.group_column is None:
        return read
    return lambda path, machine: read(path, machine, setups=setups)


def calibrate_flow(machine, data, source, options, split, inst, setups=None) -> Calibration:
    """Calibration from an instrument with a flow of its own
    (:meth:`~pkmcal.instruments.base.Instrument.calibrate`): the flow fits and reports, given
    only the options it declares and the experiment's ``setups``; every calibration's end
    (:func:`_finish`) follows, with the set-ups the flow determined in place of the given."""
    from ..report.provenance import run_date
    from . import extensions

    setups = Setups(setups)
    context = FlowContext(source=source, split=split, units=file_units(machine),
                          date=run_date, read=_io_reader(inst, setups),
                          model_choice=extensions, setups=setups)
    out = inst.calibrate(machine, data, context, options_for(inst, options))
    calibration = _finish(out.kind, out.machine, out.calibrated, out.result, out.report,
                          out.metadata, out.params, out.units, setups.merged(out.setups))
    calibration.warnings += out.warnings
    return calibration


def joint_flow(machine, data, source, noise, options, inst, setups=None) -> JointPart | None:
    """The file's part of a fit of several files, for an instrument with a flow of its own
    (:meth:`~pkmcal.instruments.base.Instrument.joint_part`; None: the generic one); its
    files read with the experiment's ``setups``."""
    return inst.joint_part(machine, data, source, noise, _io_reader(inst, setups),
                           options_for(inst, {**(options or {}), "noise": noise}))


def check_instrument(options, source, inst) -> None:
    """The options given checked against those the instrument declares
    (:func:`~pkmcal.calibration.options.check_instrument_options`)."""
    check_instrument_options(options, source, inst)


def _reader_of(inst):
    """``reader(path, machine)``: the instrument's data from a CSV file."""
    from ..io import read_measurements

    return lambda path, machine: read_measurements(inst, path, machine)


def _instrument_noise(inst, data, noise, machine):
    """The noise of ``--noise`` (the data's own weights when none is given)."""
    weights = getattr(data, "weights", None)
    if noise is None and weights is not None:
        return weights[0]
    return inst.noise_arg(noise, machine)


def calibrate_instrument(machine, data, source, options, split, inst,
                         setups=None) -> Calibration:
    """Calibration from an instrument of the shared layer that brings no flow of its own:
    its :meth:`~pkmcal.instruments.base.Instrument.calibration_model` (given its own
    options), noise and words; the experiment's ``setups`` pass to the calibrated file."""
    from ..instruments import fit_instrument

    own = options_for(inst, options)
    data = _load(data, _reader_of(inst), machine)
    noise = _instrument_noise(inst, data, options.get("noise"), machine)

    def fit(machine_, data_, noise_, **kwargs):
        return fit_instrument(machine_, data_, inst.calibration_model(machine_, data_, own),
                              noise_, **kwargs)

    data, held, result, before, calibrated, params, units = _fit_with_baseline(
        machine, data, source, split, _reader_of(inst), fit, noise, inst.advice,
        options.get("noise") is None, bool(options.get("robust")), setups)
    problem = result.problem
    rms_after, r_after = _scalar_rms(problem, result.state, data)
    rms_before, _ = _scalar_rms(before.problem, before.state, data)
    n_free = int(np.sum(result.parameters.free))
    unidentifiable = list(result.unidentifiable or [])
    report = {
        **_report_head(machine, source, inst.name, "joint"),
        "units": units,
        "measurements": len(data),
        "noise": inst.noise_text(noise),
        "convergence": _convergence_json(result),
        "residuals": scalar_residuals_json(result, r_after, rms_after, rms_before,
                                           inst.residual_words, "machine file's model"),
        "identifiability": _identifiability_json(n_free, int(result.rank), unidentifiable,
                                                 np.asarray(result.singular_values, float)),
        "parameters": _public(params),
    }
    metadata = scalar_metadata(inst.name, report, source, machine, result, rms_after,
                               len(data), unidentifiable)
    return _finish(inst.name, machine, calibrated, result, report, metadata, params, units,
                   setups)


def joint_instrument(machine, data, source, noise, options, inst, setups=None) -> JointPart:
    """The file's part of a fit of several files, for an instrument of the generic path."""
    data = _load(data, _reader_of(inst), machine)
    noise_model = _instrument_noise(inst, data, noise, machine)
    data.source = str(source)
    model = inst.calibration_model(machine, data, options_for(inst, options))
    return JointPart(data, model, noise_model,
                     inst.noise_text(noise_model), inst.name)
