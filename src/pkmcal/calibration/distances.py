"""Calibration from ballbar distances (a pivot on the base, a ball on the platform).

The instrument's model is :class:`~pkmcal.instruments.DistancesModel`: per mounting (column
``setup``) an unknown pivot ``p`` (base frame) and ball ``b`` (platform frame), and the
measured length ``d = |P + R b - p|`` at the platform pose the readings give. The machine's
parameters and every mounting's pivot and ball are estimated together by the shared estimator
(:func:`~pkmcal.instruments.fit_instrument`): the pivots start from a sphere fit on the
machine file's model, then the mountings alone are fitted, then everything.

What distances cannot fix, named from the data (:mod:`pkmcal.instruments.problem`): on a
platform that rotates, a rigid motion of the base frame absorbed by the pivots and one of the
platform frame absorbed by the balls; on a translating platform (Delta) a ball and its pivot
enter only through their difference, per mounting.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..estimation.estimator import CalibrationResult
from ..estimation.rank import RTOL
from ..instruments import DistancesModel, InstrumentData, IsotropicNoise, fit_instrument
from ..machines.base import Machine


def calibrate_distances(machine: Machine, data: InstrumentData, noise=None, rtol: float = RTOL,
                        fit_machine: bool = True, **options) -> CalibrationResult:
    """Identify the machine's parameters (and every mounting) from ballbar lengths.

    Parameters
    ----------
    machine : Machine
        Start geometry; not modified.
    data : InstrumentData
        ``kind="distances"``: readings, lengths (m) and setups.
    noise : IsotropicNoise, optional
        The ballbar's noise (default 1 um).
    rtol : float, optional
        Rank tolerance.
    fit_machine : bool, optional
        False fits the mountings alone with the machine file's model (the "before
        calibration" baseline).
    **options
        Passed to :func:`~pkmcal.estimation.estimator.levenberg_marquardt`.

    Returns
    -------
    CalibrationResult
        With ``extras``: ``problem``, ``machine`` (calibrated, with ``ballbar_setups``: a
        ``(pivot, ball)`` pair per setup, m), ``model``, ``start_model``, ``setups``,
        ``unidentifiable``.

    Raises
    ------
    InputError
        When there are fewer lengths than identifiable unknowns per mounting, or the machine
        file's model cannot reproduce some readings.
    """
    noise = IsotropicNoise(1e-6) if noise is None else noise
    if data.kind != "distances":
        raise InputError(f"{data.source}: {data.kind} data, not ballbar distances")
    counts = np.bincount(data.group, minlength=data.n_groups)
    few = np.flatnonzero(counts < 6)
    if few.size:
        raise InputError(f"{data.source}: setup {few[0] + 1} has {counts[few[0]]} row(s); each "
                         "mounting needs at least 6 lengths (its pivot and ball are unknown)")
    result = fit_instrument(machine, data, DistancesModel(data.n_groups), noise,
                            fit_machine=fit_machine, rtol=rtol, **options)
    model, state = result.extras["model"], result.state.nuisance
    setups = [(np.array(state.values[model._ip[g]]), np.array(state.values[model._ib[g]]))
              for g in range(data.n_groups)]
    result.extras["machine"].ballbar_setups = setups
    result.extras["setups"] = setups
    return result
