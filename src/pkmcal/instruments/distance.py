"""The ballbar: lengths between a pivot on the base and a ball on the platform (ISO 230-4
circles), its set-ups, plans and calibration.

Calibration from ballbar distances (a pivot on the base, a ball on the platform).

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

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..errors import InputError
from ..estimation.estimator import CalibrationResult
from ..estimation.rank import RTOL
from ..estimation.sections import Section
from ..machines.base import Machine
from ..machines.file_format import Ballbar, vector
from ..paths import path_text
from .base import (
    Instrument,
    StandardPlan,
    _check_groups,
    _fk_of,
    _sigma_arg,
    _simulated_sigma,
    _space_words,
    has_column,
    reachable,
)
from .data import InstrumentData
from .experiment import MOUNTING_ERROR, circle_poses
from .flow import (
    FlowContext,
    FlowResult,
    JointPart,
    convergence_json,
    fit_with_baseline,
    identifiability_json,
    load_data,
    option,
    public_parameters,
    scalar_metadata,
    scalar_residuals_json,
    scalar_rms,
    validation_section,
)
from .models import DistancesModel, IsotropicNoise
from .problem import InstrumentProblem, fit_instrument

#: the ballbar length of plans and simulations, m (a common measuring-ballbar length)
BALLBAR_LENGTH = 0.1


@dataclass(frozen=True)
class BallbarSetup:
    """A ballbar's set-up (the machine file's ``ballbar:`` section): one mounting per value
    1..K of a data file's ``setup`` column.

    Attributes
    ----------
    mountings : tuple of tuple
        ``((pivot (3,) base frame, ball (3,) platform frame), ...)``, m.
    """

    mountings: tuple

    def __post_init__(self):
        object.__setattr__(self, "mountings", tuple(
            (np.asarray(p, float), np.asarray(b, float)) for p, b in self.mountings))

    def __len__(self) -> int:
        return len(self.mountings)

    def __iter__(self):
        return iter(self.mountings)

    def shifted(self, t) -> BallbarSetup:
        """The set-up seen from a base frame whose points moved by ``t`` (m)."""
        return BallbarSetup([(p + np.asarray(t, float), b) for p, b in self.mountings])

    def frame_shift(self, machine):
        """None: a ballbar says nothing about the machine's frame."""
        return None

    def targets_in_base(self, machine, P):
        """``P`` itself: targets are not given relative to a ballbar."""
        return P

    def targets_from_base(self, machine, P):
        """``P`` itself: the inverse of :meth:`targets_in_base`."""
        return P


#: setups of a distance plan: the circle planes of ISO 230-4 tests (normals)
CIRCLE_NORMALS = ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0))


def setup_normals(n_setups: int) -> np.ndarray:
    """Directions from the pivots to home of ``n_setups`` planned ballbar mountings.

    The first three are the normals of the ISO 230-4 circle planes (:data:`CIRCLE_NORMALS`:
    z, y, x), the next four the diagonals of the upper half space, further ones spread over
    the upper hemisphere (a Fibonacci lattice).

    Parameters
    ----------
    n_setups : int
        Number of mountings (>= 1).

    Returns
    -------
    ndarray, shape (n_setups, 3)
        Unit vectors.
    """
    base = [np.asarray(v, float) for v in CIRCLE_NORMALS]
    base += [np.array([sx, sy, 1.0]) / np.sqrt(3.0) for sx, sy in ((1, 1), (-1, 1), (-1, -1),
                                                                    (1, -1))]
    extra = max(0, n_setups - len(base))
    for k in range(extra):
        z = 1.0 - (k + 0.5) / extra * 0.8                       # z in (0.2, 1)
        phi = k * np.pi * (3.0 - np.sqrt(5.0))
        r = np.sqrt(1.0 - z * z)
        base.append(np.array([r * np.cos(phi), r * np.sin(phi), z]))
    return np.array(base[:n_setups])


