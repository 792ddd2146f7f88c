"""The instruments a user can measure a machine with, each one object: the registry.

Every instrument knows, for any :class:`~pkmcal.machines.Machine`: whether it applies (and why
not), its default noise model, candidate poses and its standard plan, the noise-free data of a
plan on the nominal machine, and the calibration problem ``pkmcal calibrate`` solves. Planning
(:mod:`pkmcal.instruments.scenarios`), simulation and calibration look an instrument up here by
name; adding one is adding an entry, touching neither the estimator nor the CLI.

===================  ==================================================  =====================
name (aliases)       measures                                            machines
===================  ==================================================  =====================
``constraint-link``  joint readings with a fixed-length link, one joint  platforms that rotate
                     passive (seed 000)                                  (``constraint_link``)
``tracker``          a target on the platform in the instrument frame    every machine
(``points``)         (laser tracker, CMM, photogrammetry)
``pose``             the marker pose (motion capture, 6-D tracker)       platforms that rotate
(``poses``)
``distance``         ballbar length between a pivot on the base and a    every machine
(``distances``)      ball on the platform (ISO 230-4 circles)
``probe``            the nozzle's height above a flat bed at the probe   every machine
(``probe-heights``,  trigger (bed height and tilt estimated; Klipper's
``bed-probe``)       DELTA_CALIBRATE pattern)
===================  ==================================================  =====================
"""

from __future__ import annotations

import importlib

from ..errors import InputError
from .base import Instrument

#: the instrument modules (under :mod:`pkmcal.instruments`), one line each; a module exports
#: ``INSTRUMENT``, its :class:`~pkmcal.instruments.base.Instrument`. The order is the order
#: commands list them in.
INSTRUMENT_MODULES: tuple[str, ...] = (
    "constraint_link",
    "tracker",
    "pose",
    "distance",
    "probe",
    "pairs",
    "dial",
)

#: the instruments by canonical name
INSTRUMENTS: dict[str, Instrument] = {
    inst.name: inst for inst in (importlib.import_module(f"{__package__}.{module}").INSTRUMENT
                                 for module in INSTRUMENT_MODULES)}


def instrument(name: str) -> Instrument:
    """The instrument of a name or alias.

    Parameters
    ----------
    name : str
        ``constraint-link``, ``tracker`` (``points``), ``pose`` (``poses``), ``distance``
        (``distances``, ``ballbar``), ``probe`` (``probe-heights``, ``bed-probe``).

    Returns
    -------
    Instrument
        The registry entry.

    Raises
    ------
    InputError
        For an unknown name, listing the known ones.
    """
    for inst in INSTRUMENTS.values():
        if name == inst.name or name in inst.aliases:
            return inst
    known = ", ".join(f"{i.name}" + (f" ({'/'.join(i.aliases)})" if i.aliases else "")
                      for i in INSTRUMENTS.values())
    raise InputError(f"unknown scenario {name!r}; use one of {known}")


def measures_bed_height(data) -> bool:
    """Whether a data set's values are heights above a printer's bed: its instrument says so
    (:attr:`~pkmcal.instruments.base.Instrument.measures_bed_height`); False for data of no
    instrument pkmcal knows.

    Parameters
    ----------
    data : object
        A data set (its ``kind`` names the instrument).

    Returns
    -------
    bool
        True for bed heights.
    """
    kind = getattr(data, "kind", None)
    try:
        return bool(kind) and instrument(kind).measures_bed_height
    except InputError:
        return False
