"""Bed-probe heights: the nozzle's height above a flat bed at the probe's trigger, its plans
(Klipper's DELTA_CALIBRATE pattern, rings), the vertical scale heights cannot see, and its
calibration.

Calibration from bed-probe heights, and what heights fix only weakly.

The instrument's model is :class:`~pkmcal.instruments.ProbeModel`: the bed is the plane
``z = bed.z + bed.tilt_x x + bed.tilt_y y`` (base frame) and each row is the nozzle's height
above it, along z, at the readings where the probe triggered (``probe_z``, 0 for a probe that
triggers on nozzle contact). The machine's parameters and the bed are estimated together by
the shared estimator (:func:`~pkmcal.instruments.fit_instrument`): the bed starts from a plane
fit on the machine file's model, then the bed alone is fitted, then everything.

What heights cannot fix is found in the numerical null space and named
(:mod:`pkmcal.instruments.problem`): a frame motion of the machine that the bed plane
absorbs (a translation along z of the base frame - on a printer, every endstop shifted by the
same amount - with ``bed.z``, a tilt of the base frame with the bed's tilt), the motions no
height sees at all (translations and turns in the bed's plane), a vertical scale about the bed
(invisible while every probe point lies on the bed: probing at a second height sees it;
:func:`~pkmcal.instruments.probe.height_groups`) and the parameter combinations nothing
explains.

What heights fix only *weakly* is another matter: a parameter may be determined, but with a
standard deviation far beyond what a calibration is for (a Delta printer's arm lengths, fitted
from heights with a standard deviation of the order of a millimetre, nearly equal to a change
of the radius). Every calibration names such parameters by one rule, whatever the instrument
(:mod:`pkmcal.identifiability.determination`: a standard deviation beyond 1/2500 of the
machine's size at its scale, 0.1 mm on a 250 mm printer); the probe says what to measure next
(:attr:`Probe.measure_next`).
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
from ..identifiability.determination import poorly_determined
from ..machines.base import Machine, bed_height_at
from ..machines.file_format import BedPlane
from ..machines.reach import (
    _bed_points,
    bed_centre,
    bed_height,
    probe_radius,
)
from ..paths import path_text
from .base import (
    Instrument,
    StandardPlan,
    _fk_of,
    _simulated_sigma,
    _space_words,
    has_column,
    reachable,
)
from .bed import BedChoice, bed_choice
from .data import InstrumentData
from .experiment import MOUNTING_ERROR
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
from .models import IsotropicNoise, ProbeModel
from .problem import InstrumentProblem, fit_instrument

#: the probe's repeatability assumed by default, m (standard deviation of the trigger height).
#: An assumption, not a datum: the order of the spread that Klipper's PROBE_ACCURACY reports for
#: common bed probes (a few um for a good touch or piezo probe, 10-20 um for inductive ones)
PROBE_SIGMA = 10e-6


#: half-width of the random error of a simulated bed's height, m
BED_ERROR = 1e-3
#: half-width of a simulated bed's random slopes dz/dx, dz/dy (1 mm over a metre)
TILT_ERROR = 1e-3

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


def _refuse_points_outside_limits(machine: Machine, P, R, words: str) -> None:
    """Refuse planned probe points whose nominal joint values break the machine file's
    ``joint_limits`` (a probe_radius the file sets may reach beyond them), naming the limits
    and the points, numbered 1.. in the plan's order."""
    if getattr(machine, "joint_limits", None) is None:
        return
    with np.errstate(all="ignore"):
        q = np.asarray(machine.ik(P, R), float)
    outside = ~machine.within_limits(q) & np.all(np.isfinite(q), axis=-1)
    if outside.any():
        where = getattr(machine, "source", None) or "the machine file"
        raise InputError(
            f"{where}: joint_limits ({machine.joint_limits_text()}) exclude "
            f"{int(outside.sum())} of the {len(P)} probe points ({words}): probe point "
            + machine.limit_violation_text(q[outside], np.flatnonzero(outside) + 1, limit=3)
            .replace("row ", "") + "; widen joint_limits"
            + (" or lower probe_radius" if getattr(machine, "probe_radius", None) is not None
               and not callable(machine.probe_radius) else ""))


