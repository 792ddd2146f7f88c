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

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..machines.base import Machine
from ..machines.reach import (  # noqa: F401  (the probe's plans)
    PROBE_CONDITIONING,
    PROBE_MARGIN,
    _bed_points,
    _probe_ok,
    bed_centre,
    bed_height,
    probe_radius,
)
from .problem import InstrumentProblem


@dataclass
class StandardPlan:
    """The instrument's standard measurement plan (what one measures without planning), or
    the reason there is none of a given size.

    Attributes
    ----------
    name : str
        The plan in words, e.g. "seed 001's 3x3x3 grid around home".
    P : ndarray, shape (n, 3) or None
        Positions, m; None when there is no standard plan of the size asked for.
    R : ndarray, shape (n, 3, 3) or None
        Orientations.
    reason : str
        Why there is none (empty when there is one).
    group : ndarray of int, shape (n,) or None
        0-based setup of each pose (distance plans), else None.
    """

    name: str
    P: np.ndarray | None = None
    R: np.ndarray | None = None
    reason: str = ""
    group: np.ndarray | None = None

    @property
    def available(self) -> bool:
        """True when the plan has poses."""
        return self.P is not None

    def __len__(self) -> int:
        return 0 if self.P is None else len(self.P)


def _rows(rows, limit: int = 10) -> str:
    rows = [int(r) for r in rows]
    return ", ".join(map(str, rows[:limit])) + (" ..." if len(rows) > limit else "")


def reachable(machine: Machine, P, R, rows, source) -> np.ndarray:
    """Joint values of planned poses; InputError naming the rows the machine cannot reach."""
    q = machine.ik(P, R)
    bad = ~np.all(np.isfinite(q), -1)
    if bad.any():
        raise InputError(f"{source}: row(s) {_rows(rows[bad])}: pose(s) the machine cannot "
                         "reach")
    return q


class Instrument:
    """An instrument (see the module docstring); subclasses fill in the methods."""

    #: canonical name (scenario and measurement type)
    name: str = ""
    #: other names users may give (``--scenario points``)
    aliases: tuple = ()
    #: what it measures, in words
    words: str = ""
    #: default number of planned poses
    plan_size: int = 60

    def plan_size_for(self, machine: Machine) -> int:
        """The default number of planned poses for ``machine``.

        Parameters
        ----------
        machine : Machine
            The machine.

        Returns
        -------
        int
            :attr:`plan_size` unless the instrument says otherwise.
        """
        return self.plan_size

    def applies(self, machine: Machine) -> str | None:
        """Why this instrument cannot calibrate ``machine`` (None: it can).

        Parameters
        ----------
        machine : Machine
            The machine.

        Returns
        -------
        str or None
            The reason in words.
        """
        return None

    def default_noise(self):
        """The noise model ``pkmcal calibrate`` assumes by default.

        Returns
        -------
        object
            The instrument's noise model.
        """
        raise NotImplementedError

    def describe_noise(self, noise) -> str:
        """The noise model in words (um, urad).

        Parameters
        ----------
        noise : object
            A noise model of this instrument.

        Returns
        -------
        str
            One line.
        """
        raise NotImplementedError

    def candidates(self, machine: Machine, n: int, rng):
        """``n`` feasible candidate poses and their setups.

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        n : int
            Number of poses.
        rng : numpy.random.Generator
            Random generator.

        Returns
        -------
        P : ndarray, shape (n, 3)
            Positions, m.
        R : ndarray, shape (n, 3, 3)
            Orientations.
        group : ndarray of int, shape (n,) or None
            0-based setup of each pose (None: one).
        """
        from ..machines.reach import sample_workspace_poses

        P, R = sample_workspace_poses(machine, n, rng)
        return P, R, None

    def standard_plan(self, machine: Machine, n: int, seed: int) -> StandardPlan:
        """The standard plan of ``n`` poses (default: the candidate sample of ``seed``).

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        n : int
            Number of poses.
        seed : int
            Seed of sampled plans.

        Returns
        -------
        StandardPlan
            The plan.
        """
        P, R, group = self.candidates(machine, n, np.random.default_rng(seed))
        return StandardPlan(f"{n} random planned poses around home (seed {seed})", P, R,
                            group=group)

    def planned_data(self, machine: Machine, P, R, rows, source, group=None):
        """Noise-free measurements of the nominal machine at planned poses.

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        P : ndarray, shape (K, 3)
            Positions, m.
        R : ndarray, shape (K, 3, 3)
            Orientations.
        rows : ndarray of int, shape (K,)
            Row labels for messages.
        source : str
            Name of the plan.
        group : ndarray of int, shape (K,), optional
            0-based setup of each pose.

        Returns
        -------
        object
            The instrument's data.
        """
        raise NotImplementedError

    def problem(self, machine: Machine, data, noise=None, **start):
        """The calibration problem ``pkmcal calibrate`` solves by default, unsolved.

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        data : object
            The instrument's data.
        noise : object, optional
            Noise model; default :meth:`default_noise`.
        **start
            Start values of the instrument's unknowns (``registration``, ``frames``).

        Returns
        -------
        BlockProblem
            The problem.
        """
        raise NotImplementedError

    #: the measurement in words, as ``identifiability`` and ``select-poses`` print it
    measurement_words: str = ""
    #: the plan file's column naming each pose's group (``target``, ``setup``); None: one
    group_column: str | None = None
    #: the plan options the instrument takes (:meth:`planned_machine`)
    plan_options: tuple = ()

    def noise_arg(self, text, machine: Machine | None = None):
        """The noise model of ``--noise`` (None: :meth:`default_noise`; a model as it is).

        Parameters
        ----------
        text : str or float or object or None
            A level with its unit, an SI number, a noise model, or None.
        machine : Machine, optional
            Levels are checked against its size when given.

        Returns
        -------
        object
            The instrument's noise model.

        Raises
        ------
        InputError
            Naming ``--noise``, when the instrument takes no level.
        """
        if text is None:
            return self.default_noise()
        if not isinstance(text, (str, int, float)):
            return text
        raise InputError(f"--noise: {self.name} measurements take no noise level, got {text}")

    def noise_option(self, noise, pose_noise=None, machine: Machine | None = None):
        """The noise model of ``--noise`` and ``--pose-noise`` (as ``pkmcal calibrate`` takes
        them).

        Parameters
        ----------
        noise : str or float or object or None
            ``--noise`` (:meth:`noise_arg`).
        pose_noise : str or None, optional
            ``--pose-noise``: full poses alone take it.
        machine : Machine, optional
            Levels are checked against its size when given.

        Returns
        -------
        object
            The instrument's noise model.

        Raises
        ------
        InputError
            For ``pose_noise`` on an instrument that measures no pose, or a bad level.
        """
        if pose_noise is not None:
            raise InputError(f"--pose-noise applies to full-pose measurements, not {self.name}")
        return self.noise_arg(noise, machine)

    #: the name of the :mod:`pkmcal.io` function reading its CSV files
    #: (:func:`pkmcal.io.read_measurements`); instruments sit below io and name it
    reader: str = ""

    def measured_problem(self, machine: Machine, data, noise=None, source: str = ""):
        """The calibration problem ``pkmcal calibrate`` solves for measured ``data``, unsolved,
        the instrument's unknowns started from the data on the machine's geometry (a fit with
        the machine held where they need one).

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        data : object
            The instrument's measurements (:meth:`read`).
        noise : object, optional
            Noise model; default :meth:`default_noise`.
        source : str, optional
            Name of the data, for messages.

        Returns
        -------
        BlockProblem
            The problem.
        """
        return self.problem(machine, data, noise)

    def planned_machine(self, machine: Machine, **options) -> Machine:
        """The machine the instrument's plans use, with the plan options of
        :attr:`plan_options` (e.g. a ballbar's planned mountings).

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        **options
            The instrument's plan options (None: not given).

        Returns
        -------
        Machine
            ``machine``, or a copy carrying the planned set-up.
        """
        return machine


