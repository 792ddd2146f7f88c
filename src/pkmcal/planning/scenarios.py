"""Measurement scenarios before any measurement: candidate poses and planned problems.

A *plan* is a set of platform poses at which a machine will be measured. From a plan and the
nominal machine we build exactly the calibration problem ``pkmcal calibrate`` would solve if
the measurements came back noise-free (readings from the nominal inverse kinematics, measured
points or poses through the nominal measurement frames). Its scaled, whitened identification
Jacobian gives identifiability, the Cramer-Rao bound and the information each pose adds
(:mod:`pkmcal.planning.design`), all without a measurement.

Scenarios (one per measurement type, SPEC 2):

- ``constraint-link`` (Hexa Slide, seed 000): poses with ``|P| = Lc``; six joint readings,
  the encoder noise ``sigma`` (m) weighs them.
- ``tracker`` (Delta, seed 001): platform points; a laser tracker measures the reflector;
  :class:`~pkmcal.measurements.TrackerNoise` weighs them; the registration is estimated
  jointly.
- ``pose`` (six-leg platforms, SPEC 2.4): platform poses; leg readings and a motion-capture
  pose through unknown measurement frames; :class:`~pkmcal.measurements.FullPoseNoise`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..machines.base import Machine

#: the measurement type each machine kind is calibrated from
SCENARIO_OF = {"hexaslide": "constraint-link", "delta": "tracker", "stewart": "pose"}
SCENARIOS = ("constraint-link", "tracker", "pose")
#: default plan sizes (seed 000: 150 poses; seed 001: a 3x3x3 grid; SPEC 2.4: 60 poses)
DEFAULT_PLAN_SIZE = {"constraint-link": 150, "tracker": 27, "pose": 60}
#: constraint-link plans: largest allowed deviation of |P| from Lc (m); poses within it are
#: put on the sphere (rounding in a hand-made plan file)
SPHERE_TOL = 1e-4


def scenario_for(machine: Machine, scenario: str | None = None) -> str:
    """The measurement type of ``machine`` (``scenario`` checked against it when given).

    Parameters
    ----------
    machine : Machine
        The machine (its ``kind``).
    scenario : {'constraint-link', 'tracker', 'pose'}, optional
        A requested scenario.

    Returns
    -------
    str
        The machine's scenario (:data:`SCENARIO_OF`).

    Raises
    ------
    InputError
        When the machine type has no scenario, or ``scenario`` is unknown or not the machine's.
    """
    kind = getattr(machine, "kind", "")
    own = SCENARIO_OF.get(kind)
    if scenario is None:
        if own is None:
            raise InputError(f"no measurement scenario for machines of type {kind!r}")
        return own
    if scenario not in SCENARIOS:
        raise InputError(f"unknown scenario {scenario!r}; use one of {', '.join(SCENARIOS)}")
    if scenario != own:
        raise InputError(f"a {kind} is calibrated from {own} measurements in this version, not "
                         f"{scenario}")
    return scenario


def default_noise(scenario: str):
    """The default noise model of a scenario (as ``pkmcal calibrate`` assumes).

    Parameters
    ----------
    scenario : {'constraint-link', 'tracker', 'pose'}
        The scenario.

    Returns
    -------
    float, TrackerNoise or FullPoseNoise
        Encoder noise 1e-6 m for ``constraint-link``; the default ``TrackerNoise`` for
        ``tracker``; the default ``FullPoseNoise`` otherwise.
    """
    if scenario == "constraint-link":
        return 1e-6
    if scenario == "tracker":
        from ..measurements import TrackerNoise

        return TrackerNoise()
    from ..measurements import FullPoseNoise

    return FullPoseNoise()


def describe_noise(scenario: str, noise) -> str:
    """The noise model in words, for reports.

    Parameters
    ----------
    scenario : {'constraint-link', 'tracker', 'pose'}
        The scenario.
    noise : float, TrackerNoise or FullPoseNoise
        The noise model of that scenario (:func:`default_noise`).

    Returns
    -------
    str
        One line, values in um and urad.
    """
    if scenario == "constraint-link":
        return f"encoder noise {noise * 1e6:.4g} um (std)"
    if scenario == "tracker":
        return (f"laser tracker: {noise.distance * 1e6:.3g} um along the beam, "
                f"{noise.transverse * 1e6:.3g} um + {noise.transverse_per_m * 1e6:.3g} um/m "
                "across (std)")
    return (f"leg readings {noise.reading_m * 1e6:.3g} um, poses {noise.position_m * 1e6:.3g} "
            f"um / {noise.orientation_rad * 1e6:.3g} urad (std)")


@dataclass
class StandardPlan:
    """The instrument's standard measurement plan of a scenario (what one measures without
    planning), or the reason there is none of a given size.

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
    """

    name: str
    P: np.ndarray | None = None
    R: np.ndarray | None = None
    reason: str = ""

    @property
    def available(self) -> bool:
        """True when the plan has poses."""
        return self.P is not None

    def __len__(self) -> int:
        return 0 if self.P is None else len(self.P)


def _tracker_grid_plan(machine: Machine, n: int, seed: int) -> StandardPlan:
    """Seed 001's grid (3x3x3, dx = dy = 150 mm, dz = 40 mm around home); for ``n = k^3``
    the k x k x k grid spanning the same box."""
    from ..measurements import TRACKER_GRID_SPACING, grid_points

    k = int(round(n ** (1.0 / 3.0)))
    if k < 2 or k**3 != n:
        return StandardPlan("seed 001's grid around home",
                            reason=f"seed 001's grid has 3 x 3 x 3 = 27 points (k x k x k "
                                   f"grids in its box: 8, 27, 64, ...), not {n}")
    span = 2.0 * np.asarray(TRACKER_GRID_SPACING, float)       # the 3x3x3 grid's extent
    P = grid_points(machine.home[0], span / (k - 1), (k, k, k))
    return StandardPlan(f"the {k}x{k}x{k} grid of seed 001 around home", P,
                        np.broadcast_to(np.eye(3), (n, 3, 3)))


def _sampled_plan(machine: Machine, scenario: str, n: int, seed: int) -> StandardPlan:
    """The simulations' default sample of ``n`` poses (:func:`candidate_poses` with ``seed``)."""
    P, R = candidate_poses(machine, scenario, n, rng=seed)
    where = "on the constraint sphere" if scenario == "constraint-link" else "around home"
    return StandardPlan(f"{n} random planned poses {where} (seed {seed})", P, R)