@dataclass(frozen=True, slots=True)
class ProbeOptions:
    """The options of the probe's calibration flow (:meth:`Probe.calibrate`)."""

    noise: object = option(
        None, "--noise", "the trigger's repeatability along z (default 10um); held as given, "
        "else estimated from the residuals.")
    robust: bool = option(
        False, "--robust", "Leave out the rows the noise cannot explain (a chi-square test of "
        "each row) and fit again.")
    bed_tilt: str | None = option(
        None, "--bed-tilt", "On a printer (its frame is its bed, z = 0): auto "
        "(default) estimates the bed's tilt against the towers where the data tell it from "
        "the parameter set and takes the bed square to the towers otherwise, as the firmware "
        "does; estimate / square force either.", metavar="MODE",
        choices=("auto", "estimate", "square"), joint=True)


@dataclass(frozen=True)
class BedSetup:
    """A printer's bed as a probe measured it (the machine file's ``bed:`` section): the plane
    ``z = height + tilt_x x + tilt_y y`` of the base frame and, optionally, its own shape
    beside the plane.

    Attributes
    ----------
    height : float
        Height of the plane at x = y = 0, m.
    tilt_x, tilt_y : float
        Slopes dz/dx, dz/dy.
    surface : tuple or None
        ``(radius m, values (n, n) m)``: heights on a square grid over ``[-radius, radius]``
        in x and y, rows by ascending y (:mod:`pkmcal.calibration.bed_surface`); None: flat.
    """

    height: float = 0.0
    tilt_x: float = 0.0
    tilt_y: float = 0.0
    surface: tuple | None = None

    @property
    def plane(self) -> tuple[float, float, float]:
        """``(height, tilt_x, tilt_y)``."""
        return (float(self.height), float(self.tilt_x), float(self.tilt_y))

    def height_at(self, xy) -> np.ndarray:
        """The bed's height (m) at positions ``xy`` (K, 2): its plane and surface
        (:func:`~pkmcal.machines.base.bed_height_at`)."""
        return bed_height_at(self.plane, xy, self.surface)

    def shifted(self, t) -> BedSetup:
        """The bed seen from a base frame whose points moved by ``t`` (m)."""
        tx, ty, tz = (float(v) for v in np.asarray(t, float))
        h = self.height + tz - self.tilt_x * tx - self.tilt_y * ty
        return BedSetup(h, self.tilt_x, self.tilt_y, self.surface)

    def frame_shift(self, machine):
        """The shift that puts the bed at z = 0 on a machine whose frame is its bed (a
        printer, SPEC 8), else None."""
        if not getattr(machine, "frame_is_bed", False) or float(self.height) == 0.0:
            return None
        return np.array([0.0, 0.0, -float(self.height)])

    def targets_in_base(self, machine, P):
        """Targets given in a printer's frame (z their height above this bed), in the base
        frame (:meth:`~pkmcal.machines.Machine.targets_in_base`)."""
        return machine.targets_in_base(P, self.plane)

    def targets_from_base(self, machine, P):
        """Base-frame positions in a printer's frame (z their height above this bed): the
        inverse of :meth:`targets_in_base`."""
        return machine.targets_from_base(P, self.plane)


def bed_of(setups) -> BedSetup | None:
    """The printer's bed among an experiment's set-ups (the probe's :class:`BedSetup`).

    Parameters
    ----------
    setups : Setups or None
        The set-ups (:class:`~pkmcal.instruments.setups.Setups`).

    Returns
    -------
    BedSetup or None
        None without one.
    """
    return None if setups is None else setups.get(Probe.name)