class ConstraintLink(Instrument):
    """Seed 000: joint readings with the constraint link mounted, one joint passive."""

    name = "constraint-link"
    words = "a fixed-length constraint link, one joint passive (no external sensor)"
    plan_size = 150

    def applies(self, machine):
        if not machine.rotates:
            return ("the constraint link takes one degree of freedom of a platform that "
                    "rotates; this machine's platform only translates")
        if len(machine.pose_space) != 6:
            return ("the constraint link takes one degree of freedom of a platform that moves "
                    "in space (six pose coordinates); this machine's platform moves along "
                    f"{_space_words(machine)} only")
        if getattr(machine, "constraint_link_length", None) is None:
            return ("the machine file has no constraint link: add `constraint_link: {length: "
                    "...}` (in the file's length unit)")
        return None

    def default_noise(self):
        return 1e-6

    def describe_noise(self, noise):
        return f"encoder noise {noise * 1e6:.4g} um (std)"

    def candidates(self, machine, n, rng):
        from .constraint_link import sample_sphere_poses

        P, R = sample_sphere_poses(machine, link_length(machine), n, rng)
        return P, R, None

    def standard_plan(self, machine, n, seed):
        P, R, _ = self.candidates(machine, n, np.random.default_rng(seed))
        return StandardPlan(f"{n} random planned poses on the constraint sphere (seed {seed})",
                            P, R)

    def planned_data(self, machine, P, R, rows, source, group=None):
        from .constraint_link import ConstraintLinkData

        P = _on_sphere(P, machine, rows, source)
        q = reachable(machine, P, R, rows, source)
        return ConstraintLinkData(q, link_length(machine),
                                  np.arange(len(P)) % machine.n_joints, rows, source,
                                  true_P=P, true_R=R)

    def problem(self, machine, data, noise=None, **start):
        from .constraint_link import ConstraintLinkML

        return ConstraintLinkML(machine, data, self.default_noise() if noise is None else noise)

    measurement_words = ("constraint link (maximum likelihood: every reading noisy; one pose on "
                         "the sphere per measurement)")

    def noise_arg(self, text, machine=None):
        """The encoder noise of ``--noise`` (default 1 um), m."""
        return _sigma_arg(text, machine, "encoder noise", 1e-6)

    #: the io reader of its CSV files (:func:`pkmcal.io.read_measurements`)
    reader = "read_constraint_link"


#: constraint-link plans: largest allowed deviation of |P| from Lc (m); poses within it are
#: put on the sphere (rounding in a hand-made plan file)
SPHERE_TOL = 1e-4


def _space_words(machine: Machine) -> str:
    """The pose coordinates a platform moves along, in words (``x, y, rz``)."""
    return ", ".join(("x", "y", "z", "rx", "ry", "rz")[i] for i in machine.pose_space)


