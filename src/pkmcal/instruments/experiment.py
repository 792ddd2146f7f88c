"""The shared part of a simulated experiment, below every instrument: the commanded poses
measured on the true machine, circles of poses, the true machine and the noise choice.

The experiment: the *nominal* model commands poses, the *true* machine goes elsewhere (its
forward kinematics of the commanded readings), and the instrument, with its true unknowns,
measures there with noise. Each instrument simulates itself
(:meth:`~pkmcal.instruments.base.Instrument.simulate`) with these;
:func:`~pkmcal.instruments.simulate.simulate_scenario` runs one.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..machines.base import Machine
from .data import InstrumentData
from .models import NuisanceModel, NuisanceState

#: half-width of the random mounting error of simulated targets, pivots and balls, m
MOUNTING_ERROR = 1e-3


def circle_poses(machine: Machine, centre, radius: float, n: int, normal=(0.0, 0.0, 1.0)):
    """``n`` poses on a circle (a ballbar test, ISO 230-4), the platform at home orientation.

    Parameters
    ----------
    machine : Machine
        The machine (its home orientation is kept).
    centre : array_like, shape (3,)
        Centre of the circle (the ballbar's pivot), m.
    radius : float
        Radius, m.
    n : int
        Number of poses, equally spaced.
    normal : array_like, shape (3,), optional
        Normal of the circle's plane.

    Returns
    -------
    P : ndarray, shape (n, 3)
        Positions, m.
    R : ndarray, shape (n, 3, 3)
        Orientations.
    """
    nvec = np.asarray(normal, float)
    nvec = nvec / np.linalg.norm(nvec)
    a = np.cross(nvec, [1.0, 0.0, 0.0] if abs(nvec[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(nvec, a)
    t = 2 * np.pi * np.arange(n) / n
    P = np.asarray(centre, float) + radius * (np.cos(t)[:, None] * a + np.sin(t)[:, None] * b)
    return P, np.broadcast_to(machine.home[1], (n, 3, 3)).copy()


def simulate_instrument(true_machine: Machine, nominal_machine: Machine, model: NuisanceModel,
                        truth: NuisanceState, P, R, group=None, noise=None,
                        rng=None) -> InstrumentData:
    """Measurements of the true machine by an instrument at poses the nominal model commands.

    Parameters
    ----------
    true_machine : Machine
        The machine that moves.
    nominal_machine : Machine
        The model that computes the commanded readings (inverse kinematics of ``P, R``).
    model : NuisanceModel
        The instrument's model.
    truth : NuisanceState
        Its true unknowns (frame, targets, pivots).
    P : array_like, shape (K, 3)
        Commanded positions, m.
    R : array_like, shape (K, 3, 3)
        Commanded orientations.
    group : array_like of int, shape (K,), optional
        0-based target / setup of each row.
    noise : object, optional
        Has ``sample(values, rng)``; None: exact measurements.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.

    Returns
    -------
    InstrumentData
        Readings, measurements and the true poses.

    Raises
    ------
    InputError
        When the nominal model cannot reach a commanded pose or the true machine cannot reach
        the commanded readings.
    """
    rng = np.random.default_rng(rng)
    q = nominal_machine.ik(np.asarray(P, float), np.asarray(R, float))
    if not np.all(np.isfinite(q)):
        bad = np.flatnonzero(~np.all(np.isfinite(q), -1)) + 1
        raise InputError(f"poses {bad[:10].tolist()} are outside the nominal workspace")
    fk = true_machine.fk(q, start=(np.asarray(P, float), np.asarray(R, float)))
    if not fk.converged.all():
        raise InputError("the true machine cannot reach some commanded readings")
    group = np.zeros(len(q), int) if group is None else np.asarray(group, int)
    y = model.predict(truth, fk.P, fk.R, group)
    if noise is not None:
        y = y + noise.sample(y, rng)
    return InstrumentData(model.kind, q, y, group, source="<simulated>", true_P=fk.P,
                          true_R=fk.R)


def true_machine(machine: Machine, deviations, rng) -> Machine:
    """``machine`` plus deviations (a name of :func:`~pkmcal.machines.deviations.deviations`
    or a vector), every other attribute kept."""
    from ..machines.deviations import deviations as draw

    du = draw(machine, deviations, rng) if isinstance(deviations, str) else \
        np.asarray(deviations, float)
    if du.shape != (len(machine.parameters),):
        raise InputError(f"deviations: expected {len(machine.parameters)} values, got "
                         f"{du.shape}")
    return machine.with_parameters(machine.u + du)


def noise_model(noise, default):
    """The noise a simulation samples: ``default`` for None, none (exact data) for False,
    else ``noise`` as it is."""
    return default if noise is None else (None if noise is False else noise)


def given_poses(poses):
    """Commanded positions and orientations of a simulation's ``poses`` option
    (``(P, R)`` or ``(P, R, group)``) as arrays."""
    return np.asarray(poses[0], float), np.asarray(poses[1], float)


def mm_text(v) -> str:
    """``(x, y, z)`` in mm of a vector in m (a simulation's truth in words)."""
    return "(" + ", ".join(f"{x * 1e3:.6g}" for x in np.asarray(v, float)) + ")"