def planned_ballbar_setups(machine: Machine, n_setups: int = 3,
                           length: float = BALLBAR_LENGTH) -> list:
    """The planned ballbar mountings: pivots ``length`` from home, balls at the platform origin.

    The pivot of setup ``g`` stands ``length`` from the home position against the ``g``-th
    direction of :func:`setup_normals`, so the ball at the platform origin, on a ballbar of
    ``length``, sweeps a sphere through home.

    Parameters
    ----------
    machine : Machine
        The nominal machine (its home).
    n_setups : int, optional
        Number of mountings.
    length : float, optional
        Ballbar length, m.

    Returns
    -------
    list of tuple
        ``[(pivot (3,) base frame, ball (3,) platform frame), ...]``, m.

    Raises
    ------
    InputError
        When ``n_setups < 1`` or ``length`` is not > 0.
    """
    if int(n_setups) < 1:
        raise InputError(f"the number of ballbar setups must be >= 1, got {n_setups}")
    if not length > 0:
        raise InputError(f"the ballbar length must be > 0, got {length} m")
    P0 = machine.home[0]
    return [(P0 - length * n, np.zeros(3)) for n in setup_normals(int(n_setups))]


def ballbar_setups(machine: Machine, setup: BallbarSetup | None = None,
                   length: float | None = None):
    """Pivots (base frame) and balls (platform frame) of the ballbar setups of plans.

    The mountings of ``setup`` (a calibrated machine file's, or planned by a planning command
    for ``--radius`` / ``--setups``: :meth:`Distance.planned_setup`) when it has some and
    ``length`` is not given, else the three planned setups of :func:`planned_ballbar_setups`
    (ballbar ``length``, default :data:`BALLBAR_LENGTH`).

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    setup : BallbarSetup, optional
        The ballbar's set-up (None: none).
    length : float, optional
        Ballbar length, m.

    Returns
    -------
    pivots : ndarray, shape (K, 3)
        One pivot per setup, m.
    balls : ndarray, shape (K, 3)
        One ball per setup, m (platform frame).
    """
    setups = setup.mountings if setup is not None and length is None else None
    if not setups:
        setups = planned_ballbar_setups(machine, len(CIRCLE_NORMALS),
                                        BALLBAR_LENGTH if length is None else length)
    pivots = np.array([np.asarray(p, float) for p, _ in setups])
    balls = np.array([np.asarray(b, float) for _, b in setups])
    return pivots, balls


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
        :func:`ballbar_setups` of the machine.

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


@dataclass(frozen=True, slots=True)
class DistanceOptions:
    """The options of the ballbar's calibration flow (:meth:`Distance.calibrate`)."""

    noise: object = option(
        None, "--noise", "the ballbar's standard deviation (default 1um); held as given, else "
        "estimated from the residuals.")
    robust: bool = option(
        False, "--robust", "Leave out the rows the noise cannot explain (a chi-square test of "
        "each row) and fit again.")