def link_length(machine: Machine) -> float:
    """The machine file's constraint-link length, m; InputError when it has none."""
    Lc = getattr(machine, "constraint_link_length", None)
    if Lc is None:
        raise InputError(f"{getattr(machine, 'source', 'the machine file')}: no "
                         "constraint_link length; constraint-link plans need it")
    return float(Lc)


def _on_sphere(P, machine, rows, source):
    """Constraint-link plan poses put exactly on ``|P| = Lc`` (refused beyond SPHERE_TOL)."""
    Lc = link_length(machine)
    norm = np.linalg.norm(P, axis=-1)
    off = ~(np.abs(norm - Lc) <= SPHERE_TOL)
    if off.any():
        raise InputError(f"{source}: row(s) {_rows(rows[off])}: |P| differs from the "
                         f"constraint-link length {Lc * 1e3:.6g} mm by more than "
                         f"{SPHERE_TOL * 1e3:g} mm; a constraint-link plan has its poses on "
                         "that sphere")
    return P * (Lc / norm)[:, None]


def tracker_pose(machine: Machine):
    """``base_from_tracker`` of the machine file, else the simulations' default.

    Parameters
    ----------
    machine : Machine
        The machine (its ``base_from_tracker``, if any).

    Returns
    -------
    tuple of ndarray
        ``(R (3, 3), t (3,))``.
    """
    pose = getattr(machine, "base_from_tracker", None)
    if pose is None:
        from .tracker import default_tracker_pose

        pose = default_tracker_pose()
    return pose


#: where plans and simulations put an unknown target on the platform (platform frame, in
#: characteristic lengths): off the platform origin, as a reflector nest on a tool would be
TARGET_OFFSET = np.array([0.1, -0.05, -0.15])


def plan_target(machine: Machine) -> np.ndarray:
    """The target's place on the platform for plans: the machine's, else an offset one."""
    c = machine.tracker_target()
    return TARGET_OFFSET * machine.characteristic_length() if c is None else c


class Tracker(Instrument):
    """Points of a target on the platform in the instrument's frame (seed 001's tracker)."""

    name = "tracker"
    aliases = ("points",)
    words = "a target on the platform measured in the instrument frame (laser tracker, CMM)"
    plan_size = 27

    def plan_size_for(self, machine):
        # the source paper's 3x3x3 grid (seed 001, the Delta); random poses otherwise
        return self.plan_size if machine.tracker_grid_spacing() is not None else 60

    def default_noise(self):
        from .tracker import TrackerNoise

        return TrackerNoise()

    def describe_noise(self, noise):
        if hasattr(noise, "sigma"):
            return f"points: {noise.sigma * 1e6:.3g} um per coordinate (std)"
        return (f"laser tracker: {noise.distance * 1e6:.3g} um along the beam, "
                f"{noise.transverse * 1e6:.3g} um + {noise.transverse_per_m * 1e6:.3g} um/m "
                "across (std)")

    def candidates(self, machine, n, rng):
        if machine.tracker_grid_spacing() is None:
            return super().candidates(machine, n, rng)
        from ..machines.deviations import draw_accepted

        half = np.asarray(machine.tracker_grid_spacing(), float)   # the 3x3x3 grid: +/- spacing
        centre = machine.home[0]

        def draw(m, rng):
            P = centre + rng.uniform(-1.0, 1.0, (m, 3)) * half
            R = np.broadcast_to(np.eye(3), (m, 3, 3))
            q, J, _ = machine.ik_jacobians(P, R, want_du=False)
            ok = np.all(np.isfinite(q), -1)
            sv = np.linalg.svd(np.asarray(J)[ok][..., :3], compute_uv=False)
            ok[ok] = sv[..., -1] / sv[..., 0] > 0.05
            return P, R, ok

        where = str(getattr(machine, "source", "") or "").replace("{", "{{").replace("}", "}}")
        P, R = draw_accepted(draw, n, rng, (f"{where}: " if where else "")
                             + "only {have} of {n} candidate points around home are reachable "
                             "and well conditioned: check the geometry and home")
        return P, R, None

    def standard_plan(self, machine, n, seed):
        if machine.tracker_grid_spacing() is None:
            return super().standard_plan(machine, n, seed)
        from .tracker import grid_points

        k = int(round(n ** (1.0 / 3.0)))
        if k < 2 or k**3 != n:
            return StandardPlan("seed 001's grid around home",
                                reason=f"seed 001's grid has 3 x 3 x 3 = 27 points (k x k x k "
                                       f"grids in its box: 8, 27, 64, ...), not {n}")
        span = 2.0 * np.asarray(machine.tracker_grid_spacing(), float)   # 3x3x3 extent
        P = grid_points(machine.home[0], span / (k - 1), (k, k, k))
        return StandardPlan(f"the {k}x{k}x{k} grid of seed 001 around home", P,
                            np.broadcast_to(np.eye(3), (n, 3, 3)))

    def planned_data(self, machine, P, R, rows, source, group=None):
        from .tracker import TrackerData

        q = reachable(machine, P, R, rows, source)
        Rt, t = tracker_pose(machine)
        x = P + np.einsum("kij,j->ki", R, plan_target(machine))
        return TrackerData(q, (x - t) @ Rt, rows=rows, source=source, true_P=P,
                           target=None if group is None else np.asarray(group, int))

    def problem(self, machine, data, noise=None, registration=None, targets=None, **start):
        from .tracker import TrackerProblem

        groups = getattr(data, "target", getattr(data, "group", None))
        n_targets = 1 if groups is None or not len(groups) else int(np.max(groups)) + 1
        target = None if machine.tracker_target() is not None else \
            np.tile(plan_target(machine), (n_targets, 1)) if targets is None else targets
        return TrackerProblem(machine, data, self.default_noise() if noise is None else noise,
                              tracker_pose(machine) if registration is None else registration,
                              targets=target)

    measurement_words = ("points of a target on the platform (laser tracker; tracker pose and "
                         "unknown target places estimated jointly)")
    group_column = "target"
    plan_options = ("targets",)

    def noise_arg(self, text, machine=None):
        """The tracker noise of ``--noise``: leica (default), or a length per coordinate."""
        from .tracker import tracker_noise_arg

        if text is not None and not isinstance(text, str):
            return text
        return tracker_noise_arg(text, allow_none=False, machine=machine)[0]

    #: the io reader of its CSV files (:func:`pkmcal.io.read_measurements`)
    reader = "read_points"

    def measured_problem(self, machine, data, noise=None, source=""):
        """The tracker's pose and the target places started from the data: registered on the
        machine file's forward kinematics, then (unknown targets) fitted with the machine
        held."""
        from ..estimation.estimator import levenberg_marquardt
        from .models import PointsModel
        from .tracker import TrackerProblem, registration_of

        noise = self.default_noise() if noise is None else noise
        fk = _fk_of(machine, data, source)
        start = PointsModel(data.n_groups, machine.tracker_target()).start(
            fk.P, fk.R, data.values, data.group, str(source))
        registration = (start.rotation_starts[0], start.parameters.values[3:6].copy())
        targets = None
        if machine.tracker_target() is None:
            alone = TrackerProblem(machine, data, noise, registration).with_machine_fixed()
            first = levenberg_marquardt(alone)
            registration = registration_of(first.state)
            targets = first.state.nuisance.values[6:].copy()
        return self.problem(machine, data, noise, registration=registration, targets=targets)

    def planned_machine(self, machine, targets=None, **options):
        """The machine (several targets in turn need the target's place unknown)."""
        if targets is not None and targets > 1 and machine.tracker_target() is not None:
            raise InputError(f"--targets {targets}: {machine.source} gives the target's place "
                             "on the platform; one target only")
        return machine