def bed_plane(setups) -> tuple[float, float, float] | None:
    """The plane ``(height m, tilt_x, tilt_y)`` of the bed among an experiment's set-ups
    (:func:`bed_of`), as the machines' methods take it (``bed=``); None without one.

    Parameters
    ----------
    setups : Setups or None
        The set-ups.

    Returns
    -------
    tuple of float or None
        The plane.
    """
    bed = bed_of(setups)
    return None if bed is None else bed.plane


class Probe(Instrument):
    """Bed-probe heights: the nozzle's height above a flat bed of unknown height and tilt."""

    name = "probe"
    aliases = ("probe-heights", "bed-probe")
    calibrate_help = """
        A Klipper printer.cfg is data too: the heights, manual heights and DELTA_ANALYZE
        distances its [delta_calibrate] section saved (step counts turned into millimetres
        with the steppers' rotation_distance, microsteps, full_steps_per_rotation, gear_ratio)
        and its bed meshes ([bed_mesh NAME], read back into carriage travels with the values
        in force while probing; each mesh its own height offset; a mesh that disagrees with
        the points beside it is left out, named). Several configs (printer.cfg and Klipper's
        backups printer-YYYYMMDD_HHMMSS.cfg) are sessions: the same saved points counted
        once, each session but the newest with its own endstop offsets.

        Example: `pkmcal calibrate printer.yaml printer.cfg --parameters klipper-basic -o
        cal.yaml`

        Example: `pkmcal calibrate printer.yaml printer.cfg printer-*.cfg -o cal.yaml`
        """
    words = ("bed-probe heights: the nozzle's height above the bed at the trigger (bed height "
             "and tilt estimated)")
    plan_size = 37
    #: the quantities of its machine-file section (unit conversion, magnitude checks)
    file_quantities = {("bed", "height"): "length"}
    columns = ("the joint readings q1_<unit>.. where the probe triggered and probe_z_mm (the "
               "nozzle's height above the bed there, 0 for a nozzle-contact probe)")
    priority = 25
    fixes_lengths = False
    measures_bed_height = True
    #: its measurements in words (messages)
    singular = "probe height"
    plural = "probe heights"
    measure_next = ("distances (a ballbar, or caliper distances between features of a printed "
                    "object, as Klipper's enhanced DELTA_CALIBRATE) or points (a laser tracker)")

    def detect(self, header):
        return has_column(header, "probe_z")

    def applies(self, machine):
        # a vertical probe needs a z axis the platform moves along
        if 2 not in machine.pose_space:
            return ("probe heights are measured along z, which this machine's platform does "
                    f"not move along (it moves along {_space_words(machine)}): measure points "
                    "(tracker) instead")
        return None

    def unbounded_cause(self, machine):
        if getattr(machine, "frame_is_bed", False):
            return None
        from ..machines.registry import bed_frame_kinds

        printers = " or ".join(f"machine: {k}" for k in bed_frame_kinds()) or "a printer"
        return (f"a {machine.kind} has no bed (its frame is not a probed bed, as that of "
                f"{printers} is; a bed section does not make it one): probe heights see the "
                "tool's height above a bed plane they estimate, whose height and tilt take "
                "up moves of the whole platform, whatever the points probed")

    def default_noise(self):
        from .models import IsotropicNoise

        return IsotropicNoise(PROBE_SIGMA)

    def describe_noise(self, noise):
        return f"probe trigger {noise.sigma * 1e6:.3g} um along z (std)"

    montecarlo_variables = ("noise", "poses", "tolerance")
    montecarlo_metrics = {
        "height_mean": ("um", 1e-6, "mean held-out error of the nozzle's height over the bed"),
        "height_max": ("um", 1e-6, "max held-out error of the nozzle's height over the bed"),
    }
    montecarlo_evaluation_poses = 100
    montecarlo_poses = 37

    def montecarlo_run(self, run):
        """Bed-probe heights at the standard pattern (the true bed off by a random height and
        tilt), the bed plane estimated with the machine; held out: the height of the nozzle
        over the bed at other points of the bed, 1 mm above it, with the readings the nominal
        model commands there - the calibrated model and its bed against the truth."""
        s = run.settings
        nominal = s.machine
        noise = 1e-5 if s.noise is None else s.noise
        data, true, truth = run.simulate(s.poses or self.montecarlo_poses,
                                         IsotropicNoise(noise) if noise > 0 else False)
        res = calibrate_probe(nominal, data, IsotropicNoise(run.weight(noise)))
        P, R, _ = self.candidates(nominal, self.montecarlo_evaluation_poses, run.rng,
                                  s.setups.get(self.name))
        q = nominal.ik(P + np.array([0.0, 0.0, 1e-3]), R)

        def heights(machine, bed):
            fk = machine.fk(q, start=(P, R))
            z0, tx, ty = bed
            h = fk.P[:, 2] - (z0 + tx * fk.P[:, 0] + ty * fk.P[:, 1])
            return np.where(fk.converged, h, np.nan)

        e = np.abs(heights(res.machine, res.section(ProbeSection).bed)
                   - heights(true, truth["bed"]))
        ok = np.isfinite(e)
        return res, {"height_mean": float(np.mean(e[ok])) if ok.any() else math.nan,
                     "height_max": float(np.max(e[ok])) if ok.any() else math.nan}

    def candidates(self, machine, n, rng, setup=None):
        """Random points uniform on the disk of :func:`probe_radius` on the nominal bed."""
        plane = None if setup is None else setup.plane
        r = probe_radius(machine, plane)
        centre = bed_centre(machine)
        rho = r * np.sqrt(rng.uniform(0.0, 1.0, n))
        a = rng.uniform(0.0, 2 * np.pi, n)
        P, R = _bed_points(machine, centre + np.column_stack([rho * np.cos(a),
                                                             rho * np.sin(a)]), plane)
        return P, R, None

    def standard_plan(self, machine, n, seed, setup=None):
        plane = None if setup is None else setup.plane
        pattern = probe_pattern(n, probe_radius(machine, plane), bed_centre(machine))
        if pattern is None:
            return StandardPlan("a probe pattern of rings on the bed",
                                reason=f"the probe patterns have 7 points (Klipper's "
                                       f"DELTA_CALIBRATE) or 1 + 3 m (m + 1) points (centre and "
                                       f"m rings: 19, 37, 61, ...), not {n}")
        xy, words = pattern
        P, R = _bed_points(machine, xy, plane)
        return StandardPlan(words, P, R)

    def planned_data(self, machine, P, R, rows, source, group=None, setup=None):
        from .models import ProbeModel

        q = reachable(machine, P, R, rows, source)
        model = ProbeModel()
        state = model.initial()
        state.values[0] = bed_height(machine)
        h = model.predict(state, P, R, np.zeros(len(P), int))
        return InstrumentData("probe", q, h, np.zeros(len(P), int), rows, source, P, R)

    section = "bed"
    section_words = "a calibration from probe heights (probe_z) writes the bed section"
    Setup = BedSetup
    section_order = 30
    section_schema = BedPlane

    def read_setup(self, section, length_factor, machine):
        surface = section.surface
        return BedSetup(section.height * length_factor, section.tilt_x, section.tilt_y,
                        None if surface is None else (
                            surface.radius * length_factor,
                            np.asarray(surface.values, float) * length_factor))

    def setup_section(self, setup, length_factor, machine):
        out = {"height": float(setup.height) / length_factor, "tilt_x": float(setup.tilt_x),
               "tilt_y": float(setup.tilt_y)}
        if setup.surface is not None:
            radius, values = setup.surface
            out["surface"] = {"radius": float(radius) / length_factor,
                              "values": [[float(v) / length_factor for v in row]
                                         for row in np.asarray(values, float)]}
        return out

    def carried_by(self, machine, setup):
        return setup is not None

    def predict(self, machine, setup, P, R, ok, group, rows=None, source=None):
        from .models import NuisanceState

        group = np.zeros(len(P), int)
        state = NuisanceState(np.asarray(setup.plane, float), [])
        return ProbeModel().predict(state, P, R, group), None, group

    simulate_options = {"bed_error": BED_ERROR, "tilt_error": TILT_ERROR}
    simulate_options_words = "bed_error and tilt_error: apply to the probe scenario"

    def simulate(self, machine, true, n, noise, rng, truth, *, setup=None, poses=None,
                 mounting_error=MOUNTING_ERROR, bed_error=BED_ERROR, tilt_error=TILT_ERROR):
        """The standard probe pattern of ``n`` points when there is one
        (:func:`probe_pattern`: 7 = Klipper's DELTA_CALIBRATE, 19, 37, ...), else ``n``
        random points on the bed's disk, or ``poses``; the true bed is the nominal one
        (:func:`~pkmcal.machines.reach.bed_height`) raised by a uniform ``+/- bed_error`` and
        tilted by uniform slopes ``+/- tilt_error``. Each point is probed as a firmware does:
        the nominal model moves the nozzle down the vertical through the point until the
        true machine's nozzle is at the probe's trigger height (0 plus the trigger noise,
        ``noise`` an ``IsotropicNoise``, default :data:`PROBE_SIGMA`; False: exact) above the
        true bed (:func:`probe_trigger`); the readings there are recorded with
        ``probe_z = 0``. See
        :meth:`Instrument.simulate <pkmcal.instruments.base.Instrument.simulate>`.

        Returns
        -------
        tuple
            ``(data, true, truth)``; ``truth`` with ``bed`` (``(height, tilt_x, tilt_y)`` of
            the true bed) and ``setup`` (the true :class:`BedSetup`).
        """
        from .experiment import given_poses, noise_model

        if not (bed_error >= 0 and tilt_error >= 0):
            raise InputError(f"bed_error and tilt_error: must be >= 0, got {bed_error}, "
                             f"{tilt_error}")
        if poses is not None:
            P, R = given_poses(poses)
            words = f"{len(P)} given points"
        else:
            plan = self.standard_plan(machine, n, 0, setup)
            if plan.available:
                P, R, words = plan.P, plan.R, f"{n} points: {plan.name}"
            else:
                P, R, _ = self.candidates(machine, n, rng, setup)
                words = f"{n} random points on the bed's disk"
            _refuse_points_outside_limits(machine, P, R, words)
        bed = np.array([bed_height(machine) + rng.uniform(-bed_error, bed_error),
                        *rng.uniform(-tilt_error, tilt_error, 2)])
        model = noise_model(noise, self.default_noise())
        eps = (np.zeros((len(P), 1)) if model is None
               else model.sample(np.zeros((len(P), 1)), rng))
        q, fk = probe_trigger(true, machine, P, R, bed, eps[:, 0])
        data = InstrumentData("probe", q, np.zeros((len(P), 1)), None, source="<simulated>",
                              true_P=fk.P, true_R=fk.R)
        true_bed = BedSetup(*(float(v) for v in bed))
        z, tx, ty = true_bed.plane
        rows = [("bed", f"true bed at z = {z * 1e3:.6g} mm, slopes dz/dx = {tx:.3g}, dz/dy = "
                 f"{ty:.3g}; the probe triggers at probe_z = 0 (nozzle contact)")]
        truth.update(bed=true_bed.plane, poses=words, rows=rows, setup=true_bed)
        return data, true, truth

    def simulate_arguments(self, machine, noise, **flags):
        sigma = _simulated_sigma(noise, "10um", machine)
        return (IsotropicNoise(sigma) if sigma > 0 else False,
                f"probe trigger {sigma * 1e6:.4g} um along z (std)", {})

    data_columns = ("probe_z",)
    prediction_words = "predicted probe height(s) above the bed"

    def problem(self, machine, data, noise=None, setup=None, **start):

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
    Options = ProbeOptions

    def calibrate(self, machine: Machine, data, context, options):
        """The geometry and the bed plane, the heights' residuals before (the bed fitted
        alone) and after (see :meth:`~pkmcal.instruments.base.Instrument.calibrate`)."""
        return _calibration_flow(machine, data, context, options)

    def joint_part(self, machine: Machine, data, source, noise, read,
                   options: ProbeOptions | None = None):
        """The probe file's part of a fit of several files: its heights and the bed's
        unknowns, decided once the other files are known (see
        :meth:`~pkmcal.instruments.base.Instrument.joint_part`)."""
        probe = load_data(data, read, machine)
        noise_model = (probe.weights[0] if noise is None and probe.weights is not None
                       else self.noise_arg(noise, machine))
        probe.source = str(source)
        _check_heights(probe, machine)

        free_height = bool(getattr(probe, "free_height", False))

        given = (options.bed_tilt if options is not None else None) or "auto"

        def with_others(equations, unknowns, choice=None, data=probe, others=()):
            bed = bed_choice(machine, data, noise_model, choice or given, equations, unknowns,
                             others=others)
            if not free_height:
                return bed.model(), bed.words
            # a saved bed mesh keeps no absolute level (its reference): its own height offset
            return (ProbeModel(fixed=tuple(f for f in bed.fixed if f != "bed.z")),
                    bed.words + "; its own height offset (a mesh's values are relative to its "
                    "reference)")

        model, frame = with_others(0, 0, "estimate" if machine.frame_is_bed else "auto")
        return JointPart(probe, model, noise_model,
                         f"probe trigger {noise_model.sigma * 1e6:.4g} um along z (std)",
                         "probe", with_others, frame)

    def measured_problem(self, machine, data, noise=None, source="", setup=None):
        """The bed's height and tilt started from the data on the machine's geometry."""

        noise = self.default_noise() if noise is None else noise
        fk = _fk_of(machine, data, source)
        model = bed_choice(machine, data, noise).model().start(fk.P, fk.R, data.values,
                                                               data.group, str(source))
        return InstrumentProblem(machine, data, model, noise)