class Distance(Instrument):
    """A measuring ballbar between a pivot on the base and a ball on the platform."""

    name = "distance"
    aliases = ("distances", "ballbar")
    words = "ballbar lengths between a pivot on the base and a ball on the platform"
    plan_size = 90
    #: the quantities of its machine-file section (unit conversion, magnitude checks)
    file_quantities = {("ballbar", "*", "pivot", "*"): "length",
                       ("ballbar", "*", "ball", "*"): "length"}
    columns = ("the joint readings q1_<unit>.. and the ballbar length d_mm, optionally setup "
               "(1..K, one per mounting)")
    priority = 30

    def detect(self, header):
        return has_column(header, "d")

    def applies(self, machine):
        # the planned setups sweep spheres around pivots: the platform must move in space
        if not {0, 1, 2} <= set(machine.pose_space):
            return ("the ballbar plans sweep spheres around their pivots, and this machine's "
                    f"platform moves along {_space_words(machine)} only: measure points "
                    "(tracker) instead")
        return None

    def default_noise(self):
        from .models import IsotropicNoise

        return IsotropicNoise(1e-6)

    def describe_noise(self, noise):
        return f"ballbar length {noise.sigma * 1e6:.3g} um (std)"

    montecarlo_variables = ("noise", "poses", "tolerance")
    montecarlo_metrics = {
        "distance_mean": ("um", 1e-6, "mean held-out ballbar-length error"),
        "distance_max": ("um", 1e-6, "max held-out ballbar-length error"),
    }
    montecarlo_evaluation_poses = 100
    montecarlo_poses = 90
    montecarlo_exact_data = True

    def montecarlo_minimum_poses(self, settings):
        # 1 equation per pose, 3 mountings
        return max(9, len(settings.machine.parameters) - 6)

    def montecarlo_run(self, run):
        """A ballbar on three mountings (the registry's plan, random mounting errors), the
        pivots and balls estimated with the machine; held out: ballbar lengths at other poses
        on the spheres through the identified pivots and balls, against the true ones."""
        s = run.settings
        nominal = s.machine
        noise = 1e-6 if s.noise is None else s.noise
        data, true, truth = run.simulate(s.poses or self.montecarlo_poses,
                                         IsotropicNoise(noise) if noise > 0 else False)
        res = fit_instrument(nominal, data, DistancesModel(data.n_groups),
                             IsotropicNoise(run.weight(noise)))
        P, R, g = self.candidates(nominal, self.montecarlo_evaluation_poses, run.rng,
                                  run.settings.setups.get(self.name))
        q = nominal.ik(P, R)
        model = res.model
        fit = res.machine.fk(q, start=(P, R))
        d_fit = model.predict(model.initial(), fit.P, fit.R, g)[:, 0]
        exact = true.fk(q, start=(P, R))
        pivots = np.array([p for p, _ in truth["setups"]])[g]
        balls = np.array([b for _, b in truth["setups"]])[g]
        d_true = np.linalg.norm(exact.P + np.einsum("kij,kj->ki", exact.R, balls) - pivots,
                                axis=-1)
        e = np.abs(np.where(fit.converged & exact.converged, d_fit - d_true, np.nan))
        ok = np.isfinite(e)
        return res, {"distance_mean": float(np.mean(e[ok])) if ok.any() else math.nan,
                     "distance_max": float(np.max(e[ok])) if ok.any() else math.nan}

    def candidates(self, machine, n, rng, setup=None):
        """Poses on the setups' spheres (:func:`ballbar_setups`: random directions within 60
        deg of the pivot's direction to home; random orientations within 10 deg on platforms
        that rotate)."""
        from ..kinematics import matrix_from_euler
        from ..machines.deviations import draw_accepted

        pivots, balls = ballbar_setups(machine, setup)
        P0, R0 = machine.home
        arm = P0 + balls @ R0.T - pivots                  # pivot -> ball at home, per setup
        radius = np.linalg.norm(arm, axis=-1)
        normals = arm / np.where(radius > 0, radius, 1.0)[:, None]
        rotates = machine.rotates
        turns = np.isin(np.arange(3, 6), machine.pose_space)     # Euler angle i about axis i

        def draw(m, rng):
            g = rng.integers(0, len(pivots), m)
            v = rng.standard_normal((m, 3))
            v /= np.linalg.norm(v, axis=-1, keepdims=True)
            cos = np.sum(v * normals[g], -1)
            v = np.where((cos < 0)[:, None], -v, v)
            R = (matrix_from_euler(np.where(turns, rng.uniform(-0.17, 0.17, (m, 3)), 0.0)) @ R0
                 if rotates else np.broadcast_to(np.eye(3), (m, 3, 3)).copy())
            P = pivots[g] + radius[g, None] * v - np.einsum("kij,kj->ki", R, balls[g])
            with np.errstate(all="ignore"):
                ok = machine.working_mode(P, R) & (np.abs(cos) > 0.5)
            draw.group = g
            return P, R, ok

        groups = []

        def tracked(m, rng):
            P, R, ok = draw(m, rng)
            groups.append(draw.group[ok])
            return P, R, ok

        where = str(getattr(machine, "source", "") or "").replace("{", "{{").replace("}", "}}")
        P, R = draw_accepted(tracked, n, rng, (f"{where}: " if where else "")
                             + "only {have} of {n} ballbar poses around home are reachable: "
                             "check the geometry and home", machine=machine)
        return P, R, np.concatenate(groups)[:n]

    def standard_plan(self, machine, n, seed, setup=None):
        pivots, balls = ballbar_setups(machine, setup)
        k = len(pivots)
        words = {1: "one mounting", 2: "two mountings", 3: "three mountings"}.get(
            k, f"{k} mountings")
        if n < 3 * k:
            return StandardPlan(f"ballbar on {words}", reason=f"{words} need at least {3 * k} "
                                f"poses, not {n}")
        P, R, group = self.candidates(machine, n, np.random.default_rng(seed), setup)
        P0, R0 = machine.home
        lengths = np.linalg.norm(P0 + balls @ R0.T - pivots, axis=-1) * 1e3
        length = (f"{lengths[0]:.4g} mm" if np.ptp(lengths) < 1e-6
                  else "/".join(f"{v:.4g}" for v in lengths) + " mm")
        turn = " and orientations within 10 deg" if machine.rotates else ""
        return StandardPlan(f"a ballbar of {length} on {words}: {n} random poses on the "
                            f"spheres around the pivots{turn} (seed {seed})", P, R,
                            group=group)

    def planned_data(self, machine, P, R, rows, source, group=None, setup=None):

        q = reachable(machine, P, R, rows, source)
        group = np.zeros(len(P), int) if group is None else np.asarray(group, int)
        pivots, balls = ballbar_setups(machine, setup)
        pivots, balls = pivots[group % len(pivots)], balls[group % len(pivots)]
        d = np.linalg.norm(P + np.einsum("kij,kj->ki", R, balls) - pivots, axis=-1)
        return InstrumentData("distances", q, d[:, None], group, rows, source, P, R)

    section = "ballbar"
    section_words = "a calibration from distances (d: ballbar) writes the ballbar section"
    Setup = BallbarSetup
    section_order = 20
    section_schema = Ballbar
    section_lists = {"ballbar": "a list of mountings {pivot: [x, y, z], ball: [x, y, z]} (one "
                                "per setup)"}

    def read_setup(self, section, length_factor, machine):
        return BallbarSetup([(np.asarray(m.pivot, float) * length_factor,
                              np.asarray(m.ball, float) * length_factor) for m in section])

    def setup_section(self, setup, length_factor, machine):
        return [{"pivot": vector(p, length_factor), "ball": vector(b, length_factor)}
                for p, b in setup.mountings]

    def carried_by(self, machine, setup):
        return bool(setup)

    def groups_carried(self, setup):
        return 0 if setup is None else len(setup)

    def predict(self, machine, setup, P, R, ok, group, rows=None, source=None):
        from .models import NuisanceState

        setups = list(setup.mountings)
        _check_groups(group, len(setups), "setup", "ballbar", rows, source)
        model = DistancesModel(len(setups))
        values = np.zeros(len(model.parameters))
        for g, (pivot, ball) in enumerate(setups):
            values[model.parameters.indices([f"setup{g + 1}.pivot.{c}" for c in "xyz"])] = pivot
            values[model.parameters.indices([f"setup{g + 1}.ball.{c}" for c in "xyz"])] = ball
        return model.predict(NuisanceState(values, []), P, R, group), None, group

    simulate_options = {"setups": None, "length": None, "circles": False}
    simulate_options_words = "setups, length and circles: apply to the distance scenario"

    def simulate(self, machine, true, n, noise, rng, truth, *, setup=None, poses=None,
                 mounting_error=MOUNTING_ERROR, setups=None, length=None, circles=False):
        """``setups`` mountings of a ballbar of ``length`` (the machine file's, ``setup``,
        when neither is given, else :func:`planned_ballbar_setups`, 3 and
        :data:`BALLBAR_LENGTH` by default); ``n`` poses on the spheres around the pivots
        (:meth:`candidates`), ``poses``, or with ``circles`` ISO 230-4 circles
        (:func:`circle_plan`); true pivots and balls = planned + a uniform error of
        ``mounting_error``; ``noise`` an ``IsotropicNoise`` (default 1 um; False: exact).
        See :meth:`Instrument.simulate <pkmcal.instruments.base.Instrument.simulate>`.

        Returns
        -------
        tuple
            ``(data, true, truth)``; ``truth`` with ``setups``, ``planned_setups`` and
            ``length`` (per setup, m).
        """
        from .experiment import given_poses, mm_text, noise_model, simulate_instrument

        if setups is None and length is None and setup:
            plan = list(setup.mountings)
        else:
            plan = planned_ballbar_setups(machine, 3 if setups is None else int(setups),
                                          BALLBAR_LENGTH if length is None else float(length))
        k = len(plan)
        if poses is not None:
            P, R = given_poses(poses)
            group = (np.arange(len(P)) % k if len(poses) < 3 or poses[2] is None
                     else np.asarray(poses[2], int))
            words = f"{len(P)} given poses"
        elif circles:
            P, R, group = circle_plan(machine, n, plan)
            words = f"{k} ISO 230-4 circle(s), {n} poses"
        else:
            P, R, group = self.candidates(machine, n, rng, BallbarSetup(plan))
            words = (f"{n} random poses on the spheres around the {k} pivot(s)"
                     + (" with rotations within +/-10 deg" if machine.rotates else ""))
        true_setups = [(p + rng.uniform(-mounting_error, mounting_error, 3),
                        b + rng.uniform(-mounting_error, mounting_error, 3)) for p, b in plan]
        model = DistancesModel(k)
        state = model.initial()
        for g, (p, b) in enumerate(true_setups):
            state.values[model._ip[g]] = p
            state.values[model._ib[g]] = b
        data = simulate_instrument(true, machine, model, state, P, R, group,
                                   noise_model(noise, IsotropicNoise(1e-6)), rng)
        P0, R0 = machine.home
        L = [float(np.linalg.norm(P0 + R0 @ b - p)) for p, b in plan]
        lengths = sorted({round(v * 1e3, 6) for v in L})
        rows = [("ballbar", f"{'/'.join(f'{v:.6g}' for v in lengths)} mm (planned), true "
                 "pivots and balls off the planned ones by the mounting error")]
        rows += [(f"setup {g + 1}", f"pivot {mm_text(p)} mm, ball {mm_text(b)} mm (platform)")
                 for g, (p, b) in enumerate(true_setups)]
        truth.update(setups=true_setups, planned_setups=plan, length=L, poses=words, rows=rows,
                     setup=BallbarSetup(true_setups))
        return data, true, truth

    simulate_flags = {"--setups": "--scenario distance", "--radius": "--scenario distance",
                      "--circles": "--scenario distance"}

    def simulate_arguments(self, machine, noise, setups=None, radius=None, circles=False,
                           **flags):
        from ..plausibility import check_option_scale
        from ..units import parse_quantity

        sigma = _simulated_sigma(noise, "1um", machine)
        model = IsotropicNoise(sigma) if sigma > 0 else False
        if setups is not None and setups < 1:
            raise InputError(f"--setups: must be >= 1, got {setups}")
        length = None
        if radius is not None:
            length = parse_quantity(radius, "length", "--radius")
            if not length > 0:
                raise InputError(f"--radius: the ballbar length must be > 0, got {radius}")
            check_option_scale(length, machine, "--radius", "size", radius)
        elif setups is not None:
            length = BALLBAR_LENGTH
        return model, f"ballbar length {sigma * 1e6:.4g} um (std)", {
            "setups": setups, "length": length, "circles": bool(circles)}

    data_columns = ("d",)
    prediction_words = "predicted ballbar length(s)"

    def problem(self, machine, data, noise=None, setup=None, **start):
        from .models import DistancesModel
        from .problem import InstrumentProblem

        model = DistancesModel(data.n_groups)
        pivots, balls = ballbar_setups(machine, setup)
        values = np.array(model.parameters.values, float)
        for g in range(data.n_groups):
            values[model._ip[g]] = pivots[g % len(pivots)]
            values[model._ib[g]] = balls[g % len(pivots)]
        model.parameters = model.parameters.with_values(values)
        return InstrumentProblem(machine, data, model,
                                 self.default_noise() if noise is None else noise)

    measurement_words = "ballbar distances (pivot and ball of each setup estimated jointly)"
    group_column = "setup"
    plan_options = ("setups", "radius")

    def noise_arg(self, text, machine=None):
        """The ballbar length noise of ``--noise`` (default 1 um)."""
        from .models import IsotropicNoise

        if text is not None and not isinstance(text, (str, int, float)):
            return text
        return IsotropicNoise(_sigma_arg(text, machine, "the ballbar lengths", 1e-6))

    #: the io reader of its CSV files (:func:`pkmcal.io.read_measurements`)
    reader = "read_distances"
    Options = DistanceOptions

    def calibrate(self, machine: Machine, data, context, options):
        """The geometry and every mounting's pivot and ball, the lengths' residuals before
        (mountings fitted alone) and after (see
        :meth:`~pkmcal.instruments.base.Instrument.calibrate`)."""
        return _calibration_flow(machine, data, context, options)

    def joint_part(self, machine: Machine, data, source, noise, read, options=None):
        """The ballbar file's part of a fit of several files: its lengths, every mounting's
        pivot and ball unknown (see :meth:`~pkmcal.instruments.base.Instrument.joint_part`)."""
        noise_model = self.noise_arg(noise, machine)
        dist = load_data(data, read, machine)
        counts = np.bincount(dist.group, minlength=dist.n_groups)
        few = np.flatnonzero(counts < 6)
        if few.size:
            raise InputError(f"{path_text(source)}: "
                             f"setup {few[0] + 1} has {counts[few[0]]} row(s); each "
                             "mounting needs at least 6 lengths (its pivot and ball are "
                             "unknown)")
        dist.source = str(source)
        return JointPart(dist, DistancesModel(dist.n_groups), noise_model,
                         f"ballbar {noise_model.sigma * 1e6:.4g} um (std)", "distance")

    def measured_problem(self, machine, data, noise=None, source="", setup=None):
        """The pivot and ball of each setup fitted to the data with the machine held."""
        from ..estimation.estimator import levenberg_marquardt
        from .models import DistancesModel

        noise = self.default_noise() if noise is None else noise
        fk = _fk_of(machine, data, source)
        model = DistancesModel(data.n_groups).start(fk.P, fk.R, data.values, data.group,
                                                    str(source))
        alone = InstrumentProblem(machine, data, model, noise).with_machine_fixed()
        state = levenberg_marquardt(alone).state.nuisance
        start = BallbarSetup([(state.values[model._ip[g]].copy(),
                               state.values[model._ib[g]].copy())
                              for g in range(data.n_groups)])
        return self.problem(machine, data, noise, setup=start)

    def planned_setup(self, machine, setup=None, setups=None, length=None, **options):
        """``setups`` planned mountings (default 3) of a ballbar of ``length`` (default
        :data:`BALLBAR_LENGTH`) when either is given, else ``setup``."""
        if setups is None and length is None:
            return setup
        return BallbarSetup(planned_ballbar_setups(
            machine, 3 if setups is None else setups, BALLBAR_LENGTH if length is None
            else length))