class Pose(Instrument):
    """Full poses of a marker on the platform (motion capture), SPEC 2.4."""

    name = "pose"
    aliases = ("poses",)
    words = "the marker pose (motion capture, 6-D tracker)"
    plan_size = 60

    def applies(self, machine):
        if not machine.rotates:
            return ("full poses need a platform that rotates; this machine's platform only "
                    "translates: measure points (tracker) instead")
        if len(machine.pose_space) != 6:
            return ("full poses need a platform that moves in space (six pose coordinates); "
                    f"this machine's platform moves along {_space_words(machine)} only: "
                    "measure points (tracker) instead")
        return None

    def default_noise(self):
        from .pose import FullPoseNoise

        return FullPoseNoise()

    def describe_noise(self, noise):
        return (f"leg readings {noise.reading_m * 1e6:.3g} um, poses "
                f"{noise.position_m * 1e6:.3g} um / {noise.orientation_rad * 1e6:.3g} urad "
                "(std)")

    def planned_data(self, machine, P, R, rows, source, group=None):
        from .pose import FullPoseData

        q = reachable(machine, P, R, rows, source)
        Pm, Rm = measurement_frames(machine).measured(P, R)
        return FullPoseData(q, Pm, Rm, rows, source, true_P=P, true_R=R)

    def problem(self, machine, data, noise=None, frames=None, **start):
        from .pose import FullPoseML

        return FullPoseML(machine, data, self.default_noise() if noise is None else noise,
                          measurement_frames(machine) if frames is None else frames)

    measurement_words = "full pose (maximum likelihood; both measurement frames estimated)"

    def noise_option(self, noise, pose_noise=None, machine=None):
        from .pose import full_pose_noise_arg

        if noise is not None and not isinstance(noise, str):
            return noise
        return full_pose_noise_arg(noise, pose_noise, strict=True, machine=machine)

    def noise_arg(self, text, machine=None):
        """The full-pose noise of ``--noise`` (the leg readings; poses at their default)."""
        return self.noise_option(text, None, machine)

    #: the io reader of its CSV files (:func:`pkmcal.io.read_measurements`)
    reader = "read_full_pose"

    def measured_problem(self, machine, data, noise=None, source=""):
        """The measurement frames of the machine file, else estimated from the data (at least
        4 poses)."""
        from .pose import estimate_frames

        if len(data) < 4:
            raise InputError(f"{source}: {len(data)} pose(s); the measurement frames need at "
                             "least 4")
        frames = getattr(machine, "measurement_frames", None)
        if frames is None:
            frames = estimate_frames(machine, data)
        return self.problem(machine, data, noise, frames=frames)


def measurement_frames(machine: Machine):
    """``measurement_frames`` of the machine file, else the simulations' default.

    Parameters
    ----------
    machine : Machine
        The machine (its ``measurement_frames``, if any).

    Returns
    -------
    MeasurementFrames
        The frames.
    """
    frames = getattr(machine, "measurement_frames", None)
    if frames is None:
        from .pose import default_measurement_frames

        frames = default_measurement_frames()
    return frames


#: the ballbar length of plans and simulations, m (a common measuring-ballbar length)
BALLBAR_LENGTH = 0.1
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