@dataclass
class ProbeSection(Section):
    """What a probe calibration adds to its result (``result.sections["probe"]``): the bed
    plane (the printer's frame, SPEC 8) and the assumption it was fitted under.

    Attributes
    ----------
    bed : tuple of float
        ``(height, tilt_x, tilt_y)``: ``z = height + tilt_x x + tilt_y y`` (base frame), m.
    bed_choice : BedChoice
        Whether the bed's tilt was estimated or held square, in words.
    """

    instrument: ClassVar[str] = "probe"
    title: ClassVar[str] = "bed"

    bed: tuple
    bed_choice: BedChoice

    def plane(self, units=None) -> dict:
        """The bed plane in the file's length unit (tilts as slopes)."""
        from ..units import LENGTH

        unit = (units or {}).get("length", "mm")
        return {"height": self.bed[0] / LENGTH[unit], "tilt_x": self.bed[1],
                "tilt_y": self.bed[2], "unit": unit, "tilt": "slopes dz/dx, dz/dy"}

    def as_report(self, units=None) -> dict:
        return {"bed": {**self.plane(units),
                        "model": "z = height + tilt_x x + tilt_y y (base frame); heights "
                                 "measured along z",
                        "frame": self.bed_choice.words,
                        "tilt_estimated": self.bed_choice.tilt == "estimated"},
                "bed_frame": self.bed_choice.words}

    def summary_rows(self, units=None) -> list:
        # the bed's assumption is the summary's shared "bed" row (a joint fit's too); its
        # plane is in the report's "bed" (and the HTML page's table of it)
        return []