#: the standard plan of each scenario: ``(machine, n, seed) -> StandardPlan``
STANDARD_PLANS = {
    "constraint-link": lambda machine, n, seed: _sampled_plan(machine, "constraint-link", n,
                                                              seed),
    "tracker": _tracker_grid_plan,
    "pose": lambda machine, n, seed: _sampled_plan(machine, "pose", n, seed),
}


def standard_plan(machine: Machine, scenario: str, n: int | None = None,
                  seed: int = 0) -> StandardPlan:
    """The instrument's standard plan of ``n`` poses: what ``pkmcal identifiability`` analyses
    without data, and what ``pkmcal select-poses`` compares with and starts from.

    A machine may define its own (a method ``standard_plan(scenario, n, seed)`` returning a
    :class:`StandardPlan`); otherwise the scenario's entry of :data:`STANDARD_PLANS`: tracker,
    seed 001's 3x3x3 grid (dx = dy = 150 mm, dz = 40 mm around home; k x k x k grids in the
    same box for ``n = k^3``, none for other ``n``); constraint link and full pose, the
    simulations' default sample of ``n`` feasible poses (:func:`candidate_poses`, ``seed``).

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    scenario : {'constraint-link', 'tracker', 'pose'}
        The scenario.
    n : int, optional
        Number of poses; default :data:`DEFAULT_PLAN_SIZE` of the scenario.
    seed : int, optional
        Seed of sampled plans.

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
    if scenario not in SCENARIOS:
        raise InputError(f"unknown scenario {scenario!r}; use one of {', '.join(SCENARIOS)}")
    n = DEFAULT_PLAN_SIZE[scenario] if n is None else int(n)
    if n < 1:
        raise InputError(f"the number of planned poses must be >= 1, got {n}")
    own = getattr(machine, "standard_plan", None)
    if callable(own):
        return own(scenario, n, seed)
    return STANDARD_PLANS[scenario](machine, n, seed)


def candidate_poses(machine: Machine, scenario: str, n: int, rng=None):
    """``n`` feasible candidate poses of a scenario.

    constraint-link: the sphere ``|P| = Lc`` (cap of 35 deg around home, rotations within
    +/-25 deg), reachable, well conditioned and drivable with the link mounted
    (:func:`~pkmcal.measurements.sample_sphere_poses`). tracker: uniform in the box spanned by
    seed 001's 3x3x3 grid around home, reachable and away from singular poses. pose: the SPEC 5
    workspace (0.1 m cube around home, +/-10 deg), well conditioned
    (:func:`~pkmcal.measurements.sample_platform_poses`).

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    scenario : {'constraint-link', 'tracker', 'pose'}
        The scenario.
    n : int
        Number of poses (>= 1).
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.

    Returns
    -------
    P : ndarray, shape (n, 3)
        Positions, m.
    R : ndarray, shape (n, 3, 3)
        Orientations (the identity for ``tracker``).

    Raises
    ------
    InputError
        When ``n < 1``, a constraint-link machine has no link length, or not enough feasible
        poses are found.
    """
    if n < 1:
        raise InputError(f"the number of candidate poses must be >= 1, got {n}")
    rng = np.random.default_rng(rng)
    if scenario == "constraint-link":
        from ..measurements import sample_sphere_poses

        return sample_sphere_poses(machine, link_length(machine), n, rng)
    if scenario == "tracker":
        from ..measurements import TRACKER_GRID_SPACING
        from ..measurements.deviations import draw_accepted

        half = np.asarray(TRACKER_GRID_SPACING, float)      # the 3x3x3 grid spans +/- spacing
        centre = machine.home[0]

        def draw(m, rng):
            P = centre + rng.uniform(-1.0, 1.0, (m, 3)) * half
            R = np.broadcast_to(np.eye(3), (m, 3, 3))
            q, J, _ = machine.ik_jacobians(P, R, want_du=False)
            ok = np.all(np.isfinite(q), -1)
            ok[ok] = _translation_conditioning(J[ok]) > 0.05
            return P, R, ok

        where = str(getattr(machine, "source", "") or "").replace("{", "{{").replace("}", "}}")
        return draw_accepted(draw, n, rng, (f"{where}: " if where else "")
                             + "only {have} of {n} candidate points around home are reachable "
                             "and well conditioned: check the geometry and home")
    from ..measurements import sample_platform_poses

    return sample_platform_poses(machine, n, rng)


def _translation_conditioning(J):
    """Inverse condition number of the translation columns of joint Jacobians (K, n, 6)."""
    sv = np.linalg.svd(np.asarray(J)[..., :3], compute_uv=False)
    return sv[..., -1] / sv[..., 0]


def link_length(machine: Machine) -> float:
    Lc = getattr(machine, "constraint_link_length", None)
    if Lc is None:
        raise InputError(f"{getattr(machine, 'source', 'the machine file')}: no "
                         "constraint_link length; constraint-link plans need it")
    return float(Lc)


def planned_data(machine: Machine, scenario: str, P, R=None, rows=None, source="<plan>"):
    """Noise-free measurements of the *nominal* machine at planned poses.

    Constraint-link plans get the passive actuator cycling through the joints; tracker plans
    are measured through :func:`tracker_pose`, pose plans through :func:`measurement_frames`.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    scenario : {'constraint-link', 'tracker', 'pose'}
        The scenario.
    P : array_like, shape (K, 3)
        Planned positions, m.
    R : array_like, shape (K, 3, 3), optional
        Planned orientations; default identity.
    rows : array_like of int, optional
        Row labels for messages; default 1..K.
    source : str, optional
        Name of the plan, for messages.

    Returns
    -------
    ConstraintLinkData, TrackerData or FullPoseData
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
    if scenario == "constraint-link":
        P = _on_sphere(P, machine, rows, source)
    q = machine.ik(P, R)
    bad = ~np.all(np.isfinite(q), -1)
    if bad.any():
        raise InputError(f"{source}: row(s) {_rows(rows[bad])}: pose(s) the machine cannot "
                         "reach")
    if scenario == "constraint-link":
        from ..measurements import ConstraintLinkData

        return ConstraintLinkData(q, link_length(machine), np.arange(len(P)) % machine.n_joints,
                                  rows, source, true_P=P, true_R=R)
    if scenario == "tracker":
        from ..measurements import TrackerData

        Rt, t = tracker_pose(machine)
        smr = P - np.array([0.0, 0.0, getattr(machine, "smr_offset", 0.0)])
        return TrackerData(q, (smr - t) @ Rt, rows=rows, source=source, true_P=P)
    from ..measurements import FullPoseData

    Pm, Rm = measurement_frames(machine).measured(P, R)
    return FullPoseData(q, Pm, Rm, rows, source, true_P=P, true_R=R)


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
        ``(R (3, 3), t (3,))`` (:func:`~pkmcal.measurements.default_tracker_pose` when the
        machine has none).
    """
    pose = getattr(machine, "base_from_tracker", None)
    if pose is None:
        from ..measurements import default_tracker_pose

        pose = default_tracker_pose()
    return pose


def measurement_frames(machine: Machine):
    """``measurement_frames`` of the machine file, else the simulations' default.

    Parameters
    ----------
    machine : Machine
        The machine (its ``measurement_frames``, if any).

    Returns
    -------
    MeasurementFrames
        The frames (:func:`~pkmcal.measurements.default_measurement_frames` when the machine has
        none).
    """
    frames = getattr(machine, "measurement_frames", None)
    if frames is None:
        from ..measurements import default_measurement_frames

        frames = default_measurement_frames()
    return frames


def scenario_problem(machine: Machine, scenario: str, data, noise=None, registration=None,
                     frames=None):
    """The calibration problem ``pkmcal calibrate`` solves by default for ``data``, unsolved.

    ML with the per-pose unknowns for the constraint link; joint registration for the tracker;
    ML with the measurement frames estimated for full poses; at the nominal machine.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    scenario : {'constraint-link', 'tracker', 'pose'}
        The scenario.
    data : ConstraintLinkData, TrackerData or FullPoseData
        The measurements.
    noise : float, TrackerNoise or FullPoseNoise, optional
        Noise model; default :func:`default_noise`.
    registration : tuple of ndarray, optional
        Tracker: start ``base_from_tracker``; default :func:`tracker_pose`.
    frames : MeasurementFrames, optional
        Pose: start frames; default :func:`measurement_frames`.

    Returns
    -------
    ConstraintLinkML, TrackerProblem or FullPoseML
        The problem.

    Raises
    ------
    InputError
        When the problem cannot be set up for these data (see the problem classes).
    """
    noise = default_noise(scenario) if noise is None else noise
    if scenario == "constraint-link":
        from ..calibration import ConstraintLinkML

        return ConstraintLinkML(machine, data, noise)
    if scenario == "tracker":
        from ..calibration import TrackerProblem

        return TrackerProblem(machine, data, noise,
                              tracker_pose(machine) if registration is None else registration)
    from ..calibration import FullPoseML

    return FullPoseML(machine, data, noise,
                      measurement_frames(machine) if frames is None else frames)


def planned_problem(machine: Machine, scenario: str, P, R=None, noise=None, rows=None,
                    source="<plan>"):
    """:func:`scenario_problem` of the noise-free :func:`planned_data` at poses ``(P, R)``.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    scenario : {'constraint-link', 'tracker', 'pose'}
        The scenario.
    P : array_like, shape (K, 3)
        Planned positions, m.
    R : array_like, shape (K, 3, 3), optional
        Planned orientations; default identity.
    noise : float, TrackerNoise or FullPoseNoise, optional
        Noise model; default :func:`default_noise`.
    rows : array_like of int, optional
        Row labels for messages.
    source : str, optional
        Name of the plan, for messages.

    Returns
    -------
    ConstraintLinkML, TrackerProblem or FullPoseML
        The problem.

    Raises
    ------
    InputError
        As :func:`planned_data` and :func:`scenario_problem`.
    """
    return scenario_problem(machine, scenario,
                            planned_data(machine, scenario, P, R, rows, source), noise)


def _rows(rows, limit: int = 10) -> str:
    rows = [int(r) for r in rows]
    return ", ".join(map(str, rows[:limit])) + (" ..." if len(rows) > limit else "")