def ballbar_setups(machine: Machine, length: float | None = None):
    """Pivots (base frame) and balls (platform frame) of the ballbar setups of plans.

    The machine's own ``ballbar_setups`` (a calibrated machine file, or set by a planning
    command for ``--radius`` / ``--setups``) when it has them and ``length`` is not given,
    else the three planned setups of :func:`planned_ballbar_setups` (ballbar ``length``,
    default :data:`BALLBAR_LENGTH`).

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    length : float, optional
        Ballbar length, m.

    Returns
    -------
    pivots : ndarray, shape (K, 3)
        One pivot per setup, m.
    balls : ndarray, shape (K, 3)
        One ball per setup, m (platform frame).
    """
    setups = getattr(machine, "ballbar_setups", None) if length is None else None
    if not setups:
        setups = planned_ballbar_setups(machine, len(CIRCLE_NORMALS),
                                        BALLBAR_LENGTH if length is None else length)
    pivots = np.array([np.asarray(p, float) for p, _ in setups])
    balls = np.array([np.asarray(b, float) for _, b in setups])
    return pivots, balls


class Distance(Instrument):
    """A measuring ballbar between a pivot on the base and a ball on the platform."""

    name = "distance"
    aliases = ("distances", "ballbar")
    words = "ballbar lengths between a pivot on the base and a ball on the platform"
    plan_size = 90

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

    def candidates(self, machine, n, rng):
        """Poses on the setups' spheres (:func:`ballbar_setups`: random directions within 60
        deg of the pivot's direction to home; random orientations within 10 deg on platforms
        that rotate)."""
        from ..kinematics import matrix_from_euler
        from ..machines.deviations import draw_accepted

        pivots, balls = ballbar_setups(machine)
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

    def standard_plan(self, machine, n, seed):
        pivots, balls = ballbar_setups(machine)
        k = len(pivots)
        words = {1: "one mounting", 2: "two mountings", 3: "three mountings"}.get(
            k, f"{k} mountings")
        if n < 3 * k:
            return StandardPlan(f"ballbar on {words}", reason=f"{words} need at least {3 * k} "
                                f"poses, not {n}")
        P, R, group = self.candidates(machine, n, np.random.default_rng(seed))
        P0, R0 = machine.home
        lengths = np.linalg.norm(P0 + balls @ R0.T - pivots, axis=-1) * 1e3
        length = (f"{lengths[0]:.4g} mm" if np.ptp(lengths) < 1e-6
                  else "/".join(f"{v:.4g}" for v in lengths) + " mm")
        turn = " and orientations within 10 deg" if machine.rotates else ""
        return StandardPlan(f"a ballbar of {length} on {words}: {n} random poses on the "
                            f"spheres around the pivots{turn} (seed {seed})", P, R,
                            group=group)

    def planned_data(self, machine, P, R, rows, source, group=None):
        from .data import InstrumentData

        q = reachable(machine, P, R, rows, source)
        group = np.zeros(len(P), int) if group is None else np.asarray(group, int)
        pivots, balls = ballbar_setups(machine)
        pivots, balls = pivots[group % len(pivots)], balls[group % len(pivots)]
        d = np.linalg.norm(P + np.einsum("kij,kj->ki", R, balls) - pivots, axis=-1)
        return InstrumentData("distances", q, d[:, None], group, rows, source, P, R)

    def problem(self, machine, data, noise=None, **start):
        from .models import DistancesModel
        from .problem import InstrumentProblem

        model = DistancesModel(data.n_groups)
        pivots, balls = ballbar_setups(machine)
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
        return IsotropicNoise(_sigma_arg(text, machine, "ballbar length noise", 1e-6))

    #: the io reader of its CSV files (:func:`pkmcal.io.read_measurements`)
    reader = "read_distances"

    def measured_problem(self, machine, data, noise=None, source=""):
        """The pivot and ball of each setup fitted to the data with the machine held."""
        from ..estimation.estimator import levenberg_marquardt
        from .models import DistancesModel

        noise = self.default_noise() if noise is None else noise
        fk = _fk_of(machine, data, source)
        model = DistancesModel(data.n_groups).start(fk.P, fk.R, data.values, data.group,
                                                    str(source))
        alone = InstrumentProblem(machine, data, model, noise).with_machine_fixed()
        state = levenberg_marquardt(alone).state.nuisance
        start = machine.with_parameters(machine.u)
        start.ballbar_setups = [(state.values[model._ip[g]].copy(),
                                 state.values[model._ib[g]].copy())
                                for g in range(data.n_groups)]
        return self.problem(start, data, noise)

    def planned_machine(self, machine, setups=None, length=None, **options):
        """A copy carrying ``setups`` planned mountings (default 3) of a ballbar of
        ``length`` (default :data:`BALLBAR_LENGTH`), when either is given."""
        if setups is None and length is None:
            return machine
        out = machine.with_parameters(machine.u)
        out.ballbar_setups = planned_ballbar_setups(
            machine, 3 if setups is None else setups, BALLBAR_LENGTH if length is None
            else length)
        return out


