"""Simulated instrument measurements on any machine: the experiment of any instrument of the
registry (:func:`simulate_scenario`).

The experiment: the *nominal* model commands poses, the *true* machine goes elsewhere (its
forward kinematics of the commanded readings), and the instrument, with its true unknowns,
measures there with noise. The shared part lives in :mod:`pkmcal.instruments.experiment`; each
instrument simulates itself (:meth:`~pkmcal.instruments.base.Instrument.simulate`, in its own
module). The names below are kept here for their users.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..machines.base import Machine
from ..machines.reach import HALF_RANGE, MAX_ANGLE, sample_workspace_poses  # noqa: F401
from .distance import circle_plan  # noqa: F401
from .experiment import (  # noqa: F401
    MOUNTING_ERROR,
    circle_poses,
    simulate_instrument,
    true_machine,
)
from .probe import BED_ERROR, TILT_ERROR, probe_trigger  # noqa: F401
from .setups import Setups
from .tracker import planned_targets  # noqa: F401


def simulate_scenario(machine: Machine, scenario: str, n: int | None = None, noise=None,
                      rng=None, *, deviations="random", mounting_error: float = MOUNTING_ERROR,
                      poses=None, machine_setups: Setups | None = None, **options):
    """A simulated experiment: the true machine measured by an instrument of the registry.

    The true machine is ``machine`` plus ``deviations``; the nominal ``machine`` commands the
    poses; the instrument, with its true unknowns, measures the true machine there. What each
    instrument does is its :meth:`~pkmcal.instruments.base.Instrument.simulate` (in its own
    module: :mod:`~pkmcal.instruments.constraint_link`, :mod:`~pkmcal.instruments.tracker`,
    :mod:`~pkmcal.instruments.pose`, :mod:`~pkmcal.instruments.distance`,
    :mod:`~pkmcal.instruments.probe`, :mod:`~pkmcal.instruments.pairs`).

    Parameters
    ----------
    machine : Machine
        The nominal machine (not modified).
    scenario : str
        A name or alias of :mod:`pkmcal.instruments.registry`; it must apply to the machine.
    n : int, optional
        Number of measurements; default the instrument's plan size for the machine.
    noise : object, optional
        The instrument's noise model; None its default; False exact data.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed (deviations, poses, mounting errors, noise).
    deviations : str or array_like, optional
        ``"random"``, ``"none"``, ``"paper-table1"`` or a vector (true - nominal).
    mounting_error : float, optional
        Half-width of the uniform error of true targets, pivots and balls, m.
    poses : tuple, optional
        ``(P, R)`` or ``(P, R, group)``: commanded poses instead of random ones (tracker,
        distance, pose, probe).
    machine_setups : Setups, optional
        The machine file's set-ups (:func:`~pkmcal.io.load_machine_file`): the scenario
        instrument's is the start of the true one (a tracker's frame, a ballbar's
        mountings); default none.
    **options
        The instrument's own options (its ``simulate_options``): ``targets`` (tracker: number
        of targets), ``setups``, ``length``, ``circles`` (distance: ballbar mountings, length
        in m, ISO 230-4 circles), ``link_error`` (constraint-link: the file's length minus the
        true one, m), ``bed_error``, ``tilt_error`` (probe: half-widths of the true bed's
        height error, m, and slopes).

    Returns
    -------
    data : object
        The measurements: ``ConstraintLinkData``, ``FullPoseData`` or
        :class:`~pkmcal.instruments.InstrumentData` (with ``group`` the 0-based target / setup
        and the true poses).
    true_machine : Machine
        The true machine (a constraint link's true length: ``constraint_link_length``).
    truth : dict
        The instrument's truth and plan: ``scenario`` (canonical name), ``poses`` (words),
        ``rows`` (the truth in words, ``(name, text)`` pairs), ``setup`` (the true set-up of
        an instrument that has one: :class:`~pkmcal.instruments.tracker.TrackerSetup`,
        :class:`~pkmcal.instruments.pose.MeasurementFrames`,
        :class:`~pkmcal.instruments.distance.BallbarSetup`,
        :class:`~pkmcal.instruments.probe.BedSetup`), ``true_setups`` (a
        :class:`~pkmcal.instruments.setups.Setups`: the machine file's set-ups with the true
        one, what a truth file carries), and per instrument
        ``link_length``; ``base_from_tracker``, ``targets``, ``planned_targets``; ``frames``;
        ``setups``, ``planned_setups``, ``length``; ``bed`` (``(height, tilt_x, tilt_y)``).

    Raises
    ------
    InputError
        When the scenario does not apply to the machine (with the reason), an option does
        not apply to it, or the poses cannot be drawn or reached.
    """
    from .registry import INSTRUMENTS, instrument

    inst = instrument(scenario)
    why = inst.applies(machine)
    if why is not None:
        raise InputError(f"scenario {scenario}: does not apply to this "
                         f"{getattr(machine, 'kind', 'machine')}: {why}")
    name = inst.name
    rng = np.random.default_rng(rng)
    n = inst.plan_size_for(machine) if n is None else int(n)
    if n < 1:
        raise InputError(f"the number of measurements must be >= 1, got {n}")
    known = {k for other in INSTRUMENTS.values() for k in other.simulate_options}
    for key in options:
        if key not in known:
            raise TypeError(f"simulate_scenario() got an unexpected keyword argument {key!r}")
    for other in INSTRUMENTS.values():
        if other is not inst and any(k in options and options[k] != default
                                     for k, default in other.simulate_options.items()):
            raise InputError(f"{other.simulate_options_words}, not {name}")
    if not mounting_error >= 0:
        raise InputError(f"mounting_error: must be >= 0, got {mounting_error}")
    true = true_machine(machine, deviations, rng)
    own = {k: options.get(k, default) for k, default in inst.simulate_options.items()}
    setups = Setups(machine_setups)
    data, true, truth = inst.simulate(machine, true, n, noise, rng, {"scenario": name},
                                      setup=setups.get(name), poses=poses,
                                      mounting_error=mounting_error, **own)
    truth["true_setups"] = (setups.with_setup(name, truth["setup"]) if "setup" in truth
                            else setups)
    return data, true, truth
