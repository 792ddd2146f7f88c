"""Measurement scenarios before any measurement: candidate poses and planned problems.

A *plan* is a set of platform poses at which a machine will be measured. From a plan and the
nominal machine we build exactly the calibration problem ``pkmcal calibrate`` would solve if
the measurements came back noise-free (readings from the nominal inverse kinematics, measured
points, poses or distances through the nominal instrument). Its scaled, whitened
identification Jacobian gives identifiability, the Cramer-Rao bound and the information each
pose adds (:mod:`pkmcal.planning.design`), all without a measurement.

A scenario is an instrument of the registry (:mod:`pkmcal.instruments.registry`):
``constraint-link`` (seed 000), ``tracker`` (``points``: laser tracker, CMM), ``pose``
(``poses``: motion capture) and ``distance`` (``distances``: a ballbar), each on every machine
it applies to. The functions here look the instrument up and ask it; none switches on a
machine or an instrument.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..machines.base import Machine
from .base import StandardPlan
from .constraint_link import SPHERE_TOL, link_length  # noqa: F401  (re-exported: plan checks)
from .pose import measurement_frames
from .registry import INSTRUMENTS, instrument
from .tracker import tracker_pose

__all__ = ["DEFAULT_PLAN_SIZE", "SCENARIOS", "STANDARD_PLANS", "StandardPlan",
           "candidate_poses", "candidate_set", "default_noise", "describe_noise",
           "measurement_frames", "planned_data", "planned_problem", "scenario_for",
           "scenario_problem", "standard_plan", "tracker_pose"]

#: every scenario (canonical names; aliases are accepted by :func:`scenario_for`)
SCENARIOS = tuple(INSTRUMENTS)
#: default plan sizes (seed 000: 150 poses; seed 001: a 3x3x3 grid; SPEC 2.4: 60 poses)
DEFAULT_PLAN_SIZE = {name: inst.plan_size for name, inst in INSTRUMENTS.items()}


def scenario_for(machine: Machine, scenario: str | None = None) -> str:
    """The scenario of ``machine``: the requested one when it applies, else its default.

    Parameters
    ----------
    machine : Machine
        The machine.
    scenario : str, optional
        A requested scenario (a name or alias of :mod:`pkmcal.instruments.registry`).

    Returns
    -------
    str
        The canonical scenario name.

    Raises
    ------
    InputError
        When the scenario is unknown or does not apply to the machine (with the reason), or
        the machine has no default.
    """
    if scenario is None:
        name = getattr(machine, "default_instrument", None)   # the machine's own (paper's)
        if name is None:
            raise InputError(f"no measurement scenario for machines of type "
                             f"{getattr(machine, 'kind', '')!r}")
        return name
    inst = instrument(scenario)
    why = inst.applies(machine)
    if why is not None:
        raise InputError(f"--scenario {scenario}: does not apply to this "
                         f"{getattr(machine, 'kind', 'machine')}: {why}")
    return inst.name


def default_noise(scenario: str):
    """The default noise model of a scenario (as ``pkmcal calibrate`` assumes).

    Parameters
    ----------
    scenario : str
        The scenario.

    Returns
    -------
    object
        Encoder noise 1e-6 m (constraint link), ``TrackerNoise``, ``FullPoseNoise`` or the
        ballbar's ``IsotropicNoise``.
    """
    return instrument(scenario).default_noise()


def describe_noise(scenario: str, noise) -> str:
    """The noise model in words, for reports.

    Parameters
    ----------
    scenario : str
        The scenario.
    noise : object
        The noise model of that scenario (:func:`default_noise`).

    Returns
    -------
    str
        One line, values in um and urad.
    """
    return instrument(scenario).describe_noise(noise)


def _standard_plan_entry(name):
    return lambda machine, n, seed, setup=None: INSTRUMENTS[name].standard_plan(machine, n, seed,
                                                                                setup)


#: the standard plan of each scenario: ``(machine, n, seed, setup=None) -> StandardPlan``
STANDARD_PLANS = {name: _standard_plan_entry(name) for name in INSTRUMENTS}


def standard_plan(machine: Machine, scenario: str, n: int | None = None,
                  seed: int = 0, setup=None) -> StandardPlan:
    """The instrument's standard plan of ``n`` poses: what ``pkmcal identifiability`` analyses
    without data, and what ``pkmcal select-poses`` compares with and starts from.

    A machine may define its own (a method ``standard_plan(scenario, n, seed)`` returning a
    :class:`StandardPlan`); otherwise the instrument's: tracker on a translating platform,
    seed 001's 3x3x3 grid (k x k x k grids in the same box for ``n = k^3``, none for other
    ``n``); distance, a ballbar on three mountings; the others, the simulations' default sample of
    ``n`` feasible poses (``seed``).

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    scenario : str
        The scenario.
    n : int, optional
        Number of poses; default :data:`DEFAULT_PLAN_SIZE` of the scenario.
    seed : int, optional
        Seed of sampled plans.
    setup : object, optional
        The instrument's set-up (a tracker's frame, a ballbar's mountings:
        :mod:`pkmcal.instruments.setups`); default the planning one.

    Returns
    -------
    StandardPlan
        The plan, or (``available`` false) the reason there is none of ``n`` poses.

    Raises
    ------
    InputError
        For an unknown scenario, ``n < 1``, or when a sampled plan finds too few feasible
        poses.
    """
    inst = instrument(scenario)
    n = inst.plan_size_for(machine) if n is None else int(n)
    if n < 1:
        raise InputError(f"the number of planned poses must be >= 1, got {n}")
    own = getattr(machine, "standard_plan", None)
    if callable(own):
        return own(inst.name, n, seed)
    return inst.standard_plan(machine, n, seed, setup)


def candidate_set(machine: Machine, scenario: str, n: int, rng=None, setup=None):
    """``n`` feasible candidate poses of a scenario, with their setups.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    scenario : str
        The scenario.
    n : int
        Number of poses (>= 1).
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.
    setup : object, optional
        The instrument's set-up (a tracker's frame, a ballbar's mountings:
        :mod:`pkmcal.instruments.setups`); default the planning one.

    Returns
    -------
    P : ndarray, shape (n, 3)
        Positions, m.
    R : ndarray, shape (n, 3, 3)
        Orientations.
    group : ndarray of int, shape (n,) or None
        0-based setup of each pose (ballbar mountings), None for one.

    Raises
    ------
    InputError
        When ``n < 1`` or not enough feasible poses are found.
    """
    if n < 1:
        raise InputError(f"the number of candidate poses must be >= 1, got {n}")
    inst = instrument(scenario)
    return inst.candidates(machine, n, np.random.default_rng(rng), setup)


def candidate_poses(machine: Machine, scenario: str, n: int, rng=None, setup=None):
    """``n`` feasible candidate poses of a scenario (:func:`candidate_set` without setups).

    constraint-link: the sphere ``|P| = Lc`` (cap of 35 deg around home, rotations within
    +/-25 deg); tracker: uniform in the box of seed 001's grid on translating platforms, else
    the workspace around home with rotations; pose: the workspace around home with rotations;
    distance: spheres of the ballbar length around the planned pivots.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    scenario : str
        The scenario.
    n : int
        Number of poses (>= 1).
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.
    setup : object, optional
        The instrument's set-up (a tracker's frame, a ballbar's mountings:
        :mod:`pkmcal.instruments.setups`); default the planning one.

    Returns
    -------
    P : ndarray, shape (n, 3)
        Positions, m.
    R : ndarray, shape (n, 3, 3)
        Orientations.

    Raises
    ------
    InputError
        When ``n < 1``, a constraint-link machine has no link length, or not enough feasible
        poses are found.
    """
    P, R, _ = candidate_set(machine, scenario, n, rng, setup)
    return P, R


def planned_data(machine: Machine, scenario: str, P, R=None, rows=None, source="<plan>",
                 group=None, setup=None):
    """Noise-free measurements of the *nominal* machine at planned poses.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    scenario : str
        The scenario.
    P : array_like, shape (K, 3)
        Planned positions, m.
    R : array_like, shape (K, 3, 3), optional
        Planned orientations; default identity.
    rows : array_like of int, optional
        Row labels for messages; default 1..K.
    source : str, optional
        Name of the plan, for messages.
    group : array_like of int, shape (K,), optional
        0-based target / setup of each pose.
    setup : object, optional
        The instrument's set-up (a tracker's frame, a ballbar's mountings:
        :mod:`pkmcal.instruments.setups`); default the planning one.

    Returns
    -------
    object
        The data of the scenario, with the planned poses as the true ones.

    Raises
    ------
    InputError
        Naming ``rows``, for poses the machine cannot reach and for constraint-link plans off
        the sphere ``|P| = Lc`` by more than :data:`SPHERE_TOL`.
    """
    P = np.atleast_2d(np.asarray(P, float))
    R = np.broadcast_to(np.eye(3), (len(P), 3, 3)) if R is None else np.asarray(R, float)
    rows = np.arange(1, len(P) + 1) if rows is None else np.asarray(rows)
    inst = instrument(scenario)
    return inst.planned_data(machine, P, R, rows, source, group, setup)


def scenario_problem(machine: Machine, scenario: str, data, noise=None, registration=None,
                     frames=None, setup=None):
    """The calibration problem ``pkmcal calibrate`` solves by default for ``data``, unsolved.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    scenario : str
        The scenario.
    data : object
        The measurements.
    noise : object, optional
        Noise model; default :func:`default_noise`.
    registration : tuple of ndarray, optional
        Tracker: start ``base_from_tracker``; default :func:`tracker_pose`.
    frames : MeasurementFrames, optional
        Pose: start frames; default :func:`measurement_frames`.
    setup : object, optional
        The instrument's set-up (a tracker's frame, a ballbar's mountings:
        :mod:`pkmcal.instruments.setups`); default the planning one.

    Returns
    -------
    BlockProblem
        The problem.

    Raises
    ------
    InputError
        When the problem cannot be set up for these data.
    """
    start = {k: v for k, v in (("registration", registration), ("frames", frames))
             if v is not None}
    inst = instrument(scenario)
    return inst.problem(machine, data, noise, setup=setup, **start)


def planned_problem(machine: Machine, scenario: str, P, R=None, noise=None, rows=None,
                    source="<plan>", group=None, setup=None):
    """:func:`scenario_problem` of the noise-free :func:`planned_data` at poses ``(P, R)``.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    scenario : str
        The scenario.
    P : array_like, shape (K, 3)
        Planned positions, m.
    R : array_like, shape (K, 3, 3), optional
        Planned orientations; default identity.
    noise : object, optional
        Noise model; default :func:`default_noise`.
    rows : array_like of int, optional
        Row labels for messages.
    source : str, optional
        Name of the plan, for messages.
    group : array_like of int, shape (K,), optional
        0-based target / setup of each pose.
    setup : object, optional
        The instrument's set-up (a tracker's frame, a ballbar's mountings:
        :mod:`pkmcal.instruments.setups`); default the planning one.

    Returns
    -------
    BlockProblem
        The problem.

    Raises
    ------
    InputError
        As :func:`planned_data` and :func:`scenario_problem`.
    """
    return scenario_problem(machine, scenario,
                            planned_data(machine, scenario, P, R, rows, source, group, setup),
                            noise, setup=setup)