#: the probe's repeatability assumed by default, m (standard deviation of the trigger height).
#: An assumption, not a datum: the order of the spread that Klipper's PROBE_ACCURACY reports for
#: common bed probes (a few um for a good touch or piezo probe, 10-20 um for inductive ones)
PROBE_SIGMA = 10e-6
#: Klipper's DELTA_CALIBRATE points (klippy/extras/delta_calibrate.py): the centre, then six
#: points at 90 + 60 i deg on circles of these fractions of the probe radius
KLIPPER_SCATTER = (0.95, 0.90, 0.85, 0.70, 0.75, 0.80)
def probe_pattern(n: int, radius: float, centre=(0.0, 0.0)) -> tuple[np.ndarray, str] | None:
    """The standard probe pattern of ``n`` points on the bed, or None when there is none.

    ``n = 7``: Klipper's ``DELTA_CALIBRATE`` points (``klippy/extras/delta_calibrate.py``):
    the centre and six points at ``90 + 60 i`` deg on circles of ``0.95, 0.90, 0.85, 0.70,
    0.75, 0.80`` times the radius. ``n = 1 + 3 m (m + 1)`` (19, 37, 61, ...): the centre and
    ``m`` rings, ring ``k`` of ``6 k`` points at radius ``k / m`` of the radius, starting at
    90 deg (Klipper's first direction).

    Parameters
    ----------
    n : int
        Number of points.
    radius : float
        Probe radius, m.
    centre : array_like, shape (2,), optional
        Centre of the pattern, m.

    Returns
    -------
    tuple or None
        ``(xy (n, 2), words)``; None for other ``n``.
    """
    centre = np.asarray(centre, float)
    if n == 7:
        a = np.deg2rad(90.0 + 60.0 * np.arange(6))
        d = radius * np.asarray(KLIPPER_SCATTER)
        xy = np.vstack([[0.0, 0.0], np.column_stack([np.cos(a) * d, np.sin(a) * d])])
        return centre + xy, (f"Klipper's DELTA_CALIBRATE pattern (centre + 6 points at 0.7-0.95 "
                             f"of a {radius * 1e3:.4g} mm radius)")
    m = int(round((-3 + np.sqrt(9 + 12 * (n - 1))) / 6)) if n >= 1 else 0
    if m < 1 or 1 + 3 * m * (m + 1) != n:
        return None
    pts = [np.zeros(2)]
    for k in range(1, m + 1):
        a = np.deg2rad(90.0) + 2 * np.pi * np.arange(6 * k) / (6 * k)
        pts += list(radius * k / m * np.column_stack([np.cos(a), np.sin(a)]))
    return centre + np.array(pts), (f"the centre and {m} ring(s) of 6, 12, ... points within "
                                    f"a {radius * 1e3:.4g} mm radius")


#: relative lift (of the characteristic length) of the probe points of :func:`height_groups`
LIFT = 0.01


def height_groups(problem, state, scales, null_space) -> list:
    """Null directions of probe heights that probing at other heights would see, named.

    With every tip on the bed (the same ``probe_z`` everywhere), a change of the machine
    that moves the nozzle along z in proportion to its height above the bed (a vertical
    scale about the bed) changes no height. The directions of the null space that the same
    points, every other one lifted by :data:`LIFT` characteristic lengths, would see are
    returned as one group.

    Parameters
    ----------
    problem : InstrumentProblem
        A probe problem.
    state : InstrumentState
        The state to linearise at.
    scales : ndarray, shape (n,)
        Column scales.
    null_space : ndarray, shape (n, k)
        The problem's null space (scaled).

    Returns
    -------
    list of NullGroup
        Empty, or one group ``vertical scale about the bed``.
    """
    from ..identifiability import NullGroup
    from .data import InstrumentData

    N = np.asarray(null_space, float)
    if N.shape[1] == 0:
        return []
    machine = problem.machine.with_parameters(state.u)
    fk = machine.fk(problem.data.q)
    if not fk.converged.all():
        return []
    P = np.array(fk.P, float)
    P[::2, 2] += LIFT * machine.characteristic_length()
    q = machine.ik(P, fk.R)
    if not np.all(np.isfinite(q)):
        return []
    model = problem.model.with_start(state.nuisance)
    lifted = InstrumentData("probe", q, model.predict(model.initial(), P, fk.R,
                                                      np.zeros(len(P), int)))
    other = InstrumentProblem(machine, lifted, model, problem.noise)
    _, J, _ = other.evaluate(other.initial_state())
    J = (J * scales).reshape(-1, len(scales))
    s0 = np.linalg.svd(J, compute_uv=False)[0]
    _, s, Vt = np.linalg.svd(J @ N, full_matrices=False)
    seen = s > 1e-6 * s0
    if not seen.any():
        return []
    return [NullGroup("vertical scale about the bed",
                      "moving the nozzle along z in proportion to its height above the bed "
                      "changes no height while every probe point lies on the bed (one "
                      "probe_z); probe at a second height too (on a gauge block of known "
                      "thickness, its thickness as probe_z) to see it", N @ Vt[seen].T)]


class ProbeProblem(InstrumentProblem):
    """The instrument problem of probe heights; its null directions are named by the
    machine's frame motions (what absorbs them) and :func:`height_groups`."""

    def null_groups(self, state, scales, null_space=None):
        """The null directions in words.

        Parameters
        ----------
        state : InstrumentState
            The state to linearise at.
        scales : ndarray, shape (n,)
            Column scales.
        null_space : ndarray, shape (n, k), optional
            The null space when known.

        Returns
        -------
        list of NullGroup
            Frame motions, then the vertical scale about the bed when it is null.
        """
        N = self.null_space(state) if null_space is None else np.asarray(null_space, float)
        groups = super().null_groups(state, scales, N)
        # the vertical scale is searched for outside what the frame motions already name: on
        # a tilted bed lifted points see the towers' tilt slightly (heights are vertical, the
        # bed slopes), which would otherwise be named a second time as a "vertical scale"
        rest = N
        if groups and N.shape[1]:
            Q, _ = np.linalg.qr(np.column_stack([g.tangents for g in groups]))
            U, sv, _ = np.linalg.svd(N - Q @ (Q.T @ N), full_matrices=False)
            rest = U[:, sv > 1e-3]
        return groups + height_groups(self, state, scales, rest)