def calibrate_probe(machine: Machine, data: InstrumentData, noise=None, rtol: float = RTOL,
                    fit_machine: bool = True, bed: BedChoice | str = "auto",
                    **options) -> CalibrationResult:
    """Identify the machine's parameters (and the bed plane) from probe heights.

    Parameters
    ----------
    machine : Machine
        Start geometry; not modified.
    data : InstrumentData
        ``kind="probe"``: readings at the triggers and the nozzle's heights above the bed
        there (m).
    noise : IsotropicNoise, optional
        The probe's repeatability along z (default
        :data:`~pkmcal.instruments.probe.PROBE_SIGMA`, 10 um).
    rtol : float, optional
        Rank tolerance.
    fit_machine : bool, optional
        False fits the bed alone with the machine file's model (the "before calibration"
        baseline).
    bed : BedChoice or str, optional
        The bed's unknowns (:func:`bed_choice`; a string is its ``choice``).
    **options
        Passed to :func:`~pkmcal.estimation.estimator.levenberg_marquardt`.

    Returns
    -------
    CalibrationResult
        With ``problem``, ``machine`` (calibrated), ``model``, ``start_model``,
        ``unidentifiable``, its :class:`ProbeSection` (the bed: ``(height, tilt_x,
        tilt_y)``) and ``poorly_determined`` (:func:`poorly_determined`).

    Raises
    ------
    InputError
        When the data are not probe heights, there are fewer than 3 rows (the bed plane), or
        the machine file's model cannot reproduce some readings.
    """

    noise = IsotropicNoise(PROBE_SIGMA) if noise is None else noise
    if data.kind != "probe":
        raise InputError(f"{path_text(data.source)}: {data.kind} data, not probe heights")
    if len(data) < 3:
        raise InputError(f"{path_text(data.source)}: "
                         f"{len(data)} probe height(s); at least 3 points not "
                         "on one line are needed")
    if isinstance(bed, str):
        bed = bed_choice(machine, data, noise, bed, rtol=rtol)
    result = fit_instrument(machine, data, bed.model(), noise, fit_machine=fit_machine,
                            rtol=rtol, **options)
    # the null directions named with the probe's own words (a vertical scale about the bed)
    from ..identifiability import name_null_space, name_weak_directions

    problem = ProbeProblem.__new__(ProbeProblem)
    problem.__dict__.update(result.problem.__dict__)
    groups = problem.null_groups(result.state, result.scales, result.null_space)
    result.problem = problem
    result.unidentifiable = (
        name_null_space(result.null_space, problem.parameters, groups)
        + name_weak_directions(result, problem.parameters))
    choice = bed
    bed = tuple(float(v) for v in result.state.nuisance.values[:3])
    result.add_section(ProbeSection(bed, choice))
    n_machine = len(machine.parameters)
    result.poorly_determined = (
        poorly_determined(result, n_machine, machine.characteristic_length())
        if fit_machine else [])
    return result