@dataclass
class DistanceSection(Section):
    """What a ballbar calibration adds to its result (``result.sections["distance"]``): each
    mounting's pivot (base frame) and ball (platform frame), m, and its rows.

    Attributes
    ----------
    setups : list of (ndarray (3,), ndarray (3,))
        ``(pivot, ball)`` per mounting, m.
    rows : list of int
        The rows of each mounting.
    """

    instrument: ClassVar[str] = "distance"
    title: ClassVar[str] = "Ballbar mountings"

    setups: list
    rows: list

    def as_report(self, units=None) -> dict:
        from ..units import LENGTH

        unit = (units or {}).get("length", "mm")
        fl = LENGTH[unit]
        return {"setups": [{"setup": g + 1, "rows": int(n), "pivot": (np.asarray(p) / fl).tolist(),
                            "ball": (np.asarray(b) / fl).tolist(), "unit": unit}
                           for g, ((p, b), n) in enumerate(zip(self.setups, self.rows,
                                                               strict=True))]}

    def summary_rows(self, units=None) -> list:
        return [(f"setup {u['setup']}", f"{u['rows']} rows; pivot ("
                 + ", ".join(f"{v:.6g}" for v in u["pivot"]) + f") {u['unit']} (base), ball ("
                 + ", ".join(f"{v:.6g}" for v in u["ball"]) + f") {u['unit']} (platform)")
                for u in self.as_report(units)["setups"]]


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
        With ``problem``, ``machine`` (calibrated), ``model``, ``start_model``,
        ``unidentifiable`` and its :class:`DistanceSection` (the mountings: a ``(pivot,
        ball)`` pair per setup, m).

    Raises
    ------
    InputError
        When there are fewer lengths than identifiable unknowns per mounting, or the machine
        file's model cannot reproduce some readings.
    """
    noise = IsotropicNoise(1e-6) if noise is None else noise
    if data.kind != "distances":
        raise InputError(f"{path_text(data.source)}: {data.kind} data, not ballbar distances")
    counts = np.bincount(data.group, minlength=data.n_groups)
    few = np.flatnonzero(counts < 6)
    if few.size:
        raise InputError(f"{path_text(data.source)}: "
                         f"setup {few[0] + 1} has {counts[few[0]]} row(s); each "
                         "mounting needs at least 6 lengths (its pivot and ball are unknown)")
    result = fit_instrument(machine, data, DistancesModel(data.n_groups), noise,
                            fit_machine=fit_machine, rtol=rtol, **options)
    model, state = result.model, result.state.nuisance
    setups = [(np.array(state.values[model._ip[g]]), np.array(state.values[model._ib[g]]))
              for g in range(data.n_groups)]
    result.add_section(DistanceSection(setups, np.bincount(data.group,
                                                           minlength=data.n_groups).tolist()))
    return result



#: this module's instrument (:data:`~pkmcal.instruments.registry.INSTRUMENT_MODULES`)
INSTRUMENT = Distance()


# -- calibration flow (pkmcal calibrate) ------------------------------------------------------


def _calibration_flow(machine, data, context: FlowContext,
                      options: DistanceOptions) -> FlowResult:
    """``pkmcal calibrate`` from ballbar lengths (:meth:`Distance.calibrate`)."""

    source, split = context.source, context.split
    noise = INSTRUMENT.noise_arg(options.noise, machine)
    data, held, result, before, calibrated, params, units = fit_with_baseline(
        machine, data, context, calibrate_distances, noise,
        "measure each mounting over a spread of poses (a sphere around the pivot, with "
        "rotations on a platform that rotates)", estimate_noise=options.noise is None,
        robust=options.robust)
    problem, before_problem = result.problem, before.problem
    rms_after, r_after = scalar_rms(problem, result.state, data)
    rms_before, _ = scalar_rms(before_problem, before.state, data)
    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.unidentifiable)
    report = {
        **context.head(machine, "distance", "joint"),
        "units": units,
        "measurements": len(data),
        "noise": f"ballbar {noise.sigma * 1e6:.4g} um (std)",
        **result.section(DistanceSection).as_report(units),      # setups
        "convergence": convergence_json(result),
        "residuals": scalar_residuals_json(
            result, r_after, rms_after, rms_before,
            "ballbar lengths, measured - predicted (forward kinematics of the readings)",
            "machine file's model, mountings (pivots and balls) fitted alone"),
        "identifiability": identifiability_json(n_free, rank, unidentifiable, s),
        "parameters": public_parameters(params),
    }
    if held is not None:
        report["validation"] = validation_section(
            split, held, "ballbar lengths of the held-out rows, measured - predicted with the "
            "identified mountings; before: the machine file's model with the mountings fitted "
            "alone on the calibration rows", "um",
            scalar_rms(before_problem, before.state, held)[0],
            scalar_rms(problem, result.state, held)[0], rms_after)
    metadata = scalar_metadata("ballbar", report, source, machine, result, rms_after, len(data),
                               unidentifiable)
    return FlowResult("distance", machine, calibrated, result, report, metadata, params, units,
                      setups={"distance": BallbarSetup(result.section(DistanceSection).setups)})


# --------------------------------------------------------------------------------------------
# named parameter sets (--parameters)
# --------------------------------------------------------------------------------------------