class Probe(Instrument):
    """Bed-probe heights: the nozzle's height above a flat bed of unknown height and tilt."""

    name = "probe"
    aliases = ("probe-heights", "bed-probe")
    words = ("bed-probe heights: the nozzle's height above the bed at the trigger (bed height "
             "and tilt estimated)")
    plan_size = 37

    def applies(self, machine):
        # a vertical probe needs a z axis the platform moves along
        if 2 not in machine.pose_space:
            return ("probe heights are measured along z, which this machine's platform does "
                    f"not move along (it moves along {_space_words(machine)}): measure points "
                    "(tracker) instead")
        return None

    def default_noise(self):
        from .models import IsotropicNoise

        return IsotropicNoise(PROBE_SIGMA)

    def describe_noise(self, noise):
        return f"probe trigger {noise.sigma * 1e6:.3g} um along z (std)"

    def candidates(self, machine, n, rng):
        """Random points uniform on the disk of :func:`probe_radius` on the nominal bed."""
        r = probe_radius(machine)
        centre = bed_centre(machine)
        rho = r * np.sqrt(rng.uniform(0.0, 1.0, n))
        a = rng.uniform(0.0, 2 * np.pi, n)
        P, R = _bed_points(machine, centre + np.column_stack([rho * np.cos(a),
                                                             rho * np.sin(a)]))
        return P, R, None

    def standard_plan(self, machine, n, seed):
        pattern = probe_pattern(n, probe_radius(machine), bed_centre(machine))
        if pattern is None:
            return StandardPlan("a probe pattern of rings on the bed",
                                reason=f"the probe patterns have 7 points (Klipper's "
                                       f"DELTA_CALIBRATE) or 1 + 3 m (m + 1) points (centre and "
                                       f"m rings: 19, 37, 61, ...), not {n}")
        xy, words = pattern
        P, R = _bed_points(machine, xy)
        return StandardPlan(words, P, R)

    def planned_data(self, machine, P, R, rows, source, group=None):
        from .data import InstrumentData
        from .models import ProbeModel

        q = reachable(machine, P, R, rows, source)
        model = ProbeModel()
        state = model.initial()
        state.values[0] = bed_height(machine)
        h = model.predict(state, P, R, np.zeros(len(P), int))
        return InstrumentData("probe", q, h, np.zeros(len(P), int), rows, source, P, R)

    def problem(self, machine, data, noise=None, **start):
        from .bed import bed_choice

        noise = self.default_noise() if noise is None else noise
        # a printer's frame is its bed: its height held at 0, its tilt where the data tell it
        model = bed_choice(machine, data, noise).model()
        values = np.array(model.parameters.values, float)
        values[0] = bed_height(machine)
        model.parameters = model.parameters.with_values(values)
        return ProbeProblem(machine, data, model, noise)

    measurement_words = ("bed-probe heights (bed height and tilt estimated jointly; on a "
                         "printer the bed is z = 0 and its tilt estimated where the data tell "
                         "it)")

    def noise_arg(self, text, machine=None):
        """The probe noise of ``--noise`` (text or SI number or model; default
        :data:`PROBE_SIGMA`)."""
        from ..plausibility import check_option_scale
        from ..units import parse_quantity
        from .models import IsotropicNoise

        if text is None:
            return IsotropicNoise(PROBE_SIGMA)
        if hasattr(text, "whitening"):
            return text
        sigma = parse_quantity(text, "length", "--noise") if isinstance(text, str) \
            else float(text)
        if not sigma > 0:
            raise InputError(f"--noise: must be > 0 (the standard deviation of the probe's "
                             f"trigger height), got {text}")
        check_option_scale(sigma, machine, "--noise", "noise", str(text))
        return IsotropicNoise(sigma)

    #: the io reader of its CSV files (:func:`pkmcal.io.read_measurements`)
    reader = "read_probe"

    def measured_problem(self, machine, data, noise=None, source=""):
        """The bed's height and tilt started from the data on the machine's geometry."""
        from .bed import bed_choice

        noise = self.default_noise() if noise is None else noise
        fk = _fk_of(machine, data, source)
        model = bed_choice(machine, data, noise).model().start(fk.P, fk.R, data.values,
                                                               data.group, str(source))
        return InstrumentProblem(machine, data, model, noise)