# -- calibration flow (pkmcal calibrate; issue 14 items 2, 3) ---------------------------------

#: a common offset of the probe heights against the machine file's model beyond this (m) is
#: checked for a flipped sign or a wrong unit (below it the two cannot be told from a
#: machine file's endstop error)
HEIGHT_CHECK = 2e-4


def _check_heights(data, machine) -> None:
    """Probe heights with a flipped sign or a wrong unit, refused naming the fix.

    On a machine whose frame is its bed the machine file's model puts the nozzle at a height
    for each row's readings; the saved heights sit about there (the file's values are the
    firmware's). When they sit ``HEIGHT_CHECK`` or more away from it and their negatives, or
    the same numbers in mm / um, sit ten times closer, the sign or the unit is wrong.
    """
    if not getattr(machine, "frame_is_bed", False) or not len(data):
        return
    fk = machine.fk(data.q)
    if not fk.converged.all():
        return
    z = np.asarray(fk.P, float)[:, 2]
    h = np.asarray(data.values, float)[:, 0]
    offset = abs(float(np.median(z - h)))
    if offset < HEIGHT_CHECK:
        return
    fixes = (("the opposite sign", -h, "probe_z is the nozzle's height ABOVE the bed when the "
              "probe triggers (Klipper's heightN and [probe] z_offset; Marlin's M851 Z is its "
              "negative): flip the sign"),
             ("in um", h * 1e-3, "the unit of probe_z is wrong (the numbers are um)"),
             ("in mm", h * 1e3, "the unit of probe_z is wrong (the numbers are mm)"))
    for words, other, fix in fixes:
        if abs(float(np.median(z - other))) < 0.1 * offset:
            raise InputError(f"{path_text(data.source)}: "
                             f"the probe heights sit {offset * 1e3:.4g} mm "
                             f"from where the machine file puts the nozzle, and {words} "
                             f"within {abs(float(np.median(z - other))) * 1e3:.3g} mm of it: "
                             f"{fix} (or, if the machine file's position_endstop values are "
                             "that far from the ones the data were probed with, import the "
                             "config the data were saved with)")


