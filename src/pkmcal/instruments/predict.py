"""What a calibrated machine's instrument measures for new joint readings (issue 13 item 3).

A calibration from points, poses or distances fits, beside the machine's parameters, the
instrument's own unknowns, and the calibrated machine file keeps them as the instrument's
set-up (:mod:`pkmcal.instruments.setups`, the loader's second value):

==============  ===========================  ===============================================
instrument      set-up (file section)        predicted measurement per reading
==============  ===========================  ===============================================
``tracker``     ``TrackerSetup``             ``mx, my, mz``: the target (column ``target``,
(points)        (``tracker``)                1..K) in the tracker frame
``pose``        ``MeasurementFrames``        ``x, y, z, qx, qy, qz, qw``: the marker pose in
(poses)         (``measurement_frames``)     the motion-capture frame
``distance``    ``BallbarSetup``             ``d``: the ballbar length of the mounting
(ballbar)       (``ballbar``)                (column ``setup``, 1..K)
``probe``       ``BedSetup`` (``bed``)       ``probe_z``: the nozzle's height above the bed
                                             plane (vertical)
==============  ===========================  ===============================================

The prediction is the forward kinematics of the readings followed by the instrument's own
model (:class:`~pkmcal.instruments.PointsModel`, :class:`~pkmcal.instruments.DistancesModel`,
:class:`~pkmcal.instruments.pose.MeasurementFrames`), the same models the calibration fitted: a
user checks a calibration by comparing new measurements with these predictions.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..machines.base import Machine
from .tracker import tracker_targets  # noqa: F401  (the tracker's targets, kept here)


def _sections() -> list:
    """The instruments a calibrated machine can carry (those with a machine-file section), in
    the order they are offered (the registry's)."""
    from .registry import INSTRUMENTS

    return [inst for inst in INSTRUMENTS.values() if inst.section is not None]


def instrument_name(name: str) -> str:
    """The canonical name of an instrument a calibrated machine can carry.

    Parameters
    ----------
    name : str
        ``tracker`` (``points``), ``pose`` (``poses``) or ``distance`` (``distances``,
        ``ballbar``).

    Returns
    -------
    str
        ``"tracker"``, ``"pose"`` or ``"distance"``.

    Raises
    ------
    InputError
        For another name, listing the known ones.
    """
    for inst in _sections():
        if name == inst.name or name in inst.aliases:
            return inst.name
    raise InputError(f"unknown instrument {name!r}; use one of "
                     f"{', '.join(inst.name for inst in _sections())}")


def fitted_instruments(machine: Machine, setups: Mapping) -> list[str]:
    """The instruments whose fitted unknowns a (calibrated) machine file carries.

    Parameters
    ----------
    machine : Machine
        The machine.
    setups : Setups
        Its set-ups (:func:`~pkmcal.io.load_machine_file`).

    Returns
    -------
    list of str
        Among ``"tracker"``, ``"pose"``, ``"distance"``, in that order.
    """
    return [inst.name for inst in _sections() if inst.carried_by(machine, setups.get(inst.name))]


def _where(machine: Machine) -> str:
    return str(getattr(machine, "source", "") or "the machine")


def choose_instrument(machine: Machine, setups: Mapping, instrument: str | None = None,
                      option: str = "instrument") -> str:
    """The instrument to predict for: the one asked for, or the only one the machine file
    carries.

    Parameters
    ----------
    machine : Machine
        A calibrated machine.
    setups : Setups
        Its set-ups.
    instrument : str, optional
        An instrument name or alias (:func:`instrument_name`); None: the machine must carry
        exactly one.
    option : str, optional
        The option that names the instrument, for messages (``instrument`` for the Python
        argument, ``--instrument`` on the command line).

    Returns
    -------
    str
        ``"tracker"``, ``"pose"`` or ``"distance"``.

    Raises
    ------
    InputError
        When the machine carries none (saying which calibration writes what), several and
        none is named (listing them), or not the one named.
    """
    have = fitted_instruments(machine, setups)
    where = _where(machine)
    if instrument is not None:
        name = instrument_name(instrument)
        if name not in have:
            from .registry import instrument as entry

            inst = entry(name)
            offered = (f"; it has: {', '.join(have)}" if have else
                       "; it has no instrument section")
            raise InputError(f"{option} {instrument}: {where} has no {inst.section} section "
                             f"({inst.section_words}){offered}")
        return name
    if not have:
        makers = "; ".join(inst.section_words for inst in _sections())
        raise InputError(f"{where} carries no instrument (no tracker, measurement_frames or "
                         f"ballbar section): {makers}; a constraint-link calibration measures "
                         "in no instrument frame")
    if len(have) > 1:
        raise InputError(f"{where} carries several instruments: name one with {option} "
                         f"({'|'.join(have)})")
    return have[0]


@dataclass
class InstrumentPrediction:
    """Predicted measurements of an instrument for joint readings.

    Attributes
    ----------
    instrument : str
        ``"tracker"``, ``"pose"`` or ``"distance"``.
    values : ndarray, shape (K, 3) or (K, 1)
        Tracker points (tracker frame), marker positions (motion-capture frame) or ballbar
        lengths, m; NaN where the forward kinematics failed.
    R : ndarray, shape (K, 3, 3) or None
        Marker orientations in the motion-capture frame (``pose``), else None.
    group : ndarray of int, shape (K,)
        0-based target / setup of each row (0 for poses).
    converged : ndarray of bool, shape (K,)
        Rows whose forward kinematics converged.
    fk : FKResult
        The forward kinematics of the readings (platform poses, base frame).
    """

    instrument: str
    values: np.ndarray
    R: np.ndarray | None
    group: np.ndarray
    converged: np.ndarray
    fk: object


def predict_instrument(machine: Machine, setups: Mapping, q, instrument: str | None = None,
                       group=None, rows=None, source: str | None = None,
                       start=None) -> InstrumentPrediction:
    """What the calibration's instrument measures for joint readings ``q``.

    Forward kinematics of ``q`` on ``machine``, then the instrument's model with the unknowns
    the calibration fitted (see the module docstring).

    Parameters
    ----------
    machine : Machine
        A calibrated machine.
    setups : Setups
        Its set-ups (the tracker's, the motion-capture frames, the ballbar's, the bed).
    q : array_like, shape (K, n_joints)
        Joint readings, internal units.
    instrument : str, optional
        ``tracker`` (``points``), ``pose`` (``poses``) or ``distance`` (``distances``,
        ``ballbar``); needed when the machine carries several.
    group : array_like of int, shape (K,), optional
        0-based target (tracker) or setup (distance) of each row; default 0.
    rows : array_like of int, shape (K,), optional
        File line numbers, for messages.
    source : str, optional
        The readings' file, for messages.
    start : tuple of ndarray, optional
        Start poses ``(P, R)`` of the forward kinematics; default home.

    Returns
    -------
    InstrumentPrediction
        The predicted measurements (NaN where the forward kinematics failed).

    Raises
    ------
    InputError
        When the machine carries no instrument, several and none is named, not the one named,
        or a target / setup number beyond those in the machine file.
    """
    from .registry import instrument as entry

    name = choose_instrument(machine, setups, instrument)
    setup = setups[name]
    entry(name).check_group_column(setup, group is not None, source)
    q = np.atleast_2d(np.asarray(q, float))
    K = len(q)
    group = np.zeros(K, int) if group is None else np.asarray(group, int).reshape(K)
    fk = machine.fk(q, start=start)
    ok = np.asarray(fk.converged, bool)
    P = np.where(ok[:, None], np.asarray(fk.P, float), 0.0)
    R = np.where(ok[:, None, None], np.asarray(fk.R, float), np.eye(3))

    values, Rm, group = entry(name).predict(machine, setup, P, R, ok, group, rows, source)
    values = np.where(ok[:, None], values, np.nan)
    return InstrumentPrediction(name, values, Rm, group, ok, fk)