class PairDistance(Instrument):
    """Distances between the platform point at two sets of readings (a caliper on a printed
    part, Klipper's DELTA_ANALYZE object): :mod:`pkmcal.instruments.pairs`. A plan's poses
    come in pairs, rows ``2k`` and ``2k + 1`` one distance."""

    name = "pair-distances"
    aliases = ("caliper", "two-point-distances")
    words = ("distances between the nozzle at two sets of readings (a caliper on a printed "
             "part; Klipper's DELTA_ANALYZE object)")
    plan_size = 24

    def applies(self, machine):
        return None

    def default_noise(self):
        from .models import IsotropicNoise
        from .pairs import PAIR_SIGMA

        return IsotropicNoise(PAIR_SIGMA)

    def describe_noise(self, noise):
        return f"distance {noise.sigma * 1e6:.4g} um (std)"

    def noise_arg(self, text, machine, allow_zero: bool = False):
        """The noise of ``--noise`` (text with a unit, an SI number or a noise model; None:
        the default); ``allow_zero``: 0 gives exact data (False), as ``simulate`` takes it.

        Raises
        ------
        InputError
            Naming ``--noise``: not a length, not above 0, or beyond the machine's scale.
        """
        from ..plausibility import check_option_scale
        from ..units import parse_quantity
        from .models import IsotropicNoise

        if text is None:
            return self.default_noise()
        if hasattr(text, "whitening"):
            return text
        sigma = parse_quantity(text, "length", "--noise") if isinstance(text, str) \
            else float(text)
        if not (sigma > 0 or (allow_zero and sigma == 0)):
            raise InputError(f"--noise: must be > 0 (the standard deviation of a measured "
                             f"distance), got {text}")
        if sigma == 0:
            return False
        check_option_scale(sigma, machine, "--noise", "noise", str(text))
        return IsotropicNoise(sigma)

    def candidates(self, machine, n, rng):
        raise InputError("pair-distances: poses are chosen in pairs (one distance each); "
                         "pose selection picks single poses - use the standard plan, "
                         "Klipper's DELTA_ANALYZE object (--scenario pair-distances)")

    def standard_plan(self, machine, n, seed):
        from .pairs import klipper_object_pairs

        pairs, words = klipper_object_pairs(height=bed_height(machine))
        if n != 2 * len(pairs):
            return StandardPlan(words, reason=f"Klipper's object has {len(pairs)} distances "
                                              f"({2 * len(pairs)} poses), not {n} poses")
        P = pairs.reshape(-1, 3)
        return StandardPlan(words, P, np.broadcast_to(np.eye(3), (len(P), 3, 3)).copy())

    def planned_data(self, machine, P, R, rows, source, group=None):
        from .pairs import pair_data

        if len(P) % 2:
            raise InputError(f"{source}: {len(P)} poses; two-point distances take them in "
                             "pairs")
        q = reachable(machine, P, R, rows, source)
        d = np.linalg.norm(P[0::2] - P[1::2], axis=-1)
        return pair_data(q[0::2], q[1::2], d, np.asarray(rows)[0::2], source)

    def simulate(self, machine, true, n, noise, rng, truth):
        """Klipper's object printed by the nominal model's commands on the true machine and
        measured: each distance between the true nozzle positions of the commanded pair,
        plus the noise (``noise`` an ``IsotropicNoise``, default :data:`PAIR_SIGMA`; False:
        exact). ``n`` must be the plan's poses (24).

        Returns
        -------
        tuple
            ``(data, true, truth)`` as :func:`~pkmcal.instruments.simulate.simulate_scenario`.
        """
        from .pairs import pair_data

        plan = self.standard_plan(machine, n, 0)
        if not plan.available:
            raise InputError(f"--poses {n}: {plan.reason}")
        q = reachable(machine, plan.P, plan.R, np.arange(1, len(plan.P) + 1), "the plan")
        fk = true.fk(q)
        if not fk.converged.all():
            raise InputError("the true machine cannot reach the plan's points")
        d = np.linalg.norm(fk.P[0::2] - fk.P[1::2], axis=-1)
        model = self.default_noise() if noise is None else noise
        if model is not False and model is not None:
            d = d + model.sample(d[:, None], rng)[:, 0]
        data = pair_data(q[0::2], q[1::2], d, None, "<simulated>")
        truth.update(poses=plan.name, rows=[
            ("object", f"printed at the nominal model's commands; the distances of the true "
                       f"nozzle positions, {d.min() * 1e3:.6g}..{d.max() * 1e3:.6g} mm")])
        return data, true, truth

    def problem(self, machine, data, noise=None, **start):
        from .pairs import PairDistanceModel, PairProblem

        return PairProblem(machine, data, PairDistanceModel(),
                           self.default_noise() if noise is None else noise)

    measurement_words = ("distances between the nozzle at two sets of readings (no unknown of "
                         "their own)")

    #: the io reader of its CSV files (:func:`pkmcal.io.read_measurements`)
    reader = "read_pairs"


#: the instruments by canonical name
INSTRUMENTS: dict[str, Instrument] = {i.name: i for i in (ConstraintLink(), Tracker(), Pose(),
                                                          Distance(), Probe(), PairDistance())}


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


def _sigma_arg(text, machine, what: str, default: float) -> float:
    """A standard deviation of ``--noise`` (text with a unit or an SI number; None: the
    default), m; checked against the machine's size when given."""
    from ..plausibility import check_option_scale
    from ..units import parse_quantity

    if text is None:
        return default
    sigma = parse_quantity(text, "length", "--noise") if isinstance(text, str) \
        else float(text)
    if not sigma > 0:
        raise InputError(f"--noise: must be > 0 (the standard deviation of the {what}), "
                         f"got {text}")
    if machine is not None:
        check_option_scale(sigma, machine, "--noise", "noise", str(text))
    return sigma


def _fk_of(machine: Machine, data, source):
    """The forward kinematics of measured readings; InputError naming the rows none
    reproduces."""
    fk = machine.fk(data.q)
    if not fk.converged.all():
        raise InputError(f"{source}: row(s) {_rows(data.rows[~fk.converged])}: no "
                         f"platform pose of {machine.source} reproduces these readings "
                         "(outside the workspace, or a wrong unit or zero)")
    return fk