def _calibration_flow(machine, data, context: FlowContext,
                      options: ProbeOptions) -> FlowResult:
    """``pkmcal calibrate`` from probe heights (:meth:`Probe.calibrate`)."""

    source, split = context.source, context.split
    noise = INSTRUMENT.noise_arg(options.noise, machine)
    chosen: dict = {}

    def fit(machine_, data_, noise_, **kwargs):
        # one bed model for the fit and its baseline, chosen on the parameter set's unknowns
        if "bed" not in chosen:
            _check_heights(data_, machine)
            chosen["bed"] = bed_choice(machine, data_, noise_, options.bed_tilt or "auto")
        return calibrate_probe(machine_, data_, noise_, bed=chosen["bed"], **kwargs)

    data, held, result, before, calibrated, params, units = fit_with_baseline(
        machine, data, context, fit, noise,
        "probe over the whole bed (the centre and rings out to the edge of the reachable "
        "radius)", estimate_noise=options.noise is None, robust=options.robust)
    problem, before_problem = result.problem, before.problem
    rms_after, r_after = scalar_rms(problem, result.state, data)
    rms_before, r_before = scalar_rms(before_problem, before.state, data)
    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.unidentifiable)
    section = result.section(ProbeSection)
    bed_report = section.as_report(units)
    bed_report["bed"]["before"] = before.section(ProbeSection).plane(units)

    report = {
        **context.head(machine, "probe", "joint"),
        "units": units,
        "measurements": len(data),
        "noise": f"probe trigger {noise.sigma * 1e6:.4g} um along z (std)",
        **bed_report,                       # bed (with the one fitted alone), bed_frame
        "convergence": convergence_json(result),
        "residuals": scalar_residuals_json(
            result, r_after, rms_after, rms_before,
            "probe heights, measured - predicted (forward kinematics of the readings, height "
            "above the fitted bed along z)",
            "machine file's model, bed plane (height and tilt) fitted alone", r_before),
        "identifiability": identifiability_json(n_free, rank, unidentifiable, s),
        "parameters": public_parameters(params),
    }
    if held is not None:
        report["validation"] = validation_section(
            split, held, "probe heights of the held-out rows, measured - predicted with the "
            "identified bed; before: the machine file's model with the bed fitted alone on "
            "the calibration rows", "um",
            scalar_rms(before_problem, before.state, held)[0],
            scalar_rms(problem, result.state, held)[0], rms_after)
    metadata = scalar_metadata("probe", report, source, machine, result, rms_after, len(data),
                               unidentifiable)
    # the bed's plane as fitted; its own shape (the machine file's) kept until meshes refit it
    given = context.setups.get("probe")
    fitted = BedSetup(*section.bed, surface=None if given is None else given.surface)
    return FlowResult("probe", machine, calibrated, result, report, metadata, params, units,
                      setups={"probe": fitted})


#: this module's instrument (:data:`~pkmcal.instruments.registry.INSTRUMENT_MODULES`)
INSTRUMENT = Probe()
