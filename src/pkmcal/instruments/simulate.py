"""Simulated instrument measurements on any machine: workspace poses, circles, the experiment.

The experiment: the *nominal* model commands poses, the *true* machine goes elsewhere (its
forward kinematics of the commanded readings), and the instrument, with its true unknowns,
measures there with noise.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..machines.base import Machine
from ..machines.reach import HALF_RANGE, MAX_ANGLE, sample_workspace_poses  # noqa: F401
from .data import InstrumentData
from .models import NuisanceModel, NuisanceState


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


# -- a whole simulated experiment of any instrument on any machine ---------------------------

#: half-width of the random mounting error of simulated targets, pivots and balls, m
MOUNTING_ERROR = 1e-3
#: half-width of the random error of a simulated bed's height, m
BED_ERROR = 1e-3
#: half-width of a simulated bed's random slopes dz/dx, dz/dy (1 mm over a metre)
TILT_ERROR = 1e-3


def planned_targets(machine: Machine, n_targets: int = 1) -> np.ndarray:
    """Planned places of ``n_targets`` tracker targets (reflector nests) on the platform.

    The machine's own target when its file gives one (a Delta's ``smr_offset``; then only one
    target makes sense); else target 1 at
    :func:`~pkmcal.instruments.tracker.plan_target` and the others turned about the platform
    z axis by ``360 deg g / n_targets``.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    n_targets : int, optional
        Number of targets (>= 1).

    Returns
    -------
    ndarray, shape (n_targets, 3)
        Places in the platform frame, m.

    Raises
    ------
    InputError
        When ``n_targets < 1``, or several targets are asked for on a machine whose file
        gives the target's place.
    """
    from .tracker import plan_target

    n_targets = int(n_targets)
    if n_targets < 1:
        raise InputError(f"the number of targets must be >= 1, got {n_targets}")
    known = machine.tracker_target()
    if known is not None:
        if n_targets > 1:
            raise InputError(f"{getattr(machine, 'source', None) or 'the machine file'} gives "
                             "the target's place on the platform (e.g. a Delta's "
                             "smr_offset): one target only")
        return np.asarray(known, float)[None, :]
    c = plan_target(machine)
    t = 2 * np.pi * np.arange(n_targets) / n_targets
    return np.column_stack([np.cos(t) * c[0] - np.sin(t) * c[1],
                            np.sin(t) * c[0] + np.cos(t) * c[1], np.full(n_targets, c[2])])


def circle_plan(machine: Machine, n: int, setups=None):
    """ISO 230-4 style ballbar circles, one per setup, the platform at its home orientation.

    For setup ``g`` (pivot ``p``, ball ``b``, ballbar length ``L = |home + R0 b - p|``) the ball
    runs on the circle of radius ``L sin 45 deg`` about the pivot's direction to home, ``L cos
    45 deg`` above the pivot; the ``n`` poses are shared out among the setups in turn.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    n : int
        Number of poses (at least 3 per setup).
    setups : list of tuple, optional
        ``[(pivot, ball), ...]``; default
        :func:`~pkmcal.instruments.distance.ballbar_setups` of the machine.

    Returns
    -------
    P : ndarray, shape (n, 3)
        Positions, m.
    R : ndarray, shape (n, 3, 3)
        Orientations.
    group : ndarray of int, shape (n,)
        0-based setup of each pose.

    Raises
    ------
    InputError
        When there are fewer than 3 poses per setup or the machine cannot reach a pose.
    """
    from .distance import ballbar_setups

    if setups is None:
        pivots, balls = ballbar_setups(machine)
    else:
        pivots = np.array([np.asarray(p, float) for p, _ in setups])
        balls = np.array([np.asarray(b, float) for _, b in setups])
    k = len(pivots)
    if n < 3 * k:
        raise InputError(f"{k} ballbar circles need at least {3 * k} poses, got {n}")
    P0, R0 = machine.home
    Ps, Rs, gs = [], [], []
    for g in range(k):
        m = n // k + (1 if g < n % k else 0)
        arm = P0 + R0 @ balls[g] - pivots[g]
        L = np.linalg.norm(arm)
        normal = arm / L
        h = L * np.cos(np.deg2rad(45.0))
        P, R = circle_poses(machine, pivots[g] + h * normal, h, m, normal)
        Ps.append(P - np.einsum("kij,j->ki", R, balls[g]))
        Rs.append(R)
        gs.append(np.full(m, g))
    P, R, group = np.concatenate(Ps), np.concatenate(Rs), np.concatenate(gs)
    with np.errstate(all="ignore"):
        ok = np.all(np.isfinite(machine.ik(P, R)), -1) & machine.working_mode(P, R)
    if not ok.all():
        bad = np.flatnonzero(~ok)
        raise InputError(f"ballbar circle {group[bad[0]] + 1}: {bad.size} of its poses are out "
                         "of the machine's reach (e.g. at ("
                         + ", ".join(f"{v * 1e3:.6g}" for v in P[bad[0]]) + ") mm); use a "
                         "shorter ballbar or fewer setups")
    return P, R, group


def _true_machine(machine: Machine, deviations, rng) -> Machine:
    """``machine`` plus deviations (a name of :func:`~pkmcal.machines.deviations.deviations`
    or a vector), every other attribute kept."""
    from ..machines.deviations import deviations as draw

    du = draw(machine, deviations, rng) if isinstance(deviations, str) else \
        np.asarray(deviations, float)
    if du.shape != (len(machine.parameters),):
        raise InputError(f"deviations: expected {len(machine.parameters)} values, got "
                         f"{du.shape}")
    return machine.with_parameters(machine.u + du)


def simulate_scenario(machine: Machine, scenario: str, n: int | None = None, noise=None,
                      rng=None, *, deviations="random", targets: int = 1, setups=None,
                      length: float | None = None, circles: bool = False,
                      mounting_error: float = MOUNTING_ERROR, link_error: float = 0.0,
                      poses=None, bed_error: float = BED_ERROR, tilt_error: float = TILT_ERROR):
    """A simulated experiment: the true machine measured by an instrument of the registry.

    The true machine is ``machine`` plus ``deviations``; the nominal ``machine`` commands the
    poses; the instrument, with its true unknowns, measures the true machine there:

    - ``constraint-link``: :func:`~pkmcal.instruments.constraint_link.simulate_constraint_link` on
      the sphere of the true link (the file's length minus ``link_error``); ``noise`` encoder std
      (m, default 1 um).
    - ``tracker`` (``points``): ``n`` random workspace poses (registry candidates: rotations
      on platforms that rotate), or ``poses``; ``targets`` targets, rows cycling through them;
      the tracker at the machine file's ``base_from_tracker`` (else the simulations'
      default); true target places = planned (:func:`planned_targets`) + a uniform error of
      ``mounting_error`` per coordinate (the file's target when it gives one). ``noise`` a
      tracker noise model (default ``TrackerNoise()``; None-valued noise: pass
      ``noise=False`` for exact data).
    - ``pose`` (``poses``): :func:`~pkmcal.instruments.pose.simulate_full_pose` at ``n`` random
      poses, through the machine file's ``measurement_frames`` (else the default);
      ``noise`` a ``FullPoseNoise``.
    - ``distance`` (``distances``): ``setups`` mountings of a ballbar of ``length`` (the
      machine's ``ballbar_setups`` when neither is given, else
      :func:`~pkmcal.instruments.distance.planned_ballbar_setups`, 3 and 100 mm by default);
      ``n`` poses on the spheres around the pivots (registry candidates) or, with
      ``circles``, ISO 230-4 circles (:func:`circle_plan`); true pivots and balls = planned +
      a uniform error of ``mounting_error``; ``noise`` an ``IsotropicNoise`` (default 1 um).
    - ``probe`` (``probe-heights``, ``bed-probe``): the standard probe pattern of ``n`` points
      when there is one (:func:`~pkmcal.instruments.probe.probe_pattern`: 7 = Klipper's
      DELTA_CALIBRATE, 19, 37, ...), else ``n`` random points on the bed's disk, or ``poses``;
      the true bed is the nominal one (:func:`~pkmcal.machines.reach.bed_height`)
      raised by a uniform ``+/- bed_error`` and tilted by uniform slopes ``+/- tilt_error``.
      Each point is probed as a firmware does: the nominal model moves the nozzle down the
      vertical through the point until the true machine's nozzle is at the probe's trigger
      height (0 plus the trigger noise, ``noise`` an ``IsotropicNoise``, default 10 um)
      above the true bed; the readings there are recorded with ``probe_z = 0``.

    Parameters
    ----------
    machine : Machine
        The nominal machine (not modified).
    scenario : str
        A name or alias of :mod:`pkmcal.instruments.registry`; it must apply to the machine.
    n : int, optional
        Number of measurements; default the instrument's plan size for the machine.
    noise : object, optional
        The instrument's noise model (see above); None its default; False exact data.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed (deviations, poses, mounting errors, noise).
    deviations : str or array_like, optional
        ``"random"``, ``"none"``, ``"paper-table1"`` or a vector (true - nominal).
    targets : int, optional
        tracker: number of targets.
    setups : int, optional
        distance: number of ballbar mountings (default 3).
    length : float, optional
        distance: ballbar length, m (default
        :data:`~pkmcal.instruments.distance.BALLBAR_LENGTH`).
    circles : bool, optional
        distance: ISO 230-4 circles instead of poses on the spheres.
    mounting_error : float, optional
        Half-width of the uniform error of true targets, pivots and balls, m.
    link_error : float, optional
        constraint-link: the file's length minus the true one, m.
    poses : tuple, optional
        ``(P, R)`` or ``(P, R, group)``: commanded poses instead of random ones (tracker,
        distance, pose).
    bed_error : float, optional
        probe: half-width of the uniform error of the true bed's height, m.
    tilt_error : float, optional
        probe: half-width of the uniform true bed slopes dz/dx, dz/dy.

    Returns
    -------
    data : object
        The measurements: ``ConstraintLinkData``, ``FullPoseData`` or
        :class:`~pkmcal.instruments.InstrumentData` (``points`` / ``distances``, with
        ``group`` the 0-based target / setup and the true poses).
    true_machine : Machine
        The true machine, carrying its true instrument: ``constraint_link_length``,
        ``base_from_tracker`` and ``tracker_targets`` (None when the file gives the target),
        ``measurement_frames`` or ``ballbar_setups`` (``[(pivot, ball), ...]``).
    truth : dict
        The instrument's truth and plan in words: ``scenario`` (canonical name), ``poses``
        (words), and per scenario ``link_length``; ``base_from_tracker``, ``targets``,
        ``planned_targets``; ``frames``; ``setups``, ``planned_setups``, ``length``; ``bed``
        (``(height, tilt_x, tilt_y)`` of the true bed, also the true machine's ``probe_bed``).

    Raises
    ------
    InputError
        When the scenario does not apply to the machine (with the reason), an option does
        not apply to it, or the poses cannot be drawn or reached.
    """
    from .distance import BALLBAR_LENGTH, planned_ballbar_setups
    from .pose import measurement_frames
    from .registry import instrument
    from .tracker import tracker_pose

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
    if name != "tracker" and int(targets) != 1:
        raise InputError(f"targets: apply to the tracker (points) scenario, not {name}")
    if name != "distance" and (setups is not None or length is not None or circles):
        raise InputError(f"setups, length and circles: apply to the distance scenario, not "
                         f"{name}")
    if name != "probe" and (bed_error != BED_ERROR or tilt_error != TILT_ERROR):
        raise InputError(f"bed_error and tilt_error: apply to the probe scenario, not {name}")
    if not (bed_error >= 0 and tilt_error >= 0):
        raise InputError(f"bed_error and tilt_error: must be >= 0, got {bed_error}, "
                         f"{tilt_error}")
    if name != "constraint-link" and link_error:
        raise InputError(f"link_error: applies to the constraint-link scenario, not {name}")
    if not mounting_error >= 0:
        raise InputError(f"mounting_error: must be >= 0, got {mounting_error}")
    true = _true_machine(machine, deviations, rng)
    truth: dict = {"scenario": name}
    own = getattr(inst, "simulate", None)
    if callable(own):           # an instrument that simulates itself
        return own(machine, true, n, noise, rng, truth)

    if name == "constraint-link":
        from .constraint_link import simulate_constraint_link

        Lc = float(machine.constraint_link_length) - float(link_error)
        if not Lc > 0:
            raise InputError(f"link_error: the true link length {Lc * 1e3:.6g} mm is not "
                             "positive")
        true.constraint_link_length = Lc
        sigma = 1e-6 if noise is None else (0.0 if noise is False else float(noise))
        data = simulate_constraint_link(true, n, sigma, link_length=Lc,
                                        link_length_error=float(link_error), rng=rng)
        truth.update(link_length=Lc, poses=f"{n} poses on the true link's sphere |P| = "
                     f"{Lc * 1e3:.6g} mm")
        return data, true, truth

    if name == "pose":
        from .pose import FullPoseNoise, simulate_full_pose

        frames = measurement_frames(machine)
        true.measurement_frames = frames
        model = FullPoseNoise() if noise is None else (None if noise is False else noise)
        if poses is None:
            poses = sample_workspace_poses(true, n, rng)
            words = (f"{n} random poses in the 0.1 m cube around home, Euler angles within "
                     "+/-10 deg")
        else:
            poses = (np.asarray(poses[0], float), np.asarray(poses[1], float))
            words = f"{len(poses[0])} given poses"
        data = simulate_full_pose(true, poses, frames, model, rng)
        truth.update(frames=frames, poses=words)
        return data, true, truth

    if name == "tracker":
        from .models import PointsModel
        from .tracker import TrackerNoise

        k = int(targets)
        planned = planned_targets(machine, k)
        known = machine.tracker_target() is not None
        c = planned if known else planned + rng.uniform(-mounting_error, mounting_error,
                                                        planned.shape)
        Rt, t = tracker_pose(machine)
        model = PointsModel(k, machine.tracker_target())
        state = model.initial()
        state.rotations = [np.asarray(Rt, float)]
        state.values[3:6] = t
        if not known:
            state.values[model._it.ravel()] = c.ravel()
        if poses is None:
            P, R, _ = inst.candidates(machine, n, rng)
            words = (f"{n} random workspace poses around home"
                     + (" with rotations within +/-10 deg" if machine.rotates else ""))
        else:
            P, R = np.asarray(poses[0], float), np.asarray(poses[1], float)
            words = f"{len(P)} given poses"
        group = np.arange(len(P)) % k
        model_noise = TrackerNoise() if noise is None else (None if noise is False else noise)
        data = simulate_instrument(true, machine, model, state, P, R, group, model_noise, rng)
        true.base_from_tracker = (np.asarray(Rt, float), np.asarray(t, float))
        true.tracker_targets = None if known else c
        truth.update(base_from_tracker=true.base_from_tracker, targets=c,
                     planned_targets=planned, poses=words)
        return data, true, truth

    if name == "probe":
        return _simulate_probe(machine, true, inst, n, noise, rng, poses, bed_error,
                               tilt_error, truth)

    # distance
    from .models import DistancesModel, IsotropicNoise

    if setups is None and length is None and getattr(machine, "ballbar_setups", None):
        plan = [(np.asarray(p, float), np.asarray(b, float)) for p, b in machine.ballbar_setups]
    else:
        plan = planned_ballbar_setups(machine, 3 if setups is None else int(setups),
                                      BALLBAR_LENGTH if length is None else float(length))
    nominal = machine.with_parameters(machine.u)
    nominal.ballbar_setups = plan
    k = len(plan)
    if poses is not None:
        P, R = np.asarray(poses[0], float), np.asarray(poses[1], float)
        group = (np.arange(len(P)) % k if len(poses) < 3 or poses[2] is None
                 else np.asarray(poses[2], int))
        words = f"{len(P)} given poses"
    elif circles:
        P, R, group = circle_plan(nominal, n, plan)
        words = f"{k} ISO 230-4 circle(s), {n} poses"
    else:
        P, R, group = inst.candidates(nominal, n, rng)
        words = (f"{n} random poses on the spheres around the {k} pivot(s)"
                 + (" with rotations within +/-10 deg" if machine.rotates else ""))
    true_setups = [(p + rng.uniform(-mounting_error, mounting_error, 3),
                    b + rng.uniform(-mounting_error, mounting_error, 3)) for p, b in plan]
    model = DistancesModel(k)
    state = model.initial()
    for g, (p, b) in enumerate(true_setups):
        state.values[model._ip[g]] = p
        state.values[model._ib[g]] = b
    model_noise = IsotropicNoise(1e-6) if noise is None else (None if noise is False else noise)
    data = simulate_instrument(true, machine, model, state, P, R, group, model_noise, rng)
    true.ballbar_setups = true_setups
    P0, R0 = machine.home
    L = [float(np.linalg.norm(P0 + R0 @ b - p)) for p, b in plan]
    truth.update(setups=true_setups, planned_setups=plan, length=L, poses=words)
    return data, true, truth


def probe_trigger(true_machine: Machine, nominal_machine: Machine, P, R, bed, heights,
                  tip=None, tol: float = 1e-13, max_iter: int = 50):
    """Readings at which a probe triggers: the nominal model lowers the nozzle along the
    vertical through each commanded point until the true machine's nozzle tip is ``heights``
    above the true bed (vertically).

    Parameters
    ----------
    true_machine : Machine
        The machine that moves.
    nominal_machine : Machine
        The model that commands (inverse kinematics).
    P : array_like, shape (K, 3)
        Commanded points (their x, y; z the start of the search), m.
    R : array_like, shape (K, 3, 3)
        Commanded orientations (kept).
    bed : array_like, shape (3,)
        True bed ``(height, tilt_x, tilt_y)`` (:class:`~pkmcal.instruments.ProbeModel`).
    heights : array_like, shape (K,)
        True heights of the tip at the trigger, m.
    tip : array_like, shape (3,), optional
        The nozzle tip on the platform, m; default the platform origin.
    tol : float, optional
        Tolerance on the height, m.
    max_iter : int, optional
        Largest number of steps.

    Returns
    -------
    q : ndarray, shape (K, n_joints)
        Readings at the trigger.
    fk : FKResult
        The true machine's poses there.

    Raises
    ------
    InputError
        When a point cannot be reached or the search does not converge.
    """
    from .models import ProbeModel

    model = ProbeModel(tip)
    state = model.initial()
    state.values[:] = np.asarray(bed, float)
    P = np.array(P, float)
    R = np.asarray(R, float)
    heights = np.asarray(heights, float)
    zero = np.zeros(len(P), int)
    for _ in range(max_iter):
        q = nominal_machine.ik(P, R)
        if not np.all(np.isfinite(q)):
            bad = np.flatnonzero(~np.all(np.isfinite(q), -1)) + 1
            raise InputError(f"probe points {bad[:10].tolist()}: the nominal model cannot "
                             "reach them on the way down to the bed")
        fk = true_machine.fk(q, start=(P, R))
        if not fk.converged.all():
            raise InputError("the true machine cannot reach some probe readings")
        # the height changes with the commanded z at a rate of about 1: Newton with slope 1
        miss = model.predict(state, fk.P, fk.R, zero)[:, 0] - heights
        if np.max(np.abs(miss)) <= tol:
            return q, fk
        P[:, 2] -= miss
    raise InputError(f"the probe search did not converge to {tol * 1e3:g} mm in {max_iter} "
                     "steps: the true machine's heights do not follow the commanded ones")


def _simulate_probe(machine, true, inst, n, noise, rng, poses, bed_error, tilt_error, truth):
    """The probe branch of :func:`simulate_scenario` (see there)."""
    from ..machines.reach import bed_height

    if poses is not None:
        P, R = np.asarray(poses[0], float), np.asarray(poses[1], float)
        words = f"{len(P)} given points"
    else:
        plan = inst.standard_plan(machine, n, 0)
        if plan.available:
            P, R, words = plan.P, plan.R, f"{n} points: {plan.name}"
        else:
            P, R, _ = inst.candidates(machine, n, rng)
            words = f"{n} random points on the bed's disk"
    bed = np.array([bed_height(machine) + rng.uniform(-bed_error, bed_error),
                    *rng.uniform(-tilt_error, tilt_error, 2)])
    model = inst.default_noise() if noise is None else (None if noise is False else noise)
    eps = np.zeros((len(P), 1)) if model is None else model.sample(np.zeros((len(P), 1)), rng)
    q, fk = probe_trigger(true, machine, P, R, bed, eps[:, 0])
    data = InstrumentData("probe", q, np.zeros((len(P), 1)), None, source="<simulated>",
                          true_P=fk.P, true_R=fk.R)
    true.probe_bed = tuple(float(v) for v in bed)
    truth.update(bed=true.probe_bed, poses=words)
    return data, true, truth
